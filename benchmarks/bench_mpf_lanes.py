"""The MPF's `predict_weigh` pass stage by stage, and its propagation across particles (issue 14, stop 25).

    .venv/bin/python benchmarks/bench_mpf_lanes.py [--particles 500] [--repeat 400]

The filter (this checkout's defaults, full model, as `tirefilter run` builds it) steps through
the first 5 s of recorded paper-sim samples (seed 0); the arguments of `predict_weigh_full` at the
middle sample are kept, and each variant below runs on fresh copies of them. Printed:

1. Whether `predict_weigh_full`'s loops run in SIMD lanes: packed (ymm) against scalar (sd)
   multiplications, divisions and square roots in its machine code.
2. The pass split into its stages as stop 24 left it (f46c9b0; the loops copied below, each a
   kernel of its own, run in sequence; checked equal to `predict_weigh_full` bit for bit): the
   interval wheel slip, the propagation with the forgetting and the model at x_k, the weights'
   h, D, L11, L12, S and e, the Cholesky factors of S, the solve with the Student-t density, the
   innovation with the log-sum-exp. Minimum (and median) us over `--repeat` rounds; an empty
   kernel with the same arguments gives the dispatch, subtracted in the "net" column.
3. The propagation stage (the costliest) in three forms, alternating round by round, each
   compared with the first bit for bit:
   - "arrays": stop 24's loop (`_model1` and `_xdot1` write the model's a, B and dx/dt into
     scratch arrays and read them back);
   - "registers": the same arithmetic on scalars (`single_track_numba._model_t`, `_xdot_t`: the model's
     values returned, not stored), on the same (N, 3) / (N, 3, 3) arrays: what the pass now runs;
   - "lanes": the registers' code over one 1D array per component (structure of arrays: x0[i],
     x1[i], ..., B22[i]), compiled with numba's internal `noalias` flag on the arguments (a
     custom pipeline) and `error_model="numpy"` (no ZeroDivisionError exit in the loop): the
     only form of the three that LLVM vectorises (4 particles per AVX2 register); without
     `noalias` its loop needs too many run-time alias checks and stays scalar, and a (k, N)
     array instead of 1D arrays does not help (the rows' distance is the run-time N);
   plus the transposes that "lanes" would need in a pass that keeps today's (N, ...) arrays:
   x, w, Lam into columns, and x, a, B, Lam back.
4. The weights' stage (h, D, L11, L12, S, e) on scalars, a prototype that the pass does not run
   (full model, every channel, bias off), against stop 24's loop, bit for bit and timed.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # noqa: E402

import argparse  # noqa: E402
import copy  # noqa: E402
import math  # noqa: E402
import re  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from numba import njit  # noqa: E402
from numba.core.compiler import CompilerBase, DefaultPassBuilder  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_cost import record  # noqa: E402
from profile_mpf_step import captured  # noqa: E402

from tirefilter.estimators import build_estimator  # noqa: E402
from tirefilter.estimators.mpf import kernels as M  # noqa: E402
from tirefilter.estimators.mpf.kernels_weigh import _normalise_into, _t_const  # noqa: E402
from tirefilter.vehicle.single_track_numba import (  # noqa: E402
    _interval_slip1,
    _model1,
    _model_t,
    _steer_consts,
    _xdot1,
    _xdot_t,
)

_J = dict(nogil=True)
NAMES = ("x u_prev w_prev a B af ar slip dt max_step heun interval jw c_floor noise noise_scale b P q bias_on forget "
         "lam nu_min gamma mu Lam nu uk y avail R roll_gain vp full rear_drive h D L11 nu_w L12 Lc e v ll ok logw nc "
         "want_nis beta yaw_max gate_speed sizes").split()  # (sizes: kernels.SIZES_FULL)
# `predict_weigh`'s workspace tuples (kernels_weigh.py), by the names above
LAYOUT = ("x b P gamma mu Lam nu a B slip", "af ar h D L11 nu_w L12 Lc e v ll ok",
          "u_prev uk y avail w_prev logw noise noise_scale", "vp jw c_floor R q",
          "dt max_step lam nu_min roll_gain beta yaw_max gate_speed",
          "heun interval bias_on forget full rear_drive want_nis",
          "nc", "sizes")


def unpack(args) -> dict:
    """`predict_weigh`'s arguments by name."""
    out = {}
    for names, arg in zip(LAYOUT, args):
        names = names.split()
        out.update(zip(names, arg) if len(names) > 1 else [(names[0], arg)])
    return out


