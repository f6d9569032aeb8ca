"""Per-step cost against N, every estimator and a peer in one run (Fig. 14 of paper A).

    .venv/bin/python benchmarks/bench_cost.py [--particles 50 100 200 500 1000 2000 5000]
        [--duration 10] [--estimators mpf augpf ekf rls kf bootstrap gpssm-axle gpssm-tensor gpssm-tensor100]
        [--figure benchmarks/figures/stiffness_fig14_cost.png] [--gpssm-max 1000] [--interleave]
    .venv/bin/python benchmarks/bench_cost.py --replay LOG.csv --vehicle V.toml [--particles 500] [--repeat R]
        [--backends numba c]

What is timed: `step()` of each estimator (median wall time and median CPU time of the
thread after 10 warm-up steps, one process, one BLAS thread), fed the same recorded samples:
- mpf, augpf, ekf, rls, kf: paper-sim (full model, 100 Hz, seed 0, the first `--duration` s),
  the stiffness estimators as `tirefilter run` builds them;
- bootstrap: the peer, a bootstrap particle filter of the `particles` library (Chopin,
  `pip install --no-deps particles==0.4`, see pyproject's `bench` extra) on the same car and
  the same samples: the single-track model of the estimators (linear tires at the nominal
  stiffness, Euler steps) written as a `particles.state_space_models.StateSpaceModel`, state
  [vx, vy, r], inputs delta and the wheel rates, measurements ax, ay, yaw rate. It learns
  nothing: it is the cost of a plain particle filter of the same car in a maintained library;
  one step is one `next()` of `particles.SMC` (systematic resampling at ESS < N / 2, as ours);
- gpssm-*: the friction GP-SSM (exact statistics, the default) on friction-snow (25 Hz, seed 0),
  the per-axle basis (20 odd functions in all), the default odd tensor (50) and the paper's
  tensor (100), N up to `--gpssm-max`; `gpssm-axle-rank1` etc. (named explicitly): the same
  with the rank-one statistics.

`--interleave`: besides, the MPF and the peer step alternately through the same samples in
one loop at each N (one MPF step, one peer step, ...), so that a load that comes and goes on
a shared machine falls on both alike: the ratio of their CPU medians printed from that loop
is the comparison to quote on a busy machine (separate loops can see loads apart by 2x).

`--replay LOG --vehicle V.toml`: instead, the MPF as `tirefilter replay LOG --vehicle V.toml
--particles N` builds it (every default of a replay: the bias filter with the wandering offsets, the
calibrated band, the wheel-speed filter, the roll gradient, the IMU's
lever arm; the log's samples as the run loop hands them to `step`, the measurement guard applied) and
the peer on the same log (the car of the vehicle TOML, the noise figures the MPF assumes, the log's
median sample period), stepped alternately as with `--interleave`, `--repeat` times at each N, one MPF per
backend of `--backends` (default numba and c) in the same loop; the MPF's options are printed with the figures. docs/results.md uses a 66 s peer drive
(`tirefilter peer-drive --maneuver mixed --duration 66 --seed 0`).

Each estimator's first two calls (numba compilation when the cache is cold, imports; the
MPF's first sample compiles or loads its kernels, with the informed start's weights) are printed apart: `first call ms` is their sum, the median excludes both. The load
average is printed before and after: on a shared machine, compare numbers within one run
only.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # noqa: E402  (small batched calls; see tests/conftest.py)

import argparse  # noqa: E402
import math  # noqa: E402
import shutil  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from tirefilter.cosim.fmu import VehicleFMU  # noqa: E402
from tirefilter.cosim.run import cosim_samples  # noqa: E402
from tirefilter.runs import spawn_seeds  # noqa: E402
from tirefilter.estimators import build_estimator  # noqa: E402
from tirefilter.scenarios import load_scenario  # noqa: E402
from tirefilter.vehicle.single_track import wheel_slip  # noqa: E402

PARTICLE_FREE = ("ekf", "rls", "kf")
GPSSM = {"gpssm-axle": {"basis": "axle"}, "gpssm-tensor": {"basis": "tensor"},
         "gpssm-tensor100": {"basis": "tensor", "symmetry": "none"}}
# the same with the rank-one statistics (stats = "rank1"), named on request only
GPSSM.update({f"{k}-rank1": dict(v, stats="rank1") for k, v in list(GPSSM.items())})
WARMUP = 10


def record(name: str, duration: float, seed: int = 0) -> tuple:
    """The scenario (shortened) and its estimator samples [(t, Inputs, Measurement)]."""
    sc = load_scenario(name)
    sc = replace(sc, duration=min(duration, sc.duration),
                 surface_changes=tuple(t for t in sc.surface_changes if t < duration))
    fmu_seed, _ = spawn_seeds(seed)
    with VehicleFMU() as fmu:
        samples = [(s.t, s.inputs, s.meas) for s in cosim_samples(sc, fmu, sc.fmu_parameters(fmu_seed))]
    return sc, samples


def _timed(step, n: int) -> tuple[float, float, float]:
    """Call step(k) for k < n: (median wall us, median CPU us of this thread, first two calls ms)
    after the warm-up. On a loaded machine a step longer than the scheduler's time slice is
    preempted and its wall time inflates; the thread's CPU time does not."""
    wall, cpu = [], []
    for k in range(n):
        c0, t0 = time.thread_time(), time.perf_counter()
        step(k)
        wall.append(time.perf_counter() - t0)
        cpu.append(time.thread_time() - c0)
    return float(np.median(wall[WARMUP:]) * 1e6), float(np.median(cpu[WARMUP:]) * 1e6), (wall[0] + wall[1]) * 1e3


