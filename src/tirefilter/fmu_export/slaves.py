"""The Python FMUs (Co-Simulation, FMI 2.0 through pythonfmu and FMI 3.0 through
pythonfmu3, from the same code): the estimator and the driver.

The classes here are FMI-version independent (`_EstimatorLogic`, ...): the variable types,
enumerations and the slave base class come from `self._T` (`_API`). The FMU classes
`EstimatorSlave`, `FrictionEstimatorSlave`, `DriverSlave` (FMI 2.0, pythonfmu) and
`EstimatorSlave3`, `FrictionEstimatorSlave3`, `DriverSlave3` (FMI 3.0, pythonfmu3) are
made on first access (module `__getattr__`), so an FMU needs only its own pythonfmu.

`EstimatorSlave` wraps any estimator that `tirefilter.estimators.build` (with `for_log`)
builds by name from a vehicle record plus options; the FMU class of one estimator only
names it (`estimator_name`, see `build.ESTIMATOR_FMUS`). `DriverSlave` plays a scenario's
input profile (steer, torques, surface, bank) with its speed-hold driver closed over the
vehicle's speed.

pythonfmu calls these methods from its C++ layer: parameters and inputs are attributes
registered as FMI variables; `exit_initialization_mode` validates the parameters and
builds the estimator; `do_step(t, h)` processes the samples due in [t, t + h);
`_get_fmu_state`/`_set_fmu_state` copy the whole estimator; `_fmu_state_to_bytes`/
`_fmu_state_from_bytes` serialise it (`state.py`).

An exception here is fatal for the FMU instance (pythonfmu turns it into fmi2Fatal); it
is logged first through the FMI logger with a message naming the parameter or input.
Every Real variable has a unit (`UNITS`, variables.py, with the other variable tables; `to_xml`
writes them, pythonfmu 0.7 cannot).
After initialisation the outputs hold the prior (t = start time, samples = 0).
"""

from __future__ import annotations

import copy
import inspect
import math
import sys
import tomllib
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from xml.etree.ElementTree import Element, SubElement

import numpy as np
import scipy.special  # noqa: F401  the estimators need it: a missing scipy fails the load, not later

from tirefilter.errors import TirefilterError
from tirefilter.fmu_export import state as fmu_state
from tirefilter.fmu_export.variables import (DRIVES, ESTIMATOR_INPUTS, ESTIMATOR_OUTPUTS, FRICTION_ALPHA_DEG,
                                             FRICTION_VISITED, MODELS, UNITS, VEHICLE_UNITS,
                                             _vehicle_parameters, friction_output)


# pythonfmu 0.7's loader (findClass in its C++ layer) releases one reference to the entry
# module's __dict__ that it only borrowed, on every instantiation: the second or third
# instance in one process then finds the module emptied ("module has no attribute ...") or
# crashes. Every instance gives that reference back here, so any number of instances works.
_MODULE_DICT_REFS: list = []


@dataclass(frozen=True)
class _API:
    """One pythonfmu flavour: FMI version, slave base, variable types and enumerations."""

    fmi: str  # "2" | "3"
    Slave: type
    Real: type
    Integer: type
    Boolean: type
    String: type
    causality: type
    variability: type
    initial: type
    status: type


@lru_cache(maxsize=None)
def _api(fmi: str) -> _API:
    if fmi == "2":
        from pythonfmu import Boolean, Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real, String
        from pythonfmu.enums import Fmi2Initial, Fmi2Status

        return _API("2", Fmi2Slave, Real, Integer, Boolean, String, Fmi2Causality, Fmi2Variability, Fmi2Initial,
                    Fmi2Status)
    from pythonfmu3 import Boolean, Fmi3Causality, Fmi3Slave, Fmi3Variability, Float64, Int32, String
    from pythonfmu3.enums import Fmi3Initial, Fmi3Status

    return _API("3", Fmi3Slave, Float64, Int32, Boolean, String, Fmi3Causality, Fmi3Variability, Fmi3Initial,
                Fmi3Status)


