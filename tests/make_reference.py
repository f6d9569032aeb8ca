"""Regenerate tests/data/reference_paper-sim.csv (only when the model changes on purpose):

    .venv/bin/python tests/make_reference.py

paper-sim, seed 7, FMI 2.0, every 10th sample of the truth and sensor columns.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tirefilter.cosim.run import run_scenario
from tirefilter.io.results import ESTIMATE_COLUMNS, INPUT_TRUTH_COLUMNS, truth_column
from tirefilter.cosim.fmu import VehicleFMU
from tirefilter.scenarios import load_scenario

REFERENCE = Path(__file__).parent / "data" / "reference_paper-sim.csv"
SEED, EVERY = 7, 10
COLUMNS = ("t", "meas_ax", "meas_ay", "meas_yaw_rate", "meas_omega_f", "meas_omega_r", "true_vx", "true_vy",
           "true_yaw_rate", "true_alpha_f", "true_alpha_r", "true_lambda_f", "true_lambda_r", "true_Cf_y",
           "true_Cr_y", "true_Cx", "true_Cf_y_mean", "true_x", "true_y", "true_psi", "true_delta",
           "true_drive_torque", "true_surface")


def reference_rows() -> np.ndarray:
    with VehicleFMU("2") as fmu:
        all_columns = ESTIMATE_COLUMNS + tuple(map(truth_column, fmu.output_names)) + INPUT_TRUTH_COLUMNS
        _, rows = run_scenario(load_scenario("paper-sim"), seed=SEED, fmu=fmu, keep_rows=True)
    return rows[::EVERY, [all_columns.index(c) for c in COLUMNS]]


if __name__ == "__main__":
    np.savetxt(REFERENCE, reference_rows(), delimiter=",", header=",".join(COLUMNS), comments="", fmt="%.15g")
    print(f"wrote {REFERENCE}")