def time_estimator(est, samples, seed: int = 1) -> tuple[float, float, float]:
    """(median wall us per step after the warm-up, median CPU us, first call in ms)."""
    est.reset(np.random.default_rng(seed))
    return _timed(lambda k: est.step(*samples[k]), len(samples))


# ---- the peer: a bootstrap PF of the `particles` library on the same car -----------------
def bootstrap_peer(scenario, samples, N: int, seed: int = 1) -> tuple[float, float, float]:
    """(median wall us per step after the warm-up, median CPU us, first call in ms) of the peer."""
    return _timed(bootstrap_step(scenario, samples, N, seed), len(samples))


def bootstrap_step(scenario, samples, N: int, seed: int = 1):
    """The peer's step: a function of the sample index k that runs one `next()` of the SMC."""
    s = scenario.sensor_spec
    return peer_step(scenario.vehicle, (s.sigma_ax, s.sigma_ay, s.sigma_yaw_rate), scenario.sample_period, samples,
                     N, seed)


def peer_step(v, sigma, Ts: float, samples, N: int, seed: int = 1):
    """The peer's step for the car `v` (VehicleParams), the measurement noise std `sigma` (a^X, a^Y, yaw rate)
    and the sample period Ts: a function of the sample index k that runs one `next()` of the SMC."""
    import particles
    from particles import distributions as dists
    from particles import state_space_models as ssm

    drive_front = v.drive != "rear"
    Cx_other = v.Cx if v.Cx_undriven is None else v.Cx_undriven
    Cfx, Crx = (v.Cx, Cx_other) if drive_front else (Cx_other, v.Cx)
    U = np.array([[u.delta, u.omega_f, u.omega_r] for _, u, _ in samples])
    Y = [np.array([y.ax, y.ay, y.yaw_rate]) for _, _, y in samples]

    def accelerations(x, u):
        """(a^X, a^Y, r') of the single-track model with linear tires (eq. (1)-(4) of paper A)."""
        vx, vy, r = x[:, 0], x[:, 1], x[:, 2]
        ivx = 1.0 / np.maximum(vx, 1.0)
        af = u[0] - (vy + v.lf * r) * ivx
        ar = (v.lr * r - vy) * ivx
        lf_, lr_ = wheel_slip(vx, v.wheel_radius * u[1]), wheel_slip(vx, v.wheel_radius * u[2])
        Ffy, Fry, Ffx, Frx = v.Cf_y * af, v.Cr_y * ar, Cfx * lf_, Crx * lr_
        cd, sd = math.cos(u[0]), math.sin(u[0])
        ax = (Ffx * cd - Ffy * sd + Frx) / v.mass
        ay = (Ffy * cd + Ffx * sd + Fry) / v.mass
        return ax, ay, (v.lf * (Ffy * cd + Ffx * sd) - v.lr * Fry) / v.yaw_inertia

    class SingleTrack(ssm.StateSpaceModel):
        """x = [vx, vy, r]; Euler step of eq. (1) plus Gaussian process noise; y = (ax, ay, r)."""

        q = np.array([0.05, 0.05, 0.005])  # per step: the estimators' state noise would be 0

        def PX0(self):
            return dists.IndepProd(dists.Normal(loc=U[0, 2] * v.wheel_radius, scale=1.0),
                                   dists.Normal(scale=0.5), dists.Normal(loc=Y[0][2], scale=0.0175))

        def PX(self, t, xp):
            ax, ay, rd = accelerations(xp, U[t - 1])
            vx, vy, r = xp[:, 0], xp[:, 1], xp[:, 2]
            return dists.IndepProd(dists.Normal(loc=vx + Ts * (vy * r + ax), scale=self.q[0]),
                                   dists.Normal(loc=vy + Ts * (ay - vx * r), scale=self.q[1]),
                                   dists.Normal(loc=r + Ts * rd, scale=self.q[2]))

        def PY(self, t, xp, x):
            ax, ay, _ = accelerations(x, U[t])
            return dists.IndepProd(dists.Normal(loc=ax, scale=sigma[0]), dists.Normal(loc=ay, scale=sigma[1]),
                                   dists.Normal(loc=x[:, 2], scale=sigma[2]))

    np.random.seed(seed)  # particles draws from numpy's global generator (not ours: the peer's way)
    smc = particles.SMC(fk=ssm.Bootstrap(ssm=SingleTrack(), data=Y), N=N, resampling="systematic", ESSrmin=0.5,
                        store_history=False, collect=None)
    return lambda k: next(smc)


