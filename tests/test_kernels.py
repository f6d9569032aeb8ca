"""The compiled (numba) kernels against the numpy reference: fed the same numbers and the
same random generator, equal to 1e-12 relative (to each array's largest magnitude, so
entries near zero are compared on the array's scale).

Stiffness MPF: whole filter runs, the backends from one seed, full and lateral models,
bias estimation on and off, resampling at every step, missing samples, a gap that is
sub-stepped, and restarts. The C backend (estimators/mpf/native) runs each of these drives
too and equals the numba backend bit for bit (`_assert_c_is_numba`).

Friction GP-SSM: the basis, the MNIW predictive / update / forgetting (exact and rank-one
statistics) and whole filter runs with resampling, over the per-axle basis, the default
(odd 50-function tensor) and the paper's 100-function tensor. Sizes are small: the test is
about equality, the cost is the benchmarks' business.
"""

from __future__ import annotations

import math
import sys

import numpy as np
import pytest

from tirefilter.estimators.base import Inputs, Measurement
from tirefilter.estimators.gpssm.filter import FrictionGPSSM, GPSSMConfig
from tirefilter.estimators.mpf import MPFConfig, StiffnessMPF
from tirefilter.scenarios import load_scenario
from tirefilter.stats.gp import GPBasis1D, make_basis
from tirefilter.stats.mniw import make_mniw
from tirefilter.stats.mniw_numba import basis_features

RTOL = 1e-12
# The paper's 100-function tensor basis: its statistics M come out of solves with the 100 x 100
# Lambda, whose conditioning spreads the two backends' rounding (summation order, fused
# multiply-add) wider: measured 1.3e-12 of the largest |M| on a Xeon of the CI class.
TENSOR_100_RTOL = 1e-11

# (basis, symmetry, functions per slip dimension): per-axle, default, the paper's tensor
BASES = [("axle", "odd", 20), ("tensor", "odd", 10), ("tensor", "none", 10)]
BASIS_IDS = ["axle", "tensor-odd-50", "tensor-100"]


def assert_equal_to_rounding(a, b, what="", rtol=None):
    rtol = RTOL if rtol is None else rtol  # the module's RTOL at call time (some tests patch it)
    a, b = np.asarray(a, float), np.asarray(b, float)
    assert a.shape == b.shape, (what, a.shape, b.shape)
    scale = float(np.max(np.abs(b))) if b.size else 0.0
    np.testing.assert_allclose(a, b, rtol=rtol, atol=rtol * scale, err_msg=what)


def _basis(kind, symmetry, m):
    return make_basis(kind, GPBasis1D(30 * math.pi / 180, m, 2 * math.pi / 180, 500.0), symmetry == "odd")


@pytest.mark.parametrize("kind,symmetry,m", BASES, ids=BASIS_IDS)
def test_basis_features_equal(kind, symmetry, m):
    basis = _basis(kind, symmetry, m)
    rng = np.random.default_rng(1)
    af, ar = rng.uniform(-0.5, 0.5, 37), rng.uniform(-0.5, 0.5, 37)
    assert_equal_to_rounding(basis_features(basis, af, ar), basis.features(af, ar), "features")


@pytest.mark.parametrize("stats", ["exact", "rank1"])
@pytest.mark.parametrize("kind,symmetry,m", BASES, ids=BASIS_IDS)
def test_mniw_kernels_equal(kind, symmetry, m, stats):
    """Twelve rounds of forget / predictive / update (with the prior's dof clamp active at
    the start) and a resampling `take`, both backends fed the same zeta and phi."""
    basis = _basis(kind, symmetry, m)
    d = 2 if kind == "tensor" else 1
    batch = (7,) if d == 2 else (7, 2)
    nu0 = d + 3.0
    Lam0 = np.eye(d) * 1e-4 * (nu0 - d - 1.0)
    ref = make_mniw(stats, batch, d, basis.S, Lam0, nu0, "numpy")
    fast = make_mniw(stats, batch, d, basis.S, Lam0, nu0, "numba")
    rng = np.random.default_rng(2)
    for k in range(12):
        for s in (ref, fast):
            s.forget(0.97, nu_min=nu0)
        af, ar = rng.uniform(-0.2, 0.2, 7), rng.uniform(-0.2, 0.2, 7)
        phi = basis.features(af, ar)
        out_ref, out_fast = ref.predictive(phi), fast.predictive(phi)
        for a, b, name in zip(out_fast, out_ref, ("loc", "scale", "dof")):
            assert_equal_to_rounding(a, b, f"{name} at round {k}")
        zeta = out_ref[0] + 0.01 * rng.standard_normal(out_ref[0].shape)
        ref.update(zeta, phi)
        fast.update(zeta, phi)
        if k == 6:
            idx = rng.integers(0, 7, 7)
            ref, fast = ref.take(idx), fast.take(idx)
    for a, b in zip(fast.posterior(), ref.posterior()):
        assert_equal_to_rounding(a, b, "posterior")
    assert_equal_to_rounding(fast.nu, ref.nu, "nu")


def _drive(est: FrictionGPSSM, steps: int, snapshot_every: int = 0, missing: bool = False):
    """A synthetic slalom at 15 m/s, 25 Hz, a^Y and yaw rate from a linear single track
    with a little noise (no FMU): enough to learn, resample and clip nothing. With
    `snapshot_every`, `friction()` between steps (the compiled step's pending update and
    K's upper triangle are then brought up to date mid-run); `missing`: a^Y missing every
    7th sample, the yaw rate once."""
    est.reset(np.random.default_rng(9))
    return _drive_on(est, 0, steps, snapshot_every, missing)


def _drive_on(est: FrictionGPSSM, start: int, steps: int, snapshot_every: int = 0, missing: bool = False):
    """`_drive`'s samples `start` to `steps` on `est` as it is (an unpickled copy resumes
    there): the noise of the samples before `start` is drawn and dropped."""
    rng = np.random.default_rng(5)
    out = []
    for k in range(steps):
        if k < start:
            rng.standard_normal(2)
            continue
        if snapshot_every and k % snapshot_every == snapshot_every - 1:
            f = est.friction()
            out.append((f.mu_f[40], f.mu_r[40], f.mu_f_std[40], f.mu_r_std[40], float(np.sum(f.mu_f))))
        t = 0.04 * k
        delta = 0.03 * math.sin(2 * math.pi * 0.5 * t)
        r = 15.0 * delta / 2.8
        ay, yaw_rate = 15.0 * r + 0.05 * rng.standard_normal(), r + 0.003 * rng.standard_normal()
        if missing:
            ay = math.nan if k % 7 == 3 else ay
            yaw_rate = math.nan if k == 11 else yaw_rate
        e = est.step(t, Inputs(delta=delta, vx=15.0), Measurement(ay=ay, yaw_rate=yaw_rate))
        out.append((e.vy, e.yaw_rate, e.ess, e.Cf_y, e.Cr_y))
    return np.array(out)


