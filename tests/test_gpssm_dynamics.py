"""The GP-SSM's dynamics between two samples (`gpssm.dynamics`) against a brute-force
integration of the same ODE: the held forces (the paper's discretisation (7)) and the forces
growing linearly over the step (`force_hold = "linear"`)."""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

from tirefilter.estimators.gpssm.dynamics import force_rates, linear_hold_remainder, propagate
from tirefilter.scenarios import load_scenario

VEHICLE = load_scenario("friction-snow").vehicle
FZ = np.array(VEHICLE.static_axle_loads(9.81))


def _rates(mu, delta):
    v = VEHICLE
    return force_rates(mu, np.cos(delta), FZ, v.mass, v.lf, v.lr, v.yaw_inertia)


def _ode_end(x0, rates0, rates1, vx, dt):
    """x = [v^Y, r] after dt of v^Y' = a(s) - v^X r, r' = rho(s), (a, rho) linear from rates0
    to rates1, by an adaptive Runge-Kutta integration (rtol 1e-12)."""
    out = []
    for x, r0, r1 in zip(x0, rates0, rates1):
        def f(s, z, r0=r0, r1=r1):
            a, rho = r0 + (r1 - r0) * s / dt
            return [a - vx * z[1], rho]
        sol = solve_ivp(f, (0.0, dt), x, method="DOP853", rtol=1e-12, atol=1e-14)
        out.append(sol.y[:, -1])
    return np.array(out)


def test_force_rates_are_eq_1_with_the_static_loads():
    """a^Y = (F^z_f mu_f cos delta + F^z_r mu_r) / m, r' = (l_f F^z_f mu_f cos delta - l_r F^z_r
    mu_r) / I_zz, written out."""
    v = VEHICLE
    mu = np.array([[0.2, 0.15], [-0.1, 0.05]])
    got = _rates(mu, 0.05)
    Ff, Fr = FZ[0] * mu[:, 0] * np.cos(0.05), FZ[1] * mu[:, 1]
    np.testing.assert_allclose(got[:, 0], (Ff + Fr) / v.mass, rtol=1e-15)
    np.testing.assert_allclose(got[:, 1], (v.lf * Ff - v.lr * Fr) / v.yaw_inertia, rtol=1e-15)


def test_linear_hold_is_the_held_step_plus_the_remainder():
    """The held forces' Euler sub-steps plus `linear_hold_remainder` equal the integral of the
    ODE with forces linear between the two samples; the held step alone equals the ODE with the
    forces held. Both up to the Euler sub-steps' error in the kinematic term, exactly
    v^X |r'| h dt / 2 in v^Y (r is linear in time under held forces), none in r."""
    rng = np.random.default_rng(0)
    x0 = rng.standard_normal((4, 2)) * [0.3, 0.1]
    mu0, mu1 = rng.uniform(-0.3, 0.3, (4, 2)), rng.uniform(-0.3, 0.3, (4, 2))
    rates0, rates1 = _rates(mu0, 0.04), _rates(mu1, 0.07)
    vx, dt, n = 12.0, 0.04, 4000
    held = propagate(x0, rates0, vx, dt, dt / n)
    euler = vx * np.abs(rates0[:, 1]) * (dt / n) * dt / 2  # (4,) the sub-steps' error in v^Y
    tol = np.stack([1.0001 * euler + 1e-12, np.full(4, 1e-12)], axis=1)
    assert np.all(np.abs(held - _ode_end(x0, rates0, rates0, vx, dt)) <= tol)
    linear = held + linear_hold_remainder(rates0, rates1, vx, dt)
    exact = _ode_end(x0, rates0, rates1, vx, dt)
    assert np.all(np.abs(linear - exact) <= tol)
    # the remainder is not small against that tolerance: it is what the held forces miss
    assert np.min(np.abs(linear - held)) > 1e-4


def test_remainder_is_linear_in_the_change_and_zero_without_one():
    rng = np.random.default_rng(1)
    r0, d = rng.standard_normal((3, 2)), rng.standard_normal((3, 2))
    np.testing.assert_array_equal(linear_hold_remainder(r0, r0, 15.0, 0.04), np.zeros((3, 2)))
    np.testing.assert_allclose(linear_hold_remainder(r0, r0 + 2 * d, 15.0, 0.04),
                               2 * linear_hold_remainder(r0, r0 + d, 15.0, 0.04), rtol=1e-13, atol=1e-16)


def test_held_forces_lag_half_a_step_and_the_linear_hold_does_not():
    """The held forces' lag (derivations F4): with a^Y = A sin(w t) and no
    yaw (r' = 0), the held forces' v^Y after k steps is the left Riemann sum of a^Y, whose error
    against the exact integral is -(T_s / 2) (a^Y(t_k) - a^Y(0)) up to the Euler-Maclaurin term
    (T_s^2 / 12) |a'(t_k) - a'(0)| <= T_s^2 A w / 6 and the next one, T_s^4 A w^3 / 360; the
    linear hold's is those terms alone."""
    A, w, T, vx = 1.0, 2 * np.pi / 4.0, 0.04, 12.0
    t = np.arange(0, 101) * T
    a = A * np.sin(w * t)
    rates = np.stack([a, np.zeros_like(a)], axis=1)
    x_held = np.zeros((1, 2))
    x_linear = np.zeros((1, 2))
    bound = T * T * A * w / 6.0 + T**4 * A * w**3 / 360.0
    for k in range(1, len(t)):
        x_held = propagate(x_held, rates[k - 1:k], vx, T, T)
        x_linear = (propagate(x_linear, rates[k - 1:k], vx, T, T)
                    + linear_hold_remainder(rates[k - 1:k], rates[k:k + 1], vx, T))
        exact = A / w * (1.0 - np.cos(w * t[k]))
        assert abs(x_held[0, 0] - exact + 0.5 * T * (a[k] - a[0])) <= bound + 1e-10
        assert abs(x_linear[0, 0] - exact) <= bound + 1e-10
    assert 0.5 * T * A > 20 * bound  # the lag is what matters, not the bound

