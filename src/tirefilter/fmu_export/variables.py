"""The variable tables of the Python FMUs (`slaves.py`): the estimator FMU's inputs and outputs
with their units and descriptions, the vehicle record's parameters (`vehicle.<key>`) and their
units, the enumerations of the model and the drive, the unit definitions, and the friction
estimator FMU's curve outputs."""

from __future__ import annotations

from dataclasses import fields

# FMI inputs of the estimator FMU (u.: Inputs, y.: Measurement of the Estimator protocol) -> (unit, description)
ESTIMATOR_INPUTS = {
    "u.delta": ("rad", "road-wheel steer angle"),
    "u.omega_f": ("rad/s", "front wheel rotation rate (axle mean)"),
    "u.omega_r": ("rad/s", "rear wheel rotation rate (axle mean)"),
    "u.vx": ("m/s", "longitudinal speed from other logic (lateral model)"),
    "y.ax": ("m/s2", "measured longitudinal acceleration (IMU)"),
    "y.ay": ("m/s2", "measured lateral acceleration (IMU)"),
    "y.yaw_rate": ("rad/s", "measured yaw rate (IMU)"),
}
# Outputs (unit, description): the estimate columns of the Result CSV (docs/usage.md), the state stds;
# `active` (Boolean) and `samples` (Integer) are added in EstimatorSlave.__init__
ESTIMATOR_OUTPUTS = {
    "t": ("s", "time of the sample the outputs belong to"),
    "vx": ("m/s", "longitudinal velocity estimate"),
    "vy": ("m/s", "lateral velocity estimate"),
    "yaw_rate": ("rad/s", "yaw rate estimate"),
    "beta": ("rad", "sideslip estimate atan2(vy, vx)"),
    "Cf_y": ("N/rad", "front cornering stiffness: posterior mean of the mean (eq. (27a) plus nominal)"),
    "Cr_y": ("N/rad", "rear cornering stiffness: posterior mean of the mean"),
    "Cx": ("N", "driven axle longitudinal stiffness (NaN when not estimated)"),
    "Cf_y_std": ("N/rad", "posterior std of the front stiffness mean"),
    "Cr_y_std": ("N/rad", "posterior std of the rear stiffness mean"),
    "Cx_std": ("N", "posterior std of the longitudinal stiffness mean"),
    "Cf_y_sigma": ("N/rad", "estimated spread of the front stiffness deviations (eq. (27b))"),
    "Cr_y_sigma": ("N/rad", "estimated spread of the rear stiffness deviations"),
    "Cx_sigma": ("N", "estimated spread of the longitudinal stiffness deviations"),
    "b_ax": ("m/s2", "accelerometer x bias estimate (measured - true)"),
    "b_ay": ("m/s2", "accelerometer y bias estimate"),
    "b_yaw_rate": ("rad/s", "gyro bias estimate"),
    "ess": ("1", "effective sample size"),
    "roll_gradient": ("rad.s2/m",
                      "roll gradient k of the IMU's a^Y gain 1 + k g: posterior mean (NaN when not estimated)"),
    "roll_gradient_std": ("rad.s2/m", "posterior std of the roll gradient"),
    "vx_std": ("m/s", "posterior std of vx"),
    "vy_std": ("m/s", "posterior std of vy"),
    "yaw_rate_std": ("rad/s", "posterior std of the yaw rate"),
}
MODELS = {1: "full", 2: "lateral"}
DRIVES = {0: "front", 1: "rear", 2: "all"}
# units of the vehicle record's keys (`vehicle.<key>` parameters); Integer keys have none
VEHICLE_UNITS = {
    "mass": "kg", "yaw_inertia": "kg.m2", "lf": "m", "lr": "m", "wheel_radius": "m", "cg_height": "m",
    "Cf_y": "N/rad", "Cr_y": "N/rad", "Cx": "N", "steering_ratio": "1", "roll_gradient": "rad.s2/m", "imu_x": "m",
    "imu_y": "m", "relaxation_length": "m", "load_sensitivity": "s4/m2", "sigma_ax": "m/s2", "sigma_ay": "m/s2", "sigma_yaw_rate": "rad/s", "Cx_undriven": "N",
    "wheel_inertia_f": "kg.m2", "wheel_inertia_r": "kg.m2", "brake_front_share": "1", "awd_front_share": "1",
    "rolling_resistance": "1", "drag_coefficient": "N.s2/m2", "bias0_std_ax": "m/s2", "bias0_std_ay": "m/s2",
    "bias0_std_yaw_rate": "rad/s", "bias_q_ax": "m2/s5", "bias_q_ay": "m2/s5", "bias_q_yaw_rate": "rad2/s3",
}
# The TOML's bias random walks (per sqrt(s)) have no unit with integer exponents: the FMU
# takes their variance per second, bias_q = bias_rw^2 (as the vehicle FMU does)
RW_AS_VARIANCE = {"bias_rw_ax": "bias_q_ax", "bias_rw_ay": "bias_q_ay", "bias_rw_yaw_rate": "bias_q_yaw_rate"}
# every unit the Python FMUs use, as SI base-unit exponents (UnitDefinitions)
UNITS = {
    "1": {}, "s": {"s": 1}, "Hz": {"s": -1}, "m": {"m": 1}, "kg": {"kg": 1}, "kg.m2": {"kg": 1, "m": 2},
    "m/s": {"m": 1, "s": -1}, "m/s2": {"m": 1, "s": -2}, "rad": {"rad": 1}, "rad/s": {"rad": 1, "s": -1},
    "N": {"kg": 1, "m": 1, "s": -2}, "N/rad": {"kg": 1, "m": 1, "s": -2, "rad": -1},
    "N.m": {"kg": 1, "m": 2, "s": -2}, "N.s2/m2": {"kg": 1, "m": -1}, "rad.s2/m": {"rad": 1, "s": 2, "m": -1},
    "m2/s5": {"m": 2, "s": -5}, "rad2/s3": {"rad": 2, "s": -3}, "s4/m2": {"s": 4, "m": -2},
}


