"""Scenarios as data: maneuvers, surfaces and sensor specifications (TOML files in data/).

A scenario names its vehicle (data/vehicles/NAME.toml) and tire set (data/tires/NAME.toml),
states its estimator rate, sensors, excitation windows and surface changes, the truth
model's stochastic settings, the estimators' initialisation, and the input profiles.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tirefilter.config import check_known_keys, get_choice, get_number, get_table, read_toml
from tirefilter.errors import ConfigError
from tirefilter.scenarios.faults import parse_faults
from tirefilter.scenarios.profiles import INPUTS, InputSchedule, SpeedHold, parse_component
from tirefilter.vehicle.params import PacejkaParams, SensorSpec, VehicleParams, load_vehicle
from tirefilter.vehicle.single_track import TruthModel

DATA_DIR = Path(__file__).resolve().parent / "data"
SENSORS = ("ax", "ay", "yaw_rate", "omega_f", "omega_r", "delta", "vx")
_TRUTH_KEYS = {
    "stiffness_dev_std": (0.0, 0.5), "vx0": (None, None), "vy0": (None, None), "yaw_rate0": (None, None),
    "vx0_std": (0.0, None), "vy0_std": (0.0, None), "yaw_rate0_std": (0.0, None),
    "roll_gradient": (0.0, 0.05), "load_transfer_time_constant": (1e-3, None),
}
_TOP_KEYS = {"name", "description", "source", "duration", "estimator_rate", "communication_step", "vehicle",
             "sensors", "excitation", "tires", "truth", "sensor_noise", "estimator", "inputs", "faults"}


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    source: str
    duration: float  # s
    estimator_rate: float  # Hz
    communication_step: float  # s
    sensors: tuple[str, ...]
    excitation: tuple[tuple[float, float], ...]  # s, windows where the estimators can learn
    model: TruthModel
    sensor_spec: SensorSpec
    truth: dict  # stiffness_dev_std, initial state mean/std, truth-only overrides
    estimator: dict  # estimator initialisation (interpreted by the estimators)
    inputs: InputSchedule
    file: Path
    vehicle_file: Path
    surface_changes: tuple[float, ...] = field(default=())
    faults: tuple = field(default=())  # scenarios.faults.Fault: applied to the sensors, not the truth

    @property
    def sample_period(self) -> float:
        return 1.0 / self.estimator_rate

    @property
    def steps_per_sample(self) -> int:
        return int(round(self.sample_period / self.communication_step))

    @property
    def vehicle(self) -> VehicleParams:
        return self.model.vehicle

    def reference_stiffness(self) -> dict[str, float]:
        """The true surface-1 stiffness at static load: the initial slope of the tire
        curves (Pacejka B C mu F_z) or the linear values; Cx is the driven axle's."""
        v = self.vehicle
        if self.model.tire_model == "linear":
            Cf_y, Cr_y, Cf_x, Cr_x = self.model.axle_stiffness()
        else:
            p = self.model.pacejka
            Fz_f, Fz_r = v.static_axle_loads()
            Cf_y, Cr_y = p.lateral_stiffness(Fz_f), p.lateral_stiffness(Fz_r)
            Cf_x, Cr_x = p.longitudinal_stiffness(Fz_f), p.longitudinal_stiffness(Fz_r)
        return {"Cf_y": Cf_y, "Cr_y": Cr_y, "Cx": Cr_x if v.drive == "rear" else Cf_x}

    def summary(self) -> dict:
        """The `tirefilter scenarios --json` record."""
        return {
            "name": self.name,
            "description": self.description,
            "source": self.source,
            "duration": self.duration,
            "estimator_rate": self.estimator_rate,
            "communication_step": self.communication_step,
            "sensors": list(self.sensors),
            "excitation": [list(w) for w in self.excitation],
            "surface_changes": list(self.surface_changes),
            "tire_model": self.model.tire_model,
            "vehicle": self.vehicle_file.stem,
            "file": str(self.file),
        }

    def fmu_parameters(self, seed: int) -> dict[str, float | int]:
        """Parameter values of the vehicle FMU for this scenario."""
        v, m = self.vehicle, self.model
        Cf_y, Cr_y, Cf_x, Cr_x = m.axle_stiffness()
        p = {
            "mass": v.mass, "yaw_inertia": v.yaw_inertia, "lf": v.lf, "lr": v.lr, "cg_height": v.cg_height,
            "wheel_radius": v.wheel_radius, "wheel_inertia_f": v.wheel_inertia_f, "wheel_inertia_r": v.wheel_inertia_r,
            "drive": {"front": 0, "rear": 1, "all": 2}[v.drive], "awd_front_share": v.awd_front_share,
            "brake_front_share": v.brake_front_share, "rolling_resistance": v.rolling_resistance,
            "drag_coefficient": v.drag_coefficient,
            "roll_gradient": self.truth.get("roll_gradient", v.roll_gradient or 0.0),
            "imu_x": v.imu_x, "imu_y": v.imu_y,
            "load_transfer_time_constant": m.load_transfer_time_constant,
            "tire_model": 0 if m.tire_model == "linear" else 1,
            "Cf_y": Cf_y, "Cr_y": Cr_y, "Cf_x": Cf_x, "Cr_x": Cr_x,
            "seed": int(seed), "sample_period": self.sample_period,
        }
        if m.pacejka is not None:
            p.update({f"pac_{f.name}": getattr(m.pacejka, f.name) for f in dataclasses.fields(PacejkaParams)})
        s = self.sensor_spec
        p.update({f.name: getattr(s, f.name) for f in dataclasses.fields(SensorSpec) if f.name != "available"})
        for axis in ("ax", "ay", "yaw_rate"):  # the FMU takes the random-walk intensity as variance per second
            p[f"bias_q_{axis}"] = p.pop(f"bias_rw_{axis}") ** 2
        for key in ("stiffness_dev_std", "vx0", "vy0", "yaw_rate0", "vx0_std", "vy0_std", "yaw_rate0_std"):
            if key in self.truth:
                p[key] = self.truth[key]
        return p


