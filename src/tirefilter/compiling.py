"""The one-time compile of the numba kernels, watched: announced when it starts and timed
apart from the run (docs/performance.md, "The first run").

The estimators' kernels are compiled on their first call and cached beside the sources
(`cache=True`), so the first run of this code on a machine spends 20-60 s compiling inside
its first steps, and later runs load the cache in a fraction of a second. numba reports
each compile as a "numba:compile" event (a cache hit is none); `CompileWatch` listens to
them while it is entered and adds up the time of the outermost ones (a kernel compiles
the kernels it calls inside its own event).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable

ANNOUNCEMENT = ("compiling the estimator's numba kernels: once for this code on this machine, cached beside the "
                "sources for later runs (20-60 s) ...")


class CompileWatch:
    """Context manager: `seconds` of numba compiling (outermost compiles) and `kernels`
    (their number) while entered; `announce(ANNOUNCEMENT)` is called when the first
    compile starts (None: silent). It listens only where numba is imported when it is entered
    (the run after the estimator was built, which imports the kernels' modules and compiles none):
    without numba it counts nothing."""

    def __init__(self, announce: Callable[[str], None] | None = None):
        self.announce = announce
        self.seconds = 0.0
        self.kernels = 0
        self._depth = 0
        self._start = 0.0
        self._listener = None
        self._installed = None

    def __enter__(self) -> CompileWatch:
        if "numba" not in sys.modules:  # nothing to watch: an estimator without kernels does not import numba
            return self  # (some 110 MB resident), and one with them has imported it when it was built
        from numba.core import event
        watch = self

        class Listener(event.Listener):
            def on_start(self, ev) -> None:
                watch._started()

            def on_end(self, ev) -> None:
                watch._ended()

        self._listener = Listener()
        self._installed = event.install_listener("numba:compile", self._listener)
        self._installed.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        if self._installed is not None:
            self._installed.__exit__(*exc)
            self._installed = None

    def _started(self) -> None:
        self._depth += 1
        if self._depth == 1:
            if self.kernels == 0 and self.announce is not None:
                self.announce(ANNOUNCEMENT)
            self._start = time.perf_counter()

    def _ended(self) -> None:
        self._depth -= 1
        if self._depth == 0:
            self.seconds += time.perf_counter() - self._start
            self.kernels += 1
