"""The vehicle FMU's variables, defined once.

`build.py` (beside this file) generates from this table both `modelDescription.xml` (FMI 2.0
and 3.0) and the C header with the value references and the variable struct, so the two
cannot drift.

Each row: name, type ("Real" or "Integer"), causality, start (parameters and inputs),
unit, description, and optional min/max; outputs also their variability ("continuous",
or "discrete" when the value only changes at sample instants). Value references are
assigned in table order, starting at 1 (0 is `time` in FMI 3.0).

`EQUATIONS` lists, for every output and every intermediate quantity of
`vehicle_model.c`, what it is computed from at the same instant (inputs, other
quantities; the continuous state and the parameters are left out: they never change
within an instant). `direct_inputs(name)` closes over it: the inputs an output depends on
directly, which `build.py` writes as the output's `dependencies` in the model
structure. tests/test_fmu_metadata.py perturbs every input after a step and checks that
exactly these outputs move at once.

The GUID / instantiation token is a hash of this table (`instantiation_token()`): a change
of a name, type, causality, start value, unit or range changes it.
"""

from __future__ import annotations

import hashlib
from dataclasses import astuple, dataclass

MODEL_NAME = "TirefilterVehicle"
MODEL_IDENTIFIER = "TirefilterVehicle"
DESCRIPTION = (
    "Planar single-track vehicle with wheel-spin dynamics, linear or Pacejka tires, "
    "per-sample stiffness deviations and production sensors (IMU with bias, wheel speeds)."
)

UNITS = {
    "kg": {"kg": 1},
    "kg.m2": {"kg": 1, "m": 2},
    "m": {"m": 1},
    "s": {"s": 1},
    "m/s": {"m": 1, "s": -1},
    "m/s2": {"m": 1, "s": -2},
    "rad": {"rad": 1},
    "rad/s": {"rad": 1, "s": -1},
    "rad/s2": {"rad": 1, "s": -2},
    "N": {"kg": 1, "m": 1, "s": -2},
    "N.m": {"kg": 1, "m": 2, "s": -2},
    "N/rad": {"kg": 1, "m": 1, "s": -2, "rad": -1},
    "N.s2/m2": {"kg": 1, "m": -1},
    "rad.s2/m": {"rad": 1, "m": -1, "s": 2},
    "m2/s5": {"m": 2, "s": -5},  # random-walk intensity of an accelerometer bias: (m/s2)^2 per s
    "rad2/s3": {"rad": 2, "s": -3},  # random-walk intensity of a gyro bias: (rad/s)^2 per s
    "1": {},
}


@dataclass(frozen=True)
class Var:
    name: str
    type: str  # "Real" | "Integer"
    causality: str  # "parameter" | "input" | "output"
    start: float | int | None
    unit: str
    description: str
    min: float | None = None
    max: float | None = None
    variability: str | None = None  # outputs: "continuous" or "discrete"; None: from the causality


def _p(name, start, unit, description, lo=None, hi=None, type_="Real"):
    return Var(name, type_, "parameter", start, unit, description, lo, hi)


def _i(name, start, unit, description, lo=None, hi=None):
    return Var(name, "Real", "input", start, unit, description, lo, hi)


def _o(name, unit, description, variability="continuous"):
    return Var(name, "Real", "output", None, unit, description, variability=variability)


def _s(name, unit, description):
    """A sensor output: sampled and held at the sample instants k sample_period."""
    return _o(name, unit, description + "; sampled at t = k sample_period and held", "discrete")


