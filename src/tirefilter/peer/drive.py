"""A peer drive: integrate a peer model under a maneuver, sample it at 100 Hz, add the
sensors, and write the Log CSV (docs/usage.md, "Replaying recorded logs") and a vehicle TOML of data-sheet
values. The CommonRoad models (`model`) are integrated here; the two-track model (`--model
tt`) in `two_track_drive`, with the same maneuvers, rate, settling and sensors, the IMU off
the centre of gravity and, by default, the logger's dropouts (`with_dropouts`).

Integration: classical Runge-Kutta (RK4) with a fixed step of 1 ms (10 steps per sample;
the fastest mode, the wheel spin of ~300 1/s at 15 m/s, gives h*lambda ~ 0.3) after 2 s of
settling at the initial speed (the MB model starts off its static equilibrium). The
driver: the steering rate input is the profile's rate plus a 20 1/s correction towards
the profile's steer; the acceleration input holds the set speed (its rate plus 1 1/s
times the speed error). Both pass the peer's own input constraints.

Log columns: `t, delta, ax, ay, yaw_rate, vx, omega_f, omega_r` (road-wheel steer, the
IMU's readings with bias and noise, the model's v^X, axle-mean wheel rates with noise),
then references: `beta_true, vx_true, vy_true, yaw_rate_true, ax_true, ay_true,
alpha_f_true, alpha_r_true, roll_true, Cf_y_true, Cr_y_true, Cx_true, Fz_f_true, Fz_r_true,
b_ax_true, b_ay_true, b_yaw_rate_true, Cf_y_eff_true, Cr_y_eff_true` (biases = measured -
true IMU reading; for the MB model the true IMU lateral reading includes g sin(roll),
which is no bias). `C*_y_true` is the tires' linear-region stiffness at the actual axle
load (derivations: "Peer drives"); `C*_y_eff_true` the effective axle stiffness of the
whole drive (`model.effective_stiffness`, one value repeated), which differs from it where
the MB model's camber thrust is on (`--camber continuous|peer`; the default is off).
"""

from __future__ import annotations

import math
import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tirefilter.errors import TirefilterError
from tirefilter.peer.maneuvers import Profile, make_profile
from tirefilter.peer.model import VEHICLES, PeerModel, effective_stiffness, load_model
from tirefilter.peer.sensors import DropoutSpec, SensorSpec, dropouts, measure

RATE = 100.0  # Hz, log sample rate
SUBSTEPS = 10  # RK4 steps per sample (h = 1 ms)
SETTLE = 2.0  # s of straight driving before t = 0
K_STEER = 20.0  # 1/s, steering correction towards the profile
K_SPEED = 1.0  # 1/s, cruise control gain
# The nominal stiffness a user would guess (vehicle TOML), not the peer's truth: a cornering
# coefficient of CORNERING_PER_DEG per degree of slip per unit axle load (passenger-car radial
# tires, rule of thumb 0.15-0.3 /deg), and a slip stiffness of LONGITUDINAL_PER_LOAD times
# the driven axle's static load.
CORNERING_PER_DEG = 0.25
LONGITUDINAL_PER_LOAD = 20.0
G = 9.81  # m/s^2, for the guessed static loads

LOG_COLUMNS = ("t", "delta", "ax", "ay", "yaw_rate", "vx", "omega_f", "omega_r")
TRUE_COLUMNS = ("beta", "vx", "vy", "yaw_rate", "ax", "ay", "alpha_f", "alpha_r", "roll", "Cf_y", "Cr_y", "Cx",
                "Fz_f", "Fz_r")


