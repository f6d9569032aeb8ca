"""The friction CSV (docs/usage.md, "Friction learning"): snapshots of a friction estimator's curves.

`run` writes `DIR/friction.csv`, `replay` writes `RESULT.friction.csv` (the stem of
RESULT + `.friction.csv`). Columns `t, alpha, mu_f, mu_f_std, mu_r, mu_r_std` (mu as
lateral force over normal load, alpha in rad), plus `true_mu_f, true_mu_r` in
co-simulation: the pure-lateral Pacejka curve at static axle load times the surface scale
(docs/usage.md, "Run summary"; a linear-tire scenario: C_y alpha / F^z times the
surface). One block of rows per snapshot: every `every` seconds of estimator time and at
the end. Each block is flushed when written, so a run that fails keeps its snapshots.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tirefilter.io.csv_format import format_rows

FRICTION_COLUMNS = ("t", "alpha", "mu_f", "mu_f_std", "mu_r", "mu_r_std")
TRUTH_COLUMNS = ("true_mu_f", "true_mu_r")


def friction_csv_path(results_csv: str | Path) -> Path:
    """RESULT.csv -> RESULT.friction.csv (replay)."""
    p = Path(results_csv)
    return p.with_name(p.stem + ".friction.csv")


def is_friction_estimator(estimator) -> bool:
    return estimator is not None and callable(getattr(estimator, "friction", None))


def friction_truth(scenario):
    """(alpha (G,), surface) -> (true_mu_f, true_mu_r) of a scenario's tires."""
    from tirefilter.vehicle.tires import pure_lateral_friction

    model = scenario.model
    if model.tire_model == "pacejka":
        p = model.pacejka
        return lambda alpha, s: (pure_lateral_friction(p, alpha, s), pure_lateral_friction(p, alpha, s))
    Cf, Cr, _, _ = model.axle_stiffness()
    Fzf, Fzr = scenario.vehicle.static_axle_loads()
    return lambda alpha, s: (s * Cf * alpha / Fzf, s * Cr * alpha / Fzr)


class FrictionWriter:
    """Writes snapshots of `estimator.friction()`; `truth(alpha, surface)` adds the truth.

    A sink of the run loop (`runs.Run`): `write(row)` takes a Result-CSV row with the header
    `columns` (its time, and with a truth its `true_surface`), `finish()` writes the end
    snapshot, `close()` the file."""

    def __init__(self, path: str | Path, estimator, *, every: float | None = None, truth=None, columns=()):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.estimator, self.truth = estimator, truth
        cfg = getattr(estimator, "cfg", None)
        self.every = float(every if every is not None else getattr(cfg, "snapshot_every", 10.0))
        self.columns = FRICTION_COLUMNS + (TRUTH_COLUMNS if truth is not None else ())
        self._file = self.path.open("w", newline="")
        self._file.write(",".join(self.columns) + "\n")
        self._file.flush()
        self._t0 = None
        self._next = None
        self.last_t = None
        self.blocks = 0
        self._t_index = list(columns).index("t") if "t" in columns else 0
        self._surface_index = list(columns).index("true_surface") if truth is not None and "true_surface" in columns \
            else None

    def write(self, row) -> None:
        """After the estimator's step whose Result-CSV row this is."""
        self.sample(float(row[self._t_index]), 1.0 if self._surface_index is None else float(row[self._surface_index]))

    def sample(self, t: float, surface: float = 1.0) -> None:
        """After the estimator's step at t: a snapshot when t has reached the next one."""
        if self._t0 is None:
            self._t0 = t
            self._next = t + self.every
        if t >= self._next - 1e-9:
            self.snapshot(t, surface)
            while self._next <= t + 1e-9:
                self._next += self.every
        self._last = (t, surface)

    def finish(self) -> None:
        """The end snapshot (unless one was just written at the last sample)."""
        last = getattr(self, "_last", None)
        if last is not None and self.last_t != last[0]:
            self.snapshot(*last)

    def snapshot(self, t: float, surface: float = 1.0) -> None:
        fc = self.estimator.friction()
        n = len(fc.alpha)
        cols = [np.full(n, t), fc.alpha, fc.mu_f, fc.mu_f_std, fc.mu_r, fc.mu_r_std]
        if self.truth is not None:
            cols += list(self.truth(fc.alpha, surface))
        rows = np.column_stack(cols)
        self._file.write(format_rows(rows.tolist()))
        self._file.flush()
        self.last_t = t
        self.blocks += 1

    def close(self) -> None:
        if not self._file.closed:
            self._file.close()


def read_friction(path: str | Path) -> dict[str, np.ndarray]:
    """A friction CSV as columns of floats."""
    from tirefilter.io.results import read_results

    return read_results(path)


def snapshot_blocks(columns: dict[str, np.ndarray]) -> list[dict[str, np.ndarray]]:
    """Split the columns of a friction CSV into its snapshots (one dict per time)."""
    t = columns["t"]
    out = []
    for tk in np.unique(t):
        m = t == tk
        out.append({k: v[m] for k, v in columns.items()})
    return out
