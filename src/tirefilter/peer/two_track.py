"""A two-track (four-wheel) vehicle model for peer drives, written here from the textbooks
and independent of the estimators' single-track model: H. B. Pacejka, "Tire and Vehicle
Dynamics" (3rd ed., 2012), T. D. Gillespie, "Fundamentals of Vehicle Dynamics" (1992),
R. Rajamani, "Vehicle Dynamics and Control" (2nd ed., 2012).

Body: planar motion of the centre of gravity in body axes (x forward, y left, z up),
state v^X, v^Y, yaw rate r, and the pose psi, X, Y:

    m (dv^X/dt - r v^Y) = sum F_x,i - F_drag        m (dv^Y/dt + r v^X) = sum F_y,i
    I_z dr/dt = sum (x_i F_y,i - y_i F_x,i)

with the wheel forces F_i rotated from the wheel axes by the wheel's steer angle
(Rajamani ch. 2; Gillespie ch. 6). Wheels FL, FR, RL, RR at (x_i, y_i) = (l_f, +t_f/2),
(l_f, -t_f/2), (-l_r, +t_r/2), (-l_r, -t_r/2); the front wheels steer, with a share
`ackermann` of the Ackermann geometry, tan delta_i = L tan delta / (L - y_i tan delta).

Wheel spin: I_w domega_i/dt = T_i - R F_x,i - f_r R F_z,i (drive or brake torque, the
longitudinal tyre force at the rolling radius R, rolling resistance as a moment).

Tyres: the Magic Formula in the form of Bakker, Nyborg and Pacejka (1987, SAE 870421; also
Pacejka 2012, sec. 4.3), pure slip, load-sensitive peak D = (a1 F_z + a2) F_z and cornering
stiffness BCD = a3 sin(a4 atan(a5 F_z)) (Pacejka '94: a4 = 2, a5 = 1/a4'), driven by
relaxed slips (Pacejka 2012, ch. 7, the first-order relaxation-length model):

    sigma_alpha d(tan alpha')/dt + |V_x| tan alpha' = -V_y
    sigma_kappa dkappa'/dt + |V_x| kappa' = R omega - V_x

(V the wheel centre's velocity in wheel axes); in steady state tan alpha' = -V_y/V_x and
kappa' = (R omega - V_x)/V_x. No combined-slip reduction and no aligning moment.

Loads (Gillespie ch. 8; quasi-static): per axle the static load, the longitudinal transfer
m a^X h / L and the lateral transfer of the axle's share of the roll moment,

    Delta F_z,f t_f = m a^Y [h' K_f / (K_f + K_r - m g h') + z_f l_r / L]   (front; rear alike)

(h' the height of the centre of gravity above the roll axis, z_f, z_r the roll-centre
heights, K_f, K_r the roll stiffness), on the outer wheel and off the inner one. The body
rolls by phi = m a^Y h' / (K_f + K_r - m g h') and pitches by theta = k_theta a^X. The a^X,
a^Y of these formulas are lagged by `load_lag` (states 18, 19: the suspension's settling),
so a steady turn has exactly the static formulas and the model stays an ODE without an
algebraic loop.

IMU: fixed to the rolling, pitching body at (imu_x, imu_y) from the centre of gravity in
the plane; it reads the specific force of that point, a_cg + dr/dt z x p + r z x (r z x p)
(the yaw-rate and yaw-acceleration lever-arm terms; roll and pitch rates are left out with
the quasi-static roll), in the body's tilted axes (gravity leaks in as g sin(phi), g
sin(theta)), and the yaw rate r cos(theta) cos(phi).

Everything is batch-first: states (..., NX), inputs (..., 2) = [road-wheel steer (rad),
total wheel torque (N m; > 0 drives the driven axle, < 0 brakes all four wheels)].
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from tirefilter.errors import TirefilterError

G = 9.81  # m/s^2
NX = 20
# state layout
VX, VY, R_, PSI, X_, Y_ = range(6)
OMEGA = slice(6, 10)  # wheel spin rates FL, FR, RL, RR (rad/s)
SLIP_Y = slice(10, 14)  # relaxed lateral slip tan(alpha') per wheel
SLIP_X = slice(14, 18)  # relaxed longitudinal slip kappa' per wheel
AX_LAG, AY_LAG = 18, 19  # the accelerations the loads and the roll follow (m/s^2)
WHEELS = ("FL", "FR", "RL", "RR")


@dataclass(frozen=True)
class MagicFormulaTyre:
    """Pure-slip Magic Formula of Bakker, Nyborg and Pacejka (1987), coefficients in the
    published units: F_z in kN, slip angle in degrees, longitudinal slip in %, forces in N.
    Fields may be arrays of one shape (a tyre per wheel, `stack`).

    F_y = D sin(C atan(B a - E (B a - atan(B a)))), a in deg, C = C_y, D = (a1 F_z + a2) F_z,
    BCD = a3 sin(a4 atan(a5 F_z)), E = a6 F_z^2 + a7 F_z + a8;
    F_x the same in kappa (%) with C = C_x, D = (b1 F_z + b2) F_z,
    BCD = (b3 F_z^2 + b4 F_z) exp(-b5 F_z), E = b6 F_z^2 + b7 F_z + b8."""

    C_y: float
    a1: float  # N/kN^2
    a2: float  # N/kN
    a3: float  # N/deg
    a4: float  # 1
    a5: float  # 1/kN
    a6: float  # 1/kN^2
    a7: float  # 1/kN
    a8: float  # 1
    C_x: float
    b1: float  # N/kN^2
    b2: float  # N/kN
    b3: float  # N/%/kN^2
    b4: float  # N/%/kN
    b5: float  # 1/kN
    b6: float  # 1/kN^2
    b7: float  # 1/kN
    b8: float  # 1
    sigma_alpha: float  # m, lateral relaxation length
    sigma_kappa: float  # m, longitudinal relaxation length

    def lateral(self, tan_alpha, Fz):
        """F_y [N] at the slip tan(alpha) and load F_z [N] (> 0 for alpha > 0)."""
        fz = np.maximum(Fz, 10.0) * 1e-3
        D = (self.a1 * fz + self.a2) * fz
        B = self.a3 * np.sin(self.a4 * np.arctan(self.a5 * fz)) / (self.C_y * D)
        E = (self.a6 * fz + self.a7) * fz + self.a8
        Ba = B * np.degrees(np.arctan(tan_alpha))
        return D * np.sin(self.C_y * np.arctan(Ba - E * (Ba - np.arctan(Ba))))

    def longitudinal(self, kappa, Fz):
        """F_x [N] at the slip kappa (unit, not %) and load F_z [N]."""
        fz = np.maximum(Fz, 10.0) * 1e-3
        D = (self.b1 * fz + self.b2) * fz
        B = (self.b3 * fz + self.b4) * fz * np.exp(-self.b5 * fz) / (self.C_x * D)
        E = (self.b6 * fz + self.b7) * fz + self.b8
        Bk = B * (100.0 * kappa)
        return D * np.sin(self.C_x * np.arctan(Bk - E * (Bk - np.arctan(Bk))))

    def cornering_stiffness(self, Fz):
        """dF_y/dalpha at alpha = 0 [N/rad]: BCD."""
        fz = np.asarray(Fz, float) * 1e-3
        return self.a3 * np.sin(self.a4 * np.arctan(self.a5 * fz)) * (180.0 / math.pi)

    def slip_stiffness(self, Fz):
        """dF_x/dkappa at kappa = 0 [N per unit slip]: 100 BCD."""
        fz = np.asarray(Fz, float) * 1e-3
        return 100.0 * (self.b3 * fz + self.b4) * fz * np.exp(-self.b5 * fz)

    def peak_friction(self, Fz):
        """D_y / F_z: the lateral friction coefficient at the load F_z [N]."""
        fz = np.asarray(Fz, float) * 1e-3
        return (self.a1 * fz + self.a2) * 1e-3

    def scaled(self, *, load: float = 1.0, friction: float = 1.0, cornering: float = 1.0,
               slip: float = 1.0) -> "MagicFormulaTyre":
        """This tyre with the Magic Formula's user scaling factors (Pacejka 2012, sec. 4.3.2):
        `load` stretches the load axis (lambda_Fz0: the same curves per unit load at `load`
        times the load), `friction` scales the peaks (lambda_mu), `cornering` and `slip` the
        cornering and slip stiffness (lambda_Kya, lambda_Kxk)."""
        s = load
        return dataclasses.replace(
            self, a1=friction * self.a1 / s, a2=friction * self.a2, a3=cornering * s * self.a3, a5=self.a5 / s,
            a6=self.a6 / s**2, a7=self.a7 / s, b1=friction * self.b1 / s, b2=friction * self.b2,
            b3=slip * self.b3 / s, b4=slip * self.b4, b5=self.b5 / s, b6=self.b6 / s**2, b7=self.b7 / s)

    def stack(self, other: "MagicFormulaTyre") -> "MagicFormulaTyre":
        """A tyre per wheel: this one on FL, FR, `other` on RL, RR (fields of shape (4,))."""
        return _stack(self, other)


@dataclass(frozen=True)
class LinearTyre:
    """A linear tyre whose stiffness is proportional to the load (for the exact answers of
    the tests): F_y = c_y F_z tan(alpha), F_x = c_x F_z kappa."""

    c_y: float  # 1/rad, cornering stiffness per unit load
    c_x: float  # 1, slip stiffness per unit load
    sigma_alpha: float = 0.5  # m
    sigma_kappa: float = 0.2  # m

    def lateral(self, tan_alpha, Fz):
        return self.c_y * Fz * tan_alpha

    def longitudinal(self, kappa, Fz):
        return self.c_x * Fz * kappa

    def cornering_stiffness(self, Fz):
        return self.c_y * np.asarray(Fz, float)

    def slip_stiffness(self, Fz):
        return self.c_x * np.asarray(Fz, float)

    def stack(self, other: "LinearTyre") -> "LinearTyre":
        return _stack(self, other)


def _stack(front, rear):
    if type(front) is not type(rear):
        raise TirefilterError("front and rear tyres must be of one kind")
    return type(front)(**{f.name: np.array([getattr(front, f.name)] * 2 + [getattr(rear, f.name)] * 2, float)
                          for f in dataclasses.fields(front)})


# Bakker, Nyborg and Pacejka (1987), "Tyre modelling for use in vehicle dynamics studies",
# SAE 870421: the published passenger-car tyre (camber terms left out). Their relaxation
# lengths are not part of that fit: sigma_alpha 0.5 m and sigma_kappa 0.2 m are of the
# order Pacejka (2012, ch. 7) shows for passenger-car tyres (lateral: about the wheel
# radius and more, longitudinal: well below it).
BAKKER_1987 = MagicFormulaTyre(
    C_y=1.30, a1=-22.1, a2=1011.0, a3=1078.0, a4=1.82, a5=0.208, a6=0.0, a7=-0.354, a8=0.707,
    C_x=1.65, b1=-21.3, b2=1144.0, b3=49.6, b4=226.0, b5=0.069, b6=-0.006, b7=0.056, b8=0.486,
    sigma_alpha=0.5, sigma_kappa=0.2)


@dataclass(frozen=True)
class TwoTrackParams:
    """A car for the two-track model (SI units)."""

    name: str
    mass: float  # kg
    yaw_inertia: float  # kg m^2
    lf: float  # m, centre of gravity to the front axle
    lr: float  # m, centre of gravity to the rear axle
    track_f: float  # m
    track_r: float  # m
    cg_height: float  # m
    wheel_radius: float  # m, rolling radius
    wheel_inertia: float  # kg m^2, spin inertia of one wheel
    drive: str  # "front" | "rear" | "all"
    tyre_f: MagicFormulaTyre | LinearTyre
    tyre_r: MagicFormulaTyre | LinearTyre
    roll_centre_f: float = 0.05  # m, roll-centre height at the front axle
    roll_centre_r: float = 0.10  # m
    roll_gradient: float = 0.0085  # rad per m/s^2 of a^Y (sets the total roll stiffness, `roll_stiffness`)
    roll_share_f: float = 0.6  # front share of the roll stiffness
    pitch_gradient: float = 0.002  # rad of nose-up pitch per m/s^2 of a^X (the IMU's tilt only)
    ackermann: float = 0.5  # share of the Ackermann steer geometry (0: parallel)
    brake_share_f: float = 0.65  # front share of the brake torque
    drag: float = 0.4  # N s^2/m^2, 0.5 rho c_d A
    rolling_resistance: float = 0.012  # f_r
    load_lag: float = 0.05  # s, the lag of the loads and the roll behind the accelerations
    imu_x: float = 0.4  # m, IMU ahead of the centre of gravity
    imu_y: float = 0.0  # m, IMU left of the centre of gravity

    @property
    def wheelbase(self) -> float:
        return self.lf + self.lr

    @property
    def roll_arm(self) -> float:
        """h': height of the centre of gravity above the roll axis [m]."""
        return self.cg_height - (self.roll_centre_f + (self.roll_centre_r - self.roll_centre_f) * self.lf
                                 / self.wheelbase)

    def roll_stiffness(self) -> tuple[float, float]:
        """(K_f, K_r) [N m/rad] that give the roll gradient: phi / a^Y = m h' / (K - m g h')
        (Gillespie ch. 8), split by `roll_share_f`."""
        h = self.roll_arm
        K = self.mass * h * (1.0 / self.roll_gradient + G)
        return self.roll_share_f * K, (1.0 - self.roll_share_f) * K

    def static_wheel_loads(self) -> np.ndarray:
        """(4,) F_z at rest [N], FL, FR, RL, RR."""
        L = self.wheelbase
        f, r = 0.5 * self.mass * G * self.lr / L, 0.5 * self.mass * G * self.lf / L
        return np.array([f, f, r, r])


