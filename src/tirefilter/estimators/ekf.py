"""Extended Kalman filter (EKF) on the state augmented with random-walk stiffness and IMU
bias: the baseline of the stiffness paper (Berntorp & Di Cairano, IEEE TCST 2018) Sec. VII-B ("EKF"), "tuned carefully".

State z = [x, c, b]: the vehicle state x (full model [vx, vy, r], lateral [vy, r] with v^X
given), the stiffness deviations from nominal c in units of the reference stiffness (full
[dC_x, dCf_y, dCr_y] / C_ref, lateral [dCf_y, dCr_y] / C_ref; C_x is the driven axle's;
relative units keep the covariance well conditioned) and the biases b of the model's IMU channels (full
[ax, ay, yaw rate], lateral [ay, yaw rate]): 9 states (full), 6 (lateral).

Model (`dynamics`, `measurement`): the MPF's accelerations, eq. (1), (2), (4) and (3) with
the traction-positive slip sign (docs/design.md) and the axle stiffness C_nom + c:
  vx' = vy r + a^X,  vy' = a^Y - vx r,  r' = (lf F_yf,body - lr F_yr) / I,  c' = 0 + w_c,
  b' = 0 + w_b,  y = [a^X - i_y r' - i_x r^2, (1 + k g) a^Y + i_x r' - i_y r^2, r] + b + e
(the IMU at (i_x, i_y) = (imu_x, imu_y) from the centre of gravity, `single_track.measurement`),
with slip angles alpha_f = delta - (vy + lf r)/v, alpha_r = (lr r - vy)/v, v = max(vx, 1)
and wheel slip (R_w omega - vx) / max(|vx|, |R_w omega|, 1). Jacobians are analytic
(`dynamics`, `measurement` return them; tested against finite differences).

Prediction over dt (inputs of the previous sample held): local linearisation, the exact
solution of the model linearised at the current estimate z0, z' ~ f(z0) + A (z - z0):
  z <- z0 + int_0^dt e^{A s} ds f(z0),  P <- e^{A dt} P e^{A dt}^T + Qd,
both from one matrix exponential (Van Loan, `baseline_common.discretize_zoh`). For the lateral
model with fixed stiffness the model is affine in x and this is the exact discretisation:
the EKF then reduces to `linear_kf.LinearKF` (tested).

Tuning (each value an option of the `[ekf]` table; the reasoning):
- `stiffness_rw` = 0.05: random-walk std of each stiffness per sqrt(s), relative to the
  reference: 5% in 1 s, 16% in 10 s, enough to follow paper-sim's 50% drop in a few seconds
  of excitation without chasing the 5% per-step deviations. Zero while the MPF's learning
  gate is closed, and then the stiffness gain rows are zeroed as well (Schmidt "consider"
  states with the Joseph-form covariance update): stiffness frozen, still reported.
- `dev_sigma` = 0.05: the per-step deviations (the MPF's w, 5% std in paper-sim) are white
  noise held over a sample period Ts: they add Ts G Sigma G^T to the state's noise intensity
  (G = d x' / d c, Sigma = diag((dev_sigma C_ref)^2)) and H_c Sigma H_c^T to the measurement
  covariance (their correlation with the process noise is neglected).
- `q_state` = (0.01, 0.01, 0.001): white-noise intensity on vx', vy', r' (m^2/s^3,
  rad^2/s^3) for the rest of the model error (Pacejka curvature, load transfer, bank).
- Initial covariance: x from `x0_std`, c from the MPF's initial stiffness distribution
  (`init_std` or the uniform's std, times the reference), b from `bias0_std`; the bias
  random walk is `bias_rw` (the scenario's sensor spec). Missing bias (both zero): the bias
  states stay exactly 0.
Parameter projection (Sec. V): after each update the stiffness is clipped to
[bound_low, bound_high] times the reference. Reported `*_std` = sqrt(P_cc); `*_sigma` NaN
(the EKF has no model of the deviations' spread beyond the fixed `dev_sigma`); ESS NaN.
Deterministic: the rng is unused; `--particles` is accepted and ignored.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from tirefilter.errors import ConfigError
from tirefilter.estimators.base import Estimate, Inputs, Measurement, Posterior
from tirefilter.estimators.baseline_common import (GateOptions, check_common, discretize_zoh, gate_open, held_ay,
                                                    small_solve, stiffness_prior)
from tirefilter.vehicle import single_track
from tirefilter.vehicle.params import VehicleParams
from tirefilter.vehicle.single_track import GRAVITY

NAN = math.nan


@dataclass(frozen=True)
class EKFConfig(GateOptions):
    """Options of the EKF (the `[ekf]` table of --config); tuning in the module docstring.
    Fields named as in MPFConfig mean the same and are taken from the scenario or log the
    same way."""

    model: str = "full"  # "full" (wheel speeds) | "lateral" (vx given)
    stiffness_rw: float = 0.05  # relative random-walk std per sqrt(s) of each stiffness
    dev_sigma: float = 0.05  # relative std of the per-step stiffness deviations (0: none)
    q_state: tuple[float, ...] = (0.01, 0.01, 0.001)  # white-noise intensity on vx', vy', r' (lateral: last 2)
    init_center: tuple[float, ...] | None = None  # absolute, per parameter (default: the reference)
    init_distribution: str = "normal"
    init_std: float = 0.3
    init_half_width: float = 0.1
    init_reference: tuple[float, ...] | None = None
    x0_mean: tuple[float, ...] | None = None  # full: vx, vy, r (lateral: the last 2)
    x0_std: tuple[float, ...] = (1.0, 0.5, 0.0175)
    x0_vx_from_wheels: bool = True  # full model: vx_0 = R_w omega of the undriven axle
    x0_vx_wheel_std: float = 0.1  # m/s, its std
    sigma: tuple[float, float, float] = (0.05, 0.05, 0.0035)  # ax, ay, yaw-rate white noise
    bias_rw: tuple[float, float, float] = (0.0, 0.0, 0.0)  # per sqrt(s)
    bias0_std: tuple[float, float, float] = (0.0, 0.0, 0.0)
    sample_period: float = 0.01  # s: Ts of the per-step deviations
    vx_min: float = 1.0  # m/s, speed floor of the slip angles

    def validated(self) -> "EKFConfig":
        def bad(key, problem):
            raise ConfigError("ekf configuration", key, problem)

        check_common(self, bad)
        for key in ("stiffness_rw", "dev_sigma"):
            if not (getattr(self, key) >= 0 and math.isfinite(getattr(self, key))):
                bad(key, f"must be finite and >= 0, got {getattr(self, key)!r}")
        if len(self.q_state) != 3 or any(not (v >= 0 and math.isfinite(v)) for v in self.q_state):
            bad("q_state", f"needs 3 finite values >= 0 (vx, vy, r), got {self.q_state!r}")
        if not self.vx_min > 0:
            bad("vx_min", f"must be > 0, got {self.vx_min!r}")
        return self


class SingleTrackEKFModel:
    """The EKF's model maths (module docstring) for one vehicle and model choice: pure
    functions of (z, u) with analytic Jacobians. u = [delta, omega_f, omega_r, vx]."""

    def __init__(self, vehicle: VehicleParams, full: bool, vx_min: float = 1.0, C_scale=None):
        v = vehicle
        self.v, self.full, self.vx_min = v, full, vx_min
        self.rear_drive = v.drive == "rear"
        self.C_nom_fx, self.C_nom_rx = single_track.longitudinal_stiffness(v)
        self.nx = 3 if full else 2
        self.params = ("Cx", "Cf_y", "Cr_y") if full else ("Cf_y", "Cr_y")
        self.n_w = len(self.params)
        self.C_nom = np.array([v.Cx, v.Cf_y, v.Cr_y] if full else [v.Cf_y, v.Cr_y], float)
        # the stiffness states are deviations in units of C_scale (default nominal): O(0.1)
        # numbers, like the other states, for a well-conditioned covariance
        self.C_scale = self.C_nom.copy() if C_scale is None else np.asarray(C_scale, float)
        self.m = 3 if full else 2  # IMU channels (bias states)
        self.nz = self.nx + self.n_w + self.m
        self.roll_gain = v.imu_roll_gain(GRAVITY)

    def _forces(self, z, u):
        """Accelerations (a^X, a^Y, r') and their gradients over z (3, nz)."""
        v, nz, nx = self.v, self.nz, self.nx
        delta = u[0]
        cd, sd = math.cos(delta), math.sin(delta)
        if self.full:
            vx, vy, r = z[0], z[1], z[2]
        else:
            vx, vy, r = u[3], z[0], z[1]
        iv = (0, 1, 2) if self.full else (None, 0, 1)  # indices of vx, vy, r in z

        def grad(**parts):
            g = np.zeros(nz)
            for name, val in parts.items():
                i = {"vx": iv[0], "vy": iv[1], "r": iv[2]}[name]
                if i is not None:
                    g[i] += val
            return g

        s = max(vx, self.vx_min)
        ds = 1.0 if vx > self.vx_min else 0.0  # d s / d vx
        af, ar = single_track.small_slip_angles(vx, vy, r, delta, v.lf, v.lr, self.vx_min)
        g_af = grad(vx=ds * (vy + v.lf * r) / (s * s), vy=-1.0 / s, r=-v.lf / s)
        g_ar = grad(vx=-ds * (v.lr * r - vy) / (s * s), vy=-1.0 / s, r=v.lr / s)
        cs = self.C_scale
        c = z[nx:nx + self.n_w] * cs  # absolute deviations, N/rad (N)
        j = 1 if self.full else 0  # index of dCf_y within c
        Cf, Cr = v.Cf_y + c[j], v.Cr_y + c[j + 1]
        e_cf, e_cr = np.zeros(nz), np.zeros(nz)  # d C / d z
        e_cf[nx + j], e_cr[nx + j + 1] = cs[j], cs[j + 1]
        Ffy, g_Ffy = Cf * af, Cf * g_af + af * e_cf
        Fry, g_Fry = Cr * ar, Cr * g_ar + ar * e_cr
        if self.full:
            lam, g_lam = [], []
            for omega in (u[1], u[2]):
                if not math.isfinite(omega):  # no wheel-speed sample yet: no slip
                    lam.append(0.0), g_lam.append(np.zeros(nz))
                    continue
                wr = v.wheel_radius * omega
                den = max(abs(vx), abs(wr), 1.0)
                lam.append(single_track.floored_wheel_slip(vx, wr))
                if den == abs(vx) and abs(vx) > 1.0 and abs(vx) >= abs(wr):
                    d = -wr / (vx * abs(vx))  # d/dvx of (wr - vx)/|vx|
                else:
                    d = -1.0 / den
                g_lam.append(grad(vx=d))
            e_cx = np.zeros(nz)
            e_cx[nx] = cs[0]
            if self.rear_drive:
                Cfx, g_Cfx, Crx, g_Crx = self.C_nom_fx, np.zeros(nz), self.C_nom_rx + c[0], e_cx
            else:
                Cfx, g_Cfx, Crx, g_Crx = self.C_nom_fx + c[0], e_cx, self.C_nom_rx, np.zeros(nz)
            Ffx, g_Ffx = Cfx * lam[0], Cfx * g_lam[0] + lam[0] * g_Cfx
            Frx, g_Frx = Crx * lam[1], Crx * g_lam[1] + lam[1] * g_Crx
            Fyf, g_Fyf = Ffy * cd + Ffx * sd, g_Ffy * cd + g_Ffx * sd
            aX, g_aX = (Ffx * cd - Ffy * sd + Frx) / v.mass, (g_Ffx * cd - g_Ffy * sd + g_Frx) / v.mass
        else:
            Fyf, g_Fyf = Ffy * cd, g_Ffy * cd
            aX, g_aX = 0.0, np.zeros(nz)
        aY, g_aY = (Fyf + Fry) / v.mass, (g_Fyf + g_Fry) / v.mass
        rd, g_rd = (v.lf * Fyf - v.lr * Fry) / v.yaw_inertia, (v.lf * g_Fyf - v.lr * g_Fry) / v.yaw_inertia
        return np.array([aX, aY, rd]), np.array([g_aX, g_aY, g_rd]), (af, ar)

    def dynamics(self, z, u):
        """f(z, u) = dz/dt (nz,) and its Jacobian A = df/dz (nz, nz); also the slip angles."""
        acc, g, slip = self._forces(z, u)
        f = np.zeros(self.nz)
        A = np.zeros((self.nz, self.nz))
        if self.full:
            vx, vy, r = z[0], z[1], z[2]
            f[:3] = (vy * r + acc[0], acc[1] - vx * r, acc[2])
            A[:3] = g
            A[0, 1] += r
            A[0, 2] += vy
            A[1, 0] -= r
            A[1, 2] -= vx
        else:
            vx = u[3]
            f[:2] = (acc[1] - vx * z[1], acc[2])
            A[:2] = g[1:]
            A[0, 1] -= vx
        return f, A, slip

    def measurement(self, z, u):
        """h(z, u) (m,) of the model's IMU channels and H = dh/dz (m, nz)."""
        acc, g, _ = self._forces(z, u)
        b = z[self.nx + self.n_w:]
        H = np.zeros((self.m, self.nz))
        H[:, self.nx + self.n_w:] = np.eye(self.m)
        if self.full:
            h = np.array([acc[0], self.roll_gain * acc[1], z[2]]) + b
            H[0] += g[0]
            H[1] += self.roll_gain * g[1]
            H[2, 2] += 1.0
        else:
            h = np.array([self.roll_gain * acc[1], z[1]]) + b
            H[0] += self.roll_gain * g[1]
            H[1, 1] += 1.0
        ix, iy = self.v.imu_x, self.v.imu_y
        if ix != 0.0 or iy != 0.0:  # the lever arm: r' = acc[2] and the centripetal r^2 (`single_track.measurement`)
            jr = self.nx - 1
            r = z[jr]
            jy = 1 if self.full else 0
            if self.full:
                h[0] += -iy * acc[2] - ix * r * r
                H[0] += -iy * g[2]
                H[0, jr] += -2.0 * ix * r
            h[jy] += ix * acc[2] - iy * r * r
            H[jy] += ix * g[2]
            H[jy, jr] += -2.0 * iy * r
        return h, H


class StiffnessEKF:
    """EKF on [vehicle state, stiffness deviations, IMU biases] (module docstring)."""

    name = "ekf"
    predictive_wanted = False  # keep the one-step predictive for the model check (`model_check.ModelCheck` sets it)

    def __init__(self, vehicle: VehicleParams, config: EKFConfig = EKFConfig()):
        self.vehicle = vehicle
        self.cfg = cfg = config.validated()
        self.full = cfg.model == "full"
        mdl = SingleTrackEKFModel(vehicle, self.full, cfg.vx_min)
        self.params, self.C_nom, self.n_w = mdl.params, mdl.C_nom, mdl.n_w
        self.C_ref, self.C_center, C_std = stiffness_prior(cfg, self.C_nom, self.params, "ekf configuration")
        self.mdl = mdl = SingleTrackEKFModel(vehicle, self.full, cfg.vx_min, C_scale=self.C_ref)  # c in units of C_ref
        self.nx, self.nz = mdl.nx, mdl.nz
        self.channels = (0, 1, 2) if self.full else (1, 2)
        self.ic = slice(self.nx, self.nx + self.n_w)
        self.ib = slice(self.nx + self.n_w, self.nz)
        ch = list(self.channels)
        self.R = np.diag(np.asarray(cfg.sigma, float)[ch] ** 2)
        self.Sigma_dev = np.eye(self.n_w) * cfg.dev_sigma**2  # relative units
        q = np.zeros(self.nz)
        q[:self.nx] = np.asarray(cfg.q_state, float)[-self.nx:]
        q[self.ib] = np.asarray(cfg.bias_rw, float)[ch] ** 2
        self.q_closed = q.copy()
        q[self.ic] = cfg.stiffness_rw**2
        self.q_open = q
        x0_std = np.asarray(cfg.x0_std, float)[-self.nx:]
        self.P0 = np.diag(np.concatenate([x0_std**2, (C_std / self.C_ref) ** 2,
                                          np.asarray(cfg.bias0_std, float)[ch] ** 2]))
        self.lo = cfg.bound_low - self.C_nom / self.C_ref  # projection bounds, relative units
        self.hi = cfg.bound_high - self.C_nom / self.C_ref

    def config_dict(self) -> dict:
        d = asdict(self.cfg)
        d.update(params=list(self.params), C_nominal=self.C_nom.tolist(), P0_diag=np.diagonal(self.P0).tolist())
        return d

    def reset(self, rng: np.random.Generator | None = None) -> None:
        """Back to the prior. Deterministic: rng is accepted and unused."""
        cfg = self.cfg
        x0 = cfg.x0_mean if cfg.x0_mean is not None else ((20.0, 0.0, 0.0) if self.full else (0.0, 0.0))
        self.z = np.concatenate([np.asarray(x0, float)[-self.nx:], (self.C_center - self.C_nom) / self.C_ref, np.zeros(len(self.channels))])
        self.P = self.P0.copy()
        self.t_prev = None
        self.t_start = None
        self.ay_last = math.nan  # the last finite a^Y of the linear-region test (`held_ay`)
        self.u_prev = None
        self.active = False
        self._pred = None  # this step's one-step predictive (`one_step_predictive`)

    def _process_noise(self, A) -> np.ndarray:
        """Continuous noise intensity Qc (module docstring, tuning)."""
        Qc = np.diag(self.q_open if self.active else self.q_closed)
        if self.cfg.dev_sigma > 0:
            G = A[:self.nx, self.ic]
            Qc[:self.nx, :self.nx] += self.cfg.sample_period * (G @ self.Sigma_dev @ G.T)
        return Qc

    def predict(self, u, dt: float) -> None:
        """Local-linearisation prediction over dt with u held (module docstring)."""
        f, A, _ = self.mdl.dynamics(self.z, u)
        Ad, bd, Qd = discretize_zoh(A, f, self._process_noise(A), dt)
        self.z = self.z + bd
        P = Ad @ self.P @ Ad.T + Qd
        self.P = 0.5 * (P + P.T)

    def update(self, u, yk: np.ndarray) -> None:
        """Update with the finite components of yk (the model's channels). Joseph form
        P = (I - K H) P (I - K H)^T + K R K^T, valid for the Schmidt gain (stiffness rows
        of K zeroed while the gate is closed)."""
        a = np.flatnonzero(np.isfinite(yk))
        if not a.size:
            return
        h, H = self.mdl.measurement(self.z, u)
        H, Ra = H[a], self.R[np.ix_(a, a)]
        if self.cfg.dev_sigma > 0:
            Hc = H[:, self.ic]
            Ra = Ra + Hc @ self.Sigma_dev @ Hc.T
        PHt = self.P @ H.T
        S = H @ PHt + Ra
        if self.predictive_wanted and self.t_prev is not None:  # the model check's (h, S: the predictive)
            self._keep_predictive(yk, a, h[a], S)
        K = small_solve(S, PHt.T).T
        if not self.active:
            K[self.ic] = 0.0  # consider states: frozen stiffness
        self.z = self.z + K @ (yk[a] - h[a])
        IKH = np.eye(self.nz) - K @ H
        P = IKH @ self.P @ IKH.T + K @ Ra @ K.T
        self.P = 0.5 * (P + P.T)
        self.z[self.ic] = np.clip(self.z[self.ic], self.lo, self.hi)  # parameter projection (Sec. V)

    def step(self, t: float, u: Inputs, y: Measurement) -> Estimate:
        cfg = self.cfg
        t = float(t)
        if not math.isfinite(t):
            raise ConfigError("inputs", "t", f"time must be finite, got {t!r}")
        uk = np.array([u.delta, u.omega_f, u.omega_r, u.vx], float)
        self._pred, self._t = None, t
        if self.u_prev is not None:
            uk = np.where(np.isfinite(uk), uk, self.u_prev)  # hold the last finite input
        if not self.full and not math.isfinite(uk[3]):
            raise ConfigError("inputs", "vx", f"the lateral model needs vx; none given up to t = {t} s")
        if not math.isfinite(uk[0]):
            uk[0] = 0.0
        if self.t_prev is None:
            self.t_start = t
            if self.full and cfg.x0_vx_from_wheels:
                omega = uk[1] if self.mdl.rear_drive else uk[2]  # the undriven axle hardly slips
                if math.isfinite(omega):
                    self.z[0] = self.vehicle.wheel_radius * omega
                    self.P[0, :], self.P[:, 0] = 0.0, 0.0
                    self.P[0, 0] = cfg.x0_vx_wheel_std**2
        else:
            dt = t - self.t_prev
            if not dt > 0:
                raise ConfigError("inputs", "t", f"time must increase: {t} after {self.t_prev}")
            self.predict(self.u_prev, dt)
        yk = np.array([y.ax, y.ay, y.yaw_rate], float)[list(self.channels)]
        self.update(uk, yk)
        self.t_prev, self.u_prev = t, uk
        _, _, (af, ar) = self.mdl.dynamics(self.z, uk)
        vx = self.z[0] if self.full else uk[3]
        ay_gate = self.ay_last = held_ay(y.ay, self.ay_last)
        self.active = gate_open(cfg, t=t, t_start=self.t_start, vx=vx, delta=uk[0], ay_meas=ay_gate,
                                alpha=max(abs(af), abs(ar)), vy_std=math.sqrt(max(self.P[self.nx - 2, self.nx - 2], 0.0)))
        return self._estimate(vx)

    def _keep_predictive(self, yk: np.ndarray, a: np.ndarray, h: np.ndarray, S: np.ndarray) -> None:
        """The Gaussian predictive of the available channels a (mean h, covariance S of the
        linearisation) kept for `one_step_predictive`: a^Y and the yaw rate."""
        got = {self.channels[c]: j for j, c in enumerate(a)}
        if 1 not in got:
            return
        j, k = got[1], got.get(2)
        mean = (float(h[j]), NAN if k is None else float(h[k]))
        var = (float(S[j, j]), NAN if k is None else float(S[k, k]))
        meas = (float(yk[a[j]]), NAN if k is None else float(yk[a[k]]))
        self._pred = (self._t, mean, var, meas)

    def one_step_predictive(self):
        """This step's one-step predictive of the measurements before the update (with
        `predictive_wanted`; `model_check`): (t, mean, variance, measured) of a^Y and the yaw rate,
        NaN for a missing one; None at the first sample or without an a^Y sample."""
        return self._pred

    def _estimate(self, vx) -> Estimate:
        std = np.sqrt(np.maximum(np.diagonal(self.P), 0.0))
        C = self.C_nom + self.C_ref * self.z[self.ic]
        vals = dict(zip(self.params, zip(C, self.C_ref * std[self.ic])))
        bias = dict(zip(("ax", "ay", "yaw_rate")[-len(self.channels):], self.z[self.ib]))
        x = self.z[:self.nx]
        vy, r = x[-2], x[-1]
        sstd = tuple(std[:3]) if self.full else (0.0, std[0], std[1])
        cx = vals.get("Cx", (NAN, NAN))
        return Estimate(
            active=self.active, vx=float(vx), vy=float(vy), yaw_rate=float(r),
            Cf_y=float(vals["Cf_y"][0]), Cr_y=float(vals["Cr_y"][0]), Cx=float(cx[0]),
            Cf_y_std=float(vals["Cf_y"][1]), Cr_y_std=float(vals["Cr_y"][1]), Cx_std=float(cx[1]),
            Cf_y_sigma=NAN, Cr_y_sigma=NAN, Cx_sigma=NAN,
            b_ax=float(bias.get("ax", NAN)), b_ay=float(bias["ay"]), b_yaw_rate=float(bias["yaw_rate"]),
            ess=NAN, state_std=tuple(float(s) for s in sstd),
        )

    def posterior(self) -> Posterior:
        """The Gaussian posterior as one 'particle' z (1, nz) with log-weight 0 and its
        covariance in stats["cov"] (1, nz, nz)."""
        return Posterior(self.z[None].copy(), np.zeros(1),
                         {"cov": self.P[None].copy(), "C_nominal": self.C_nom.copy(), "params": self.params})