class _Slave:
    """What every FMU shares (a mixin before pythonfmu's slave class): explicit
    getters/setters for dotted names, units and InitialUnknowns in the model description
    (fmpy's validation asks for them), the independent variable `time` (FMI 3.0), logging
    an error before raising it, and the reference that pythonfmu's loader drops (above)."""

    _T: _API  # set by the FMU classes (`_fmu_class`)

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        module = sys.modules.get(type(self).__module__)
        if module is not None:
            _MODULE_DICT_REFS.append(module.__dict__)
        self._units: dict[str, str] = {}
        self._time = 0.0
        if self._T.fmi == "3":  # value reference 0: the independent variable
            self.register_variable(self._T.Real("time", causality=self._T.causality.independent,
                                                variability=self._T.variability.continuous,
                                                description="simulation time", getter=lambda: self._time),
                                   nested=False)
            self._units["time"] = "s"

    def _add(self, kind, name, causality, value, description, variability=None, initial=None, unit=None):
        T = self._T
        kind = {"Real": T.Real, "Integer": T.Integer, "Boolean": T.Boolean, "String": T.String}[kind]
        self._values[name] = value
        var = kind(name, causality=causality, description=description, variability=variability, initial=initial,
                   getter=lambda n=name: self._values[n], setter=lambda v, n=name: self._values.__setitem__(n, v))
        if unit is not None:
            self._units[name] = unit
        self.register_variable(var, nested=False)

    def _parameter(self, kind, name, value, description, unit=None):
        T = self._T
        self._add(kind, name, T.causality.parameter, value, description, T.variability.fixed, T.initial.exact, unit)

    def _output(self, kind, name, value, description, unit=None):
        self._add(kind, name, self._T.causality.output, value, description, self._T.variability.discrete, None, unit)

    def to_xml(self, model_options=dict()):
        root = super().to_xml(model_options)
        self._write_units(root)
        if self._T.fmi == "2":
            structure = root.find("ModelStructure")
            outputs = [i + 1 for i, v in enumerate(self.vars.values()) if v.causality == self._T.causality.output]
            if outputs:
                unknowns = SubElement(structure, "InitialUnknowns")
                for index in outputs:
                    SubElement(unknowns, "Unknown", attrib={"index": str(index)})
        return root

    def _write_units(self, root) -> None:
        """`unit` on every Real variable and the UnitDefinitions after <CoSimulation>."""
        missing = [v.name for v in self.vars.values() if type(v) is self._T.Real and v.name not in self._units]
        if missing:
            raise TirefilterError(f"no unit for the FMU variables {', '.join(missing)}")
        for elem in root.find("ModelVariables"):
            unit = self._units.get(elem.get("name"))
            if unit is not None:
                (elem.find("Real") if self._T.fmi == "2" else elem).set("unit", unit)
        defs = Element("UnitDefinitions")
        for name in sorted(set(self._units.values())):
            unit = SubElement(defs, "Unit", attrib={"name": name})
            SubElement(unit, "BaseUnit", attrib={k: str(e) for k, e in UNITS[name].items()})
        position = list(root).index(root.find("CoSimulation")) + 1
        root.insert(position, defs)

    def _fail(self, message: str):
        self.log(message, self._T.status.error)
        raise RuntimeError(message)


def _with_start(setting, start):
    """`setting` (an `estimators.Setting`) whose MPF configuration takes the table `start` (the config's
    `[mpf_start]`: `mpf.config.START_FIELDS`, what a scenario tells the filter about its start)."""
    import dataclasses

    from tirefilter.estimators import apply_overrides
    from tirefilter.estimators.mpf.config import START_FIELDS

    base = setting.mpf_config
    return dataclasses.replace(setting, mpf_config=lambda model, particles, overrides: apply_overrides(
        base(model, particles, overrides), start, "config [mpf_start]", options=START_FIELDS))


