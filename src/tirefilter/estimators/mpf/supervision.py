"""The stiffness MPF's supervision (a mixin of `StiffnessMPF`, on its attributes): the learning
gate (observability and the linear tire region, Sec. V), the restarts (a contradiction between
slip and a^Y, a stiffness mean held at a projection bound, every particle implausible), the
plausibility check, v^X drawn from the wheel speeds at the start and after a gap in the data,
and the informed start."""

from __future__ import annotations

import math

import numpy as np

from tirefilter.estimators.base import Estimate, Measurement
from tirefilter.estimators.baseline_common import gate_open, held_ay
from tirefilter.stats import normalize_log_weights
from tirefilter.vehicle import single_track

RESTART_ALPHA = 0.15  # rad: an estimated slip angle beyond this with |a^Y| below gate_ay_max is no tyre's (restart test)


class Supervision:
    """Gate, restarts, plausibility, gaps and the informed start of `StiffnessMPF`."""

    def _pin_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The deviations (n_w,) at or beyond which a posterior mean counts as held at a
        projection bound (Sec. V): within 1% of the reference stiffness of it."""
        cfg = self.cfg
        tol = 0.01 * self.C_ref
        return cfg.bound_low * self.C_ref - self.C_nom + tol, cfg.bound_high * self.C_ref - self.C_nom - tol

    def _gate_or_restart(self, t: float, uk: np.ndarray, y: Measurement, vx_est: float, alpha: float,
                         vy_std: float, pinned: bool) -> bool:
        """Opens or closes the learning gate (observability and the linear tire region, Sec. V)
        and says whether the cloud must restart: a large slip angle with a small measured a^Y
        for `restart_after` s (no tire explains that: the state has locked onto a wrong
        sideslip, which the sampled w explains regardless), or a stiffness mean `pinned` at a
        projection bound for `restart_at_bound_after` s."""
        cfg = self.cfg
        # a missing sample is no evidence of the linear region: the last one holds ("Linear-region test")
        ay = self.ay_last = held_ay(y.ay, self.ay_last)
        ay_m = ay if math.isfinite(ay) else 0.0
        self.linear_region = abs(ay_m) < cfg.gate_ay_max
        self.active = gate_open(cfg, t=t, t_start=self.t_start, vx=vx_est, delta=uk[0], ay_meas=ay, alpha=alpha,
                                vy_std=vy_std)
        # (the measured a^Y: a state locked onto a wrong slip predicts the large a^Y of that slip)
        ay_y = y.ay if math.isfinite(y.ay) else 0.0
        contradiction = alpha > RESTART_ALPHA and abs(ay_y) < cfg.gate_ay_max
        self._contradiction_since = (self._contradiction_since or t) if contradiction else None
        if contradiction and t - self._contradiction_since >= cfg.restart_after:
            return True
        return cfg.restart_at_bound_after > 0 and self._pinned_too_long(t, pinned)

    def _pinned(self, mbar: np.ndarray) -> bool:
        lo, hi = self._pin_bounds()
        return bool(np.any((mbar <= lo) | (mbar >= hi)))

    def _pinned_too_long(self, t: float, pinned: bool) -> bool:
        """A posterior mean held at a projection bound (`pinned`, `_pinned`) since
        `restart_at_bound_after` s or longer: the cloud has locked onto a wrong stiffness that
        the projection keeps it at, and the filter starts again."""
        cfg = self.cfg
        if not pinned:
            self._bound_since = None
        elif self._bound_since is None:
            self._bound_since = t
        elif t - self._bound_since >= cfg.restart_at_bound_after:
            return True
        return False

    # ---- start-up, plausibility, gaps and restarts -----------------------------------------
    def _informed_start(self, uk, yk) -> np.ndarray:
        """Draw each particle's initial (r, vy) from its prior conditioned on the first yaw
        rate and a^Y samples, given the particle's own stiffness mean (Gaussian, a^Y
        linearised in vy), and return the log marginal likelihood of those samples as the
        first weights (they replace the step's weighting: the samples are used once).

        Why: weighting prior draws by the first a^Y collapses the cloud onto the few
        particles whose vy happens to fit their stiffness (ESS of a handful out of 500), and
        a biased stiffness prior then locks in a vy offset (derivations, "Start-up, plausibility and restart"). Drawn
        this way, every stiffness hypothesis keeps a consistent state and the yaw dynamics
        decide between them."""
        logw = np.zeros(len(self.x))
        jr, jy = len(self.channels) - 1, len(self.channels) - 2  # yaw rate, a^Y
        ix_r, ix_vy = self.x.shape[1] - 1, self.x.shape[1] - 2
        std = np.asarray(self.cfg.x0_std, float)[-2:]
        var_vy, var_r = std[0] ** 2, std[1] ** 2
        if math.isfinite(yk[jr]) and var_r > 0:
            s2 = self.R[jr, jr]
            gain = var_r / (var_r + s2)
            e = yk[jr] - self.b[:, jr] - self.x[:, ix_r]
            logw += -0.5 * (e * e / (var_r + s2) + math.log(2 * math.pi * (var_r + s2)))
            self.x[:, ix_r] += gain * e + math.sqrt(var_r * (1 - gain)) * self.rng.standard_normal(len(self.x))
        if math.isfinite(yk[jy]) and var_vy > 0:
            a, B, *_ = self._model(self.x, uk)
            h, D = self._measurement(a, B, self.x)
            x1 = self.x.copy()
            x1[:, ix_vy] += 1.0
            h1, _ = self._measurement(*self._model(x1, uk)[:2], x1)
            k = (h1 - h)[:, jy]  # d a^Y / d vy at w = 0 (the w-dependent part is left out)
            mu_w, L11, nu_w = self.stats.predictive()
            d = D[:, jy]
            S = np.einsum("ni,nij,nj->n", d, L11, d) * nu_w / (nu_w - 2.0) + self.R[jy, jy] + self.P[:, jy, jy]
            e = yk[jy] - h[:, jy] - self.b[:, jy] - np.einsum("ni,ni->n", d, mu_w)
            Se = k * k * var_vy + S
            gain = k * var_vy / Se
            logw += -0.5 * (e * e / Se + np.log(2 * math.pi * Se))
            self.x[:, ix_vy] += gain * e + np.sqrt(np.maximum(var_vy * (1 - gain * k), 0.0)) * self.rng.standard_normal(
                len(self.x))
        return logw

    def _plausible(self, uk) -> bool:
        """Zero the weight of particles outside the physically possible region; False when
        none is left."""
        vx = self.x[:, 0] if self.full else uk[3]
        vy, r = self.x[:, -2], self.x[:, -1]
        ok = (np.abs(vy) <= self.cfg.plausible_beta * np.maximum(np.abs(vx), self.cfg.gate_speed)) & (
            np.abs(r) <= self.cfg.plausible_yaw_rate)
        if ok.all():
            return True
        if not ok.any():
            return False
        self.logw = normalize_log_weights(np.where(ok, self.logw, -np.inf))
        return None  # some left: the weights changed

    def _vx_from_wheels(self, uk) -> float:
        """`single_track.vx_from_wheels`: R_w omega of the undriven axle; NaN without that wheel speed."""
        return single_track.vx_from_wheels(uk, self._vp, self.rear_drive)

    def _draw_vx_from_wheels(self, uk) -> bool:
        """The particles' v^X drawn around `_vx_from_wheels(uk)` with std `x0_vx_wheel_std`;
        False (nothing drawn) without the wheel speed."""
        vx = self._vx_from_wheels(uk)
        if not math.isfinite(vx):
            return False
        self.x[:, 0] = vx + self.cfg.x0_vx_wheel_std * self.rng.standard_normal(len(self.x))
        return True

    def _gap(self, dt: float) -> bool:
        """A time step after which `_redraw_after_gap` draws v^X again (full model)."""
        return self.full and 0 < self.cfg.gap_after < dt

    def _redraw_after_gap(self, dt: float, u_now) -> bool:
        """After a gap in the data (a time step `dt` longer than `gap_after`), with the
        particles propagated across it: their v^X drawn again around the speed of the
        undriven wheels at the sample after the gap (derivations, "After a gap in the data"); `u_now` is that
        sample's inputs as measured (no held value: without the wheel speed nothing is drawn). Over the gap the
        filter held its last inputs, so its v^X misses the acceleration it did not see, and
        through the driven axle's wheel slip that error becomes a longitudinal force error
        that the weights and the learning take for a wrong state or stiffness. Full model
        only; True when drawn (counted in `gap_redraws`)."""
        if not self._gap(dt):
            return False
        if not self._draw_vx_from_wheels(u_now):
            return False
        self.gap_redraws += 1
        return True

    def _restart(self, t, uk, y) -> Estimate:
        """Every particle has left the plausible region (the state diverged, typically after
        learning an unstable stiffness from a wrong start): draw the particles from the prior
        again, around the current speed and the measured yaw rate, and go on from there."""
        if self.full:
            vx = self._vx_from_wheels(uk)
            vx = vx if math.isfinite(vx) else float(np.median(self.x[:, 0]))
        r0 = y.yaw_rate if math.isfinite(y.yaw_rate) else 0.0
        self._draw_prior((vx, 0.0, r0) if self.full else (0.0, r0))
        if self.cfg.informed_start:
            yk = np.array([y.ax, y.ay, y.yaw_rate], float)[list(self.channels)]
            self.logw = normalize_log_weights(self._informed_start(uk, yk))
        self.restarts += 1
        self._reset_cx_excitation()  # the prior again: nothing of Cx learned
        if self._calib is not None:
            self._calib.reset()
            self._load_level[:] = 0.0
        self.t_start, self.t_prev, self.u_prev, self.active = t, t, uk, False
        self._contradiction_since = self._bound_since = None
        self._at_x = self._model(self.x, uk)
        self._keep_relaxed(self._at_x)
        self.w_prev = self.stats.mu.copy()  # the next propagation uses the prior means
        if self._nb is not None:  # (the compiled moments)
            return self._estimate_compiled(float(self.cfg.particles))
        return self._estimate(float(self.cfg.particles))
