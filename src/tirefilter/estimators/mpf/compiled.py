"""The stiffness MPF's compiled step (a mixin of `StiffnessMPF`, on its attributes): with the
numba backend, every sample runs as three compiled passes over the particles (`kernels`) on arrays allocated once (`_MPFWork`), drawing the random
numbers here with the reference's generator calls in the reference's order, so both backends
follow the same path (tests/test_kernels.py). The rare branches (restarts) go through the
reference methods."""

from __future__ import annotations

import math

import numpy as np

from tirefilter.estimators.base import Estimate, Measurement
from tirefilter.estimators.mpf import predictive
from tirefilter.estimators.mpf.adaptation import DRIFT_TIME
from tirefilter.stats import effective_sample_size, normalize_log_weights
from tirefilter.vehicle.single_track import GRAVITY

NAN = math.nan
_new_object = object.__new__  # (`CompiledStep._estimate_fused`)


class CompiledStep:
    """`StiffnessMPF._step_compiled` and what it needs: the fused estimate and the work arrays."""

    def _step_compiled(self, t: float, uk: np.ndarray, y: Measurement, dt: float, u_now: np.ndarray) -> Estimate:
        """Steps 1-5 of `step` (`_step`, the numpy reference) for every sample, by three compiled
        passes over the particles (`kernels.predict_weigh`, `resample_gate`, `sample_update`) on
        arrays allocated once (`_MPFWork`), with the random numbers drawn here by the reference's
        generator calls in the reference's order: the same numbers as the numpy path
        (tests/test_kernels.py). The first sample skips the propagation and, with the informed
        start, takes its weights (`_informed_start`) instead of the likelihood's; after a gap
        v^X is drawn again from the wheel speeds `u_now` (`_redraw_after_gap`). A restart
        (`_restart`) draws the prior with the reference's methods."""
        cfg, nb, rng = self.cfg, self._nb, self.rng
        start = self.t_prev is None
        wk = self._work()
        ch = self.channels
        yl = [y.ax, y.ay, y.yaw_rate] if self.full else [y.ay, y.yaw_rate]
        yk = np.array(yl, float)
        # the predictive weights (`_predict_ay`: the gate's a^Y prediction, the residual of `_calibrate`;
        # `_match_state_noise`), into a buffer
        logw_pred = None
        if wk.keep_pred or self.predictive_wanted:
            logw_pred = wk.logw_pred
            np.copyto(logw_pred, self.logw)
        redraw, weigh = wk.no_redraw, True
        if start:  # the first sample: the informed start's weights in place of the likelihood's
            self.t_start = t
            if cfg.informed_start:
                self.logw, weigh = self._informed_start(uk, yk), False
        elif self._gap(dt):  # v^X drawn again around the wheel speeds after the gap (`_redraw_after_gap`)
            vx = self._vx_from_wheels(u_now)
            if math.isfinite(vx):
                redraw = vx + cfg.x0_vx_wheel_std * rng.standard_normal(cfg.particles)
                self.gap_redraws += 1
        if self.state_noise is not None and not start:  # optional regularisation against sample impoverishment
            noise, noise_scale = rng.standard_normal(self.x.shape), self._state_noise_scale(dt)
        else:
            noise, noise_scale = wk.no_noise, wk.no_scale
        if self.k_roll is not None:  # the roll gain per particle (`_walk_roll`, `_roll_gains`)
            if start:
                np.multiply(self.k_roll, GRAVITY, out=wk.gain)
                wk.gain += 1.0
            else:  # `_walk_roll`'s draw and walk, the gain with it
                z_roll = rng.standard_normal(len(self.k_roll))
                if not (self.k_roll.flags.c_contiguous and self.k_roll.flags.writeable
                        and self.k_roll.dtype == np.float64):  # (the kernel writes into it)
                    self.k_roll = np.array(self.k_roll, float)
                nb.walk_roll(self.k_roll, z_roll, cfg.roll_gradient_rw * math.sqrt(dt), wk.roll_lo, wk.roll_hi,
                             GRAVITY, wk.gain)
        if self.k_load is not None:  # the load-transfer gain per particle (`_load_gains`)
            wk.load_gain[:] = self._load_gains()
        if self.relaxing:  # the relaxed slip angles (`_keep_relaxed`): the kernel relaxes from them and overwrites them
            if self.relaxed is not None and self.relaxed is not wk.relaxed:
                wk.relaxed[...] = self.relaxed
            self.relaxed = wk.relaxed
        if math.isfinite(sum(yl)):  # the kernels compiled for this model's sizes (kernels.SIZES_FULL ...)
            a, nc, sizes = wk.avail_all, wk.nc_all, wk.sizes_all
        else:
            sizes = wk.sizes_any
            a = np.flatnonzero(np.isfinite(yk))
            nc = int(sum(ch[j] in (0, 1) for j in a))
        adaptive = cfg.forgetting_mode == "adaptive"
        u_prev = uk if start else self.u_prev  # (not read without the propagation)
        self.t_prev, self.u_prev = t, uk
        innovation, ess, count, nu_common = nb.predict_weigh(
            wk.own, wk.scratch, (u_prev, uk, yk, a, self.w_prev, self.logw, noise, noise_scale, redraw),
            wk.model[self.linear_region],
            (dt, wk.max_step, float(self.lam), self.nu0, wk.beta, wk.yaw_max, wk.gate_speed),
            wk.flags[self.active] if not start else wk.start_flags[weigh], nc, sizes)
        if math.isfinite(innovation):  # adaptive forgetting (`_adapt_forgetting`)
            self._smooth_surprise(innovation, dt)
        if self.predictive_wanted and not start and a.size:  # the model check's (`estimators.mpf.predictive`)
            predictive.keep(self, t, yk, a, wk.e, wk.Lc, wk.nu_w, logw_pred, compiled=True)
        self.w_prev = wk.w
        # af, ar in the order before any resampling: the next propagation reads only a, B and slip
        self._at_x = (wk.a, wk.B, wk.af, wk.ar, wk.slip if self.full else None)
        if count == 0:
            return self._restart(t, uk, y)
        if count < cfg.particles:  # some particles left the plausible region (`_plausible`)
            self.logw = normalize_log_weights(np.where(wk.ok, self.logw, -np.inf))
            ess = -1.0
        if cfg.state_noise_from_data and a.size and weigh:  # (the scale of this propagation's noise)
            self._match_state_noise(logw_pred, dt, None if start else noise_scale)
        if ess < 0:
            ess = float(effective_sample_size(self.logw))
        resample = ess < cfg.resample_threshold * cfg.particles
        u0 = float(rng.random((1,))[0]) if resample else 0.0
        vx_est, vy_std, alpha, pinned = nb.resample_gate(self.logw, u0, resample, wk.idx, wk.own, wk.spares, wk.af,
                                                         wk.ar, self.full, wk.pin_lo, wk.pin_hi, wk.q)
        if resample:
            self._swap_work(wk)
            self.resamples += 1
            if self.k_roll is not None:
                self.k_roll = self.k_roll[wk.idx]
            if self.k_load is not None:
                self.k_load = self.k_load[wk.idx]
            if self.relaxing:
                wk.relaxed[...] = wk.relaxed[:, wk.idx]
        vx_est = vx_est if self.full else uk[3]
        if self._gate_or_restart(t, uk, y, vx_est, alpha, vy_std, pinned):
            return self._restart(t, uk, y)
        if self.active and self._calib is not None and a.size:
            self._ay_residual(a, logw_pred, wk)
        N = cfg.particles
        z = rng.standard_normal((N, self.n_w))
        if nu_common > 0:
            nu_draw = wk.nu_draw
            nu_draw.fill(nu_common + nc)
            chi = rng.chisquare(nu_common + nc, N)
        else:
            nu_draw = wk.nu_w[wk.idx] + nc if nc else wk.nu_w[wk.idx]
            chi = rng.chisquare(nu_draw)
        drift = bool(self.active and nc and adaptive)
        if drift and self.drift is not wk.drift_checked:  # (the kernel writes into it)
            if not (self.drift.flags.c_contiguous and self.drift.dtype == np.float64):
                self.drift = np.array(self.drift, float)
            wk.drift_checked = self.drift
        zd, k_mean, k_std = nb.sample_update(
            wk.idx, wk.own, wk.scratch, (z, chi, nu_draw, wk.ones2), wk.w, (self.R, a, yk),
            (0.0, -math.expm1(-dt / DRIFT_TIME), wk.lo, wk.hi),
            (False, bool(a.size and self.bias_on), self.active, drift), nc, (self.drift, wk.mom, wk.q, wk.no_k if self.k_roll is None else self.k_roll), sizes)
        if zd == zd:  # `_track_drift` (the statistic is NaN when not computed)
            self._cap_forgetting(zd)
        if self.full:
            self._excite_cx(float(wk.mom[0, 0]), uk, dt)
        est = self._estimate_fused(ess, wk.mom, dt, (k_mean, k_std))
        # the wheel-speed filter's drive at the next sample (`_filter_wheels`): E[b_ax] and E[v^Y r] of these particles
        self._drive_moments = (float(wk.mom[5, 0]), float(wk.mom[6, 0])) if self.wheels is not None else None
        return est

    def _estimate_fused(self, ess: float, mom: np.ndarray, dt: float | None = None, roll=None) -> Estimate:
        """`_estimate_from` on the moments that `sample_update` left in the rows of mom, written out
        for the fused step: the same Estimate (tests/test_kernels.py compares every field) in a
        third of the time. With `dt` (the fused step) and `std_calibration = "sandwich"`, the
        calibration's update and factors (`_calibrate_moments`) go into the one Estimate built.
        The frozen dataclass's fields are filled directly (every field: its generated __init__
        sets each through object.__setattr__, several us per step); Estimate has no
        __post_init__ and no __slots__ (tests/test_kernels.py checks both and compares the
        object with the constructor's). `roll`: the roll gradient's mean and std where `sample_update`
        returned them."""
        xm, xs, mb, vm, s2, bm, vyr = mom.tolist()
        root, C = _sqrt_or_nan, self._C_nom_list
        f0 = f1 = 1.0
        k_mean, k_std = self._roll_moments() if roll is None else roll
        est = _new_object(Estimate)
        if self.full:  # params Cx, Cf_y, Cr_y; bias ax, ay, yaw rate
            if dt is not None and self._calib is not None:
                f0, f1 = self._calibrate_moments(xm[0], xm[1], xm[2], dt)
            sf, sr = root(vm[1]) * f0, root(vm[2]) * f1
            if dt is not None and self._calib is not None and self.k_load is not None:  # (`_calibrate`)
                e0, e1 = self._load_band(C[1] + mb[1], C[2] + mb[2])
                sf, sr = math.hypot(sf, e0), math.hypot(sr, e1)
            est.__dict__.update(active=bool(self.active), vx=xm[0], vy=xm[1], yaw_rate=xm[2], Cf_y=C[1] + mb[1],
                                Cr_y=C[2] + mb[2], Cx=C[0] + mb[0], Cf_y_std=sf,
                                Cr_y_std=sr, Cx_std=root(vm[0]), Cf_y_sigma=root(s2[1]),
                                Cr_y_sigma=root(s2[2]), Cx_sigma=root(s2[0]), b_ax=bm[0], b_ay=bm[1], b_yaw_rate=bm[2],
                                ess=float(ess), state_std=(xs[0], xs[1], xs[2]), roll_gradient=k_mean,
                                roll_gradient_std=k_std)
            return est
        vx = float(self.u_prev[3])
        if dt is not None and self._calib is not None:
            f0, f1 = self._calibrate_moments(vx, xm[0], xm[1], dt)
        sf, sr = root(vm[0]) * f0, root(vm[1]) * f1
        if dt is not None and self._calib is not None and self.k_load is not None:  # (`_calibrate`)
            e0, e1 = self._load_band(C[0] + mb[0], C[1] + mb[1])
            sf, sr = math.hypot(sf, e0), math.hypot(sr, e1)
        est.__dict__.update(active=bool(self.active), vx=vx, vy=xm[0], yaw_rate=xm[1], Cf_y=C[0] + mb[0],
                            Cr_y=C[1] + mb[1], Cx=NAN, Cf_y_std=sf, Cr_y_std=sr, Cx_std=NAN,
                            Cf_y_sigma=root(s2[0]), Cr_y_sigma=root(s2[1]), Cx_sigma=NAN, b_ax=NAN, b_ay=bm[0],
                            b_yaw_rate=bm[1], ess=float(ess), state_std=(0.0, xs[0], xs[1]), roll_gradient=k_mean,
                            roll_gradient_std=k_std)
        return est

    def _estimate_compiled(self, ess: float) -> Estimate:
        """`_estimate` by the compiled moments (`kernels.estimate_moments`) and `_estimate_fused`."""
        st = self.stats
        mom = np.zeros((7, max(self.x.shape[1], self.n_w, len(self.channels))))
        self._nb.estimate_moments(self.logw, self.x, st.gamma, st.mu, st.Lam, st.nu, self.b, mom)
        return self._estimate_fused(ess, mom)

    def _ay_residual(self, a: np.ndarray, logw_pred: np.ndarray, wk: "_MPFWork") -> None:
        """`_predict_ay`'s `_e_ay` for the fused step, the residual of the calibration ("Batch-means sandwich"):
        the same expression on the column of a^Y (looked up once when every channel is there) and
        a buffer for the predictive weights; NaN when the a^Y sample is missing. Computed only
        once the gate is open: a closed gate does not feed the sandwich."""
        j = wk.ay_col if a is wk.avail_all else next((j for j in range(len(a)) if self.channels[a[j]] == 1), -1)
        if j >= 0:
            self._e_ay = float(np.dot(np.exp(logw_pred, out=wk.q_pred), wk.e[:, j]))  # (`@`'s own dot, bit for bit)

    def _work(self) -> "_MPFWork":
        """The fused step's arrays, the particles' own arrays among them: an array that the
        reference methods replaced (the prior drawn at the start or a restart, a loaded state) is copied in."""
        wk = self.__dict__.get("_wk")
        st = self.stats
        first = self.__dict__.get("_at_x")  # (none before the first sample)
        if (wk is not None and self.x is wk.x and self.w_prev is wk.w and st.mu is wk.mu and st.Lam is wk.Lam
                and st.gamma is wk.gamma and st.nu is wk.nu and self.b is wk.b and self.P is wk.P
                and first is not None and first[0] is wk.a):  # the last sample's fused step left them all in place
            return wk
        nx = self.x.shape[1]
        if wk is None or wk.x.shape != self.x.shape:
            wk = self._wk = _MPFWork(self, len(self.x), nx, self.n_w, len(self.channels))
        for name, arr in (("x", self.x), ("b", self.b), ("P", self.P), ("gamma", st.gamma), ("mu", st.mu),
                          ("Lam", st.Lam), ("nu", st.nu), ("w", self.w_prev)):
            buf = getattr(wk, name)
            if arr is not buf and arr is not None:  # (no w before the first sample)
                buf[...] = arr
        self.x, self.b, self.P, self.w_prev = wk.x, wk.b, wk.P, wk.w
        st.gamma, st.mu, st.Lam, st.nu = wk.gamma, wk.mu, wk.Lam, wk.nu
        if first is not None and first[0] is not wk.a:
            wk.a[...], wk.B[...] = first[0], first[1]
            wk.slip[...] = 0.0 if first[4] is None else first[4]
        return wk

    def _swap_work(self, wk: "_MPFWork") -> None:
        """After `resample_gate`: the spares hold the resampled particles."""
        wk.swap()
        st = self.stats
        self.x, self.b, self.P = wk.x, wk.b, wk.P
        st.gamma, st.mu, st.Lam, st.nu = wk.gamma, wk.mu, wk.Lam, wk.nu
        self._at_x = (wk.a, wk.B, wk.af, wk.ar, wk.slip if self.full else None)


