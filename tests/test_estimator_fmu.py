"""The estimator exported as an FMU (pythonfmu), its driver FMU and the SSP of snow-sine.

Exactness is shown by reduction: the FMU's outputs equal the Python estimator's on the same
samples (bit for bit, checked to 1e-9), its restored state reproduces the steps after it,
and the SSP's vehicle truth equals the in-process co-simulation's until the master's
coupling can make a difference, which is then bounded (module docstring of
tirefilter.fmu_export.ssp).
"""

from __future__ import annotations

import dataclasses
import math
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

pytest.importorskip("pythonfmu")

from tirefilter.io.results import ESTIMATE_COLUMNS, INPUT_TRUTH_COLUMNS, truth_column  # noqa: E402
from tirefilter.estimators import build_estimator  # noqa: E402
from tirefilter.estimators.base import Inputs, Measurement  # noqa: E402
from tirefilter.fmu_export.host import FMUHost  # noqa: E402
from tirefilter.fmu_export.ssp import scenario_run_parameters  # noqa: E402
from tirefilter.runs import spawn_seeds  # noqa: E402
from tirefilter.scenarios import load_scenario  # noqa: E402

SEED = 5
N = 40
OUT = ("t", "vx", "vy", "yaw_rate", "Cf_y", "Cr_y", "Cx", "Cf_y_std", "Cr_y_std", "Cx_std", "Cf_y_sigma",
       "b_ax", "b_ay", "b_yaw_rate", "ess", "vy_std")
IN_NAMES = ("u.delta", "u.omega_f", "u.omega_r", "u.vx", "y.ax", "y.ay", "y.yaw_rate")


@pytest.fixture(scope="module")
def fmus(python_fmu):
    return {"estimator": python_fmu("mpf"), "driver": python_fmu("driver")}


@pytest.fixture(scope="module")
def snow():
    """snow-sine: the estimator FMU's parameters and options for one run, and a sample
    stream (the in-process co-simulation's sensors, 3 s) to drive it with."""
    from tirefilter.cosim.run import run_scenario

    sc = load_scenario("snow-sine")
    _, est_p, _, options = scenario_run_parameters(sc, seed=SEED, particles=N)
    short = dataclasses.replace(sc, duration=3.0)
    _, rows = run_scenario(short, seed=SEED, keep_rows=True)
    from tirefilter.cosim.fmu import VehicleFMU

    with VehicleFMU() as fmu:
        names = list(ESTIMATE_COLUMNS) + [truth_column(n) for n in fmu.output_names] + list(INPUT_TRUTH_COLUMNS)
    cols = ("meas_delta", "meas_omega_f", "meas_omega_r", "true_vx", "meas_ax", "meas_ay", "meas_yaw_rate")
    stream = rows[:, [names.index(c) for c in cols]].copy()
    return sc, dict(est_p, t_first=0.0, config=options), stream


def _python_estimator(sc):
    est = build_estimator("mpf", sc, model="auto", particles=N, config={})
    est.reset(spawn_seeds(SEED)[1])
    return est


def _step_python(est, k, row, h=0.01):
    return est.step(k * h, Inputs(*row[:4]), Measurement(*row[4:]))


def _run_fmu(host, stream, k0, k1, h=0.01):
    out = []
    for k in range(k0, k1):
        host.step(h, dict(zip(IN_NAMES, stream[k])))
        out.append([host.get(OUT)[n] for n in OUT])
    return np.array(out)


def test_fmus_validate(fmus):
    from fmpy.validation import validate_fmu

    for path in fmus.values():
        assert validate_fmu(str(path)) == []


