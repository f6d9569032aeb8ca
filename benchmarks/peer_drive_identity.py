"""The peer drives of tests/test_peer_drive.py, simulated and written as `tirefilter peer-drive`
writes them: per drive the CPU seconds of `simulate` and a SHA-256 of the Log CSV and the vehicle
TOML; then the steady turns of `test_steady_state_matches_linear_single_track` (X, U and the sampled
values). Run it with two trees' `PYTHONPATH` and compare the hashes (benchmarks/README.md, "Test
suite time: the peer drives (stop 26)"):

    .venv/bin/python benchmarks/peer_drive_identity.py
    PYTHONPATH=/tmp/base/src .venv/bin/python benchmarks/peer_drive_identity.py
"""

from __future__ import annotations

import hashlib
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import tirefilter
from tirefilter.peer.drive import RATE, SUBSTEPS, DriveSpec, integrate, simulate, steer_gain, write_drive
from tirefilter.peer.maneuvers import Profile
from tirefilter.peer.model import load_model

DRIVES = [  # the module fixture's two, the Cx test's, the camber test's, the command test's three
    DriveSpec(model="std", vehicle=2, maneuver="sine", duration=40.0, seed=1),
    DriveSpec(model="mb", vehicle=2, maneuver="sine", duration=40.0, seed=1),
    DriveSpec(model="std", vehicle=3, maneuver="mixed", duration=60.0, seed=21, speed=18.0),
    DriveSpec(model="mb", vehicle=2, maneuver="sine", duration=10.0, seed=1, camber="peer"),
    DriveSpec(model="std", vehicle=1, maneuver="steps", duration=10.0, seed=4),
    DriveSpec(model="std", vehicle=1, maneuver="steps", duration=10.0, seed=5),
]


def main() -> None:
    print(f"tirefilter from {Path(tirefilter.__file__).parent}", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        for i, spec in enumerate(DRIVES):
            t0 = time.process_time()
            drive = simulate(spec)
            cpu = time.process_time() - t0
            log, vehicle = write_drive(drive, Path(tmp) / f"{i}.csv", Path(tmp) / f"{i}.toml")
            digest = hashlib.sha256(log.read_bytes() + vehicle.read_bytes()).hexdigest()[:16]
            print(f"{spec.model} vehicle {spec.vehicle} {spec.maneuver} {spec.duration:g} s seed {spec.seed} "
                  f"camber {spec.camber}: simulate {cpu:.2f} CPU s, sha256 {digest}", flush=True)
    for kind, vehicle_id in (("std", 1), ("std", 2), ("mb", 2)):  # test_steady_state_matches_linear_single_track
        model = load_model(kind, vehicle_id)
        dt = 0.5 / (RATE * SUBSTEPS)
        t = np.arange(int(round(6.0 / dt)) + 1) * dt
        delta = steer_gain(model)(20.0) * (0.5 - 0.5 * np.cos(np.pi * np.clip(t / 2.0, 0.0, 1.0)))
        t0 = time.process_time()
        _, X, U = integrate(model, Profile(t, delta, np.gradient(delta, dt), np.full_like(t, 20.0), np.zeros_like(t)))
        cpu = time.process_time() - t0
        s = model.sample(X[-1], U[-1])
        digest = hashlib.sha256(X.tobytes() + U.tobytes() + repr([(k, float(v)) for k, v in sorted(s.items())]).encode()).hexdigest()[:16]
        print(f"steady turn {kind} vehicle {vehicle_id}: integrate {cpu:.2f} CPU s, sha256 {digest}", flush=True)


if __name__ == "__main__":
    sys.exit(main())