class _EstimatorLogic(_Slave):
    """An online estimator as a Co-Simulation FMU (subclasses set `estimator_name`)."""

    estimator_name = "mpf"
    option_table = "mpf"  # the --config table that `forgetting` goes to
    default_model = 1  # start values of the `model` (1 full, 2 lateral), `particles` and `estimator_rate` parameters
    default_particles = 500
    default_rate = 100.0
    description = "tirefilter online estimator (tire stiffness, vehicle state, IMU bias)"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        from tirefilter import __version__

        self.version = __version__
        self._values = {}
        P, I, S = "Real", "Integer", "String"
        for key, default in _vehicle_parameters():
            kind = I if key == "drive" else P
            desc = ("drive axle: 0 front, 1 rear, 2 all" if key == "drive" else
                    "vehicle TOML key (0 = not given)" if key in ("steering_ratio", "Cx_undriven") else
                    "vehicle TOML key (SI units)")
            self._parameter(kind, f"vehicle.{key}", default, desc, None if key == "drive" else VEHICLE_UNITS[key])
        self._parameter(I, "particles", self.default_particles, "number of particles N")
        self._parameter(P, "forgetting", 0.99, "forgetting factor lambda of eq. (20), in (0, 1]", "1")
        self._parameter(I, "seed", 0, "seed of the run's SeedSequence (spawns the vehicle's and the estimator's)")
        self._parameter(P, "estimator_rate", self.default_rate, "[Hz] samples at n / estimator_rate", "Hz")
        self._parameter(I, "model", self.default_model, "estimation model: 1 full (wheel speeds), 2 lateral (u.vx given)")
        self._parameter(P, "t_first", 0.0, "[s] first sample time processed (masters that start connectors "
                        "at 0 deliver real inputs one communication step later)", "s")
        self._parameter(S, "config", self._default_config(), "estimator options: TOML text or a path to a TOML "
                        "file, as --config ([mpf] table)")
        self._parameter(S, "rrd", "", "optional Rerun recording (.rrd) to write; empty: none")
        for name, (unit, desc) in ESTIMATOR_INPUTS.items():
            self._add(P, name, self._T.causality.input, 0.0, f"[{unit}] {desc}; NaN = missing sample", unit=unit)
        self._output("Boolean", "active", False, "learning gate open at the last sample")
        for name, (unit, desc) in ESTIMATOR_OUTPUTS.items():
            self._output(P, name, math.nan, f"[{unit}] {desc}", unit)
        self._output(I, "samples", 0, "samples processed so far")
        self._est = None
        self._run = None  # runs.Run: the estimator's steps and the recording
        self._skipping = False  # the last sample was skipped (its speeds all zero): warned once per stretch
        self._start_time = 0.0

    def _default_config(self) -> str:
        """The `config` start value: resources/estimator_config.toml when the FMU was built
        with one (an SSP bakes its scenario's options in), else empty."""
        path = Path(self.resources or ".") / "estimator_config.toml"
        return path.read_text() if path.is_file() else ""

    # ---- initialisation -------------------------------------------------------------
    def setup_experiment(self, start_time, stop_time=None, tolerance=None):
        self._start_time = self._time = float(start_time)

    def exit_initialization_mode(self):
        try:
            self._initialize()
        except TirefilterError as exc:
            self._fail(f"{self.instance_name}: {exc}")
        self._publish_prior()

    def _config(self) -> dict:
        text = str(self._values["config"]).strip()
        if not text:
            return {}
        if "\n" not in text and text.endswith(".toml"):
            from tirefilter.config import read_toml

            return read_toml(text)
        try:
            return tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise _param_error("config", f"not valid TOML ({exc})") from None

    def _initialize(self) -> None:
        from tirefilter.errors import ConfigError
        from tirefilter.estimators import build, for_log
        from tirefilter.io.results import ESTIMATE_COLUMNS
        from tirefilter.runs import spawn_seeds
        from tirefilter.vehicle.params import vehicle_from_dict

        v = self._values
        for name, unit in self._units.items():  # every Real parameter: a number
            if name in v and _is_parameter(self, name) and not math.isfinite(v[name]):
                raise _param_error(name, f"{v[name]!r} is not finite [{unit}]")
        data = {}
        for key, _ in _vehicle_parameters():
            value = v[f"vehicle.{key}"]
            if key == "drive":
                if value not in DRIVES:
                    raise _param_error("vehicle.drive", f"{value!r} is out of range: expected 0 (front), 1 (rear) "
                                       "or 2 (all)")
                data[key] = DRIVES[value]
            elif key in ("steering_ratio", "Cx_undriven") and value == 0.0:
                continue
            elif key.startswith("bias_q_"):
                if value < 0:
                    raise _param_error(f"vehicle.{key}", f"{value!r} is out of range: a variance per second is >= 0")
                data[key.replace("bias_q_", "bias_rw_")] = math.sqrt(value)
            else:
                data[key] = value
        try:
            vehicle = vehicle_from_dict(data, "FMU")
        except ConfigError as exc:
            raise _param_error(f"vehicle.{exc.key}", exc.problem) from None
        particles, forgetting, seed, rate, model = (v["particles"], v["forgetting"], v["seed"], v["estimator_rate"],
                                                    v["model"])
        if not particles >= 1:
            raise _param_error("particles", f"{particles!r} is out of range: expected >= 1")
        if not 0.0 < forgetting <= 1.0:
            raise _param_error("forgetting", f"{forgetting!r} is out of range: expected in (0, 1]")
        if not seed >= 0:
            raise _param_error("seed", f"{seed!r} is out of range: expected >= 0")
        if not (math.isfinite(rate) and 0.0 < rate <= 10000.0):
            raise _param_error("estimator_rate", f"{rate!r} is out of range: expected in (0, 10000] Hz")
        if model not in MODELS:
            raise _param_error("model", f"{model!r} is out of range: expected 1 (full) or 2 (lateral)")
        if not (math.isfinite(v["t_first"]) and v["t_first"] >= 0.0):
            raise _param_error("t_first", f"{v['t_first']!r} is out of range: expected a finite time >= 0")
        config = self._config()
        for key in ("mpf", "gpssm"):  # numpy kernels unless the config asks for numba: an FMU is
            # unpacked afresh by each importing tool, so numba's cache (beside the sources) does not
            # survive and every instantiation would compile for 10-30 s (fmu_export REQUIREMENTS)
            config[key] = {"backend": "numpy", **config.get(key, {})}
        table = dict(config.get(self.option_table, {}))
        table["forgetting"] = float(forgetting)
        config[self.option_table] = table
        start = config.pop("mpf_start", {})
        self.Ts = 1.0 / rate
        # built as for a log whose every signal is present but has no sample yet: the IMU noise from the
        # vehicle parameters (else the defaults), the MEMS bias model, the state's prior mean the defaults'
        nan2 = np.full(2, math.nan)
        signals = {"delta": nan2, "omega_f": nan2, "omega_r": nan2, "vx": nan2, "ax": nan2, "ay": nan2,
                   "yaw_rate": nan2}
        setting = for_log(vehicle, np.array([0.0, self.Ts]), signals, source="FMU")  # (its sample period: Ts)
        if start:  # what an SSP's scenario tells the MPF about the start (`ssp.scenario_run_parameters`)
            setting = _with_start(setting, start)
        try:
            est = build(self.estimator_name, setting, model=MODELS[model], particles=int(particles), config=config)
        except ConfigError as exc:  # the FMU parameters are checked above: what is left is in `config`
            raise _param_error("config", str(exc)) from None
        _, rng = spawn_seeds(int(seed))
        est.reset(rng)
        self._est = est
        first = max(self._start_time, float(v["t_first"]))
        self._n = max(0, math.ceil(first / self.Ts - 1e-9))
        rrd = str(v["rrd"]).strip()
        sinks = []
        if rrd:  # clouds and densities every `log_every` rows, as in `run`
            from tirefilter.viz.rerun_log import RerunRecorder

            sinks.append(RerunRecorder(rrd, ESTIMATE_COLUMNS, self.estimator_name))
        self._run = self._stepper(sinks)

    def _stepper(self, sinks=()):
        """The run loop's step (`runs.Run`) of this instance's estimator, into `sinks`. The
        estimator steps on the inputs as the master sets them: no measurement guard (the
        outputs equal an in-process estimator's steps on the same samples)."""
        from tirefilter.io.results import ESTIMATE_COLUMNS
        from tirefilter.runs import Run

        return Run(self._est, ESTIMATE_COLUMNS, sinks, on_error=self._estimator_failed, guard=False)

    # ---- stepping -------------------------------------------------------------------
    def do_step(self, current_time, step_size):
        from tirefilter.estimators.base import Inputs, Measurement
        from tirefilter.runs import Sample

        if self._est is None:
            self._fail(f"{self.instance_name}: doStep before initialisation")
        v = self._values
        # the inputs hold over the communication step: judged once, before any sample is processed
        problem = self._impossible_input(current_time)
        if problem:  # refused with the state unchanged: fmi2Discard / fmi3Discard (pythonfmu has no Error here)
            self.log(problem, self._T.status.error)
            return False
        skip = self._unconnected(current_time)
        eps = 1e-9 * self.Ts
        end = current_time + step_size - eps
        while self._n * self.Ts < end:
            s = self._n * self.Ts  # the in-process runs' sample time k h (same double for h = Ts)
            self._n += 1
            if s < current_time - eps or skip:
                continue  # an instant the master stepped over (start time inside a period), or a skipped one
            u = Inputs(delta=v["u.delta"], omega_f=v["u.omega_f"], omega_r=v["u.omega_r"], vx=v["u.vx"])
            y = Measurement(ax=v["y.ax"], ay=v["y.ay"], yaw_rate=v["y.yaw_rate"])
            self._run.step(Sample(self._n - 1, s, u, y))
            self._publish(s, self._run.est)
        self._time = current_time + step_size
        return True

    def _estimator_failed(self, sample, exc: Exception) -> RuntimeError:
        """Logged with the sample time, then fatal for this instance."""
        message = (f"{self.instance_name}: the estimator failed at t = {sample.t:.6g} s: "
                   f"{type(exc).__name__}: {exc}")
        self.log(message, self._T.status.error)
        return RuntimeError(message)

    def _speeds(self) -> tuple[str, ...]:
        """The inputs that carry the longitudinal speed the model uses: u.vx for the lateral model, the
        wheel speeds for the full one."""
        return ("u.vx",) if MODELS[self._values["model"]] == "lateral" else ("u.omega_f", "u.omega_r")

    def _impossible_input(self, s: float) -> str | None:
        """The error message for physically impossible inputs at `s` (NaN is a missing sample, allowed):
        an infinite value, or a negative speed the model uses; None when they are possible."""
        v = self._values
        for name, (unit, _) in ESTIMATOR_INPUTS.items():
            if math.isinf(v[name]):
                return (f"{self.instance_name}: input {name} = {v[name]!r} {unit} at t = {s:.6g} s is not finite "
                        "(NaN marks a missing sample)")
        for name in self._speeds():
            if v[name] < 0.0:
                return (f"{self.instance_name}: input {name} = {v[name]!r} {ESTIMATOR_INPUTS[name][0]} at "
                        f"t = {s:.6g} s: the {MODELS[v['model']]} model needs a forward speed (>= 0)")
        return None

    def _unconnected(self, s: float) -> bool:
        """Whether the samples of the step from `s` are skipped: every speed the model uses is zero, as a
        master sends before it has connected the inputs (or the vehicle stands, where the models do not
        hold). The first step of each such stretch is logged as a warning."""
        v = self._values
        given = [n for n in self._speeds() if not math.isnan(v[n])]
        skip = bool(given) and all(v[n] == 0.0 for n in given)
        if skip and not self._skipping:
            self.log(f"{self.instance_name}: samples from t = {s:.6g} s skipped: {' and '.join(given)} = 0 (the "
                     "input is not connected yet, or the vehicle stands; the models need a forward speed)",
                     self._T.status.warning)
        self._skipping = skip
        return skip

    def _publish_prior(self) -> None:
        """Outputs at the start time: the estimator's prior (no sample processed yet)."""
        from tirefilter.io.results import ESTIMATE_COLUMNS, estimate_values

        est = _prior_estimate(self._est, self._values["u.vx"])
        v = self._values
        for name, value in zip(ESTIMATE_COLUMNS, estimate_values(self._start_time, est)):
            if name != "active":
                v[name] = float(value)
        v["active"] = False
        v["vx_std"], v["vy_std"], v["yaw_rate_std"] = (float(x) for x in est.state_std)

    def _publish(self, s, est) -> None:
        from tirefilter.io.results import ESTIMATE_COLUMNS, estimate_values

        v = self._values
        for name, value in zip(ESTIMATE_COLUMNS, estimate_values(s, est)):
            if name != "active":
                v[name] = float(value)
        v["active"] = bool(est.active)
        v["vx_std"], v["vy_std"], v["yaw_rate_std"] = (float(x) for x in est.state_std)
        v["samples"] += 1

    def terminate(self):
        if self._run is not None:
            self._run.close()  # the recording
            self._run = None

    # ---- FMU state: the whole particle system ----------------------------------------
    def _get_fmu_state(self):
        # everything do_step needs, so the state restores into a fresh instance too (one
        # that was only instantiated, as fmusim's --initial-fmu-state-file does)
        return {"estimator": copy.deepcopy(self._est), "n": self._n, "Ts": self.Ts, "time": self._time,
                "start_time": self._start_time, "values": {k: x for k, x in self._values.items()
                                                           if not _is_parameter(self, k) or k == "model"}}

    def _set_fmu_state(self, state):
        self._est = copy.deepcopy(state["estimator"])
        if self._run is None:  # a fresh instance, never initialised
            self._run = self._stepper()
        self._run.estimator = self._est
        self._n = state["n"]
        self.Ts = state["Ts"]
        self._time = state["time"]
        self._start_time = state["start_time"]
        self._values.update(state["values"])

    @staticmethod
    def _fmu_state_to_bytes(state):
        return fmu_state.state_to_bytes(state)

    @staticmethod
    def _fmu_state_from_bytes(data):
        return fmu_state.state_from_bytes(data)


