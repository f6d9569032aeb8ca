"""`tirefilter bench stiffness`: the comparisons of the stiffness paper (Sec. VI and VII).

Parts (all by default, `--part` picks):
1. `accuracy`: paper-sim, 100 trials, N = 500, lambda = 0.99 (the scenario's): per stiffness
   parameter the mean and the worst steady-state error, the settling time after the 30 s
   surface change, the 90% coverage and the spread; Fig. 6 (histograms of the per-trial
   mean error and spread error of Cf_y) and Fig. 4 (one trial); the wall time of the part.
2. `particles`: time-averaged v^Y RMSE against N for the MPF and AUGPF (Fig. 5).
3. `comparison`: snow-sine and asphalt-normal, 50 trials each, the error table of every
   estimator side by side; Figs. 7, 8 and 9 (snow), 11 and 12 (asphalt).
4. `cost`: median microseconds per `step()` against N for every estimator (Fig. 14).

Tables are printed and written to `OUT/report.md`, plots to `OUT/*.png`, trials to
`OUT/<part>/<scenario>/<estimator>-N<N>/` (see `montecarlo`), so an interrupted study
resumes where it stopped.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from tirefilter.errors import ConfigError
from tirefilter.metrics import steady_state_mask
from tirefilter.study.montecarlo import PARAMS, StudyRun, TrialSpec, run_study

PARTS = ("accuracy", "particles", "comparison", "cost")
DEFAULTS = {  # part -> (scenarios, estimators, trials, particle counts)
    "accuracy": (("paper-sim",), ("mpf", "augpf", "rls"), 100, (500,)),
    "particles": (("paper-sim",), ("mpf", "augpf"), 20, (50, 100, 200, 500, 1000)),
    "comparison": (("snow-sine", "asphalt-normal"), ("mpf", "augpf", "ekf", "rls"), 50, (500,)),
    "cost": (("paper-sim",), None, 1, (50, 100, 200, 500, 1000, 2000)),
}
PARTICLE_FREE = ("kf", "rls", "ekf")  # accept and ignore --particles
COST_DURATION = 4.0  # s of paper-sim per cost measurement (400 steps, the first 10 left out)


@dataclass(frozen=True)
class StudyOptions:
    out: Path
    parts: tuple[str, ...] = PARTS
    trials: int | None = None  # each part's default when None
    particles: tuple[int, ...] | None = None
    scenarios: tuple[str, ...] | None = None
    estimators: tuple[str, ...] | None = None
    workers: int | None = None
    scheduler: str | None = None  # a Dask scheduler's address: run the trials there (docs/dask.md)
    seed: int = 0
    duration: float | None = None  # shorten every trial (quick looks, tests)
    plots: bool = True
    progress: bool = False
    config: dict = field(default_factory=dict)  # estimator tables for every trial, as `--config` gives them


class Report:
    """Lines printed as they come and kept for OUT/report.md."""

    def __init__(self, path: Path):
        self.path, self.lines = path, []

    def __call__(self, line: str = "") -> None:
        print(line, flush=True)
        self.lines.append(line)

    def write(self) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.path.write_text("\n".join(self.lines) + "\n")


def run_stiffness_study(opts: StudyOptions) -> Report:
    from tirefilter.estimators import ESTIMATORS, FRICTION_ESTIMATORS

    for part in opts.parts:
        if part not in PARTS:
            raise ConfigError("--part", part, f"unknown part (available: {', '.join(PARTS)})")
    for name in opts.estimators or ():
        if name not in ESTIMATORS or name == "none":
            raise ConfigError("--estimators", name, f"unknown estimator (available: {', '.join(ESTIMATORS[1:])})")
    report = Report(Path(opts.out) / "report.md")
    report(f"# Stiffness study (tirefilter bench stiffness), study seed {opts.seed}")
    try:
        for part in opts.parts:
            scenarios, estimators, trials, particles = DEFAULTS[part]
            scenarios = opts.scenarios or scenarios
            stiffness = [e for e in ESTIMATORS[1:] if e not in FRICTION_ESTIMATORS]  # not the friction learners
            estimators = [e for e in (opts.estimators or estimators or stiffness) if e in ESTIMATORS]
            particles = opts.particles or particles
            trials = opts.trials or trials
            report(f"\n## {part}: scenarios {', '.join(scenarios)}; estimators {', '.join(estimators)}; "
                   f"N {', '.join(map(str, particles))}" + (f"; {trials} trials" if part != "cost" else ""))
            if part == "cost":
                _cost(opts, report, estimators, particles)
            else:
                _trials_part(part, opts, report, scenarios, estimators, particles, trials)
            report.write()
    finally:
        report.write()
    return report


def _spec(opts: StudyOptions, scenario: str, estimator: str, n: int) -> TrialSpec:
    return TrialSpec(scenario, estimator, particles=None if estimator in PARTICLE_FREE else n, model="auto",
                     duration=opts.duration, config=opts.config)


def _trials_part(part, opts, report, scenarios, estimators, particles, trials) -> None:
    runs: dict[tuple[str, str, int], StudyRun] = {}
    for scenario in scenarios:
        for n in particles:
            for est in estimators:
                spec = _spec(opts, scenario, est, n)
                if (scenario, est, spec.particles or 0) in runs:
                    continue
                t0 = time.perf_counter()
                before = _finished(Path(opts.out) / part / spec.key())
                run = run_study(spec, trials, Path(opts.out) / part / spec.key(), study_seed=opts.seed,
                                workers=opts.workers, progress=opts.progress, scheduler=opts.scheduler)
                wall = time.perf_counter() - t0
                new = len(run.metrics) - before
                runs[(scenario, est, spec.particles or 0)] = run
                failed = len(run.metrics) - len(run.ok())
                report(f"- {spec.key()}: {len(run.ok())} trials ok" + (f", {failed} failed" if failed else "")
                       + f", wall time of this invocation {wall:.1f} s "
                       + (f"on the Dask cluster at {opts.scheduler}" if opts.scheduler
                          else f"with {opts.workers or os.cpu_count()} workers")
                       + (f" ({new} trials run, the others were in {opts.out})" if new < trials else ""))
    if part == "particles":
        _vy_table(report, runs, particles)
    else:
        for scenario in scenarios:
            _error_table(report, {k: v for k, v in runs.items() if k[0] == scenario}, scenario)
    if opts.plots:
        from tirefilter.study import plots

        for path in plots.PART_PLOTS[part](runs, Path(opts.out), opts):
            report(f"plot: {path}")


CONVERGED_PCT = 10.0  # a trial converged: time-averaged |error| of each lateral stiffness below this


def converged(m: dict) -> bool:
    return all(m[p]["mean_abs"] < CONVERGED_PCT for p in ("Cf_y", "Cr_y") if p in m)


def _error_table(report, runs, scenario) -> None:
    report(f"\n### {scenario}: steady-state stiffness error against the surface mean")
    for (_, est, n), run in runs.items():
        ok = run.ok()
        good = [m for m in ok if converged(m)]
        report(f"- {est}{f' N = {n}' if n else ''}: lateral stiffness converged (time-averaged |err| < "
               f"{CONVERGED_PCT:g}%) in {len(good)} of {len(ok)} trials"
               + (f" (not: trials {', '.join(str(m['trial']) for m in ok if not converged(m))})" if len(good) < len(ok)
                  else ""))
    for label, keep in (("all trials", lambda m: True), ("converged trials only", converged)):
        if label != "all trials" and all(converged(m) for run in runs.values() for m in run.ok()):
            break
        report(f"\n{label}:\n")
        report("| estimator | N | param | trials | mean abs err % | mean err % | worst trial mean abs err % | "
               "max abs err % | last 100 s: worst trial abs err % | settling s (median / max) | coverage 90% | "
               "sigma % | v^Y RMSE m/s |")
        report("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
        for (_, est, n), run in runs.items():
            ok = [m for m in run.ok() if keep(m)]
            for p in PARAMS:
                rows = [m[p] for m in ok if p in m]
                if not rows:
                    continue
                settle = np.array([r["settle"] for r in rows], float)
                settle_txt = "n/a" if np.all(np.isnan(settle)) else f"{np.median(settle):.2f} / {np.max(settle):.2f}"
                cov = [r.get("coverage90", math.nan) for r in rows]
                sig = [r.get("sigma_pct", math.nan) for r in rows]
                final = [abs(r.get("final", math.nan)) for r in rows]
                report(f"| {est} | {n or '-'} | {p} | {len(rows)} | {np.mean([r['mean_abs'] for r in rows]):.2f} | "
                       f"{np.mean([r['mean'] for r in rows]):+.2f} | "
                       f"{max(r['mean_abs'] for r in rows):.2f} | {max(r['max_abs'] for r in rows):.1f} | "
                       f"{np.nanmax(final) if np.isfinite(final).any() else math.nan:.2f} | "
                       f"{settle_txt} | {_nanmean(cov):.2f} | {_nanmean(sig):.2f} | "
                       f"{np.mean([m['vy_rmse'] for m in ok]):.4f} |")


def _vy_table(report, runs, particles) -> None:
    report("\n### time-averaged v^Y RMSE (m/s), mean over trials +- its standard error (Fig. 5)")
    ests = sorted({k[1] for k in runs})
    report("| N | " + " | ".join(ests) + " |")
    report("|---" * (len(ests) + 1) + "|")
    for n in particles:
        cells = []
        for est in ests:
            run = runs.get(("paper-sim", est, n)) or next((v for k, v in runs.items() if k[1] == est and k[2] == n),
                                                         None)
            x = np.array([m["vy_rmse"] for m in run.ok()]) if run else np.array([])
            cells.append(f"{x.mean():.4f} +- {x.std(ddof=1) / math.sqrt(x.size):.4f}" if x.size > 1 else "-")
        report(f"| {n} | " + " | ".join(cells) + " |")


def _cost(opts, report, estimators, particles) -> None:
    """Median step time at each N, one short paper-sim run per point, in this process."""
    from tirefilter.cosim.fmu import VehicleFMU
    from tirefilter.study.montecarlo import run_trial

    report(f"\n### median us per step() (paper-sim, {COST_DURATION:g} s, after {10} warm-up steps; Fig. 14)")
    report("| estimator | " + " | ".join(f"N = {n}" for n in particles) + " |")
    report("|---" * (len(particles) + 1) + "|")
    table = {}
    with VehicleFMU() as fmu:
        for est in estimators:
            cells = []
            for n in particles:
                if est in PARTICLE_FREE and n != particles[0]:
                    cells.append(cells[0] if cells else "-")
                    continue
                spec = replace(_spec(opts, "paper-sim", est, n), duration=COST_DURATION)
                m = run_trial(spec, 0, 1, fmu=fmu).metrics
                table[(est, n)] = m["median_step_us"]
                cells.append(f"{m['median_step_us']:.0f}" if m["median_step_us"] else "failed")
            report(f"| {est} | " + " | ".join(cells) + " |")
    if opts.plots:
        from tirefilter.study import plots

        report(f"plot: {plots.cost_plot(table, estimators, particles, Path(opts.out))}")


def _finished(directory: Path) -> int:
    lines = directory / "metrics.jsonl"
    return sum(1 for line in lines.read_text().splitlines() if line.strip()) if lines.exists() else 0


def steady_errors(series: dict, scenario, param: str) -> np.ndarray:
    """Per-sample steady-state errors (%) of a stored (decimated) series."""
    mask = steady_state_mask(series["t"], scenario)
    truth = series[f"true_{param}_mean"][mask]
    return 100.0 * (series[param][mask] - truth) / truth


def _nanmean(x) -> float:
    x = np.asarray(x, float)
    return float(np.nanmean(x)) if np.any(np.isfinite(x)) else math.nan