def pack(d: dict) -> list:
    """`predict_weigh`'s arguments from their names."""
    return [tuple(d[k] for k in names.split()) if " " in names else d[names] for names in LAYOUT]


# ---- stop 24's predict_weigh_full (f46c9b0), stage by stage ----------------------------------------------------
@njit(**_J)
def st_slip(x, a, B, w_prev, slip, u_prev, uk, dt, vp, jw, c_floor, rear_drive):
    for i in range(x.shape[0]):
        acc0 = 0.0
        for j in range(3):
            acc0 += B[i, 0, j] * w_prev[i, j]
        acc0 = a[i, 0] + acc0
        slip[0, i], slip[1, i] = _interval_slip1((x[i, 0], x[i, 1], x[i, 2]), acc0, w_prev[i, 0],
                                                 (slip[0, i], slip[1, i]), u_prev, uk, dt, vp, jw, c_floor, rear_drive)


@njit(**_J)
def st_prop(x, a, B, af, ar, slip, w_prev, u_prev, uk, dt, vp, rear_drive, gamma, nu, Lam, lam, nu_min, ok, beta,
            gate_speed, yaw_max):
    """"arrays": stop 24's propagation (interval slip, Heun, one sub-step, full model, no state noise)."""
    n, nx = x.shape
    kp = _steer_consts(u_prev[0], vp)
    kk = _steer_consts(uk[0], vp)
    hs = dt
    xi = np.empty(nx)
    x1 = np.empty(nx)
    k1 = np.empty(nx)
    k2 = np.empty(nx)
    ai = np.empty(3)
    Bi = np.empty((3, 3))
    count = 0
    for i in range(n):
        for c in range(nx):
            xi[c] = x[i, c]
        sf, sr = slip[0, i], slip[1, i]
        _model1((xi[0], xi[1], xi[2]), (u_prev[0], u_prev[1], u_prev[2], u_prev[3]), kp, True, sf, sr, ai, Bi, vp,
                True, rear_drive, 3)
        _xdot1(xi, u_prev[3], ai, Bi, w_prev[i], k1, True, 3)
        for c in range(nx):
            x1[c] = xi[c] + hs * k1[c]
        _model1((x1[0], x1[1], x1[2]), (u_prev[0], u_prev[1], u_prev[2], u_prev[3]), kp, True, sf, sr, ai, Bi, vp,
                True, rear_drive, 3)
        _xdot1(x1, u_prev[3], ai, Bi, w_prev[i], k2, True, 3)
        for c in range(nx):
            xi[c] = xi[c] + (0.5 * hs) * (k1[c] + k2[c])
        for c in range(nx):
            x[i, c] = xi[c]
        f = max(lam, min(1.0, nu_min / nu[i])) if nu_min > 0 else lam
        gamma[i] = gamma[i] / f
        nu[i] = nu[i] * f
        for j in range(3):
            for k in range(3):
                Lam[i, j, k] = Lam[i, j, k] * f
        af[i], ar[i], slip[0, i], slip[1, i] = _model1((x[i, 0], x[i, 1], x[i, 2]), (uk[0], uk[1], uk[2], uk[3]), kk,
                                                       False, 0.0, 0.0, a[i], B[i], vp, True, rear_drive, 3)
        ok[i] = abs(x[i, nx - 2]) <= beta * max(abs(x[i, 0]), gate_speed) and abs(x[i, nx - 1]) <= yaw_max
        count += ok[i]
    return count