class _FrictionLogic(_EstimatorLogic):
    """A friction estimator (`gpssm`, `combined`) as an FMU: the outputs of every
    estimator FMU plus the learned curves on a fixed slip grid (FMI 2.0 has scalars only):
    `mu_f[i]`, `mu_f_std[i]`, `mu_r[i]`, `mu_r_std[i]` at alpha = the i-th of
    FRICTION_ALPHA_DEG deg (`friction_output`) (linear interpolation of the estimator's finer `friction()`
    grid), and the visited slip range. Evaluating the curves solves each particle's
    statistics, so they are refreshed every `friction_period` seconds of samples (and at
    the first sample); `friction_t` says when."""

    estimator_name = "combined"
    option_table = "gpssm"
    default_model = 2  # the friction GP-SSM has the lateral model only (u.vx given)
    default_particles = 200  # the friction paper's N and Ts = 40 ms
    default_rate = 25.0
    description = "tirefilter friction GP-SSM: tire-friction curves mu(alpha), lateral state"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self._parameter("Real", "friction_period", 1.0, "[s] time between updates of the friction outputs "
                        "(0: every sample)", "s")
        self._output("Real", "friction_t", math.nan, "[s] sample time of the friction outputs", "s")
        for k in FRICTION_ALPHA_DEG:
            for axle, what in (("f", "front"), ("r", "rear")):
                self._output("Real", friction_output(f"mu_{axle}", k), math.nan,
                             f"[1] {what} axle friction (lateral force / normal load) at alpha = {k} deg", "1")
                self._output("Real", friction_output(f"mu_{axle}_std", k), math.nan,
                             f"[1] posterior std of mu_{axle} at alpha = {k} deg", "1")
        for name in FRICTION_VISITED:
            self._output("Real", name, math.nan, f"[rad] visited slip range while learning: {name}", "rad")

    def _initialize(self) -> None:
        period = self._values["friction_period"]
        if not (math.isfinite(period) and period >= 0.0):
            raise _param_error("friction_period", f"{period!r} is out of range: expected a finite time >= 0")
        super()._initialize()
        self._friction_due = -math.inf

    def _publish(self, s, est) -> None:
        super()._publish(s, est)
        if s + 1e-9 * self.Ts < self._friction_due:
            return
        self._friction_due = s + self._values["friction_period"]
        curve = self._est.friction()
        alpha = np.deg2rad(np.array(FRICTION_ALPHA_DEG, float))
        v = self._values
        for axle in ("f", "r"):
            for field in (f"mu_{axle}", f"mu_{axle}_std"):
                values = np.interp(alpha, curve.alpha, getattr(curve, field), left=math.nan, right=math.nan)
                for k, value in zip(FRICTION_ALPHA_DEG, values):
                    v[friction_output(field, k)] = float(value)
        for name, value in zip(FRICTION_VISITED, curve.visited):
            v[name] = float(value)
        v["friction_t"] = float(s)

    def _get_fmu_state(self):
        state = super()._get_fmu_state()
        state["friction_due"] = self._friction_due
        return state

    def _set_fmu_state(self, state):
        super()._set_fmu_state(state)
        self._friction_due = state["friction_due"]


