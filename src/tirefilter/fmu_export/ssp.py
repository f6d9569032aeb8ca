"""An SSP (System Structure and Parameterization 1.0) of a scenario: driver FMU -> vehicle
FMU -> estimator FMU, and running it with `fmpy.ssp.simulation.simulate_ssp`.

The archive holds `SystemStructure.ssd` (components, connectors, connections, default
experiment), the three FMUs under `resources/` and `resources/parameters.ssv` with every
parameter of the run: the vehicle FMU's parameters of the scenario (its seed spawned from
the run seed exactly as `tirefilter run` does), the estimator's vehicle record, N,
forgetting, seed and rate, and `t_first`. The estimator options of the scenario
(`mpf_config_for_scenario`: initial stiffness, noise levels, ...) are baked into the
estimator FMU of the SSP as the start value of its `config` parameter, because fmpy's
master cannot set String parameters.

fmpy's master is a Jacobi scheme: every connector starts at 0, each step sets every
component's inputs from the values after the previous step, steps every component from
t to t + h and then copies outputs to inputs. Hence:
- the estimator sees the vehicle's samples at t from its step t on (no delay), except the
  sample at the start time, which no connector carries: `t_first` = one step;
- the driver's speed-hold PI sees v^X one communication step old (`DriverSlave`);
- a vehicle input connected from the driver is 0 in the first step: the surface scale
  (which the vehicle rejects below 0.01) is connected only when the scenario changes it,
  otherwise the vehicle keeps its start value 1.
"""

from __future__ import annotations

import dataclasses
import math
import shutil
import tempfile
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from tirefilter.errors import FMUError

DRIVER_OUTPUTS = ("delta", "drive_torque", "brake_torque", "surface", "bank")
SENSOR_CONNECTIONS = (  # vehicle FMU output -> estimator FMU input, scenario sensor name
    ("delta_meas", "u.delta", "delta"), ("omega_f_meas", "u.omega_f", "omega_f"),
    ("omega_r_meas", "u.omega_r", "omega_r"), ("vx", "u.vx", "vx"), ("ax_meas", "y.ax", "ax"),
    ("ay_meas", "y.ay", "ay"), ("yaw_rate_meas", "y.yaw_rate", "yaw_rate"),
)
TRUTH_RECORDED = ("vy", "yaw_rate", "true_Cf_y_mean", "true_Cr_y_mean", "true_Cx_mean",
                  "true_b_ax", "true_b_ay", "true_b_yaw_rate")


def config_toml(config, keys=None) -> str:
    """An estimator configuration dataclass as the `[table]` TOML of --config (None
    fields left out; floats written exactly): the fields named in `keys` (default every one)."""
    def value(x):
        if isinstance(x, bool):
            return "true" if x else "false"
        if isinstance(x, int):
            return str(x)
        if isinstance(x, float):
            return repr(x) if math.isfinite(x) else ("nan" if math.isnan(x) else ("inf" if x > 0 else "-inf"))
        if isinstance(x, str):
            return '"' + x.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(x, (tuple, list)):
            return "[" + ", ".join(value(float(e) if isinstance(e, (np.floating, int)) and not isinstance(e, bool)
                                         else e) for e in x) + "]"
        raise TypeError(f"cannot write {x!r} as TOML")

    lines = []
    for name in keys or [f.name for f in dataclasses.fields(config)]:
        x = getattr(config, name)
        if x is None or name in ("particles", "model", "forgetting", "sample_period"):
            continue  # None: the default; the others are FMU parameters
        lines.append(f"{name} = {value(x)}")
    return "\n".join(lines) + "\n"


def scenario_run_parameters(scenario, *, seed: int, particles: int | None = None, model: str = "auto"):
    """(vehicle FMU parameters, estimator FMU parameters, driver FMU parameters, estimator
    options TOML) of one run of `scenario`, as `tirefilter run` sets them up: the MPF's options
    (`[mpf]`) and what the scenario tells it about the start (`[mpf_start]`, `START_FIELDS`)."""
    from tirefilter.estimators import check_model_signals, mpf_config_for_scenario, resolve_model
    from tirefilter.estimators.mpf.config import START_FIELDS, USER_OPTIONS
    from tirefilter.fmu_export.variables import RW_AS_VARIANCE
    from tirefilter.runs import spawn_seeds

    fmu_seed, _ = spawn_seeds(seed)
    vehicle = scenario.fmu_parameters(fmu_seed)
    model = resolve_model(model, scenario.sensors)
    check_model_signals(model, scenario.sensors, scenario.file, "sensors")
    cfg = mpf_config_for_scenario(scenario, model=model, particles=particles, overrides={})
    v = scenario.vehicle
    est = {}
    for f in dataclasses.fields(v):
        x = getattr(v, f.name)
        if f.name == "drive":
            est["vehicle.drive"] = {"front": 0, "rear": 1, "all": 2}[x]
        elif f.name in RW_AS_VARIANCE and x is not None:
            est[f"vehicle.{RW_AS_VARIANCE[f.name]}"] = float(x) ** 2
        elif x is not None:
            est[f"vehicle.{f.name}"] = float(x)
        elif f.name in ("steering_ratio", "Cx_undriven"):
            est[f"vehicle.{f.name}"] = 0.0  # "not given"
        # other keys the vehicle file leaves out (the IMU bias) keep the FMU's default, as a replay's
    est.update({"particles": int(cfg.particles), "forgetting": float(cfg.forgetting), "seed": int(seed),
                "estimator_rate": float(scenario.estimator_rate), "model": 1 if model == "full" else 2,
                "t_first": float(scenario.communication_step)})
    for fmu_output, fmu_input, sensor in SENSOR_CONNECTIONS:
        if sensor not in scenario.sensors:
            est[fmu_input] = math.nan  # a missing sensor: NaN, as the in-process master gives
    driver = {"t_first": float(scenario.communication_step)}
    return vehicle, est, driver, ("[mpf]\n" + config_toml(cfg, USER_OPTIONS) + "\n[mpf_start]\n"
                                  + config_toml(cfg, START_FIELDS))


