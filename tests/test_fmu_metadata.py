"""The vehicle FMU as importing tools see it: the model structure derived from the
equations (checked by perturbing every input), units, the token, variabilities, refused
steps, the serialized state, and the defects a second probe found (each test here failed
on the FMU before its fix)."""

from __future__ import annotations

import ctypes
import dataclasses
import re
import shutil
import subprocess
import sys
import textwrap
import xml.etree.ElementTree as ET
import zipfile

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.fmi1 import FMICallException

from tirefilter.cosim.fmu import INPUT_NAMES, VehicleFMU, variable_table
from tirefilter.vehicle_fmu.build import fmi_headers_dir

H = 0.01  # s: the default sample period
PERTURB = {"delta": 0.03, "drive_torque": 300.0, "brake_torque": 200.0, "surface": 0.8, "bank": 0.05}
BASE_U = [0.02, 100.0, 0.0, 1.0, 0.0]


def _outputs(fmu: VehicleFMU) -> dict[str, float]:
    return dict(zip(fmu.output_names, fmu.outputs().copy()))


def _moved_at_once(version: str, params: dict) -> dict[str, set[str]]:
    """input -> outputs that change when only that input changes, at a sample instant after
    a few steps (no time passes between the two reads)."""
    moved = {}
    with VehicleFMU(version) as fmu:
        fmu.reset(params)
        for k in range(3):
            fmu.step(k * H, H, BASE_U)
        fmu.set_inputs(BASE_U)
        y0 = _outputs(fmu)
        for j, name in enumerate(INPUT_NAMES):
            u = list(BASE_U)
            u[j] = PERTURB[name]
            fmu.set_inputs(u)
            y1 = _outputs(fmu)
            moved[name] = {o for o in y0 if y1[o] != y0[o]}
            fmu.set_inputs(BASE_U)
            assert _outputs(fmu) == y0  # the outputs are a function of the inputs at the instant
    return moved


@pytest.mark.parametrize("version", ["2", "3"])
def test_dependencies_are_what_perturbing_the_inputs_moves(fmu_paths, version):
    """Each output's `dependencies` are exactly the inputs that move it at once: the union
    over linear tires and Pacejka tires (combined slip couples F^X to the steer) with body
    roll on (the lateral accelerometer picks up the bank through the roll)."""
    md = read_model_description(str(fmu_paths[version]))
    by_vr = {v.valueReference: v.name for v in md.modelVariables}
    declared = {}
    for u in md.outputs:
        assert u.dependencies is not None and len(u.dependencies) == len(u.dependenciesKind)
        assert set(u.dependenciesKind) <= {"dependent"}
        declared[u.variable.name] = {d.name if hasattr(d, "name") else by_vr[d] for d in u.dependencies}
    assert len(declared) == 40
    moved: dict[str, set[str]] = {o: set() for o in declared}
    for params in ({"roll_gradient": 0.01, "imu_x": 0.3, "imu_y": 0.1},
                   {"tire_model": 1, "roll_gradient": 0.01, "imu_x": 0.3, "imu_y": 0.1}):
        for name, outs in _moved_at_once(version, params).items():
            for o in outs:
                moved[o].add(name)
    assert moved == declared
    # an importing tool's example: the steer moves these at once, and not vx or the yaw rate
    assert {"alpha_f", "ax", "ay", "Fy_f", "yaw_acc", "delta_meas"} <= {o for o, d in declared.items() if "delta" in d}
    assert not declared["vx"] and not declared["yaw_rate"]
    assert not any(declared[o] & {"drive_torque", "brake_torque"} for o in declared)  # through the wheel spin only


def _unit_exponents(name: str) -> dict[str, int]:
    """Base-unit exponents of a unit string like "kg.m2", "m/s2", "N.s2/m2", "rad2/s3"."""
    base = {"kg": {"kg": 1}, "m": {"m": 1}, "s": {"s": 1}, "rad": {"rad": 1}, "N": {"kg": 1, "m": 1, "s": -2}}
    out: dict[str, int] = {}
    if name == "1":
        return out
    num, *den = name.split("/")
    for sign, part in [(1, num)] + [(-1, d) for d in den]:
        for factor in part.split("."):
            sym, exp = re.fullmatch(r"([A-Za-z]+)(-?\d+)?", factor).groups()
            for k, e in base[sym].items():
                out[k] = out.get(k, 0) + sign * e * int(exp or 1)
    return {k: e for k, e in out.items() if e}