@dataclass(frozen=True)
class DriveSpec:
    """What to generate (the options of `tirefilter peer-drive`)."""

    model: str = "std"  # "std" | "mb" | "tt" (the two-track model, `two_track`)
    vehicle: int = 2  # peer parameter set 1, 2, 3
    maneuver: str = "sine"
    duration: float = 40.0  # s
    seed: int = 0
    speed: float = 20.0  # m/s, set speed
    ay: float = 3.0  # m/s^2, peak lateral acceleration in steady state
    straight: float = 4.0  # s of straight driving at the start
    sensors: SensorSpec = field(default_factory=SensorSpec)
    camber: str = "off"  # MB tire camber terms: "continuous" | "peer" | "off" (model.load_model)
    cornering_per_deg: float = CORNERING_PER_DEG  # the user's guess of the nominal stiffness
    roll_gradient_in_vehicle: bool = False  # write the MB model's measured roll gradient into the vehicle TOML
    dropouts: str = "auto"  # logger dropouts (sensors.DropoutSpec): "on" | "off" | "auto" (on for tt only)
    imu_x: float | None = None  # m, tt only: the IMU ahead of the CG (None: the car's, two_track.VEHICLES_TT)
    imu_y: float | None = None  # m, tt only: the IMU left of the CG
    relaxation_in_vehicle: bool = False  # tt only: write the tyres' relaxation length into the vehicle TOML


@dataclass
class PeerDrive:
    spec: DriveSpec
    model: PeerModel  # a two_track.Model for tt
    columns: dict  # Log CSV columns, (n,) each
    vehicle: dict  # vehicle TOML values
    roll_gradient: float  # rad per m/s^2, least-squares roll / a^Y of the drive (0 for STD; the model's for tt)
    dropped: tuple[int, int] = (0, 0)  # rows and cells the logger dropped


DROPOUTS = ("auto", "on", "off")


def _check(spec: DriveSpec) -> None:
    if spec.dropouts not in DROPOUTS:
        raise TirefilterError(f"dropouts must be one of {', '.join(DROPOUTS)}, got {spec.dropouts!r}")
    if spec.model != "tt" and (spec.imu_x is not None or spec.imu_y is not None):
        raise TirefilterError(f"the IMU position can be set for the two-track model (tt) only, not {spec.model}")


def steer_gain(model: PeerModel):
    """v -> steady-state road-wheel steer per m/s^2 of lateral acceleration, (L + K_us v^2) / v^2,
    from the peer's static linear stiffness."""
    p, L = model.p, model.wheelbase
    Cf, Cr = model.static_stiffness()
    k_us = p.m * (p.b / Cf - p.a / Cr) / L
    return lambda v: (L + k_us * v * v) / (v * v)


def rk4_step(rhs, p, x: list, h: float, u1, u2, u3) -> list:
    """One classical RK4 step of dx/dt = rhs(x, u(x), p) from the state x (a list of floats)
    with the input laws u1, u2, u3 (state -> [steering rate, acceleration]) at t, t + h/2 and
    t + h. Each call of the peer's right-hand side gets a fresh list (it may clip its argument
    in place). The operations are those of the numpy form x + (h/2) k1, ..., x + (h/6) (((k1 +
    2 k2) + 2 k3) + k4), element by element and in the same order, so the result is
    bit-identical to it (tests/test_peer_drive.py)."""
    h2, h6 = 0.5 * h, h / 6.0
    k1 = rhs(list(x), u1(x), p)
    y = [a + h2 * b for a, b in zip(x, k1)]
    k2 = rhs(y, u2(y), p)
    y = [a + h2 * b for a, b in zip(x, k2)]
    k3 = rhs(y, u2(y), p)
    y = [a + h * b for a, b in zip(x, k3)]
    k4 = rhs(y, u3(y), p)
    return [a + h6 * (b1 + 2 * b2 + 2 * b3 + b4) for a, b1, b2, b3, b4 in zip(x, k1, k2, k3, k4)]