def test_fmu_equals_python_estimator_nan_samples_included(fmus, snow):
    """Same samples -> same estimates; NaN samples (missing) behave as in Python."""
    sc, params, stream = snow
    stream = stream.copy()
    stream[40:45, 5] = np.nan  # a^Y missing
    stream[60, 4:] = np.nan  # the whole IMU sample missing
    stream[80:82, 1] = np.nan  # a wheel speed missing (held)
    est = _python_estimator(sc)
    with FMUHost(fmus["estimator"]) as host:
        host.initialize(params)
        got = _run_fmu(host, stream, 0, 150)
    want = []
    for k in range(150):
        e = _step_python(est, k, stream[k])
        row = dict(zip(ESTIMATE_COLUMNS, [k * 0.01, e.active, e.vx, e.vy, e.yaw_rate, e.beta, e.Cf_y, e.Cr_y, e.Cx,
                                          e.Cf_y_std, e.Cr_y_std, e.Cx_std, e.Cf_y_sigma, e.Cr_y_sigma, e.Cx_sigma,
                                          e.b_ax, e.b_ay, e.b_yaw_rate, e.ess]))
        row["vy_std"] = e.state_std[1]
        want.append([row[n] for n in OUT])
    want = np.array(want)
    assert np.all(np.isfinite(got))
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=0)


def test_state_save_step_restore_step_again(fmus, snow):
    _, params, stream = snow
    with FMUHost(fmus["estimator"]) as host:
        host.initialize(params)
        _run_fmu(host, stream, 0, 100)
        state = host.get_state()
        data = host.serialize(state)
        first = _run_fmu(host, stream, 100, 140)
        host.set_state(state)
        again = _run_fmu(host, stream, 100, 140)
        host.set_state(host.deserialize(data, state[1]))
        from_bytes = _run_fmu(host, stream, 100, 140)
    np.testing.assert_array_equal(again, first)
    np.testing.assert_array_equal(from_bytes, first)
    # the serialised state restores into a fresh instance too
    with FMUHost(fmus["estimator"], "other") as other:
        other.initialize(params)
        other.set_state(other.deserialize(data, state[1]))
        np.testing.assert_array_equal(_run_fmu(other, stream, 100, 140), first)


def test_state_bytes_refuse_foreign_pickles():
    import pickle

    from tirefilter.fmu_export.state import FORMAT, MAGIC, StateError, state_from_bytes

    evil = MAGIC + bytes([FORMAT]) + pickle.dumps({"x": os.system})
    with pytest.raises(StateError, match="posix.system|os.system|nt.system"):
        state_from_bytes(evil)
    with pytest.raises(StateError, match="header"):
        state_from_bytes(b"garbage")
    # a state of an older format (other attributes) is refused by its header, before unpickling
    with pytest.raises(StateError, match=f"FMU state format 1, this FMU reads format {FORMAT}"):
        state_from_bytes(MAGIC + bytes([1]) + pickle.dumps({}))


@pytest.mark.parametrize("name, value, expect", [
    ("vehicle.mass", -1.0, "parameter vehicle.mass: -1.0 is out of range"),
    ("vehicle.drive", 7, "parameter vehicle.drive: 7 is out of range"),
    ("forgetting", 1.5, "parameter forgetting: 1.5 is out of range"),
    ("particles", 0, "parameter particles: 0 is out of range"),
    ("estimator_rate", 0.0, "parameter estimator_rate: 0.0 is out of range"),
    ("model", 3, "parameter model: 3 is out of range"),
    ("config", "[mpf]\ninit_std = -0.5\n", "init_std"),
    ("config", "[mpf\n", "parameter config: not valid TOML"),
])
def test_bad_parameters_rejected_at_initialisation(fmus, name, value, expect):
    from fmpy.fmi1 import FMICallException

    with FMUHost(fmus["estimator"]) as host:
        with pytest.raises(FMICallException):
            host.initialize({name: value})
        assert any(expect in m for m in host.errors()), host.messages


def test_estimator_failure_is_logged_with_the_sample_time(fmus):
    """The lateral model without any v^X: the Python estimator's error, through the FMI logger."""
    from fmpy.fmi1 import FMICallException

    with FMUHost(fmus["estimator"]) as host:
        host.initialize({"model": 2})
        with pytest.raises(FMICallException):
            host.step(0.01, {"u.vx": math.nan, "y.ay": 0.1})
        assert any("the estimator failed at t = 0 s" in m and "vx" in m for m in host.errors()), host.messages


