"""Tire force laws, batch-first: linear (F = C slip) and the Pacejka Magic Formula with
combined slip. Slip angle alpha > 0 and wheel slip > 0 (traction) give positive force."""

from __future__ import annotations

import numpy as np

from tirefilter.vehicle.params import PacejkaParams


def magic_formula(B, C, D, E, s):
    """Pacejka's Magic Formula D sin(C atan(B s - E (B s - atan(B s))))."""
    Bs = B * s
    return D * np.sin(C * np.arctan(Bs - E * (Bs - np.arctan(Bs))))


def linear_forces(Cy, Cx, alpha, lam):
    """Axle forces of the linear model, eq. (2) of the stiffness paper: (Fy, Fx)."""
    return Cy * alpha, Cx * lam


def pacejka_forces(p: PacejkaParams, Fz, alpha, lam, dev_y=0.0, dev_x=0.0):
    """Combined-slip Magic Formula axle forces (Fy, Fx).

    The relative stiffness deviations scale the stiffness factors B (initial slope scales,
    peak friction does not). Combined slip by the weighting functions
    G_y,kappa = cos(C_yk atan(B_yk lambda)), B_yk = r_By1 cos(atan(r_By2 alpha)), and
    G_x,alpha = cos(C_xa atan(B_xa alpha)), B_xa = r_Bx1 cos(atan(r_Bx2 lambda))
    (Pacejka 2006, Sec. 4.3.2).
    """
    Fy0 = magic_formula(p.B_y * (1.0 + dev_y), p.C_y, p.mu_y * Fz, p.E_y, alpha)
    Fx0 = magic_formula(p.B_x * (1.0 + dev_x), p.C_x, p.mu_x * Fz, p.E_x, lam)
    G_yk = np.cos(p.Cyk * np.arctan(p.rBy1 * np.cos(np.arctan(p.rBy2 * alpha)) * lam))
    G_xa = np.cos(p.Cxa * np.arctan(p.rBx1 * np.cos(np.arctan(p.rBx2 * lam)) * alpha))
    return Fy0 * G_yk, Fx0 * G_xa


def pure_lateral_friction(p: PacejkaParams, alpha, surface=1.0):
    """mu_y(alpha) = Fy / Fz of the pure-lateral Magic Formula times the surface scale
    (the friction truth of docs/design.md)."""
    return surface * magic_formula(p.B_y, p.C_y, p.mu_y, p.E_y, alpha)