def _ssv(parameters: dict[str, dict], types: dict[str, dict], name: str) -> str:
    out = ['<?xml version="1.0" encoding="UTF-8"?>',
           '<ssv:ParameterSet xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues"'
           f' version="1.0" name={quoteattr(name)}>', "  <ssv:Parameters>"]
    for component, values in parameters.items():
        for key, x in values.items():
            kind = types[component].get(key, "Real")
            text = str(int(x)) if kind == "Integer" else ("NaN" if math.isnan(x) else repr(float(x)))
            out.append(f'    <ssv:Parameter name={quoteattr(component + "." + key)}>'
                       f'<ssv:{kind} value="{text}"/></ssv:Parameter>')
    out += ["  </ssv:Parameters>", "</ssv:ParameterSet>", ""]
    return "\n".join(out)


def _component(name: str, source: str, connectors: list[tuple[str, str, str]]) -> list[str]:
    out = [f'      <ssd:Component name="{name}" type="application/x-fmu-sharedlibrary" source="{source}">',
           "        <ssd:Connectors>"]
    for cname, kind, ctype in connectors:
        out.append(f'          <ssd:Connector name={quoteattr(cname)} kind="{kind}"><ssc:{ctype}/></ssd:Connector>')
    out += ["        </ssd:Connectors>", "      </ssd:Component>"]
    return out


def surface_connected(scenario) -> bool:
    """Whether the SSP connects the driver's surface to the vehicle: only when the scenario
    changes it. Then fmpy's simulate_ssp cannot run the SSP (the 0 of the first step is
    outside the vehicle's [0.01, 2]); masters that initialise connectors from the FMUs'
    initial outputs can."""
    grid = np.arange(int(round(scenario.duration / scenario.communication_step)) + 1) * scenario.communication_step
    return bool(np.any(scenario.inputs.open_loop(grid)[:, 3] != 1.0))