def alternate(est, peer, samples, others=()) -> tuple[float, ...]:
    """One MPF step, one peer step, ... through the samples: the median CPU us per step of each after
    the warm-up (`WARMUP` samples). `others`: more estimators stepped in the same loop (after the MPF), their
    medians returned after the peer's."""
    steppers = [est, *others]
    cpu: list[list[float]] = [[] for _ in range(len(steppers) + 1)]
    for k, s in enumerate(samples):
        for j, step in enumerate([*(e.step for e in steppers), None]):
            c0 = time.thread_time()
            step(*s) if step is not None else peer(k)
            if k >= WARMUP:
                cpu[j].append(time.thread_time() - c0)
    med = [float(np.median(c) * 1e6) for c in cpu]
    return (med[0], med[-1], *med[1:-1])


def interleaved(scenario, samples, N: int, seed: int = 1) -> tuple[float, float]:
    """The MPF (as `tirefilter run` builds it) and the peer at N particles, stepped alternately
    through the same samples in one process, so that both see the same load: the median CPU
    us per step of each after the warm-up."""
    est = build_estimator("mpf", scenario, model="auto", particles=N, config={})
    est.reset(np.random.default_rng(seed))
    peer = bootstrap_step(scenario, samples, N, seed)
    return alternate(est, peer, samples)


def replay_setting(log_path: Path, vehicle_path: Path, N: int, backend: str | None = None):
    """The MPF as `tirefilter replay LOG --vehicle V.toml --particles N` builds it (every default of a
    replay: the bias filter, the wandering offsets, the calibration, the wheel-speed filter, the roll gain,
    the IMU lever arm; `backend`: the MPF's backend, None its default) and the log's samples as the run loop
    hands them to `step` (the measurement guard applied): (estimator, [(t, Inputs, Measurement)], sample
    period)."""
    from tirefilter.estimators import build, for_log
    from tirefilter.replay.run import LogSource
    from tirefilter.replay.stream import scan_log
    from tirefilter.vehicle.params import load_vehicle

    vehicle = load_vehicle(vehicle_path)
    log = scan_log(log_path, vehicle)
    setting = for_log(vehicle, log.t, log.signals, source=log.path)
    est = build("mpf", setting, model="auto", particles=N, config={} if backend is None else {"mpf": {"backend": backend}})
    guard = est.guard
    guard.reset()
    samples = [(s.t, s.inputs, guard(s.t, s.meas)) for s in LogSource(log)]
    return est, samples, setting.sample_period