VARIABLES: list[Var] = [
    # --- chassis -----------------------------------------------------------------------
    _p("mass", 2050.0, "kg", "vehicle mass", 1.0, None),
    _p("yaw_inertia", 3850.0, "kg.m2", "yaw moment of inertia about the CG", 1.0, None),
    _p("lf", 1.30, "m", "CG to front axle", 0.01, None),
    _p("lr", 1.60, "m", "CG to rear axle", 0.01, None),
    _p("cg_height", 0.70, "m", "CG height (longitudinal load transfer)", 0.0, None),
    _p("wheel_radius", 0.36, "m", "effective rolling radius", 0.05, None),
    _p("wheel_inertia_f", 3.6, "kg.m2", "spin inertia of the front axle (both wheels)", 0.01, None),
    _p("wheel_inertia_r", 3.6, "kg.m2", "spin inertia of the rear axle (both wheels)", 0.01, None),
    _p("drive", 0, "1", "driven axles: 0 front, 1 rear, 2 all", 0, 2, "Integer"),
    _p("awd_front_share", 0.5, "1", "share of drive torque on the front axle when drive = 2", 0.0, 1.0),
    _p("brake_front_share", 0.6, "1", "share of brake torque on the front axle", 0.0, 1.0),
    _p("rolling_resistance", 0.0, "1", "rolling-resistance coefficient (force / weight)", 0.0, 0.1),
    _p("drag_coefficient", 0.0, "N.s2/m2", "aerodynamic drag 0.5 rho cd A", 0.0, None),
    _p("load_transfer_time_constant", 0.1, "s", "first-order lag of longitudinal load transfer (pitch)", 1e-3, None),
    _p("roll_gradient", 0.0, "rad.s2/m", "body roll per lateral acceleration (phi = k a^Y)", 0.0, 0.05),
    _p("imu_x", 0.0, "m", "IMU position ahead of the CG", None, None),
    _p("imu_y", 0.0, "m", "IMU position left of the CG", None, None),
    # --- tires -------------------------------------------------------------------------
    _p("tire_model", 0, "1", "0 linear (F = C slip), 1 Pacejka Magic Formula with combined slip", 0, 1, "Integer"),
    _p("Cf_y", 109400.0, "N/rad", "front axle cornering stiffness (linear model, surface 1)", 1.0, None),
    _p("Cr_y", 88900.0, "N/rad", "rear axle cornering stiffness (linear model, surface 1)", 1.0, None),
    _p("Cf_x", 263000.0, "N", "front axle longitudinal stiffness per unit slip (linear model)", 1.0, None),
    _p("Cr_x", 213800.0, "N", "rear axle longitudinal stiffness per unit slip (linear model)", 1.0, None),
    _p("pac_mu_x", 1.20, "1", "Pacejka longitudinal peak friction D/Fz", 0.01, 3.0),
    _p("pac_B_x", 11.7, "1", "Pacejka longitudinal stiffness factor", 0.01, None),
    _p("pac_C_x", 1.69, "1", "Pacejka longitudinal shape factor", 0.01, 3.0),
    _p("pac_E_x", 0.377, "1", "Pacejka longitudinal curvature factor", -10.0, 1.0),
    _p("pac_mu_y", 0.935, "1", "Pacejka lateral peak friction D/Fz", 0.01, 3.0),
    _p("pac_B_y", 8.86, "1", "Pacejka lateral stiffness factor (per rad)", 0.01, None),
    _p("pac_C_y", 1.19, "1", "Pacejka lateral shape factor", 0.01, 3.0),
    _p("pac_E_y", -1.21, "1", "Pacejka lateral curvature factor", -10.0, 1.0),
    _p("pac_rBx1", 13.476, "1", "combined slip: G_x,alpha stiffness factor", 0.0, None),
    _p("pac_rBx2", 11.354, "1", "combined slip: G_x,alpha slip dependence", 0.0, None),
    _p("pac_Cxa", 1.1231, "1", "combined slip: G_x,alpha shape factor", 0.0, 3.0),
    _p("pac_rBy1", 7.7856, "1", "combined slip: G_y,kappa stiffness factor", 0.0, None),
    _p("pac_rBy2", 8.1697, "1", "combined slip: G_y,kappa slip-angle dependence", 0.0, None),
    _p("pac_Cyk", 1.0533, "1", "combined slip: G_y,kappa shape factor", 0.0, 3.0),
    # --- stochastic truth and sensors ----------------------------------------------------
    _p("seed", 1, "1", "seed of the FMU's random generator", 0, 2147483647, "Integer"),
    _p("sample_period", 0.01, "s", "estimator sample period: deviations and sensor noise held over it", 1e-4, 10.0),
    _p("stiffness_dev_std", 0.05, "1", "std of the i.i.d. relative stiffness deviations", 0.0, 0.5),
    _p("sigma_ax", 0.05, "m/s2", "white-noise std of the longitudinal accelerometer", 0.0, None),
    _p("sigma_ay", 0.05, "m/s2", "white-noise std of the lateral accelerometer", 0.0, None),
    _p("sigma_yaw_rate", 0.0035, "rad/s", "white-noise std of the yaw-rate gyro", 0.0, None),
    _p("sigma_omega", 0.0, "rad/s", "white-noise std of the wheel-speed sensors", 0.0, None),
    _p("sigma_delta", 0.0, "rad", "white-noise std of the steer-angle sensor", 0.0, None),
    _p("bias_q_ax", 0.0, "m2/s5", "random-walk intensity of the ax bias: variance growth per second "
       "(the square of a std per sqrt(s))", 0.0, None),
    _p("bias_q_ay", 0.0, "m2/s5", "random-walk intensity of the ay bias: variance growth per second", 0.0, None),
    _p("bias_q_yaw_rate", 0.0, "rad2/s3", "random-walk intensity of the gyro bias: variance growth per second",
       0.0, None),
    _p("bias0_ax", 0.0, "m/s2", "initial ax bias mean", None, None),
    _p("bias0_ay", 0.0, "m/s2", "initial ay bias mean", None, None),
    _p("bias0_yaw_rate", 0.0, "rad/s", "initial gyro bias mean", None, None),
    _p("bias0_std_ax", 0.0, "m/s2", "initial ax bias std", 0.0, None),
    _p("bias0_std_ay", 0.0, "m/s2", "initial ay bias std", 0.0, None),
    _p("bias0_std_yaw_rate", 0.0, "rad/s", "initial gyro bias std", 0.0, None),
    # --- initial state -------------------------------------------------------------------
    _p("vx0", 22.0, "m/s", "initial longitudinal velocity mean", None, None),
    _p("vy0", 0.0, "m/s", "initial lateral velocity mean", None, None),
    _p("yaw_rate0", 0.0, "rad/s", "initial yaw rate mean", None, None),
    _p("vx0_std", 0.0, "m/s", "initial longitudinal velocity std", 0.0, None),
    _p("vy0_std", 0.0, "m/s", "initial lateral velocity std", 0.0, None),
    _p("yaw_rate0_std", 0.0, "rad/s", "initial yaw rate std", 0.0, None),
    # --- numerics ------------------------------------------------------------------------
    _p("max_step", 1e-3, "s", "largest internal RK4 step", 1e-6, 1e-3),
    _p("v_min", 1.0, "m/s", "the model is valid above this speed; doStep fails below it", 0.01, None),
    # --- inputs --------------------------------------------------------------------------
    _i("delta", 0.0, "rad", "road-wheel steer angle", -1.5707963267948966, 1.5707963267948966),
    _i("drive_torque", 0.0, "N.m", "drive torque at the wheels (negative: engine braking)"),
    _i("brake_torque", 0.0, "N.m", "brake torque at the wheels", 0.0, None),
    _i("surface", 1.0, "1", "surface scale: multiplies stiffness and peak friction", 0.01, 2.0),
    _i("bank", 0.0, "rad", "road bank angle, left side up positive", -0.5, 0.5),
    # --- sensors (what an estimator sees) ------------------------------------------------
    _s("ax_meas", "m/s2", "measured longitudinal acceleration (IMU, with noise and bias)"),
    _s("ay_meas", "m/s2", "measured lateral acceleration (IMU, roll pick-up, noise and bias)"),
    _s("yaw_rate_meas", "rad/s", "measured yaw rate (gyro, with noise and bias)"),
    _s("omega_f_meas", "rad/s", "measured front wheel rotation rate"),
    _s("omega_r_meas", "rad/s", "measured rear wheel rotation rate"),
    _s("delta_meas", "rad", "measured road-wheel steer angle"),
    # --- ground truth --------------------------------------------------------------------
    _o("vx", "m/s", "longitudinal velocity at the CG"),
    _o("vy", "m/s", "lateral velocity at the CG"),
    _o("yaw_rate", "rad/s", "yaw rate"),
    _o("beta", "rad", "sideslip atan2(vy, vx)"),
    _o("alpha_f", "rad", "front slip angle"),
    _o("alpha_r", "rad", "rear slip angle"),
    _o("lambda_f", "1", "front wheel slip (traction positive)"),
    _o("lambda_r", "1", "rear wheel slip (traction positive)"),
    _o("omega_f", "rad/s", "front wheel rotation rate"),
    _o("omega_r", "rad/s", "rear wheel rotation rate"),
    _o("ax", "m/s2", "longitudinal specific force at the CG (ideal accelerometer)"),
    _o("ay", "m/s2", "lateral specific force at the CG (ideal accelerometer, no roll)"),
    _o("yaw_acc", "rad/s2", "yaw acceleration"),
    _o("x", "m", "position east"),
    _o("y", "m", "position north"),
    _o("psi", "rad", "heading"),
    _o("roll", "rad", "body roll angle relative to the road"),
    _o("Fz_f", "N", "front axle normal load"),
    _o("Fz_r", "N", "rear axle normal load"),
    _o("Fx_f", "N", "front axle longitudinal tire force"),
    _o("Fx_r", "N", "rear axle longitudinal tire force"),
    _o("Fy_f", "N", "front axle lateral tire force"),
    _o("Fy_r", "N", "rear axle lateral tire force"),
    _o("true_Cf_y", "N/rad", "current effective front cornering stiffness (deviation and surface)"),
    _o("true_Cr_y", "N/rad", "current effective rear cornering stiffness (deviation and surface)"),
    _o("true_Cf_x", "N", "current effective front longitudinal stiffness"),
    _o("true_Cr_x", "N", "current effective rear longitudinal stiffness"),
    _o("true_Cx", "N", "current effective longitudinal stiffness of the driven axle (front for AWD)"),
    _o("true_Cf_y_mean", "N/rad", "surface mean of the front cornering stiffness (no deviation)"),
    _o("true_Cr_y_mean", "N/rad", "surface mean of the rear cornering stiffness (no deviation)"),
    _o("true_Cx_mean", "N", "surface mean of the driven axle's longitudinal stiffness"),
    _o("true_b_ax", "m/s2", "current ax sensor bias", "discrete"),
    _o("true_b_ay", "m/s2", "current ay sensor bias", "discrete"),
    _o("true_b_yaw_rate", "rad/s", "current gyro bias", "discrete"),
]

