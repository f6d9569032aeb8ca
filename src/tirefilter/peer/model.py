"""The peer's vehicle models and what a Log CSV needs from their states.

Two models of the CommonRoad vehicle models (`vehiclemodels`, Althoff and Wuersching 2020):

- `std`: the single-track drift model (`vehicle_dynamics_std`), states
  [x, y, delta, v, psi, r, beta, omega_f, omega_r] (v the speed at the centre of gravity,
  beta the sideslip, omega_* the wheel rotation rates), Pacejka (MF 5.2-like) tires with
  combined slip and longitudinal load transfer.
- `mb`: the multi-body model (`vehicle_dynamics_mb`, after the DOT model), 29 states:
  sprung mass with roll and pitch, two unsprung axles with roll, four wheel rates, tire
  camber, vertical tire compliance; its x[3], x[10] are v^X, v^Y of the sprung mass.

Both take u = [steering rate of the road wheels (rad/s), longitudinal acceleration
(m/s^2)], clipped by the peer's own steering and acceleration constraints. Parameter sets
1 (Ford Escort, front drive), 2 (BMW 320i, rear drive), 3 (VW Vanagon, rear drive).

Sign conventions of the peer (checked against its source, docs/derivations.md "Peer drives"):
its slip angle is the negative of ours (alpha_peer = atan(...) - delta), and its lateral
coefficient p_ky1 < 0, so our positive axle cornering stiffness is -p_ky1 * F_z. Its
longitudinal slip s = 1 - R_w omega / u_w is the negative of ours (it flips it again
inside the tire formula), so the driven axle's slip stiffness is p_kx1 * F_z. In the MB
model the wheels named "left" carry the vehicle's -y side (they speed up and take load in
a left turn, r > 0); positive roll x[6] leans the body towards +y, so in a left turn the
body rolls outwards with x[6] < 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tirefilter.errors import TirefilterError
from tirefilter.peer import require_vehiclemodels

MODELS = ("std", "mb")
VEHICLES = {1: "Ford Escort", 2: "BMW 320i", 3: "VW Vanagon"}  # the peer's parameter sets for STD and MB
G_PEER = 9.81  # m/s^2, the gravity constant inside the peer's models


@dataclass(frozen=True)
class PeerModel:
    """One peer model with one parameter set. `p` is the peer's VehicleParameters."""

    kind: str  # "std" | "mb"
    vehicle_id: int
    p: object

    @property
    def drive(self) -> str:
        """Driven axle from the peer's engine-torque split T_se (share on the front axle)."""
        return {1.0: "front", 0.0: "rear"}.get(float(self.p.T_se), "all")

    @property
    def wheelbase(self) -> float:
        return self.p.a + self.p.b

    def rhs(self, x: list, u: list) -> list:
        """The peer's right-hand side dx/dt (it may clip x in place: pass a copy)."""
        return self.rhs_function()(x, u, self.p)

    def speed(self, x) -> float:
        """The speed the cruise control holds: v (STD), v^X (MB)."""
        return float(x[3])

    def initial_state(self, v0: float) -> np.ndarray:
        """Straight driving at v0 (the peer's own init functions)."""
        require_vehiclemodels()
        from vehiclemodels.init_mb import init_mb
        from vehiclemodels.init_std import init_std

        init = init_std if self.kind == "std" else init_mb
        return np.asarray(init([0.0, 0.0, 0.0, float(v0), 0.0, 0.0, 0.0], self.p), float)

    def static_axle_loads(self) -> tuple[float, float]:
        """Front and rear axle normal loads at rest [N], as the peer's models settle to."""
        p, L = self.p, self.wheelbase
        if self.kind == "std":
            return p.m * G_PEER * p.b / L, p.m * G_PEER * p.a / L
        return p.m_s * G_PEER * p.b / L + p.m_uf * G_PEER, p.m_s * G_PEER * p.a / L + p.m_ur * G_PEER  # init_mb

    def lateral_coefficient(self) -> float:
        """Axle cornering stiffness per unit normal load [1/rad]: -p_ky1 (derivations: "Peer drives")."""
        return -float(self.p.tire.p_ky1)

    def longitudinal_coefficient(self) -> float:
        """Slip stiffness per unit normal load [1]: p_kx1."""
        return float(self.p.tire.p_kx1)

    def static_stiffness(self) -> tuple[float, float]:
        """True linear-region axle cornering stiffness (Cf_y, Cr_y) [N/rad] at the static loads."""
        Ff, Fr = self.static_axle_loads()
        k = self.lateral_coefficient()
        return k * Ff, k * Fr

    def driven_load(self, Fz_f: float, Fz_r: float) -> float:
        return {"front": Fz_f, "rear": Fz_r}.get(self.drive, Fz_f + Fz_r)

    def sample(self, x: np.ndarray, u: list) -> dict:
        """What the log needs from state x under input u: the reference quantities, the
        accelerometer's and gyro's true readings (specific force and rate in the axes of
        the body that carries the IMU, at the centre of gravity), the axle-mean wheel rates,
        the axle loads and the true linear-region stiffness at those loads."""
        x, u = np.asarray(x, float).tolist(), np.asarray(u, float).tolist()  # Python floats (as `integrate`)
        f = self.rhs(list(x), list(u))
        return _sample_std(self, x, u, f) if self.kind == "std" else _sample_mb(self, x, f)

    def rhs_function(self):
        """The peer's right-hand side function f(x, u, p) (`vehicle_dynamics_std` or
        `vehicle_dynamics_mb`): x and u lists of Python floats, p this model's `p`."""
        require_vehiclemodels()
        if self.kind == "std":
            from vehiclemodels.vehicle_dynamics_std import vehicle_dynamics_std
            return vehicle_dynamics_std
        from vehiclemodels.vehicle_dynamics_mb import vehicle_dynamics_mb
        return vehicle_dynamics_mb