def build_ssp(scenario_name: str = "snow-sine", out: Path | None = None, *, seed: int = 0,
              particles: int | None = None, stop_time: float | None = None, estimator: str = "mpf") -> Path:
    """Build `<out>` (default fmu/build/<scenario>.ssp) for one run of the scenario."""
    from fmpy import read_model_description

    from tirefilter.cosim.fmu import BUILD_DIR, vehicle_fmu_path
    from tirefilter.fmu_export.build import ESTIMATOR_FMUS, build_driver_fmu, build_estimator_fmu
    from tirefilter.fmu_export.variables import ESTIMATOR_OUTPUTS
    from tirefilter.scenarios import DATA_DIR, load_scenario

    scenario = load_scenario(scenario_name)
    vehicle_fmu = vehicle_fmu_path("2")
    if not vehicle_fmu.is_file():
        raise FMUError(f"vehicle FMU not found at {vehicle_fmu}; build it with `tirefilter fmu build vehicle`")
    out = Path(out) if out else BUILD_DIR / f"{scenario.name}.ssp"
    vehicle_p, est_p, driver_p, options = scenario_run_parameters(scenario, seed=seed, particles=particles)
    md = read_model_description(str(vehicle_fmu))
    vtypes = {v.name: v.type for v in md.modelVariables}
    est_types = {"vehicle.drive": "Integer", "particles": "Integer", "seed": "Integer", "model": "Integer"}
    changes_surface = surface_connected(scenario)
    est_identifier = ESTIMATOR_FMUS[estimator].model_identifier
    stop = float(stop_time if stop_time is not None else scenario.duration)

    with tempfile.TemporaryDirectory(prefix="tirefilter_ssp_") as tmp:
        tmp = Path(tmp)
        est_fmu = build_estimator_fmu(estimator, tmp, config_toml=options)
        builtin = scenario.file.parent == DATA_DIR
        driver_fmu = build_driver_fmu(scenario.name if builtin else str(scenario.file.resolve()), tmp)
        driver_conn = [("vx", "input", "Real")] + [(n, "output", "Real") for n in DRIVER_OUTPUTS]
        vehicle_in = [n for n in DRIVER_OUTPUTS if n != "surface" or changes_surface]
        vehicle_conn = ([(n, "input", "Real") for n in vehicle_in]
                        + [(o, "output", "Real") for o, _, s in SENSOR_CONNECTIONS if s in scenario.sensors]
                        + [(o, "output", "Real") for o in TRUTH_RECORDED])
        est_conn = ([(i, "input", "Real") for _, i, s in SENSOR_CONNECTIONS if s in scenario.sensors]
                    + [("active", "output", "Boolean"), ("samples", "output", "Integer")]
                    + [(o, "output", "Real") for o in ESTIMATOR_OUTPUTS])
        connections = [("driver", n, "vehicle", n) for n in vehicle_in] + [("vehicle", "vx", "driver", "vx")]
        connections += [("vehicle", o, "estimator", i) for o, i, s in SENSOR_CONNECTIONS if s in scenario.sensors]
        ssd = [
            '<?xml version="1.0" encoding="UTF-8"?>',
            '<ssd:SystemStructureDescription xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon"'
            ' xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription" version="1.0"'
            f' name={quoteattr(scenario.name)} generationTool="tirefilter">',
            f'  <ssd:System name="root" description={quoteattr(scenario.description)}>',
            "    <ssd:ParameterBindings>",
            '      <ssd:ParameterBinding source="resources/parameters.ssv"/>',
            "    </ssd:ParameterBindings>",
            "    <ssd:Elements>",
            *_component("driver", f"resources/{driver_fmu.name}", driver_conn),
            *_component("vehicle", f"resources/{vehicle_fmu.name}", vehicle_conn),
            *_component("estimator", f"resources/{est_fmu.name}", est_conn),
            "    </ssd:Elements>",
            "    <ssd:Connections>",
            *[f'      <ssd:Connection startElement="{a}" startConnector="{b}" endElement="{c}" endConnector="{d}"/>'
              for a, b, c, d in connections],
            "    </ssd:Connections>",
            "  </ssd:System>",
            f'  <ssd:DefaultExperiment startTime="0.0" stopTime="{stop!r}"/>',
            "</ssd:SystemStructureDescription>",
            "",
        ]
        types = {"vehicle": vtypes, "estimator": est_types, "driver": {}}
        ssv = _ssv({"vehicle": vehicle_p, "estimator": est_p, "driver": driver_p}, types, scenario.name)
        out.parent.mkdir(parents=True, exist_ok=True)
        part = out.with_name(out.name + ".part")
        with zipfile.ZipFile(part, "w", zipfile.ZIP_DEFLATED) as zf:
            zf.writestr("SystemStructure.ssd", "\n".join(ssd))
            zf.writestr("resources/parameters.ssv", ssv)
            zf.write(driver_fmu, f"resources/{driver_fmu.name}")
            zf.write(vehicle_fmu, f"resources/{vehicle_fmu.name}")
            zf.write(est_fmu, f"resources/{est_fmu.name}")
        part.replace(out)
    return out


def ssp_step_size(path: str | Path) -> float:
    """The communication step of the SSP's scenario (= the driver's t_first parameter)."""
    from fmpy.ssp.ssd import read_ssd

    for p in read_ssd(str(path)).system.parameterBindings[0].parameterValues[0].parameters:
        if p.name == "driver.t_first":
            return float(p.value)
    raise FMUError(f"{path}: no driver.t_first parameter")


def run_ssp(path: str | Path, *, stop_time: float | None = None, step_size: float | None = None) -> np.ndarray:
    """Simulate the SSP with fmpy.ssp.simulation.simulate_ssp and its parameter set;
    returns fmpy's structured array (column `time`, then `component.connector`; each row
    holds the values after the step that starts at `time`). simulate_ssp loads and frees
    the FMUs itself; the Python FMUs' binaries it leaves loaded are released after it
    (`release.python_fmus_released`: their destructor would corrupt the heap at exit)."""
    from fmpy.ssp.simulation import simulate_ssp
    from fmpy.ssp.ssd import read_ssd

    from tirefilter.fmu_export.release import python_fmus_released

    path = Path(path)
    ssd = read_ssd(str(path))
    parameters = ssd.system.parameterBindings[0].parameterValues[0]
    if stop_time is None:
        with zipfile.ZipFile(path) as zf:
            root = ET.fromstring(zf.read("SystemStructure.ssd"))
        exp = root.find("{http://ssp-standard.org/SSP1/SystemStructureDescription}DefaultExperiment")
        stop_time = float(exp.get("stopTime"))
    h = step_size or ssp_step_size(path)
    # fmpy accumulates time += h; stop half a step early so round-off adds no extra step
    with python_fmus_released():
        return simulate_ssp(str(path), start_time=0.0, stop_time=stop_time - 0.5 * h, step_size=h,
                            parameter_set=parameters)