def scenario_files() -> dict[str, Path]:
    return {p.stem: p for p in sorted(DATA_DIR.glob("*.toml"))}


def load_scenario(name_or_path: str | Path) -> Scenario:
    """A built-in scenario by name, or a scenario TOML file by path."""
    path = Path(name_or_path)
    if not path.suffix == ".toml":
        files = scenario_files()
        if str(name_or_path) not in files:
            raise ConfigError(name_or_path, "", f"unknown scenario; known scenarios: {', '.join(files)}")
        path = files[str(name_or_path)]
    return _parse(read_toml(path), path)


def list_scenarios() -> list[Scenario]:
    return [load_scenario(name) for name in scenario_files()]


def _resolve(ref: str, folder: str, file, key) -> Path:
    if not isinstance(ref, str):
        raise ConfigError(file, key, f"expected a name or a path, got {ref!r}")
    candidate = Path(ref)
    if candidate.suffix == ".toml":
        return candidate if candidate.is_absolute() else (Path(file).parent / candidate)
    path = DATA_DIR / folder / f"{ref}.toml"
    if not path.is_file():
        known = ", ".join(p.stem for p in sorted((DATA_DIR / folder).glob("*.toml")))
        raise ConfigError(file, key, f"unknown {folder[:-1]} {ref!r} (known: {known})")
    return path