def test_rerun_recording_parameter(fmus, snow, tmp_path):
    _, params, stream = snow
    rrd = tmp_path / "est.rrd"
    with FMUHost(fmus["estimator"]) as host:
        host.initialize(dict(params, rrd=str(rrd)))
        got = _run_fmu(host, stream, 0, 30)
    from test_cosim import _rrd_series

    t, v = _rrd_series(rrd, "/estimator/mpf/stiffness/Cf_y")
    np.testing.assert_allclose(t, got[:, 0], atol=1e-9)
    np.testing.assert_allclose(v, got[:, OUT.index("Cf_y")] * 1e-3, rtol=1e-12)  # recorded in kN/rad
    # the posterior snapshots too, every log_every-th sample as in `tirefilter run`
    from test_viz import read_recording
    from tirefilter.viz.options import RecordingOptions

    rec = read_recording(rrd)
    every = RecordingOptions().log_every
    for entity in ("/estimator/mpf/density/Cf_y", "/estimator/mpf/particles/stiffness"):
        assert entity in rec, sorted(rec)
        assert len([r for r in rec[entity] if r["t"] is not None]) == len(range(0, 30, every)), entity


def test_failed_load_prints_requirements(fmus):
    """Without scipy the FMU cannot load: the tool's process gets the requirements."""
    code = textwrap.dedent(f"""
        import sys
        from tirefilter.fmu_export.host import FMUHost
        sys.modules["scipy"] = None  # a package the FMU needs and the tool (fmpy) does not
        for name in [m for m in sys.modules if m == "tirefilter" or m.startswith("tirefilter.")]:
            del sys.modules[name]
        try:
            FMUHost({str(fmus["estimator"])!r})
        except Exception as exc:
            print("load failed:", type(exc).__name__)
    """)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert "load failed: FMUError" in proc.stdout, proc.stderr
    assert "TirefilterMPF FMU cannot load" in proc.stderr
    assert "scipy" in proc.stderr.splitlines()[0]  # what is missing, then what is needed
    assert "CPython >= 3.11" in proc.stderr and "numpy" in proc.stderr and "LD_PRELOAD" in proc.stderr


# ---- the SSP: driver -> vehicle FMU -> estimator FMU, run by fmpy's simulate_ssp ------------
SSP_STOP = 21.5  # s: 20 s straight, then the sine steering starts and the speed hold acts


@pytest.fixture(scope="module")
def ssp_path(fmu_paths, tmp_path_factory):
    from tirefilter.fmu_export.ssp import build_ssp

    return build_ssp("snow-sine", tmp_path_factory.mktemp("ssp") / "snow-sine.ssp", seed=SEED, particles=N,
                     stop_time=SSP_STOP)


@pytest.fixture(scope="module")
def ssp_run(ssp_path):
    from tirefilter.cosim.run import run_scenario
    from tirefilter.fmu_export.ssp import run_ssp

    r = run_ssp(ssp_path)
    sc = load_scenario("snow-sine")
    _, rows = run_scenario(dataclasses.replace(sc, duration=SSP_STOP), seed=SEED, keep_rows=True)
    from tirefilter.cosim.fmu import VehicleFMU

    with VehicleFMU() as fmu:
        names = list(ESTIMATE_COLUMNS) + [truth_column(n) for n in fmu.output_names] + list(INPUT_TRUTH_COLUMNS)
    return sc, r, rows, names