@njit(**_J)
def st_build(x, a, B, roll_gain, h, D, nu, nu_w, gamma, Lam, L11, avail, L12, R, Lc, mu, y, b, e):
    n, nx = x.shape
    DL = np.empty((3, 3))
    for i in range(n):
        h[i, 0] = a[i, 0]
        h[i, 1] = roll_gain * a[i, 1]
        h[i, 2] = x[i, nx - 1]
        for j in range(3):
            D[i, 0, j] = B[i, 0, j]
            D[i, 1, j] = B[i, 1, j] * roll_gain
            D[i, 2, j] = 0.0
        dof = nu[i] - 3 + 1.0
        nu_w[i] = dof
        f = (1.0 + gamma[i]) / dof
        for j in range(3):
            for k in range(3):
                L11[i, j, k] = f * Lam[i, j, k]
        for q in range(3):
            ch = avail[q]
            for k in range(3):
                s = 0.0
                for j in range(3):
                    s += D[i, ch, j] * L11[i, j, k]
                DL[q, k] = s
                L12[i, k, q] = s
        cf = (dof - 2.0) / dof
        for q in range(3):
            for q2 in range(q + 1):
                s = 0.0
                for k in range(3):
                    s += DL[q, k] * D[i, avail[q2], k]
                Lc[i, q, q2] = s + cf * R[avail[q], avail[q2]]
        for q in range(3):
            ch = avail[q]
            s = 0.0
            for j in range(3):
                s += D[i, ch, j] * mu[i, j]
            e[i, q] = y[ch] - (h[i, ch] + b[i, ch]) - s


@njit(**_J)
def st_chol(Lc):
    for i in range(Lc.shape[0]):
        for j in range(3):
            Sjj = Lc[i, j, j]
            d = Sjj
            for k in range(j):
                d = d - Lc[i, j, k] * Lc[i, j, k]
            Ljj = math.sqrt(max(d, abs(Sjj) * 1e-14 + 1e-300))
            Lc[i, j, j] = Ljj
            inv = 1.0 / Ljj
            for r in range(j + 1, 3):
                acc = Lc[i, r, j]
                for k in range(j):
                    acc = acc - Lc[i, r, k] * Lc[i, j, k]
                Lc[i, r, j] = acc * inv
            for r in range(j):
                Lc[i, r, j] = 0.0


@njit(**_J)
def st_solve_ll(Lc, e, v, nu_w, ll):
    last, cn = -1.0, 0.0
    for i in range(Lc.shape[0]):
        dof = nu_w[i]
        logdet = 0.0
        vv = 0.0
        for q in range(3):
            acc = e[i, q]
            for k in range(q):
                acc = acc - Lc[i, q, k] * v[i, k]
            v[i, q] = acc / Lc[i, q, q]
            vv += v[i, q] * v[i, q]
            logdet += math.log(Lc[i, q, q])
        logdet *= 2.0
        if dof != last:
            last, cn = dof, _t_const(dof, 3.0)
        ll[i] = cn - 0.5 * logdet - 0.5 * (dof + 3.0) * math.log1p(vv / dof)


@njit(**_J)
def st_norm(v, logw, nu_w, ll, nc):
    innovation = 0.0
    for i in range(v.shape[0]):
        vv = 0.0
        for q in range(nc):
            vv += v[i, q] * v[i, q]
        innovation += math.exp(logw[i]) * (vv * (nu_w[i] - 2.0) / (nu_w[i] * nc))
    return innovation, _normalise_into(logw, ll)


@njit
def _empty(*a):
    return 0


def stage_calls(t: dict) -> list:
    g = t.__getitem__
    return [
        ("interval slip", st_slip, [g(k) for k in "x a B w_prev slip u_prev uk dt vp jw c_floor rear_drive".split()]),
        ("propagation, forgetting, model", st_prop, prop_args(t)),
        ("weights: h, D, L11, L12, S, e", st_build,
         [g(k) for k in "x a B roll_gain h D nu nu_w gamma Lam L11 avail L12 R Lc mu y b e".split()]),
        ("Cholesky of S", st_chol, [g("Lc")]),
        ("solve, Student-t density", st_solve_ll, [g(k) for k in "Lc e v nu_w ll".split()]),
        ("innovation, log-sum-exp, ESS", st_norm, [g(k) for k in "v logw nu_w ll nc".split()]),
    ]


