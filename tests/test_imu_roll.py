"""The IMU in the estimators' model (`single_track.measurement`, its compiled twin, the MPF's
weighting): the lever arm (imu_x, imu_y) against the rigid body's kinematics differentiated
numerically, d against the full model differentiated in the stiffness, the twin against the
numpy map, the compiled MPF against the reference with the roll gradient estimated, and the
roll gradient recovered from a drive whose IMU reads (1 + k g) a^Y (docs/derivations.md,
"The single-track model and the measurement", "The roll gain from the data")."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from figures import within

from test_kernels import _assert_c_is_numba, _assert_mpf_runs_equal, _mpf_drive, assert_equal_to_rounding

from tirefilter.estimators.base import Inputs, Measurement
from tirefilter.estimators.mpf import MPFConfig, StiffnessMPF
from tirefilter.scenarios import load_scenario
from tirefilter.vehicle import single_track as st
from tirefilter.vehicle import single_track_numba as stn

# distinct values everywhere (tests/test_exact_model.py's), the IMU 0.43 m ahead and 0.12 m right
P = np.array([1530.0, 2420.0, 1.21, 1.47, 98000.0, 121000.0, 153000.0, 141000.0, 0.317, 0.42, 0.43, -0.12])


def _particles(rng, n=6):
    x = np.column_stack([rng.uniform(8.0, 30.0, n), rng.uniform(-1.0, 1.0, n), rng.uniform(-0.5, 0.5, n)])
    u = np.array([0.04, 20.3 / P[st.P_WHEEL_RADIUS], 19.8 / P[st.P_WHEEL_RADIUS], 20.0])
    return x, u


def _pose(t):
    """A planar motion with every derivative nonzero: the CG's position (2,) in the world and the
    heading psi, as functions of t (arrays of t broadcast)."""
    return np.array([12.0 * t + 0.8 * t**2, 3.0 * np.sin(0.7 * t) + 0.2 * t**3]), 0.3 * np.sin(1.3 * t) + 0.25 * t**2


def _rot(psi):
    c, s = np.cos(psi), np.sin(psi)
    return np.array([[c, -s], [s, c]])


def _second_derivative(f, t, h=1e-3):
    """f'' by the 5-point central stencil (error O(h^4))."""
    return (-f(t + 2 * h) + 16 * f(t + h) - 30 * f(t) + 16 * f(t - h) - f(t - 2 * h)) / (12 * h * h)


def test_lever_arm_is_the_rigid_body_acceleration():
    """A point fixed at (imu_x, imu_y) on a body moving in the plane: its acceleration in the
    world (the position differentiated numerically) turned into the body's axes equals
    `measurement`'s h^X, h^Y from the centre of gravity's body-frame acceleration, the yaw rate
    and the yaw acceleration; with a roll gain g only the centre of gravity's a^Y is scaled."""
    ix, iy = P[st.P_IMU_X], P[st.P_IMU_Y]
    n_w = 3
    for t in (0.3, 1.1, 2.5):
        psi = _pose(t)[1]
        a_cg = _rot(psi).T @ _second_derivative(lambda s: _pose(s)[0], t)
        imu = lambda s: _pose(s)[0] + _rot(_pose(s)[1]) @ np.array([ix, iy])  # noqa: E731
        a_imu = _rot(psi).T @ _second_derivative(imu, t)
        h_ = 1e-4
        r = (_pose(t + h_)[1] - _pose(t - h_)[1]) / (2 * h_)
        rd = _second_derivative(lambda s: _pose(s)[1], t)
        a = np.array([[a_cg[0], a_cg[1], rd]])
        x = np.array([[20.0, 0.3, r]])
        for g in (1.0, 1.13):
            h, D = st.measurement(a, np.zeros((1, 3, n_w)), x, g, True, P)
            np.testing.assert_allclose(h[0, 0], a_imu[0], rtol=0, atol=2e-6)
            np.testing.assert_allclose(h[0, 1] - (g - 1.0) * a_cg[1], a_imu[1], rtol=0, atol=2e-6)
            assert h[0, 2] == r and not D.any()
            hl, _ = st.measurement(a, np.zeros((1, 3, 2)), x[:, 1:], g, False, P)
            np.testing.assert_array_equal(hl[0], h[0, 1:])
    # the measurement differs from the centre of gravity's by more than the tolerance
    assert abs(a_imu[1] - a_cg[1]) > 0.1 and abs(a_imu[0] - a_cg[0]) > 0.1