def integrate(model: PeerModel, profile: Profile, rate: float = RATE, substeps: int = SUBSTEPS) -> tuple:
    """States and inputs at the samples t = k / rate inside the profile: (t (n,), X (n, nx),
    U (n, 2)). The profile's grid must be h / 2 with h = 1 / (rate substeps).

    The state, the inputs and the stages stay Python floats (`rk4_step`): the peer's right-hand
    side is pure Python, and numpy scalars in its inputs made each of its operations a numpy-scalar
    operation (an STD call 24 instead of 16 us); the drives are bit-identical to the numpy form's
    (docs/development.md, "How long `make test` takes")."""
    h = 1.0 / (rate * substeps)
    if abs(profile.dt - h / 2) > 1e-12:
        raise ValueError(f"profile grid {profile.dt} s, expected {h / 2} s")
    d, dd = profile.delta.tolist(), profile.delta_rate.tolist()
    v, dv = profile.speed.tolist(), profile.speed_rate.tolist()
    rhs, p = model.rhs_function(), model.p

    def control(j):  # j: index on the half-step grid
        ddj, dj, dvj, vj = dd[j], d[j], dv[j], v[j]
        return lambda x: [ddj + K_STEER * (dj - x[2]), dvj + K_SPEED * (vj - x[3])]

    x = model.initial_state(v[0]).tolist()
    # settle: straight at the initial set speed (the grid's first point held)
    settle_u = lambda x: [K_STEER * (d[0] - x[2]), K_SPEED * (v[0] - x[3])]  # noqa: E731
    for _ in range(int(round(SETTLE / h))):
        x = rk4_step(rhs, p, x, h, settle_u, settle_u, settle_u)
    n = int(math.floor(profile.t[-1] * rate + 1e-6)) + 1  # samples up to the profile's end
    X = np.empty((n, len(x)))
    U = np.empty((n, 2))
    for k in range(n):
        X[k] = x
        U[k] = control(2 * k * substeps)(x)
        if k == n - 1:
            break
        for s in range(substeps):
            j = 2 * (k * substeps + s)
            x = rk4_step(rhs, p, x, h, control(j), control(j + 1), control(j + 2))
        if not all(map(math.isfinite, x)):
            raise TirefilterError(f"peer model {model.kind} (vehicle {model.vehicle_id}) diverged "
                                  f"at t = {k / rate:g} s")
    return np.arange(n) / rate, X, U


def trajectory(spec: DriveSpec, model: PeerModel) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.random.SeedSequence]:
    """The drive's maneuver integrated on `model`: times, states and controls at the sample
    rate, and the seed left for the sensors (one `SeedSequence(spec.seed)` spawns both)."""
    maneuver_seed, sensor_seed = np.random.SeedSequence(spec.seed).spawn(2)
    profile = make_profile(spec.maneuver, spec.duration, speed=spec.speed, ay=spec.ay, steer_gain=steer_gain(model),
                           straight=spec.straight, dt=0.5 / (RATE * SUBSTEPS),
                           rng=np.random.default_rng(maneuver_seed))
    t, X, U = integrate(model, profile)
    return t, X, U, sensor_seed


def simulate(spec: DriveSpec) -> PeerDrive:
    """Generate the drive `spec`: integrate, sample, add the sensors (and the logger's
    dropouts where `spec.dropouts` has them)."""
    _check(spec)
    if spec.model == "tt":
        drive = _simulate_tt(spec)
    else:
        model = load_model(spec.model, spec.vehicle, spec.camber)
        t, X, U, sensor_seed = trajectory(spec, model)
        rows = [model.sample(x, u) for x, u in zip(X, U)]
        true = {key: np.array([r[key] for r in rows]) for key in rows[0]}
        meas, bias = measure(t, true, spec.sensors, sensor_seed)
        columns = _columns(t, true, meas, bias, effective_stiffness(model, true))
        turning = np.abs(true["ay"]) > 0.5
        roll_gradient = (float(-np.sum(true["roll"][turning] * true["ay"][turning]) / np.sum(true["ay"][turning] ** 2))
                         if spec.model == "mb" and turning.any() else 0.0)  # outward roll is -x[6] for a^Y > 0
        drive = PeerDrive(spec, model, columns, vehicle_values(model, spec, roll_gradient), roll_gradient)
    return with_dropouts(drive) if spec.dropouts == "on" or (spec.dropouts == "auto" and spec.model == "tt") else drive


def _columns(t, true: dict, meas: dict, bias: np.ndarray, eff: tuple[float, float]) -> dict:
    columns = {"t": t, "delta": true["delta"], "ax": meas["ax"], "ay": meas["ay"], "yaw_rate": meas["yaw_rate"],
               "vx": true["vx"], "omega_f": meas["omega_f"], "omega_r": meas["omega_r"]}
    columns.update({f"{name}_true": true[name] for name in TRUE_COLUMNS})
    columns.update({f"b_{name}_true": bias[:, i] for i, name in enumerate(("ax", "ay", "yaw_rate"))})
    columns["Cf_y_eff_true"] = np.full(t.size, eff[0])
    columns["Cr_y_eff_true"] = np.full(t.size, eff[1])
    return columns