@pytest.mark.parametrize("version", ["2", "3"])
def test_units_have_integer_exponents_that_match_their_names(fmu_paths, version):
    with zipfile.ZipFile(fmu_paths[version]) as zf:
        root = ET.fromstring(zf.read("modelDescription.xml"))
    units = root.findall("UnitDefinitions/Unit")
    assert units
    for unit in units:
        base = unit.find("BaseUnit")
        got = {k: int(e) for k, e in (base.attrib.items() if base is not None else [])}  # int(): integer exponents
        assert got == _unit_exponents(unit.get("name")), unit.get("name")
    md = read_model_description(str(fmu_paths[version]))
    units_of = {v.name: v.unit for v in md.modelVariables}
    assert units_of["bias_q_ax"] == "m2/s5" and units_of["bias_q_yaw_rate"] == "rad2/s3"


def test_bias_intensity_is_a_variance_per_second(fmu_paths):
    """The gyro bias after n samples of a pure random walk of intensity q has variance n q Ts."""
    q, n, runs = 4e-6, 200, 300
    finals = []
    with VehicleFMU("2") as fmu:
        for seed in range(runs):
            fmu.reset({"seed": seed, "bias_q_yaw_rate": q, "stiffness_dev_std": 0.0})
            for k in range(n):
                y = fmu.step(k * H, H, [0.0, 0.0, 0.0, 1.0, 0.0])
            finals.append(y[fmu.output_names.index("true_b_yaw_rate")])
    var = np.var(finals, ddof=1)
    # chi-square with 299 dof: the sample variance lies within +-25 % of n q Ts with probability > 0.99
    assert abs(var / (n * q * H) - 1.0) < 0.25, var


def test_token_is_a_hash_of_the_variable_table(fmu_paths):
    table = variable_table()
    md2 = read_model_description(str(fmu_paths["2"]))
    md3 = read_model_description(str(fmu_paths["3"]))
    assert md2.guid == md3.instantiationToken == table.instantiation_token()
    original = table.VARIABLES[0]
    try:
        table.VARIABLES[0] = dataclasses.replace(original, start=2051.0)
        assert table.instantiation_token() != md2.guid
        table.VARIABLES[0] = dataclasses.replace(original, unit="g")
        assert table.instantiation_token() != md2.guid
    finally:
        table.VARIABLES[0] = original
    assert table.instantiation_token() == md2.guid


@pytest.mark.parametrize("version", ["2", "3"])
def test_sampled_outputs_are_discrete_and_held_between_samples(fmu_paths, version):
    md = read_model_description(str(fmu_paths[version]))
    var = {v.name: v.variability for v in md.modelVariables if v.causality == "output"}
    sampled = {"ax_meas", "ay_meas", "yaw_rate_meas", "omega_f_meas", "omega_r_meas", "delta_meas", "true_b_ax",
               "true_b_ay", "true_b_yaw_rate"}
    assert {n for n, v in var.items() if v == "discrete"} == sampled
    steer = lambda t: [0.02 * np.sin(2.0 * t), 100.0, 0.0, 1.0, 0.0]  # noqa: E731
    with VehicleFMU(version) as fmu:
        fmu.reset({"sigma_ay": 0.05, "bias_q_ay": 1e-4})
        rows, t = [], 0.0
        for k in range(40):  # 2.5 ms steps: 4 per sample
            rows.append(fmu.step(t, 0.0025, steer(t)).copy())
            t += 0.0025
    rows = np.array(rows)
    names = fmu.output_names
    for name in ("ay_meas", "delta_meas", "true_b_ay"):
        y = rows[:, names.index(name)]
        for k in range(0, 36, 4):  # rows k..k+2 (t = k/4 h + 2.5, 5, 7.5 ms): the sample of t = k/4 h, held;
            assert y[k] == y[k + 1] == y[k + 2] != y[k + 3], (name, k)  # row k + 3 ends on the next sample
    ay = rows[:, names.index("ay")]
    assert np.all(np.diff(ay[:8]) != 0)  # the true value is continuous


@pytest.mark.parametrize("version", ["2", "3"])
@pytest.mark.parametrize("h", [-0.01, float("nan"), float("inf"), -float("inf")])
def test_negative_or_non_finite_step_is_refused_with_a_message(fmu_paths, version, h):
    code = textwrap.dedent(f"""
        from tirefilter.cosim.fmu import VehicleFMU
        from tirefilter.errors import FMUError
        with VehicleFMU({version!r}) as fmu:
            fmu.reset({{}})
            fmu.step(0.0, 0.01, [0.0, 0.0, 0.0, 1.0, 0.0])
            try:
                fmu.do_step(0.01, float({str(h)!r}))
                print("accepted")
            except FMUError as exc:
                print("refused:", exc)
            print("time", fmu._slave.getFloat64([0])[0] if {version!r} == "3" else "n/a")
            fmu.do_step(0.01, 0.01)  # the instance is still usable
            print("then ok")
    """)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert "refused:" in proc.stdout and "must be finite, the step size not negative" in proc.stdout, proc.stdout
    assert "then ok" in proc.stdout, proc.stderr
    if version == "3":
        assert "time 0.01" in proc.stdout


