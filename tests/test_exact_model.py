"""The estimators' single-track model (`vehicle.single_track`: accelerations, state
derivative, propagation, slip over a step, measurement map) against the equations written
again here, one particle and one float at a time, and against brute-force integration where
the model integrates. The co-simulation tests check the truth model; these check the model
the filters carry, on every branch (front and rear drive, the undriven axle's share, the
lateral model, speed floors, sub-steps)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tirefilter.vehicle import single_track as st

# distinct values everywhere, so that a swapped index or a dropped factor changes the result
P = np.array([1530.0, 2420.0, 1.21, 1.47, 98000.0, 121000.0, 153000.0, 141000.0, 0.317, 0.42])
M, I, LF, LR, CFY, CRY, CFX, CRX, RW, SHARE = P


def _particles(rng, n=7):
    x = np.column_stack([rng.uniform(8.0, 30.0, n), rng.uniform(-1.0, 1.0, n), rng.uniform(-0.5, 0.5, n)])
    w = np.column_stack([rng.uniform(-3e4, 3e4, n), rng.uniform(-2e4, 2e4, n), rng.uniform(-2e4, 2e4, n)])
    return x, w


def _inputs(rng, vx=20.0):
    return np.array([rng.uniform(-0.1, 0.1), (vx + rng.uniform(-0.8, 0.8)) / RW, (vx + rng.uniform(-0.8, 0.8)) / RW,
                     vx])


def _forces(vx, vy, r, u, w, full, rear_drive, share, slip=None):
    """Axle forces of eq. (2), (7) with the small-angle slip of eq. (4) (speed floored at 1 m/s)
    and the floored wheel slip of eq. (3), for one particle, written out in floats."""
    delta = float(u[0])
    v = max(vx, 1.0)
    af, ar = delta - (vy + LF * r) / v, (LR * r - vy) / v
    if full:
        wx, wf, wr = w
        if slip is None:
            slip = [(RW * float(u[k]) - vx) / max(abs(vx), abs(RW * float(u[k])), 1.0) for k in (1, 2)]
        lam_f, lam_r = slip
        cfx = CFX + (share * wx if rear_drive else wx)
        crx = CRX + (wx if rear_drive else share * wx)
        Ffx, Frx = cfx * lam_f, crx * lam_r
    else:
        wf, wr = w
        Ffx = Frx = 0.0
    return af, ar, (CFY + wf) * af, (CRY + wr) * ar, Ffx, Frx


def _accelerations(vx, vy, r, u, w, full, rear_drive, share, slip=None):
    """(a^X, a^Y, r') of eq. (1) from `_forces` (a^X = 0 in the lateral model)."""
    _, _, Ffy, Fry, Ffx, Frx = _forces(vx, vy, r, u, w, full, rear_drive, share, slip)
    cd, sd = math.cos(u[0]), math.sin(u[0])
    ax = (Ffx * cd - Ffy * sd + Frx) / M if full else 0.0
    return ax, (Ffy * cd + Ffx * sd + Fry) / M, (LF * (Ffy * cd + Ffx * sd) - LR * Fry) / I


@pytest.mark.parametrize("full", [True, False])
def test_load_gain_scales_the_lateral_axle_forces(full):
    """With the load-transfer gain g per particle (derivations, "Load transfer") a + B w equals the
    accelerations of the lateral forces (C_n + w) alpha g (the longitudinal ones unchanged), still
    linear in w; g = 1 gives the model without it bit for bit."""
    rng = np.random.default_rng(4)
    x, w = _particles(rng)
    u = _inputs(rng)
    if not full:
        x, w = x[:, 1:], w[:, 1:]
    g = rng.uniform(0.5, 1.0, len(x))
    a, B, *_ = st.accelerations(x, u, P, full, False, load_gain=g)
    acc = a + np.einsum("nij,nj->ni", B, w)
    rows = slice(0, 3) if full else slice(1, 3)
    cd, sd = math.cos(u[0]), math.sin(u[0])
    for i in range(len(x)):
        vx, vy, r = (x[i, 0], x[i, 1], x[i, 2]) if full else (u[3], x[i, 0], x[i, 1])
        _, _, Ffy, Fry, Ffx, Frx = _forces(vx, vy, r, u, w[i], full, False, float(P[st.P_UNDRIVEN_SHARE]))
        Ffy, Fry = g[i] * Ffy, g[i] * Fry
        want = ((Ffx * cd - Ffy * sd + Frx) / M if full else 0.0, (Ffy * cd + Ffx * sd + Fry) / M,
                (LF * (Ffy * cd + Ffx * sd) - LR * Fry) / I)
        np.testing.assert_allclose(acc[i, rows], np.array(want)[rows], rtol=1e-12, atol=1e-12)
    plain, ones = st.accelerations(x, u, P, full, False), st.accelerations(x, u, P, full, False,
                                                                          load_gain=np.ones(len(x)))
    for p0, p1 in zip(plain[:4], ones[:4]):
        assert np.array_equal(p0, p1)


@pytest.mark.parametrize("full", [True, False])
def test_relaxed_slip_angles_are_the_first_order_lag(full):
    """With the relaxation length sigma (derivations, "Tyre relaxation") the slip angles the forces follow
    solve sigma d alpha' / dt + v alpha' = v alpha with alpha held over h (RK4 of that equation, brute
    force), v = max(v^X, 1); B's lateral columns and the forces are those of the relaxed angles (a + B w
    against the kinematic model's, scaled per axle); h = 0 keeps the previous angles exactly, and
    sigma = 0 or no previous angles give the kinematic model bit for bit."""
    rng = np.random.default_rng(5)
    x, w = _particles(rng)
    u = _inputs(rng)
    if not full:
        x, w = x[:, 1:], w[:, 1:]
    sigma, h = 0.45, 0.013
    p = np.concatenate([P, [0.0, 0.0, sigma]])
    kin = st.accelerations(x, u, p, full, False)
    prev = rng.uniform(-0.05, 0.05, (2, len(x)))
    a, B, af, ar, _ = st.accelerations(x, u, p, full, False, relax=(prev, h))
    j = 1 if full else 0  # the column of dCf_y
    for i in range(len(x)):
        v = max(x[i, 0] if full else u[3], 1.0)
        y, n = prev[:, i].copy(), 2000
        target = np.array([kin[2][i], kin[3][i]])
        f = lambda z: v / sigma * (target - z)  # noqa: E731
        for _ in range(n):
            k1 = f(y)
            k2 = f(y + 0.5 * h / n * k1)
            k3 = f(y + 0.5 * h / n * k2)
            y = y + h / n / 6 * (k1 + 2 * k2 + 2 * k3 + f(y + h / n * k3))
        np.testing.assert_allclose([af[i], ar[i]], y, rtol=1e-10, atol=1e-14)
        np.testing.assert_allclose(B[i, :, j], kin[1][i, :, j] * (af[i] / kin[2][i]), rtol=1e-10)
        np.testing.assert_allclose(B[i, :, j + 1], kin[1][i, :, j + 1] * (ar[i] / kin[3][i]), rtol=1e-10)
    held = st.accelerations(x, u, p, full, False, relax=(prev, 0.0))
    assert np.array_equal(held[2], prev[0]) and np.array_equal(held[3], prev[1])
    for off in (st.accelerations(x, u, np.concatenate([P, [0.0, 0.0, 0.0]]), full, False, relax=(prev, h)),
                st.accelerations(x, u, p, full, False, relax=None)):
        for k in range(4):
            assert np.array_equal(off[k], kin[k])


@pytest.mark.parametrize("full, rear_drive, share", [(True, False, 0.0), (True, False, 0.35), (True, True, 0.0),
                                                      (True, True, 0.35), (False, False, 0.0)])
def test_accelerations_are_the_equations_and_linear_in_w(full, rear_drive, share):
    """a + B w equals the accelerations of the forces at C_n + w, for every particle; a is
    their value at w = 0 (so B is the exact derivative: the model is linear in w); the slip
    angles and the wheel slip are eq. (3)-(4) as written above."""
    rng = np.random.default_rng(1)
    x, w = _particles(rng)
    x[0, 0] = 0.6  # below the 1 m/s floor of the slip angles and the wheel slip
    u = _inputs(rng)
    p = P.copy()
    p[st.P_UNDRIVEN_SHARE] = share
    if not full:
        x, w = x[:, 1:], w[:, 1:]
    a, B, af, ar, slip = st.accelerations(x, u, p, full, rear_drive)
    assert B.shape == (len(x), 3, 3 if full else 2) and (slip is None) == (not full)
    acc = a + np.einsum("nij,nj->ni", B, w)
    rows = slice(0, 3) if full else slice(1, 3)  # (the lateral model has no a^X: the filters never read it)
    for i in range(len(x)):
        vx, vy, r = (x[i, 0], x[i, 1], x[i, 2]) if full else (u[3], x[i, 0], x[i, 1])
        want = _accelerations(vx, vy, r, u, w[i], full, rear_drive, share)
        np.testing.assert_allclose(acc[i, rows], want[rows], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(a[i], _accelerations(vx, vy, r, u, 0 * w[i], full, rear_drive, share),
                                   rtol=1e-12, atol=1e-12)
        f = _forces(vx, vy, r, u, w[i], full, rear_drive, share)
        assert (af[i], ar[i]) == pytest.approx(f[:2], rel=1e-14)
        if full:
            want_slip = [(RW * u[k] - vx) / max(abs(vx), abs(RW * u[k]), 1.0) for k in (1, 2)]
            np.testing.assert_allclose(slip[:, i], want_slip, rtol=1e-14)
    # a held wheel slip is used as given
    if full:
        held = np.vstack([np.full(len(x), 0.031), np.full(len(x), -0.012)])
        a2, B2, *_ , slip2 = st.accelerations(x, u, p, full, rear_drive, held)
        assert slip2 is held
        acc2 = a2 + np.einsum("nij,nj->ni", B2, w)
        for i in range(len(x)):
            want = _accelerations(x[i, 0], x[i, 1], x[i, 2], u, w[i], full, rear_drive, share, [0.031, -0.012])
            np.testing.assert_allclose(acc2[i], want, rtol=1e-12, atol=1e-12)


def test_slip_helpers_floors_and_branches():
    """Small slip angles with the speed floor (floats and arrays alike); the wheel slip's
    denominator the largest of |v^X|, |R_w omega| and 1; the undriven wheel's speed."""
    for vx in (0.4, 12.0):
        af, ar = st.small_slip_angles(vx, 0.3, 0.2, 0.05, LF, LR)
        v = max(vx, 1.0)
        assert (af, ar) == pytest.approx((0.05 - (0.3 + LF * 0.2) / v, (LR * 0.2 - 0.3) / v), rel=1e-15)
        afa, ara = st.small_slip_angles(np.array([vx]), np.array([0.3]), np.array([0.2]), 0.05, LF, LR)
        assert (afa[0], ara[0]) == (af, ar)
    for vx, rw in ((10.0, 11.0), (11.0, 10.0), (0.2, 0.5), (-3.0, 2.0)):
        want = (rw - vx) / max(abs(vx), abs(rw), 1.0)
        assert st.floored_wheel_slip(vx, rw) == pytest.approx(want, rel=1e-15)
        assert st.floored_wheel_slip(np.array([vx]), rw)[0] == pytest.approx(want, rel=1e-15)
    u = np.array([0.0, 61.0, 63.0, np.nan])
    assert st.vx_from_wheels(u, P, rear_drive=False) == RW * 63.0  # front drive: the rear wheels
    assert st.vx_from_wheels(u, P, rear_drive=True) == RW * 61.0


@pytest.mark.parametrize("full", [True, False])
def test_state_derivative_is_eq_1(full):
    rng = np.random.default_rng(2)
    x, w = _particles(rng, 4)
    u = _inputs(rng)
    if not full:
        x, w = x[:, 1:], w[:, 1:]
    a, B, *_ = st.accelerations(x, u, P, full, False)
    d = st.state_derivative(x, u, a, B, w, full)
    acc = a + np.einsum("nij,nj->ni", B, w)
    for i in range(len(x)):
        if full:
            want = [x[i, 1] * x[i, 2] + acc[i, 0], acc[i, 1] - x[i, 0] * x[i, 2], acc[i, 2]]
        else:
            want = [acc[i, 1] - u[3] * x[i, 1], acc[i, 2]]
        np.testing.assert_allclose(d[i], want, rtol=1e-14, atol=1e-14)


def _f(x, u, w, full, slip):
    """x' of one particle from `_accelerations` (the wheel slip held)."""
    if full:
        vx, vy, r = x
        ax, ay, rd = _accelerations(vx, vy, r, u, w, True, False, SHARE, slip)
        return np.array([vy * r + ax, ay - vx * r, rd])
    vy, r = x
    _, ay, rd = _accelerations(u[3], vy, r, u, w, False, False, SHARE)
    return np.array([ay - u[3] * r, rd])


@pytest.mark.parametrize("full", [True, False])
@pytest.mark.parametrize("heun", [False, True])
def test_propagate_is_euler_or_heun_with_sub_steps(full, heun):
    """`propagate` over dt = 0.25 s with max_step 0.1 s: three equal sub-steps of Euler or Heun
    (the same w, the wheel slip of the step's start held within each sub-step, evaluated again
    at each sub-step's start), as written out here; one step when dt <= max_step."""
    rng = np.random.default_rng(3)
    x, w = _particles(rng, 3)
    u = _inputs(rng)
    if not full:
        x, w = x[:, 1:], w[:, 1:]
    for dt, n_sub in ((0.01, 1), (0.25, 3)):
        first = st.accelerations(x, u, P, full, False)
        got = st.propagate(x, u, w, dt, first, P, full, False, 0.1, heun)
        h = dt / n_sub
        for i in range(len(x)):
            xi = x[i].copy()
            for _ in range(n_sub):
                vx = xi[0] if full else u[3]
                slip = [(RW * u[k] - vx) / max(abs(vx), abs(RW * u[k]), 1.0) for k in (1, 2)]
                k1 = _f(xi, u, w[i], full, slip)
                if heun:
                    xi = xi + 0.5 * h * (k1 + _f(xi + h * k1, u, w[i], full, slip))
                else:
                    xi = xi + h * k1
            np.testing.assert_allclose(got[i], xi, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("rear_drive", [False, True])
def test_slip_over_step_is_the_mean_of_the_settling_wheel(rear_drive):
    """The wheel slip `slip_over_step` holds over the step is the time average over [0, dt] of
    slip(t) = slip_1 + (slip_0 - slip_1) exp(-t / tau), tau = J D / C, integrated here by the
    midpoint rule on 20000 points (error ~1e-9 relative), with v^X at t_k+1 from the first
    stage of eq. (1a) and the axle stiffness nominal plus the particle's w (the undriven axle's
    share of it), floored."""
    rng = np.random.default_rng(4)
    x, w = _particles(rng, 5)
    w[0, 0] = -2.0e5  # below the floor: C = c_floor
    u0, u1 = _inputs(rng), _inputs(rng)
    p = P.copy()
    p[st.P_UNDRIVEN_SHARE] = 0.3
    jw = np.array([1.1, 0.9]) / RW**2
    c_floor = np.array([0.3 * CFX, 0.3 * CRX])
    dt = 0.02
    first = st.accelerations(x, u0, p, True, rear_drive)
    got = st.slip_over_step(x, u0, u1, w, first, dt, p, jw, c_floor, rear_drive)
    tgrid = (np.arange(20000) + 0.5) * (dt / 20000)
    for i in range(len(x)):
        vx, vy, r = x[i]
        ax = _accelerations(vx, vy, r, u0, w[i], True, rear_drive, 0.3)[0]
        vx1 = vx + dt * (vy * r + ax)
        wx = w[i, 0]
        C = [CFX + (0.3 * wx if rear_drive else wx), CRX + (wx if rear_drive else 0.3 * wx)]
        for k, axle in enumerate((1, 2)):
            s0 = (RW * u0[axle] - vx) / max(abs(vx), abs(RW * u0[axle]), 1.0)
            s1 = (RW * u1[axle] - vx1) / max(abs(vx1), abs(RW * u1[axle]), 1.0)
            tau = jw[k] * max(abs(vx), abs(RW * u0[axle]), 1.0) / max(C[k], c_floor[k])
            mean = np.mean(s1 + (s0 - s1) * np.exp(-tgrid / tau))
            assert got[4][k, i] == pytest.approx(mean, rel=1e-8, abs=1e-15)
    # and the rest of the tuple is `accelerations` at x_k with that slip held
    again = st.accelerations(x, u0, p, True, rear_drive, got[4])
    for g, want in zip(got[:4], again[:4]):
        np.testing.assert_array_equal(g, want)


@pytest.mark.parametrize("full", [True, False])
def test_measurement_is_eq_12_with_the_roll_gain(full):
    """h = (a^X, g a^Y, r) (lateral: (g a^Y, r)) and d = d h / d w: B's rows with a^Y times the
    roll gain g and no row for the yaw rate (it does not depend on w)."""
    rng = np.random.default_rng(5)
    x, w = _particles(rng, 4)
    u = _inputs(rng)
    if not full:
        x, w = x[:, 1:], w[:, 1:]
    a, B, *_ = st.accelerations(x, u, P, full, False)
    g = 1.07
    h, D = st.measurement(a, B, x, g, full)
    m, n_w = (3, 3) if full else (2, 2)
    assert h.shape == (len(x), m) and D.shape == (len(x), m, n_w)
    for i in range(len(x)):
        r = x[i, -1]
        want_h = [a[i, 0], g * a[i, 1], r] if full else [g * a[i, 1], r]
        np.testing.assert_allclose(h[i], want_h, rtol=1e-15)
        want_D = np.vstack([B[i, 0], g * B[i, 1], np.zeros(n_w)]) if full else np.vstack([g * B[i, 1], np.zeros(n_w)])
        np.testing.assert_allclose(D[i], want_D, rtol=1e-15)
        # d is the derivative of the noise-free measurement a + B w
        hw, _ = st.measurement(a + np.einsum("nij,nj->ni", B, w), B, x, g, full)
        np.testing.assert_allclose(hw[i], h[i] + D[i] @ w[i], rtol=1e-12, atol=1e-12)