def _stiffness_params(p, w, full, rear_drive):
    """p with the nominal stiffness moved by the deviations w (one particle): the model at
    C_n + w is the model at C_n with a + B w (eq. (2), (7))."""
    q = p.copy()
    if full:
        wx, wf, wr = w
        s = p[st.P_UNDRIVEN_SHARE]
        q[st.P_CX_R if rear_drive else st.P_CX_F] += wx
        q[st.P_CX_F if rear_drive else st.P_CX_R] += s * wx
    else:
        wf, wr = w
    q[st.P_CF_Y] += wf
    q[st.P_CR_Y] += wr
    return q


@pytest.mark.parametrize("full,rear_drive", [(True, False), (True, True), (False, False)])
def test_d_is_the_derivative_of_the_model_measurement_in_w(full, rear_drive):
    """d of `measurement` against the measurement of the whole model (accelerations and
    measurement at C_n + w) differentiated numerically in each deviation, with the lever arm
    (its r' term depends on w through the yaw moment) and a roll gain per particle."""
    rng = np.random.default_rng(3)
    x, u = _particles(rng)
    if not full:
        x = x[:, 1:]
    n_w = 3 if full else 2
    gain = 1.0 + 9.80665 * rng.uniform(0.0, 0.02, len(x))
    a, B, *_ = st.accelerations(x, u, P, full, rear_drive)
    h, D = st.measurement(a, B, x, gain, full, P)
    step = 2000.0
    for i in range(len(x)):
        for j in range(n_w):
            hs = []
            for sign in (1.0, -1.0):
                w = np.zeros(n_w)
                w[j] = sign * step
                q = _stiffness_params(P, w, full, rear_drive)
                aw, Bw, *_ = st.accelerations(x[i:i + 1], u, q, full, rear_drive)
                hs.append(st.measurement(aw, Bw, x[i:i + 1], gain[i:i + 1], full, q)[0][0])
            fd = (hs[0] - hs[1]) / (2 * step)
            np.testing.assert_allclose(D[i, :, j], fd, rtol=1e-7, atol=1e-12 * np.abs(D[i]).max())
        # the lever arm's share of d (through r') is there: without the IMU's offset d differs
        _, D0 = st.measurement(a, B, x, gain, full, None)
        assert np.abs(D0[i] - D[i]).max() > 1e-3 * np.abs(D[i]).max()


@pytest.mark.parametrize("full", [True, False])
def test_compiled_measurement_equals_the_numpy_map(full):
    """`single_track_numba.measurement` (the per-particle helpers of the MPF's weighting) equals
    `single_track.measurement` with the lever arm and per-particle gains, and without them."""
    rng = np.random.default_rng(4)
    x, u = _particles(rng, 9)
    if not full:
        x = x[:, 1:]
    n_w = 3 if full else 2
    a, B, *_ = st.accelerations(x, u, P, full, False)
    gain = 1.0 + rng.uniform(0.0, 0.2, len(x))
    for p in (P, np.r_[P[:10], 0.0, 0.0]):
        h, D = st.measurement(a, B, x, gain, full, p)
        hc, Dc = stn.measurement(a, B, x, gain, p, full, n_w)
        np.testing.assert_array_equal(hc, h)
        np.testing.assert_array_equal(Dc, D)


