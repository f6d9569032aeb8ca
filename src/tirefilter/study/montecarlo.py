"""The Monte-Carlo engine: many co-simulated trials of one estimator configuration.

- **Seeds** come from one `SeedSequence(study_seed)`: trial i gets the 32-bit integer drawn
  from its i-th spawned child, and `tirefilter run --seed <that integer>` reproduces the
  trial exactly. Every configuration of a study uses the same trial seeds, so estimators
  and particle counts are compared on the same truth and sensor noise (common random
  numbers).
- **Workers**: trials run in a process pool (`spawn` start method), one vehicle FMU per
  worker, reset between its trials (`run_scenario(fmu=...)`). With one worker they run in
  this process. With `scheduler` (an address, `tcp://host:8786`) they run on an existing
  Dask cluster instead (dask.distributed, the `dask` extra): the same function per trial,
  one FMU per worker thread, reused across its trials (docs/dask.md). The estimators step one trial at a time; none of them carries a trial
  axis, so trials are not batched inside a process.
- **Results** are written per trial as it finishes: its metrics as one line of
  `DIR/metrics.jsonl` and its (decimated) series as `DIR/trial-<i>.npz`. An interrupted
  study keeps what finished, and running the same configuration into the same directory
  again runs only the trials that are missing (`DIR/spec.json` records the configuration;
  a different one in the same directory is an error, not a silent mix).
"""

from __future__ import annotations

import json
import math
import os
import threading
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import asdict, dataclass, field, replace
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from tirefilter.errors import ConfigError
from tirefilter.metrics import run_metrics, settling_time, steady_state_mask, stiffness_errors
from tirefilter.runs import check_interrupt

PARAMS = ("Cf_y", "Cr_y", "Cx")
SERIES = ("t", "active", "vx", "vy", "yaw_rate", "true_vy", "true_yaw_rate", "meas_yaw_rate", "true_delta", "ess",
          "b_ax", "b_ay", "b_yaw_rate", "true_b_ax", "true_b_ay", "true_b_yaw_rate",
          *(f"{p}{s}" for p in PARAMS for s in ("", "_std", "_sigma")),
          *(f"true_{p}{s}" for p in PARAMS for s in ("", "_mean")))


@dataclass(frozen=True)
class TrialSpec:
    """One configuration of a study: everything a trial needs except its seed."""

    scenario: str
    estimator: str
    particles: int | None = None
    model: str = "auto"
    config: dict = field(default_factory=dict)  # estimator tables, as `--config` gives them
    duration: float | None = None  # s, shorter than the scenario's (tests, quick looks)
    decimate: int = 10  # keep every n-th sample of the stored series

    def key(self) -> str:
        """A directory name for the configuration."""
        n = f"-N{self.particles}" if self.particles else ""
        d = f"-{self.duration:g}s" if self.duration else ""
        return f"{self.scenario}/{self.estimator}{n}{d}"


def trial_seeds(study_seed: int, trials: int) -> list[int]:
    """The integer seed of each trial, from one SeedSequence (see the module docstring)."""
    return [int(c.generate_state(1, dtype=np.uint32)[0]) for c in np.random.SeedSequence(study_seed).spawn(trials)]


@dataclass
class TrialResult:
    index: int
    seed: int
    metrics: dict
    series: dict[str, np.ndarray]


class StudyRun:
    """The finished trials of one configuration in `directory`, loaded and appended to."""

    def __init__(self, directory: Path, spec: TrialSpec, study_seed: int):
        self.dir = Path(directory)
        self.spec, self.study_seed = spec, study_seed
        record = {"spec": asdict(spec), "study_seed": study_seed}
        spec_file = self.dir / "spec.json"
        if spec_file.exists():
            old = json.loads(spec_file.read_text())
            if old != json.loads(json.dumps(record)):
                raise ConfigError(str(spec_file), "spec", f"this directory holds trials of another configuration "
                                  f"({old}); use another --out or remove it")
        self.dir.mkdir(parents=True, exist_ok=True)
        spec_file.write_text(json.dumps(record, indent=1) + "\n")
        self.metrics: dict[int, dict] = {}
        lines = self.dir / "metrics.jsonl"
        if lines.exists():
            for line in lines.read_text().splitlines():
                if line.strip():
                    m = json.loads(line)
                    self.metrics[m["trial"]] = m

    def save(self, result: TrialResult) -> None:
        np.savez_compressed(self.dir / f"trial-{result.index}.npz", **result.series)
        with open(self.dir / "metrics.jsonl", "a") as f:
            f.write(json.dumps(result.metrics) + "\n")
        self.metrics[result.index] = result.metrics

    def series(self, index: int) -> dict[str, np.ndarray] | None:
        path = self.dir / f"trial-{index}.npz"
        if not path.exists():
            return None
        with np.load(path) as z:
            return {k: z[k] for k in z.files}

    def ok(self) -> list[dict]:
        """Metrics of the trials that finished, in trial order."""
        return [self.metrics[i] for i in sorted(self.metrics) if self.metrics[i]["status"] == "ok"]