def test_ssp_estimates_equal_python_estimator_on_its_samples(ssp_run):
    """The estimator FMU inside the SSP is the Python estimator: fed the samples the master
    delivered (row j-1 holds the inputs of step j), it gives the same estimates to 1e-9."""
    sc, r, _, _ = ssp_run
    h = sc.communication_step
    est = _python_estimator(sc)
    # t_first: step 0 carries zeros and is not processed; the outputs hold the prior
    from tirefilter.fmu_export.slaves import _prior_estimate

    prior = _prior_estimate(est, math.nan)
    assert r["estimator.samples"][0] == 0 and r["estimator.Cf_y"][0] == prior.Cf_y and r["estimator.vy"][0] == prior.vy
    got, want = [], []
    for j in range(1, len(r)):
        q = r[j - 1]
        e = _step_python(est, j, [q["estimator." + n] for n in IN_NAMES], h)
        want.append([j * h, e.Cf_y, e.Cr_y, e.Cx, e.vx, e.vy, e.b_ay, e.ess, e.Cf_y_std])
        got.append([r[j]["estimator." + n] for n in ("t", "Cf_y", "Cr_y", "Cx", "vx", "vy", "b_ay", "ess",
                                                       "Cf_y_std")])
    assert len(got) == round(SSP_STOP / h) - 1
    np.testing.assert_allclose(np.array(got), np.array(want), rtol=1e-9, atol=0)


def test_ssp_runs_without_its_parameter_set(ssp_path):
    """fmpy's simulate_ssp on its own (no parameter set, as a user runs an SSP first): the estimator's
    first step gets the unconnected zeros, skips them with a warning and then estimates."""
    from fmpy.ssp.simulation import simulate_ssp

    r = simulate_ssp(str(ssp_path), stop_time=0.3, step_size=0.01)
    assert r["estimator.samples"][0] == 0 and r["estimator.samples"][-1] == len(r) - 1
    assert np.all(np.isfinite(r["estimator.Cf_y"])) and np.all(r["estimator.vx"][1:] > 1.0)


def test_ssp_driver_plays_the_profile(ssp_run):
    """Driver outputs after step j are the inputs of t_{j+1}: the open-loop profile on the
    scenario's grid exactly, plus the speed-hold PI on v^X one step old."""
    sc, r, _, _ = ssp_run
    h = sc.communication_step
    t = (np.arange(len(r)) + 1) * h
    u = sc.inputs.open_loop(t)
    np.testing.assert_array_equal(r["driver.delta"], u[:, 0])
    np.testing.assert_array_equal(r["driver.bank"], u[:, 4])
    hold = sc.inputs.speed_hold
    gain = sc.vehicle.mass * sc.vehicle.wheel_radius
    integral, torque = 0.0, []
    vx_seen = np.concatenate([[np.nan], r["vehicle.vx"][:-1]])  # what the driver had at step j
    for j in range(len(r)):
        err = 0.0 if j == 0 else float(hold.reference(t[j])) - vx_seen[j]
        integral += err * h
        torque.append(u[j, 1] + gain * (hold.kp * err + hold.ki * integral))
    np.testing.assert_allclose(r["driver.drive_torque"], torque, rtol=1e-12, atol=1e-12)


def test_ssp_truth_matches_in_process_cosimulation_within_the_coupling_bound(ssp_run):
    """Row j of the SSP holds the vehicle at t_{j+1}, row k of the in-process run the vehicle
    at t_k. While the inputs are constant (straight at the set speed, 20 s) the Jacobi
    coupling changes nothing and truth and sensors are the same bit for bit. Once the steer
    changes, two coupling effects appear: the sensors with direct feedthrough of the inputs
    (a^X, a^Y) are read before the master sets the new inputs (in-process: after), and the
    speed-hold PI sees v^X one step late. Measured over the first 1.5 s of steering:
    |d a^Y_meas| <= 0.01 m/s^2 (the steer change of one 10 ms step), |dvx| 1e-4 m/s,
    |d yaw rate| 8e-7 rad/s; the bounds below are 5-13 times those."""
    sc, r, rows, names = ssp_run
    n = len(r)
    col = {c: rows[1:n + 1, names.index(c)] for c in ("true_vx", "true_yaw_rate", "meas_ay", "true_drive_torque")}
    # the first row where the steer or the drive torque changes
    start = min(int(np.argmax(np.abs(col["true_drive_torque"]) > 0)), int(np.argmax(r["driver.drive_torque"] != 0)),
                int(np.argmax(r["driver.delta"] != 0)))
    assert 19.9 < (start + 1) * sc.communication_step < 20.5
    for name, c in (("vehicle.vx", "true_vx"), ("vehicle.yaw_rate", "true_yaw_rate"), ("vehicle.ay_meas", "meas_ay")):
        np.testing.assert_array_equal(r[name][:start], col[c][:start])
    assert np.max(np.abs(r["vehicle.vx"] - col["true_vx"])) < 1e-3
    assert np.max(np.abs(r["vehicle.yaw_rate"] - col["true_yaw_rate"])) < 1e-5
    assert np.max(np.abs(r["vehicle.ay_meas"] - col["meas_ay"])) < 0.05