def test_imu_at_the_centre_of_gravity_adds_no_term():
    """imu_x = imu_y = 0: the map is the one without a lever arm, bit for bit (the scalar gain
    and a per-particle array of it alike)."""
    rng = np.random.default_rng(6)
    x, u = _particles(rng)
    p0 = np.r_[P[:10], 0.0, 0.0]
    a, B, *_ = st.accelerations(x, u, p0, True, False)
    for full, xs in ((True, x), (False, x[:, 1:])):
        Bs = B if full else B[:, :, 1:]
        want = st.measurement(a, Bs, xs, 1.07, full)
        for got in (st.measurement(a, Bs, xs, 1.07, full, p0), st.measurement(a, Bs, xs, np.full(len(x), 1.07), full,
                                                                                p0)):
            for g, w in zip(got, want):
                np.testing.assert_array_equal(g, w)


def _imu_vehicle():
    return dataclasses.replace(load_scenario("paper-sim").vehicle, imu_x=0.4, imu_y=-0.1, roll_gradient=None)


@pytest.mark.parametrize("model", ["full", "lateral"])
def test_mpf_backends_equal_with_the_lever_arm_and_the_estimated_roll_gradient(model, monkeypatch):
    """The vehicle file without roll_gradient and with the IMU off the centre of gravity: the
    compiled step (its weighting through the model twin's helpers, the roll gradient walking
    and resampled with the particles) equals the numpy reference, and so do the roll gradients
    of the particles and their estimate."""
    vehicle = _imu_vehicle()
    runs = {}
    for backend in ("numpy", "numba", "c"):
        cfg = MPFConfig(particles=24, model=model, backend=backend, resample_threshold=1.0, gate_warmup=0.05,
                        gate_vy_std=10.0, gate_steer=0.0, bias_rw=(0.01, 0.01, 0.001), bias0_std=(0.1, 0.1, 0.01))
        est = StiffnessMPF(vehicle, cfg)
        runs[backend] = (_mpf_drive(est, 60), est)
    (a, fast), (b, ref) = runs["numba"], runs["numpy"]
    _assert_c_is_numba(runs)
    assert ref.roll_estimated and ref.resamples >= 20 and fast.resamples == ref.resamples
    _assert_mpf_runs_equal(a, b, fast, ref)
    k_fast, k_ref = fast.posterior().stats["roll_gradient"], ref.posterior().stats["roll_gradient"]
    assert_equal_to_rounding(k_fast, k_ref, "roll gradients")
    assert np.ptp(k_ref) > 0  # the walk keeps them apart
    lo, hi = ref.cfg.roll_gradient_prior
    assert (k_ref >= lo).all() and (k_ref <= hi).all()
    t = ref.t_prev + 0.01
    u, y = Inputs(delta=0.01, omega_f=56.0, omega_r=56.0, vx=20.0), Measurement(ax=0.1, ay=0.5, yaw_rate=0.07)
    e_fast, e_ref = fast.step(t, u, y), ref.step(t, u, y)
    assert lo <= e_ref.roll_gradient <= hi and e_ref.roll_gradient_std >= 0
    assert_equal_to_rounding([e_fast.roll_gradient, e_fast.roll_gradient_std],
                             [e_ref.roll_gradient, e_ref.roll_gradient_std], "estimate")


def test_roll_gradient_given_in_the_vehicle_file_is_not_estimated():
    """A vehicle file with roll_gradient (0 included) keeps its fixed gain: no per-particle
    gradient, NaN in the estimate; `roll_estimate = false` takes 0 for an absent one."""
    v = load_scenario("paper-sim").vehicle
    assert v.roll_gradient == 0.0
    for vehicle, cfg in ((v, MPFConfig(particles=8)), (dataclasses.replace(v, roll_gradient=None),
                                                       MPFConfig(particles=8, roll_estimate=False))):
        est = StiffnessMPF(vehicle, cfg)
        est.reset(np.random.default_rng(0))
        e = est.step(0.0, Inputs(delta=0.0, omega_f=55.0, omega_r=55.0), Measurement(ax=0.0, ay=0.0, yaw_rate=0.0))
        assert est.k_roll is None and math.isnan(e.roll_gradient) and est.roll_gain == 1.0


