"""A second co-simulation master: the vehicle FMU and the estimator FMU (FMI 2.0; libcosim
crashes on FMI 3.0 FMUs) run together in the Open Simulation Platform's libcosim
(`libcosimpy`, step sizes in integer nanoseconds) and, with the same coupling, in fmpy:
the results agree to 1e-9.

libcosim's fixed-step algorithm steps every FMU from t_k to t_k+1 and then copies the
connected outputs to the inputs; in initialisation it copies the outputs the FMUs report
in Initialization Mode (the vehicle's initial state: the estimator's first sample at t = 0
sees v^X = vx0, not 0). The fmpy run below does the same by hand.

libcosim runs in a child process (this file run as a script): it loads the estimator FMU's
embedded Python into the test process otherwise, and unloading it there is libcosim's
business at interpreter exit.
"""

from __future__ import annotations

import gc
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description
from libcosimpy.CosimExecution import CosimExecution
from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
from libcosimpy.CosimObserver import CosimObserver
from libcosimpy.CosimSlave import CosimLocalSlave

from tirefilter.cosim.fmu import VehicleFMU
from tirefilter.fmu_export.host import FMUHost

H_NS = 10_000_000  # the communication step, 10 ms, in integer nanoseconds (libcosim's time type)
H = H_NS * 1e-9
STEPS = 150
CONNECTIONS = (("delta_meas", "u.delta"), ("omega_f_meas", "u.omega_f"), ("omega_r_meas", "u.omega_r"),
               ("vx", "u.vx"), ("ax_meas", "y.ax"), ("ay_meas", "y.ay"), ("yaw_rate_meas", "y.yaw_rate"))
VEHICLE_INPUTS = {"delta": 0.03, "drive_torque": 400.0}  # held: a steady turn at slowly rising speed
ESTIMATOR_PARAMETERS = {"particles": 60, "seed": 3}
EST_OUT = ("t", "Cf_y", "Cr_y", "vx", "vy", "yaw_rate", "b_ay", "ess", "Cf_y_std")
VEH_OUT = ("vx", "vy", "yaw_rate", "ay_meas", "Fy_f")


@pytest.fixture(scope="module")
def fmus(fmu_paths, python_fmu):
    return fmu_paths["2"], python_fmu("mpf", "2")


def _run_libcosim(vehicle, estimator):
    log_output_level(CosimLogLevel.ERROR)
    mv = {v.name: v.valueReference for v in read_model_description(str(vehicle)).modelVariables}
    me = {v.name: v.valueReference for v in read_model_description(str(estimator)).modelVariables}
    ex = CosimExecution.from_step_size(step_size=H_NS)
    iv = ex.add_local_slave(CosimLocalSlave(fmu_path=str(vehicle), instance_name="vehicle"))
    ie = ex.add_local_slave(CosimLocalSlave(fmu_path=str(estimator), instance_name="estimator"))
    for name, value in VEHICLE_INPUTS.items():
        assert ex.real_initial_value(iv, mv[name], value)
    for name, value in ESTIMATOR_PARAMETERS.items():
        assert ex.integer_initial_value(ie, me[name], value)
    for out, inp in CONNECTIONS:
        assert ex.connect_real_variables(iv, mv[out], ie, me[inp]) in (0, True)
    observer = CosimObserver.create_last_value()
    ex.add_observer(observer)
    rows = []
    for _ in range(STEPS):
        assert ex.step()
        rows.append(observer.last_real_values(ie, [me[n] for n in EST_OUT])
                    + observer.last_real_values(iv, [mv[n] for n in VEH_OUT]))
    status = ex.status()
    assert status.current_time == STEPS * H_NS  # integer nanoseconds: no drift
    # unload the FMUs now, while the interpreter the estimator FMU runs in is whole (not at exit)
    del observer, ex
    gc.collect()
    return np.array(rows)


def _run_fmpy(vehicle, estimator):
    """The same coupling with fmpy as the importer: inputs from the outputs of the last
    communication point (after initialisation for the first step), then both FMUs step."""
    rows = []
    with VehicleFMU("2", vehicle) as veh, FMUHost(estimator) as est:
        veh.reset({})
        veh.set_inputs([VEHICLE_INPUTS.get(n, {"surface": 1.0}.get(n, 0.0)) for n in
                        ("delta", "drive_torque", "brake_torque", "surface", "bank")])
        y = dict(zip(veh.output_names, veh.outputs().copy()))
        est.initialize(ESTIMATOR_PARAMETERS)
        for k in range(STEPS):
            est.step(H, {inp: y[out] for out, inp in CONNECTIONS})
            y = dict(zip(veh.output_names, veh.do_step(k * H, H).copy()))
            e = est.get(EST_OUT)
            rows.append([e[n] for n in EST_OUT] + [y[n] for n in VEH_OUT])
    return np.array(rows)


def test_libcosim_and_fmpy_give_the_same_run(fmus, tmp_path):
    vehicle, estimator = fmus
    out = tmp_path / "libcosim.npy"
    proc = subprocess.run([sys.executable, __file__, str(vehicle), str(estimator), str(out)], capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0 and out.is_file(), proc.stderr[-3000:]
    cosim = np.load(out)
    fmpy_rows = _run_fmpy(vehicle, estimator)
    assert cosim.shape == fmpy_rows.shape == (STEPS, len(EST_OUT) + len(VEH_OUT))
    assert np.all(np.isfinite(cosim))
    # the estimator processed the sample of t_k in step k, the first at t = 0 with the initial outputs
    np.testing.assert_allclose(cosim[:, 0], np.arange(STEPS) * H, rtol=0, atol=1e-12)
    np.testing.assert_allclose(cosim, fmpy_rows, rtol=1e-9, atol=1e-12)
    # and it did something: the steady turn moved the stiffness estimate and the lateral state
    assert np.ptp(cosim[:, EST_OUT.index("Cf_y")]) > 0 and np.ptp(cosim[:, len(EST_OUT) + VEH_OUT.index("vy")]) > 0


if __name__ == "__main__":  # the libcosim run, in the child process of the test
    from tirefilter.fmu_export.release import python_fmus_released

    # the estimator FMU's binary stays loaded after libcosim unloads it (the first pythonfmu
    # binary of the process): released here, its destructor has nothing to do at exit (release.py)
    with python_fmus_released():
        rows = _run_libcosim(Path(sys.argv[1]), Path(sys.argv[2]))
    np.save(sys.argv[3], rows)