def run_study(spec: TrialSpec, trials: int, directory: str | Path, *, study_seed: int = 0, workers: int | None = None,
              progress: bool = False, scheduler: str | None = None) -> StudyRun:
    """Run the trials of `spec` that `directory` does not hold yet; returns all of them.

    `workers` defaults to the number of CPUs; 1 runs the trials in this process.
    `scheduler`: the address of a Dask scheduler; the trials run on its workers (`workers`
    is then ignored) and are saved here as they finish, as with the local pool.
    """
    if trials < 1:
        raise ConfigError("--trials", "", f"needs at least one trial, got {trials}")
    store = StudyRun(Path(directory), spec, study_seed)
    seeds = trial_seeds(study_seed, trials)
    todo = [(i, s) for i, s in enumerate(seeds) if i not in store.metrics]
    bar = _Bar(spec.key(), trials, len(seeds) - len(todo), progress)
    workers = max(1, min(workers or os.cpu_count() or 1, len(todo) or 1))
    if scheduler is not None:
        if todo:
            _run_on_dask(scheduler, spec, todo, store, bar)
    elif workers == 1:
        fmu = None
        try:
            for i, s in todo:
                if fmu is None:
                    from tirefilter.cosim.fmu import VehicleFMU

                    fmu = VehicleFMU()
                store.save(run_trial(spec, i, s, fmu=fmu))  # Interrupted (runs.check_interrupt) leaves it unsaved
                bar.update()
                check_interrupt()
        finally:
            if fmu is not None:
                fmu.close()
    else:
        with ProcessPoolExecutor(workers, mp_context=get_context("spawn"), initializer=_worker_init) as pool:
            futures = [pool.submit(_worker_trial, spec, i, s) for i, s in todo]
            try:
                pending = set(futures)
                while pending:  # polled, so that a signal noted by runs.interruptible stops it promptly
                    done, pending = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
                    for fut in done:
                        store.save(fut.result())
                        bar.update()
                    check_interrupt()
            except BaseException:
                for f in futures:
                    f.cancel()
                for proc in list(getattr(pool, "_processes", {}).values()):  # trials under way are run again on resume
                    proc.kill()  # they ignore SIGTERM (_worker_init)
                raise
    bar.close()
    return store


DASK_CONNECT_TIMEOUT_S = 20.0  # s: how long `--scheduler ADDRESS` waits for the scheduler to answer


def _run_on_dask(address: str, spec: TrialSpec, todo, store: StudyRun, bar) -> None:
    """The trials `todo` on the Dask cluster at `address`, saved as they come back."""
    try:
        from dask.distributed import Client, as_completed as dask_completed
    except ImportError:
        raise ConfigError("--scheduler", "", "needs dask.distributed: pip install 'tirefilter[dask]'") from None
    try:
        client = Client(address, timeout=f"{DASK_CONNECT_TIMEOUT_S}s", set_as_default=False)
    except OSError as exc:
        raise ConfigError("--scheduler", "", f"no Dask scheduler at {address!r} ({exc})") from None
    try:
        with client.as_current():
            futures = [client.submit(_worker_trial, spec, i, s, key=f"tirefilter-trial-{spec.key()}-{i}-{s}",
                                     pure=False) for i, s in todo]
            try:
                for fut in dask_completed(futures):
                    store.save(fut.result())
                    bar.update()
            except BaseException:
                client.cancel(futures)
                raise
    finally:
        client.close()


_WORKER = threading.local()  # one vehicle FMU per worker thread (pool process or Dask worker thread)


def _worker_init() -> None:
    """Pool workers ignore SIGINT and SIGTERM: the main process decides (a Ctrl-C reaches
    the whole process group) and terminates them."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)


def _worker_trial(spec: TrialSpec, index: int, seed: int) -> TrialResult:
    """A trial in a pool or Dask worker, on that worker's one FMU instance."""
    fmu = getattr(_WORKER, "fmu", None)
    if fmu is None:
        from tirefilter.cosim.fmu import VehicleFMU

        fmu = _WORKER.fmu = VehicleFMU()
    return run_trial(spec, index, seed, fmu=fmu)


