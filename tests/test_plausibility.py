"""Plausibility warnings of check-log and of the start of replay: values a road car cannot
produce, each with its likely cause."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tirefilter.cli import main
from tirefilter.replay import check_log, write_log
from tirefilter.io.log import read_log
from tirefilter.replay.plausibility import Plausibility

VEHICLE = Path(__file__).resolve().parents[1] / "src/tirefilter/scenarios/data/vehicles/midsize-suv.toml"


def _drive(n=2000, **change):
    rng = np.random.default_rng(0)
    t = np.arange(n) * 0.01
    cols = {"t": t, "delta": 0.02 * np.sin(t), "ax": 0.1 * np.sin(3 * t) + 0.05 * rng.standard_normal(n),
            "ay": 2 * np.sin(t) + 0.05 * rng.standard_normal(n), "yaw_rate": 0.1 * np.sin(t) + 0.003 *
            rng.standard_normal(n), "vx": 20 + 0.1 * np.sin(t)}
    for k, f in change.items():
        cols[k] = f(cols[k])
    return cols


def _held(x, share=0.12, seed=1):
    x = x.copy()
    idx = np.flatnonzero(np.random.default_rng(seed).random(x.size) < share)
    idx = idx[idx > 0]
    for k in idx:
        x[k] = x[k - 1]
    return x


@pytest.mark.parametrize("change, expected", [
    (dict(vx=lambda x: 3.6 * 30 + 0 * x), "vx beyond 90 m/s in 2000 samples (largest 108 m/s"),
    (dict(delta=lambda x: np.degrees(x) * 20), "steering in degrees"),
    (dict(delta=lambda x: x * 40), "the steering-wheel angle instead of the road-wheel angle"),
    (dict(ay=lambda x: np.where(np.arange(x.size) == 500, 25.0, x)), "ay beyond 15 m/s^2 in 1 samples (largest 25 "
     "m/s^2 at t = 5 s, data row 501): spikes"),
    (dict(yaw_rate=lambda x: np.degrees(x) * 30), "yaw rate in deg/s"),
    (dict(ax=_held), "ax repeats its previous sample in 1"),
])
def test_each_warning_names_its_cause(tmp_path, change, expected):
    path = write_log(tmp_path / "log.csv", _drive(**change))
    warnings = check_log(path, VEHICLE).warnings
    assert any(expected in w for w in warnings), warnings


def test_a_plausible_drive_gets_none_and_chunks_add_up(tmp_path):
    path = write_log(tmp_path / "log.csv", _drive())
    assert check_log(path, VEHICLE).warnings == ()
    held = write_log(tmp_path / "held.csv", _drive(ay=lambda x: _held(x, 0.12)))
    whole = Plausibility()
    whole.add(read_log(held))
    from tirefilter.io.log import iter_log_chunks

    chunked = Plausibility()
    for chunk in iter_log_chunks(held, chunk_rows=7):
        chunked.add(chunk)
    assert chunked.repeats == whole.repeats and chunked.warnings() == whole.warnings()
    assert abs(whole.repeated_share("ay") - 0.12) < 0.03


def test_replay_warns_at_its_start(tmp_path, capsys):
    path = write_log(tmp_path / "log.csv", _drive(n=300, vx=lambda x: 3.6 * (x + 10)))  # km/h
    assert main(["replay", str(path), "--vehicle", str(VEHICLE), "--estimator", "kf", "--out",
                 str(tmp_path / "r.csv"), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert err.startswith("warning: vx beyond 90 m/s") and "km/h" in err