CAMBER = ("continuous", "peer", "off")


def load_model(kind: str, vehicle_id: int, camber: str = "off") -> PeerModel:
    """The peer model `kind` ("std" or "mb") with parameter set `vehicle_id` (1, 2, 3).

    `camber` (matters for MB only; STD has no camber): the peer's lateral tire formula
    shifts the curve by S_hy = sign(gamma) (p_hy1 + p_hy3 |gamma|) and adds S_vy =
    sign(gamma) F_z (p_vy1 + p_vy3 |gamma|), so the constant offsets p_hy1, p_vy1 (in the
    Magic Formula a conicity / ply-steer offset, not a camber effect) switch sign with the
    camber: a step of 2 |p_ky1 p_hy1 + p_vy1| = 4.3 % of the wheel load in lateral force
    whenever a wheel's camber crosses zero. "continuous" sets p_hy1 = p_vy1 = 0, which leaves the Magic Formula's
    continuous camber thrust p_hy3 gamma, F_z p_vy3 gamma; "peer" keeps the published
    parameters; "off" also sets p_hy3 = p_vy3 = 0 (no camber thrust). The cornering
    stiffness p_ky1 is the same in all three."""
    if camber not in CAMBER:
        raise TirefilterError(f"camber must be one of {', '.join(CAMBER)}, got {camber!r}")
    if kind not in MODELS:
        raise TirefilterError(f"peer model must be one of {', '.join(MODELS)}, got {kind!r}")
    if vehicle_id not in VEHICLES:
        raise TirefilterError(f"peer vehicle must be one of {', '.join(map(str, VEHICLES))} "
                              f"({', '.join(f'{k}: {v}' for k, v in VEHICLES.items())}), got {vehicle_id!r}")
    require_vehiclemodels()
    from vehiclemodels.vehicle_parameters import setup_vehicle_parameters

    p = setup_vehicle_parameters(vehicle_id=vehicle_id)  # a fresh, mutable dataclass per call
    zero = {"peer": (), "continuous": ("p_hy1", "p_vy1"), "off": ("p_hy1", "p_vy1", "p_hy3", "p_vy3")}[camber]
    for name in zero:
        setattr(p.tire, name, 0.0)
    return PeerModel(kind, vehicle_id, p)


def effective_stiffness(model: PeerModel, true: dict, min_ay: float = 0.3) -> tuple[float, float]:
    """Effective axle cornering stiffness of a drive (Cf, Cr) [N/rad]: the least-squares
    slope (with offset) of the single-track axle lateral forces against the single-track
    slip angles over the samples with |a^Y| > min_ay. The forces come from the peer's own
    accelerations, m a^Y = F_yf cos(delta) + F_yr and I_z dr/dt = l_f F_yf cos(delta) -
    l_r F_yr; `true` holds (n,) arrays "ay", "yaw_acc", "delta", "alpha_f", "alpha_r".
    With linear tires and no camber this is the tire stiffness; the MB model's camber
    thrust from body roll makes it larger (derivations: "Peer drives")."""
    p = model.p
    return axle_stiffness_fit(p.m, p.I_z, p.a, p.b, true, min_ay)