def _corrupt(blob: bytes, at: int) -> bytes:
    b = bytearray(blob)
    b[at] ^= 0x01
    return bytes(b)


@pytest.mark.parametrize("version", ["2", "3"])
def test_serialized_state_has_a_checked_header(fmu_paths, version):
    with VehicleFMU(version) as fmu:
        fmu.reset({})
        for k in range(5):
            fmu.step(k * H, H, BASE_U)
        blob = fmu.serialize_state(fmu.get_state())
        assert blob[:8] == b"TFVSTATE"
        assert int.from_bytes(blob[8:12], sys.byteorder) == 1  # format version
        assert int.from_bytes(blob[16:24], sys.byteorder) == len(blob)
        cases = {"magic": _corrupt(blob, 0), "format version 2": blob[:8] + (2).to_bytes(4, sys.byteorder) + blob[12:],
                 "bytes given": blob[:-8], "another variable table": _corrupt(blob, 24),
                 "checksum mismatch": _corrupt(blob, len(blob) - 100)}
        for expect, bad in cases.items():
            fmu.messages.clear()
            with pytest.raises(FMICallException):
                fmu.deserialize_state(bad)
            assert any(expect in m for m in fmu.messages), (expect, fmu.messages)
        y = fmu.outputs().copy()
        fmu.step(5 * H, H, BASE_U)
        fmu.set_state(fmu.deserialize_state(blob))
        np.testing.assert_array_equal(fmu.outputs(), y)


@pytest.mark.parametrize("version", ["2", "3"])
def test_outputs_in_initialization_mode_are_the_initial_values(fmu_paths, version):
    with VehicleFMU(version) as fmu:
        s, vr = fmu._slave, fmu._vars
        refs = [vr[n].valueReference for n in ("vx", "omega_f", "alpha_f", "Fz_f")]
        if version == "2":
            s.setupExperiment(startTime=0.0)
            s.enterInitializationMode()
            s.setReal([vr["vx0"].valueReference, vr["wheel_radius"].valueReference], [25.0, 0.4])
            got = s.getReal(refs)
        else:
            s.enterInitializationMode(startTime=0.0)
            s.setFloat64([vr["vx0"].valueReference, vr["wheel_radius"].valueReference], [25.0, 0.4])
            got = s.getFloat64(refs)
        s.exitInitializationMode()
        fmu._initialized = True
        after = list(fmu.outputs()[[fmu.output_names.index(n) for n in ("vx", "omega_f", "alpha_f", "Fz_f")]])
    assert got[0] == 25.0 and got[1] == 25.0 / 0.4 and got[3] > 0
    assert got == after


@pytest.mark.parametrize("version", ["2", "3"])
def test_restored_state_serves_the_outputs_of_its_inputs(fmu_paths, version):
    """Saved right after an input changed (outputs not yet read), restored: the outputs are
    those of the saved inputs, not the ones computed before the input changed."""
    with VehicleFMU(version) as fmu:
        fmu.reset({})
        for k in range(5):
            fmu.step(k * H, H, [0.1, 0.0, 0.0, 1.0, 0.0])
        old = _outputs(fmu)["alpha_f"]
        fmu.set_inputs([0.2, 0.0, 0.0, 1.0, 0.0])
        state = fmu.get_state()
        fresh = _outputs(fmu)["alpha_f"]
        fmu.step(5 * H, H, [0.0, 0.0, 0.0, 1.0, 0.0])
        fmu.set_state(state)
        restored = _outputs(fmu)["alpha_f"]
    assert abs(fresh - old - 0.1) < 1e-12
    assert restored == fresh


def test_fmi3_event_mode_is_refused_with_a_message(fmu_paths):
    from fmpy import extract
    from fmpy.fmi3 import FMU3Slave

    md = read_model_description(str(fmu_paths["3"]))
    assert md.coSimulation.hasEventMode is False
    messages = []
    unzip = extract(str(fmu_paths["3"]))
    try:
        slave = FMU3Slave(guid=md.instantiationToken, unzipDirectory=unzip, modelIdentifier="TirefilterVehicle",
                          instanceName="v")
        with pytest.raises(Exception, match="instantiate"):
            slave.instantiate(eventModeUsed=True, logMessage=lambda env, status, cat, msg: messages.append(msg))
        assert any(b"eventModeUsed = true" in m and b"hasEventMode = false" in m for m in messages), messages
    finally:
        shutil.rmtree(unzip, ignore_errors=True)


