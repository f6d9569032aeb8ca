"""One step of the stiffness MPF's numpy reference against textbook answers computed here
from the particles as they stood: the weights (eq. (36): each particle's predictive
Student-t density of the sample, scipy's multivariate_t, also with a missing channel), the
bias filter (eq. (30): a Kalman update per particle), the statistics update (eq. (19) with
the drawn w_k, then the projection onto the stiffness bounds) and the drift statistic of the
adaptive forgetting. The compiled step is checked against this reference in
tests/test_kernels.py; these tests are what would catch an error made in both. Found by
mutation testing (benchmarks/mutation.py)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy import stats as sps
from scipy.special import logsumexp

from tirefilter.estimators.base import Inputs, Measurement
from tirefilter.estimators.mpf import MPFConfig, StiffnessMPF
from tirefilter.estimators.mpf.adaptation import DRIFT_TIME
from tirefilter.scenarios import load_scenario
from tirefilter.stats.niw import NiW

STEPS = 30  # the step checked is the 31st: the gate has been open since the 6th


def _samples(vehicle, steps, missing_ay_at=None):
    """A gentle sine steer at 20 m/s with sensor noise (fixed seed); the a^Y sample of step
    `missing_ay_at` missing."""
    rng = np.random.default_rng(80)
    omega = 20.0 / vehicle.wheel_radius
    for k in range(steps):
        t = 0.01 * k
        delta = 0.02 * math.sin(2 * math.pi * 0.7 * t)
        r = 20.0 * delta / (vehicle.lf + vehicle.lr)
        ay = math.nan if k == missing_ay_at else 20.0 * r + 0.05 * rng.standard_normal()
        y = Measurement(ax=0.2 + 0.05 * rng.standard_normal(), ay=ay, yaw_rate=r + 0.003 * rng.standard_normal())
        yield t, Inputs(delta=delta, omega_f=omega * 1.01, omega_r=omega, vx=20.0), y


class _Before:
    """The particles as the checked step's weighting finds them (after the propagation, the
    bias covariance's prediction and the statistics' forgetting): recorded when the step
    evaluates the measurement model, with that model's h and D."""

    def __init__(self, est: StiffnessMPF):
        self.armed, self.rec = False, None
        measurement = est._measurement

        def recorded(a, B, x):
            h, D = measurement(a, B, x)
            if self.armed and self.rec is None:
                st = est.stats
                self.rec = dict(h=h.copy(), D=D.copy(), b=est.b.copy(), P=est.P.copy(), logw=est.logw.copy(),
                                drift=np.array(est.drift, float), active=est.active,
                                stats=NiW(st.gamma.copy(), st.mu.copy(), st.Lam.copy(), st.nu.copy()))
            return h, D

        est._measurement = recorded


def _step_checked(model: str, missing: bool, **options):
    """A numpy-backend filter (N = 8, no resampling, learning from 0.05 s) run STEPS samples,
    then one more with the particles recorded before its weighting: (filter, record, y)."""
    vehicle = load_scenario("paper-sim").vehicle
    cfg = MPFConfig(particles=8, model=model, backend="numpy", resample_threshold=0.0, gate_warmup=0.05,
                    gate_vy_std=10.0, gate_steer=0.0, bias_rw=(0.01, 0.01, 0.001), bias0_std=(0.1, 0.1, 0.01),
                    **options)
    est = StiffnessMPF(vehicle, cfg)
    est.reset(np.random.default_rng(81))
    before = _Before(est)
    samples = list(_samples(vehicle, STEPS + 1, missing_ay_at=STEPS if missing else None))
    for t, u, y in samples[:STEPS]:
        est.step(t, u, y)
    before.armed = True
    t, u, y = samples[STEPS]
    est.step(t, u, y)
    assert est.restarts == 0 and est.resamples == 0 and before.rec["active"] and est.active
    yk = np.array([y.ax, y.ay, y.yaw_rate])[list(est.channels)]
    return est, before.rec, yk


CASES = [("full", False), ("full", True), ("lateral", False), ("lateral", True)]
IDS = ["full", "full-ay-missing", "lateral", "lateral-ay-missing"]


@pytest.mark.parametrize("model,missing", CASES, ids=IDS)
def test_weights_are_each_particles_predictive_density_of_the_sample(model, missing):
    """Eq. (36): the log-weight gains log St(y_a; h_a + b_a + D_a mu, D_a L D_a^T +
    (nu - 2) / nu (R_aa + P_aa), nu) over the available channels a, with (mu, L, nu) the
    particle's NiW predictive of w; then normalised."""
    est, rec, yk = _step_checked(model, missing)
    a = np.flatnonzero(np.isfinite(yk))
    assert len(a) == len(yk) - missing
    mu, L, nu = rec["stats"].predictive()
    ll = np.empty(len(mu))
    for i in range(len(mu)):
        D = rec["D"][i][a]
        S = D @ L[i] @ D.T + (nu[i] - 2.0) / nu[i] * (est.R[np.ix_(a, a)] + rec["P"][i][np.ix_(a, a)])
        loc = rec["h"][i][a] + rec["b"][i][a] + D @ mu[i]
        ll[i] = sps.multivariate_t(loc=loc, shape=S, df=nu[i]).logpdf(yk[a])
    total = rec["logw"] + ll
    np.testing.assert_allclose(est.logw, total - logsumexp(total), rtol=1e-9, atol=1e-9)
    assert np.ptp(ll) > 0.1  # the weights differ between the particles


