"""The compiled (numba) kernels against the numpy reference: fed the same numbers and the
same random generator, equal to 1e-12 relative (to each array's largest magnitude, so
entries near zero are compared on the array's scale).

Friction GP-SSM: the basis, the MNIW predictive / update / forgetting (exact and rank-one
statistics) and whole filter runs with resampling, over the per-axle basis, the default
(odd 50-function tensor) and the paper's 100-function tensor. Sizes are small: the test is
about equality, the cost is the benchmarks' business.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tirefilter.estimators.base import Inputs, Measurement
from tirefilter.estimators.friction_gpssm import FrictionGPSSM, GPSSMConfig
from tirefilter.scenarios import load_scenario
from tirefilter.stats.gp import GPBasis1D, make_basis
from tirefilter.stats.mniw import make_mniw
from tirefilter.stats.mniw_numba import basis_features

RTOL = 1e-12

# (basis, symmetry, functions per slip dimension): per-axle, default, the paper's tensor
BASES = [("axle", "odd", 20), ("tensor", "odd", 10), ("tensor", "none", 10)]
BASIS_IDS = ["axle", "tensor-odd-50", "tensor-100"]


def assert_equal_to_rounding(a, b, what=""):
    a, b = np.asarray(a, float), np.asarray(b, float)
    assert a.shape == b.shape, (what, a.shape, b.shape)
    scale = float(np.max(np.abs(b))) if b.size else 0.0
    np.testing.assert_allclose(a, b, rtol=RTOL, atol=RTOL * scale, err_msg=what)


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


def _drive(est: FrictionGPSSM, steps: int):
    """A synthetic slalom at 15 m/s, 25 Hz, a^Y and yaw rate from a linear single track
    with a little noise (no FMU): enough to learn, resample and clip nothing."""
    rng = np.random.default_rng(5)
    est.reset(np.random.default_rng(9))
    out = []
    for k in range(steps):
        t = 0.04 * k
        delta = 0.03 * math.sin(2 * math.pi * 0.5 * t)
        r = 15.0 * delta / 2.8
        e = est.step(t, Inputs(delta=delta, vx=15.0),
                     Measurement(ay=15.0 * r + 0.05 * rng.standard_normal(), yaw_rate=r + 0.003 * rng.standard_normal()))
        out.append((e.vy, e.yaw_rate, e.ess, e.Cf_y, e.Cr_y))
    return np.array(out)


@pytest.mark.parametrize("stats", ["exact", "rank1"])
@pytest.mark.parametrize("kind,symmetry,m", BASES, ids=BASIS_IDS)
def test_friction_gpssm_backends_equal(kind, symmetry, m, stats):
    """A whole filter run (25 steps, N = 16, resampling at every step: threshold 1), numba
    and numpy backends from the same seed: the same estimates, particles and statistics."""
    vehicle = load_scenario("friction-snow").vehicle
    runs = {}
    for backend in ("numpy", "numba"):
        cfg = GPSSMConfig(particles=16, basis=kind, symmetry=symmetry, basis_functions=m, stats=stats,
                          backend=backend, resample_threshold=1.0)
        est = FrictionGPSSM(vehicle, cfg)
        runs[backend] = (_drive(est, 25), est)
    (a, fast), (b, ref) = runs["numba"], runs["numpy"]
    assert ref.resamples >= 12 and fast.resamples == ref.resamples
    assert_equal_to_rounding(a, b, "estimates")
    pa, pb = fast.posterior(), ref.posterior()
    assert_equal_to_rounding(pa.particles, pb.particles, "particles")
    assert_equal_to_rounding(pa.log_weights, pb.log_weights, "log-weights")
    for key in ("M", "Lam", "nu", "mu"):
        assert_equal_to_rounding(pa.stats[key], pb.stats[key], key)
    fa, fb = fast.friction(), ref.friction()
    assert_equal_to_rounding(fa.mu_f, fb.mu_f, "mu_f")
    assert_equal_to_rounding(fa.mu_r_std, fb.mu_r_std, "mu_r_std")


def test_backend_is_checked():
    from tirefilter.errors import ConfigError

    with pytest.raises(ConfigError, match="backend"):
        GPSSMConfig(backend="fortran").validated()