@pytest.mark.parametrize("snapshots", [0, 4], ids=["", "snapshots"])
@pytest.mark.parametrize("stats", ["exact", "rank1"])
@pytest.mark.parametrize("kind,symmetry,m", BASES, ids=BASIS_IDS)
def test_friction_gpssm_backends_equal(kind, symmetry, m, stats, snapshots):
    """A whole filter run (25 steps, N = 37: more than one block of the compiled
    factorisation's 32 lanes, the last one partly padding; resampling at every step:
    threshold 1), numba and numpy backends from the same seed: the same estimates, particles
    and statistics; `snapshots`: friction curves every 4th step, and the forces' linear hold
    (`force_hold = "linear"`; held without snapshots)."""
    vehicle = load_scenario("friction-snow").vehicle
    runs = {}
    for backend in ("numpy", "numba"):
        cfg = GPSSMConfig(particles=37, basis=kind, symmetry=symmetry, basis_functions=m, stats=stats,
                          backend=backend, resample_threshold=1.0, force_hold="linear" if snapshots else "zero")
        est = FrictionGPSSM(vehicle, cfg)
        runs[backend] = (_drive(est, 25, snapshots), est)
    (a, fast), (b, ref) = runs["numba"], runs["numpy"]
    assert ref.resamples >= 12 and fast.resamples == ref.resamples
    rtol = TENSOR_100_RTOL if (kind, symmetry) == ("tensor", "none") else RTOL
    assert_equal_to_rounding(a, b, "estimates", rtol)
    pa, pb = fast.posterior(), ref.posterior()
    assert_equal_to_rounding(pa.particles, pb.particles, "particles", rtol)
    assert_equal_to_rounding(pa.log_weights, pb.log_weights, "log-weights", rtol)
    for key in ("M", "Lam", "nu", "mu"):
        assert_equal_to_rounding(pa.stats[key], pb.stats[key], key, rtol)
    fa, fb = fast.friction(), ref.friction()
    assert_equal_to_rounding(fa.mu_f, fb.mu_f, "mu_f", rtol)
    assert_equal_to_rounding(fa.mu_r_std, fb.mu_r_std, "mu_r_std", rtol)


@pytest.mark.parametrize("measurement_friction,force_hold", [("learned", "linear"), ("prior", "zero")])
def test_friction_gpssm_backends_equal_state_noise_and_prior_measurement(measurement_friction, force_hold):
    """The compiled step's other branches: state noise (drawn between propagation and the
    slip angles), the paper's prior-only measurement (zeta drawn from the predictive), the
    paper's held forces and missing samples."""
    vehicle = load_scenario("friction-snow").vehicle
    runs = {}
    for backend in ("numpy", "numba"):
        cfg = GPSSMConfig(particles=37, backend=backend, resample_threshold=1.0, state_noise=(0.02, 0.002),
                          measurement_friction=measurement_friction, force_hold=force_hold)
        est = FrictionGPSSM(vehicle, cfg)
        runs[backend] = (_drive(est, 20, 6, missing=True), est)
    (a, fast), (b, ref) = runs["numba"], runs["numpy"]
    assert ref.resamples >= 10 and fast.resamples == ref.resamples
    assert_equal_to_rounding(a, b, "estimates")
    assert_equal_to_rounding(fast.posterior().particles, ref.posterior().particles, "particles")
    assert_equal_to_rounding(fast.posterior().stats["M"], ref.posterior().stats["M"], "M")


@pytest.mark.parametrize("order", ["sorted", "shuffled"])
def test_resampling_copies_equal_indexing(order):
    """The in-place resampling copies (`gather_rows`, `gather_lower`) equal a[idx], for sorted
    ancestors (systematic resampling: no copy of the arrays) and any other order."""
    from tirefilter.estimators.gpssm.kernels_resample import gather_lower, gather_rows

    rng, more = np.random.default_rng(3), np.random.default_rng(13)
    for _ in range(20):
        idx = np.sort(rng.integers(0, 23, 23))
        if order == "shuffled":
            idx = rng.permutation(idx)
        a, b = rng.standard_normal((23, 5)), rng.standard_normal((23, 2))
        K = rng.standard_normal((23, 2, 4, 4))
        # five (N, k) arrays, as the exact statistics' step passes them (Psi, Phi, nu, x, work): the
        # signature the step compiled and cached; another count of arrays is another signature
        rows = (a, b) + tuple(more.standard_normal((23, k)) for k in (1, 2, 7))
        want = [r[idx] for r in rows]
        want_K = K[idx]
        gather_rows(rows, idx)
        gather_lower(K, idx)
        assert all(np.array_equal(r, w) for r, w in zip(rows, want))
        low = np.tril(np.ones((4, 4), bool))
        assert np.array_equal(K[..., low], want_K[..., low])