def _simulate_tt(spec: DriveSpec) -> PeerDrive:
    from tirefilter.peer import two_track_drive as ttd

    model = ttd.load(spec)
    t, X, U, sensor_seed = ttd.trajectory_tt(spec, model, rate=RATE, substeps=SUBSTEPS, settle=SETTLE, k_speed=K_SPEED)
    true = ttd.true_values(model, X, U)
    meas, bias = measure(t, true, spec.sensors, sensor_seed)
    columns = _columns(t, true, meas, bias, ttd.effective_stiffness_tt(model, true))
    columns.update({f"{name}_true": true[name] for name in ttd.TT_TRUE_EXTRA})
    return PeerDrive(spec, model, columns, vehicle_values(model, spec, model.roll_per_ay), model.roll_per_ay)


def with_dropouts(drive: PeerDrive, spec: DropoutSpec = DropoutSpec()) -> PeerDrive:
    """`drive` as a data logger with dropouts records it (`sensors.dropouts`, the third
    child of the drive's seed): rows removed, signal cells empty; the gap starts after the
    straight start."""
    c = drive.columns
    keep, blank = dropouts(c["t"], spec, np.random.SeedSequence(drive.spec.seed).spawn(3)[2],
                           after=drive.spec.straight)
    columns = {}
    for name, values in c.items():
        values = np.array(values, float)
        if name in blank:
            values[blank[name]] = math.nan
        columns[name] = values[keep]
    cells = int(sum(np.count_nonzero(b[keep]) for b in blank.values()))
    return dataclasses.replace(drive, columns=columns, dropped=(int(keep.size - np.count_nonzero(keep)), cells))


def vehicle_values(model: PeerModel, spec: DriveSpec, roll_gradient: float = 0.0) -> dict:
    """The vehicle TOML a user would write from the data sheet: the peer's published mass,
    yaw inertia, axle distances, wheel radius, centre-of-gravity height and driven axle,
    and nominal stiffness guessed by the rule of thumb (CORNERING_PER_DEG,
    LONGITUDINAL_PER_LOAD) from the static axle loads; for the two-track model also the
    IMU's mounting position. No sensor noise, no bias keys."""
    if spec.model == "tt":
        return _vehicle_values_tt(model, spec, roll_gradient)
    p = model.p
    L = p.a + p.b
    Ff, Fr = p.m * G * p.b / L, p.m * G * p.a / L
    k = spec.cornering_per_deg * 180.0 / math.pi
    values = {"mass": float(p.m), "yaw_inertia": float(p.I_z), "lf": float(p.a), "lr": float(p.b),
              "wheel_radius": float(p.R_w), "cg_height": float(p.h_cg), "drive": model.drive,
              "Cf_y": round(k * Ff, -2), "Cr_y": round(k * Fr, -2),
              "Cx": round(LONGITUDINAL_PER_LOAD * model.driven_load(Ff, Fr), -2)}
    if spec.roll_gradient_in_vehicle and roll_gradient > 0:
        values["roll_gradient"] = round(roll_gradient, 5)
    return values


def _vehicle_values_tt(model, spec: DriveSpec, roll_gradient: float) -> dict:
    p = model.p
    L = p.wheelbase
    Ff, Fr = p.mass * G * p.lr / L, p.mass * G * p.lf / L
    k = spec.cornering_per_deg * 180.0 / math.pi
    driven = {"front": Ff, "rear": Fr}.get(p.drive, Ff + Fr)
    values = {"mass": float(p.mass), "yaw_inertia": float(p.yaw_inertia), "lf": float(p.lf), "lr": float(p.lr),
              "wheel_radius": float(p.wheel_radius), "cg_height": float(p.cg_height), "drive": p.drive,
              "Cf_y": round(k * Ff, -2), "Cr_y": round(k * Fr, -2), "Cx": round(LONGITUDINAL_PER_LOAD * driven, -2),
              "imu_x": float(p.imu_x), "imu_y": float(p.imu_y)}
    if spec.relaxation_in_vehicle:
        values["relaxation_length"] = float(np.max(p.tyre_f.sigma_alpha))
    if spec.roll_gradient_in_vehicle and roll_gradient > 0:
        values["roll_gradient"] = round(roll_gradient, 5)
    return values