def _parse(data: dict, file: Path) -> Scenario:
    check_known_keys(data, _TOP_KEYS, file)
    name = data.get("name", file.stem)
    duration = get_number(data, "duration", file, lo=0.0, lo_open=True)
    rate = get_number(data, "estimator_rate", file, lo=0.0, lo_open=True, hi=10000.0)
    h = get_number(data, "communication_step", file, default=min(0.01, 1.0 / rate), lo=1e-5, hi=1.0)
    ratio = (1.0 / rate) / h
    if abs(ratio - round(ratio)) > 1e-9 * ratio or round(ratio) < 1:
        raise ConfigError(file, "communication_step",
                          f"{h} s must divide the estimator sample period {1.0 / rate} s a whole number of times")

    sensors = data.get("sensors", list(SENSORS))
    if not isinstance(sensors, list) or any(s not in SENSORS for s in sensors):
        raise ConfigError(file, "sensors", f"expected a list drawn from {', '.join(SENSORS)}, got {sensors!r}")

    excitation = data.get("excitation", [[0.0, duration]])
    if not isinstance(excitation, list) or not all(
        isinstance(w, list) and len(w) == 2 and all(isinstance(x, (int, float)) for x in w) and 0 <= w[0] < w[1] <= duration
        for w in excitation
    ):
        raise ConfigError(file, "excitation", f"expected a list of [t_start, t_end] windows inside [0, {duration}] s, "
                          f"got {excitation!r}")

    vehicle_file = _resolve(data.get("vehicle", "midsize-suv"), "vehicles", file, "vehicle")
    vehicle = load_vehicle(vehicle_file)

    tires = get_table(data, "tires", file, default={"model": "linear"})
    check_known_keys(tires, {"model", "set"}, file, prefix="tires.")
    tire_model = get_choice(tires, "model", file, ("linear", "pacejka"), prefix="tires.")
    pacejka = None
    if tire_model == "pacejka" or "set" in tires:
        if "set" not in tires:
            raise ConfigError(file, "tires.set", "missing (the Pacejka model needs a tire set, e.g. 'snow')")
        pacejka = _load_pacejka(_resolve(tires["set"], "tires", file, "tires.set"))

    truth_table = get_table(data, "truth", file, default={})
    check_known_keys(truth_table, set(_TRUTH_KEYS), file, prefix="truth.")
    truth = {k: get_number(truth_table, k, file, prefix="truth.", lo=lo, hi=hi)
             for k, (lo, hi) in _TRUTH_KEYS.items() if k in truth_table}
    model = TruthModel(vehicle, tire_model, pacejka, truth.get("load_transfer_time_constant", 0.1))

    noise = get_table(data, "sensor_noise", file, default={})
    spec_fields = {f.name for f in dataclasses.fields(SensorSpec)} - {"available"}
    check_known_keys(noise, spec_fields, file, prefix="sensor_noise.")
    defaults = {k: getattr(vehicle, k) for k in ("sigma_ax", "sigma_ay", "sigma_yaw_rate")
                if getattr(vehicle, k) is not None}
    spec_values = {}
    for k in spec_fields:
        lo = None if k.startswith("bias0_") and "std" not in k else 0.0
        spec_values[k] = get_number(noise, k, file, prefix="sensor_noise.", lo=lo,
                                    default=defaults.get(k, SensorSpec.__dataclass_fields__[k].default))
    sensor_spec = SensorSpec(available=tuple(sensors), **spec_values)

    estimator = get_table(data, "estimator", file, default={})
    if "forgetting" in estimator:
        get_number(estimator, "forgetting", file, prefix="estimator.", lo=0.0, lo_open=True, hi=1.0)
    if "particles" in estimator:
        get_number(estimator, "particles", file, prefix="estimator.", lo=1, integer=True)

    inputs_table = get_table(data, "inputs", file, default={})
    components, speed_hold = {}, None
    for key, comps in inputs_table.items():
        if key not in INPUTS:
            raise ConfigError(file, f"inputs.{key}", f"unknown input (known: {', '.join(INPUTS)})")
        if not isinstance(comps, list):
            raise ConfigError(file, f"inputs.{key}", "expected an array of tables ([[inputs.NAME]])")
        parsed = []
        for i, comp in enumerate(comps):
            c = parse_component(comp, file, f"inputs.{key}[{i}]")
            if isinstance(c, SpeedHold):
                if key != "drive_torque" or speed_hold is not None:
                    raise ConfigError(file, f"inputs.{key}[{i}].type", "speed_hold drives drive_torque, once")
                speed_hold = c
            else:
                parsed.append(c)
        components[key] = tuple(parsed)
    schedule = InputSchedule(components, speed_hold)
    try:
        changes = tuple(schedule.surface_changes())
    except ValueError as exc:
        raise ConfigError(file, "inputs.surface", str(exc)) from None
    _check_input_ranges(schedule, duration, h, file)

    return Scenario(
        name=name, description=data.get("description", ""), source=data.get("source", ""), duration=duration,
        estimator_rate=rate, communication_step=h, sensors=tuple(sensors),
        excitation=tuple((float(a), float(b)) for a, b in excitation), model=model, sensor_spec=sensor_spec,
        truth=truth, estimator=estimator, inputs=schedule, file=Path(file), vehicle_file=vehicle_file,
        surface_changes=changes, faults=parse_faults(data.get("faults"), str(file)),
    )


def _check_input_ranges(schedule: InputSchedule, duration: float, h: float, file) -> None:
    t = np.arange(int(round(duration / h))) * h
    u = schedule.open_loop(t)
    limits = {"delta": (-np.pi / 2, np.pi / 2), "brake_torque": (0.0, np.inf), "surface": (0.01, 2.0),
              "bank": (-0.5, 0.5)}
    for j, name in enumerate(INPUTS):
        if name not in limits:
            continue
        lo, hi = limits[name]
        bad = np.flatnonzero((u[:, j] < lo) | (u[:, j] > hi))
        if bad.size:
            k = bad[0]
            raise ConfigError(file, f"inputs.{name}", f"value {u[k, j]:.6g} at t = {t[k]:.3f} s is outside "
                              f"[{lo:.6g}, {hi:.6g}]" + (" rad (steer beyond +-90 deg)" if name == "delta" else ""))


def _load_pacejka(path: Path) -> PacejkaParams:
    data = read_toml(path)
    names = {f.name for f in dataclasses.fields(PacejkaParams)}
    check_known_keys(data, names, path)
    values = {}
    for f in dataclasses.fields(PacejkaParams):
        lo = 0.0 if f.name.startswith(("mu", "B", "C", "r")) else None
        kwargs = {} if f.default is dataclasses.MISSING else {"default": f.default}
        values[f.name] = get_number(data, f.name, path, lo=lo, lo_open=f.name.startswith(("mu", "B_", "C_")), **kwargs)
    return PacejkaParams(**values)
