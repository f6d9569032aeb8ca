"""Accuracy figures of the tests, checked against their bounds and recorded.

An accuracy test states each figure it measures (an error, an RMSE, a settling time) with its
bound through `within`, which asserts it and, where the environment variable
`TIREFILTER_FIGURES` names a file, appends one JSON line to it: the test, the figure's name, the
value, the bound. `tools/bounds.py` runs the accuracy tests that way and prints every figure
beside its bound, so that how tight each bound is against today's figure is printed, not only
claimed in a comment. The bounds' rule (docs/development.md, "Accuracy bounds"): at most about
3x the figure measured when the bound was set, or the spread over seeds where the figure is
stochastic; a wider bound says why (`wide`).
"""

from __future__ import annotations

import json
import math
import os

ENV = "TIREFILTER_FIGURES"


def within(name: str, value: float, bound: float, *, lower: float | None = None, wide: str = "") -> None:
    """Assert `lower <= value <= bound` (`lower` None: `value <= bound`) and record the figure.

    `name` says what was measured, with its unit ("Cf_y mean abs error %"); `wide` says why a
    bound is wider than about 3x the figure where it is (a stated exception). A NaN value fails.
    """
    value = float(value)
    ok = value <= bound and (lower is None or value >= lower)
    path = os.environ.get(ENV)
    if path:
        test = os.environ.get("PYTEST_CURRENT_TEST", "?").rsplit(" (", 1)[0]
        record = {"test": test, "figure": name, "value": value if math.isfinite(value) else None,
                  "bound": bound, "lower": lower, "wide": wide, "ok": ok}
        with open(path, "a", encoding="utf-8") as f:  # one short line per write: appends from xdist workers stay whole
            f.write(json.dumps(record) + "\n")
    span = f"[{lower:g}, {bound:g}]" if lower is not None else f"<= {bound:g}"
    assert ok, f"{name}: {value:.6g}, bound {span}"