BY_NAME = {v.name: v for v in VARIABLES}
INPUTS = tuple(v.name for v in VARIABLES if v.causality == "input")

# What each output and intermediate quantity of vehicle_model.c is computed from at one
# instant (vm_derivatives, axle_forces, vm_update_outputs); state and parameters omitted.
EQUATIONS: dict[str, tuple[str, ...]] = {
    # vm_derivatives: slips from the state, the front slip angle also from the steer
    "alpha_f": ("delta",), "alpha_r": (), "lambda_f": (), "lambda_r": (), "Fz_f": (), "Fz_r": (),
    # axle_forces: linear F = surface C (1 + dev) slip; Pacejka surface MF(slip) G(other slip)
    "Fy_f": ("alpha_f", "lambda_f", "surface"), "Fx_f": ("lambda_f", "alpha_f", "surface"),
    "Fy_r": ("alpha_r", "lambda_r", "surface"), "Fx_r": ("lambda_r", "alpha_r", "surface"),
    "true_Cf_y": ("surface", "Fz_f"), "true_Cr_y": ("surface", "Fz_r"), "true_Cf_x": ("surface", "Fz_f"),
    "true_Cr_x": ("surface", "Fz_r"), "true_Cx": ("true_Cf_x", "true_Cr_x"),
    "true_Cf_y_mean": ("surface", "Fz_f"), "true_Cr_y_mean": ("surface", "Fz_r"),
    "true_Cx_mean": ("surface", "Fz_f", "Fz_r"),
    # specific force and yaw acceleration: the axle forces rotated by the steer (eq. 1a-1c)
    "ax": ("Fx_f", "Fy_f", "Fx_r", "delta"), "ay": ("Fy_f", "Fx_f", "Fy_r", "delta"),
    "yaw_acc": ("Fy_f", "Fx_f", "Fy_r", "delta"),
    # the state itself
    "vx": (), "vy": (), "yaw_rate": (), "beta": (), "omega_f": (), "omega_r": (), "x": (), "y": (), "psi": (),
    "true_b_ax": (), "true_b_ay": (), "true_b_yaw_rate": (),
    # sensors: IMU lever arm, roll pick-up of gravity on the banked road, noise and bias
    "roll": ("ay",), "ax_meas": ("ax", "yaw_acc"), "ay_meas": ("ay", "yaw_acc", "roll", "bank"),
    "yaw_rate_meas": (), "omega_f_meas": (), "omega_r_meas": (), "delta_meas": ("delta",),
}


def direct_inputs(name: str) -> tuple[str, ...]:
    """The inputs `name` depends on at the same instant (table order), from EQUATIONS."""
    seen, todo = set(), [name]
    while todo:
        for arg in EQUATIONS.get(todo.pop(), ()):
            if arg not in seen:
                seen.add(arg)
                if arg not in INPUTS:
                    todo.append(arg)
    return tuple(n for n in INPUTS if n in seen)


def instantiation_token() -> str:
    """The GUID (FMI 2.0) / instantiationToken (FMI 3.0): a SHA-256 of the variable table,
    written as a UUID."""
    text = repr((MODEL_IDENTIFIER, [astuple(v) for v in VARIABLES]))
    h = hashlib.sha256(text.encode()).hexdigest()
    return "{" + f"{h[:8]}-{h[8:12]}-{h[12:16]}-{h[16:20]}-{h[20:32]}" + "}"


INSTANTIATION_TOKEN = instantiation_token()


def value_reference(name: str) -> int:
    """Value reference of a variable (its 1-based row in the table)."""
    return VARIABLES.index(BY_NAME[name]) + 1
