"""Vehicle, tire and sensor parameters: typed, immutable, validated on load."""

from __future__ import annotations

from dataclasses import MISSING, dataclass, fields
from pathlib import Path

from tirefilter.config import check_known_keys, get_choice, get_number, read_toml

DRIVES = ("front", "rear", "all")


@dataclass(frozen=True)
class VehicleParams:
    """Single-track vehicle (keys of the vehicle TOML, docs/design.md)."""

    mass: float  # kg
    yaw_inertia: float  # kg m^2
    lf: float  # m, CG to front axle
    lr: float  # m, CG to rear axle
    wheel_radius: float  # m
    cg_height: float  # m
    Cf_y: float  # N/rad, nominal front axle cornering stiffness
    Cr_y: float  # N/rad, nominal rear axle cornering stiffness
    Cx: float  # N per unit slip, nominal longitudinal stiffness of the driven axle
    drive: str = "front"  # "front" | "rear" | "all"
    steering_ratio: float | None = None  # steering-wheel angle / road-wheel angle
    # rad of roll per m/s^2 of lateral acceleration: the IMU reads (1 + k g) a^Y; None (absent): the MPF estimates
    # it (derivations, "The roll gain from the data"), the other estimators and the simulator take 0
    roll_gradient: float | None = None
    imu_x: float = 0.0  # m, IMU ahead of the CG
    imu_y: float = 0.0  # m, IMU left of the CG
    # m, the tyres' lateral relaxation length: the slip the force follows lags the kinematic one by
    # relaxation_length / v^X (derivations, "Tyre relaxation"); 0 (absent): at once, the paper's model
    relaxation_length: float = 0.0
    # s^4/m^2, the load sensitivity kappa of the axles' effective stiffness C_0 (1 - kappa a^Y^2) (derivations,
    # "Load transfer") where the MPF's `load_sensitivity_estimate` is on; None (absent): the MPF estimates it;
    # 0: the paper's linear axle
    load_sensitivity: float | None = None
    # IMU white-noise std; None (absent): estimated from the data (estimators.sensors)
    sigma_ax: float | None = None  # m/s^2
    sigma_ay: float | None = None  # m/s^2
    sigma_yaw_rate: float | None = None  # rad/s
    # IMU bias prior std and random walk; None (absent): automotive MEMS defaults
    # (estimators.sensors); bias estimation is on unless all are 0
    bias0_std_ax: float | None = None  # m/s^2
    bias0_std_ay: float | None = None  # m/s^2
    bias0_std_yaw_rate: float | None = None  # rad/s
    bias_rw_ax: float | None = None  # m/s^2 per sqrt(s)
    bias_rw_ay: float | None = None  # m/s^2 per sqrt(s)
    bias_rw_yaw_rate: float | None = None  # rad/s per sqrt(s)
    # Truth-model details (optional keys, used by the vehicle FMU):
    Cx_undriven: float | None = None  # N, longitudinal stiffness of the other axle (default Cx)
    wheel_inertia_f: float = 3.6  # kg m^2, front axle spin inertia (both wheels)
    wheel_inertia_r: float = 3.6  # kg m^2
    brake_front_share: float = 0.6  # share of brake torque on the front axle
    awd_front_share: float = 0.5  # share of drive torque on the front axle (drive = "all")
    rolling_resistance: float = 0.0  # rolling-resistance coefficient
    drag_coefficient: float = 0.0  # N s^2/m^2, 0.5 rho cd A

    @property
    def wheelbase(self) -> float:
        return self.lf + self.lr

    def imu_roll_gain(self, g: float = 9.80665) -> float:
        """The IMU's gain on a^Y from body roll, 1 + k g (k = `roll_gradient`, 0 when absent)."""
        return 1.0 + (0.0 if self.roll_gradient is None else self.roll_gradient) * g

    def static_axle_loads(self, g: float = 9.80665) -> tuple[float, float]:
        """Front and rear static normal loads [N]."""
        return self.mass * g * self.lr / self.wheelbase, self.mass * g * self.lf / self.wheelbase