def axle_stiffness_fit(mass: float, yaw_inertia: float, lf: float, lr: float, true: dict,
                       min_ay: float = 0.3) -> tuple[float, float]:
    """`effective_stiffness` of any car: mass [kg], yaw inertia [kg m^2], axle distances [m]."""
    L = lf + lr
    ay, dr = true["ay"], true["yaw_acc"]
    Fyf = (mass * ay * lr + yaw_inertia * dr) / L / np.cos(true["delta"])
    Fyr = (mass * ay * lf - yaw_inertia * dr) / L
    sel = np.abs(ay) > min_ay
    if np.count_nonzero(sel) < 10:
        return math.nan, math.nan
    out = []
    for F, a in ((Fyf, true["alpha_f"]), (Fyr, true["alpha_r"])):
        A = np.column_stack([a[sel], np.ones(np.count_nonzero(sel))])
        out.append(float(np.linalg.lstsq(A, F[sel], rcond=None)[0][0]))
    return out[0], out[1]


def _stiffness(model: PeerModel, Fz_f: float, Fz_r: float) -> dict:
    k = model.lateral_coefficient()
    return {"Fz_f": Fz_f, "Fz_r": Fz_r, "Cf_y": k * Fz_f, "Cr_y": k * Fz_r,
            "Cx": model.longitudinal_coefficient() * model.driven_load(Fz_f, Fz_r)}


def _sample_std(model: PeerModel, x, u, f) -> dict:
    from vehiclemodels.utils.acceleration_constraints import acceleration_constraints

    p = model.p
    delta, v, r, beta = x[2], x[3], x[5], x[6]
    vx, vy = v * math.cos(beta), v * math.sin(beta)
    dv, dbeta = f[3], f[6]
    # body-frame acceleration of the centre of gravity: d/dt (v cos b, v sin b) + r x v
    ax = dv * math.cos(beta) - v * math.sin(beta) * dbeta - r * vy
    ay = dv * math.sin(beta) + v * math.cos(beta) * dbeta + r * vx
    a = acceleration_constraints(v, u[1], p.longitudinal)  # the input the peer applied
    L = model.wheelbase
    Fz_f = p.m * (-a * p.h_s + G_PEER * p.b) / L  # the peer's load transfer (vehicle_dynamics_std)
    Fz_r = p.m * (a * p.h_s + G_PEER * p.a) / L
    out = {"delta": delta, "vx": vx, "vy": vy, "yaw_rate": r, "yaw_acc": f[5], "beta": math.atan2(vy, vx),
           "ax": ax, "ay": ay, "ax_imu": ax, "ay_imu": ay, "yaw_rate_imu": r, "roll": 0.0, "pitch": 0.0,
           "omega_f": x[7], "omega_r": x[8],
           "alpha_f": delta - math.atan2(vy + p.a * r, vx), "alpha_r": -math.atan2(vy - p.b * r, vx)}
    out.update(_stiffness(model, Fz_f, Fz_r))
    return out


def _sample_mb(model: PeerModel, x, f) -> dict:
    p = model.p
    delta, vx, vy, r, roll, pitch = x[2], x[3], x[10], x[5], x[6], x[8]
    ax = f[3] - r * vy  # sum of longitudinal forces / m (the peer's f[3] = sumX/m + r vy)
    ay = f[10] + r * vx  # sprung mass: sumY_s / m_s (f[10] = sumY_s/m_s - r vx)
    az_up = G_PEER - f[12]  # upward support force / m_s (the peer's z points down: f[12] = g - sumZ_s/m_s)
    # Specific force on the body axes (the IMU is fixed to the sprung mass at its centre of
    # gravity): roll leans the lateral axis, pitch (x[8] > 0 nose up) the longitudinal one,
    # so each picks up a share of the support force (derivations: "Peer drives").
    ay_imu = ay * math.cos(roll) - az_up * math.sin(roll)
    ax_imu = ax * math.cos(pitch) + az_up * math.sin(pitch)
    Fz_f = 2 * (x[16] + p.R_w * (math.cos(x[13]) - 1)) * p.K_zt  # F_z_LF + F_z_RF of the peer
    Fz_r = 2 * (x[21] + p.R_w * (math.cos(x[18]) - 1)) * p.K_zt
    out = {"delta": delta, "vx": vx, "vy": vy, "yaw_rate": r, "yaw_acc": f[5], "beta": math.atan2(vy, vx),
           "ax": ax, "ay": ay, "ax_imu": ax_imu, "ay_imu": ay_imu, "yaw_rate_imu": r * math.cos(roll) * math.cos(pitch),
           "roll": roll, "pitch": pitch,
           "omega_f": 0.5 * (x[23] + x[24]), "omega_r": 0.5 * (x[25] + x[26]),
           "alpha_f": delta - math.atan2(vy + p.a * r, vx), "alpha_r": -math.atan2(vy - p.b * r, vx)}
    out.update(_stiffness(model, Fz_f, Fz_r))
    return out