def _drive_with_roll(k: float, imu=(0.4, 0.1), duration=20.0, seed=2):
    """The truth's single-track model (`single_track.rk4_step`, linear tires, the paper-sim
    vehicle) in a steering sine from 20 m/s, the wheels rolling freely (their speeds set to
    v^X / R_w after each step: no wheel slip, no longitudinal force), sampled at 100 Hz: the IMU
    at `imu` on a body that rolls by k a^Y reads (1 + k g) a^Y plus its lever-arm terms, and
    a^X, the yaw rate, with white noise. Returns the vehicle and the samples (t, Inputs, Measurement)."""
    v = load_scenario("paper-sim").vehicle
    model = st.TruthModel(v)
    rng = np.random.default_rng(seed)
    dt = 0.01
    x = np.zeros(9)
    x[st.VX] = 20.0
    x[st.WF] = x[st.WR] = 20.0 / v.wheel_radius
    out = []
    for k_step in range(int(duration / dt)):
        t = k_step * dt
        delta = 0.025 * math.sin(2 * math.pi * 0.5 * t) * min(1.0, t / 2.0)
        u = {"delta": delta, "drive_torque": 0.0, "brake_torque": 0.0, "surface": 1.0, "bank": 0.0}
        dx, aux = st.derivatives(x, u, model)
        ax, ay, rd, r = aux["ax"], aux["ay"], dx[st.R], x[st.R]
        ax_imu = (ax - imu[1] * rd) - imu[0] * r * r
        ay_imu = (1.0 + k * st.GRAVITY) * ay + imu[0] * rd - imu[1] * r * r
        out.append((t, Inputs(delta=delta, omega_f=x[st.WF], omega_r=x[st.WR]),
                    Measurement(ax=ax_imu + 0.05 * rng.standard_normal(), ay=ay_imu + 0.05 * rng.standard_normal(),
                                yaw_rate=r + 0.0035 * rng.standard_normal())))
        x = st.rk4_step(x, u, model, dt)
        x[st.WF] = x[st.WR] = x[st.VX] / v.wheel_radius
    return v, out


# the bounds: |k - k_true|, and the largest |relative error| of Cf_y, Cr_y at the end (measured in the comments)
RECOVERY = {0.012: (0.0009, 0.018),  # measured: 0.00028, 0.0059
            0.0: (0.0014, 0.0021)}  # measured: 0.00045 (the prior's lower bound is 0), 0.0007


@pytest.mark.parametrize("k_true", list(RECOVERY))
def test_roll_gradient_and_stiffness_recovered_from_a_rolling_imu(k_true):
    """A 20 s drive whose IMU, 0.4 m ahead and 0.1 m left, reads (1 + k g) a^Y (k = 0.012:
    1.118 a^Y; k = 0: a flat body): with the vehicle file giving the IMU's position and no
    roll_gradient the MPF finds k and the lateral stiffness; told k = 0 instead, it takes the
    roll's 12 % for stiffness."""
    v, samples = _drive_with_roll(k_true)
    cfg = MPFConfig(particles=200, bias_rw=(0.0, 0.0, 0.0), bias0_std=(0.0, 0.0, 0.0),
                    disturbance_rw=(0.0, 0.0, 0.0))
    results = {}
    for name, roll in (("estimated", None), ("zero", 0.0))[:2 if k_true else 1]:
        est = StiffnessMPF(dataclasses.replace(v, imu_x=0.4, imu_y=0.1, roll_gradient=roll), cfg)
        est.reset(np.random.default_rng(1))
        for t, u, y in samples:
            e = est.step(t, u, y)
        results[name] = e
    e = results["estimated"]
    k_bound, c_bound = RECOVERY[k_true]
    within("roll gradient abs error, rad per m/s^2", abs(e.roll_gradient - k_true), k_bound)
    err = [e.Cf_y / v.Cf_y - 1.0, e.Cr_y / v.Cr_y - 1.0]
    within("largest abs lateral stiffness error", max(abs(x) for x in err), c_bound)
    if k_true:
        z = results["zero"]
        assert min(z.Cf_y / v.Cf_y, z.Cr_y / v.Cr_y) > 1.1  # measured: 1.24, 1.22