class _MPFWork:
    """The arrays of `StiffnessMPF._step_compiled`, allocated once per filter: the
    particles' own arrays (x, b, P, the NiW statistics, the model's first stage a, B, slip)
    with a spare of each for resampling, and the weighting's per-particle arrays for all m
    channels (the first na columns are used when samples are missing). The kernels take them
    as tuples (their workspace): `own` (the arrays named OWN), `spares` (OWN2) and `scratch`."""

    OWN = ("x", "b", "P", "gamma", "mu", "Lam", "nu", "a", "B", "slip")
    OWN2 = tuple(name + "2" for name in OWN)

    def __init__(self, mpf: "StiffnessMPF", N: int, nx: int, n_w: int, m: int):
        shapes = dict(x=(N, nx), b=(N, m), P=(N, m, m), gamma=(N,), mu=(N, n_w), Lam=(N, n_w, n_w), nu=(N,),
                      a=(N, 3), B=(N, 3, n_w), slip=(2, N))
        for name, shape in shapes.items():
            setattr(self, name, np.zeros(shape))
            setattr(self, name + "2", np.zeros(shape))
        self.af, self.ar, self.nu_w, self.ll, self.nu_draw, self.q = (np.zeros(N) for _ in range(6))
        self.h, self.e, self.v = np.zeros((N, m)), np.zeros((N, m)), np.zeros((N, m))
        self.D, self.L11 = np.zeros((N, m, n_w)), np.zeros((N, n_w, n_w))
        self.L12, self.Lc = np.zeros((N, n_w, m)), np.zeros((N, m, m))
        self.w = np.zeros((N, n_w))
        self.ok = np.zeros(N, bool)
        self.idx = np.arange(N)
        self.mom = np.zeros((7, max(nx, n_w, m)))
        self.pin_lo, self.pin_hi = mpf._pin_bounds()
        self.no_noise, self.no_scale = np.zeros((0, nx)), np.zeros(nx)
        self.avail_all = np.arange(m)
        self.nc_all = sum(c in (0, 1) for c in mpf.channels)
        self.heun = mpf.cfg.integrator == "heun"
        self.interval = mpf.full and mpf.cfg.slip_hold == "interval"
        cfg = mpf.cfg
        # the kernels' sizes when every channel is there, as constants (`kernels.predict_weigh`'s `sizes`), and
        # otherwise from the arrays
        self.sizes_all = np.empty((0, 0, 0)) if mpf.full else np.empty((0, 0))
        self.sizes_any = np.empty(0)
        # the predictive weights kept for the calibration's residual (`_ay_residual`, "Batch-means sandwich") and
        # `_match_state_noise` ("State noise from the data")
        self.keep_pred = cfg.state_noise_from_data or mpf._calib is not None
        self.logw_pred, self.q_pred = np.zeros(N), np.zeros(N)
        self.ay_col = mpf.channels.index(1)  # the a^Y column of e when every channel is there
        self.ones2 = np.ones(2)  # `sample_update`'s std factors of the draw of w: the draw as it is
        self.drift_checked = None  # the drift statistic's array once checked C-contiguous float64
        self.lo = cfg.bound_low * mpf.C_ref - mpf.C_nom
        self.hi = cfg.bound_high * mpf.C_ref - mpf.C_nom
        # what `predict_weigh` takes besides the arrays: the options as floats, the model's arrays (the bias's random
        # walk q by the linear region, `model[linear_region]`), and the flags (by the gate, `flags[active]`)
        self.max_step, self.beta = float(cfg.max_step), float(cfg.plausible_beta)
        self.yaw_max, self.gate_speed = float(cfg.plausible_yaw_rate), float(cfg.gate_speed)
        self.gain = np.full(N, mpf.roll_gain)  # the roll gain per particle (`_roll_gains`)
        self.no_k = np.zeros(0)  # (`sample_update`'s k where the roll gradient is not estimated)
        self.roll_lo, self.roll_hi = (float(k) for k in cfg.roll_gradient_prior)  # (`_walk_roll`'s bounds)
        self.load_gain = np.ones(N)  # the load-transfer gain per particle (`_load_gains`)
        self.relaxed = np.zeros((2, N) if mpf.relaxing else (2, 0))  # the relaxed slip angles (`_keep_relaxed`)
        self.model = {linear: (mpf._vp, mpf._jw, mpf._c_floor, mpf.R, mpf.q_bias if linear else mpf.q_bias_nonlinear,
                               self.gain, self.load_gain, self.relaxed) for linear in (False, True)}
        adaptive = cfg.forgetting_mode == "adaptive"
        self.flags = {active: (self.heun, self.interval, mpf.bias_on, active, mpf.full, mpf.rear_drive, adaptive,
                               True, True) for active in (False, True)}
        # the first sample's: no propagation; the likelihood's weights, or the informed start's (`start_flags[False]`)
        self.start_flags = {weigh: (self.heun, self.interval, mpf.bias_on, False, mpf.full, mpf.rear_drive,
                                    adaptive and weigh, False, weigh) for weigh in (False, True)}
        self.no_redraw = np.zeros(0)  # (`predict_weigh`'s redraw when v^X is not drawn again)

        self.own = tuple(getattr(self, name) for name in self.OWN)
        self.spares = tuple(getattr(self, name + "2") for name in self.OWN)
        self.scratch = (self.af, self.ar, self.h, self.D, self.L11, self.nu_w, self.L12, self.Lc, self.e, self.v,
                        self.ll, self.ok)

    def swap(self) -> None:
        """The spares become the particles' arrays and the other way round (`own` and `spares`
        are always the tuples of the arrays named OWN and OWN2)."""
        d = self.__dict__
        self.own, self.spares = self.spares, self.own
        d.update(zip(self.OWN, self.own))
        d.update(zip(self.OWN2, self.spares))


def _sqrt_or_nan(v: float) -> float:
    """np.sqrt on a float: NaN below zero."""
    return math.sqrt(v) if v >= 0 else NAN
