"""Drives from a vehicle model nobody here wrote: the CommonRoad vehicle models
(PyPI `commonroad-vehicle-models`, import `vehiclemodels`; Althoff and Wuersching,
"CommonRoad: Vehicle Models", TU Munich, 2020), as Log CSVs with reference columns and
a vehicle TOML of data-sheet values, for testing the estimators against a truth that is
not ours.

- `model`: the peer's models (single-track drift STD, multi-body MB) and parameter sets,
  what the log needs from their states (accelerations, wheel rates, true stiffness).
- `maneuvers`: steering and speed profiles (sine, sweep, steps, slalom, mixed).
- `sensors`: IMU white noise and biases, wheel-speed noise, logger dropouts.
- `drive`: integrate, sample at 100 Hz, write the Log CSV and the vehicle TOML.
- `two_track`, `two_track_drive`: a two-track model written here from the textbooks (four
  wheels, load transfer, load-sensitive Magic Formula tyres with relaxation), its drives.

`vehiclemodels` is an optional dependency (the `peer` extra): it is imported only when
a CommonRoad drive is generated, with a clear error when it is missing (the two-track
model needs only numpy).
"""

from tirefilter.errors import TirefilterError

INSTALL_HINT = "pip install 'tirefilter[peer]' (or pip install commonroad-vehicle-models)"


def require_vehiclemodels():
    """Import `vehiclemodels`, or raise a TirefilterError that says how to install it."""
    try:
        import vehiclemodels
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise TirefilterError(f"peer drives need the CommonRoad vehicle models: {INSTALL_HINT} ({exc})") from None
    return vehiclemodels
