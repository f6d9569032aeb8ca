"""The co-simulation master: scenario inputs -> vehicle FMU -> sensors -> estimator -> results.

One run: reset the FMU with the scenario's parameters and a seed, then for every
communication step set the inputs, read the outputs at estimator sample instants, call
the estimator, write a Result-CSV row (and a Rerun row), and step the FMU.
"""

from __future__ import annotations

import json
import math
import platform
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tirefilter import __version__
from tirefilter.cosim.fmu import INPUT_NAMES, VehicleFMU
from tirefilter.cosim.results import ESTIMATE_COLUMNS, INPUT_TRUTH_COLUMNS, ResultWriter, estimate_values, truth_column
from tirefilter.estimators.base import Estimator, Inputs, Measurement
from tirefilter.scenarios import Scenario


def spawn_seeds(seed: int) -> tuple[int, np.random.Generator]:
    """One SeedSequence -> (the FMU's 31-bit seed, the estimator's Generator)."""
    fmu_ss, est_ss = np.random.SeedSequence(seed).spawn(2)
    fmu_seed = int(fmu_ss.generate_state(1, dtype=np.uint32)[0] & 0x7FFFFFFF)
    return fmu_seed, np.random.default_rng(est_ss)


@dataclass
class RunSummary:
    scenario: str
    seed: int
    fmu_seed: int
    estimator: str
    steps: int  # estimator samples
    communication_steps: int
    wall_time_s: float
    median_step_us: float | None
    status: str = "ok"
    error: str | None = None
    results: str | None = None


class _Progress:
    def __init__(self, total: int, enabled: bool):
        self.total, self.enabled, self._last = total, enabled, -1

    def update(self, k: int) -> None:
        if not self.enabled:
            return
        pct = int(100 * k / max(self.total, 1))
        if pct != self._last:
            self._last = pct
            bar = "#" * (pct // 4)
            sys.stderr.write(f"\r[{bar:<25}] {pct:3d}%")
            sys.stderr.flush()

    def close(self) -> None:
        if self.enabled:
            sys.stderr.write("\n")


def run_scenario(
    scenario: Scenario,
    *,
    estimator: Estimator | None = None,
    seed: int = 0,
    fmu: VehicleFMU | None = None,
    fmi_version: str = "2",
    results_csv: str | Path | None = None,
    rrd: str | Path | None = None,
    progress: bool = False,
    keep_rows: bool = False,
    parameter_overrides: dict | None = None,
) -> tuple[RunSummary, np.ndarray | None]:
    """Co-simulate `scenario`; returns the summary and, with keep_rows, the result rows.

    The FMU is created (and closed) here unless one is passed in, so Monte-Carlo callers
    reuse one instance. Rows are written incrementally: when the FMU or the estimator
    fails, every row before the failure is in the CSV and the recording, and the error is
    raised after the summary has been filled in (`summary.status = "failed"`).
    """
    own_fmu = fmu is None
    fmu = fmu or VehicleFMU(fmi_version)
    fmu_seed, rng = spawn_seeds(seed)
    params = scenario.fmu_parameters(fmu_seed)
    params.update(parameter_overrides or {})

    h = scenario.communication_step
    n = int(round(scenario.duration / h))
    sps = scenario.steps_per_sample
    t_grid = np.arange(n + 1) * h
    U = scenario.inputs.open_loop(t_grid)
    hold = scenario.inputs.speed_hold
    gain = scenario.vehicle.mass * scenario.vehicle.wheel_radius

    out_names = fmu.output_names
    idx = {name: j for j, name in enumerate(out_names)}
    sensors = set(scenario.sensors)
    est_name = getattr(estimator, "name", None) if estimator is not None else None
    columns = ESTIMATE_COLUMNS + tuple(truth_column(n_) for n_ in out_names) + INPUT_TRUTH_COLUMNS

    def sensor(name: str, output: str, y) -> float:
        return float(y[idx[output]]) if name in sensors else math.nan

    writer = ResultWriter(results_csv, columns) if results_csv else None
    recorder = None
    if rrd:
        from tirefilter.viz.rerun_log import RerunRecorder

        recorder = RerunRecorder(rrd, columns, est_name)
    rows = [] if keep_rows else None
    step_times: list[float] = []
    summary = RunSummary(scenario.name, seed, fmu_seed, est_name or "none", 0, 0, 0.0, None,
                         results=str(results_csv) if results_csv else None)
    bar = _Progress(n, progress)
    t0 = time.perf_counter()
    try:
        fmu.reset(params)
        if estimator is not None:
            estimator.reset(rng)
        y = fmu.outputs()
        integral = 0.0
        u = np.empty(len(INPUT_NAMES))
        for k in range(n + 1):
            t = k * h
            u[:] = U[k]
            if hold is not None:
                err = float(hold.reference(t)) - float(y[idx["vx"]])
                integral += err * h
                u[1] += gain * (hold.kp * err + hold.ki * integral)
            fmu.set_inputs(u)
            if k % sps == 0:
                y = fmu.outputs()
                est = None
                if estimator is not None:
                    inputs = Inputs(delta=sensor("delta", "delta_meas", y), omega_f=sensor("omega_f", "omega_f_meas", y),
                                    omega_r=sensor("omega_r", "omega_r_meas", y), vx=sensor("vx", "vx", y))
                    meas = Measurement(ax=sensor("ax", "ax_meas", y), ay=sensor("ay", "ay_meas", y),
                                       yaw_rate=sensor("yaw_rate", "yaw_rate_meas", y))
                    ts = time.perf_counter()
                    est = estimator.step(t, inputs, meas)
                    step_times.append(time.perf_counter() - ts)
                row = np.concatenate([estimate_values(t, est), y, u])
                if writer:
                    writer.write(row)
                if recorder:
                    recorder.log_row(row)
                if rows is not None:
                    rows.append(row)
                summary.steps += 1
            if k == n:
                break
            y = fmu.do_step(t, h)
            summary.communication_steps += 1
            if k % 256 == 0:
                bar.update(k)
    except Exception as exc:
        summary.status = "failed"
        summary.error = str(exc)
        exc.summary = summary  # callers write the run summary of a failed run too
        raise
    finally:
        bar.close()
        summary.wall_time_s = time.perf_counter() - t0
        if step_times:
            summary.median_step_us = float(np.median(step_times[min(10, len(step_times) - 1):]) * 1e6)
        if writer:
            writer.close()
        if recorder:
            recorder.close()
        if own_fmu:
            fmu.close()
    return summary, np.vstack(rows) if rows else None


def write_run_json(path: str | Path, summary: RunSummary, *, command: list[str], model: str, particles: int | None,
                   estimator_config: dict, fmi_version: str) -> None:
    """The run summary JSON of DESIGN.md."""
    record = {
        "version": __version__,
        "command": command,
        "scenario": summary.scenario,
        "seed": summary.seed,
        "fmu_seed": summary.fmu_seed,
        "estimator": summary.estimator,
        "model": model,
        "N": particles,
        "estimator_config": estimator_config,
        "fmi_version": fmi_version,
        "steps": summary.steps,
        "communication_steps": summary.communication_steps,
        "wall_time_s": summary.wall_time_s,
        "median_step_us": summary.median_step_us,
        "status": summary.status,
        "error": summary.error,
        "results": summary.results,
        "python": platform.python_version(),
        "platform": platform.platform(),
    }
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(json.dumps(record, indent=2) + "\n")

