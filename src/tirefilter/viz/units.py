"""Units of the recorded values (docs/rerun.md, "Units").

The Result CSV is SI (N/rad, rad); a recording shows what an engineer reads: stiffness in
kN/rad (lateral) and kN per unit slip (Cx, longitudinal), the sideslip and slip angles in
degrees. `scale(column)` is the factor from the CSV's value to the recorded one; every
other column is recorded as it is (m/s, rad/s, m/s^2, rad for the steer angle).
"""

from __future__ import annotations

import math
import re

KILO = 1e-3  # N -> kN
DEG = 180.0 / math.pi  # rad -> deg

_STIFFNESS = re.compile(r"^(true_)?(Cf_y|Cr_y|Cx|Cf_x|Cr_x)(_std|_sigma|_mean)?$")
_DEGREES = {"beta", "true_beta", "true_alpha_f", "true_alpha_r"}
UNITS = {"Cf_y": "kN/rad", "Cr_y": "kN/rad", "Cx": "kN/unit slip", "Cf_x": "kN/unit slip", "Cr_x": "kN/unit slip",
         "vx": "m/s", "vy": "m/s", "yaw_rate": "rad/s", "beta": "deg", "ax": "m/s²", "ay": "m/s²", "delta": "rad"}


def scale(column: str) -> float:
    """Factor from a Result-CSV column's SI value to its recorded value."""
    if _STIFFNESS.match(column):
        return KILO
    if column in _DEGREES:
        return DEG
    return 1.0


def unit(name: str) -> str:
    """The recorded unit of a stiffness parameter, state or sensor channel (`Cx`, `vy`,
    `ay`, ...), as the views' titles give it."""
    return UNITS[name]
