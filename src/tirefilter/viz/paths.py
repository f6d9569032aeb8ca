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
    """Bands drawn around the estimate: `posterior_lower|upper` = param -+ 2 param_std,
    `spread_lower|upper` = param -+ 2 param_sigma."""
    return f"{estimator_root(estimator)}/stiffness/{param}/{which}"


def particles(estimator: str, what: str) -> str:
    """`stiffness` (per-particle stiffness means) or `state` (state particles)."""
    return f"{estimator_root(estimator)}/particles/{what}"


def density(estimator: str, param: str) -> str:
    return f"{estimator_root(estimator)}/density/{param}"


def density_history(estimator: str, param: str) -> str:
    """The density of every snapshot as an image (stiffness up, time to the right), static."""
    return f"{estimator_root(estimator)}/density_history/{param}"


def density_mass(estimator: str, param: str) -> str:
    """The exact probability of the density grid's range (scalar beside the density)."""
    return f"{density(estimator, param)}/mass"


def friction(estimator: str, axle: str, part: str | None = None) -> str:
    """The posterior-mean curve of an axle, or its `band` (+-2 std) / `visited` range."""
    base = f"{estimator_root(estimator)}/friction/{axle}"
    return base if part is None else f"{base}/{part}"


def truth_friction(axle: str) -> str:
    return f"/truth/friction/{axle}"


VEHICLE_BODY = "/vehicle/body"  # pose (transform per step), outline and heading arrow below it
VEHICLE_OUTLINE = "/vehicle/body/outline"
VEHICLE_HEADING = "/vehicle/body/heading"
VEHICLE_FRAME = "/vehicle/body/frame"  # a faint square around the car that the top view's camera follows
VEHICLE_STEER = "/vehicle/body/steer"  # front wheel: transform (lf, steer angle) and arrow
VEHICLE_TRAIL = "/vehicle/trail"  # one point per sample: the path up to the time cursor
VEHICLE_PATH = "/vehicle/path"  # the whole path, static, written at the end