class Model(NamedTuple):
    """The car's parameters and what the right-hand side needs of them, computed once."""

    p: TwoTrackParams
    x: np.ndarray  # (4,) wheel positions ahead of the centre of gravity [m]
    y: np.ndarray  # (4,) wheel positions left of it [m]
    tyre: MagicFormulaTyre | LinearTyre  # fields (4,)
    Fz0: np.ndarray  # (4,) static loads [N]
    transfer_x: np.ndarray  # (4,) dF_z / da^X [N s^2/m]
    transfer_y: np.ndarray  # (4,) dF_z / da^Y [N s^2/m]
    roll_per_ay: float  # rad per m/s^2
    drive_share: np.ndarray  # (4,) shares of a positive wheel torque
    brake_share: np.ndarray  # (4,) shares of a negative one
    sigma_alpha: np.ndarray  # (4,)
    sigma_kappa: np.ndarray  # (4,)


def make_model(p: TwoTrackParams) -> Model:
    """Precompute the geometry, load transfer and torque split of `p`."""
    if p.drive not in ("front", "rear", "all"):
        raise TirefilterError(f"drive must be front, rear or all, got {p.drive!r}")
    L, m = p.wheelbase, p.mass
    x = np.array([p.lf, p.lf, -p.lr, -p.lr])
    y = np.array([0.5 * p.track_f, -0.5 * p.track_f, 0.5 * p.track_r, -0.5 * p.track_r])
    Kf, Kr = p.roll_stiffness()
    h, K = p.roll_arm, Kf + Kr
    denom = K - m * G * h
    # roll moment per m/s^2 carried by each axle (Gillespie ch. 8), on the outer wheel, off the inner one
    Mf = m * (h * Kf / denom + p.roll_centre_f * p.lr / L)
    Mr = m * (h * Kr / denom + p.roll_centre_r * p.lf / L)
    transfer_y = -np.array([Mf / p.track_f, -Mf / p.track_f, Mr / p.track_r, -Mr / p.track_r])  # a^Y > 0: right gains
    transfer_x = 0.5 * m * p.cg_height / L * np.array([-1.0, -1.0, 1.0, 1.0])
    drive_share = {"front": [0.5, 0.5, 0, 0], "rear": [0, 0, 0.5, 0.5], "all": [0.25] * 4}[p.drive]
    bf = p.brake_share_f
    tyre = p.tyre_f.stack(p.tyre_r)
    return Model(p, x, y, tyre, p.static_wheel_loads(), transfer_x, transfer_y, m * h / denom,
                 np.array(drive_share, float), np.array([bf / 2, bf / 2, (1 - bf) / 2, (1 - bf) / 2]),
                 np.asarray(tyre.sigma_alpha, float), np.asarray(tyre.sigma_kappa, float))


