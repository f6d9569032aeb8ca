"""What the baseline estimators (augpf, rls, ekf) share with the stiffness MPF: the
configuration conventions (initial stiffness, sensors, gate, parameter projection), the
learning gate, and the initial stiffness distribution.

The baselines take their scenario- and log-dependent options from the MPF's builders
(`mpf_config_for_scenario`, `mpf_config_for_log`): `shared_options` copies the fields that
mean the same thing into a baseline's own configuration, so every estimator of a study
starts from the same prior, the same sensor noise and the same gate.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from tirefilter.errors import ConfigError

# MPFConfig fields a baseline configuration may share (copied where it has them)
SHARED_FIELDS = (
    "particles", "forgetting", "model", "integrator", "init_center", "init_distribution", "init_std",
    "init_half_width", "init_reference", "x0_mean", "x0_std", "gate_speed", "gate_steer",
    "gate_ay_max", "gate_alpha_max", "gate_vy_std", "gate_warmup", "bound_low", "bound_high", "sigma", "bias_rw",
    "bias0_std", "sample_period", "max_step", "plausible_beta", "plausible_yaw_rate",
)
GATE_FIELDS = ("gate_speed", "gate_steer", "gate_ay_max", "gate_alpha_max", "gate_vy_std", "gate_warmup")


@dataclass(frozen=True)
class GateOptions:
    """The MPF's learning gate (Sec. V; `gate_open`) and parameter projection, with the
    MPF's defaults: what every baseline configuration has (they subclass this)."""

    gate_speed: float = 5.0  # m/s
    gate_steer: float = 0.0035  # rad
    gate_ay_max: float = 4.0  # m/s^2
    gate_alpha_max: float = 0.08  # rad
    gate_vy_std: float = 0.15  # m/s
    gate_warmup: float = 1.0  # s
    bound_low: float = 0.2  # parameter projection (Sec. V), relative to the reference stiffness
    bound_high: float = 3.0


def shared_options(config_cls, mpf_config, overrides: dict, source: str):
    """A `config_cls` instance with the MPF configuration's shared fields, then the user's
    `overrides` (the baseline's own table of --config, named `source` in errors)."""
    from tirefilter.estimators import apply_overrides

    own = {f.name for f in dataclasses.fields(config_cls)}
    values = {k: getattr(mpf_config, k) for k in SHARED_FIELDS if k in own}
    return apply_overrides(config_cls(**values), overrides, source)


def gate_open(cfg, *, t: float, t_start: float, vx: float, delta: float, ay_meas: float, alpha: float,
              vy_std: float) -> bool:
    """The learning gate of the MPF and the baselines (observability and linear tire region,
    Sec. V of the stiffness paper): speed above `gate_speed`, |steer| above `gate_steer`,
    |measured a^Y| below `gate_ay_max` (`held_ay`: a missing sample holds the last one; 0
    before any), the larger |slip
    angle| estimate below `gate_alpha_max`, the lateral velocity known to `gate_vy_std`,
    and `gate_warmup` seconds since the first sample."""
    ay = ay_meas if math.isfinite(ay_meas) else 0.0
    return bool(vx > cfg.gate_speed and abs(delta) > cfg.gate_steer and abs(ay) < cfg.gate_ay_max
                and alpha < cfg.gate_alpha_max and vy_std < cfg.gate_vy_std and t - t_start >= cfg.gate_warmup)


def held_ay(ay: float, last: float) -> float:
    """The a^Y that `gate_open`'s linear-region test reads, and the caller keeps as `last`: the
    sample, or where it is missing the last finite one. A sample the measurement guard marks
    missing (a held repeat, an outlier) is no evidence of the linear region; counted as 0 it
    opened the gate at any load (derivations, "Linear-region test"). Every estimator's gate holds it this way."""
    return ay if math.isfinite(ay) else last


