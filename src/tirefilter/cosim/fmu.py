"""The vehicle FMU seen from Python: load once, reset between trials, step fast.

fmpy loads the FMU and performs the calls; the hot path (set inputs, doStep, get outputs)
calls the FMI functions with preallocated ctypes buffers so one communication step costs
a few microseconds of Python.
"""

from __future__ import annotations

import ctypes
import shutil
from pathlib import Path

import numpy as np

from tirefilter.errors import FMUError
from tirefilter.vehicle_fmu import build

REPO_ROOT = Path(__file__).resolve().parents[3]  # the checkout's root, when running from one
BUILD_DIR = build.DEFAULT_OUT  # fmu/build/ in a checkout, else $TIREFILTER_FMU_DIR or the user cache
INPUT_NAMES = ("delta", "drive_torque", "brake_torque", "surface", "bank")


def variable_table():
    return build.load_table()


def vehicle_fmu_path(fmi_version: str = "2", build_dir: Path = BUILD_DIR) -> Path:
    return build.fmu_path(build_dir, fmi_version)


def build_vehicle_fmu(build_dir: Path = BUILD_DIR, versions=("2", "3")) -> dict[str, Path]:
    try:
        return build.build_vehicle(build_dir, tuple(versions))
    except build.BuildError as exc:
        raise FMUError(str(exc)) from None


def _check(status: int, what: str) -> None:
    """The raw FMI calls return a status: OK 0, warning 1, discard 2, error 3, fatal 4."""
    if status > 1:
        raise RuntimeError(f"{what} returned FMI status {status}")


