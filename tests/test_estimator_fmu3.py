"""The Python FMUs in FMI 3.0 (pythonfmu3) beside FMI 2.0 (pythonfmu), from the same slave
code, and what both declare and refuse: units, the prior as the outputs at the
start time, impossible inputs and parameters refused with the variable named, the state
restored into a fresh instance."""

from __future__ import annotations

import math
import zipfile
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from fmpy.fmi1 import FMICallException
from fmpy.validation import validate_fmu

from test_estimator_fmu import IN_NAMES, OUT, _python_estimator, _run_fmu, snow  # noqa: F401  (snow: fixture)
from tirefilter.fmu_export.host import FMUHost
from tirefilter.fmu_export.slaves import _prior_estimate

pytest.importorskip("pythonfmu3")


@pytest.mark.parametrize("name", ["mpf", "combined", "driver"])
def test_fmi3_fmus_validate(python_fmu, name):
    path = python_fmu(name, "3")
    assert path.name.endswith("_fmi3.fmu")
    assert validate_fmu(str(path)) == []
    with zipfile.ZipFile(path) as zf:
        root = ET.fromstring(zf.read("modelDescription.xml"))
    assert root.get("fmiVersion") == "3.0"
    time = root.find("ModelVariables")[0]
    assert (time.get("name"), time.get("causality"), time.get("valueReference")) == ("time", "independent", "0")


def test_fmi3_estimator_equals_fmi2_and_restores_its_state(python_fmu, snow):  # noqa: F811
    """The same samples give the same estimates bit for bit in both versions; the FMI 3.0
    state (de)serialises and restores into a fresh instance."""
    _, params, stream = snow
    got = {}
    for fmi in ("2", "3"):
        with FMUHost(python_fmu("mpf", fmi)) as host:
            host.initialize(params)
            got[fmi] = _run_fmu(host, stream, 0, 120)
            if fmi == "3":
                data = host.serialize(host.get_state())
                first = _run_fmu(host, stream, 120, 150)
    np.testing.assert_array_equal(got["3"], got["2"])
    assert np.all(np.isfinite(got["3"]))
    with FMUHost(python_fmu("mpf", "3"), "fresh") as other:
        other.set_state(other.deserialize(data, 1.2))
        np.testing.assert_array_equal(_run_fmu(other, stream, 120, 150), first)


@pytest.mark.parametrize("fmi", ["2", "3"])
@pytest.mark.parametrize("name", ["mpf", "combined", "driver"])
def test_every_real_variable_has_a_defined_unit(python_fmu, name, fmi):
    with zipfile.ZipFile(python_fmu(name, fmi)) as zf:
        root = ET.fromstring(zf.read("modelDescription.xml"))
    defined = {u.get("name"): {k: int(e) for k, e in u.find("BaseUnit").attrib.items()}
               for u in root.findall("UnitDefinitions/Unit")}
    units = {}
    for v in root.find("ModelVariables"):
        if fmi == "2":
            real = v.find("Real")
            if real is not None:
                units[v.get("name")] = real.get("unit")
        elif v.tag == "Float64":
            units[v.get("name")] = v.get("unit")
    assert units and all(u in defined for u in units.values()), {n: u for n, u in units.items() if u not in defined}
    expect = {"mpf": {"u.vx": "m/s", "y.ay": "m/s2", "Cf_y": "N/rad", "Cx": "N", "vehicle.mass": "kg",
                      "vehicle.yaw_inertia": "kg.m2", "estimator_rate": "Hz", "b_yaw_rate": "rad/s", "ess": "1"},
              "combined": {"mu_f[1]": "1", "friction_t": "s", "alpha_f_min": "rad"},
              "driver": {"vx": "m/s", "drive_torque": "N.m", "delta": "rad"}}[name]
    assert {n: units[n] for n in expect} == expect
    if name != "driver":
        assert defined["N/rad"] == {"kg": 1, "m": 1, "s": -2, "rad": -1} and defined["Hz"] == {"s": -1}


@pytest.mark.parametrize("fmi", ["2", "3"])
def test_outputs_at_the_start_time_are_the_prior(python_fmu, snow, fmi):  # noqa: F811
    sc, params, _ = snow
    prior = _prior_estimate(_python_estimator(sc), math.nan)
    with FMUHost(python_fmu("mpf", fmi)) as host:
        host.initialize(params)
        out = host.get(["t", "samples", "active", "vx", "vy", "yaw_rate", "Cf_y", "Cr_y", "Cf_y_std", "Cr_y_std",
                        "Cf_y_sigma", "ess", "vx_std", "vy_std", "beta"])
    assert out["t"] == 0.0 and out["samples"] == 0 and not out["active"]
    assert all(math.isfinite(x) for x in out.values()), out
    assert (out["Cf_y"], out["Cr_y"], out["vy"], out["ess"]) == (prior.Cf_y, prior.Cr_y, prior.vy, prior.ess)
    assert abs(out["Cf_y"] / sc.vehicle.Cf_y - 1.0) < 0.5  # around the nominal stiffness