def wheel_steer(delta, model: Model):
    """(..., 4) steer angles of FL, FR, RL, RR for the road-wheel steer delta (...,): the
    front wheels with a share `ackermann` of tan delta_i = L tan delta / (L - y_i tan delta)."""
    delta = np.asarray(delta, float)[..., None]
    p = model.p
    t = np.tan(delta)
    full = np.arctan2(p.wheelbase * t, p.wheelbase - model.y[:2] * t)
    front = delta + p.ackermann * (full - delta)
    return np.concatenate([front, np.zeros_like(front)], axis=-1)


def wheel_loads(ax, ay, model: Model):
    """(..., 4) F_z [N] under the accelerations a^X, a^Y (...,) (the lagged ones of the state):
    static loads plus the quasi-static longitudinal and lateral transfer. They sum to m g."""
    return model.Fz0 + model.transfer_x * np.asarray(ax)[..., None] + model.transfer_y * np.asarray(ay)[..., None]


class Forces(NamedTuple):
    """The intermediate quantities of one right-hand-side evaluation (each (..., 4) per wheel
    or (...,))."""

    steer: np.ndarray  # wheel steer angles
    vxw: np.ndarray  # wheel-centre velocity along the wheel
    vyw: np.ndarray  # across it
    Fz: np.ndarray
    Fxw: np.ndarray  # tyre forces in wheel axes
    Fyw: np.ndarray
    Fx: np.ndarray  # in body axes
    Fy: np.ndarray
    torque: np.ndarray  # wheel torques (drive > 0, brake < 0)
    ax: np.ndarray  # acceleration of the centre of gravity in body axes [m/s^2]
    ay: np.ndarray
    yaw_acc: np.ndarray  # dr/dt [rad/s^2]