def vehicle_toml(drive: PeerDrive) -> str:
    """The vehicle TOML text, with the source of each value."""
    if drive.spec.model == "tt":
        return _vehicle_toml_tt(drive)
    s, v, p = drive.spec, drive.vehicle, drive.model.p
    lines = [f"# {VEHICLES[s.vehicle]}: data-sheet values of the CommonRoad vehicle models' parameter set "
             f"{s.vehicle} (vehiclemodels)",
             f"# written by `tirefilter peer-drive` for the {s.model.upper()} model; no sensor noise or bias keys.",
             f'mass = {v["mass"]!r}  # kg',
             f'yaw_inertia = {v["yaw_inertia"]!r}  # kg m^2',
             f'lf = {v["lf"]!r}  # m',
             f'lr = {v["lr"]!r}  # m',
             f'wheel_radius = {v["wheel_radius"]!r}  # m',
             f'cg_height = {v["cg_height"]!r}  # m',
             f'drive = "{v["drive"]}"  # engine-torque split T_se = {float(p.T_se):g}',
             f'# guessed, not the truth: cornering coefficient {s.cornering_per_deg:g} per degree of slip angle '
             f'times the static axle load ({s.cornering_per_deg * 180 / math.pi:.3g} per rad)',
             f'Cf_y = {v["Cf_y"]!r}  # N/rad',
             f'Cr_y = {v["Cr_y"]!r}  # N/rad',
             f'Cx = {v["Cx"]!r}  # N per unit slip: guessed, {LONGITUDINAL_PER_LOAD:g} x the driven axle\'s '
             'static load']
    if "roll_gradient" in v:
        lines.append(f'roll_gradient = {v["roll_gradient"]!r}  # rad per m/s^2, measured on this drive '
                     '(not a data-sheet value)')
    return "\n".join(lines) + "\n"


def _vehicle_toml_tt(drive: PeerDrive) -> str:
    s, v = drive.spec, drive.vehicle
    lines = [f"# {VEHICLES[s.vehicle]}: data-sheet values of the two-track peer car {s.vehicle} (mass, inertia and "
             "geometry of the CommonRoad parameter set of that number)",
             "# written by `tirefilter peer-drive` for the TT model; no sensor noise or bias keys.",
             f'mass = {v["mass"]!r}  # kg',
             f'yaw_inertia = {v["yaw_inertia"]!r}  # kg m^2',
             f'lf = {v["lf"]!r}  # m',
             f'lr = {v["lr"]!r}  # m',
             f'wheel_radius = {v["wheel_radius"]!r}  # m',
             f'cg_height = {v["cg_height"]!r}  # m',
             f'drive = "{v["drive"]}"',
             f'# guessed, not the truth: cornering coefficient {s.cornering_per_deg:g} per degree of slip angle '
             f'times the static axle load ({s.cornering_per_deg * 180 / math.pi:.3g} per rad)',
             f'Cf_y = {v["Cf_y"]!r}  # N/rad',
             f'Cr_y = {v["Cr_y"]!r}  # N/rad',
             f'Cx = {v["Cx"]!r}  # N per unit slip: guessed, {LONGITUDINAL_PER_LOAD:g} x the driven axle\'s '
             'static load',
             f'imu_x = {v["imu_x"]!r}  # m, IMU mounting position ahead of the CG',
             f'imu_y = {v["imu_y"]!r}  # m, IMU mounting position left of the CG']
    if "relaxation_length" in v:
        lines.append(f'relaxation_length = {v["relaxation_length"]!r}  # m, the tyres\' lateral relaxation length '
                     '(tyre data)')
    if "roll_gradient" in v:
        lines.append(f'roll_gradient = {v["roll_gradient"]!r}  # rad per m/s^2, the model\'s (not a data-sheet '
                     'value)')
    return "\n".join(lines) + "\n"