@dataclass(frozen=True)
class PacejkaParams:
    """Magic Formula F = D sin(C atan(B s - E (B s - atan(B s)))), D = mu Fz, per direction,
    with the combined-slip weighting functions of Pacejka (2006), Sec. 4.3.2."""

    mu_x: float
    B_x: float
    C_x: float
    E_x: float
    mu_y: float
    B_y: float
    C_y: float
    E_y: float
    rBx1: float = 0.0
    rBx2: float = 0.0
    Cxa: float = 1.0
    rBy1: float = 0.0
    rBy2: float = 0.0
    Cyk: float = 1.0

    def lateral_stiffness(self, Fz: float) -> float:
        """Initial slope B C D of the lateral curve at load Fz [N/rad]."""
        return self.B_y * self.C_y * self.mu_y * Fz

    def longitudinal_stiffness(self, Fz: float) -> float:
        return self.B_x * self.C_x * self.mu_x * Fz


@dataclass(frozen=True)
class SensorSpec:
    """Which signals exist and how noisy they are (white noise and random-walk bias)."""

    available: tuple[str, ...] = ("ax", "ay", "yaw_rate", "omega_f", "omega_r", "delta")
    sigma_ax: float = 0.05  # m/s^2
    sigma_ay: float = 0.05  # m/s^2
    sigma_yaw_rate: float = 0.0035  # rad/s
    sigma_omega: float = 0.0  # rad/s
    sigma_delta: float = 0.0  # rad
    bias_rw_ax: float = 0.0  # m/s^2 per sqrt(s)
    bias_rw_ay: float = 0.0
    bias_rw_yaw_rate: float = 0.0  # rad/s per sqrt(s)
    bias0_ax: float = 0.0  # m/s^2, initial bias mean
    bias0_ay: float = 0.0
    bias0_yaw_rate: float = 0.0  # rad/s
    bias0_std_ax: float = 0.0
    bias0_std_ay: float = 0.0
    bias0_std_yaw_rate: float = 0.0


_POSITIVE = ("mass", "yaw_inertia", "lf", "lr", "wheel_radius", "Cf_y", "Cr_y", "Cx",
             "wheel_inertia_f", "wheel_inertia_r")


def load_vehicle(path: str | Path) -> VehicleParams:
    """Read and check a vehicle TOML (docs/design.md keys, SI units)."""
    return vehicle_from_dict(read_toml(path), path)


def vehicle_from_dict(data: dict, path) -> VehicleParams:
    """Check the keys of a vehicle TOML given as a dict (`path` names the source in errors:
    a file, or e.g. the FMU whose parameters they are)."""
    known = {f.name for f in fields(VehicleParams)}
    check_known_keys(data, known, path)
    values = {}
    for f in fields(VehicleParams):
        if f.name == "drive":
            values["drive"] = get_choice(data, "drive", path, DRIVES, default="front")
            continue
        kwargs = {} if f.default is MISSING else {"default": f.default}
        lo, lo_open, hi = None, False, None
        if f.name in _POSITIVE or f.name in ("steering_ratio", "Cx_undriven") or f.name.startswith("sigma"):
            lo, lo_open = 0.0, True
        elif f.name in ("cg_height", "rolling_resistance", "drag_coefficient", "roll_gradient",
                        "relaxation_length", "load_sensitivity") or f.name.startswith(
                "bias"):
            lo = 0.0
        if f.name in ("brake_front_share", "awd_front_share"):
            lo, hi = 0.0, 1.0
        if f.name == "roll_gradient":
            hi = 0.05
        if f.name == "relaxation_length":
            hi = 5.0
        if f.name == "load_sensitivity":
            hi = 0.05
        values[f.name] = get_number(data, f.name, path, lo=lo, lo_open=lo_open, hi=hi, **kwargs)
    return VehicleParams(**values)