def test_fmi3_unsupported_calls_log_why_and_zero_variables_succeed(fmu_paths):
    from fmpy.fmi3 import fmi3ValueReference

    with VehicleFMU("3") as fmu:
        fmu.reset({})
        s = fmu._slave
        f = s.dll.fmi3GetBoolean
        f.restype = ctypes.c_int
        values = (ctypes.c_bool * 1)()
        assert f(s.component, (fmi3ValueReference * 0)(), 0, values, 0) == 0  # zero variables: OK
        assert not fmu.messages
        assert f(s.component, (fmi3ValueReference * 1)(1), 1, values, 1) == 3
        assert any("fmi3GetBoolean is not supported" in m for m in fmu.messages), fmu.messages
        fmu.messages.clear()
        g = s.dll.fmi3EnterEventMode
        g.restype = ctypes.c_int
        assert g(s.component) == 3 and any("fmi3EnterEventMode is not supported" in m for m in fmu.messages)
        fmu.messages.clear()
        buf = (ctypes.c_double * 2)()
        get = s.dll.fmi3GetFloat64
        get.restype = ctypes.c_int
        assert get(s.component, (fmi3ValueReference * 1)(1), 1, buf, 2) == 3
        assert any("nValues = 2, but 1 value references" in m for m in fmu.messages), fmu.messages


@pytest.mark.parametrize("version", ["2", "3"])
def test_falling_below_v_min_is_a_discard_that_terminates(fmu_paths, version):
    with VehicleFMU(version) as fmu:
        fmu.reset({"vx0": 2.0, "v_min": 1.0})
        s = fmu._slave
        with pytest.raises(FMICallException) as info:
            for k in range(300):  # full brake until the speed falls below v_min
                fmu.set_inputs([0.0, 0.0, 3000.0, 1.0, 0.0])
                s.doStep(k * H, H)
        assert info.value.status == 2  # fmi2Discard / fmi3Discard
        assert any("fell below v_min" in m for m in fmu.messages)
        if version == "2":
            status = ctypes.c_int()
            f = s.dll.fmi2GetBooleanStatus
            f.restype = ctypes.c_int
            assert f(s.component, 3, ctypes.byref(status)) == 0 and status.value == 1  # fmi2Terminated
        fmu._initialized = False  # the instance is done; close() frees it without terminate


def test_fmi3_sources_build_from_their_build_description(fmu_paths, tmp_path):
    """The shipped sources compile by buildDescription.xml alone, and the library they make
    gives the shipped binary's outputs."""
    cc = shutil.which("cc") or shutil.which("gcc")
    if not cc:
        pytest.skip("needs a C compiler")
    unzipped = tmp_path / "fmu"
    with zipfile.ZipFile(fmu_paths["3"]) as zf:
        zf.extractall(unzipped)
    src = unzipped / "sources"
    root = ET.parse(src / "buildDescription.xml").getroot()
    conf = root.find("BuildConfiguration")
    assert conf.get("modelIdentifier") == "TirefilterVehicle"
    files = [str(src / f.get("name")) for f in conf.iter("SourceFile")]
    libs = [f"-l{lib.get('name')}" for lib in conf.iter("Library")]
    lib = unzipped / "binaries" / "x86_64-linux" / "TirefilterVehicle.so"
    lib.unlink()
    subprocess.run([cc, "-std=c99", "-shared", "-fPIC", f"-I{src}", f"-I{fmi_headers_dir()}",
                    "-o", str(lib), *files, *libs], check=True, capture_output=True)
    rebuilt = tmp_path / "rebuilt.fmu"
    with zipfile.ZipFile(rebuilt, "w") as zf:
        for p in sorted(unzipped.rglob("*")):
            if p.is_file():
                zf.write(p, p.relative_to(unzipped).as_posix())
    out = {}
    for name, path in (("shipped", fmu_paths["3"]), ("rebuilt", rebuilt)):
        with VehicleFMU("3", path) as fmu:
            fmu.reset({})
            for k in range(20):
                y = fmu.step(k * H, H, BASE_U)
            out[name] = y.copy()
    np.testing.assert_allclose(out["rebuilt"], out["shipped"], rtol=1e-12)