def write_drive(drive: PeerDrive, log_path: str | Path,
                vehicle_path: str | Path | None = None) -> tuple[Path, Path | None]:
    """Write the Log CSV (and the vehicle TOML when `vehicle_path` is given)."""
    from tirefilter.io.log import write_log

    log_path = write_log(log_path, drive.columns)
    if vehicle_path is not None:
        vehicle_path = Path(vehicle_path)
        vehicle_path.parent.mkdir(parents=True, exist_ok=True)
        vehicle_path.write_text(vehicle_toml(drive))
    return log_path, vehicle_path


def describe(drive: PeerDrive) -> str:
    """A few lines on the drive: truth ranges, stiffness, biases, the guess."""
    c, s, v = drive.columns, drive.spec, drive.vehicle
    t = c["t"]
    cf, cr = c["Cf_y_true"], c["Cr_y_true"]
    lines = [f"peer drive: {s.model.upper()} model, vehicle {s.vehicle} ({VEHICLES[s.vehicle]}), "
             f"maneuver {s.maneuver}, {t[-1]:g} s at {RATE:g} Hz, seed {s.seed}",
             f"  |a^Y| max {np.max(np.abs(c['ay_true'])):.2f} m/s^2, v^X {np.min(c['vx_true']):.1f}-"
             f"{np.max(c['vx_true']):.1f} m/s, |beta| max {np.degrees(np.max(np.abs(c['beta_true']))):.2f} deg, "
             f"|alpha_f| max {np.degrees(np.max(np.abs(c['alpha_f_true']))):.2f} deg",
             f"  true stiffness Cf_y {np.mean(cf):.4g} ({np.min(cf):.4g}-{np.max(cf):.4g}), "
             f"Cr_y {np.mean(cr):.4g} ({np.min(cr):.4g}-{np.max(cr):.4g}) N/rad; "
             f"vehicle TOML guess Cf_y {v['Cf_y']:.4g} ({100 * (v['Cf_y'] / np.mean(cf) - 1):+.0f} %), "
             f"Cr_y {v['Cr_y']:.4g} ({100 * (v['Cr_y'] / np.mean(cr) - 1):+.0f} %)",
             f"  effective axle stiffness of the drive (least squares on the peer's forces): Cf_y "
             f"{c['Cf_y_eff_true'][0]:.4g} ({100 * (c['Cf_y_eff_true'][0] / np.mean(cf) - 1):+.1f} %), Cr_y "
             f"{c['Cr_y_eff_true'][0]:.4g} ({100 * (c['Cr_y_eff_true'][0] / np.mean(cr) - 1):+.1f} %)"
             + (f", camber {s.camber}" if s.model == "mb" else ""),
             f"  IMU bias at t = 0: b_ax {c['b_ax_true'][0]:+.3f} m/s^2, b_ay {c['b_ay_true'][0]:+.3f} m/s^2, "
             f"b_yaw_rate {c['b_yaw_rate_true'][0]:+.4f} rad/s; noise std {s.sensors.sigma[0]:g}, "
             f"{s.sensors.sigma[1]:g} m/s^2, {s.sensors.sigma[2]:g} rad/s"]
    if s.model == "tt":
        p = drive.model.p
        lines.append(f"  two-track: IMU at ({p.imu_x:g}, {p.imu_y:g}) m from the CG, true Cf_y "
                     f"{c['Cf_y_true'][0]:.4g}, Cr_y {c['Cr_y_true'][0]:.4g} N/rad at the static loads, at the "
                     f"current loads {np.min(c['Cf_y_load_true']):.4g}-{np.max(c['Cf_y_load_true']):.4g} and "
                     f"{np.min(c['Cr_y_load_true']):.4g}-{np.max(c['Cr_y_load_true']):.4g}")
    if any(drive.dropped):
        lines.append(f"  logger dropouts: {drive.dropped[0]} rows missing (one gap among them), "
                     f"{drive.dropped[1]} empty cells")
    if s.model in ("mb", "tt"):
        lines.append(f"  body roll {drive.roll_gradient:.4f} rad per m/s^2 (the IMU's a^Y reads about "
                     f"{1 + G * drive.roll_gradient:.3f} x a^Y)")
    return "\n".join(lines)