# ---- the propagation stage: registers and lanes ----------------------------------------------------------------
def prop_args(t: dict) -> list:
    return [t[k] for k in "x a B af ar slip w_prev u_prev uk dt vp rear_drive gamma nu Lam lam nu_min ok beta "
            "gate_speed yaw_max".split()]


@njit(**_J)
def regs_prop(x, a, B, af, ar, slip, w_prev, u_prev, uk, dt, vp, rear_drive, gamma, nu, Lam, lam, nu_min, ok, beta,
              gate_speed, yaw_max):
    """"registers": `st_prop` with the model's values as scalars, on the same arrays."""
    n = x.shape[0]
    kp = _steer_consts(u_prev[0], vp)
    kk = _steer_consts(uk[0], vp)
    hs = dt
    count = 0
    for i in range(n):
        x0, x1, x2 = x[i, 0], x[i, 1], x[i, 2]
        w0, w1, w2 = w_prev[i, 0], w_prev[i, 1], w_prev[i, 2]
        sf, sr = slip[0, i], slip[1, i]
        m = _model_t((x0, x1, x2), (u_prev[0], u_prev[1], u_prev[2], u_prev[3]), kp, True, sf, sr, vp, True, rear_drive)
        k10, k11, k12 = _xdot_t(x0, x1, x2, u_prev[3], m, w0, w1, w2, True)
        y0, y1, y2 = x0 + hs * k10, x1 + hs * k11, x2 + hs * k12
        m = _model_t((y0, y1, y2), (u_prev[0], u_prev[1], u_prev[2], u_prev[3]), kp, True, sf, sr, vp, True, rear_drive)
        k20, k21, k22 = _xdot_t(y0, y1, y2, u_prev[3], m, w0, w1, w2, True)
        x0 = x0 + (0.5 * hs) * (k10 + k20)
        x1 = x1 + (0.5 * hs) * (k11 + k21)
        x2 = x2 + (0.5 * hs) * (k12 + k22)
        x[i, 0], x[i, 1], x[i, 2] = x0, x1, x2
        f = max(lam, min(1.0, nu_min / nu[i])) if nu_min > 0 else lam
        gamma[i] = gamma[i] / f
        nu[i] = nu[i] * f
        for j in range(3):
            for k in range(3):
                Lam[i, j, k] = Lam[i, j, k] * f
        m = _model_t((x0, x1, x2), (uk[0], uk[1], uk[2], uk[3]), kk, False, 0.0, 0.0, vp, True, rear_drive)
        a[i, 0], a[i, 1], a[i, 2] = m[0], m[1], m[2]
        B[i, 0, 0], B[i, 0, 1], B[i, 0, 2] = m[3], m[4], m[5]
        B[i, 1, 0], B[i, 1, 1], B[i, 1, 2] = m[6], m[7], m[8]
        B[i, 2, 0], B[i, 2, 1], B[i, 2, 2] = m[9], m[10], m[11]
        af[i], ar[i], slip[0, i], slip[1, i] = m[12], m[13], m[14], m[15]
        ok[i] = abs(x1) <= beta * max(abs(x0), gate_speed) and abs(x2) <= yaw_max
        count += ok[i]
    return count


class _NoAlias(CompilerBase):
    """numba's nopython pipeline with its internal `noalias` flag set: the array arguments' data pointers
    marked noalias, so that LLVM's loop vectoriser needs no run-time alias checks."""

    def define_pipelines(self):
        self.state.flags.noalias = True
        return [DefaultPassBuilder.define_nopython_pipeline(self.state)]


