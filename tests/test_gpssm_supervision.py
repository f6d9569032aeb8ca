"""The friction GP-SSM on a drive from a model we did not write (a CommonRoad peer drive with a
large a^Y offset): with its bias model it holds, also from the wheel speeds alone (no `vx`
column); without it the filter diverges as it did before the bias model, and the supervision
detects the divergence, reports it and starts the state again (docs/derivations.md, "F7. IMU
bias", "F8. v^X from the wheel speeds", "F9. Divergence: detection and recovery")."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("vehiclemodels")

from tirefilter.estimators import build_log_estimator  # noqa: E402
from tirefilter.estimators.gpssm.supervision import Checkpoints, DivergenceMonitor  # noqa: E402
from tirefilter.io.log import read_log  # noqa: E402
from tirefilter.peer.drive import DriveSpec, simulate, write_drive  # noqa: E402
from tirefilter.peer.sensors import SensorSpec  # noqa: E402
from tirefilter.replay import replay_log, result_columns  # noqa: E402
from tirefilter.vehicle.params import load_vehicle  # noqa: E402

pytestmark = pytest.mark.xdist_group("peer_drive")
FAST = {"basis": "axle", "particles": 100}  # the per-axle basis: a few seconds per replay


def _make_drive(folder, bias_scale: float):
    """40 s of the STD model, vehicle 2, 0.5 Hz sine at 20 m/s up to 4 m/s^2, the IMU offsets
    `bias_scale` times the defaults (a^Y offset 0.196 m/s^2 times it): the drive, its log, its
    log without the `vx` column, the data-sheet vehicle."""
    d = simulate(DriveSpec(model="std", vehicle=2, maneuver="sine", duration=40.0, seed=0, ay=4.0,
                           sensors=SensorSpec().scaled(bias=bias_scale)))
    log_path, vehicle_path = write_drive(d, folder / "drive.csv", folder / "vehicle.toml")
    lines = log_path.read_text().splitlines()
    keep = [i for i, c in enumerate(lines[0].split(",")) if c != "vx"]
    no_vx = folder / "drive-no-vx.csv"
    no_vx.write_text("\n".join(",".join(row.split(",")[i] for i in keep) for row in lines) + "\n")
    return d, log_path, no_vx, load_vehicle(vehicle_path)


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    """The peer drives' own IMU offsets (a^Y 0.196 m/s^2, within the MEMS prior's 0.3)."""
    return _make_drive(tmp_path_factory.mktemp("gpssm-peer"), 1.0)


@pytest.fixture(scope="module")
def drive_large_offset(tmp_path_factory):
    """Four times the offsets (a^Y 0.78 m/s^2): without a bias model v^Y runs off within 10 s."""
    return _make_drive(tmp_path_factory.mktemp("gpssm-peer-x4"), 4.0)


def _replay(path, vehicle, name, config):
    log = read_log(path, vehicle)
    est = build_log_estimator(name, vehicle, log.t, {s: log.signals[s] for s in log.available}, model="auto",
                              particles=None, config=config, source=log.path)
    summary, rows = replay_log(log, estimator=est, seed=0, keep_rows=True)
    return est, summary, dict(zip(result_columns(log), rows.T))


def _beta_err_deg(d, cols):
    return np.degrees(np.abs(cols["beta"] - d.columns["beta_true"]))


def test_the_bias_model_holds_the_drive_from_the_wheel_speeds_alone(drive):
    """Defaults of a replay (bias on with the MEMS prior, the prior curve's slope from the
    vehicle file), no `vx` column: v^X from the undriven wheels, no divergence, the a^Y offset
    learned, the sideslip close to the truth."""
    d, _, no_vx, vehicle = drive
    est, summary, cols = _replay(no_vx, vehicle, "gpssm", {"gpssm": FAST})
    assert est.vx_source == "wheels" and not est.divergences
    assert np.max(np.abs(cols["vx"] - d.columns["vx_true"])) < 0.15  # m/s; measured 0.048
    b_true = float(np.mean(d.columns["b_ay_true"][-500:]))
    assert abs(cols["b_ay"][-1] - b_true) < 0.005  # m/s^2 (offset 0.209); measured 0.0010
    rmse = math.sqrt(np.mean(_beta_err_deg(d, cols) ** 2))
    assert rmse < 0.02  # deg; measured 0.0065 (a zero-sideslip guess: 0.225)
    assert est.diagnostics()["symptom_max"]["clip"] == 0.0
    assert not summary.metrics["warnings"] or all("GP-SSM" not in w for w in summary.metrics["warnings"])


def test_without_the_bias_model_it_diverges_and_the_divergence_is_caught(drive_large_offset):
    """The bias model off (the filter before it): unsupervised, v^Y runs off at the rate of the
    a^Y offset; supervised, the divergence is detected, named with its time and symptom in
    the diagnostics and the run summary's warnings, and the particles start again, so that the
    sideslip error stays bounded."""
    d, log_path, _, vehicle = drive_large_offset
    off = dict(FAST, bias0_std=[0.0, 0.0], bias_rw=[0.0, 0.0])
    est, _, cols = _replay(log_path, vehicle, "gpssm", {"gpssm": dict(off, supervise=False)})
    free = _beta_err_deg(d, cols)
    assert np.max(free) > 40.0  # deg: diverged; measured 59
    est, summary, cols = _replay(log_path, vehicle, "gpssm", {"gpssm": off})
    div = est.diagnostics()["divergences"]
    assert div, "no divergence reported"
    first = div[0]
    assert first["cause"] in ("beta", "clip", "residual") and 0.0 < first["t_onset"] < first["t_detected"] < 40.0
    assert "restarted" in first["action"]
    warnings = [w for w in summary.metrics["warnings"] if w.startswith("friction GP-SSM diverged at t = ")]
    assert len(warnings) == len(div)
    supervised = _beta_err_deg(d, cols)
    # restarted each time the sideslip estimate has been beyond diverge_beta = 20 deg for 1 s: measured at most
    # 22.3 deg against 59; RMSE 12.7 against 39.4 deg
    assert np.max(supervised) < 30.0
    assert math.sqrt(np.mean(supervised**2)) < 0.5 * math.sqrt(np.mean(free**2))


def test_monitor_confirms_a_symptom_only_after_it_lasted():
    mon = DivergenceMonitor(clip_share=0.2, beta=0.35, nis=25.0, window=2.0, after=1.0)
    for k in range(30):  # healthy
        assert mon.observe(0.1 * k, 0.0, 0.01, 1.0) is None
    assert mon.healthy
    for k in range(30, 39):  # clipped for 0.8 s, then back
        assert mon.observe(0.1 * k, 0.5, 0.01, 1.0) is None
    assert mon.observe(3.9, 0.0, 0.01, 1.0) is None and mon.healthy
    found = None
    for k in range(40, 80):  # beta beyond 0.35 rad from t = 4.0 s
        found = found or mon.observe(0.1 * k, 0.0, 0.5, 1.0)
    assert found == ("beta", pytest.approx(4.0))
    mon.reset()
    hits = [mon.observe(0.1 * k, 0.0, 0.01, 100.0) for k in range(100)]  # residuals 10 sigma: smoothed over 2 s
    k = next(i for i, h in enumerate(hits) if h is not None)
    assert hits[k][0] == "residual" and 1.0 < 0.1 * k < 3.0


def test_checkpoints_keep_the_last_ones_and_give_the_one_before_a_time():
    ck = Checkpoints(every=5.0, keep=3)
    for t in np.arange(0.0, 30.0, 0.5):
        if ck.due(t):
            ck.add(t, f"stats at {t:g}")
    assert [t for t, _ in ck.items] == [15.0, 20.0, 25.0]
    assert ck.before(22.0) == (20.0, "stats at 20") and ck.before(15.0) is None
