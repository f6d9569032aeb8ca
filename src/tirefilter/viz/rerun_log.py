"""Rerun recordings of a run: truth, sensors, vehicle pose and estimate series.

Rows are buffered and sent in bulk with `send_columns` every `chunk` rows and at close,
so a recording costs little per step and a run that fails keeps what was sent.
Entity paths (README, DESIGN.md):
  /truth/<name>                     ground truth (Result CSV `true_<name>`)
  /sensors/<name>                   measured signals (Result CSV `meas_<name>`)
  /vehicle/x, /vehicle/y, /vehicle/psi, /vehicle/path
  /estimator/<est>/state/<vx|vy|yaw_rate|beta>
  /estimator/<est>/stiffness/<Cf_y|Cr_y|Cx>[_std|_sigma]
  /estimator/<est>/bias/<ax|ay|yaw_rate>
  /estimator/<est>/ess, /estimator/<est>/active
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

TIMELINE = "sim_time"


def entity_path(column: str, estimator: str | None) -> str | None:
    """Entity path of a Result-CSV column (None for `t`)."""
    if column == "t":
        return None
    if column.startswith("true_"):
        name = column[len("true_"):]
        if name in ("x", "y", "psi"):
            return f"/vehicle/{name}"
        return f"/truth/{name}"
    if column.startswith("meas_"):
        return f"/sensors/{column[len('meas_'):]}"
    if estimator is None:
        return None
    base = f"/estimator/{estimator}"
    if column in ("vx", "vy", "yaw_rate", "beta"):
        return f"{base}/state/{column}"
    if column.startswith(("Cf_y", "Cr_y", "Cx")):
        return f"{base}/stiffness/{column}"
    if column.startswith("b_"):
        return f"{base}/bias/{column[2:]}"
    return f"{base}/{column}"  # ess, active


class RerunRecorder:
    """Writes one run to an .rrd file (headless)."""

    def __init__(self, path: str | Path, columns: tuple[str, ...], estimator: str | None, *,
                 application_id: str = "tirefilter", recording_id: str | None = None, chunk: int = 1000):
        import rerun as rr

        self._rr = rr
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.rec = rr.RecordingStream(application_id, recording_id=recording_id)
        self.rec.save(str(self.path))
        self.columns = tuple(columns)
        self._paths = [entity_path(c, estimator) for c in self.columns]
        self._t_index = self.columns.index("t")
        self._rows: list[np.ndarray] = []
        self._chunk = chunk
        self._xy: list[np.ndarray] = []
        self._ix = self.columns.index("true_x") if "true_x" in self.columns else None
        self._iy = self.columns.index("true_y") if "true_y" in self.columns else None

    def log_row(self, values) -> None:
        self._rows.append(np.asarray(values, dtype=float))
        if len(self._rows) >= self._chunk:
            self.flush()

    def flush(self) -> None:
        if not self._rows:
            return
        rr = self._rr
        data = np.vstack(self._rows)
        self._rows.clear()
        times = rr.TimeColumn(TIMELINE, duration=data[:, self._t_index])
        for j, path in enumerate(self._paths):
            if path is None:
                continue
            column = data[:, j]
            keep = ~np.isnan(column)
            if not keep.any():
                continue
            if keep.all():
                rr.send_columns(path, indexes=[times], columns=rr.Scalars.columns(scalars=column), recording=self.rec)
            else:
                rr.send_columns(path, indexes=[rr.TimeColumn(TIMELINE, duration=data[keep, self._t_index])],
                                columns=rr.Scalars.columns(scalars=column[keep]), recording=self.rec)
        if self._ix is not None and self._iy is not None:
            self._xy.append(data[:, [self._ix, self._iy]])

    def close(self) -> None:
        self.flush()
        if self._xy:
            path = np.vstack(self._xy)
            self.rec.log("/vehicle/path", self._rr.LineStrips2D([path]), static=True)
        self.rec.flush()
        self.rec.disconnect()