def forces(x: np.ndarray, u: np.ndarray, model: Model) -> Forces:
    """The wheels' kinematics, loads and forces and the body's accelerations at state x
    (..., NX) under the input u (..., 2)."""
    p = model.p
    vx, vy, r = x[..., VX, None], x[..., VY, None], x[..., R_, None]
    steer = wheel_steer(u[..., 0], model)
    c, s = np.cos(steer), np.sin(steer)
    vxi, vyi = vx - r * model.y, vy + r * model.x  # wheel centres, body axes
    vxw, vyw = c * vxi + s * vyi, c * vyi - s * vxi
    Fz = wheel_loads(x[..., AX_LAG], x[..., AY_LAG], model)
    Fyw = model.tyre.lateral(x[..., SLIP_Y], Fz)
    Fxw = model.tyre.longitudinal(x[..., SLIP_X], Fz)
    Fx, Fy = c * Fxw - s * Fyw, s * Fxw + c * Fyw
    T = u[..., 1, None]
    torque = T * np.where(T >= 0.0, model.drive_share, model.brake_share)
    v = x[..., VX]
    ax = (np.sum(Fx, axis=-1) - p.drag * v * np.abs(v)) / p.mass
    ay = np.sum(Fy, axis=-1) / p.mass
    yaw_acc = np.sum(model.x * Fy - model.y * Fx, axis=-1) / p.yaw_inertia
    return Forces(steer, vxw, vyw, Fz, Fxw, Fyw, Fx, Fy, torque, ax, ay, yaw_acc)


