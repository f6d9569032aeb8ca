"""tirefilter: online estimation of tire stiffness, tire friction and vehicle state from
production-car sensors, co-simulated against a vehicle FMU."""

__version__ = "0.1.0"
