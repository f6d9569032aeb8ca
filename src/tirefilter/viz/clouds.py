"""Particle clouds drawn so that they explain themselves: framed at every step, with named
axes, physical tick labels and a weight colour scale.

A cloud's points are recorded in physical units (kN/rad, kN/unit slip, m/s, rad/s). With
them goes a transform (`normalising`) to a frame where the cloud has mean 0 and std 1 on
each axis, so a fixed camera frames it however it moves or shrinks; the axes, ticks and
labels (`axes`) are drawn in that frame, each tick labelled with its physical value. Rerun's
2-D views draw y downwards, so the 2-D frame flips y.

Weights are coloured on a fixed logarithmic scale of N w (1 = the uniform weight 1/N), so a
colour means the same at every step: after resampling every particle has the colour of 1,
not the 'heaviest' colour (`weight_colors`, `WEIGHT_TICKS`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

REACH = 3.0  # the axes run over -+REACH std
LOG_RANGE = (-2.0, 1.0)  # log10(N w) from the first to the last colour
WEIGHT_TICKS = (0.01, 0.1, 1.0, 10.0)  # N w values labelled on the colour scale
_VIRIDIS = np.array([[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], float)
AXIS_COLOR = (60, 60, 60)


def viridis(x) -> np.ndarray:
    """(n, 3) uint8 colours of x in [0, 1] (clipped): dark purple .. yellow."""
    x = np.clip(np.asarray(x, float), 0.0, 1.0) * (len(_VIRIDIS) - 1)
    anchors = np.arange(len(_VIRIDIS))
    return np.stack([np.interp(x, anchors, _VIRIDIS[:, c]) for c in range(3)], axis=-1).astype(np.uint8)


def weight_position(nw) -> np.ndarray:
    """Where N w lies on the colour scale, 0 .. 1 (log10 over LOG_RANGE, clipped)."""
    with np.errstate(divide="ignore"):
        lg = np.log10(np.asarray(nw, float))
    lo, hi = LOG_RANGE
    return np.clip((np.nan_to_num(lg, nan=lo, neginf=lo) - lo) / (hi - lo), 0.0, 1.0)


def weight_colors(log_weights) -> np.ndarray:
    """(N, 3) uint8 colours of particles by N times their normalised weight, on the fixed
    logarithmic scale LOG_RANGE (viridis: dark = below 1 % of uniform, yellow = 10 times)."""
    lw = np.asarray(log_weights, float)
    lw = np.where(np.isnan(lw), -np.inf, lw)
    if not lw.size:
        return np.zeros((0, 3), np.uint8)
    m = np.max(lw)
    w = np.exp(lw - m) if np.isfinite(m) else np.ones_like(lw)
    w = w / w.sum()
    return viridis(weight_position(len(w) * w))


@dataclass(frozen=True)
class Frame:
    """The normalising frame of a cloud: x_normalised = (x - center) / spread per axis."""

    center: np.ndarray  # (d,)
    spread: np.ndarray  # (d,) > 0

    def apply(self, x) -> np.ndarray:
        return (np.asarray(x, float) - self.center) / self.spread


def normalising(points) -> Frame:
    """The frame in which the cloud (N, d) has mean 0 and std 1 per axis (unweighted, so the
    whole cloud is framed, light particles too). A collapsed axis gets a spread of 1e-3 of
    its mean (at least 1e-9): the points then sit on the axis, which still has ticks."""
    x = np.asarray(points, float)
    x = x[np.all(np.isfinite(x), axis=1)] if x.size else x
    if not len(x):
        d = np.shape(points)[1]
        return Frame(np.zeros(d), np.ones(d))
    c = x.mean(axis=0)
    s = x.std(axis=0)
    floor = np.maximum(1e-3 * np.abs(c), 1e-9)
    return Frame(c, np.where(s > floor, s, floor))


def nice_ticks(lo: float, hi: float, n: int = 4) -> tuple[np.ndarray, int]:
    """About n round values inside [lo, hi], 1, 2 or 5 x 10^k apart (the one nearest to
    (hi - lo) / n on a log scale that leaves at least 3), and the decimals their labels need."""
    span = hi - lo
    if not span > 0:
        return np.array([lo]), 3
    raw = span / n
    mag = 10.0 ** math.floor(math.log10(raw))
    for step in sorted((m * mag for m in (0.5, 1, 2, 5, 10)), key=lambda st: abs(math.log(st / raw))):
        ticks = np.arange(math.ceil(lo / step) * step, hi + 1e-9 * span, step)
        if len(ticks) >= 3:
            break
    return ticks, max(0, -math.floor(math.log10(step) + 1e-12))


@dataclass(frozen=True)
class Axes:
    """What `axes` draws, in the normalised frame (2-D: y flipped): line strips (axis lines
    and tick marks), label positions and their texts."""

    strips: list  # of (k, d) arrays
    label_positions: np.ndarray  # (m, d)
    labels: list[str]


# Where each axis runs in the normalised frame, as the edges of a box of half-size REACH around
# the cloud (the camera, blueprint.CLOUD_EYE, looks from +x, -y, +z): 3-D x along the front
# bottom edge, y along the right bottom edge, z up the front left edge; 2-D x along the bottom,
# y up the left side. Per axis: (start corner, direction of its tick labels) in units of REACH.
_EDGES = {3: [((-1, -1, -1), (0, -1, -1)), ((1, -1, -1), (1, 0, -1)), ((-1, -1, -1), (-1, 0, 0))],
          2: [((-1, -1), (0, -1)), ((-1, -1), (-1, 0))]}


def axes(frame: Frame, names: tuple[str, ...]) -> Axes:
    """Axes on the edges of the box -+REACH around the cloud's centre (`_EDGES`), ticks at
    round physical values with their labels outside the box, each axis named (with its unit)
    beyond the middle of its tick labels (the upward axis above its end)."""
    d = len(names)
    flip = np.ones(d)
    if d == 2:
        flip[1] = -1.0  # Rerun's 2-D views draw y downwards
    strips, pos, text = [], [], []
    for a, name in enumerate(names):
        start, out = (np.array(v, float) for v in _EDGES[d][a])
        start, out = start * REACH, out / np.linalg.norm(out)
        along = np.zeros(d)
        along[a] = 1.0
        strips.append(np.stack([start, start + 2 * REACH * along]) * flip)
        lo = frame.center[a] - REACH * frame.spread[a]
        hi = frame.center[a] + REACH * frame.spread[a]
        values, decimals = nice_ticks(lo, hi)
        for v in values:
            u = (v - frame.center[a]) / frame.spread[a]
            at = start + (u + REACH) * along
            strips.append(np.stack([at, at + 0.12 * out]) * flip)
            pos.append((at + 0.45 * out) * flip)
            text.append(f"{v:.{decimals}f}")
        last = a == d - 1  # the upward axis: named above its end, the others below their middle
        pos.append((start + (2 * REACH + 0.5) * along if last else start + REACH * along + 1.1 * out) * flip)
        text.append(name)
    return Axes(strips, np.array(pos), text)


def weight_scale(d: int, n: int = 24) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """The colour scale of the weights as a bar of n points beside the box, in the normalised
    frame: (positions (n, d), colours (n, 3), label positions (m, d), labels). 3-D: up the
    box's back right edge, pushed out to the right; 2-D: up its right side."""
    s = np.linspace(0.0, 1.0, n)
    if d == 3:
        base, up, side = np.array([1.0, 1.05, 0.0]) * REACH, np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.7, 0.0])
    else:
        base, up, side = np.array([1.3 * REACH, 0.0]), np.array([0.0, -1.0]), np.array([0.4, 0.0])
    pos = base + np.outer((2 * s - 1) * REACH * 0.8, up)
    label_pos, labels = [], []
    for v in WEIGHT_TICKS:
        label_pos.append(base + (2 * weight_position(v) - 1) * REACH * 0.8 * up + side)
        labels.append(f"{v:g}" + (" = uniform" if v == 1 else ""))
    label_pos.append(base + REACH * 1.0 * up + 0.5 * side)
    labels.append("weight x N")
    return pos, viridis(s), np.array(label_pos), labels


def transform(frame: Frame) -> tuple[np.ndarray, np.ndarray]:
    """(translation (3,), scale (3,)) of the Transform3D from a cloud's physical points to
    its normalised frame: x_n = x / spread - center / spread (2-D: y flipped, z kept)."""
    d = len(frame.center)
    scale = np.ones(3)
    translation = np.zeros(3)
    scale[:d] = 1.0 / frame.spread
    translation[:d] = -frame.center / frame.spread
    if d == 2:
        scale[1], translation[1] = -scale[1], -translation[1]
    return translation, scale