def rhs(x: np.ndarray, u: np.ndarray, model: Model, f: Forces | None = None) -> np.ndarray:
    """dx/dt (..., NX) at state x (..., NX) under u (..., 2) = [steer (rad), wheel torque (N m)]."""
    p = model.p
    f = forces(x, u, model) if f is None else f
    vx, vy, r, psi = x[..., VX], x[..., VY], x[..., R_], x[..., PSI]
    omega = x[..., OMEGA]
    dx = np.empty_like(x)
    dx[..., VX] = f.ax + r * vy
    dx[..., VY] = f.ay - r * vx
    dx[..., R_] = f.yaw_acc
    dx[..., PSI] = r
    cpsi, spsi = np.cos(psi), np.sin(psi)
    dx[..., X_] = vx * cpsi - vy * spsi
    dx[..., Y_] = vx * spsi + vy * cpsi
    R = p.wheel_radius
    # wheel spin: drive/brake torque, tyre force at the rolling radius, rolling resistance moment
    dx[..., OMEGA] = (f.torque - R * f.Fxw - p.rolling_resistance * R * f.Fz * np.tanh(omega)) / p.wheel_inertia
    speed = np.abs(f.vxw)
    dx[..., SLIP_Y] = (-f.vyw - speed * x[..., SLIP_Y]) / model.sigma_alpha  # relaxation, Pacejka ch. 7
    dx[..., SLIP_X] = (R * omega - f.vxw - speed * x[..., SLIP_X]) / model.sigma_kappa
    dx[..., AX_LAG] = (f.ax - x[..., AX_LAG]) / p.load_lag
    dx[..., AY_LAG] = (f.ay - x[..., AY_LAG]) / p.load_lag
    return dx