@njit(nogil=True, error_model="numpy", pipeline_class=_NoAlias)
def lanes_prop(X0, X1, X2, W0, W1, W2, SF, SR, G, NU, L0, L1, L2, L3, L4, L5, L6, L7, L8, A0, A1, A2, B0, B1, B2, B3,
               B4, B5, B6, B7, B8, AF, AR, OK, u_prev, uk, dt, vp, rear_drive, lam, nu_min, beta, gate_speed, yaw_max):
    """"lanes": `regs_prop` over one (N,) array per component (OK: 1.0 / 0.0)."""
    n = X0.shape[0]
    kp = _steer_consts(u_prev[0], vp)
    kk = _steer_consts(uk[0], vp)
    hs = dt
    pos = nu_min > 0
    for i in range(n):
        x0, x1, x2 = X0[i], X1[i], X2[i]
        w0, w1, w2 = W0[i], W1[i], W2[i]
        sf, sr = SF[i], SR[i]
        m = _model_t((x0, x1, x2), (u_prev[0], u_prev[1], u_prev[2], u_prev[3]), kp, True, sf, sr, vp, True, rear_drive)
        k10, k11, k12 = _xdot_t(x0, x1, x2, u_prev[3], m, w0, w1, w2, True)
        y0, y1, y2 = x0 + hs * k10, x1 + hs * k11, x2 + hs * k12
        m = _model_t((y0, y1, y2), (u_prev[0], u_prev[1], u_prev[2], u_prev[3]), kp, True, sf, sr, vp, True, rear_drive)
        k20, k21, k22 = _xdot_t(y0, y1, y2, u_prev[3], m, w0, w1, w2, True)
        x0 = x0 + (0.5 * hs) * (k10 + k20)
        x1 = x1 + (0.5 * hs) * (k11 + k21)
        x2 = x2 + (0.5 * hs) * (k12 + k22)
        X0[i], X1[i], X2[i] = x0, x1, x2
        nui = NU[i]
        f = max(lam, min(1.0, nu_min / nui)) if pos else lam
        G[i] = G[i] / f
        NU[i] = nui * f
        L0[i] *= f
        L1[i] *= f
        L2[i] *= f
        L3[i] *= f
        L4[i] *= f
        L5[i] *= f
        L6[i] *= f
        L7[i] *= f
        L8[i] *= f
        m = _model_t((x0, x1, x2), (uk[0], uk[1], uk[2], uk[3]), kk, False, 0.0, 0.0, vp, True, rear_drive)
        A0[i], A1[i], A2[i] = m[0], m[1], m[2]
        B0[i], B1[i], B2[i], B3[i], B4[i], B5[i], B6[i], B7[i], B8[i] = m[3], m[4], m[5], m[6], m[7], m[8], m[9], \
            m[10], m[11]
        AF[i], AR[i], SF[i], SR[i] = m[12], m[13], m[14], m[15]
        OK[i] = 1.0 if (abs(x1) <= beta * max(abs(x0), gate_speed)) & (abs(x2) <= yaw_max) else 0.0


def lanes_args(t: dict) -> tuple[list, list]:
    """lanes_prop's arguments from the pass's (copies: 1D columns of their own) and its constants."""
    n = t["x"].shape[0]
    col = [t["x"][:, k].copy() for k in range(3)] + [t["w_prev"][:, k].copy() for k in range(3)]
    col += [t["slip"][0].copy(), t["slip"][1].copy(), t["gamma"].copy(), t["nu"].copy()]
    col += [t["Lam"].reshape(n, 9)[:, k].copy() for k in range(9)] + [np.empty(n) for _ in range(15)]
    const = [t[k] for k in "u_prev uk dt vp rear_drive lam nu_min beta gate_speed yaw_max".split()]
    return col, const


def lanes_back(col: list) -> dict:
    """The (N, ...) arrays of `st_prop`'s outputs from lanes_prop's columns."""
    n = col[0].shape[0]
    return dict(x=np.stack(col[0:3], 1), slip=np.stack(col[6:8]), gamma=col[8], nu=col[9],
                Lam=np.stack(col[10:19], 1).reshape(n, 3, 3), a=np.stack(col[19:22], 1),
                B=np.stack(col[22:31], 1).reshape(n, 3, 3), af=col[31], ar=col[32], ok=col[33] > 0)