def interleaved_replay(log_path: Path, vehicle_path: Path, N: int, seed: int = 1,
                       backends: tuple[str, ...] = ("numba",)) -> tuple[list[float], float, dict]:
    """The replay's MPF (one per backend) and the peer on the same log at N particles, stepped alternately
    (one step of each MPF, one peer step, ...) so that all see the same load: the median CPU us per step of
    each MPF and of the peer after the warm-up, and the MPF's options that the comparison is about."""
    ests = []
    for b in backends:
        est, samples, Ts = replay_setting(log_path, vehicle_path, N, b)
        est.reset(np.random.default_rng(seed))
        ests.append(est)
    peer = peer_step(est.vehicle, est.sensors.sigma, Ts, samples, N, seed)
    mpf_us, peer_us, *more = alternate(ests[0], peer, samples, ests[1:])
    cfg = est.cfg
    options = {"model": cfg.model, "bias filter": est.bias_on,
               "wandering offsets": bool(np.any(np.asarray(cfg.disturbance_rw) > 0)),
               "calibration": cfg.std_calibration, "wheel filter": est.wheels is not None,
               "roll gain": "estimated" if est.k_roll is not None else f"{est.roll_gain:.4g}",
               "lever arm": tuple(float(c) for c in est._vp[10:12]), "samples": len(samples)}
    return [mpf_us, *more], peer_us, options