@pytest.mark.parametrize("order", ["sorted", "shuffled"])
@pytest.mark.parametrize("n", [3, 23])
def test_lanes_copies_equal_indexing(order, n):
    """K in lanes (`lanes_load`, `gather_lanes`, `lanes_store`; 2 batch elements per particle,
    8 lanes: the last block partly padding, whose lanes stay the identity): the lower triangles
    after the copies equal K[idx]'s, in place for sorted ancestors and through a copy otherwise."""
    from tirefilter.estimators.gpssm.kernels_resample import gather_lanes
    from tirefilter.estimators.gpssm.kernels_stats import lanes_load, lanes_store

    rng = np.random.default_rng(6)
    low = np.tril(np.ones((4, 4), bool))
    for _ in range(10):
        idx = np.sort(rng.integers(0, n, n))
        if order == "shuffled":
            idx = rng.permutation(idx)
        K = rng.standard_normal((n, 2, 4, 4))
        Kl = np.full((-(-2 * n // 8), 4, 4, 8), np.nan)
        lanes_load(K.reshape(2 * n, 4, 4), Kl)
        gather_lanes(Kl, idx, 2)
        got = np.zeros_like(K)
        lanes_store(Kl, got.reshape(2 * n, 4, 4))
        assert np.array_equal(got[..., low], K[idx][..., low])
        pad = Kl.reshape(-1, 4, 4, 8).transpose(0, 3, 1, 2).reshape(-1, 4, 4)[2 * n:]
        assert np.array_equal(pad[:, low], np.broadcast_to(np.eye(4)[low], (len(pad), low.sum())))


@pytest.mark.parametrize("per", [1, 2])
def test_rows_pass_makes_the_resampling_copy_of_K(per):
    """The rows pass (`exact_forget_predictive_rows`, from `LANES_BELOW` functions) with a
    deferred resampling copy (`gather`: each element's sweep starts from its ancestor's K)
    equals `gather_lower` followed by the pass without it, bit for bit: K's lower triangles,
    Psi, Phi, nu and the predictive, with and without a pending update and the forgetting;
    sorted ancestors (systematic resampling's) in `copy_order`, no K read after it was written.
    `resample` defers the copy for sorted ancestors only and otherwise makes it itself."""
    from tirefilter.estimators.gpssm.kernels_particles import PHI
    from tirefilter.estimators.gpssm.kernels_resample import gather_lower
    from tirefilter.estimators.gpssm.kernels_stats import copy_order, exact_forget_predictive_rows

    rng = np.random.default_rng(8)
    N, d, m = 23, 2 if per == 1 else 1, 6
    nb = N * per
    low = np.tril(np.ones((m, m), bool))
    for trial in range(12):
        idx = np.sort(rng.integers(0, N, N))
        assert np.array_equal(np.sort(copy_order(idx)), np.arange(N))
        X = rng.standard_normal((nb, m, 3 * m))
        K = X @ X.transpose(0, 2, 1) / m + np.eye(m)
        Psi, Phi = rng.standard_normal((nb, d, m)), np.eye(d) + 0.1 * rng.standard_normal((nb, d, d))
        nu = 5.0 + rng.random(nb)
        V, Lam0 = 1.0 + rng.random(m), np.eye(d)
        work = rng.standard_normal((N, PHI + m * per))
        zeta, phi_p = rng.standard_normal((N, 2)), rng.standard_normal((N, m * per))
        pending, forget = trial % 3 != 0, trial % 2 == 0
        a = [K.copy(), Psi.copy(), Phi.copy(), nu.copy(), work.copy()]
        b = [K.copy(), Psi.copy(), Phi.copy(), nu.copy(), work.copy()]
        exact_forget_predictive_rows(a[0], (a[1], a[2], a[3]), (V, Lam0), a[4], per, (forget, 0.99, 10.0),
                                     (pending, zeta, phi_p), idx, True)
        gather_lower(b[0].reshape(N, per, m, m), idx)
        exact_forget_predictive_rows(b[0], (b[1], b[2], b[3]), (V, Lam0), b[4], per, (forget, 0.99, 10.0),
                                     (pending, zeta, phi_p), np.arange(N), False)
        assert np.array_equal(a[0][:, low], b[0][:, low]), trial
        for x, y in zip(a[1:], b[1:]):
            assert np.array_equal(x, y), trial
    # resample: sorted ancestors leave K alone (deferred); with defer off it copies K itself
    from tirefilter.estimators.gpssm.kernels_resample import resample

    logw = np.log(np.full(N, 1.0 / N))
    logw[:3] += 3.0
    logw -= np.log(np.exp(logw).sum())
    for defer in (True, False):
        K = rng.standard_normal((N, per, m, m))
        K0, anc, rows = K.copy(), np.zeros(N, np.int64), (rng.standard_normal((N, 3)),)
        rows += tuple(np.zeros((N, k)) for k in (1, 2, 3, 4))  # five, as the exact statistics' step
        resample(logw.copy(), 0.3, rows, K, per, False, 0.0, np.zeros((N, PHI + 1)), anc, defer)
        if defer:
            assert np.array_equal(K, K0) and np.any(anc != np.arange(N)) and np.all(np.diff(anc) >= 0)
        else:
            assert np.array_equal(anc, np.arange(N)) and not np.array_equal(K[..., low], K0[..., low])


def test_friction_gpssm_tensor_resampling_copy_waits_for_the_next_pass():
    """The tensor basis's resampling leaves its copy of K to the next pass (`gather`); a
    reader of the statistics in between (`flush`) and a pickle taken then both see the copied
    K: the friction curve read at that point and the resumed run equal the numpy reference's."""
    import pickle

    vehicle = load_scenario("friction-snow").vehicle
    kw = dict(particles=19, basis="tensor", symmetry="odd", resample_threshold=1.0)
    fast, ref = FrictionGPSSM(vehicle, GPSSMConfig(**kw)), FrictionGPSSM(vehicle, GPSSMConfig(backend="numpy", **kw))
    a, b = _drive(fast, 12), _drive(ref, 12)
    assert fast._compiled.gather and fast.resamples == ref.resamples >= 5
    copy, ref_copy = pickle.loads(pickle.dumps(fast)), pickle.loads(pickle.dumps(ref))
    assert copy._compiled.gather
    assert_equal_to_rounding(fast.friction().mu_f, ref.friction().mu_f, "mu_f")  # flushed: the copy made
    assert not fast._compiled.gather
    assert_equal_to_rounding(fast.stats.K, ref.stats.K, "K")
    c, d = _drive_on(copy, 12, 20), _drive_on(ref_copy, 12, 20)
    assert_equal_to_rounding(np.vstack([a, c]), np.vstack([b, d]), "estimates")
    assert_equal_to_rounding(copy.stats.K, ref_copy.stats.K, "K after the resumed run")


def test_friction_gpssm_statistics_replaced_while_the_copy_waits():
    """Statistics set from outside (`est.stats = other`) between steps, while the compiled step
    still holds work for the old ones (the resampling's copy of K, the pending update): that
    work lands in the statistics replaced, never in the new ones, and the old ones equal the
    numpy reference's."""
    import copy

    vehicle = load_scenario("friction-snow").vehicle
    kw = dict(particles=11, basis="tensor", symmetry="odd", resample_threshold=1.0)
    fast, ref, other = (FrictionGPSSM(vehicle, GPSSMConfig(**kw)), FrictionGPSSM(vehicle, GPSSMConfig(backend="numpy", **kw)),
                        FrictionGPSSM(vehicle, GPSSMConfig(**kw)))
    _drive(fast, 9), _drive(ref, 9), _drive(other, 7)
    assert fast._compiled.gather and fast._compiled.pending
    old, new = fast._stats, copy.deepcopy(other.stats)
    K_new = new.K.copy()
    fast.stats = new
    assert fast.stats is new
    np.testing.assert_array_equal(new.K, K_new)
    assert_equal_to_rounding(old.K, ref.stats.K, "K of the statistics replaced")


def test_systematic_ancestors_equal_reference():
    """The compiled systematic resampling equals `stats.systematic_resample` from the same
    generator state, for peaked, flat and degenerate weights."""
    from tirefilter.estimators.gpssm.kernels_resample import systematic_ancestors
    from tirefilter.stats import normalize_log_weights, systematic_resample

    rng = np.random.default_rng(4)
    for scale in (0.0, 1.0, 30.0, 1e4):
        for n in (1, 7, 200):
            logw = normalize_log_weights(scale * rng.standard_normal(n))
            r1, r2 = np.random.default_rng(n), np.random.default_rng(n)
            want = systematic_resample(logw, r1)
            got = systematic_ancestors(logw, float(r2.random((1,))[0]))
            assert np.array_equal(got, want), (scale, n)


def test_backend_is_checked():
    from tirefilter.errors import ConfigError

    with pytest.raises(ConfigError, match="backend"):
        GPSSMConfig(backend="fortran").validated()
    with pytest.raises(ConfigError, match="backend"):
        MPFConfig(backend="fortran").validated()


@pytest.mark.parametrize("undriven", ["excited", "nominal"])
@pytest.mark.parametrize("drive", ["front", "rear"])
def test_slip_over_step_kernel_equal(drive, undriven):
    """`single_track_numba.slip_over_step` against `single_track.slip_over_step` on a spread of
    particles (traction and braking slips, a driven stiffness deviation below the floor),
    and the reference's interval slip between the slips at the two ends of the step; the
    undriven axle at its nominal stiffness or following the driven axle's deviation in full
    ("learned" with Cx fully excited, rho = 1)."""
    import dataclasses

    vehicle = dataclasses.replace(load_scenario("paper-sim").vehicle, drive=drive)
    mode = "nominal" if undriven == "nominal" else "learned"
    ests = {b: StiffnessMPF(vehicle, MPFConfig(backend=b, undriven_stiffness=mode)) for b in ("numpy", "numba")}
    if undriven == "excited":
        for est in ests.values():
            est.cx_weight = 1.0
            est._set_undriven_share()
    rng = np.random.default_rng(3)
    n, Rw = 40, vehicle.wheel_radius
    x = np.column_stack([20 + rng.normal(0, 0.5, n), rng.normal(0, 0.3, n), rng.normal(0, 0.1, n)])
    w = rng.normal(0, 3e4, (n, 3))
    w[:5, 0] = -2.5e5  # below the floor of the time constant's stiffness
    u0 = np.array([0.02, 20.3 / Rw, 19.9 / Rw, 20.0])
    u1 = np.array([0.021, 20.25 / Rw, 19.95 / Rw, 20.0])
    # C order, as the compiled step passes them (the reference's a is a transpose: Fortran order, a second signature)
    first = tuple(np.ascontiguousarray(f) for f in ests["numpy"]._model(x, u0))
    ref = ests["numpy"]._slip_over_step(x, u0, u1, w, first, 0.01)
    fast = ests["numba"]._slip_over_step(x, u0, u1, w, first, 0.01)
    for a, b, name in zip(fast, ref, ("a", "B", "af", "ar", "slip")):
        assert_equal_to_rounding(a, b, name)
    # the reference against the time mean of the settling, integrated numerically (particle 7)
    i, dt, est = 7, 0.01, ests["numpy"]
    a0, B0 = first[0][i], first[1][i]
    vx1 = x[i, 0] + dt * (x[i, 1] * x[i, 2] + a0[0] + B0[0] @ w[i])
    s = est.undriven_share
    own = (1.0, s) if drive == "front" else (s, 1.0)  # the share of w_x in the front and rear stiffness
    C = np.array([est.C_nom_fx + own[0] * w[i, 0], est.C_nom_rx + own[1] * w[i, 0]])
    for k in range(2):
        slip1 = (Rw * u1[1 + k] - vx1) / max(abs(vx1), abs(Rw * u1[1 + k]))
        J = (vehicle.wheel_inertia_f, vehicle.wheel_inertia_r)[k]
        tau = J * max(x[i, 0], Rw * u0[1 + k]) / (Rw**2 * C[k])
        tt = np.linspace(0.0, dt, 200001)
        path = slip1 + (first[4][k, i] - slip1) * np.exp(-tt / tau)
        mean = np.sum(0.5 * (path[1:] + path[:-1])) * (tt[1] - tt[0]) / dt
        assert ref[4][k, i] == pytest.approx(mean, rel=1e-8, abs=1e-12)
        assert 1e-4 < tau < dt  # the settling is fast: the interval mean lies near the end slip


@pytest.mark.parametrize("drive", ["front", "rear"])
@pytest.mark.parametrize("relax", [0.0, 0.4], ids=["", "relaxation"])
@pytest.mark.parametrize("model", ["full", "lateral"])
def test_c_model_kernels_equal_numba(model, relax, drive):
    """The C core's model for all particles (`native.accelerations`, `propagate`, `slip_over_step`: the
    filter's reference path with backend "c", the first sample, restarts) equals the numba twin's bit for
    bit: front and rear drive, load-transfer gains per particle, relaxed slip angles, Heun and Euler with
    sub-steps."""
    import dataclasses

    from tirefilter.estimators.mpf import native
    from tirefilter.vehicle import single_track_numba as stn

    vehicle = dataclasses.replace(load_scenario("paper-sim").vehicle, relaxation_length=relax, drive=drive)
    est = StiffnessMPF(vehicle, MPFConfig(model=model, backend="c"))
    full, n_w, vp = est.full, est.n_w, est._vp.copy()
    vp[9] = 0.4  # the undriven axle's share of the driven axle's deviation
    rng = np.random.default_rng(4)
    n, Rw = 33, vehicle.wheel_radius
    x = np.column_stack([20 + rng.normal(0, 0.5, n), rng.normal(0, 0.3, n), rng.normal(0, 0.1, n)])[:, 0 if full else 1:]
    w = rng.normal(0, 3e4, (n, n_w))
    u0 = np.array([0.02, 20.3 / Rw, 19.9 / Rw, 20.0])
    u1 = np.array([0.021, 20.25 / Rw, 19.95 / Rw, 20.0])
    lg = 1.0 + rng.normal(0, 0.05, n)
    rel = rng.normal(0, 0.01, (2, n)) if relax else np.zeros((2, 0))
    first = [native.accelerations(x, u0, vp, full, est.rear_drive, n_w, lg, rel, 0.01),
             stn.accelerations(x, u0, vp, full, est.rear_drive, n_w, lg, rel, 0.01)]
    for c, b in zip(*first):
        assert np.array_equal(c, b)
    a, B, _, _, slip = first[1]
    for heun, max_step in ((True, 0.02), (True, 0.004), (False, 0.004)):
        args = (x, u0, w, (a, B, slip), 0.01, max_step, heun, vp, full, est.rear_drive, n_w, (lg, rel))
        assert np.array_equal(native.propagate(*args), stn.propagate(*args))
    if full:
        args = (x, u0, u1, w, (a, B, slip), 0.01, vp, est._jw, est._c_floor, est.rear_drive, n_w, (lg, rel))
        for c, b in zip(native.slip_over_step(*args), stn.slip_over_step(*args)):
            assert np.array_equal(c, b)


def test_c_core_refuses_what_it_cannot_read():
    """The C core names the array it cannot take (not C-contiguous, not float64, not an array) and computes
    nothing; without a C compiler the backend's error names the compiler it looked for."""
    from tirefilter.estimators.mpf import native

    k, z, gain = np.zeros(4), np.ones(4), np.zeros(4)
    native.walk_roll(k, z, 0.1, -1.0, 1.0, 9.81, gain)
    assert np.allclose(gain, 1.0 + 0.1 * 9.81)
    for bad_z in (np.ones(8)[::2], np.ones(4, np.float32), [1.0, 1.0, 1.0, 1.0]):
        with pytest.raises(TypeError, match="walk_roll.* z "):
            native.walk_roll(k, bad_z, 0.1, -1.0, 1.0, 9.81, gain)
    frozen = np.zeros(4)
    frozen.flags.writeable = False
    with pytest.raises(TypeError, match="gain"):
        native.walk_roll(k, z, 0.1, -1.0, 1.0, 9.81, frozen)


def test_c_backend_without_a_compiler_names_it(monkeypatch):
    from tirefilter.estimators.mpf import native

    monkeypatch.setenv("CC", "no-such-cc")
    monkeypatch.setenv("PATH", "/nonexistent")
    with pytest.raises(native.NativeBuildError, match="C compiler.*gcc"):
        native.compiler()


def test_c_backend_with_an_unwritable_cache_names_it(monkeypatch, tmp_path):
    from tirefilter.estimators.mpf import native

    blocked = tmp_path / "not-a-folder"
    blocked.write_text("")
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocked))
    with pytest.raises(native.NativeBuildError, match="not-a-folder.*XDG_CACHE_HOME"):
        native.build()


# the paper's wheel slip and undriven axle (the other variant: the interval slip and the surface-scaled
# undriven axle); x0_vx_wheel_std the earlier default: with 0.02 this drive
# amplifies the rounding differences of the two backends to 1e-10 of v^Y by step 80 (same path, not a
# different computation: it is 1e-16 with 0.1)
PAPER_SLIP = dict(slip_hold="start", undriven_stiffness="nominal", x0_vx_wheel_std=0.1)


def _mpf_samples(vehicle, steps: int, gap: float = 0.05, slip_wave: float = 0.0):
    """A steering sine at about 20 m/s, 100 Hz, from a linear single track with noise and a
    little wheel slip (no FMU): (t, Inputs, Measurement) per sample; a^Y missing every 7th
    sample, all sensors missing once, and one gap of `gap` s before sample 30 (50 ms:
    sub-stepped). `slip_wave`: the front wheel's slip swings by this much at 3 Hz (Cx excited)."""
    rng, v, t = np.random.default_rng(5), vehicle, 0.0
    for k in range(steps):
        t += gap if k == 30 else 0.01
        delta = 0.02 * math.sin(2 * math.pi * 0.7 * t)
        r = 20.0 * delta / (v.lf + v.lr)
        omega = 20.0 / v.wheel_radius
        slip = 0.01 + slip_wave * math.sin(2 * math.pi * 3.0 * t)
        ay = math.nan if k % 7 == 3 else 20.0 * r + 0.05 * rng.standard_normal()
        ax = 0.2 + 0.8 * v.Cx * (slip - 0.01) / v.mass
        y = Measurement() if k == 40 else Measurement(ax=ax + 0.05 * rng.standard_normal(), ay=ay,
                                                       yaw_rate=r + 0.003 * rng.standard_normal())
        yield t, Inputs(delta=delta, omega_f=omega * (1 + slip), omega_r=omega, vx=20.0), y


def _mpf_outputs(e) -> tuple:
    return e.vx, e.vy, e.yaw_rate, e.Cf_y, e.Cr_y, e.Cf_y_std, e.Cr_y_sigma, e.b_ay, e.b_yaw_rate, e.ess


def _mpf_drive(est: StiffnessMPF, steps: int, gap: float = 0.05, slip_wave: float = 0.0):
    """`est` reset and stepped through `_mpf_samples`: its outputs per sample, with the
    excitation weight of Cx and the undriven axle's share."""
    est.reset(np.random.default_rng(9))
    return np.array([_mpf_outputs(est.step(t, u, y)) + (est.cx_weight, est.undriven_share)
                     for t, u, y in _mpf_samples(est.vehicle, steps, gap, slip_wave)])


@pytest.mark.parametrize("paper", [False, True, "learned"], ids=["", "paper-slip", "learned-undriven"])
@pytest.mark.parametrize("restarts", [False, True], ids=["", "restarts"])
@pytest.mark.parametrize("bias", [False, True], ids=["no-bias", "bias"])
@pytest.mark.parametrize("model", ["full", "lateral"])
def test_stiffness_mpf_backends_equal(model, bias, restarts, paper, monkeypatch):
    """80 steps at N = 24 with resampling at every step (threshold 1) and learning from the
    fifth sample: numba and numpy give the same estimates, particles, bias and statistics.
    `restarts`: a plausible yaw rate so small that the cloud leaves it now and then.
    `paper`: the paper's wheel slip (held from the start of the step) and undriven axle;
    False: the defaults; "learned": the undriven axle scaled by the excitation weight of Cx (the
    default) on a drive whose front slip swings by 0.5% (the weight grows).
    The numba filter runs its fused step (`_step_compiled`) on every sample, the first among them
    (a restart is decided inside it); the numpy filter never does."""
    if paper == "learned" and model == "lateral":
        pytest.skip("the lateral model has no Cx")
    variant = PAPER_SLIP if paper is True else {}
    fused = _count_fused_steps(monkeypatch)
    vehicle = load_scenario("paper-sim").vehicle
    noise = dict(bias_rw=(0.01, 0.01, 0.001), bias0_std=(0.1, 0.1, 0.01)) if bias else dict(
        bias_rw=(0.0, 0.0, 0.0), bias0_std=(0.0, 0.0, 0.0))
    runs = {}
    for backend in ("numpy", "numba", "c"):
        cfg = MPFConfig(particles=24, model=model, backend=backend, resample_threshold=1.0, gate_warmup=0.05,
                        gate_vy_std=10.0, gate_steer=0.0, plausible_yaw_rate=0.02 if restarts else 2.0, **noise,
                        **variant)
        est = StiffnessMPF(vehicle, cfg)
        runs[backend] = (_mpf_drive(est, 80, slip_wave=0.005 if paper == "learned" else 0.0), est)
    (a, fast), (b, ref) = runs["numba"], runs["numpy"]
    _assert_c_is_numba(runs)
    if paper == "learned" and not restarts:  # the weight has grown: the undriven axle's share moved
        assert b[-1, -2] > 0.5 and b[-1, -1] == pytest.approx(b[-1, -2] * ref.full_share)
    assert fused[id(ref)] == 0 and fused[id(fast)] == 80  # (a restart is decided inside the fused step)
    assert ref.resamples >= 30 and fast.resamples == ref.resamples
    assert fast.restarts == ref.restarts and (ref.restarts >= 2 if restarts else ref.restarts == 0)
    assert np.isfinite(b[:, :7]).all()
    _assert_mpf_runs_equal(a, b, fast, ref)


def _assert_mpf_runs_equal(a: np.ndarray, b: np.ndarray, fast: StiffnessMPF, ref: StiffnessMPF) -> None:
    """The numba filter `fast` (outputs a) and the numpy reference `ref` (outputs b) equal to
    rounding: estimates, particles, log-weights and statistics."""
    assert_equal_to_rounding(a, b, "estimates")
    pa, pb = fast.posterior(), ref.posterior()
    assert_equal_to_rounding(pa.particles, pb.particles, "particles")
    assert_equal_to_rounding(pa.log_weights, pb.log_weights, "log-weights")
    for key in ("gamma", "mu", "Lam", "nu", "bias", "bias_cov"):
        assert_equal_to_rounding(pa.stats[key], pb.stats[key], key)


def _assert_c_is_numba(runs: dict) -> None:
    """The C backend's run (runs["c"]: outputs, filter, ...) equals the numba backend's bit for bit: the
    outputs, the particles, the log-weights, the statistics, the counters."""
    (a, fast, *_), (c, native, *_) = runs["numba"], runs["c"]
    assert np.array_equal(c, a, equal_nan=True)
    assert (native.resamples, native.restarts, native.gap_redraws) == (fast.resamples, fast.restarts, fast.gap_redraws)
    pa, pc = fast.posterior(), native.posterior()
    assert np.array_equal(pc.particles, pa.particles) and np.array_equal(pc.log_weights, pa.log_weights)
    for key in ("gamma", "mu", "Lam", "nu", "bias", "bias_cov"):
        assert np.array_equal(pc.stats[key], pa.stats[key], equal_nan=True), key


def _count_fused_steps(monkeypatch) -> dict:
    """Count the calls of `StiffnessMPF._step_compiled` per filter (id -> calls)."""
    from collections import Counter

    calls, fused = Counter(), StiffnessMPF._step_compiled

    def counted(self, *args):
        calls[id(self)] += 1
        return fused(self, *args)

    monkeypatch.setattr(StiffnessMPF, "_step_compiled", counted)
    return calls


def test_stiffness_mpf_gap_step_takes_the_compiled_path(monkeypatch):
    """A 0.6 s gap (longer than gap_after, 0.5 s) before sample 30: the numba filter runs that
    step through the fused step too (sub-steps, v^X drawn again from the wheels); both backends
    stay equal to rounding."""
    fused = _count_fused_steps(monkeypatch)
    vehicle = load_scenario("paper-sim").vehicle
    runs = {}
    for backend in ("numpy", "numba", "c"):
        cfg = MPFConfig(particles=24, backend=backend, resample_threshold=1.0, gate_warmup=0.05, gate_vy_std=10.0,
                        gate_steer=0.0, bias_rw=(0.01, 0.01, 0.001), bias0_std=(0.1, 0.1, 0.01))
        est = StiffnessMPF(vehicle, cfg)
        runs[backend] = (_mpf_drive(est, 60, gap=0.6), est)
    (a, fast), (b, ref) = runs["numba"], runs["numpy"]
    _assert_c_is_numba(runs)
    assert ref.gap_redraws == fast.gap_redraws == 1 and ref.restarts == fast.restarts == 0
    assert fused[id(ref)] == 0 and fused[id(fast)] == 60  # the first sample and the gap among them
    _assert_mpf_runs_equal(a, b, fast, ref)


def test_stiffness_mpf_backends_equal_rear_drive():
    """A rear-driven car (the driven axle's stiffness deviation on the rear wheel slip, the undriven share on
    the front) on a drive whose front slip swings: the three backends equal (C and numba bit for bit)."""
    import dataclasses

    vehicle = dataclasses.replace(load_scenario("paper-sim").vehicle, drive="rear")
    runs = {}
    for backend in ("numpy", "numba", "c"):
        cfg = MPFConfig(particles=24, backend=backend, resample_threshold=1.0, gate_warmup=0.05, gate_vy_std=10.0,
                        gate_steer=0.0, bias_rw=(0.01, 0.01, 0.001), bias0_std=(0.1, 0.1, 0.01))
        est = StiffnessMPF(vehicle, cfg)
        runs[backend] = (_mpf_drive(est, 60, slip_wave=0.005), est)
    (a, fast), (b, ref) = runs["numba"], runs["numpy"]
    _assert_c_is_numba(runs)
    assert fast.rear_drive and fast.resamples == ref.resamples >= 20
    _assert_mpf_runs_equal(a, b, fast, ref)


def test_stiffness_mpf_backends_equal_with_the_wheel_filter(monkeypatch):
    """The wheel-speed pre-filter on (sigma_omega > 0, derivations, "Wheel-speed pre-filter"): it works on the
    inputs before either backend's step, so the fused step and the reference stay equal to
    rounding, through a gap that starts the filter again (0.6 s before sample 30) and the
    sample whose sensors are all missing (no drive for the filter)."""
    fused = _count_fused_steps(monkeypatch)
    vehicle = load_scenario("paper-sim").vehicle
    runs = {}
    for backend in ("numpy", "numba", "c"):
        cfg = MPFConfig(particles=24, backend=backend, resample_threshold=1.0, gate_warmup=0.05, gate_vy_std=10.0,
                        gate_steer=0.0, bias_rw=(0.01, 0.01, 0.001), bias0_std=(0.1, 0.1, 0.01), sigma_omega=0.03)
        est = StiffnessMPF(vehicle, cfg)
        runs[backend] = (_mpf_drive(est, 60, gap=0.6, slip_wave=0.005), est)
    (a, fast), (b, ref) = runs["numba"], runs["numpy"]
    _assert_c_is_numba(runs)
    assert ref.wheels is not None and fast.wheels is not None
    assert fused[id(fast)] == 60 and ref.gap_redraws == fast.gap_redraws == 1
    assert_equal_to_rounding(fast.wheels.s, ref.wheels.s, "filtered wheel speeds")
    _assert_mpf_runs_equal(a, b, fast, ref)


OPTIONS = {"noise-euler": dict(state_noise=(0.02, 0.01, 0.002), integrator="euler"),
           "fixed-forgetting-subgap": dict(forgetting_mode="fixed", max_step=0.004),
           # derivations, "State noise from the data": the statistics drawn again after the gate's first open sample
           "redraw-gate": dict(x0_given=False),
           "noise-from-data": dict(state_noise_from_data=True, state_noise_time=0.1),
           # the calibrated *_std ("Batch-means sandwich") with batches short enough to close within the drive: the fused
           # step's update on floats from the moments against the reference's `_calibrate`
           "calibration-batches": dict(calibration_batch=0.03),
           # the load-transfer gain per particle (derivations, "Load transfer") in the propagation and the weighting
           # (paper-sim's vehicle file states kappa = 0: a file without the key has it estimated)
           "load-sensitivity": dict(vehicle=dict(load_sensitivity=None), load_sensitivity_estimate=True,
                                    load_sensitivity_prior=(0.0, 0.03), load_sensitivity_rw=1e-3),
           # kappa stated by the vehicle file: the same gain for every particle, no walk
           "load-given": dict(vehicle=dict(load_sensitivity=0.02), load_sensitivity_estimate=True),
           # the tyres' relaxation (derivations, "Tyre relaxation"; a key of the vehicle file), sub-stepped and not,
           # with the load-transfer gain
           "relaxation": dict(vehicle=dict(relaxation_length=0.5, load_sensitivity=None),
                              load_sensitivity_estimate=True),
           "relaxation-substeps": dict(vehicle=dict(relaxation_length=0.3), max_step=0.004, integrator="euler")}
# the state noise from the data (derivations, "State noise from the data") subtracts two nearly equal spreads each step, which
# amplifies the backends' rounding differences (6e-12 relative in the statistics after 60 steps)
OPTION_RTOL = {"noise-from-data": 1e-9}


@pytest.mark.parametrize("model", ["full", "lateral"])
@pytest.mark.parametrize("options", list(OPTIONS))
def test_stiffness_mpf_backends_equal_options(options, model, monkeypatch):
    """The options the runs above leave at their defaults, through the fused step's loops:
    the state noise and the Euler propagation; fixed forgetting (no drift statistic) with every
    step sub-stepped (`max_step` 4 ms at 10 ms samples). The backends stay equal to rounding."""
    fused = _count_fused_steps(monkeypatch)
    monkeypatch.setattr(sys.modules[__name__], "RTOL", OPTION_RTOL.get(options, RTOL))
    import dataclasses

    opts = dict(OPTIONS[options])
    vehicle = dataclasses.replace(load_scenario("paper-sim").vehicle, **opts.pop("vehicle", {}))
    runs = {}
    for backend in ("numpy", "numba", "c"):
        cfg = MPFConfig(particles=24, model=model, backend=backend, resample_threshold=1.0, gate_warmup=0.05,
                        gate_vy_std=10.0, gate_steer=0.0, bias_rw=(0.01, 0.01, 0.001), bias0_std=(0.1, 0.1, 0.01),
                        **opts)
        est = StiffnessMPF(vehicle, cfg)
        runs[backend] = (_mpf_drive(est, 60), est)
    (a, fast), (b, ref) = runs["numba"], runs["numpy"]
    _assert_c_is_numba(runs)
    assert fused[id(fast)] == 60 and fast.resamples == ref.resamples >= 20
    assert np.isfinite(b[:, :7]).all()
    if options == "calibration-batches":
        assert ref._calib.batches >= 10 and ref._calib.factor.max() > 1.0
        assert_equal_to_rounding(fast._calib.factor, ref._calib.factor, "std factor")
    if options.startswith("relaxation"):
        assert ref.relaxed is not None and np.ptp(ref.relaxed) > 0
        assert_equal_to_rounding(fast.relaxed, ref.relaxed, "relaxed slip angles")
    if options == "load-sensitivity":
        assert np.ptp(ref.k_load) > 0 and abs(ref._ay_step) > 0.5
        assert_equal_to_rounding(fast.k_load, ref.k_load, "load sensitivity")
    if options == "load-given":
        assert abs(ref._ay_step) > 0.5
        for est in (fast, ref):
            assert not est.load_estimated and np.all(est.k_load == 0.02)
    _assert_mpf_runs_equal(a, b, fast, ref)


@pytest.mark.parametrize("model", ["full", "lateral"])
def test_stiffness_mpf_fused_estimate_equals_the_reference_estimate(model):
    """The fused step's Estimate (`_estimate_fused`, written out) has every field of the
    reference's `_estimate_from` on the same moments, bit for bit (NaN where not estimated)."""
    import dataclasses

    est = StiffnessMPF(load_scenario("paper-sim").vehicle, MPFConfig(particles=24, model=model, gate_warmup=0.05,
                                                                     gate_vy_std=10.0, gate_steer=0.0))
    out = _mpf_drive(est, 20)
    assert est.active and np.isfinite(out[-1, :7]).all()
    nx, n_w, m = est.x.shape[1], est.n_w, len(est.channels)
    r = est._wk.mom.tolist()
    ref = dataclasses.astuple(est._estimate_from(0.7, r[0][:nx], r[1][:nx], r[2][:n_w], r[3][:n_w], r[4][:n_w],
                                                 r[5][:m]))
    obj = est._estimate_fused(0.7, est._wk.mom)
    fused = dataclasses.astuple(obj)
    # (NaN where not estimated: Cx in the lateral model; the last two, the roll gradient, given in the vehicle file)
    assert len(fused) == len(ref) and any(isinstance(v, float) and math.isnan(v) for v in ref[:-2]) == (
        model == "lateral") and all(math.isnan(v) for v in ref[-2:])
    for a, b in zip(fused, ref):
        assert type(a) is type(b) and (a == b or (a != a and b != b)), (fused, ref)
    # its fields are filled without Estimate's __init__: every field, and nothing __init__ would add
    from tirefilter.estimators.base import Estimate

    assert not hasattr(Estimate, "__post_init__") and not hasattr(Estimate, "__slots__")
    assert type(obj) is Estimate and obj.__dict__.keys() == {f.name for f in dataclasses.fields(Estimate)}
    built = Estimate(**{f.name: getattr(obj, f.name) for f in dataclasses.fields(Estimate)})
    assert repr(built) == repr(obj)  # (every field, in order; NaN where not estimated)


def test_stiffness_mpf_bound_restart_in_the_fused_step_equal(monkeypatch):
    """Narrow projection bounds (0.97-1.03 of nominal) and restart_at_bound_after = 0.05 s:
    the posterior mean sits at a bound, the fused step restarts the filter after resampling
    (`resample_gate`'s bound test, then the reference's `_restart`), and the backends stay
    equal to rounding."""
    fused = _count_fused_steps(monkeypatch)
    vehicle = load_scenario("paper-sim").vehicle
    runs = {}
    for backend in ("numpy", "numba", "c"):
        cfg = MPFConfig(particles=24, backend=backend, resample_threshold=1.0, gate_warmup=0.05, gate_vy_std=10.0,
                        gate_steer=0.0, bound_low=0.97, bound_high=1.03, restart_at_bound_after=0.05)
        est = StiffnessMPF(vehicle, cfg)
        runs[backend] = (_mpf_drive(est, 60), est)
    (a, fast), (b, ref) = runs["numba"], runs["numpy"]
    _assert_c_is_numba(runs)
    assert ref.restarts >= 2 and fast.restarts == ref.restarts and fused[id(fast)] == 60
    _assert_mpf_runs_equal(a, b, fast, ref)


def test_friction_gpssm_compiled_state_pickles():
    """The compiled step's state (a pending update of the exact statistics, K's lower
    triangle) survives pickling mid-run (the estimator FMU's saved state): the resumed run
    equals the uninterrupted one."""
    import pickle

    vehicle = load_scenario("friction-snow").vehicle
    cfg = GPSSMConfig(particles=19, basis="tensor", symmetry="odd", resample_threshold=1.0)
    whole, resumed = FrictionGPSSM(vehicle, cfg), FrictionGPSSM(vehicle, cfg)
    a = _drive(whole, 20)
    b = _drive(resumed, 12)
    assert resumed._compiled.pending  # learning: the last update waits for the next step
    copy = pickle.loads(pickle.dumps(resumed))
    rest = _drive_on(copy, 12, 20)
    assert np.array_equal(np.vstack([b, rest]), a)
    assert np.array_equal(copy.posterior().stats["M"], whole.posterior().stats["M"])


@pytest.mark.parametrize("particles", [3, 37])
def test_friction_gpssm_axle_lanes_state_pickles_and_equals_reference(particles):
    """The per-axle basis keeps K in the compiled step's lanes between flushes (`Kl`): a run
    pickled mid-run (K only in the lanes, an update pending) resumes as the uninterrupted one,
    and a run with friction snapshots (K written back and loaded again) equals the numpy
    reference; N = 3 (6 batch elements: 8 lanes, 2 of them padding) and N = 37 (3 blocks)."""
    import pickle

    vehicle = load_scenario("friction-snow").vehicle
    cfg = GPSSMConfig(particles=particles, basis="axle", resample_threshold=1.0)
    whole, part = FrictionGPSSM(vehicle, cfg), FrictionGPSSM(vehicle, cfg)
    a = _drive(whole, 20)
    b = _drive(part, 12)
    assert part._compiled.pending and part._compiled.kl_loaded  # K lives in the lanes now
    copy = pickle.loads(pickle.dumps(part))
    rest = _drive_on(copy, 12, 20)
    assert np.array_equal(np.vstack([b, rest]), a)
    assert np.array_equal(copy.posterior().stats["M"], whole.posterior().stats["M"])
    # a new particles' array (the same values) while K lives in the lanes: the lanes stay current
    swapped = FrictionGPSSM(vehicle, cfg)
    b = _drive(swapped, 12)
    assert swapped._compiled.kl_loaded
    swapped.x = swapped.x.copy()
    assert np.array_equal(np.vstack([b, _drive_on(swapped, 12, 20)]), a)
    assert np.array_equal(swapped.posterior().stats["M"], whole.posterior().stats["M"])
    ref = FrictionGPSSM(vehicle, GPSSMConfig(particles=particles, basis="axle", resample_threshold=1.0,
                                             backend="numpy"))
    fast = FrictionGPSSM(vehicle, cfg)
    c, d = _drive(fast, 20, 3), _drive(ref, 20, 3)
    assert fast.resamples == ref.resamples >= 10
    assert_equal_to_rounding(c, d, "estimates")
    for key in ("M", "Lam", "nu"):
        assert_equal_to_rounding(fast.posterior().stats[key], ref.posterior().stats[key], key)


def test_friction_gpssm_compiled_estimate_equals_the_reference_estimate():
    """The compiled step's Estimate (`CompiledStep._estimate`: a template's fields with the step's)
    has every field of `FrictionGPSSM._estimate` on the same moments, bit for bit, before and
    after a friction snapshot (which sets the learned slope) and after the prior changed."""
    import dataclasses

    from tirefilter.estimators.base import Estimate

    est = FrictionGPSSM(load_scenario("friction-snow").vehicle, GPSSMConfig(particles=11, basis="axle"))
    _drive(est, 8)
    moments = (0.125, -0.5, 0.25, 0.0625)
    for change in ("none", "snapshot", "prior"):
        if change == "snapshot":
            est.friction()
        elif change == "prior":
            est.prior = dataclasses.replace(est.prior, B=(3.0, 4.0))
        for _ in range(2):  # built anew, then from the template
            fast, ref = est._compiled._estimate(0.7, 15.0, moments), est._estimate(0.7, 15.0, moments)
            assert type(fast) is Estimate and fast == ref
            for a, b in zip(dataclasses.astuple(fast), dataclasses.astuple(ref)):
                assert type(a) is type(b) and (a == b or (a != a and b != b)), (fast, ref)


def test_friction_gpssm_bin_equals_searchsorted():
    """`FrictionGPSSM._bin` (bisection on the grid as a list) is np.searchsorted's bin clipped to the
    grid, for slip angles inside, outside and on the grid points, infinities, -0.0 and NaN."""
    est = FrictionGPSSM(load_scenario("friction-snow").vehicle, GPSSMConfig(particles=3))
    g = est.grid
    vals = np.concatenate([np.random.default_rng(8).uniform(-1.2 * g[-1], 1.2 * g[-1], 2000), g,
                           [np.inf, -np.inf, np.nan, 0.0, -0.0]])
    for a in vals.tolist():
        assert est._bin(a) == min(max(int(np.searchsorted(g, a)), 0), len(g) - 1), a


def test_stiffness_mpf_fused_state_pickles():
    """The fused step's arrays (`_MPFWork`: the particles' arrays, their spares, the model's
    first stage) survive pickling mid-run (the estimator FMU's saved state, Dask): the
    resumed filter continues exactly as the uninterrupted one."""
    import pickle

    vehicle = load_scenario("paper-sim").vehicle
    # (short batches of the calibrated *_std, "Batch-means sandwich": its factor moves within the drive and reads the
    # weighting's residuals, `_ay_residual`)
    cfg = MPFConfig(particles=24, resample_threshold=1.0, gate_warmup=0.05, gate_vy_std=10.0, gate_steer=0.0,
                    calibration_batch=0.03)
    whole = StiffnessMPF(vehicle, cfg)
    a = _mpf_drive(whole, 40)
    assert whole._calib.batches >= 4 and whole._calib.factor.max() > 1.0
    part = StiffnessMPF(vehicle, cfg)
    b = _mpf_drive(part, 25)
    copy = pickle.loads(pickle.dumps(part))
    assert copy.x is copy._wk.x and copy.stats.mu is copy._wk.mu  # still the work arrays, not copies of them
    # the samples 25-39 of `_mpf_drive`, after the first 25 (their noise drawn in the same order)
    rest = [_mpf_outputs(copy.step(t, u, y)) + (copy.cx_weight, copy.undriven_share)
            for k, (t, u, y) in enumerate(_mpf_samples(vehicle, 40)) if k >= 25]
    assert np.array_equal(np.vstack([b, rest]), a)
    assert np.array_equal(copy.posterior().stats["Lam"], whole.posterior().stats["Lam"])


@pytest.mark.parametrize("kind", ["axle", "tensor"])
def test_friction_gpssm_backends_equal_with_differing_dof(kind):
    """The compiled step draws the Student-t variables itself when every particle has the
    same dof (`common_dof`) and through `t_draws` otherwise: with the particles' nu made to
    differ mid-run (the same change in both backends' statistics), both backends still
    draw the same numbers and give the same estimates and statistics."""
    from tirefilter.estimators.gpssm.kernels_particles import DOF, common_dof

    vehicle = load_scenario("friction-snow").vehicle
    runs = {}
    for backend in ("numpy", "numba"):
        cfg = GPSSMConfig(particles=37, basis=kind, backend=backend, resample_threshold=1.0)
        est = FrictionGPSSM(vehicle, cfg)
        _drive(est, 10)
        est.friction()  # the compiled step's pending update applied: both statistics equal now
        est._stats.nu[1::2] += 0.5
        rng = np.random.default_rng(7)
        out, differ = [], 0
        for k in range(10, 20):
            t = 0.04 * k
            delta = 0.03 * math.sin(2 * math.pi * 0.5 * t)
            r = 15.0 * delta / 2.8
            e = est.step(t, Inputs(delta=delta, vx=15.0),
                         Measurement(ay=15.0 * r + 0.05 * rng.standard_normal(),
                                     yaw_rate=r + 0.003 * rng.standard_normal()))
            out.append((e.vy, e.yaw_rate, e.ess, e.Cf_y, e.Cr_y))
            if backend == "numba":
                dof = est._compiled.work[:, DOF]
                differ += math.isnan(common_dof(est._compiled.work, 0.0)) and np.ptp(dof) > 0
        runs[backend] = (np.array(out), est, differ)
    (a, fast, differ), (b, ref, _) = runs["numba"], runs["numpy"]
    assert differ >= 5  # the t_draws branch was taken
    assert_equal_to_rounding(a, b, "estimates")
    pa, pb = fast.posterior(), ref.posterior()
    assert_equal_to_rounding(pa.particles, pb.particles, "particles")
    for key in ("M", "Lam", "nu", "mu"):
        assert_equal_to_rounding(pa.stats[key], pb.stats[key], key)
