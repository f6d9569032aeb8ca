"""The friction GP-SSM's step compiled (numba, nopython, `cache=True`): the `backend = "numba"`
path of `FrictionGPSSM.step`, the same arithmetic as the numpy reference in
`filter.py` (tested equal to 1e-12 relative in tests/test_kernels.py with the same
random numbers, resampling included).

One step is four kernel calls (five on a resampling step); the random numbers are drawn outside
them with the reference's generator calls, in the reference's order (yaw-rate start or state
noise, the resampling uniform, the Student-t draws `student_t.t_draws`), so both backends follow
one path:
  1. `front`: propagation (eq. (1), Euler sub-steps), slip angles (eq. (4)) clipped to
     [-L, L], the basis (eq. (10b)) by the angle-addition recurrence
     sin((k+1) a) = sin(k a) cos a + cos(k a) sin a (one sin and one cos per slip angle
     instead of one sin per function), the Pacejka prior (Sec. 4); the libm calls in one loop
     over the particles, the recurrence in a second one over all particles at once (a vector
     operation per function: per particle it is a chain of dependent multiply-adds);
  2. one pass over the statistics: for the exact statistics the previous step's update
     (eq. (27), kept pending until now), the forgetting (eq. (29)) and the predictive
     (eq. (31)-(32)), `exact_forget_predictive` (`_rows` from `LANES_BELOW` functions);
     for the rank-one ones the forgetting and the predictive, `rank1_forget_predictive`;
  3. `weigh`: the Student-t a^Y and Gaussian yaw-rate likelihoods (eq. (22)) with the bias
     filters' prediction (`gpssm.bias`; its random walk is added before, in numpy), the one-step
     prediction and its variance, log-sum-exp normalisation and the ESS, and `common_dof` (whether every
     particle draws with the same dof: the step then makes `t_draws`' two generator calls
     itself, `t_draws` otherwise);
  4. `resample` (when the ESS is low): systematic resampling (`systematic_ancestors`, the
     uniform drawn as `stats.systematic_resample` draws it) and its copies, in place
     (`gather_rows`, `gather_lanes`; sorted ancestors: only the rows that change are copied),
     the log-weights reset, `common_dof` again; from `LANES_BELOW` functions (the tensor bases)
     K's copy is left to the next pass, whose sweep copies each row of an element's ancestor's
     K into the element's and updates it there (`exact_forget_predictive_rows`, `copy_order`;
     sorted ancestors only, else `resample` copies K itself; `flush` makes the copy with
     `gather_lower` when the statistics are read in between): one pass over K instead of two;
  5. `sample`: the conditional Student-t draw of zeta (the locally optimal proposal), mu = mu~
     + zeta, the forces' linear hold (`force_hold = "linear"`: what their linear growth from the
     rates `front` held to those of mu's conditional mean adds to x over the step), the weighted
     moments for the estimate and of the slip angles (the band's slip
     variance) and, while the exact statistics learn, the features of the pending update; then
     the bias filters' update given mu (numpy, `FrictionGPSSM._bias_update`);
  6. `rank1_update` (rank-one statistics, eq. (27)/(28) as recursive least squares); the exact
     statistics' update waits for the next step's pass (`CompiledStep.flush` applies it with
     `exact_update` when the statistics are read in between).

The step keeps only the lower triangle of the exact statistics' K = Sigma + V up to date
(`flush` mirrors it); below `LANES_BELOW` functions it keeps K in lanes (`CompiledStep.Kl`,
below) and writes it back into the statistics only at `flush`. The exact predictive factorises K
(m x m) per batch element, and only forward substitution is needed: with Z = C^-1 [Psi^T, phi]
(C C^T = K), Psi K^-1 Psi^T = Z_Psi^T Z_Psi, phi^T K^-1 phi = |z_phi|^2 and M phi = Z_Psi^T
z_phi. Below `LANES_BELOW` basis functions (the per-axle basis) the factorisation runs on
`LANES` batch elements at once, one SIMD lane each (the matrices interleaved as (m, m, LANES),
so every inner loop is a vector operation over lanes; fewer lanes when the batch is smaller), in
three stages per block of lanes: the pending update and the forgetting, a vector operation over
the lanes per entry of K, since the step keeps K itself in lanes between `flush`es (`Kl`
(blocks, m, m, LANES), loaded from the statistics by `lanes_load` at the first step after a
flush, written back by `lanes_store`; the sweep over each element's K apart,
written into its lane strided by the lane count, took half of the pass), each entry written into
the factorisation's matrix in the same sweep (`_lane_heads` does each element's scalar part),
the factorisation with the forward substitution (`_chol_lanes`), and the predictive's sums over
the basis accumulated over all lanes at once before each lane's scalar tail
(`_write_predictive_lanes`; reading each lane's sums apart, strided by the lane count, cost
10-20% of the pass at m = 10). From `LANES_BELOW` up (the tensor bases) each matrix is
factorised alone by a register-blocked row Cholesky (`_chol_rows`: four rows against two
columns, the sums over the columns vectorised), about 0.6 of LAPACK's dpotrf called per matrix
at m = 100 and 0.9 of the lanes at m = 50 (docs/performance.md, "Backends"). No exact low-rank update of the factor exists under the paper's forgetting
(docs/derivations.md, "The GP-SSM's exact statistics in the compiled step"): each step refactorises.

The kernels, by concern: kernels_particles.py (`front`, `weigh`, `sample`, `common_dof`, the
columns of `work`), kernels_stats.py (the pass over the statistics, K's lanes, `mirror`,
`rank1_update`), kernels_resample.py (`resample` and its copies).

Per-particle quantities of the step live in one (N, columns) array `work` (its columns in kernels_particles.py),
so resampling copies them with the statistics in one call. The Python around the kernels is
kept short (at N = 8 the per-axle step is mostly this fixed cost): the flat views
of the statistics and the configuration's scalars are made once (`CompiledStep._arrays`,
rebuilt when the statistics or the particles' or the bias filters' arrays are replaced, not
pickled), and the
Estimate is a copy of a template's fields (`CompiledStep._estimate`).
"""