def replay_main(args) -> int:
    """`--replay LOG --vehicle V.toml`: the replay's MPF (each of `--backends`) against the peer, interleaved,
    `--repeat` times."""
    if args.vehicle is None:
        sys.exit("bench_cost.py: --replay needs --vehicle V.toml")
    print(f"load average before: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores; replay of {args.replay}")
    backends = tuple(args.backends)
    for n in args.particles:
        for r in range(args.repeat):
            mpfs, peer, options = interleaved_replay(args.replay, args.vehicle, n, backends=backends)
            if r == 0 and n == args.particles[0]:
                print("  the MPF of the replay: " + ", ".join(f"{k} {v}" for k, v in options.items()))
            cells = ", ".join(f"mpf ({b}) {m:.0f} us CPU" for b, m in zip(backends, mpfs))
            ratios = ", ".join(f"mpf ({b}) / bootstrap {m / peer:.2f}" for b, m in zip(backends, mpfs))
            print(f"  replay, interleaved N = {n:5d} (run {r + 1}): {cells}, bootstrap {peer:.0f} us CPU; {ratios}",
                  flush=True)
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--particles", type=int, nargs="+", default=[50, 100, 200, 500, 1000, 2000, 5000])
    ap.add_argument("--duration", type=float, default=10.0, help="s of each scenario's samples (default 10)")
    ap.add_argument("--estimators", nargs="+",
                    default=["mpf", "augpf", "ekf", "rls", "kf", "bootstrap",
                             *(k for k in GPSSM if not k.endswith("-rank1"))])
    ap.add_argument("--gpssm-max", type=int, default=1000, help="largest N for the GP-SSM rows (default 1000)")
    ap.add_argument("--figure", type=Path, help="write Fig. 14 here (e.g. benchmarks/figures/stiffness_fig14_cost.png)")
    ap.add_argument("--cpu-figure", action="store_true", help="plot the CPU medians (default: wall)")
    ap.add_argument("--interleave", action="store_true",
                    help="also step the MPF and the peer alternately in one loop (the same load on both) and print "
                         "their CPU medians and ratio per N")
    ap.add_argument("--replay", type=Path, metavar="LOG",
                    help="instead: the MPF as `tirefilter replay LOG --vehicle V.toml` builds it against the peer on "
                         "that log, interleaved, at each --particles N (e.g. a 66 s `tirefilter peer-drive`)")
    ap.add_argument("--vehicle", type=Path, help="the vehicle TOML of --replay")
    ap.add_argument("--repeat", type=int, default=1, help="--replay: runs one after another (default 1)")
    ap.add_argument("--backends", nargs="+", default=["numba", "c"], choices=["numba", "c", "numpy"],
                    help="--replay: the MPF's backends, each stepped in the same loop (default numba c)")
    args = ap.parse_args()
    if args.replay is not None:
        try:
            import particles  # noqa: F401
        except ImportError:
            sys.exit("bench_cost.py: the peer needs the `particles` library: "
                     ".venv/bin/pip install --no-deps particles==0.4 && .venv/bin/pip install -e '.[bench]'")
        return replay_main(args)
    if "bootstrap" in args.estimators or args.interleave:
        try:
            import particles  # noqa: F401
        except ImportError:
            sys.exit("bench_cost.py: the peer needs the `particles` library: "
                     ".venv/bin/pip install --no-deps particles==0.4 && .venv/bin/pip install -e '.[bench]'")
    print(f"load average before: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores; "
          f"paper-sim and friction-snow, {args.duration:g} s of samples each")
    sim, sim_samples = record("paper-sim", args.duration)
    snow, snow_samples = record("friction-snow", args.duration)
    table: dict[tuple[str, int], float] = {}
    cpu_table: dict[tuple[str, int], float] = {}
    first: dict[str, float] = {}
    for name in args.estimators:
        for n in args.particles:
            if name in PARTICLE_FREE and n != args.particles[0]:
                continue
            if name in GPSSM and n > args.gpssm_max:
                continue
            if name == "bootstrap":
                us, cpu, ms = bootstrap_peer(sim, sim_samples, n)
            elif name in GPSSM:
                est = build_estimator("gpssm", snow, model="auto", particles=n, config={"gpssm": GPSSM[name]})
                us, cpu, ms = time_estimator(est, snow_samples)
            else:
                est = build_estimator(name, sim, model="auto", particles=None if name in PARTICLE_FREE else n,
                                      config={})
                us, cpu, ms = time_estimator(est, sim_samples)
            table[(name, n)], cpu_table[(name, n)] = us, cpu
            first.setdefault(name, ms)
            print(f"  {name:16s} N = {n:5d}: {us:9.0f} us per step wall, {cpu:9.0f} us CPU (first call {ms:.0f} ms)",
                  flush=True)
    if args.interleave:
        for n in args.particles:
            mpf, peer = interleaved(sim, sim_samples, n)
            print(f"  interleaved N = {n:5d}: mpf {mpf:.0f} us CPU, bootstrap {peer:.0f} us CPU, mpf / bootstrap "
                  f"{mpf / peer:.2f}", flush=True)
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    cols = args.particles
    for label, tab in (("wall", table), ("CPU", cpu_table)):
        print(f"\nmedian {label} us per step()")
        print("| estimator | " + " | ".join(f"N = {n}" for n in cols) + " | first call ms |")
        print("|---" * (len(cols) + 2) + "|")
        for name in args.estimators:
            cells = []
            for n in cols:
                key = (name, cols[0] if name in PARTICLE_FREE else n)
                cells.append(f"{tab[key]:.0f}" if key in tab else "-")
            print(f"| {name} | " + " | ".join(cells) + f" | {first.get(name, math.nan):.0f} |")
        for n in cols:
            if ("mpf", n) in tab and ("bootstrap", n) in tab:
                print(f"{label}: mpf / bootstrap at N = {n}: {tab[('mpf', n)] / tab[('bootstrap', n)]:.2f}")
        if ("mpf", 500) in tab and ("mpf", 5000) in tab:
            print(f"{label}: mpf N = 5000 / N = 500: {tab[('mpf', 5000)] / tab[('mpf', 500)]:.2f}")
    if args.figure:
        from tirefilter.study import plots

        plots.COLORS.update({"bootstrap": "black", "gpssm-axle": "tab:orange", "gpssm-tensor": "tab:purple",
                             "gpssm-tensor100": "tab:brown"})
        plots.LABELS.update({"bootstrap": "bootstrap PF (particles, peer)", "gpssm-axle": "GP-SSM per-axle",
                             "gpssm-tensor": "GP-SSM tensor 50", "gpssm-tensor100": "GP-SSM tensor 100"})
        with tempfile.TemporaryDirectory() as tmp:
            shown = [e for e in args.estimators if e != "kf"]
            path = plots.cost_plot(cpu_table if args.cpu_figure else table, shown, cols, Path(tmp))
            args.figure.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(path, args.figure)
        print(f"figure: {args.figure}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
