"""Golden masters of the estimators' outputs: what the product computes today, end to end.

Each case runs one command of the `tirefilter` CLI in-process, exactly as a user would, and
keeps the estimate columns of its Result CSV (and the friction CSV where there is one):

    paper-sim      tirefilter run --scenario paper-sim --seed 0            (the MPF, README's run)
    snow-sine      tirefilter run --scenario snow-sine --seed 0            (the MPF with IMU bias)
    friction-snow  tirefilter run --scenario friction-snow --estimator gpssm --seed 0
    replay-gaps    tirefilter replay LOG --vehicle VEHICLE.toml --seed 0   (default replay: bias,
                   calibration, wheel filter) over a 30 s peer drive (CommonRoad single-track
                   model, sine steer, seed 3) with dropped rows, blank cells and a 1 s gap

Commands (run from the repository root):

    .venv/bin/python tests/golden.py --hash    # sha256 of each case's full output: refactors
                                               # that must not change a bit compare these
    .venv/bin/python tests/golden.py --check   # compare with the committed masters (1e-9)
    .venv/bin/python tests/golden.py --write   # rewrite tests/data/golden/ (only when an
                                               # output changes on purpose: say why in the commit)
    .venv/bin/python tests/golden.py --hash --backend numba   # the MPF's cases on its numba
                                               # backend: the same hashes as the default C core's

The committed masters keep every EVERY-th row with all estimate columns in `repr` precision,
so they stay small while any change of the filter shows within a few steps. tests/test_golden.py
compares each case with its master to a relative tolerance of 1e-9: bit-identical on one
machine. Across CPUs it is not a safe margin for paper-sim: resampling amplifies a rounding
difference about tenfold every 5 s of that run (1e-12 at 10 s, 1e-9 at 23 s), so on a machine
whose compiled kernels round differently the masters are rewritten there, not loosened.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

GOLDEN_DIR = Path(__file__).parent / "data" / "golden"
EVERY = 20  # rows kept in the committed masters
FRICTION_EVERY = 8  # of the friction snapshots' grid rows
RTOL = 1e-9
ATOL = 1e-12

ESTIMATE_COLUMNS = (
    "t", "active", "vx", "vy", "yaw_rate", "beta",
    "Cf_y", "Cr_y", "Cx", "Cf_y_std", "Cr_y_std", "Cx_std", "Cf_y_sigma", "Cr_y_sigma", "Cx_sigma",
    "b_ax", "b_ay", "b_yaw_rate", "ess",
)
CASES = ("paper-sim", "snow-sine", "friction-snow", "replay-gaps")


def _cli(argv: list[str]) -> str:
    """Run the CLI in-process; return what it printed (raise if it failed)."""
    from tirefilter.cli import main

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main(argv)
    if code != 0:
        raise RuntimeError(f"tirefilter {' '.join(argv)} exited {code}:\n{out.getvalue()}")
    return out.getvalue()


def _gap_log(directory: Path) -> tuple[Path, Path]:
    """A peer drive with the faults a logger makes: single dropped rows, blank cells, a 1 s gap."""
    from tirefilter.peer.drive import DriveSpec, simulate, vehicle_toml
    from tirefilter.io.log import write_log

    drive = simulate(DriveSpec(model="std", maneuver="sine", duration=30.0, seed=3))
    columns = {name: np.array(values, dtype=float) for name, values in drive.columns.items()}
    keep = np.ones(len(columns["t"]), dtype=bool)
    keep[[250, 251, 1700, 2333]] = False  # single dropped rows
    keep[(columns["t"] >= 12.0) & (columns["t"] < 13.0)] = False  # a 1 s logger dropout
    for name, rows in (("ay", [400, 401, 2100]), ("yaw_rate", [900, 2500]), ("ax", [1500]),
                       ("omega_f", [1800]), ("vx", [2200]), ("delta", [2600])):
        columns[name][rows] = np.nan  # blank cells: missing samples
    vehicle = directory / "peer.toml"
    vehicle.write_text(vehicle_toml(drive))
    return write_log(directory / "peer.csv", {k: v[keep] for k, v in columns.items()}), vehicle


def run_case(name: str, directory: Path, printed: list[str] | None = None,
             backend: str | None = None) -> dict[str, np.ndarray]:
    """Run one case in `directory`; return its outputs as {file: 2-D array of the kept columns}
    (and append what the command printed to `printed`, when given). `backend`: the MPF's backend
    (an [mpf] table passed with --config; None: the default; the GP-SSM case ignores it)."""
    directory = Path(directory)
    config = []
    if backend is not None and name != "friction-snow":
        (directory / "backend.toml").write_text(f'[mpf]\nbackend = "{backend}"\n')
        config = ["--config", str(directory / "backend.toml")]
    if name == "replay-gaps":
        log, vehicle = _gap_log(directory)
        result = directory / "result.csv"
        text = _cli(["replay", str(log), "--vehicle", str(vehicle), "--seed", "0", "--out", str(result), "--quiet",
                     *config])
        if printed is not None:
            printed.append(text)
        return {"results": _estimates(result)}
    argv = ["run", "--scenario", name, "--seed", "0", "--out", str(directory), "--quiet", *config]
    if name == "friction-snow":
        argv[3:3] = ["--estimator", "gpssm"]
    text = _cli(argv)
    if printed is not None:
        printed.append(text)
    outputs = {"results": _estimates(directory / "results.csv")}
    if (directory / "friction.csv").exists():
        outputs["friction"] = np.loadtxt(directory / "friction.csv", delimiter=",", skiprows=1, ndmin=2)
    return outputs


def _estimates(path: Path) -> np.ndarray:
    header = path.open().readline().strip().split(",")
    rows = np.genfromtxt(path, delimiter=",", skip_header=1, ndmin=2)
    return rows[:, [header.index(c) for c in ESTIMATE_COLUMNS]]


def digest(outputs: dict[str, np.ndarray]) -> str:
    h = hashlib.sha256()
    for key in sorted(outputs):
        h.update(key.encode())
        h.update(np.ascontiguousarray(outputs[key], dtype=np.float64).tobytes())
    return h.hexdigest()


def master_path(name: str, key: str) -> Path:
    return GOLDEN_DIR / f"{name}.{key}.csv"


def thin(key: str, values: np.ndarray) -> np.ndarray:
    """The rows a master keeps: every EVERY-th estimate row (and the last); every FRICTION_EVERY-th
    row of the friction snapshots (t, alpha, mu_f, mu_f_std, mu_r, mu_r_std; the truth columns are
    the FMU's, not the estimator's)."""
    if key != "results":
        return values[::FRICTION_EVERY, :6]
    return values[thin_index(len(values))]


def thin_index(rows: int) -> np.ndarray:
    return np.unique(np.r_[np.arange(0, rows, EVERY), rows - 1])


def write_master(name: str, outputs: dict[str, np.ndarray]) -> list[Path]:
    GOLDEN_DIR.mkdir(parents=True, exist_ok=True)
    paths = []
    for key, values in outputs.items():
        path = master_path(name, key)
        rows = thin(key, values)
        with path.open("w") as f:
            f.write(f"# golden master of tests/golden.py case {name} ({key}); rows kept: "
                    f"{'every ' + str(EVERY) + 'th and the last' if key == 'results' else 'every ' + str(FRICTION_EVERY) + 'th'}; "
                    f"{len(values)} rows in the run\n")
            for row in rows:
                f.write(",".join("" if np.isnan(v) else repr(float(v)) for v in row) + "\n")
        paths.append(path)
    return paths


def read_master(name: str, key: str) -> tuple[np.ndarray, int]:
    path = master_path(name, key)
    with path.open() as f:
        first = f.readline()
    total = int(first.rsplit(";", 1)[1].split()[0])
    return np.genfromtxt(path, delimiter=",", comments="#", ndmin=2), total


def compare(name: str, outputs: dict[str, np.ndarray]) -> list[str]:
    """Differences between a case's outputs and its master (empty: equal to RTOL)."""
    problems = []
    for key, values in outputs.items():
        if not master_path(name, key).exists():
            problems.append(f"{name}: no master for {key} ({master_path(name, key)})")
            continue
        master, total = read_master(name, key)
        if len(values) != total:
            problems.append(f"{name}.{key}: {len(values)} rows, the master's run had {total}")
            continue
        got = thin(key, values)
        if got.shape != master.shape:
            problems.append(f"{name}.{key}: shape {got.shape}, master {master.shape}")
            continue
        same_nan = np.isnan(got) == np.isnan(master)
        close = np.isclose(got, master, rtol=RTOL, atol=ATOL) | (np.isnan(got) & np.isnan(master))
        bad = ~(close & same_nan)
        if bad.any():
            i, j = np.argwhere(bad)[0]
            columns = ESTIMATE_COLUMNS if key == "results" else ("t", "alpha", "mu_f", "mu_f_std", "mu_r", "mu_r_std")
            problems.append(f"{name}.{key}: {int(bad.sum())} values differ; first at kept row {i} (t = "
                            f"{got[i, 0]:.2f} s), {columns[j]}: {got[i, j]!r} != master {master[i, j]!r}")
    return problems


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("--hash", action="store_true", help="print the sha256 of each case's full output")
    mode.add_argument("--check", action="store_true", help="compare each case with its committed master")
    mode.add_argument("--write", action="store_true", help="rewrite the committed masters")
    parser.add_argument("cases", nargs="*", default=list(CASES), help=f"cases (default: all of {', '.join(CASES)})")
    parser.add_argument("--backend", choices=["numba", "c", "numpy"], help="the MPF's backend (default: its default)")
    args = parser.parse_args(argv)
    failed = False
    for name in args.cases:
        with tempfile.TemporaryDirectory() as tmp:
            outputs = run_case(name, Path(tmp), backend=args.backend)
        if args.hash:
            print(f"{name:14s} {digest(outputs)}")
        elif args.write:
            for path in write_master(name, outputs):
                print(f"wrote {path.relative_to(Path.cwd()) if path.is_relative_to(Path.cwd()) else path}")
        else:
            problems = compare(name, outputs)
            failed |= bool(problems)
            print(f"{name:14s} " + ("equal to its master" if not problems else "\n  ".join(["DIFFERS"] + problems)))
    return 1 if failed else 0


if __name__ == "__main__":
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    sys.exit(main())
