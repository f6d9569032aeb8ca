"""A run the dashboard steps one sample at a time: a scenario co-simulated against the
vehicle FMU (`cosim.run.cosim_samples`) or a Log CSV replayed (`replay.run.LogSource`),
each feeding an estimator built as `tirefilter run` / `tirefilter replay` build it
(`estimators.build`) through the run loop's step (`runs.Run.step`, without sinks: the page
keeps the rows). Every step gives one Result-CSV row, as the command line would write it.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tirefilter.errors import ConfigError, TirefilterError
from tirefilter.io.results import ESTIMATE_COLUMNS, read_results
from tirefilter.runs import Run, spawn_seeds

SOURCES = ("scenario", "log")


class EstimatorFailure(TirefilterError):
    """The estimator raised while stepping: names the estimator, the time and the cause."""


@dataclass(frozen=True)
class Settings:
    """What the dashboard's controls choose for the next run."""

    source: str = "scenario"  # "scenario" | "log"
    scenario: str = "paper-sim"  # name (see `tirefilter scenarios`) or TOML file
    log: str = ""  # Log CSV (source "log")
    vehicle: str = ""  # vehicle TOML (source "log")
    estimator: str = "mpf"
    model: str = "auto"
    particles: int = 500
    forgetting: float = 0.99  # lambda; used by estimators whose configuration has `forgetting`
    seed: int = 0

    def validated(self) -> Settings:
        from tirefilter.estimators import ESTIMATORS

        if self.source not in SOURCES:
            raise ConfigError("dashboard", "source", f"{self.source!r} is not one of {', '.join(SOURCES)}")
        if self.estimator not in ESTIMATORS:
            raise ConfigError("dashboard", "estimator", f"unknown estimator {self.estimator!r} "
                              f"(available: {', '.join(ESTIMATORS)})")
        if int(self.particles) < 1:
            raise ConfigError("dashboard", "N", f"the number of particles must be at least 1, got {self.particles}")
        if not (0.0 < float(self.forgetting) <= 1.0):
            raise ConfigError("dashboard", "forgetting",
                              f"the forgetting factor must be in (0, 1], got {self.forgetting}")
        if self.source == "log":
            for key, value in (("Log CSV", self.log), ("vehicle TOML", self.vehicle)):
                if not str(value).strip():
                    raise ConfigError("dashboard", key, "replaying a log needs a Log CSV and a vehicle TOML")
        return self


def build_with_forgetting(build, name: str, forgetting: float):
    """`build(config)` -> estimator, with the forgetting factor set through the estimator's
    own configuration table (`[name] forgetting = ...`) when its configuration has that
    option; estimators without one (e.g. kf) are built as they are."""
    estimator = build({})
    cfg = getattr(estimator, "cfg", None)
    if (cfg is not None and dataclasses.is_dataclass(cfg)
            and "forgetting" in {f.name for f in dataclasses.fields(cfg)} and cfg.forgetting != forgetting):
        estimator = build({name: {"forgetting": float(forgetting)}})
        if estimator.cfg.forgetting != float(forgetting):  # its options live in another table: say so
            raise ConfigError("dashboard", "forgetting", f"the {name} estimator did not take the forgetting factor "
                              f"from a [{name}] table (it kept {estimator.cfg.forgetting})")
    return estimator


