"""Pure model maths: parameters, slip, tire forces, single-track dynamics, measurement map.

Everything here is batch-first numpy: states have shape (..., nx) and the leading axes
are particles and Monte-Carlo trials.
"""

from tirefilter.vehicle.params import PacejkaParams, SensorSpec, VehicleParams, load_vehicle
from tirefilter.vehicle.single_track import (TruthModel, accelerations, derivatives, floored_wheel_slip,
                                             longitudinal_stiffness, measurement, model_params, propagate, rk4_step,
                                             slip_angles, slip_over_step, small_slip_angles, state_derivative,
                                             vx_from_wheels, wheel_slip)
from tirefilter.vehicle.tires import magic_formula

__all__ = [
    "PacejkaParams",
    "SensorSpec",
    "TruthModel",
    "VehicleParams",
    "accelerations",
    "derivatives",
    "floored_wheel_slip",
    "load_vehicle",
    "longitudinal_stiffness",
    "magic_formula",
    "measurement",
    "model_params",
    "propagate",
    "rk4_step",
    "slip_angles",
    "slip_over_step",
    "small_slip_angles",
    "state_derivative",
    "vx_from_wheels",
    "wheel_slip",
]
