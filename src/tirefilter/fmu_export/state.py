"""Serialised FMU state of the Python FMUs: the whole estimator object (particles,
log-weights, per-particle statistics, bias filters, random generator) and the FMU's own
counters, as bytes a tool can store and hand back (fmi2SerializeFMUstate).

The bytes are a pickle behind a header, read back by an unpickler that admits only
numpy's array and generator reconstructors and tirefilter's own classes: a state file
cannot run arbitrary code the way a plain pickle can.
"""

from __future__ import annotations

import importlib
import io
import pickle

MAGIC = b"TIREFILTER-FMU-STATE\x00"
# The pickle holds the estimator objects as they are: raise FORMAT whenever a pickled class
# gains, loses or renames an attribute, so that an older state is refused by this check
# instead of failing inside the object. 2: the MPF's float sandwich (BatchMeansSandwichPair),
# the GP-SSM's K in lanes and its deferred resampling copy of K. 3: the MPF's work arrays name
# the kernels' sizes (`sizes_all`, `sizes_any`), not entry points. 4: the MPF's classes in the
# package `estimators.mpf`, its model parameters and kernel modules (`_vp`, `_st`), its work arrays'
# workspace tuples (`own`, `scratch`); the AUGPF's model without a borrowed MPF. 5: the MPF's roll gradient per
# particle (`k_roll`, `roll_estimated`) and the work arrays' roll gain (`gain`). 6: the MPF's load sensitivity per
# particle (`k_load`, `load_estimated`, `ay_load`, `_ay_step`) and the work arrays' `load_gain`.
FORMAT = 6

_NUMPY_ALLOWED = {
    ("numpy", "ndarray"), ("numpy", "dtype"),
    ("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
    ("numpy.core.multiarray", "scalar"), ("numpy._core.multiarray", "scalar"),
    ("numpy.core.numeric", "_frombuffer"), ("numpy._core.numeric", "_frombuffer"),
    ("numpy.random._pickle", "__generator_ctor"), ("numpy.random._pickle", "__bit_generator_ctor"),
    ("numpy.random._pickle", "__randomstate_ctor"), ("numpy.random.bit_generator", "__pyx_unpickle_SeedSequence"),
}
_BUILTINS_ALLOWED = {"slice", "set", "frozenset", "complex", "range", "tuple", "list", "dict", "float", "int",
                     "bool", "str", "bytes"}


class StateError(ValueError):
    """Bytes that are not a state of this FMU (wrong header, version or content)."""


class _RestrictedUnpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str):
        if (module, name) in _NUMPY_ALLOWED or (module == "builtins" and name in _BUILTINS_ALLOWED):
            return super().find_class(module, name)
        if module.startswith("numpy.dtypes") or (module.startswith("numpy.random.") and name[:1].isupper()):
            return super().find_class(module, name)  # dtype classes, bit generators (PCG64, ...)
        if module == "tirefilter" or module.startswith("tirefilter."):
            obj = getattr(importlib.import_module(module), name, None)
            if isinstance(obj, type):  # tirefilter classes only, no functions
                return obj
        raise StateError(f"FMU state refers to {module}.{name}, which a tirefilter FMU state never holds")


def state_to_bytes(state: dict) -> bytes:
    return MAGIC + bytes([FORMAT]) + pickle.dumps(state, protocol=5)


def state_from_bytes(data: bytes) -> dict:
    data = bytes(data)
    if not data.startswith(MAGIC) or len(data) <= len(MAGIC):
        raise StateError("not a serialised tirefilter FMU state (header missing)")
    version = data[len(MAGIC)]
    if version != FORMAT:
        raise StateError(f"FMU state format {version}, this FMU reads format {FORMAT}")
    try:
        state = _RestrictedUnpickler(io.BytesIO(data[len(MAGIC) + 1:])).load()
    except StateError:
        raise
    except Exception as exc:
        raise StateError(f"corrupt FMU state ({exc})") from None
    if not isinstance(state, dict):
        raise StateError("corrupt FMU state (not a mapping)")
    return state