def straight_state(v0: float, model: Model) -> np.ndarray:
    """(NX,) straight driving at v0 with the wheels rolling freely (the integration settles the rest)."""
    x = np.zeros(NX)
    x[VX] = v0
    x[OMEGA] = v0 / model.p.wheel_radius
    return x


def resistance(vx, model: Model):
    """Drag and rolling resistance at speed vx [N] (the speed controller's feed-forward)."""
    p = model.p
    return p.drag * vx * np.abs(vx) + p.rolling_resistance * p.mass * G


def imu_point_acceleration(ax, ay, r, yaw_acc, px: float, py: float) -> tuple:
    """Acceleration of the body point (px, py) from the centre of gravity, in body axes:
    a_cg + dr/dt z x p + r z x (r z x p) (planar)."""
    return ax - yaw_acc * py - r * r * px, ay + yaw_acc * px - r * r * py


def specific_force_body(ax, ay, roll, pitch_up):
    """The specific force (a - g) of a point with horizontal acceleration (ax, ay) in the
    axes of a body pitched nose-up by `pitch_up` and rolled by `roll` (positive: the left
    side up, as in a left turn), the yaw frame's axes rotated by pitch then roll."""
    c, s = np.cos(pitch_up), np.sin(pitch_up)
    x1, z1 = c * ax + s * G, -s * ax + c * G  # pitch
    return x1, np.cos(roll) * ay + np.sin(roll) * z1  # roll


def sample(x: np.ndarray, u: np.ndarray, model: Model) -> dict:
    """What a log needs from state x (..., NX) under u (..., 2): references, the IMU's true
    readings (the point (imu_x, imu_y) on the tilted body), axle-mean wheel rates, loads,
    single-track slip angles at the axle centres, and the axles' linear cornering stiffness
    (sum of the two tyres' BCD) at the current loads."""
    p = model.p
    f = forces(x, u, model)
    vx, vy, r = x[..., VX], x[..., VY], x[..., R_]
    delta = u[..., 0]
    ax_p, ay_p = imu_point_acceleration(f.ax, f.ay, r, f.yaw_acc, p.imu_x, p.imu_y)
    roll = model.roll_per_ay * x[..., AY_LAG]  # left side up in a left turn
    pitch_up = p.pitch_gradient * x[..., AX_LAG]
    ax_imu, ay_imu = specific_force_body(ax_p, ay_p, roll, pitch_up)
    C = model.tyre.cornering_stiffness(f.Fz)
    omega = x[..., OMEGA]
    return {"delta": delta, "vx": vx, "vy": vy, "yaw_rate": r, "yaw_acc": f.yaw_acc, "beta": np.arctan2(vy, vx),
            "ax": f.ax, "ay": f.ay, "ax_imu": ax_imu, "ay_imu": ay_imu,
            "yaw_rate_imu": r * np.cos(roll) * np.cos(pitch_up),
            "roll": -roll, "pitch": pitch_up,  # roll with the MB peer's sign (towards +y), pitch nose-up
            "omega_f": 0.5 * (omega[..., 0] + omega[..., 1]), "omega_r": 0.5 * (omega[..., 2] + omega[..., 3]),
            "alpha_f": delta - np.arctan2(vy + p.lf * r, vx), "alpha_r": -np.arctan2(vy - p.lr * r, vx),
            "Fz_f": f.Fz[..., 0] + f.Fz[..., 1], "Fz_r": f.Fz[..., 2] + f.Fz[..., 3],
            "Fy_f": f.Fy[..., 0] + f.Fy[..., 1], "Fy_r": f.Fy[..., 2] + f.Fy[..., 3],
            "Cf_y_load": C[..., 0] + C[..., 1], "Cr_y_load": C[..., 2] + C[..., 3]}


def static_stiffness(model: Model) -> tuple[float, float, float]:
    """The axles' linear cornering stiffness (Cf_y, Cr_y) [N/rad] and the driven axle's slip
    stiffness Cx [N per unit slip] at the static loads: sums of the tyres' BCD."""
    C = model.tyre.cornering_stiffness(model.Fz0)
    K = model.tyre.slip_stiffness(model.Fz0)
    return float(C[0] + C[1]), float(C[2] + C[3]), float(np.sum(K * (model.drive_share > 0)))