@njit(**_J)
def to_columns(src, dst):
    """dst (k, N) := src (N, ...) flattened to (N, k)."""
    n = src.shape[0]
    s2 = src.reshape((n, src.size // n))
    for i in range(n):
        for c in range(s2.shape[1]):
            dst[c, i] = s2[i, c]


@njit(**_J)
def from_columns(src, dst):
    n = dst.shape[0]
    d2 = dst.reshape((n, dst.size // n))
    for i in range(n):
        for c in range(d2.shape[1]):
            d2[i, c] = src[c, i]


def transposes(t: dict, buf: dict) -> None:
    """What "lanes" costs around it in a pass on (N, ...) arrays: x, w, Lam in; x, a, B, Lam out."""
    for k in ("x", "w_prev", "Lam"):
        to_columns(t[k], buf[k])
    for k in ("x", "a", "B", "Lam"):
        from_columns(buf[k], t[k])


# ---- the weights' stage on scalars (a prototype) ----------------------------------------------------------
@njit(**_J)
def build_regs(x, a, B, roll_gain, h, D, nu, nu_w, gamma, Lam, L11, avail, L12, R, Lc, mu, y, b, e):
    """A prototype, not in the pass: `st_build` on scalars for the full model with every channel
    (avail = 0, 1, 2) and the bias off (no P in S); the same products and sums in the same order
    (the zero row of D included)."""
    n, nx = x.shape
    R00, R10, R11, R20, R21, R22 = R[0, 0], R[1, 0], R[1, 1], R[2, 0], R[2, 1], R[2, 2]
    y0, y1, y2 = y[0], y[1], y[2]
    for i in range(n):
        h0, h1, h2 = a[i, 0], roll_gain * a[i, 1], x[i, nx - 1]
        h[i, 0], h[i, 1], h[i, 2] = h0, h1, h2
        d00, d01, d02 = B[i, 0, 0], B[i, 0, 1], B[i, 0, 2]
        d10, d11, d12 = B[i, 1, 0] * roll_gain, B[i, 1, 1] * roll_gain, B[i, 1, 2] * roll_gain
        D[i, 0, 0], D[i, 0, 1], D[i, 0, 2] = d00, d01, d02
        D[i, 1, 0], D[i, 1, 1], D[i, 1, 2] = d10, d11, d12
        D[i, 2, 0], D[i, 2, 1], D[i, 2, 2] = 0.0, 0.0, 0.0
        dof = nu[i] - 3 + 1.0
        nu_w[i] = dof
        f = (1.0 + gamma[i]) / dof
        l00, l01, l02 = f * Lam[i, 0, 0], f * Lam[i, 0, 1], f * Lam[i, 0, 2]
        l10, l11, l12 = f * Lam[i, 1, 0], f * Lam[i, 1, 1], f * Lam[i, 1, 2]
        l20, l21, l22 = f * Lam[i, 2, 0], f * Lam[i, 2, 1], f * Lam[i, 2, 2]
        L11[i, 0, 0], L11[i, 0, 1], L11[i, 0, 2] = l00, l01, l02
        L11[i, 1, 0], L11[i, 1, 1], L11[i, 1, 2] = l10, l11, l12
        L11[i, 2, 0], L11[i, 2, 1], L11[i, 2, 2] = l20, l21, l22
        # DL[q, k] = sum_j D[q, j] L11[j, k] (s = 0.0 then += in j order)
        a00 = ((0.0 + d00 * l00) + d01 * l10) + d02 * l20
        a01 = ((0.0 + d00 * l01) + d01 * l11) + d02 * l21
        a02 = ((0.0 + d00 * l02) + d01 * l12) + d02 * l22
        a10 = ((0.0 + d10 * l00) + d11 * l10) + d12 * l20
        a11 = ((0.0 + d10 * l01) + d11 * l11) + d12 * l21
        a12 = ((0.0 + d10 * l02) + d11 * l12) + d12 * l22
        a20 = ((0.0 + 0.0 * l00) + 0.0 * l10) + 0.0 * l20
        a21 = ((0.0 + 0.0 * l01) + 0.0 * l11) + 0.0 * l21
        a22 = ((0.0 + 0.0 * l02) + 0.0 * l12) + 0.0 * l22
        L12[i, 0, 0], L12[i, 1, 0], L12[i, 2, 0] = a00, a01, a02
        L12[i, 0, 1], L12[i, 1, 1], L12[i, 2, 1] = a10, a11, a12
        L12[i, 0, 2], L12[i, 1, 2], L12[i, 2, 2] = a20, a21, a22
        cf = (dof - 2.0) / dof
        Lc[i, 0, 0] = (((0.0 + a00 * d00) + a01 * d01) + a02 * d02) + cf * R00
        Lc[i, 1, 0] = (((0.0 + a10 * d00) + a11 * d01) + a12 * d02) + cf * R10
        Lc[i, 1, 1] = (((0.0 + a10 * d10) + a11 * d11) + a12 * d12) + cf * R11
        Lc[i, 2, 0] = (((0.0 + a20 * d00) + a21 * d01) + a22 * d02) + cf * R20
        Lc[i, 2, 1] = (((0.0 + a20 * d10) + a21 * d11) + a22 * d12) + cf * R21
        Lc[i, 2, 2] = (((0.0 + a20 * 0.0) + a21 * 0.0) + a22 * 0.0) + cf * R22
        m0, m1, m2 = mu[i, 0], mu[i, 1], mu[i, 2]
        e[i, 0] = y0 - (h0 + b[i, 0]) - (((0.0 + d00 * m0) + d01 * m1) + d02 * m2)
        e[i, 1] = y1 - (h1 + b[i, 1]) - (((0.0 + d10 * m0) + d11 * m1) + d12 * m2)
        e[i, 2] = y2 - (h2 + b[i, 2]) - (((0.0 + 0.0 * m0) + 0.0 * m1) + 0.0 * m2)


# ---- driver -----------------------------------------------------------------------------------------------------
def _packed(f) -> dict:
    asm = "\n".join(f.inspect_asm(sig) for sig in f.signatures)
    pats = {"ymm mul/div/sqrt": r"v(mul|div|sqrt)pd\s+[^\n]*%ymm", "scalar mul/div/sqrt": r"v(mul|div|sqrt)sd\s"}
    return {k: len(re.findall(p, asm)) for k, p in pats.items()}


def _t(f, a) -> int:
    t0 = time.perf_counter_ns()
    f(*a)
    return time.perf_counter_ns() - t0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--particles", type=int, default=500)
    ap.add_argument("--repeat", type=int, default=400)
    args = ap.parse_args()
    sim, samples = record("paper-sim", 5.0)
    est = build_estimator("mpf", sim, model="auto", particles=args.particles, config={})
    f_pw, a_pw = captured(est, samples)["predict_weigh"]
    cap = unpack(a_pw)
    if not (cap["interval"] and cap["heun"] and cap["noise"].shape[0] == 0 and cap["dt"] <= cap["max_step"]):
        raise SystemExit("the stage copies assume paper-sim's defaults: interval slip, Heun, one sub-step, no noise")
    fresh = lambda: copy.deepcopy(cap)  # noqa: E731

    # the stages in sequence against the pass, bit for bit
    t1, t2 = fresh(), fresh()
    f_pw(*pack(t1))
    for _, f, a in stage_calls(t2):
        f(*a)
    same = all(np.array_equal(t1[k], t2[k], equal_nan=True) for k in NAMES if isinstance(t1[k], np.ndarray))
    print(f"N = {args.particles}; load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    print(f"stop 24's stages in sequence == {f_pw.py_func.__name__} of this checkout, bit for bit: {same}")
    uncached = njit(**_J)(f_pw.py_func)  # (numba shows no machine code of a kernel loaded from its cache)
    uncached(*pack(fresh()))
    print(f"{f_pw.py_func.__name__}'s machine code: {_packed(uncached)}")

    # 2. the stages
    best: dict[str, list[int]] = {}
    whole: list[int] = []
    for _ in range(args.repeat):
        t = fresh()
        for name, f, a in stage_calls(t):
            best.setdefault(name, []).append(_t(f, a))
            best.setdefault(name + " (dispatch)", []).append(_t(_empty, a))
        t = fresh()
        whole.append(_t(f_pw, pack(t)))
    print(f"stages of stop 24's pass, us, min (median) over {args.repeat} rounds; net = min - dispatch min:")
    for name, _, _ in stage_calls(fresh()):
        v, d = np.array(best[name]) / 1e3, np.array(best[name + " (dispatch)"]) / 1e3
        print(f"  {name:34s} {v.min():7.1f} ({np.median(v):7.1f})  dispatch {d.min():4.1f}  net {v.min() - d.min():6.1f}")
    w = np.array(whole) / 1e3
    print(f"  {'the whole pass (this checkout)':34s} {w.min():7.1f} ({np.median(w):7.1f})")

    # 3. the propagation: arrays, registers, lanes, transposes
    ref = fresh()
    st_prop(*prop_args(ref))
    outs = "x a B af ar slip gamma nu Lam ok".split()
    t = fresh()
    regs_prop(*prop_args(t))
    col, const = lanes_args(fresh())
    lanes_prop(*col, *const)
    back = lanes_back(col)
    print("propagation stage, bit for bit against 'arrays': registers "
          f"{all(np.array_equal(ref[k], t[k]) for k in outs)}, lanes {all(np.array_equal(ref[k], back[k]) for k in outs)}")
    for name, f in (("arrays", st_prop), ("registers", regs_prop), ("lanes", lanes_prop)):
        print(f"  {name:10s} machine code: {_packed(f)}")
    n = cap["x"].shape[0]
    buf = {k: np.empty((cap[k].size // n, n)) for k in ("x", "w_prev", "Lam", "a", "B")}
    times: dict[str, list[int]] = {k: [] for k in ("arrays", "registers", "lanes", "transposes")}
    for _ in range(args.repeat):
        t_a, t_r, t_x = fresh(), fresh(), fresh()
        col, const = lanes_args(fresh())
        times["arrays"].append(_t(st_prop, prop_args(t_a)))
        times["registers"].append(_t(regs_prop, prop_args(t_r)))
        times["lanes"].append(_t(lanes_prop, col + const))
        t0 = time.perf_counter_ns()
        transposes(t_x, buf)
        times["transposes"].append(time.perf_counter_ns() - t0)
    print(f"propagation stage, us, min (median) over {args.repeat} rounds, alternating:")
    base = min(times["arrays"])
    for k, v in times.items():
        v = np.array(v) / 1e3
        print(f"  {k:11s} {v.min():7.1f} ({np.median(v):7.1f})  arrays / this {base / 1e3 / v.min():5.2f}")
    # 4. the weights' stage on scalars (prototype; full model, every channel, bias off)
    if list(cap["avail"]) == [0, 1, 2] and not cap["bias_on"]:
        pre = fresh()
        for _, f, a in stage_calls(pre)[:2]:
            f(*a)
        keys = "x a B roll_gain h D nu nu_w gamma Lam L11 avail L12 R Lc mu y b e".split()
        r1, r2 = copy.deepcopy(pre), copy.deepcopy(pre)
        st_build(*[r1[k] for k in keys])
        build_regs(*[r2[k] for k in keys])
        eq = all(np.array_equal(r1[k], r2[k]) for k in "h D nu_w L11 L12 Lc e".split())
        tb: dict[str, list[int]] = {"arrays": [], "registers": []}
        for _ in range(args.repeat):
            r1, r2 = copy.deepcopy(pre), copy.deepcopy(pre)
            tb["arrays"].append(_t(st_build, [r1[k] for k in keys]))
            tb["registers"].append(_t(build_regs, [r2[k] for k in keys]))
        print(f"weights' stage (h, D, L11, L12, S, e), bit for bit: {eq}; us, min (median), alternating:")
        for k, v in tb.items():
            v = np.array(v) / 1e3
            print(f"  {k:11s} {v.min():7.1f} ({np.median(v):7.1f})  arrays / this {min(tb['arrays']) / 1e3 / v.min():5.2f}")
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