def stiffness_prior(cfg, C_nom: np.ndarray, params: tuple[str, ...], source: str):
    """The initial stiffness distribution of the MPF's conventions: returns (reference,
    center, std), absolute per parameter (n_w,). `init_reference` (default nominal) is the
    stiffness the relative spreads refer to, `init_center` (default the reference) the
    mean; std = init_std * reference (normal) or init_half_width * reference / sqrt(3)
    (uniform: the std of U(-h, h))."""
    n = len(params)
    ref = np.asarray(cfg.init_reference if cfg.init_reference is not None else C_nom, float)
    center = np.asarray(cfg.init_center if cfg.init_center is not None else ref, float)
    if ref.shape != (n,) or center.shape != (n,):
        raise ConfigError(source, "init_center" if center.shape != (n,) else "init_reference",
                          f"needs {n} values ({', '.join(params)})")
    rel = cfg.init_std if cfg.init_distribution == "normal" else cfg.init_half_width / math.sqrt(3.0)
    return ref, center, rel * ref


def check_common(cfg, bad) -> None:
    """Checks of the shared fields a configuration has (`bad(key, problem)` raises)."""
    names = {f.name for f in dataclasses.fields(cfg)}
    if "model" in names and cfg.model not in ("full", "lateral"):
        bad("model", f"expected full or lateral, got {cfg.model!r}")
    if "init_distribution" in names and cfg.init_distribution not in ("normal", "uniform"):
        bad("init_distribution", f"expected normal or uniform, got {cfg.init_distribution!r}")
    if "forgetting" in names and not 0.0 < cfg.forgetting <= 1.0:
        bad("forgetting", f"lambda must be in (0, 1], got {cfg.forgetting!r}")
    for key in GATE_FIELDS + ("init_std", "init_half_width"):
        if key in names and not getattr(cfg, key) >= 0:
            bad(key, f"must be >= 0, got {getattr(cfg, key)!r}")
    for key in ("sigma", "bias_rw", "bias0_std", "x0_std"):
        if key in names and any(not v >= 0 for v in getattr(cfg, key)):
            bad(key, f"values must be >= 0, got {getattr(cfg, key)!r}")
    if "sigma" in names and min(cfg.sigma) <= 0:
        bad("sigma", f"sensor noise must be > 0, got {cfg.sigma!r}")
    if "bound_low" in names and not 0 < cfg.bound_low < cfg.bound_high:
        bad("bound_low", "need 0 < bound_low < bound_high")
    if "sample_period" in names and not cfg.sample_period > 0:
        bad("sample_period", "must be > 0")
    if "max_step" in names and not cfg.max_step > 0:
        bad("max_step", f"must be > 0, got {cfg.max_step!r}")


def expm_small(M: np.ndarray, terms: int = 16) -> np.ndarray:
    """Matrix exponential of a small matrix by scaling and squaring with a Taylor series,
    matrix products only (no LAPACK): M / 2^s has infinity norm <= 1/4, where 16 terms leave
    a truncation error below 1e-25 relative; then s squarings.

    Why not scipy.linalg.expm: on a loaded machine its LAPACK calls through a threaded
    OpenBLAS stall for milliseconds (median 32 ms for a 20 x 20 matrix at load 12 on 2
    cores, against ~50 us here), which would dominate the per-step cost of the filters."""
    norm = float(np.max(np.sum(np.abs(M), axis=1))) if M.size else 0.0
    s = max(0, math.ceil(math.log2(norm / 0.25))) if norm > 0.25 else 0
    A = M / (2.0**s)
    E = np.eye(M.shape[0]) + A
    T = A
    for k in range(2, terms + 1):
        T = (T @ A) / k
        E = E + T
    for _ in range(s):
        E = E @ E
    return E


def discretize_zoh(A: np.ndarray, b: np.ndarray, Qc: np.ndarray, dt: float):
    """`linear_kf.discretize_zoh` (Van Loan's block matrix) with `expm_small`:
    Ad = e^{A dt}, bd = int_0^dt e^{A s} ds b, Qd = int_0^dt e^{A s} Qc e^{A^T s} ds."""
    from tirefilter.estimators.linear_kf import discretize_zoh as van_loan

    return van_loan(A, b, Qc, dt, expm=expm_small)


def small_solve(S: np.ndarray, B: np.ndarray) -> np.ndarray:
    """S^-1 B for a small symmetric positive-definite S (m, m) and B (m, k), by the
    hand-written Cholesky of `stats.linalg` (no LAPACK: see `expm_small`)."""
    from tirefilter.stats.linalg import chol, chol_solve

    return chol_solve(chol(S), B)
