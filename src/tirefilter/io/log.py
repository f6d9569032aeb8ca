"""The Log CSV (replay input, docs/usage.md): its schema, the reader and its checks.

One row per sample, header names exactly: `t` [s], `delta` [rad, road-wheel] or
`steering_wheel_angle` [rad] (divided by the vehicle TOML's `steering_ratio`), `ax`, `ay`
[m/s^2], `yaw_rate` [rad/s], and `vx` [m/s] and/or `omega_f`, `omega_r` [rad/s]; optional
`omega_fl, omega_fr, omega_rl, omega_rr` (their axle means stand in for a missing
`omega_f` / `omega_r`; a corner sample missing makes the axle sample missing). Columns
named `<name>_true` or `true_<name>` are references (`Log.references`, under the name
`true_<name>`): carried into the results and scored, never given to an estimator. Other
extra columns are ignored. An empty or NaN cell is a missing sample; a `.gz` file is read
through gzip.

Rejected, with an error naming the file, column, data row (1-based, header not counted)
and file line, and the value: a missing required column, a cell that is not a number
(or is infinite), a missing or non-increasing time, a negative `vx` (reverse driving is
not supported; down to -VX_REVERSE_TOL is taken as standstill noise), an empty file.
Low speed is no error: the estimator's gate stops learning below its gate speed.
"""

from __future__ import annotations

import csv
import gzip
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tirefilter.errors import LogError

# What the estimators read from a log, in the order of the Result CSV's meas_ columns.
SIGNALS = ("delta", "ax", "ay", "yaw_rate", "vx", "omega_f", "omega_r")
REQUIRED = ("t", "ax", "ay", "yaw_rate")  # plus a steering and a speed column
STEERING = ("delta", "steering_wheel_angle")
CORNERS = {"omega_f": ("omega_fl", "omega_fr"), "omega_r": ("omega_rl", "omega_rr")}
COLUMNS = ("t", "delta", "steering_wheel_angle", "ax", "ay", "yaw_rate", "vx", "omega_f", "omega_r",
           "omega_fl", "omega_fr", "omega_rl", "omega_rr")  # the columns the reader knows
VX_REVERSE_TOL = 0.1  # m/s: vx below minus this is reverse driving


class Timed:
    """`rows` and `duration` of anything with its sample times `t` (n,)."""

    @property
    def rows(self) -> int:
        return len(self.t)

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])


@dataclass(frozen=True)
class Log(Timed):
    """A log as the estimators see it.

    `signals` holds the names of SIGNALS the file provides, directly or derived (`delta`
    from `steering_wheel_angle`, `omega_f`/`omega_r` from the corners; `derived` says how),
    each an (n,) float array with NaN for a missing sample. `columns` holds every known
    column as read from the file, `ignored` the file's other columns, `lines` the file
    line of each data row (for messages).
    """

    path: Path
    t: np.ndarray  # (n,) s, strictly increasing
    signals: dict[str, np.ndarray]
    columns: dict[str, np.ndarray]
    header: tuple[str, ...]
    ignored: tuple[str, ...] = ()
    derived: dict[str, str] = field(default_factory=dict)
    lines: np.ndarray | None = None  # (n,) int
    references: dict[str, np.ndarray] = field(default_factory=dict)  # true_<name> -> (n,), NaN where missing
    row0: int = 0  # data rows of the file before this one's first (a chunk of `iter_log_chunks`)

    @property
    def available(self) -> tuple[str, ...]:
        """The signals with at least one sample (in SIGNALS order)."""
        return tuple(s for s in SIGNALS if s in self.signals and np.isfinite(self.signals[s]).any())

    def signal(self, name: str) -> np.ndarray:
        """The signal `name`, all NaN when the log does not have it."""
        x = self.signals.get(name)
        return np.full(self.rows, math.nan) if x is None else x

    def where(self, k: int) -> dict:
        """LogError location of the 0-based data row k."""
        return {"row": self.row0 + k + 1, "line": int(self.lines[k]) if self.lines is not None else None}

    @property
    def present(self) -> tuple[str, ...]:
        """The SIGNALS the log has a column for (in SIGNALS order)."""
        return tuple(s for s in SIGNALS if s in self.signals)

    def chunks(self):
        """The log in chunks (`iter_log_chunks`); a Log in memory is its own one chunk."""
        return iter((self,))


def read_log(path: str | Path, vehicle=None, *, need_steering_ratio: bool = True, vehicle_name: str | None = None) -> Log:
    """Read and check a Log CSV (or .csv.gz).

    `vehicle` (VehicleParams, or the path of a vehicle TOML) gives the `steering_ratio` a
    log with only `steering_wheel_angle` needs; with `need_steering_ratio` False such a log
    is read without `delta` (check-log without a vehicle). `vehicle_name` names the
    vehicle in messages (default: its path, if given one).
    """
    return next(iter_log_chunks(path, vehicle, chunk_rows=None, need_steering_ratio=need_steering_ratio,
                                vehicle_name=vehicle_name))