def _vehicle_parameters():
    """(name, default, unit) of the vehicle TOML keys exposed as `vehicle.<key>`; optional
    keys without a default (steering_ratio, Cx_undriven) use 0 for "not given"; the IMU bias
    keys default to the automotive MEMS figures (bias estimation on, as in a replay)."""
    from tirefilter.estimators.sensors import CHANNELS, MEMS_BIAS0_STD, MEMS_BIAS_RW
    from tirefilter.scenarios import DATA_DIR
    from tirefilter.vehicle.params import VehicleParams, load_vehicle

    reference = load_vehicle(DATA_DIR / "vehicles" / "midsize-suv.toml")
    mems = {f"bias0_std_{c}": b for c, b in zip(CHANNELS, MEMS_BIAS0_STD)}
    mems |= {f"bias_rw_{c}": q for c, q in zip(CHANNELS, MEMS_BIAS_RW)}
    out = []
    for f in fields(VehicleParams):
        value = getattr(reference, f.name)
        if value is None and f.name in mems:  # bias estimation on, with the MEMS defaults
            value = mems[f.name]
        if f.name == "drive":
            out.append((f.name, {v: k for k, v in DRIVES.items()}[value]))
        elif f.name in RW_AS_VARIANCE:
            out.append((RW_AS_VARIANCE[f.name], float(value) ** 2))
        else:
            out.append((f.name, 0.0 if value is None else float(value)))
    return out


FRICTION_ALPHA_DEG = tuple(range(-20, 21))  # deg: the slip angles of the friction outputs


def friction_output(field: str, k: int) -> str:
    """The FMU variable of `field` (mu_f, mu_f_std, mu_r, mu_r_std) at alpha = k deg: an
    array element, 1-based over FRICTION_ALPHA_DEG (structured naming: mu_f[1] is -20 deg)."""
    return f"{field}[{FRICTION_ALPHA_DEG.index(k) + 1}]"


FRICTION_VISITED = ("alpha_f_min", "alpha_f_max", "alpha_r_min", "alpha_r_max")