def rk4(x: np.ndarray, h: float, u1, u2, u3, model: Model) -> np.ndarray:
    """One classical RK4 step from x with the input laws u1, u2, u3 (state -> input) at t,
    t + h/2 and t + h."""
    k1 = rhs(x, u1(x), model)
    y = x + 0.5 * h * k1
    k2 = rhs(y, u2(y), model)
    y = x + 0.5 * h * k2
    k3 = rhs(y, u2(y), model)
    y = x + h * k3
    k4 = rhs(y, u3(y), model)
    return x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


# ---- the three cars --------------------------------------------------------------------------------
# Mass, yaw inertia, axle distances, tracks, centre-of-gravity height, wheel radius and wheel
# spin inertia: the CommonRoad vehicle models' parameter sets 1-3 (vehiclemodels 3.0,
# `setup_vehicle_parameters`: m, I_z, a, b, T_f, T_r, h_cg, R_w, I_y_w), the cars of the
# other peer drives. The rest is not in those sets and is chosen here:
# - tyres: the Bakker-Nyborg-Pacejka (1987) tyre, and for cars 2 and 3 the same tyre with
#   the Magic Formula's scaling factors (`MagicFormulaTyre.scaled`): car 2 a stiffer,
#   grippier low-profile tyre (cornering x 1.15, friction x 1.05), car 3 a light-truck tyre
#   rated for more load (load axis x 1.3, cornering x 0.95, friction x 0.95);
# - roll: roll gradients inside the 3-7 deg/g Gillespie (ch. 8) gives for passenger cars
#   (0.0085 rad/(m/s^2) = 4.8 deg/g; the van 0.011 = 6.2 deg/g), 60 % (van 55 %) of the roll
#   stiffness at the front, roll centres 0.05 m (front) and 0.10 m (rear) high;
# - drag 0.5 rho c_d A with rho = 1.2 kg/m^3 and period figures (Escort c_d 0.36, A 1.9 m^2;
#   320i 0.38, 1.86 m^2; Vanagon 0.44, 2.8 m^2), rolling resistance 0.012 (Gillespie ch. 4:
#   0.01-0.015 for radial car tyres);
# - the IMU 0.4 m ahead of the centre of gravity (car 2 also 0.1 m to the left, car 3 0.1 m
#   to the right), where a console-mounted unit sits.
VEHICLES_TT = {
    1: TwoTrackParams(name="Ford Escort", mass=1225.888, yaw_inertia=1538.853, lf=0.88392, lr=1.50876,
                      track_f=1.389888, track_r=1.423416, cg_height=0.557784, wheel_radius=0.344, wheel_inertia=1.7,
                      drive="front", tyre_f=BAKKER_1987, tyre_r=BAKKER_1987, drag=0.41, imu_x=0.4, imu_y=0.0),
    2: TwoTrackParams(name="BMW 320i", mass=1093.295, yaw_inertia=1791.600, lf=1.156196, lr=1.422717,
                      track_f=1.38684, track_r=1.36398, cg_height=0.574869, wheel_radius=0.344, wheel_inertia=1.7,
                      drive="rear", tyre_f=BAKKER_1987.scaled(cornering=1.15, friction=1.05),
                      tyre_r=BAKKER_1987.scaled(cornering=1.15, friction=1.05), drag=0.42, imu_x=0.4, imu_y=0.1),
    3: TwoTrackParams(name="VW Vanagon", mass=1478.898, yaw_inertia=2473.118, lf=1.150792, lr=1.321136,
                      track_f=1.574292, track_r=1.543812, cg_height=0.747817, wheel_radius=0.344, wheel_inertia=1.7,
                      drive="rear", tyre_f=BAKKER_1987.scaled(load=1.3, cornering=0.95, friction=0.95),
                      tyre_r=BAKKER_1987.scaled(load=1.3, cornering=0.95, friction=0.95), roll_gradient=0.011,
                      roll_share_f=0.55, drag=0.74, imu_x=0.4, imu_y=-0.1),
}


def load_two_track(vehicle_id: int, imu_x: float | None = None, imu_y: float | None = None) -> Model:
    """The two-track model of car `vehicle_id` (1, 2, 3), the IMU optionally moved."""
    if vehicle_id not in VEHICLES_TT:
        raise TirefilterError(f"two-track vehicle must be one of {', '.join(map(str, VEHICLES_TT))}, "
                              f"got {vehicle_id!r}")
    p = VEHICLES_TT[vehicle_id]
    moved = {k: v for k, v in (("imu_x", imu_x), ("imu_y", imu_y)) if v is not None}
    return make_model(dataclasses.replace(p, **moved) if moved else p)
