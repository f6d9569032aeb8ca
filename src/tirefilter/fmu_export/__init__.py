"""The estimator (and a scenario driver) exported as Co-Simulation FMUs, FMI 2.0 with
pythonfmu and FMI 3.0 with pythonfmu3 (same slave code), and an SSP that wires driver ->
vehicle FMU -> estimator FMU. docs/using-the-fmus.md is the user's guide.

- `slaves.py`: the FMU classes (`EstimatorSlave`, `DriverSlave`; `...3` for FMI 3.0);
- `state.py`: the serialised FMU state (restricted unpickling);
- `build.py`: building the FMUs into the build folder (`fmu/build/` in a checkout;
  `tirefilter fmu build estimator`);
- `ssp.py`: the SSP of a scenario and running it with `fmpy.ssp.simulation.simulate_ssp`;
- `host.py`: a small FMI host for the Python FMUs (tests, benchmarks);
- `release.py`: unloading a Python FMU from a Python process without corrupting the heap at exit.

The Python FMUs need Python and packages on the target machine: `REQUIREMENTS` says
which, and the FMUs print it when they cannot load.
"""

REQUIREMENTS = """\
The tirefilter Python FMUs run Python code inside the importing tool's process (FMI 2.0:
pythonfmu 0.7, FMI 3.0: pythonfmu3 0.3; either ships inside its FMU).
The target machine needs:
  - CPython >= 3.11, 64-bit (Linux x86_64 or Windows x64), the same interpreter for every
    Python FMU in one process;
  - the packages numpy (>= 1.26, < 3) and scipy (>= 1.11, < 2) importable by that
    interpreter; rerun-sdk (>= 0.41, < 0.42) only when the parameter `rrd` is set;
    numba (>= 0.61) only when the `config` parameter sets `backend = "numba"` in its [mpf]
    or [gpssm] table (compiled kernels, 3-4x faster steps; the first instantiation in a
    fresh unpacking compiles them, 10-30 s); a C compiler only when it sets `backend = "c"`
    in its [mpf] table (the MPF's C core, built into the user's cache on first use, ~10 s).
    The tirefilter package itself ships inside the FMU (resources/tirefilter).
  - Linux binaries: x86_64 (FMI 2.0: binaries/linux64, FMI 3.0: binaries/x86_64-linux).
How to provide them:
  - from a Python tool (fmpy, ...): run the tool with that interpreter (e.g. the venv with
    `pip install numpy scipy`);
  - from a native tool on Linux: the FMU binary does not link libpython; preload it and
    point Python at the packages, e.g.
      LD_PRELOAD=/usr/lib/x86_64-linux-gnu/libpython3.11.so.1.0 \\
      PYTHONHOME=/usr PYTHONPATH=/path/to/venv/lib/python3.11/site-packages  <tool> ...
  - on Windows: python3X.dll of a matching CPython on PATH and PYTHONPATH as above.
"""