class LiveRun:
    """One run, stepped by `step()`; build it with `LiveRun.open(settings)`.

    Attributes: `columns` (the Result-CSV header of its rows), `duration` [s], `estimator`
    (None for "none"), `scenario` (None for a log), `label` (what the page calls it).
    """

    def __init__(self, *, columns, duration: float, estimator, samples, label: str, scenario=None,
                 close=None, on_error=None):
        self.columns = tuple(columns)
        self.duration = float(duration)
        self.estimator = estimator
        self.scenario = scenario
        self.label = label
        self.finished = False
        self._samples = iter(samples)
        self._close = close
        self._run = Run(estimator, self.columns, on_error=on_error or self._failure)
        self.t = math.nan

    @classmethod
    def open(cls, settings: Settings) -> LiveRun:
        settings = settings.validated()
        return _open_scenario(settings) if settings.source == "scenario" else _open_log(settings)

    @property
    def name(self) -> str:
        return getattr(self.estimator, "name", None) or "none"

    def step(self) -> np.ndarray | None:
        """Advance one sample; returns its Result-CSV row, None when the run is over.
        An estimator failure raises EstimatorFailure (the run is over then)."""
        if self.finished:
            return None
        try:
            sample = next(self._samples)
        except StopIteration:
            self.finished = True
            return None
        except Exception:
            self.finished = True
            raise
        try:
            row = self._run.step(sample)
        except Exception:
            self.finished = True
            raise
        self.t = sample.t
        return row

    def _failure(self, sample, exc: Exception) -> EstimatorFailure:
        return EstimatorFailure(f"{self.name} failed at t = {sample.t:g} s: {type(exc).__name__}: {exc}")

    def median_step_us(self) -> float | None:
        """Median wall time of Estimator.step [us]: after warm-up, over the last 2000 steps."""
        times = self._run.step_times
        if len(times) > 2000:
            return float(np.median(times[-2000:]) * 1e6)
        return self._run.median_step_us()

    def close(self) -> None:
        self.finished = True
        if self._close is not None:
            self._close()
            self._close = None


def _open_scenario(s: Settings) -> LiveRun:
    from tirefilter.cosim.fmu import VehicleFMU
    from tirefilter.io.results import result_columns
    from tirefilter.cosim.run import cosim_samples
    from tirefilter.estimators import build, for_scenario
    from tirefilter.scenarios import load_scenario

    scenario = load_scenario(s.scenario)
    setting = for_scenario(scenario)
    estimator = build_with_forgetting(
        lambda config: build(s.estimator, setting, model=s.model, particles=int(s.particles), config=config),
        s.estimator, s.forgetting)
    fmu = VehicleFMU("2")
    try:
        fmu_seed, rng = spawn_seeds(int(s.seed))  # as `tirefilter run --seed`
        if estimator is not None:
            estimator.reset(rng)
        samples = cosim_samples(scenario, fmu, scenario.fmu_parameters(fmu_seed))
        return LiveRun(columns=result_columns(fmu.output_names), duration=scenario.duration, estimator=estimator,
                       samples=samples, scenario=scenario, label=f"scenario {scenario.name}", close=fmu.close)
    except BaseException:
        fmu.close()
        raise


def _open_log(s: Settings) -> LiveRun:
    from tirefilter.estimators import build, for_log
    from tirefilter.replay import read_log
    from tirefilter.replay.run import LogSource, result_columns
    from tirefilter.vehicle.params import load_vehicle

    vehicle = load_vehicle(s.vehicle)
    log = read_log(s.log, vehicle, vehicle_name=s.vehicle)
    setting = for_log(vehicle, log.t, {n: log.signals[n] for n in log.available}, source=log.path)
    estimator = build_with_forgetting(
        lambda config: build(s.estimator, setting, model=s.model, particles=int(s.particles), config=config),
        s.estimator, s.forgetting)
    _, rng = spawn_seeds(int(s.seed))  # as `tirefilter replay --seed`
    if estimator is not None:
        estimator.reset(rng)
    name = getattr(estimator, "name", None)
    source = LogSource(log)
    return LiveRun(columns=result_columns(log), duration=log.duration, estimator=estimator, samples=source,
                   label=f"log {Path(s.log).name}", on_error=lambda sample, exc: source.error(sample, name, exc))


def open_result(path: str | Path) -> dict[str, np.ndarray]:
    """The columns of a Result CSV (`tirefilter run --out` / `replay --out`), checked
    for what the dashboard needs (the estimate columns of the Result CSV, at least one row)."""
    path = Path(str(path).strip())
    if not path.is_file():
        raise ConfigError(path, "", "no such Result CSV")
    try:
        data = read_results(path)
    except (ValueError, UnicodeDecodeError) as exc:
        raise ConfigError(path, "", f"not a Result CSV: {exc}") from None
    missing = [c for c in ESTIMATE_COLUMNS if c not in data]
    if missing:
        raise ConfigError(path, "", f"not a Result CSV: no column {', '.join(missing[:4])}"
                          + (f" (and {len(missing) - 4} more)" if len(missing) > 4 else ""))
    if len(data["t"]) == 0:
        raise ConfigError(path, "", "the Result CSV has no rows")
    return data
