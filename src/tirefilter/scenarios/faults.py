"""Sensor faults: what goes wrong between a car's sensors and the estimator.

A scenario TOML lists them as `[[faults]]` tables (applied to the sensors of a
co-simulation, ground truth untouched); replay tests and the fault benchmark apply the same
faults to the rows of a log (`fault_log_columns`). One injector implements them all, sample
by sample, with its own generator (the third child of the run's SeedSequence, so the FMU's
and the estimator's streams stay those of a clean run):

| kind        | keys                          | effect on the samples in [start, end)               |
|-------------|-------------------------------|------------------------------------------------------|
| `dropout`   | signal, rate                  | each sample missing (NaN) with probability `rate`    |
| `stuck`     | signal                        | the value at `start` repeats (a frozen sensor)       |
| `spike`     | signal, size, times           | `size` added at the first sample at or after each time |
| `bias_step` | signal, size                  | `size` added (an offset that appears at `start`)     |
| `held`      | signal, rate                  | with probability `rate` the previous sample repeats  |
| `jitter`    | size                          | time stamps t + N(0, size^2) [s], kept increasing    |
| `gap`       |                               | no samples at all (the logger lost them)             |

`signal` is one of the log signals (delta, ax, ay, yaw_rate, vx, omega_f, omega_r); `start`
defaults to 0 and `end` to the end of the run. Units are SI (m/s^2, rad/s, rad, m/s, s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tirefilter.errors import ConfigError

SIGNALS = ("delta", "ax", "ay", "yaw_rate", "vx", "omega_f", "omega_r")
KINDS = ("dropout", "stuck", "spike", "bias_step", "held", "jitter", "gap")
_KEYS = {"dropout": ("signal", "rate"), "stuck": ("signal",), "spike": ("signal", "size", "times"),
         "bias_step": ("signal", "size"), "held": ("signal", "rate"), "jitter": ("size",), "gap": ()}


@dataclass(frozen=True)
class Fault:
    kind: str
    signal: str | None = None
    start: float = 0.0  # s
    end: float = math.inf  # s
    rate: float = 0.0  # probability per sample (dropout, held)
    size: float = 0.0  # SI units of the signal (spike, bias_step); s (jitter std)
    times: tuple[float, ...] = ()  # s (spike)

    def active(self, t: float) -> bool:
        return self.start <= t < self.end


def parse_faults(entries, source: str = "faults") -> tuple[Fault, ...]:
    """Faults from a list of tables (`[[faults]]` of a scenario TOML, or dicts); each error
    names the source, the entry and the key."""
    if entries is None:
        return ()
    if not isinstance(entries, list):
        raise ConfigError(source, "faults", "expected an array of tables [[faults]]")
    out = []
    for j, e in enumerate(entries):
        where = f"faults[{j}]"
        if not isinstance(e, dict):
            raise ConfigError(source, where, f"expected a table, got {e!r}")
        kind = e.get("kind")
        if kind not in KINDS:
            raise ConfigError(source, f"{where}.kind", f"expected one of {', '.join(KINDS)}, got {kind!r}")
        allowed = set(_KEYS[kind]) | {"kind", "start", "end"}
        extra = sorted(set(e) - allowed)
        if extra:
            raise ConfigError(source, f"{where}.{extra[0]}", f"not a key of a {kind} fault "
                              f"(keys: {', '.join(sorted(allowed))})")
        missing = [k for k in _KEYS[kind] if k not in e]
        if missing:
            raise ConfigError(source, f"{where}.{missing[0]}", f"a {kind} fault needs {', '.join(missing)}")

        def number(key, default, lo=-math.inf, hi=math.inf):
            v = e.get(key, default)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or math.isnan(v) or not lo <= v <= hi:
                raise ConfigError(source, f"{where}.{key}", f"expected a number in [{lo:g}, {hi:g}], got {v!r}")
            return float(v)

        signal = e.get("signal")
        if "signal" in _KEYS[kind] and signal not in SIGNALS:
            raise ConfigError(source, f"{where}.signal", f"expected one of {', '.join(SIGNALS)}, got {signal!r}")
        start, end = number("start", 0.0), number("end", math.inf)
        if not start < end:
            raise ConfigError(source, f"{where}.end", f"must be after start ({start:g} s), got {end:g} s")
        times = e.get("times", ())
        if not isinstance(times, (list, tuple)) or not all(
                isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in times):
            raise ConfigError(source, f"{where}.times", f"expected a list of times in s, got {times!r}")
        out.append(Fault(kind=kind, signal=signal, start=start, end=end,
                         rate=number("rate", 0.0, 0.0, 1.0),
                         size=number("size", 0.0, 0.0 if kind == "jitter" else -math.inf, math.inf),
                         times=tuple(sorted(float(x) for x in times))))
    return tuple(out)


class FaultInjector:
    """Applies `faults` to samples in time order: `apply(t, values)` with `values` a dict
    signal -> float (modified in place) returns the faulty time stamp, or None when the
    sample falls in a gap. Deterministic for a given generator."""

    def __init__(self, faults, rng: np.random.Generator):
        self.faults = tuple(faults)
        self.rng = rng
        self._stuck: dict[int, float] = {}  # fault index -> the frozen value
        self._prev: dict[str, float] = {}  # signal -> last value handed out (for held samples)
        self._spike_next = {j: 0 for j, f in enumerate(self.faults) if f.kind == "spike"}
        self._t_out = -math.inf
        self.counts = {k: 0 for k in KINDS}  # samples affected, per kind

    def apply(self, t: float, values: dict) -> float | None:
        for j, f in enumerate(self.faults):
            if f.kind == "spike":  # independent of start/end: at its times
                k = self._spike_next[j]
                if k < len(f.times) and t >= f.times[k]:
                    self._spike_next[j] = k + 1 + sum(1 for x in f.times[k + 1:] if x <= t)
                    values[f.signal] = values[f.signal] + f.size
                    self.counts["spike"] += 1
                continue
            if not f.active(t):
                continue
            if f.kind == "gap":
                self.counts["gap"] += 1
                return None
            if f.kind == "dropout":
                if self.rng.random() < f.rate:
                    values[f.signal] = math.nan
                    self.counts["dropout"] += 1
            elif f.kind == "stuck":
                values[f.signal] = self._stuck.setdefault(j, values[f.signal])
                self.counts["stuck"] += 1
            elif f.kind == "bias_step":
                values[f.signal] = values[f.signal] + f.size
                self.counts["bias_step"] += 1
            elif f.kind == "held":
                if f.signal in self._prev and self.rng.random() < f.rate:
                    values[f.signal] = self._prev[f.signal]
                    self.counts["held"] += 1
        t_out = t
        for f in self.faults:
            if f.kind == "jitter" and f.active(t):
                t_out = t + f.size * float(self.rng.standard_normal())
                self.counts["jitter"] += 1
        t_out = max(t_out, math.nextafter(self._t_out, math.inf))  # time stamps still increase
        self._t_out = t_out
        self._prev.update(values)
        return t_out


def fault_rng(seed: int) -> np.random.Generator:
    """The faults' generator of a run with `seed`: the third child of its SeedSequence
    (runs.spawn_seeds uses the first two)."""
    return np.random.default_rng(np.random.SeedSequence(seed).spawn(3)[2])


def fault_log_columns(t: np.ndarray, signals: dict, faults, rng: np.random.Generator) -> tuple[np.ndarray, dict]:
    """The faulty copy of a log's rows: `t` (n,) and `signals` (name -> (n,) arrays) ->
    (t', signals') with the rows in gaps left out."""
    inj = FaultInjector(faults, rng)
    names = list(signals)
    cols = np.column_stack([np.asarray(signals[n], float) for n in names])
    keep, t_out, rows = [], [], []
    for k, tk in enumerate(np.asarray(t, float).tolist()):
        values = dict(zip(names, cols[k].tolist()))
        tk2 = inj.apply(tk, values)
        if tk2 is None:
            continue
        keep.append(k)
        t_out.append(tk2)
        rows.append([values[n] for n in names])
    out = np.asarray(rows, float).reshape(len(rows), len(names))
    return np.asarray(t_out), {n: out[:, j] for j, n in enumerate(names)}


def faulty_samples(samples, faults, rng: np.random.Generator):
    """The co-simulation's samples (`cosim.run.CosimSample`) with `faults` applied to what
    the estimator is given (its Inputs, Measurement and time stamp); the FMU's outputs (the
    truth and the clean sensors of the Result CSV) are left as they are; samples in a gap
    are left out."""
    import dataclasses

    inj = FaultInjector(faults, rng)
    for s in samples:
        u, y = s.inputs, s.meas
        values = {"delta": u.delta, "omega_f": u.omega_f, "omega_r": u.omega_r, "vx": u.vx,
                  "ax": y.ax, "ay": y.ay, "yaw_rate": y.yaw_rate}
        t = inj.apply(s.t, values)
        if t is None:
            continue
        yield dataclasses.replace(
            s, t=t, inputs=dataclasses.replace(u, **{k: values[k] for k in ("delta", "omega_f", "omega_r", "vx")}),
            meas=dataclasses.replace(y, **{k: values[k] for k in ("ax", "ay", "yaw_rate")}))


def fault_sets(duration: float) -> dict[str, tuple[Fault, ...]]:
    """The sensor faults (tests and the fault benchmark), placed on a drive of
    `duration` s: each alone, and `combined`, the set of the fault benchmark (20 % dropouts per IMU
    channel, the yaw rate stuck for 2 s, five a^Y spikes of +20 m/s^2, an a^Y bias step of
    +0.3 m/s^2, 1 ms time jitter)."""
    d = float(duration)
    imu = ("ax", "ay", "yaw_rate")
    sets = {
        "dropout": tuple(Fault("dropout", s, rate=0.2) for s in imu),
        "stuck": (Fault("stuck", "yaw_rate", start=0.4 * d, end=0.4 * d + 2.0),),
        "spike": (Fault("spike", "ay", size=20.0, times=tuple(round(d * f, 2) for f in (0.15, 0.3, 0.45, 0.6, 0.75))),),
        "bias_step": (Fault("bias_step", "ay", start=0.5 * d, size=0.3),),
        "held": tuple(Fault("held", s, rate=0.12) for s in imu),
        "jitter": (Fault("jitter", size=0.001),),
        "gap": (Fault("gap", start=0.65 * d, end=0.65 * d + 1.0),),
    }
    sets["combined"] = sets["dropout"] + sets["stuck"] + sets["spike"] + sets["bias_step"] + sets["jitter"]
    return sets


def fault_windows(faults) -> list[tuple[float, float]]:
    """[start, end) of the faults that end (stuck, gap, spikes as instants) for recovery checks."""
    out = []
    for f in faults:
        if f.kind == "spike":
            out += [(x, x) for x in f.times]
        elif f.kind in ("stuck", "gap") and math.isfinite(f.end):
            out.append((f.start, f.end))
    return sorted(out)
