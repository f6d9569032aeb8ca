"""A small FMI 2.0 / 3.0 Co-Simulation host for the Python FMUs (through fmpy): set
parameters by name, step with inputs by name, read outputs, save and restore the FMU
state, and keep the FMI logger's messages. Tests and benchmarks use it; any FMI tool does
the same. The FMI version is the FMU's (modelDescription.xml).
"""

from __future__ import annotations

import ctypes
import shutil
from pathlib import Path

from tirefilter.errors import FMUError


class FMUHost:
    def __init__(self, path: str | Path, instance_name: str = "estimator"):
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                               fmi2CallbackFunctions, fmi2CallbackLoggerTYPE, calloc, free)

        self.path = Path(path)
        self.md = read_model_description(str(self.path))
        self.vars = {v.name: v for v in self.md.modelVariables}
        self.unzip_dir = extract(str(self.path))
        self.messages: list[tuple[int, str]] = []
        self.fmi = self.md.fmiVersion[0]
        if self.fmi == "3":
            self._instantiate3(instance_name)
            self.time = 0.0
            self.failed = False
            return
        self.slave = FMU2Slave(guid=self.md.guid, unzipDirectory=self.unzip_dir,
                               modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=instance_name)
        callbacks = fmi2CallbackFunctions()
        callbacks.logger = fmi2CallbackLoggerTYPE(self._log)
        callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        try:
            from fmpy.logging import addLoggerProxy

            addLoggerProxy(ctypes.byref(callbacks))
        except Exception:  # pragma: no cover - proxy missing on exotic platforms
            pass
        self._callbacks = callbacks
        try:
            self.slave.instantiate(callbacks=callbacks, loggingOn=True)
        except Exception:
            self._unload()
            raise FMUError(f"{self.path.name}: instantiation failed: " + "; ".join(m for _, m in self.messages)) from None
        self.time = 0.0
        self.failed = False  # after fmi2Error/fmi2Fatal the instance gets no further calls

    def _instantiate3(self, instance_name: str) -> None:
        from fmpy.fmi3 import FMU3Slave

        self.slave = FMU3Slave(guid=self.md.instantiationToken, unzipDirectory=self.unzip_dir,
                               modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=instance_name)
        try:
            self.slave.instantiate(loggingOn=True, logMessage=lambda env, status, cat, msg: self._log(
                env, None, status, cat, msg))
        except Exception:
            self._unload()
            raise FMUError(f"{self.path.name}: instantiation failed: " + "; ".join(m for _, m in self.messages)) from None

    def _log(self, env, name, status, category, message):
        text = message.decode("utf-8", "replace") if isinstance(message, bytes) else str(message)
        self.messages.append((int(status), text))

    def set(self, values: dict) -> None:
        for name, value in values.items():
            if name not in self.vars:
                raise FMUError(f"{self.path.name} has no variable {name!r}")
            v = self.vars[name]
            vr = [v.valueReference]
            if v.type in ("Real", "Float64"):
                (self.slave.setReal if self.fmi == "2" else self.slave.setFloat64)(vr, [float(value)])
            elif v.type in ("Integer", "Int32"):
                (self.slave.setInteger if self.fmi == "2" else self.slave.setInt32)(vr, [int(value)])
            elif v.type == "Boolean":
                self.slave.setBoolean(vr, [bool(value)])
            else:
                self.slave.setString(vr, [str(value)])

    def get(self, names) -> dict:
        """The values of the variables `names`, read with one call per variable type."""
        if self.fmi == "2":
            getters = {"Real": self.slave.getReal, "Integer": self.slave.getInteger,
                       "Boolean": self.slave.getBoolean, "String": self.slave.getString}
        else:
            getters = {"Float64": self.slave.getFloat64, "Int32": self.slave.getInt32,
                       "Boolean": self.slave.getBoolean, "String": self.slave.getString}
        groups: dict[str, list] = {}
        for name in names:
            groups.setdefault(self.vars[name].type, []).append(name)
        out = {}
        for kind, group in groups.items():
            values = getters[kind]([self.vars[name].valueReference for name in group])
            out.update(zip(group, values))
        return {name: out[name] for name in names}

    def initialize(self, parameters: dict, start_time: float = 0.0) -> None:
        try:
            if self.fmi == "2":
                self.slave.setupExperiment(startTime=start_time)
                self.set(parameters)
                self.slave.enterInitializationMode()
            else:
                self.set(parameters)
                self.slave.enterInitializationMode(startTime=start_time)
            self.slave.exitInitializationMode()
        except Exception:
            self.failed = True
            raise
        self.time = start_time

    def step(self, h: float, inputs: dict | None = None) -> None:
        try:
            if inputs:
                self.set(inputs)
            self.slave.doStep(currentCommunicationPoint=self.time, communicationStepSize=h)
        except Exception:
            self.failed = True
            raise
        self.time += h

    def outputs(self) -> dict:
        return self.get([n for n, v in self.vars.items() if v.causality == "output"])

    def get_state(self):
        return (self.slave.getFMUstate() if self.fmi == "2" else self.slave.getFMUState()), self.time

    def set_state(self, state) -> None:
        (self.slave.setFMUstate if self.fmi == "2" else self.slave.setFMUState)(state[0])
        self.time = state[1]

    def serialize(self, state) -> bytes:
        return bytes((self.slave.serializeFMUstate if self.fmi == "2" else self.slave.serializeFMUState)(state[0]))

    def deserialize(self, data: bytes, time: float):
        return (self.slave.deSerializeFMUstate if self.fmi == "2" else self.slave.deserializeFMUState)(data), time

    def errors(self) -> list[str]:
        return [m for s, m in self.messages if s >= 3]

    def close(self, terminate: bool = True) -> None:
        """Terminate and free the instance, then unload the FMU (`_unload`)."""
        if self.slave is None:
            return
        freed = False
        try:
            if not self.failed:  # FMI: no calls after fmi2Fatal (pythonfmu 0.7 has freed it already)
                if terminate:
                    self.slave.terminate()
                free = self.slave.fmi2FreeInstance if self.fmi == "2" else self.slave.fmi3FreeInstance
                free(self.slave.component)
                freed = True
        except Exception:
            pass
        finally:
            self._unload(unload_library=freed)

    def _unload(self, unload_library: bool = True) -> None:
        """After the instance is freed (or was never made): release a Python FMU's embedded
        interpreter state while the binary's statics are alive (`release.py`: otherwise its
        library destructor corrupts the heap at process exit), unload the binary (fmpy's
        `freeLibrary`; only when no instance is left: not after fmi2Fatal or a failed
        terminate) and remove the unpacked FMU."""
        from tirefilter.fmu_export.release import release_embedded_python

        try:
            release_embedded_python(self.slave.dll)
            if unload_library:
                self.slave.freeLibrary()
        finally:
            self.slave = None
            shutil.rmtree(self.unzip_dir, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