# ---- the baselines' measurement maps with the lever arm ------------------------------------------
@pytest.mark.parametrize("full", [True, False])
def test_ekf_measurement_with_the_lever_arm_is_the_model_map_and_its_jacobian(full):
    """The EKF's h at zero stiffness deviation and bias equals `single_track.measurement` of the
    same state (the IMU 0.43 m ahead and 0.12 m right, a roll gain), and H its derivative
    (finite differences over the whole augmented state)."""
    from tirefilter.estimators.ekf import SingleTrackEKFModel

    vehicle = dataclasses.replace(load_scenario("paper-sim").vehicle, imu_x=0.43, imu_y=-0.12, roll_gradient=0.006)
    mdl = SingleTrackEKFModel(vehicle, full)
    p = st.model_params(vehicle)
    rng = np.random.default_rng(8)
    for _ in range(5):
        x = np.array([rng.uniform(8, 30), rng.normal(0, 0.5), rng.normal(0, 0.3)])[-mdl.nx:]
        vx = x[0] if full else rng.uniform(8, 30)
        u = np.array([rng.normal(0, 0.05), vx * 1.01 / vehicle.wheel_radius, vx * 0.995 / vehicle.wheel_radius, vx])
        z = np.concatenate([x, np.zeros(mdl.n_w + mdl.m)])
        a, B, *_ = st.accelerations(x[None], u, p, full, False)
        want, _ = st.measurement(a, B, x[None], vehicle.imu_roll_gain(), full, p)
        h, H = mdl.measurement(z, u)
        np.testing.assert_allclose(h, want[0], rtol=1e-12, atol=1e-12)
        z = np.concatenate([x, rng.normal(0, 0.2, mdl.n_w), rng.normal(0, 0.1, mdl.m)])
        h, H = mdl.measurement(z, u)
        H_fd = np.zeros_like(H)
        for i in range(mdl.nz):
            step = 1e-6 * max(1.0, abs(z[i]))
            zp, zm = z.copy(), z.copy()
            zp[i] += step
            zm[i] -= step
            H_fd[:, i] = (mdl.measurement(zp, u)[0] - mdl.measurement(zm, u)[0]) / (2 * step)
        np.testing.assert_allclose(H, H_fd, rtol=1e-5, atol=1e-6 * np.max(np.abs(H)))


def test_kf_measurement_with_the_lever_arm_is_the_model_map_at_its_linearisation_point():
    """The linear KF's y = C x + d equals the lateral model's `single_track.measurement` at the
    yaw rate r0 it is linearised at, and its slope in r there is the map's."""
    from tirefilter.estimators.linear_kf import lateral_model

    vehicle = dataclasses.replace(load_scenario("paper-sim").vehicle, imu_x=0.43, imu_y=-0.12, roll_gradient=0.006)
    p = st.model_params(vehicle)
    g = vehicle.imu_roll_gain()
    rng = np.random.default_rng(9)
    for _ in range(5):
        vx, delta = rng.uniform(8, 30), rng.normal(0, 0.05)
        x = np.array([rng.normal(0, 0.5), rng.normal(0, 0.3)])
        u = np.array([delta, 0.0, 0.0, vx])
        _, _, C, d = lateral_model(vx, delta, vehicle.Cf_y, vehicle.Cr_y, vehicle, g, 1.0, r0=x[1])
        a, B, *_ = st.accelerations(x[None], u, p, False, False)
        want, _ = st.measurement(a, B, x[None], g, False, p)
        np.testing.assert_allclose(C @ x + d, want[0], rtol=1e-12, atol=1e-12)
        eps = 1e-6
        xp = x + (0.0, eps)
        ap, Bp, *_ = st.accelerations(xp[None], u, p, False, False)
        slope = (st.measurement(ap, Bp, xp[None], g, False, p)[0][0] - want[0]) / eps
        np.testing.assert_allclose(C[:, 1], slope, rtol=1e-5)
