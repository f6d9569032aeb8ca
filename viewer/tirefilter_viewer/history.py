"""The rows a dashboard shows: Result-CSV rows of a live run or of an opened Result CSV,
with the decimated views the charts draw and the vehicle path.

Everything here is plain numpy and knows nothing of viser, so it is tested without a
browser.
"""

from __future__ import annotations

import math

import numpy as np

MAX_POINTS = 800  # samples per chart series; longer histories are decimated (every 2^j-th sample)


class History:
    """A growing table of Result-CSV rows (columns named as in the Result CSV).

    Rows are appended one at a time into a buffer that doubles when full; `column(name)`
    returns a view of the rows so far (None when the table has no such column).
    """

    def __init__(self, columns, capacity: int = 4096):
        self.columns = tuple(columns)
        self.index = {c: j for j, c in enumerate(self.columns)}
        self._data = np.empty((max(int(capacity), 1), len(self.columns)))
        self.rows = 0

    @classmethod
    def from_columns(cls, data: dict[str, np.ndarray]) -> History:
        """A history holding whole columns at once (an opened Result CSV)."""
        columns = tuple(data)
        n = len(next(iter(data.values()))) if data else 0
        h = cls(columns, capacity=max(n, 1))
        for j, c in enumerate(columns):
            h._data[:n, j] = data[c]
        h.rows = n
        return h

    def append(self, row) -> None:
        if self.rows == len(self._data):
            grown = np.empty((2 * len(self._data), len(self.columns)))
            grown[: self.rows] = self._data[: self.rows]
            self._data = grown
        self._data[self.rows] = row
        self.rows += 1

    def column(self, name: str) -> np.ndarray | None:
        j = self.index.get(name)
        return None if j is None else self._data[: self.rows, j]

    def last(self, name: str) -> float:
        """The newest value of a column (NaN when absent or empty)."""
        j = self.index.get(name)
        return math.nan if j is None or self.rows == 0 else float(self._data[self.rows - 1, j])

    def has_values(self, name: str) -> bool:
        x = self.column(name)
        return x is not None and bool(np.isfinite(x).any())

    def decimation(self, max_points: int = MAX_POINTS) -> np.ndarray:
        """Row indices a chart draws: every s-th row (s a power of two, so the points
        stay put as the run grows) and always the newest one."""
        n = self.rows
        if n == 0:
            return np.zeros(0, dtype=int)
        stride = 1
        while n > stride * max_points:
            stride *= 2
        idx = np.arange(0, n, stride)
        if idx[-1] != n - 1:
            idx = np.append(idx, n - 1)
        return idx

    def pose(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The vehicle path (x, y, psi) [m, m, rad], each (rows,).

        The truth (`true_x`, `true_y`, `true_psi`) when the rows have it; otherwise dead
        reckoning from the estimated (or else measured) v^X, v^Y and yaw rate:
        psi' = r, x' = v^X cos psi - v^Y sin psi, y' = v^X sin psi + v^Y cos psi
        (forward Euler over the sample times, a missing sample counting as zero).
        """
        if all(self.has_values(c) for c in ("true_x", "true_y", "true_psi")):
            return self.column("true_x"), self.column("true_y"), self.column("true_psi")
        n = self.rows
        t = self.column("t")
        vx = self._either("vx", "meas_vx")
        vy = self._either("vy", None)
        r = self._either("yaw_rate", "meas_yaw_rate")
        dt = np.diff(t, prepend=t[:1]) if n else np.zeros(0)
        psi = np.cumsum(np.concatenate([[0.0], (r[:-1] * dt[1:])])) if n else np.zeros(0)
        c, s = np.cos(psi), np.sin(psi)
        vxw, vyw = vx * c - vy * s, vx * s + vy * c
        x = np.cumsum(np.concatenate([[0.0], vxw[:-1] * dt[1:]])) if n else np.zeros(0)
        y = np.cumsum(np.concatenate([[0.0], vyw[:-1] * dt[1:]])) if n else np.zeros(0)
        return x, y, psi

    def _either(self, first: str, second: str | None) -> np.ndarray:
        """Column `first` where finite, else `second`, else 0."""
        out = np.zeros(self.rows)
        for name in (second, first):
            x = self.column(name) if name else None
            if x is not None:
                out = np.where(np.isfinite(x), x, out)
        return out