def test_native_host_runs_the_fmu_with_libpython_preloaded(fmus, tmp_path):
    """A plain C host (no Python) runs the estimator FMU as the README says: libpython
    preloaded, PYTHONHOME and PYTHONPATH set; its result equals fmpy's. Without the
    preload the library cannot load (undefined Python symbols)."""
    import shutil
    import sysconfig
    import zipfile
    from pathlib import Path

    from fmpy import read_model_description

    from tirefilter.vehicle_fmu.build import fmi_headers_dir

    cc = shutil.which("cc") or shutil.which("gcc")
    libpython = Path(sysconfig.get_config_var("LIBDIR") or "") / (sysconfig.get_config_var("LDLIBRARY") or "")
    if not cc or not libpython.is_file() or libpython.suffix != ".so" and ".so." not in libpython.name:
        pytest.skip("needs a C compiler and a shared libpython")
    host = tmp_path / "host_python_fmu"
    src = Path(__file__).resolve().parents[1] / "fmu" / "tests" / "host_python_fmu.c"
    subprocess.run([cc, "-std=c99", f"-I{fmi_headers_dir()}", str(src), "-ldl", "-o", str(host)],
                   check=True, capture_output=True)
    unzipped = tmp_path / "fmu"
    with zipfile.ZipFile(fmus["estimator"]) as zf:
        zf.extractall(unzipped)
    md = read_model_description(str(fmus["estimator"]))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    import numpy

    moving = {"u.omega_f": 20.0 / 0.36, "u.omega_r": 20.0 / 0.36}  # the full model needs a positive speed
    args = [str(host), str(unzipped), "TirefilterMPF", md.guid, str(vr["y.ay"]), "0.3", str(vr["vy"]), "50",
            *[f"{vr[n]}={x!r}" for n, x in moving.items()]]
    site = str(Path(numpy.__file__).resolve().parents[1])
    base = {"PATH": os.environ.get("PATH", "/usr/bin:/bin")}
    bare = subprocess.run(args, capture_output=True, text=True, env=base, timeout=120)
    assert bare.returncode == 1 and "undefined symbol: _Py" in bare.stderr
    env = dict(base, LD_PRELOAD=str(libpython), PYTHONHOME=sys.base_prefix, PYTHONPATH=site)
    proc = subprocess.run(args, capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 0, proc.stderr
    native = float(proc.stdout.strip().splitlines()[-1].split("=")[1])
    with FMUHost(fmus["estimator"]) as h:
        h.initialize({})
        for _ in range(50):
            h.step(0.01, {"y.ay": 0.3, **moving})
        assert native == h.get(["vy"])["vy"] and math.isfinite(native)


def test_cli_builds_the_estimator_fmu(capsys):
    from fmpy.validation import validate_fmu

    from tirefilter.cli import main
    from tirefilter.cosim.fmu import BUILD_DIR

    assert main(["fmu", "build", "estimator"]) == 0
    assert "built estimator FMU mpf" in capsys.readouterr().out
    assert validate_fmu(str(BUILD_DIR / "TirefilterMPF.fmu")) == []


FRICTION_H = 0.04  # s: friction-snow's estimator sample period (the friction paper's Ts)


@pytest.fixture(scope="module")
def friction_fmu(python_fmu):
    return python_fmu("combined")


@pytest.fixture(scope="module")
def friction_snow():
    """friction-snow: the friction FMU's parameters and a 6 s sample stream of the
    in-process co-simulation's sensors (v^X from the truth: the lateral model's input)."""
    from tirefilter.cosim.fmu import VehicleFMU
    from tirefilter.cosim.run import run_scenario

    sc = load_scenario("friction-snow")
    assert sc.sample_period == FRICTION_H
    vehicle, est_p, _, _ = scenario_run_parameters(sc, seed=SEED, particles=N, model="lateral")
    _, rows = run_scenario(dataclasses.replace(sc, duration=6.0), seed=SEED, keep_rows=True)
    with VehicleFMU() as fmu:
        names = list(ESTIMATE_COLUMNS) + [truth_column(n) for n in fmu.output_names] + list(INPUT_TRUTH_COLUMNS)
    cols = ("meas_delta", "meas_omega_f", "meas_omega_r", "true_vx", "meas_ax", "meas_ay", "meas_yaw_rate")
    stream = rows[:, [names.index(c) for c in cols]].copy()
    params = dict(est_p, t_first=0.0, particles=N, friction_period=1.0, config="[gpssm]\nbasis = \"axle\"\n")
    return sc, params, stream


def _python_friction_estimator(sc, params):
    """The estimator the FMU builds, built the same way in this process: from the vehicle
    and the options (no scenario), with the FMU parameters in the [gpssm] table."""
    from tirefilter.estimators import build_log_estimator

    Ts = 1.0 / params["estimator_rate"]
    config = {"gpssm": {"basis": "axle", "forgetting": params["forgetting"], "sample_period": Ts}}
    nan2 = np.full(2, math.nan)
    est = build_log_estimator("combined", sc.vehicle, np.array([0.0, Ts]), dict.fromkeys(
        ("delta", "omega_f", "omega_r", "vx", "ax", "ay", "yaw_rate"), nan2), model="lateral", particles=N,
        config=config)
    est.reset(spawn_seeds(SEED)[1])
    return est


def test_friction_fmu_validates_and_equals_python_estimator(friction_fmu, friction_snow):
    """The combined friction estimator as an FMU: validates; its estimates and its friction
    outputs (refreshed every friction_period) equal the Python estimator's on the same
    samples; a NaN a^Y sample behaves as in Python."""
    from fmpy.validation import validate_fmu
    from tirefilter.fmu_export.variables import FRICTION_ALPHA_DEG, friction_output

    assert validate_fmu(str(friction_fmu)) == []
    sc, params, stream = friction_snow
    stream = stream.copy()
    stream[30, 5] = np.nan
    names = ["t", "vy", "yaw_rate", "Cf_y", "Cr_y", "ess", "friction_t"]
    names += [friction_output(f"mu_{a}{s}", k) for a in "fr" for s in ("", "_std") for k in FRICTION_ALPHA_DEG]
    est = _python_friction_estimator(sc, params)
    alpha = np.deg2rad(np.array(FRICTION_ALPHA_DEG, float))
    got, want = [], []
    with FMUHost(friction_fmu) as host:
        host.initialize(params)
        for k in range(len(stream)):
            host.step(FRICTION_H, dict(zip(IN_NAMES, stream[k])))
            values = host.get(names)
            got.append([values[n] for n in names])
            e = est.step(k * FRICTION_H, Inputs(*stream[k, :4]), Measurement(*stream[k, 4:]))
            if k % 25 == 0:  # friction_period 1 s = 25 samples
                c = est.friction()
                curves = [np.interp(alpha, c.alpha, getattr(c, f)) for f in ("mu_f", "mu_f_std", "mu_r", "mu_r_std")]
                t_curve = k * FRICTION_H
            want.append([k * FRICTION_H, e.vy, e.yaw_rate, e.Cf_y, e.Cr_y, e.ess, t_curve, *np.concatenate(curves)])
    got, want = np.array(got), np.array(want)
    assert np.all(np.isfinite(got[:, :7]))
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)
    assert len(np.unique(got[:, 6])) == len(range(0, len(stream), 25))  # refreshed once per friction_period