CHUNK_ROWS = 2048  # rows per chunk of a streamed log (a chunk of text and its parsed columns held at a time)


def iter_log_chunks(path: str | Path, vehicle=None, *, chunk_rows: int | None = CHUNK_ROWS,
                    need_steering_ratio: bool = True, vehicle_name: str | None = None):
    """Read and check a Log CSV (or .csv.gz) `chunk_rows` data rows at a time (None: all
    at once), yielding one Log per chunk (`row0` its first data row's offset): the checks
    and errors of `read_log`, time increasing across chunks too; memory does not grow with
    the file. Each call reads the file again from its start, so a caller may make a first
    pass (a scan) and then a second (the replay)."""
    path = Path(path)
    vehicle, name = vehicle_arg(vehicle)
    vehicle_name = vehicle_name or name
    t_prev, row0 = None, 0
    for header, lines, cells in _iter_cells(path, chunk_rows):
        if row0 == 0:
            _check_columns(path, header)
        log = _chunk_log(path, header, lines, cells, vehicle, vehicle_name, need_steering_ratio, t_prev, row0)
        cells.clear()  # the chunk's text (most of its memory) goes now, not when the next chunk is read
        t_prev, row0 = float(log.t[-1]), row0 + log.rows
        yield log


def _chunk_log(path, header, lines, cells, vehicle, vehicle_name, need_steering_ratio, t_prev, row0) -> Log:
    columns = {name: _parse_column(path, name, cells[name], lines, row0) for name in COLUMNS if name in cells}
    t = columns["t"]
    _check_time(path, t, lines, t_prev, row0)

    signals = {name: columns[name] for name in SIGNALS if name in columns}
    derived = {}
    if "delta" not in columns:
        ratio = getattr(vehicle, "steering_ratio", None)
        if ratio is not None:
            signals["delta"] = columns["steering_wheel_angle"] / ratio
            derived["delta"] = f"steering_wheel_angle / steering_ratio ({ratio:g}, {vehicle_name})"
        elif need_steering_ratio:
            where = "a vehicle TOML (none given)" if vehicle is None else f"the vehicle TOML ({vehicle_name} has none)"
            raise LogError(path, f"the log has no 'delta', and converting the steering-wheel angle needs "
                           f"steering_ratio in {where}", column="steering_wheel_angle")
    for axle, (left, right) in CORNERS.items():
        if axle not in columns and left in columns and right in columns:
            signals[axle] = 0.5 * columns[left] + 0.5 * columns[right]  # (no overflow near the largest double)
            derived[axle] = f"mean of {left} and {right}"
    if "vx" in signals:
        bad = np.flatnonzero(signals["vx"] < -VX_REVERSE_TOL)
        if bad.size:
            k = int(bad[0])
            value = float(signals["vx"][k])
            raise LogError(path, f"vx = {value!r} m/s is negative: reverse driving is not supported "
                           f"(cut the log before t = {float(t[k])!r} s)", column="vx", row=row0 + k + 1,
                           line=int(lines[k]), value=value)
    signals = {name: signals[name] for name in SIGNALS if name in signals}
    references = {}
    for h in header:
        name = reference_name(h)
        if name is not None:
            if name in references:
                raise LogError(path, f"two reference columns of {name[len('true_'):]!r} ({name} and "
                               f"{name[len('true_'):]}_true)", column=h, line=1)
            references[name] = _parse_column(path, h, cells[h], lines, row0)
    ignored = tuple(c for c in header if c not in COLUMNS and reference_name(c) is None)
    return Log(path, t, signals, columns, header, ignored, derived, lines, references, row0)


def reference_name(column: str) -> str | None:
    """`true_<name>` for a reference column (`<name>_true` or `true_<name>`), else None."""
    if column.startswith("true_") and len(column) > len("true_"):
        return column
    if column.endswith("_true") and len(column) > len("_true"):
        return "true_" + column[: -len("_true")]
    return None


def vehicle_arg(vehicle) -> tuple:
    """(VehicleParams or None, how to name it in messages) from VehicleParams, a vehicle
    TOML path or None."""
    if vehicle is None:
        return None, None
    if isinstance(vehicle, (str, Path)):
        from tirefilter.vehicle.params import load_vehicle

        return load_vehicle(vehicle), str(vehicle)
    return vehicle, "the vehicle"


def _open(path: Path):
    if not path.is_file():
        raise LogError(path, "file not found")
    if path.suffix == ".gz":
        return gzip.open(path, "rt", encoding="utf-8-sig", newline="")
    return path.open(encoding="utf-8-sig", newline="")