def _prior_estimate(est, vx_input: float):
    """The Estimate of an estimator's prior, before any sample: the particle filters'
    `_estimate` on the initial particles (ESS = N), v^X from the input for the lateral model."""
    n = float(est.cfg.particles)
    if len(inspect.signature(est._estimate).parameters) == 1:  # the stiffness MPF
        return est._estimate(n)
    return est._estimate(n, float(vx_input))  # the friction GP-SSM (lateral model)


def _is_parameter(slave, name) -> bool:
    return name.startswith("vehicle.") or name in ("particles", "forgetting", "seed", "estimator_rate", "model",
                                                   "t_first", "config", "rrd", "scenario", "friction_period")


def _param_error(name: str, problem: str) -> TirefilterError:
    return TirefilterError(f"parameter {name}: {problem}")


class _DriverLogic(_Slave):
    """A scenario's input profile as an FMU: outputs delta, drive_torque, brake_torque,
    surface, bank at the end of each step (t + h: what the vehicle applies over its next
    step), the speed-hold PI driver closed over the input `vx`.

    The open-loop part is evaluated on the scenario's communication grid k h exactly as the
    in-process master does (`InputSchedule.open_loop`), so the values are the same doubles.
    The PI sees the latest vx it was given: with a master that exchanges values once per
    step (Jacobi, fmpy's SSP master) that is vx one communication step old; before
    `t_first` the vx input is not used (speed error 0), because such masters start
    connectors at 0."""

    description = "tirefilter driver: plays a scenario's input profile (steer, torques, surface, bank)"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        from tirefilter import __version__

        self.version = __version__
        self._values = {}
        path = Path(self.resources or ".") / "driver_scenario.txt"
        default = path.read_text().strip() if path.is_file() else "paper-sim"
        self._parameter("String", "scenario", default, "scenario: built-in name or path to a scenario TOML")
        self._parameter("Real", "t_first", 0.0, "[s] the vx input is used from this time on", "s")
        self._add("Real", "vx", self._T.causality.input, 0.0, "[m/s] vehicle longitudinal speed (for the speed hold)",
                  unit="m/s")
        for name, unit in (("delta", "rad"), ("drive_torque", "N.m"), ("brake_torque", "N.m"), ("surface", "1"),
                           ("bank", "rad")):
            self._output("Real", name, math.nan, f"[{unit}] vehicle input {name}", unit)
        self._start_time = 0.0

    def setup_experiment(self, start_time, stop_time=None, tolerance=None):
        self._start_time = self._time = float(start_time)

    def exit_initialization_mode(self):
        from tirefilter.scenarios import load_scenario

        try:
            self._scenario = load_scenario(str(self._values["scenario"]))
        except TirefilterError as exc:
            self._fail(f"{self.instance_name}: parameter scenario: {exc}")
        if not (math.isfinite(self._values["t_first"]) and self._values["t_first"] >= 0):
            self._fail(f"{self.instance_name}: parameter t_first: {self._values['t_first']!r} is out of range: "
                       "expected a finite time >= 0")
        sc = self._scenario
        self._h = sc.communication_step
        self._table = None
        self._integral = 0.0
        self._gain = sc.vehicle.mass * sc.vehicle.wheel_radius
        self._set_outputs(self._start_time, 0.0)

    def _open_loop(self, t: float) -> np.ndarray:
        k = round(t / self._h)
        if k >= 0 and abs(k * self._h - t) <= 1e-9 * self._h:
            if self._table is None or k >= len(self._table):
                n = max(int(round(self._scenario.duration / self._h)), 2 * k) + 1
                self._table = self._scenario.inputs.open_loop(np.arange(n) * self._h)
            return self._table[k].copy()
        return self._scenario.inputs.open_loop(np.array([t]))[0]

    def _set_outputs(self, t: float, h: float) -> None:
        u = self._open_loop(t)
        hold = self._scenario.inputs.speed_hold
        if hold is not None:
            use_vx = t - h >= self._values["t_first"] - 1e-9 * max(self._h, 1e-9)
            err = float(hold.reference(t)) - float(self._values["vx"]) if use_vx else 0.0
            self._integral += err * (h if h > 0 else self._h)
            u[1] += self._gain * (hold.kp * err + hold.ki * self._integral)
        for name, value in zip(("delta", "drive_torque", "brake_torque", "surface", "bank"), u):
            self._values[name] = float(value)

    def do_step(self, current_time, step_size):
        self._set_outputs(current_time + step_size, step_size)
        self._time = current_time + step_size
        return True

    def _get_fmu_state(self):
        return {"integral": self._integral, "values": {k: x for k, x in self._values.items()
                                                       if not _is_parameter(self, k)}}

    def _set_fmu_state(self, state):
        self._integral = state["integral"]
        self._values.update(state["values"])

    @staticmethod
    def _fmu_state_to_bytes(state):
        return fmu_state.state_to_bytes(state)

    @staticmethod
    def _fmu_state_from_bytes(data):
        return fmu_state.state_from_bytes(data)


_CLASSES = {"EstimatorSlave": _EstimatorLogic, "FrictionEstimatorSlave": _FrictionLogic, "DriverSlave": _DriverLogic}


@lru_cache(maxsize=None)
def _fmu_class(name: str):
    logic = _CLASSES[name.removesuffix("3")]
    api = _api("3" if name.endswith("3") else "2")
    return type(name, (logic, api.Slave), {"_T": api, "__module__": __name__,
                                           "__doc__": f"{logic.__doc__} (FMI {api.fmi}.0)"})


def __getattr__(name: str):
    """EstimatorSlave, FrictionEstimatorSlave, DriverSlave (FMI 2.0) and the same with a
    3 (FMI 3.0): made on first use from the logic classes and that version's pythonfmu."""
    if name.removesuffix("3") in _CLASSES:
        return _fmu_class(name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