@pytest.mark.parametrize("model,missing", CASES, ids=IDS)
def test_bias_update_is_a_kalman_step_per_particle(model, missing):
    """Eq. (30) over the available channels a: S = P_aa + R_aa + D_a E[Sigma] D_a^T,
    K = P_{:,a} S^-1, b += K (y_a - h_a - D_a mu - b_a), P -= K S K^T."""
    est, rec, yk = _step_checked(model, missing)
    a = np.flatnonzero(np.isfinite(yk))
    ESig = rec["stats"].mean_sigma()
    for i in range(len(ESig)):
        P, D = rec["P"][i], rec["D"][i][a]
        S = P[np.ix_(a, a)] + est.R[np.ix_(a, a)] + D @ ESig[i] @ D.T
        K = P[:, a] @ np.linalg.inv(S)
        innov = yk[a] - rec["h"][i][a] - D @ rec["stats"].mu[i] - rec["b"][i][a]
        np.testing.assert_allclose(est.b[i], rec["b"][i] + K @ innov, rtol=1e-10, atol=1e-14)
        np.testing.assert_allclose(est.P[i], P - K @ S @ K.T, rtol=1e-10, atol=1e-16)
        assert np.all(est.P[i] == est.P[i].T)
    assert np.all(np.abs(est.b - rec["b"])[:, a] > 0)  # the biases of the available channels moved


@pytest.mark.parametrize("model", ["full", "lateral"])
def test_statistics_learn_the_drawn_w_within_the_stiffness_bounds(model):
    """Eq. (19) with the w_k the step drew (the conjugate update of the particle's NiW
    statistics), then the projection of Sec. V: the stiffness C_nom + mu kept within
    [0.97, 1.03] C_ref (narrow bounds, so that some particles are projected and some not);
    and the drift statistic z' (derivations Sec. 17) moves by a = 1 - exp(-dt / DRIFT_TIME)
    towards the weighted mean of L^-1 (w - mu), L the Cholesky factor of the predictive scale."""
    est, rec, _ = _step_checked(model, False, bound_low=0.6, bound_high=1.4, restart_at_bound_after=0.0)
    w = est.w_prev
    want = rec["stats"].copy()
    mu_w, L11, _ = want.predictive()
    want.update(w)
    unprojected = est.C_nom + want.mu
    stiff = np.clip(unprojected, 0.6 * est.C_ref, 1.4 * est.C_ref)
    moved = stiff != unprojected
    assert moved.any() and (~moved).any()
    np.testing.assert_allclose(est.C_nom + est.stats.mu, stiff, rtol=1e-12)
    for got, exp in ((est.stats.gamma, want.gamma), (est.stats.Lam, want.Lam), (est.stats.nu, want.nu)):
        np.testing.assert_allclose(got, exp, rtol=1e-12)
    u = np.stack([np.linalg.solve(np.linalg.cholesky(L11[i]), w[i] - mu_w[i]) for i in range(len(w))])
    a = -math.expm1(-0.01 / DRIFT_TIME)
    np.testing.assert_allclose(est.drift, rec["drift"] + a * (np.exp(est.logw) @ u - rec["drift"]), rtol=1e-10)


def test_load_band_is_the_batch_level_and_the_derivative_of_c0_in_kappa():
    """kappa's share of the band (derivations, "Load transfer"): the recursive information-weighted a^Y^2
    (`_track_load_level`) equals the batch sum with the products of the later forgetting factors,
    sum_k (prod_{j>k} lam_j) d_k^2 a_k^2 / sum_k (prod_{j>k} lam_j) d_k^2, and the std is |dC_0/dkappa|
    sigma_kappa with C_0 = C_eff / (1 - kappa m) differentiated numerically at C_eff fixed."""
    vehicle = dataclasses.replace(load_scenario("paper-sim").vehicle, load_sensitivity=None)  # (estimated)
    est = StiffnessMPF(vehicle, MPFConfig(particles=50, backend="numpy", load_sensitivity_estimate=True))
    est.reset(np.random.default_rng(2))
    rng = np.random.default_rng(3)
    n = 40
    d = rng.normal(0.0, 0.02, (n, 2))
    ay = rng.uniform(-5.0, 5.0, n)
    lam = rng.uniform(0.97, 1.0, n)
    for k in range(n):
        est._ay_step, est._lam_step = ay[k], lam[k]
        est._track_load_level(d[k, 0], d[k, 1])
    k_roll = est._roll_moments()[0]  # (NaN where the vehicle file gives the roll gradient: its gain)
    a2 = (ay / (est.roll_gain if math.isnan(k_roll) else 1.0 + k_roll * 9.80665)) ** 2
    keep = np.array([np.prod(lam[k + 1:] ** est._calib_power) for k in range(n)])
    for axle in (0, 1):
        w = keep * d[:, axle] ** 2
        want = float(w @ a2 / w.sum())
        assert est._load_level[2 * axle] / est._load_level[2 * axle + 1] == pytest.approx(want, rel=1e-12)
    m_f = est._load_level[0] / est._load_level[1]
    kappa, k_std = est._load_moments()
    C0 = 1.2e5
    C_eff = C0 * (1.0 - kappa * m_f)
    h = 1e-7
    dC0 = (C_eff / (1.0 - (kappa + h) * m_f) - C_eff / (1.0 - (kappa - h) * m_f)) / (2 * h)
    assert est._load_band(C0, C0)[0] == pytest.approx(abs(dC0) * k_std, rel=1e-6)