def run_trial(spec: TrialSpec, index: int, seed: int, *, fmu) -> TrialResult:
    """Co-simulate one trial and reduce it to metrics (docs/usage.md definitions) and series.

    A failing estimator gives a trial with `status: failed`, its error and NaN metrics;
    the study goes on.
    """
    from tirefilter.io.results import result_columns
    from tirefilter.cosim.run import run_scenario
    from tirefilter.estimators import build, for_scenario

    scenario = study_scenario(spec)
    estimator = build(spec.estimator, for_scenario(scenario), model=spec.model, particles=spec.particles,
                      config=spec.config)
    metrics = {"trial": index, "seed": seed, "status": "ok", "error": None}
    t0 = time.perf_counter()
    try:
        summary, rows = run_scenario(scenario, estimator=estimator, seed=seed, fmu=fmu, keep_rows=True,
                                     metrics=False)  # trial_metrics scores the rows below
    except Exception as exc:  # an estimator that fails is a result of the study
        summary, rows = exc.summary, None
        metrics.update(status="failed", error=f"{type(exc).__name__}: {exc}")
    metrics.update(wall_time_s=time.perf_counter() - t0, median_step_us=summary.median_step_us,
                   restarts=getattr(estimator, "restarts", None))
    if rows is None:
        return TrialResult(index, seed, metrics, {})
    r = dict(zip(result_columns(fmu.output_names), rows.T))
    metrics.update(trial_metrics(r, scenario))
    series = {k: r[k][::spec.decimate].astype(np.float32) for k in SERIES if k in r}
    return TrialResult(index, seed, metrics, series)


def study_scenario(spec: TrialSpec):
    from tirefilter.scenarios import load_scenario

    scenario = load_scenario(spec.scenario)
    if spec.duration is None:
        return scenario
    if not 0 < spec.duration <= scenario.duration:
        raise ConfigError("--duration", "", f"{spec.duration:g} s is outside (0, {scenario.duration:g}] s of "
                          f"{scenario.name}")
    return replace(scenario, duration=spec.duration,
                   surface_changes=tuple(t for t in scenario.surface_changes if t < spec.duration))


FINAL_WINDOW_S = 100.0  # s: how a drive ends, "mean over the last 100 s" (paper A, Figs. 7-8)


def final_error(r: dict, param: str, window: float) -> float:
    """Mean relative error (%) of `param` against the surface mean over the last `window`
    seconds of the run (NaN estimates count as infinite errors)."""
    t = r["t"]
    last = t >= t[-1] - window
    err = 100.0 * (r[param][last] - r[f"true_{param}_mean"][last]) / r[f"true_{param}_mean"][last]
    return float(np.mean(np.where(np.isnan(err), np.inf, err)))


def trial_metrics(r: dict, scenario) -> dict:
    """Per stiffness parameter the metrics of docs/usage.md (steady-state errors, coverage,
    spread, settling time after the first surface change, and the error of the spread
    against the scenario's true deviation std, in points of the mean), plus the
    time-averaged v^Y RMSE (Fig. 5) and the share of samples with learning active."""
    run = run_metrics(r, scenario)
    out = {"vy_rmse": run["state"]["vy"]["rmse"], "active_share": run["gate_open_share"]}
    true_spread = 100.0 * scenario.truth.get("stiffness_dev_std", 0.0)
    if not np.any(steady_state_mask(r["t"], scenario)):
        return out  # no steady-state window in a shortened run
    for p in PARAMS:
        if p not in r or not np.any(np.isfinite(r[p])):
            continue
        e = stiffness_errors(r, scenario, p)
        if "sigma_pct" in e:
            e["sigma_err"] = e["sigma_pct"] - true_spread
        e["settle"] = settling_time(r, p, scenario.surface_changes[0]) if scenario.surface_changes else math.nan
        e["final"] = final_error(r, p, FINAL_WINDOW_S)
        out[p] = e
    return out


class _Bar:
    """Trials done of all, on stderr when enabled."""

    def __init__(self, label: str, total: int, done: int, enabled: bool):
        self.label, self.total, self.done, self.enabled = label, total, done, enabled
        self.t0 = time.perf_counter()
        self.update(0)

    def update(self, k: int = 1) -> None:
        self.done += k
        if self.enabled:
            import sys

            bar = "#" * (25 * self.done // self.total)
            sys.stderr.write(f"\r{self.label:<36s} [{bar:<25}] {self.done}/{self.total} "
                             f"{time.perf_counter() - self.t0:6.0f} s")
            sys.stderr.flush()

    def close(self) -> None:
        if self.enabled:
            import sys

            sys.stderr.write("\n")
