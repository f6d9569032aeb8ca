"""The co-simulation master: scenario inputs -> vehicle FMU -> sensors -> estimator -> results.

One run: reset the FMU with the scenario's parameters and a seed, then for every
communication step set the inputs, read the outputs at the estimator's sample instants
and step the FMU (`cosim_samples`, the source of the run loop `runs.run`, which steps the
estimator and writes each sample's row to the Result CSV, the recording, ...).

Coupling (`coupling=`): "gauss-seidel" (the default) sets the inputs of t_k before it reads
the outputs of t_k, so sensors with direct feedthrough (a^X, a^Y, delta) and the speed-hold
PI see the same instant. "jacobi" reproduces a master that exchanges values once per
step (fmpy's SSP master, `fmu_export.ssp`): every step uses the values of the previous
communication point, the connectors start at 0 (the vehicle's first step gets zero
inputs, the estimator's first sample is at t_1), the estimator sees the outputs read
before the new inputs are set, and the PI sees v^X one step old. docs/using-the-fmus.md.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tirefilter.cosim.fmu import INPUT_NAMES, VehicleFMU
from tirefilter.estimators.base import Estimator, Inputs, Measurement
from tirefilter.io.friction import friction_truth
from tirefilter.io.results import result_columns
from tirefilter.runs import KeptRows, Run, StepSummary, output_sinks, run, spawn_seeds
from tirefilter.scenarios import Scenario

__all__ = ["CosimSample", "RunSummary", "ScenarioOutputs", "cosim_samples", "run_scenario", "spawn_seeds"]


@dataclass(kw_only=True)
class RunSummary(StepSummary):
    scenario: str
    fmu_seed: int
    communication_steps: int = 0


@dataclass(frozen=True)
class ScenarioOutputs:
    """Where `run_scenario` writes the run besides its summary (its keywords of these names):
    the Result CSV, a file-only recording `rrd` or a Rerun `recording`
    (viz.options.RecordingOptions), the friction CSV, a progress bar."""

    results_csv: str | Path | None = None
    rrd: str | Path | None = None
    recording: object = None
    friction_csv: str | Path | None = None
    progress: bool | str = False  # runs.Progress: True a bar, "lines" a line every few seconds


def run_scenario(
    scenario: Scenario,
    *,
    estimator: Estimator | None = None,
    seed: int = 0,
    fmu: VehicleFMU | None = None,
    fmi_version: str = "2",
    keep_rows: bool = False,
    parameter_overrides: dict | None = None,
    coupling: str = "gauss-seidel",
    metrics: bool = True,
    sinks=(),
    **outputs,
) -> tuple[RunSummary, np.ndarray | None]:
    """Co-simulate `scenario`; returns the summary and, with keep_rows, the result rows.

    The samples of `cosim_samples` (with the scenario's sensor faults) run through
    `runs.run` into the sinks of `runs.output_sinks` (Result CSV, recording, friction CSV,
    metrics, progress bar), then `sinks` (more of them, e.g. the command line's run.json).
    The FMU is created (and closed) here unless one is passed in, so Monte-Carlo callers
    reuse one instance. Rows are written incrementally: when the FMU or the estimator
    fails, every row before the failure is in the CSV and the recording, and the error is
    raised after the summary has been filled in (`summary.status = "failed"`).
    A friction estimator with `friction_csv` also writes its curve snapshots there
    (`io.friction`, with the scenario's true curves); those written before a failure stay.
    `recording` (viz.options.RecordingOptions) streams the run to Rerun (file, viewer,
    decimation); `rrd` alone is a file-only recording. `metrics=False` leaves the run's
    metrics (`summary.metrics`) out, for a caller that scores the kept rows itself (a
    study trial): their streaming costs some microseconds a sample. `outputs`: the keywords of
    `ScenarioOutputs` (results_csv, rrd, recording, friction_csv, progress; another name raises
    TypeError).
    """
    out = ScenarioOutputs(**outputs)
    results_csv = out.results_csv
    own_fmu = fmu is None
    fmu = fmu or VehicleFMU(fmi_version)
    try:
        fmu_seed, rng = spawn_seeds(seed)
        params = scenario.fmu_parameters(fmu_seed)
        params.update(parameter_overrides or {})
        columns = result_columns(fmu.output_names)
        summary = RunSummary(scenario=scenario.name, seed=seed, fmu_seed=fmu_seed,
                             estimator=getattr(estimator, "name", None) or "none",
                             results=str(results_csv) if results_csv else None)
        kept = KeptRows() if keep_rows else None
        sinks_out = output_sinks(columns, estimator, results_csv=results_csv, rrd=out.rrd, recording=out.recording,
                                 context=_recording_context(scenario), friction_csv=out.friction_csv,
                                 friction_truth=friction_truth(scenario), metrics=metrics, schedule=scenario,
                                 progress=out.progress,
                                 total=int(round(scenario.duration / scenario.sample_period)) + 1)

        def on_step(k: int) -> None:
            summary.communication_steps = k + 1

        samples = cosim_samples(scenario, fmu, params, on_step=on_step, coupling=coupling)
        if scenario.faults:  # sensor faults (scenarios.faults): what the estimator sees, not the truth
            from tirefilter.scenarios.faults import fault_rng, faulty_samples

            samples = faulty_samples(samples, scenario.faults, fault_rng(seed))
        run(samples, Run(estimator, columns, [*sinks_out, *([kept] if kept else []), *sinks]), summary, rng=rng)
    finally:
        if own_fmu:
            fmu.close()
    return summary, kept.rows() if kept else None


@dataclass(frozen=True)
class CosimSample:
    """The co-simulation at one estimator sample instant (see `cosim_samples`); a
    `runs.Sample` whose row values are the FMU's outputs, then its inputs."""

    k: int  # communication step index (t = k h)
    t: float  # s
    inputs: Inputs  # what the estimator is given (NaN for sensors the scenario lacks)
    meas: Measurement
    y: np.ndarray  # FMU outputs, ordered as fmu.output_names (a view: valid until the next sample)
    u: np.ndarray  # FMU inputs held over the coming step, ordered as INPUT_NAMES (a view, idem)

    @property
    def values(self) -> tuple[np.ndarray, np.ndarray]:
        return self.y, self.u


COUPLINGS = ("gauss-seidel", "jacobi")


def cosim_samples(scenario: Scenario, fmu: VehicleFMU, params: dict,
                  on_step: Callable[[int], None] | None = None, coupling: str = "gauss-seidel") -> Iterator[CosimSample]:
    """Reset `fmu` with `params`, then co-simulate `scenario` one communication step at a
    time, yielding the sensors and outputs at every estimator sample instant.

    The scenario's open-loop inputs plus its speed hold (a PI loop on the FMU's v^X) are
    set before the outputs are read; the caller runs its estimator on each sample before
    asking for the next one (the loop of `run_scenario`, and the dashboard's stepping).
    `on_step(k)` is called after communication step k (0-based) has been taken.
    `coupling` "jacobi" exchanges values once per step (module docstring).
    """
    if coupling not in COUPLINGS:
        raise ValueError(f"coupling {coupling!r}: expected one of {', '.join(COUPLINGS)}")
    if coupling == "jacobi":
        yield from _jacobi_samples(scenario, fmu, params, on_step)
        return
    h = scenario.communication_step
    n = int(round(scenario.duration / h))
    sps = scenario.steps_per_sample
    t_grid = np.arange(n + 1) * h
    U = scenario.inputs.open_loop(t_grid)
    hold = scenario.inputs.speed_hold
    gain = scenario.vehicle.mass * scenario.vehicle.wheel_radius
    idx = {name: j for j, name in enumerate(fmu.output_names)}
    read = _sensor_reader(idx, scenario.sensors)
    vx_index = idx["vx"]
    v_ref = None if hold is None else hold.reference(t_grid)  # np.interp of the grid: the values of t = k h

    fmu.reset(params)
    y = fmu.outputs()
    integral = 0.0
    u = np.empty(len(INPUT_NAMES))
    for k in range(n + 1):
        t = k * h
        u[:] = U[k]
        if hold is not None:
            err = float(v_ref[k]) - float(y[vx_index])
            integral += err * h
            u[1] += gain * (hold.kp * err + hold.ki * integral)
        fmu.set_inputs(u)
        if k % sps == 0:
            y = fmu.outputs()
            yield _sample(k, t, y, u, read)
        if k == n:
            break
        if hold is None:
            fmu.advance(t, h)  # the outputs are next read after the inputs of t_{k+1} are set
        else:
            y = fmu.do_step(t, h)  # the PI reads v^X before setting them
        if on_step is not None:
            on_step(k)


# what the estimator is given: (sensor, FMU output), Inputs' fields then Measurement's, in their order
SENSOR_OUTPUTS = (("delta", "delta_meas"), ("omega_f", "omega_f_meas"), ("omega_r", "omega_r_meas"), ("vx", "vx"),
                  ("ax", "ax_meas"), ("ay", "ay_meas"), ("yaw_rate", "yaw_rate_meas"))


def _sensor_reader(idx: dict[str, int], sensors) -> Callable[[np.ndarray], tuple[Inputs, Measurement]]:
    """y (the FMU outputs) -> (Inputs, Measurement) of a sample: the scenario's sensors read
    from y, NaN for those it lacks. One `tolist` of y per sample."""
    sensors = set(sensors)
    nan_slot = len(idx)  # the NaN appended after y's values
    cols = [idx[output] if name in sensors else nan_slot for name, output in SENSOR_OUTPUTS]

    def read(y: np.ndarray) -> tuple[Inputs, Measurement]:
        v = y.tolist()
        v.append(math.nan)
        d, wf, wr, vx, ax, ay, r = [v[j] for j in cols]
        return Inputs(d, wf, wr, vx), Measurement(ax, ay, r)

    return read


def _sample(k, t, y, u, read) -> CosimSample:
    inputs, meas = read(y)
    return CosimSample(k, t, inputs, meas, y, u)


def _jacobi_samples(scenario: Scenario, fmu: VehicleFMU, params: dict,
                    on_step: Callable[[int], None] | None) -> Iterator[CosimSample]:
    """cosim_samples with the coupling of fmpy's SSP master (driver, vehicle and estimator
    FMUs, `fmu_export.ssp`): step k takes the inputs the driver computed in step k - 1
    (open loop at t_k, PI on v^X(t_{k-1})), step 0 zeros on every connected input; the
    sample at t_k (k >= 1) holds the outputs read after step k - 1, before u_k is set.
    The surface scale is the exception: it keeps the profile's value in step 0 (fmpy's
    master, whose connectors start at 0, cannot run a scenario that connects it)."""
    h = scenario.communication_step
    n = int(round(scenario.duration / h))
    sps = scenario.steps_per_sample
    t_grid = np.arange(n + 1) * h
    U = scenario.inputs.open_loop(t_grid)
    hold = scenario.inputs.speed_hold
    gain = scenario.vehicle.mass * scenario.vehicle.wheel_radius
    idx = {name: j for j, name in enumerate(fmu.output_names)}
    read = _sensor_reader(idx, scenario.sensors)
    vx_index = idx["vx"]
    v_ref = None if hold is None else hold.reference(t_grid)  # as in cosim_samples
    connected = [j for j, name in enumerate(INPUT_NAMES) if name != "surface"]

    fmu.reset(params)
    y = fmu.outputs()
    integral, vx_lag = 0.0, math.nan  # v^X after step k - 2: what the driver saw in step k - 1
    u = np.empty(len(INPUT_NAMES))
    for k in range(n + 1):
        t = k * h
        u[:] = U[k]
        if k == 0:
            u[connected] = 0.0  # the connectors' start value
        elif hold is not None:
            err = 0.0 if k == 1 else float(v_ref[k]) - vx_lag  # t_first = h: no v^X in step 0
            integral += err * h
            u[1] += gain * (hold.kp * err + hold.ki * integral)
        if k >= 1 and k % sps == 0:
            yield _sample(k, t, y, u, read)
        if k == n:
            break
        vx_lag = float(y[vx_index])
        fmu.set_inputs(u)
        y = fmu.do_step(t, h)
        if on_step is not None:
            on_step(k)


def _recording_context(scenario: Scenario):
    """The truth a recording draws besides the rows: the car's geometry and the true
    friction curves (those of the friction CSV)."""
    from tirefilter.viz.options import RecordingContext

    return RecordingContext(vehicle=scenario.vehicle, friction_truth=friction_truth(scenario))
