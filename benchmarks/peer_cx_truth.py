"""The peer's own truth on Cx (docs/derivations.md "Wheel-speed pre-filter"): for a peer drive of the STD model,
the driven axle's longitudinal force (the peer's tire formulas at its states) against our wheel
slip lambda = (R_w omega - v^X) / max(|v^X|, |R_w omega|, 1) from the noise-free wheel rates,
and the a^X the MPF's measurement model expects at the true stiffness.

    .venv/bin/python benchmarks/peer_cx_truth.py [--vehicle 3] [--seed 21] [--speed 18] [--duration 60]

Prints: the least-squares slope of the driven axle's force on lambda against `Cx_true`
(p_kx1 times the driven axle's load), the slip of the free-rolling wheels (the peer tire's
zero-slip offset), how exactly the peer's a^X is (F_xf cos delta - F_yf sin delta + F_xr) / m
(no drag, no rolling resistance), the regression of m a^X + F_yf sin delta - (undriven force)
on lambda (Cx as the a^X data carry it, without noise), and the residual of a^X at the true
stiffness with the MPF's model (driven axle Cx_true lambda, the other forces true).
"""

from __future__ import annotations

import argparse
import math

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--vehicle", type=int, default=3, choices=(1, 2, 3))
    ap.add_argument("--seed", type=int, default=21)
    ap.add_argument("--speed", type=float, default=18.0)
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--maneuver", default="mixed")
    args = ap.parse_args()

    import vehiclemodels.utils.tire_model as tm
    from vehiclemodels.utils.acceleration_constraints import acceleration_constraints

    from tirefilter.peer.drive import DriveSpec, trajectory
    from tirefilter.peer.model import G_PEER, load_model

    spec = DriveSpec(model="std", vehicle=args.vehicle, maneuver=args.maneuver, duration=args.duration,
                     seed=args.seed, speed=args.speed)
    model = load_model(spec.model, spec.vehicle, spec.camber)
    _, X, U, _ = trajectory(spec, model)  # the drive `tirefilter peer-drive` samples
    p = model.p
    m, lf, lr = p.m, p.a, p.b
    L = lf + lr
    rows = []
    for x, u in zip(X, U):
        d, v, r, beta, wf, wr = x[2], x[3], x[5], x[6], x[7], x[8]
        a = acceleration_constraints(v, u[1], p.longitudinal)
        Fzf, Fzr = m * (-a * p.h_s + G_PEER * lr) / L, m * (a * p.h_s + G_PEER * lf) / L
        alf = math.atan((v * math.sin(beta) + r * lf) / (v * math.cos(beta))) - d
        alr = math.atan((v * math.sin(beta) - r * lr) / (v * math.cos(beta)))
        uwf = v * math.cos(beta) * math.cos(d) + (v * math.sin(beta) + lf * r) * math.sin(d)
        uwr = v * math.cos(beta)
        sf, sr = 1 - p.R_w * wf / uwf, 1 - p.R_w * wr / uwr
        Fxf = tm.formula_longitudinal_comb(sf, alf, tm.formula_longitudinal(sf, 0, Fzf, p.tire), p.tire)
        Fxr = tm.formula_longitudinal_comb(sr, alr, tm.formula_longitudinal(sr, 0, Fzr, p.tire), p.tire)
        F0yf, muf = tm.formula_lateral(alf, 0, Fzf, p.tire)
        Fyf = tm.formula_lateral_comb(sf, alf, 0, muf, Fzf, F0yf, p.tire)
        vx = v * math.cos(beta)
        lam_f = (p.R_w * wf - vx) / max(abs(vx), abs(p.R_w * wf), 1.0)
        lam_r = (p.R_w * wr - vx) / max(abs(vx), abs(p.R_w * wr), 1.0)
        f = model.rhs(list(x), list(u))
        ax = f[3] * math.cos(beta) - v * math.sin(beta) * f[6] - r * v * math.sin(beta)
        rows.append((Fzf, Fzr, Fxf, Fxr, Fyf, d, lam_f, lam_r, ax))
    Fzf, Fzr, Fxf, Fxr, Fyf, d, lam_f, lam_r, ax = np.array(rows).T
    rear = model.drive == "rear"
    if model.drive == "all":
        raise SystemExit("an all-wheel-drive vehicle has no undriven axle")
    lam_d, F_d, Fz_d = (lam_r, Fxr, Fzr) if rear else (lam_f, Fxf, Fzf)
    lam_u, F_u = (lam_f, Fxf * np.cos(d)) if rear else (lam_r, Fxr)
    cx_true = p.tire.p_kx1 * Fz_d
    print(f"STD model, vehicle {args.vehicle}, {args.maneuver}, {args.duration:g} s, seed {args.seed}, "
          f"{args.speed:g} m/s; {model.drive} drive; mean Cx_true {cx_true.mean():.4g} N")
    print(f"driven slip lambda {lam_d.min():+.5f} to {lam_d.max():+.5f} (mean {lam_d.mean():+.5f})")
    free = np.abs(Fxf) + np.abs(Fxr) < 1.0
    if free.any():
        print(f"free rolling (|F_xf| + |F_xr| < 1 N, {np.count_nonzero(free)} samples): lambda_f "
              f"{np.mean(lam_f[free]):+.5f}, lambda_r {np.mean(lam_r[free]):+.5f} (peer p_hx1 {p.tire.p_hx1:g}, "
              f"p_vx1 {p.tire.p_vx1:g})")
    exact = np.max(np.abs(ax - (Fxf * np.cos(d) - Fyf * np.sin(d) + Fxr) / m))
    print(f"max |a^X - (F_xf cos delta - F_yf sin delta + F_xr) / m| = {exact:.2g} m/s^2")
    k = np.polyfit(lam_d, F_d, 1)
    print(f"driven force on lambda: slope {k[0]:.4g} N ({k[0] / cx_true.mean():.3f} x Cx_true), "
          f"offset {k[1]:.4g} N")
    y = m * ax + Fyf * np.sin(d) - F_u
    k = np.polyfit(lam_d, y, 1)
    print(f"m a^X + F_yf sin delta - undriven force on lambda: Cx {k[0]:.4g} N "
          f"({100 * (k[0] / cx_true.mean() - 1):+.1f} % of Cx_true), offset {k[1]:.4g} N")
    res = ax - (cx_true * lam_d - Fyf * np.sin(d) + F_u) / m
    print(f"a^X residual at the true stiffness (model: Cx_true lambda on the driven axle, other forces true): "
          f"mean {res.mean():+.3f} m/s^2, std {res.std():.3f} m/s^2")


if __name__ == "__main__":
    main()