from __future__ import annotations

import math

import numpy as np

from tirefilter.errors import ConfigError
from tirefilter.estimators.base import Estimate
from tirefilter.estimators.gpssm.bias import bias_predict
from tirefilter.estimators.gpssm.kernels_particles import DOF, PF, PHI, PR, front, sample, weigh
from tirefilter.estimators.gpssm.kernels_resample import gather_lower, resample
from tirefilter.estimators.gpssm.kernels_stats import (LANES, LANES_BELOW, exact_forget_predictive,
                                                       exact_forget_predictive_rows, lanes_load, lanes_store,
                                                       mirror, rank1_forget_predictive, rank1_update)
from tirefilter.stats.mniw_numba import exact_update
from tirefilter.stats.student_t import t_draws

NAN = math.nan
_new = object.__new__


# ---- the step ------------------------------------------------------------------------------------
def _flat(a, tail: int):
    return a.reshape((-1,) + a.shape[a.ndim - tail:])


class CompiledStep:
    """The compiled step of one `FrictionGPSSM` (built at its `reset`): the work array and
    flat views of the statistics' arrays (the statistics are updated in place); below
    `LANES_BELOW` functions with the exact statistics also K in lanes (`Kl`, the statistics'
    K written back by `flush`)."""

    def __init__(self, est):
        from tirefilter.stats.mniw_numba import NumbaMNIW, NumbaMNIWRank1

        cfg, N = est.cfg, est.cfg.particles
        self.est = est
        self.N = N
        self.tensor = est.d == 2
        self.per = 1 if self.tensor else 2
        size = est.basis.size
        self.work = np.zeros((N, PHI + size * self.per))
        self.zeta = np.zeros((N, 2))
        self.phi_p = np.zeros((N, size * self.per))  # features of the pending update
        self.pending = False  # exact statistics: this step's update waits for the next pass
        self.stale_upper = False  # the kernels keep K's lower triangle; `flush` mirrors it
        # the rows pass (from LANES_BELOW functions): the last resampling's ancestors, whose copy
        # of K's lower triangles the next pass makes (`gather`: still to be made)
        self.anc = np.arange(N, dtype=np.int64)
        self.gather = False
        keep = np.ascontiguousarray(est.basis.keep, np.int64)
        m1 = int(est.b1.m)
        self.keep, self.keep_r = (keep // m1, keep % m1) if est.d == 2 else (keep, keep)
        self.m1 = m1
        self.L = float(cfg.L)
        self.exact = cfg.stats == "exact"
        st = est._stats
        if not isinstance(st, (NumbaMNIW, NumbaMNIWRank1)):
            raise TypeError("the compiled step needs the compiled statistics (backend numba)")
        self.lanes = size < LANES_BELOW
        # exact statistics in lanes: K lives in Kl between `flush`es (kl_loaded: Kl holds K, the
        # statistics' K is stale; loaded from the statistics at the next step after a flush)
        nb = N * self.per
        W = min(LANES, -(-nb // 4) * 4)  # fewer lanes for a small batch (each lane's numbers are its own)
        self.Kl = (np.zeros((-(-nb // W), size, size, W)) if self.exact and self.lanes
                   else np.zeros((0, 0, 0, 0)))
        self.kl_loaded = False
        v = est.vehicle
        self.veh = (float(est.Fz[0]), float(est.Fz[1]), float(v.mass), float(v.lf), float(v.lr),
                    float(v.yaw_inertia))
        # the configuration's scalars, read once (the configuration is frozen)
        self.max_step = float(cfg.max_step)
        self.linear_hold = cfg.force_hold == "linear"
        self.sn = np.asarray(cfg.state_noise, float)
        self.noise = bool(cfg.state_noise[0] > 0 or cfg.state_noise[1] > 0)
        self.gate_speed = float(cfg.gate_speed)
        self.nu0 = float(est.nu0)
        self.learned = cfg.measurement_friction == "learned"
        self.threshold = cfg.resample_threshold * N
        self.R0, self.R1 = float(est.R[0]), float(est.R[1])
        self.sqrt_R1 = math.sqrt(est.R[1])
        self._cache = None  # views of the statistics and the particles (`_arrays`); not pickled
        self._prior = self._template = self._slope = self._front_prior = self._pargs = None

    def __getstate__(self):  # views would come back as copies: rebuilt after unpickling
        state = dict(self.__dict__)
        state["_cache"] = None
        return state

    def _arrays(self):
        """(statistics, particles, flat statistics' views, the resampling's (N, k) views, K for the
        resampling copies, the statistics' arrays, the bias filters), rebuilt when the statistics,
        their arrays, the particles' array or the bias's were replaced (K then loaded into the
        lanes again)."""
        est = self.est
        st = est._stats
        a0, a1, a2 = (st.K, st.Psi, st.Phi) if self.exact else (st.M, st.P, st.Lam)
        c = self._cache
        if c is not None:  # (`is` one by one: a generator over the four costs about a microsecond)
            a = c[5]
            if (c[0] is st and c[1] is est.x and a[0] is a0 and a[1] is a1 and a[2] is a2 and a[3] is st.nu
                    and c[6] is est.bias):
                return c
        arrays = (a0, a1, a2, st.nu)
        N = self.N
        views = (_flat(arrays[0], 2), _flat(arrays[1], 2), _flat(arrays[2], 2), arrays[3].reshape(-1))
        rows = (st.Psi, st.Phi) if self.exact else (st.M, st.P, st.Lam)
        rows = tuple(a.reshape(N, -1) for a in rows) + (st.nu.reshape(N, -1), est.x, self.work, est.bias)
        if self.exact and not self.lanes:  # (the rows pass makes the copy: `resample`'s `defer`)
            kcopy = st.K.reshape((N, self.per) + st.K.shape[-2:])
        else:
            kcopy = self.Kl  # lanes, or empty (rank-one statistics: nothing beyond the rows)
        if c is not None and not (c[0] is st and c[5][0] is a0):
            self.kl_loaded = False  # other statistics or another K: K from them (a new particles'
            # array alone leaves the lanes holding the statistics' current K)
            self.gather = False  # (and no resampling copy made into them)
        self._cache = c = (st, est.x, views, rows, kcopy, arrays, est.bias)
        return c

    def flush(self) -> None:
        """Apply a pending update of the exact statistics now (before anything reads them)."""
        # (each flag cleared once its work is done: a reader never sees it cleared over statistics
        # that are still stale)
        if self.kl_loaded:  # K's lower triangle back from the lanes
            lanes_store(self.Kl, self._views()[0])
            self.stale_upper = True
            self.kl_loaded = False  # the step loads it again (a reader may change the statistics)
        if self.gather:  # the last resampling's copy of K, left to the next pass
            K = self._views()[0]
            gather_lower(K.reshape((self.N, self.per) + K.shape[1:]), self.anc)
            self.stale_upper = True
            self.gather = False
        if self.pending:
            K, Psi, Phi, nu = self._views()
            d, m = Psi.shape[1:]  # per particle and step: `per` batch rows of d outputs and m features
            exact_update(Phi, Psi, K, nu, self.zeta.reshape(-1, d), self.phi_p.reshape(-1, m))
            self.stale_upper = True  # the reference's update writes both triangles; the lower one is kept
            self.pending = False
        if self.stale_upper:
            mirror(self._views()[0])
            self.stale_upper = False

    def _views(self):
        return self._arrays()[2]

    def _rows(self):
        """Every per-particle array as (N, k) views, for the resampling copies."""
        return self._arrays()[3]

    def _estimate(self, ess, vx, moments):
        """`FrictionGPSSM._estimate` with the exact statistics and no MPF, the same fields: the
        stiffness fields (`_curve_slope` without M: the last snapshot's or the prior's) and the
        Estimate's defaults built by `Estimate` again only when the snapshot's slope or the prior
        changed; per step a copy of that template's fields with this step's (a frozen dataclass's
        `__init__` sets its 18 fields one by one: 3-5 us a step)."""
        est = self.est
        if est._slope is not self._slope or est.prior is not self._prior:
            self._slope, self._prior = est._slope, est.prior
            stiff = {k: float(v) for k, v in est._curve_slope(None, None).items()}
            self._template = Estimate(active=False, vx=NAN, vy=NAN, yaw_rate=NAN, ess=NAN, **stiff).__dict__
        m0, m1, s0, s1 = moments
        e = _new(Estimate)
        fields = e.__dict__
        fields.update(self._template)
        fields.update(active=est.active, vx=vx, vy=float(m0), yaw_rate=float(m1), ess=ess,
                      state_std=(0.0, float(s0), float(s1)))
        if est.bias_on:
            fields["b_ay"], fields["b_yaw_rate"] = est.bias_mean()
        return e

    def step(self, t, uk, delta: float, vx: float, y):
        est = self.est
        N, rng = self.N, est.rng
        work, (Fz0, Fz1, mass) = self.work, self.veh[:3]
        _, _, (a1, a2, a3, nu), rows, kcopy, _, _ = self._arrays()
        # 1. propagate with the friction drawn at k-1 (eq. (1)), forget (eq. (29), fused into 2.)
        forget, lam, linear = False, 1.0, False
        propagate, n_sub, h, cd, vx_prev, dt = False, 0, 0.0, 1.0, 0.0, 0.0
        if est.t_prev is None:
            if math.isfinite(y.yaw_rate):
                est.x[:, 1] = y.yaw_rate + self.sqrt_R1 * rng.standard_normal(N)
        else:
            dt = t - est.t_prev
            if dt <= 0:
                raise ConfigError("inputs", "t", f"time must increase: {t} after {est.t_prev}")
            n_sub = max(1, math.ceil(dt / self.max_step - 1e-9))
            h = dt / n_sub
            u_prev = est.u_prev
            cd, vx_prev, propagate = math.cos(u_prev[0]), float(u_prev[1]), True
            linear = self.linear_hold  # the forces linear from mu_{k-1} to mu_k (`sample`)
            if est.bias_on:  # the bias's random walk (`gpssm.bias`)
                bias_predict(est.bias, est.q_bias, dt)
            if self.noise:
                front(est.x, est.mu, work, (True, n_sub, h, cd, vx_prev), self.veh, delta, vx,
                      (self.L, self.m1, self.keep, self.keep_r, self.tensor), (1.0, 1.0, 1.0, 0.0, 0.0, 0.0))
                est.x[:] = est.x + math.sqrt(dt) * self.sn * rng.standard_normal(est.x.shape)
                propagate = False
            forget = est.active
            lam = est.forgetting_factor(dt)
        est.active = active = bool(vx > self.gate_speed and est.learning_started)
        # 2. slip angles (clipped, counted), features, prior
        p = est.prior
        if p is not self._front_prior:  # the prior's parameters as floats, again when the prior changes
            self._front_prior = p
            self._pargs = (float(p.B[0]), float(p.B[1]), float(p.C), float(p.D[0]), float(p.D[1]), float(p.E))
        n_out = front(est.x, est.mu, work, (propagate, n_sub, h, cd, vx_prev), self.veh, delta, vx,
                      (self.L, self.m1, self.keep, self.keep_r, self.tensor), self._pargs)
        est.slip_evaluations += N
        est.clip_share = n_out / N
        if n_out:
            est.clipped += n_out
            est.clipped_steps += 1
        # 3. forgetting and predictive
        if self.exact:
            V, Lam0 = est._stats.V, est._stats.Lam0
            if self.lanes:
                if not self.kl_loaded:
                    lanes_load(a1, self.Kl)
                    self.kl_loaded = True
                exact_forget_predictive(self.Kl, (a2, a3, nu), (V, Lam0), work, self.per,
                                        (forget, lam, self.nu0), (self.pending, self.zeta, self.phi_p))
            else:
                exact_forget_predictive_rows(a1, (a2, a3, nu), (V, Lam0), work, self.per, (forget, lam, self.nu0),
                                             (self.pending, self.zeta, self.phi_p), self.anc, self.gather)
                self.stale_upper = True
                self.gather = False
            self.pending = False
        else:
            rank1_forget_predictive(a1, a2, a3, nu, work, self.per, forget, lam, self.nu0,
                                    bool(est._stats.bounded), float(est._stats.trace0))
        # 4. weights (eq. (22)), resampling
        yay, yr = float(y.ay), float(y.yaw_rate)
        have_ay = math.isfinite(yay)
        learned = self.learned
        conditional = have_ay and learned
        add = 1.0 if conditional else 0.0
        c0, c1 = Fz0 * math.cos(delta) / mass, Fz1 / mass
        ess, pa, pr_, c, va, vr = weigh(est.x, work, est.logw, est.bias, c0, c1,
                                        (yay, yr, have_ay, math.isfinite(yr)), (self.R0, self.R1), learned, add)
        est.prediction, est.prediction_var = (pa, pr_), (va, vr)
        if ess < self.threshold:  # as stats.systematic_resample, its uniform first
            defer = self.exact and not self.lanes
            c = resample(est.logw, float(rng.random((1,))[0]), rows, kcopy, self.per, self.lanes, add, work,
                         self.anc, defer)
            est.resamples += 1
            self.gather = defer  # K's copy: in the next pass (or `flush`)
        # 5. zeta (t conditional given the a^Y residual), mu, learning
        if math.isnan(c):  # dof differing between particles (or NaN): as the reference
            z, u = t_draws(work[:, DOF] + 1.0 if conditional else work[:, DOF], (N, 2), rng)
            u = np.ascontiguousarray(u, float)
        else:  # t_draws' generator calls for a common dof, without its checks
            z, u = rng.standard_normal((N, 2)), rng.chisquare(c, (N,))
        exact_active = active and self.exact
        r_seen = est.x[:, 1].copy() if est.bias_on else None  # the yaw rate the weights saw (`_bias_update`)
        m0, m1, s0, s1, mf, mr, vf, vr = sample(est.x, work, est.logw, z, u, self.zeta, est.mu, conditional,
                                                exact_active, self.phi_p,
                                                (linear, dt, vx_prev, math.cos(delta), self.veh))
        lag = est._hold_slip_error(t, y, vx) if active else 0.0  # (with the bias before its update, as the reference)
        if est.bias_on:  # the bias given the trajectory (`FrictionGPSSM._bias_update`)
            est._bias_update(y, est.mu @ np.array([c0, c1]) if learned else c0 * work[:, PF] + c1 * work[:, PR],
                             r_seen)
        if active:
            if self.exact:  # applied in the next step's pass over the statistics (or by `flush`)
                self.pending = True
            else:
                rank1_update(a1, a2, a3, nu, work, self.zeta, self.per)
            v = est.visited
            est.visited = [min(v[0], mf), max(v[1], mf), min(v[2], mr), max(v[3], mr)]
            jf, jr = est._bin(mf), est._bin(mr)
            if self.tensor:  # the reference's `_path[0, jf] += (1.0, mr)`, element by element
                path = est._path
                path[0, jf, 0] += 1.0
                path[0, jf, 1] += mr
                path[1, jr, 0] += 1.0
                path[1, jr, 1] += mf
            est._slip_spread(lam if forget else 1.0, jf, jr, vf, vr, lag)
            est.mean_slip = (mf, mr)
        est.lam_step = lam if forget else 1.0
        est.t_prev, est.u_prev, est.last_t = t, uk, t
        if self.exact and est.mpf_estimate is None:
            return self._estimate(ess, vx, (m0, m1, s0, s1))
        return est._estimate(ess, vx, (m0, m1, s0, s1))