def _iter_cells(path: Path, chunk_rows: int | None):
    """(header, the file line of each data row, the cells of the known columns) per chunk
    of `chunk_rows` data rows (None: one chunk)."""
    try:
        with _open(path) as f:
            reader = csv.reader(f)
            header = next(reader, None)
            if not header or not any(h.strip() for h in header):
                raise LogError(path, "empty file: expected a header line (t, delta, ax, ay, yaw_rate, vx, ...)", line=1)
            header = tuple(h.strip() for h in header)
            dupes = sorted({h for h in header if header.count(h) > 1})
            if dupes:
                raise LogError(path, f"the header names column {dupes[0]!r} more than once", column=dupes[0], line=1)
            known = [(j, h) for j, h in enumerate(header) if h in COLUMNS or reference_name(h) is not None]
            cells: dict[str, list[str]] = {h: [] for _, h in known}
            lines: list[int] = []
            before = 0  # data rows in the chunks already handed out
            for row in reader:
                if not row or (len(row) == 1 and not row[0].strip()):
                    continue  # blank line
                if len(row) != len(header):
                    raise LogError(path, f"{len(row)} cells for the header's {len(header)} columns",
                                   row=before + len(lines) + 1, line=reader.line_num)
                lines.append(reader.line_num)
                for j, h in known:
                    cells[h].append(row[j])
                if chunk_rows is not None and len(lines) >= chunk_rows:
                    yield header, np.asarray(lines), cells
                    before += len(lines)
                    cells, lines = {h: [] for _, h in known}, []
            if lines:
                yield header, np.asarray(lines), cells
            elif not before:
                raise LogError(path, "no data rows after the header", line=2)
    except (OSError, EOFError, UnicodeDecodeError, csv.Error) as exc:
        raise LogError(path, f"cannot be read as a CSV file ({type(exc).__name__}: {exc})") from None


def _check_columns(path: Path, header: tuple[str, ...]) -> None:
    have = set(header)
    missing = [f"'{c}'" for c in REQUIRED if c not in have]
    if not have & set(STEERING):
        missing.append("'delta' (or 'steering_wheel_angle')")
    wheels = all(a in have or set(CORNERS[a]) <= have for a in CORNERS)
    if "vx" not in have and not wheels:
        missing.append("'vx' and/or 'omega_f', 'omega_r' (or 'omega_fl', 'omega_fr', 'omega_rl', 'omega_rr')")
    if missing:
        hint = " (is it separated by ';'? The Log CSV uses ',')" if len(header) == 1 and ";" in header[0] else ""
        raise LogError(path, f"missing required column{'s' if len(missing) > 1 else ''} {', '.join(missing)}; "
                       f"the file has: {', '.join(header)}{hint}")


def _parse_column(path: Path, name: str, cells: list[str], lines: np.ndarray, row0: int = 0) -> np.ndarray:
    """Floats from cells; an empty cell (or 'nan') is NaN; anything else non-numeric or an
    infinity is an error naming the cell."""
    try:
        x = np.array([float(c or "nan") for c in cells])
    except ValueError:
        x = np.empty(len(cells))
        for k, c in enumerate(cells):
            try:
                x[k] = float(c) if c.strip() else math.nan
            except ValueError:
                raise LogError(path, f"{c!r} is not a number", column=name, row=row0 + k + 1,
                               line=int(lines[k]), value=c) from None
    inf = np.flatnonzero(np.isinf(x))
    if inf.size:
        k = int(inf[0])
        raise LogError(path, f"{cells[k]!r} is not a finite number", column=name, row=row0 + k + 1,
                       line=int(lines[k]), value=cells[k])
    return x


def _check_time(path: Path, t: np.ndarray, lines: np.ndarray, t_prev: float | None = None, row0: int = 0) -> None:
    missing = np.flatnonzero(np.isnan(t))
    if missing.size:
        k = int(missing[0])
        raise LogError(path, "missing time (every row needs t)", column="t", row=row0 + k + 1, line=int(lines[k]),
                       value=None)
    if t_prev is not None and not t[0] > t_prev:  # across the chunk boundary
        raise LogError(path, f"time must increase strictly: t = {float(t[0])!r} s after t = {t_prev!r} s in data row "
                       f"{row0}", column="t", row=row0 + 1, line=int(lines[0]), value=float(t[0]))
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        raise LogError(path, f"time must increase strictly: t = {float(t[k])!r} s after t = {float(t[k - 1])!r} s in data row {row0 + k}",
                       column="t", row=row0 + k + 1, line=int(lines[k]), value=float(t[k]))


def write_log(path: str | Path, columns: dict[str, np.ndarray]) -> Path:
    """Write a Log CSV (gzip-compressed when the name ends in .gz): one column per item,
    in order, values as `repr` (they read back exactly), NaN as an empty cell."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    names = list(columns)
    data = np.column_stack([np.asarray(columns[n], float) for n in names])
    text = "\n".join(",".join("" if x != x else repr(x) for x in row) for row in data.tolist())
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "wt", newline="") as f:
        f.write(",".join(names) + "\n" + text + "\n")
    return path
