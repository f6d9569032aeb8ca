"""Entity paths of the recordings (docs/design.md, "Rerun entity paths"; the table of docs/rerun.md).

One function per kind of entity so the recorder, the blueprint and the tests agree.
"""

from __future__ import annotations

TIMELINE = "sim_time"
STIFFNESS = ("Cf_y", "Cr_y", "Cx")  # Result-CSV names
SENSORS = ("ax", "ay", "yaw_rate")
STATES = ("vx", "vy", "yaw_rate", "beta")
AXLES = ("front", "rear")


def entity_path(column: str, estimator: str | None) -> str | None:
    """Entity path of a Result-CSV column (None for `t`, and for estimate columns
    without an estimator)."""
    if column == "t":
        return None
    if column.startswith("true_"):
        name = column[len("true_"):]
        if name in ("x", "y", "psi"):
            return f"/vehicle/{name}"
        return f"/truth/{name}"
    if column.startswith("meas_"):
        return f"/sensors/{column[len('meas_'):]}"
    if estimator is None:
        return None
    base = estimator_root(estimator)
    if column in STATES:
        return f"{base}/state/{column}"
    if column.startswith(STIFFNESS):
        return f"{base}/stiffness/{column}"
    if column.startswith("b_"):
        return f"{base}/bias/{column[2:]}"
    return f"{base}/{column}"  # ess, active


def estimator_root(estimator: str) -> str:
    return f"/estimator/{estimator}"


def stiffness_band(estimator: str, param: str, which: str) -> str:
    """Bands drawn around the estimate (90 %, Z90 = 1.645): `posterior_lower|upper` =
    param -+ Z90 param_std, `spread_lower|upper` = param -+ Z90 param_sigma."""
    return f"{estimator_root(estimator)}/stiffness/{param}/{which}"


def particles_root(estimator: str) -> str:
    """The clouds' views look from here: each cloud's transform (viz.clouds) applies below it."""
    return f"{estimator_root(estimator)}/particles"


def particles(estimator: str, what: str) -> str:
    """`stiffness` (per-particle stiffness means) or `state` (state particles)."""
    return f"{particles_root(estimator)}/{what}"


def particle_axes(estimator: str, what: str) -> str:
    """The axes, tick labels and weight colour scale drawn with a cloud, in its normalised frame."""
    return f"{particles_root(estimator)}/{what}_axes"


def density(estimator: str, param: str) -> str:
    return f"{estimator_root(estimator)}/density/{param}"


def density_mass(estimator: str, param: str) -> str:
    """The exact probability of the density window's range (scalar beside the density)."""
    return f"{density(estimator, param)}/mass"


def density_truth(estimator: str, param: str) -> str:
    """The true surface mean as one black bar in the density's view."""
    return f"{density(estimator, param)}/true_mean"


def density_quantile(estimator: str, param: str, which: str) -> str:
    """`q05`, `q95`: the 5 % and 95 % quantiles of the posterior density (scalars per snapshot)."""
    return f"{density(estimator, param)}/{which}"


def ess_line(estimator: str, which: str) -> str:
    """`particles` (N) and `threshold` (the ESS below which the filter resamples), beside the ESS."""
    return f"{estimator_root(estimator)}/ess/{which}"


def note(estimator: str, what: str) -> str:
    """A text note on the recording: `bias` (not estimated), `Cx` (not excited)."""
    return f"{estimator_root(estimator)}/notes/{what}"


def friction(estimator: str, axle: str, part: str | None = None) -> str:
    """The posterior-mean curve of an axle, or its `band` (90 %) / `visited` range."""
    base = f"{estimator_root(estimator)}/friction/{axle}"
    return base if part is None else f"{base}/{part}"


def truth_friction(axle: str) -> str:
    return f"/truth/friction/{axle}"


VEHICLE_BODY = "/vehicle/body"  # pose (transform per step), outline and heading arrow below it
VEHICLE_OUTLINE = "/vehicle/body/outline"
VEHICLE_SHAPE = "/vehicle/body/shape"  # the car's footprint, filled
VEHICLE_HEADING = "/vehicle/body/heading"
VEHICLE_STEER = "/vehicle/body/steer"  # front wheel: transform (lf, steer angle) and arrow
VEHICLE_VELOCITY = "/vehicle/body/velocity"  # true velocity direction per step (body frame), labelled with beta
VEHICLE_VELOCITY_ESTIMATE = "/vehicle/body/velocity_estimate"  # estimated velocity direction per step
VEHICLE_MARKER = "/vehicle/body/marker"  # the car as a dot of fixed screen size (the overview)
VEHICLE_POSITION = "/vehicle/position"  # the car's position without its heading (translation per step)
VEHICLE_FRAME = "/vehicle/position/frame"  # a faint square around the car that the close-up's camera follows
VEHICLE_CLOSE_SCALE = "/vehicle/position/scale"  # a 10 m scale bar beside the car
VEHICLE_TRAIL = "/vehicle/trail"  # one point per sample: the path up to the time cursor
VEHICLE_PATH = "/vehicle/path"  # the whole path, static, written at the end
VEHICLE_SCALE = "/vehicle/scale"  # the overview's scale bar, static, written at the end
