"""Pure model maths: parameters, slip, tire forces, single-track dynamics, measurement map.

Everything here is batch-first numpy: states have shape (..., nx) and the leading axes
are particles and Monte-Carlo trials.
"""

from tirefilter.vehicle.params import PacejkaParams, SensorSpec, VehicleParams, load_vehicle
from tirefilter.vehicle.single_track import TruthModel, derivatives, rk4_step, slip_angles, wheel_slip
from tirefilter.vehicle.tires import magic_formula

__all__ = [
    "PacejkaParams",
    "SensorSpec",
    "TruthModel",
    "VehicleParams",
    "derivatives",
    "load_vehicle",
    "magic_formula",
    "rk4_step",
    "slip_angles",
    "wheel_slip",
]