@pytest.mark.parametrize("fmi", ["2", "3"])
@pytest.mark.parametrize("params, inputs, expect", [
    ({"model": 2}, {"u.vx": -3.0}, "input u.vx = -3.0 m/s at t = 0 s: the lateral model needs a forward speed"),
    ({}, {"u.omega_f": 60.0, "u.omega_r": -1.0}, "input u.omega_r = -1.0 rad/s at t = 0 s: the full model"),
    ({"model": 2}, {"u.vx": 20.0, "y.ay": math.inf}, "input y.ay = inf m/s2 at t = 0 s is not finite"),
])
def test_impossible_inputs_are_refused_naming_the_variable(python_fmu, fmi, params, inputs, expect):
    """An impossible input: the step is refused (Discard: pythonfmu returns no Error from a step) with
    the state unchanged and the reason in the log; the master may go on with possible inputs."""
    with FMUHost(python_fmu("mpf", fmi)) as host:
        host.initialize(params)
        before = host.get(["samples", "Cf_y", "vy"])
        with pytest.raises(FMICallException, match="status 2"):
            host.step(0.01, inputs)
        assert any(expect in m for m in host.errors()), host.messages
        assert host.get(["samples", "Cf_y", "vy"]) == before


@pytest.mark.parametrize("fmi", ["2", "3"])
@pytest.mark.parametrize("params, zeros", [({}, {}), ({"model": 2}, {"u.vx": 0.0, "y.ay": 0.1})])
def test_unconnected_zero_speeds_are_skipped_with_one_warning(python_fmu, fmi, params, zeros):
    """A master's first steps before its connectors carry values send zeros: those samples are
    skipped (outputs hold the prior), one warning names the inputs, and the first sample with a
    speed is processed as the first sample of an instance that never saw the zeros."""
    sample = {"u.vx": 20.0, "u.omega_f": 60.0, "u.omega_r": 60.0, "y.ay": 0.1, "y.yaw_rate": 0.01}
    names = ["samples", "Cf_y", "Cr_y", "vy", "yaw_rate"]
    with FMUHost(python_fmu("mpf", fmi)) as fresh:
        fresh.initialize(params)
        prior = fresh.get(names)
        fresh.time = 0.03  # its first step starts where the other's zeros end
        fresh.step(0.01, sample)
        want = fresh.get(names)
    with FMUHost(python_fmu("mpf", fmi)) as host:
        host.initialize(params)
        for _ in range(3):
            host.step(0.01, zeros)
            assert host.get(names) == prior
        warnings = [m for s, m in host.messages if s == 1]
        assert len(warnings) == 1 and "samples from t = 0 s skipped" in warnings[0], host.messages
        host.step(0.01, sample)  # the zeros left no trace
        assert host.get(names) == want


@pytest.mark.parametrize("fmi", ["2", "3"])
@pytest.mark.parametrize("name, value, expect", [
    ("vehicle.mass", math.nan, "parameter vehicle.mass: nan is not finite [kg]"),
    ("vehicle.Cf_y", math.inf, "parameter vehicle.Cf_y: inf is not finite [N/rad]"),
    ("t_first", math.nan, "parameter t_first: nan is not finite [s]"),
])
def test_non_finite_parameters_are_refused_naming_the_parameter(python_fmu, fmi, name, value, expect):
    with FMUHost(python_fmu("mpf", fmi)) as host:
        with pytest.raises(FMICallException):
            host.initialize({name: value})
        assert any(expect in m for m in host.errors()), host.messages


def test_missing_samples_are_not_refused(python_fmu):
    """NaN marks a missing sample (a sensor the car lacks): the lateral model with v^X given
    runs without wheel speeds or a^X."""
    with FMUHost(python_fmu("mpf", "2")) as host:
        host.initialize({"model": 2})
        for _ in range(5):
            host.step(0.01, {"u.vx": 20.0, "u.omega_f": math.nan, "u.omega_r": math.nan, "y.ax": math.nan,
                             "y.ay": 0.2, "u.delta": 0.01})
        assert host.get(["samples"])["samples"] == 5 and not host.errors()


@pytest.mark.parametrize("fmi", ["2", "3"])
def test_state_restores_into_an_instance_that_was_only_instantiated(python_fmu, snow, fmi):  # noqa: F811
    """As fmusim's --initial-fmu-state-file does: SetFMUstate right after instantiation,
    then doStep; the steps equal those after the state in the original instance."""
    _, params, stream = snow
    with FMUHost(python_fmu("mpf", fmi)) as host:
        host.initialize(params)
        _run_fmu(host, stream, 0, 60)
        data = host.serialize(host.get_state())
        first = _run_fmu(host, stream, 60, 80)
    with FMUHost(python_fmu("mpf", fmi), "fresh") as fresh:
        fresh.set_state(fresh.deserialize(data, 0.6))
        np.testing.assert_array_equal(_run_fmu(fresh, stream, 60, 80), first)


def test_cli_builds_fmi2_and_fmi3_of_every_fmu_all_validated(capsys):
    from tirefilter.cli import main
    from tirefilter.cosim.fmu import BUILD_DIR

    assert main(["fmu", "build", "all"]) == 0
    out = capsys.readouterr().out
    for line in ("built vehicle FMU (FMI 2.0)", "built vehicle FMU (FMI 3.0)",
                 "built estimator FMU mpf (FMI 2.0, pythonfmu)", "built estimator FMU mpf (FMI 3.0, pythonfmu3)",
                 "built estimator FMU combined (FMI 3.0, pythonfmu3)", "built driver FMU of snow-sine (FMI 3.0)",
                 "built SSP of snow-sine", "validated 8 FMUs with fmpy.validation.validate_fmu: no problems"):
        assert line in out, out
    for name in ("TirefilterVehicle_fmi2", "TirefilterVehicle_fmi3", "TirefilterMPF", "TirefilterMPF_fmi3",
                 "TirefilterFriction", "TirefilterFriction_fmi3", "TirefilterDriver", "TirefilterDriver_fmi3"):
        assert validate_fmu(str(BUILD_DIR / f"{name}.fmu")) == [], name