def test_friction_fmu_state_restores(friction_fmu, friction_snow):
    _, params, stream = friction_snow
    names = ["vy", "Cf_y", "friction_t", "mu_f[26]", "mu_r[26]", "mu_f_std[26]"]  # 5 deg

    def run(host, k0, k1):
        out = []
        for k in range(k0, k1):
            host.step(FRICTION_H, dict(zip(IN_NAMES, stream[k])))
            values = host.get(names)
            out.append([values[n] for n in names])
        return np.array(out)

    with FMUHost(friction_fmu) as host:
        host.initialize(params)
        run(host, 0, 60)
        state = host.get_state()
        first = run(host, 60, 110)
        host.set_state(state)
        np.testing.assert_array_equal(run(host, 60, 110), first)


def test_friction_fmu_rejects_bad_friction_period(friction_fmu, friction_snow):
    _, params, _ = friction_snow
    from fmpy.fmi1 import FMICallException

    with FMUHost(friction_fmu) as host:
        with pytest.raises(FMICallException):
            host.initialize(dict(params, friction_period=-1.0))
        assert any("parameter friction_period: -1.0 is out of range" in m for m in host.errors()), host.messages


def test_ssp_equals_the_in_process_master_with_jacobi_coupling(ssp_run):
    """The in-process master with coupling="jacobi" is the SSP run: vehicle truth and
    sensors, the driver's inputs and the estimates agree to 1e-9 (relative) at every step.
    (Gauss-Seidel, the default, differs by the coupling effects bounded in the test above.)"""
    from tirefilter.cosim.run import run_scenario

    sc, r, _, names = ssp_run
    est = _python_estimator(sc)
    _, rows = run_scenario(dataclasses.replace(sc, duration=SSP_STOP), seed=SEED, estimator=est, keep_rows=True,
                           coupling="jacobi")
    n = len(r)
    assert len(rows) == n and rows[0, names.index("t")] == sc.communication_step  # samples t_1 ... t_n
    col = lambda c: rows[:, names.index(c)]  # noqa: E731
    # row i of the in-process run is t_{i+1}: the SSP's vehicle after step i, its estimator after step i + 1
    for fmu_name, c in (("vehicle.vx", "true_vx"), ("vehicle.vy", "true_vy"), ("vehicle.yaw_rate", "true_yaw_rate"),
                        ("vehicle.ay_meas", "meas_ay"), ("vehicle.yaw_rate_meas", "meas_yaw_rate")):
        np.testing.assert_allclose(col(c), r[fmu_name], rtol=1e-9, atol=1e-12, err_msg=fmu_name)
    np.testing.assert_allclose(col("true_drive_torque"), r["driver.drive_torque"], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(col("true_delta"), r["driver.delta"], rtol=1e-9, atol=0)
    for c in ("t", "Cf_y", "Cr_y", "vx", "vy", "yaw_rate", "b_ay", "ess", "Cf_y_std"):
        assert np.all(np.isfinite(col(c))), c
        np.testing.assert_allclose(col(c)[:-1], r["estimator." + c][1:], rtol=1e-9, atol=0, err_msg=c)
    # the default coupling is not the same run: the steering phase shows the difference
    _, gs = run_scenario(dataclasses.replace(sc, duration=SSP_STOP), seed=SEED, keep_rows=True)
    assert np.max(np.abs(gs[1:n + 1, names.index("true_vx")] - r["vehicle.vx"])) > 1e-9