class VehicleFMU:
    """One instance of the vehicle FMU (FMI 2.0 or 3.0 Co-Simulation).

    `reset(parameters)` (re)initialises it for a run; `step(t, h, inputs)` sets the five
    inputs, does one communication step and returns the output vector (a view into a
    buffer, ordered as `output_names`, valid until the next step).
    """

    def __init__(self, fmi_version: str = "2", path: str | Path | None = None):
        from fmpy import extract, read_model_description

        self.fmi_version = str(fmi_version)
        if self.fmi_version not in ("2", "3"):
            raise FMUError(f"fmi_version must be '2' or '3', got {fmi_version!r}")
        self.path = Path(path) if path else vehicle_fmu_path(self.fmi_version)
        if not self.path.is_file():
            raise FMUError(
                f"vehicle FMU not found at {self.path}; build it with `tirefilter fmu build vehicle`"
            )
        self.model_description = read_model_description(str(self.path))
        self._unzip_dir = extract(str(self.path))
        self.messages: list[str] = []
        variables = {v.name: v for v in self.model_description.modelVariables}
        self.output_names = tuple(v.name for v in self.model_description.modelVariables if v.causality == "output")
        self._vars = variables
        self._in_vr = (ctypes.c_uint32 * len(INPUT_NAMES))(*[variables[n].valueReference for n in INPUT_NAMES])
        self._out_vr = (ctypes.c_uint32 * len(self.output_names))(*[variables[n].valueReference for n in self.output_names])
        self._in_buf = np.zeros(len(INPUT_NAMES))
        self._out_buf = np.zeros(len(self.output_names))
        self._in_ptr = self._in_buf.ctypes.data_as(ctypes.POINTER(ctypes.c_double))
        self._out_ptr = self._out_buf.ctypes.data_as(ctypes.POINTER(ctypes.c_double))
        self._slave = self._instantiate()
        self._initialized = False

    # -- setup ------------------------------------------------------------------------
    def _log(self, status, message) -> None:
        text = message.decode("utf-8", "replace") if isinstance(message, bytes) else str(message)
        self.messages.append(text)

    def _instantiate(self):
        md = self.model_description
        common = dict(guid=md.guid, unzipDirectory=self._unzip_dir, modelIdentifier=md.coSimulation.modelIdentifier,
                      instanceName="vehicle")
        if self.fmi_version == "2":
            from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                                   fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
            from fmpy.fmi2 import calloc, free

            slave = FMU2Slave(**common)
            callbacks = fmi2CallbackFunctions()
            callbacks.logger = fmi2CallbackLoggerTYPE(lambda env, name, status, cat, msg: self._log(status, msg))
            callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
            callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
            try:
                from fmpy.logging import addLoggerProxy

                addLoggerProxy(ctypes.byref(callbacks))
            except Exception:  # pragma: no cover - proxy missing on exotic platforms
                pass
            self._callbacks = callbacks
            slave.instantiate(callbacks=callbacks)
            self._set_real = slave._functions["fmi2SetReal"]
            self._get_real = slave._functions["fmi2GetReal"]
            self._do_step_raw = slave._functions["fmi2DoStep"]
        else:
            from fmpy.fmi3 import FMU3Slave

            slave = FMU3Slave(**common)
            slave.instantiate(logMessage=lambda env, status, cat, msg: self._log(status, msg))
            self._set_real = slave._functions["fmi3SetFloat64"]
            self._get_real = slave._functions["fmi3GetFloat64"]
            self._do_step_raw = slave._functions["fmi3DoStep"]
            self._flags = [ctypes.c_bool() for _ in range(3)]
            self._last_time = ctypes.c_double()
            self._step_refs = (*(ctypes.byref(f) for f in self._flags), ctypes.byref(self._last_time))
        return slave

    def reset(self, parameters: dict[str, float | int], start_time: float = 0.0) -> None:
        """(Re)initialise with the given parameter values (others keep their defaults)."""
        s = self._slave
        if self._initialized:
            s.reset()
        self.messages.clear()
        unknown = sorted(set(parameters) - set(self._vars))
        if unknown:
            raise FMUError(f"the vehicle FMU has no parameter {unknown[0]!r}")
        reals = {k: float(v) for k, v in parameters.items() if self._vars[k].type in ("Real", "Float64")}
        ints = {k: int(v) for k, v in parameters.items() if self._vars[k].type in ("Integer", "Int32")}
        try:
            if self.fmi_version == "2":
                s.setupExperiment(startTime=start_time)
                s.enterInitializationMode()
                s.setReal([self._vars[k].valueReference for k in reals], list(reals.values()))
                s.setInteger([self._vars[k].valueReference for k in ints], list(ints.values()))
            else:
                s.enterInitializationMode(startTime=start_time)
                s.setFloat64([self._vars[k].valueReference for k in reals], list(reals.values()))
                s.setInt32([self._vars[k].valueReference for k in ints], list(ints.values()))
            s.exitInitializationMode()
        except Exception as exc:
            raise FMUError(f"vehicle FMU initialisation failed: {self._message(exc)}") from None
        self._initialized = True
        self.time = start_time

    def _message(self, exc: Exception) -> str:
        return "; ".join(self.messages) if self.messages else str(exc)

    # -- hot path ---------------------------------------------------------------------
    def outputs(self) -> np.ndarray:
        """Current outputs (after reset or the last step)."""
        n = len(self.output_names)
        if self.fmi_version == "2":
            status = self._get_real(self._slave.component, self._out_vr, n, self._out_ptr)
        else:
            status = self._get_real(self._slave.component, self._out_vr, n, self._out_ptr, n)
        if status > 1:
            raise FMUError(f"vehicle FMU: reading the outputs failed: {self._message(RuntimeError(status))}")
        return self._out_buf

    def set_inputs(self, inputs) -> None:
        """Set the five inputs (ordered as INPUT_NAMES)."""
        self._in_buf[:] = inputs
        c = self._slave.component
        try:
            if self.fmi_version == "2":
                status = self._set_real(c, self._in_vr, 5, self._in_ptr)
            else:
                status = self._set_real(c, self._in_vr, 5, self._in_ptr, 5)
            _check(status, "set inputs")
        except Exception as exc:
            raise FMUError(f"vehicle FMU rejected the inputs {dict(zip(INPUT_NAMES, inputs))}: "
                           f"{self._message(exc)}") from None

    def do_step(self, t: float, h: float) -> np.ndarray:
        """One communication step from t to t + h; returns the outputs."""
        self.advance(t, h)
        return self.outputs()

    def advance(self, t: float, h: float) -> None:
        """One communication step from t to t + h, without reading the outputs (a master
        that reads them only after setting the next inputs saves a getReal call; the
        vehicle FMU computes its outputs when they are read, from the state and inputs)."""
        c = self._slave.component
        try:
            if self.fmi_version == "2":
                status = self._do_step_raw(c, t, h, 1)
            else:
                status = self._do_step_raw(c, t, h, True, *self._step_refs)
            _check(status, "doStep")
        except Exception as exc:
            raise FMUError(f"vehicle FMU failed in the step from t = {t:.4f} s: {self._message(exc)}") from None
        self.time = t + h

    def step(self, t: float, h: float, inputs) -> np.ndarray:
        """set_inputs, then do_step."""
        self.set_inputs(inputs)
        return self.do_step(t, h)

    # -- FMU state ----------------------------------------------------------------------
    def get_state(self):
        """Snapshot of the whole FMU state (random generator included)."""
        s = self._slave
        return s.getFMUstate() if self.fmi_version == "2" else s.getFMUState()

    def set_state(self, state) -> None:
        s = self._slave
        s.setFMUstate(state) if self.fmi_version == "2" else s.setFMUState(state)

    def serialize_state(self, state) -> bytes:
        s = self._slave
        return bytes(s.serializeFMUstate(state) if self.fmi_version == "2" else s.serializeFMUState(state))

    def deserialize_state(self, data: bytes):
        s = self._slave
        return s.deSerializeFMUstate(data) if self.fmi_version == "2" else s.deserializeFMUState(data)

    def close(self) -> None:
        if getattr(self, "_slave", None) is not None:
            try:
                if self._initialized:
                    self._slave.terminate()
                self._slave.freeInstance()
            finally:
                self._slave = None
                shutil.rmtree(self._unzip_dir, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
