"""The stiffness MPF's per-particle work in C (`backend = "c"`): the C99 sources in `native/`
(package data) built on first use with the system C compiler into a per-user cache and loaded
with ctypes. This module is the C twin of `kernels` (the three passes `predict_weigh`,
`resample_gate`, `sample_update`, and `estimate_moments`, `match_state_noise`, `walk_roll`), of the model
check's `predictive.mixture_moments_chol`, and of
the model kernels of `vehicle.single_track_numba` that the filter's reference path calls
(`accelerations`, `propagate`, `slip_over_step`): the same functions with the same arguments, so
that `CompiledStep._step_compiled` (compiled.py) runs either unchanged. The C code computes the
numba kernels' expressions in the same order and takes the random numbers from the caller, so the
two backends give the same numbers bit for bit (tests/test_kernels.py); it is compiled without
FMA contraction and without fast-math for that.

The library is built once per version of the sources: `$XDG_CACHE_HOME/tirefilter/mpf-c/`
(`~/.cache/tirefilter/mpf-c/` when XDG_CACHE_HOME is unset or not absolute) keeps
`mpf_core-<hash>.so`, the hash over the sources, the compiler and its flags and the processor (the library
is built for this processor's instruction sets, -march=native; without FMA contraction its numbers do not
depend on them). The compiler is
`$CC`, else gcc, cc or clang; `NativeBuildError` names it when none is found or the build fails.
numba is not imported on this path.

The arrays go to C by address: those of the filter's work arrays (`compiled._MPFWork`), which live
as long as the filter, are looked up once per tuple (`own`, `spares`, `scratch`, `model`) into C
structs kept in a small cache; the others (this sample's inputs and draws) go as numpy objects whose
data pointers `native/mpf_numpy.c` reads, checking each one's type, dtype, C-contiguity and, where the
kernel writes into it, writeability (an array that fails is named in a TypeError, never copied). The
rare calls (the model for all particles, the moments) take addresses from Python."""

from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from ctypes import POINTER, Structure, c_double, c_int32, c_int64, c_void_p, py_object
from pathlib import Path

import numpy as np

from tirefilter.errors import TirefilterError

SOURCE_DIR = Path(__file__).resolve().parent / "native"
SOURCES = ("mpf_weigh.c", "mpf_update.c", "single_track.c", "mpf_numpy.c")
HEADERS = ("mpf_core.h", "single_track.h")
# no FMA contraction and no fast-math: the numba kernels' roundings, operation for operation
CFLAGS = ("-std=c99", "-O3", "-march=native", "-ffp-contract=off", "-fno-fast-math", "-fPIC", "-shared")
MAX_DIM = 4  # MPF_MAX_DIM of mpf_core.h: n_w and m at most this

_F64, _I64 = np.dtype(np.float64), np.dtype(np.int64)
build_seconds = 0.0  # the time this process spent building the library (0 when it was in the cache)


class NativeBuildError(TirefilterError):
    """The MPF's C core could not be built or loaded: the message names the compiler and why."""


def cache_dir() -> Path:
    cache = os.environ.get("XDG_CACHE_HOME", "")
    return (Path(cache) if os.path.isabs(cache) else Path.home() / ".cache") / "tirefilter" / "mpf-c"


def compiler() -> str:
    for cc in (os.environ.get("CC"), "gcc", "cc", "clang"):
        if cc and shutil.which(cc):
            return cc
    raise NativeBuildError("the stiffness MPF's C backend needs a C compiler and none was found ($CC, gcc, cc, "
                           "clang): install gcc (Debian: apt-get install gcc), set CC, or use backend = \"numba\"")


def library_path(cc: str | None = None) -> Path:
    """The cached library for these sources, this compiler and these flags."""
    cc = cc or compiler()
    h = hashlib.sha256()
    for name in (*SOURCES, *HEADERS):
        h.update(name.encode() + b"\0" + (SOURCE_DIR / name).read_bytes())
    h.update(" ".join((shutil.which(cc) or cc, *CFLAGS, platform.machine(), _cpu())).encode())
    return cache_dir() / f"mpf_core-{h.hexdigest()[:16]}.so"


def _cpu() -> str:
    """The processor's model and instruction sets (-march=native builds for them: a cache shared by several
    machines keeps one library per kind of processor)."""
    try:
        with open("/proc/cpuinfo") as f:
            lines = [ln for ln in f if ln.startswith(("model name", "flags"))][:2]
        return "".join(lines) or platform.processor()
    except OSError:
        return platform.processor()


def build(force: bool = False) -> Path:
    """Compile the sources into the cache (a no-op when this version is there); returns the library."""
    global build_seconds
    missing = [f for f in (*SOURCES, *HEADERS) if not (SOURCE_DIR / f).is_file()]
    if missing:
        raise NativeBuildError(f"the MPF's C sources {missing} are missing from {SOURCE_DIR}: the package was "
                               "installed without its package data")
    cc = compiler()
    lib = library_path(cc)
    if lib.is_file() and not force:
        return lib
    t0 = time.perf_counter()
    print(f"building the stiffness MPF's C core with {cc} into {lib.parent} (once per version of its sources, "
          "a few seconds) ...", file=sys.stderr, flush=True)
    try:
        lib.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(suffix=".so.part", dir=lib.parent)
    except OSError as exc:
        raise NativeBuildError(f"the MPF's C core cannot be built into {lib.parent} ({exc}): set XDG_CACHE_HOME to a "
                               "writable folder") from exc
    os.close(fd)
    cmd = [cc, *CFLAGS, "-o", tmp, *(str(SOURCE_DIR / f) for f in SOURCES), "-lm"]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            raise NativeBuildError(f"building the MPF's C core with {cc} failed: {' '.join(cmd)}\n{proc.stderr}")
        os.replace(tmp, lib)  # (atomic: a parallel process loads either the old or the new file whole)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    build_seconds += time.perf_counter() - t0
    return lib


# ---- the library and its entry points --------------------------------------------------------------------
class _Own(Structure):
    _fields_ = [(name, c_void_p) for name in ("x", "b", "P", "gamma", "mu", "Lam", "nu", "a", "B", "slip")]


class _Scratch(Structure):
    _fields_ = [(name, c_void_p) for name in ("af", "ar", "h", "D", "L11", "nu_w", "L12", "Lc", "e", "v", "ll",
                                              "ok")]


class _Model(Structure):
    _fields_ = [(name, c_void_p) for name in ("vp", "jw", "c_floor", "R", "q", "gain", "load_gain", "relaxed")]


class _Dims(Structure):
    _fields_ = [("n", c_int64), ("nx", c_int64), ("n_w", c_int64), ("m", c_int64)]


_P, _D, _I, _I32, _O = c_void_p, c_double, c_int64, c_int32, py_object
_DIMS, _OWN, _SCRATCH, _MODEL = POINTER(_Dims), POINTER(_Own), POINTER(_Scratch), POINTER(_Model)
_SIGNATURES = {  # name: (argument types, result type); *_np: the arrays as objects (mpf_numpy.c)
    "mpf_predict_weigh_np": ([_DIMS, _OWN, _SCRATCH, _O, _O, _O, _O, _O, _O, _O, _O, _O, _MODEL, _P, _P, _I, _P],
                             c_int32),
    "mpf_resample_gate_np": ([_DIMS, _O, _D, _I32, _O, _OWN, _OWN, _O, _O, _I32, _O, _O, _O, _P], c_int32),
    "mpf_sample_update_np": ([_DIMS, _O, _OWN, _SCRATCH, _O, _O, _O, _O, _O, _O, _O, _O, _D, _D, _O, _O, _P, _I, _O,
                              _O, _O, _O, _P], c_int32),
    "mpf_match_state_noise_np": ([_O, _O, _O, _O, _D, _D, _O], c_int32),
    "mpf_walk_roll_np": ([_O, _O, _D, _D, _D, _D, _O], c_int32),
    "mpf_np_probe": ([_O, _P], None),
    "mpf_np_set_type": ([_P], None),
    "mpf_estimate_moments": ([_DIMS, _P, _P, _P, _P, _P, _P, _P, _P, _I], None),
    "mpf_mixture_moments_chol": ([_I, _I, _P, _P, _P, _P, _P, _I, _P], None),
    "st_accelerations": ([_I, _I, _I, _P, _P, _P, _I32, _I32, _P, _P, _D, _P, _P, _P, _P, _P], None),
    "st_propagate": ([_I, _I, _I, _P, _P, _P, _P, _P, _P, _D, _D, _I32, _P, _I32, _I32, _P, _P, _P], None),
    "st_slip_over_step": ([_I, _I, _P, _P, _P, _P, _P, _P, _P, _D, _P, _P, _P, _I32, _P, _P, _P, _P, _P, _P, _P],
                          None),
}
_LIB: list = []


def library() -> ctypes.CDLL:
    """The built library, loaded once per process and checked (`_probe`)."""
    if not _LIB:
        path = build()
        try:
            lib = ctypes.CDLL(str(path))
        except OSError as exc:
            raise NativeBuildError(f"the MPF's C core {path} could not be loaded: {exc}") from exc
        for name, (argtypes, restype) in _SIGNATURES.items():
            fn = getattr(lib, name)
            fn.argtypes, fn.restype = argtypes, restype
        _probe(lib)
        _LIB.append(lib)
    return _LIB[0]


def _probe(lib) -> None:
    """mpf_numpy.c reads numpy arrays' data pointer, shape, dtype and flags from the objects: check that
    it reads what numpy says for arrays of each kind the kernels take."""
    lib.mpf_np_set_type(id(np.ndarray))  # (CPython: id is the object's address)
    out = np.zeros(5, np.int64)
    for a in (np.arange(6.0).reshape(3, 2), np.arange(4), np.zeros(3, bool), np.zeros((2, 0)),
              np.arange(6.0).reshape(2, 3).T):
        lib.mpf_np_probe(a, out.ctypes.data)
        want = [a.ctypes.data, a.ndim, a.shape[0], ord(a.dtype.char), None]
        if out[:4].tolist() != want[:4] or bool(out[4] & 1) != a.flags.c_contiguous:
            raise NativeBuildError("the MPF's C core reads numpy arrays other than this Python and numpy lay them "
                                   f"out (read {out.tolist()} of an array with {want[:4]}): use backend = \"numba\"")


def _check(status: int, fn: str, names: str) -> None:
    """A kernel's status: 0, else the position (1-based) of the array among `names` that is not as it takes it."""
    if status:
        name = names.split()[status - 1]
        raise TypeError(f"the MPF's C core ({fn}) takes {name} as a C-contiguous numpy array of float64 (int64 "
                        "for indices), writeable where it writes into it: got another")


def _addr(a: np.ndarray, dtype=_F64) -> int:
    """The address of a C-contiguous array of `dtype` (the kernels write into some: never a copy)."""
    if a.dtype != dtype or not a.flags.c_contiguous:
        raise TypeError(f"the MPF's C core takes C-contiguous {dtype} arrays, got {a.dtype} of strides {a.strides}")
    return a.ctypes.data


def _addr_or_null(a: np.ndarray) -> int | None:
    """`_addr`, None (NULL: the option off) for an empty array."""
    return _addr(a) if a.size else None


_OUT4 = c_double * 4  # the entry points' returned scalars: one per call (ctypes releases the GIL during it)
_CACHE: dict = {}  # id(tuple) -> (tuple, its ctypes struct): the work arrays' addresses, looked up once
# (about a dozen entries a filter; the entries keep their arrays alive until they are forgotten, so the
# cache holds a few filters' worth: filters run one after another in a process)
_CACHE_MAX = 48


def _cached(key_obj, make):
    hit = _CACHE.get(id(key_obj))
    if hit is not None and hit[0] is key_obj:
        return hit[1]
    if len(_CACHE) >= _CACHE_MAX:  # (filters come and go: forget the oldest half)
        for k in list(_CACHE)[: _CACHE_MAX // 2]:
            del _CACHE[k]
    value = make(key_obj)
    _CACHE[id(key_obj)] = (key_obj, value)  # (the tuple kept: its id is not reused while it is cached)
    return value


def _own_struct(own) -> _Own:
    x, b, P, gamma, mu, Lam, nu, a, B, slip = own
    if mu.shape[1] > MAX_DIM or b.shape[1] > MAX_DIM or x.shape[1] > 3:
        raise ValueError(f"the MPF's C core takes at most {MAX_DIM} parameters and channels and 3 states")
    return _Own(*(_addr(arr) for arr in own))


def _scratch_struct(scratch) -> _Scratch:
    return _Scratch(*(_addr(arr) for arr in scratch[:-1]), _addr(scratch[-1], np.dtype(np.bool_)))


def _model_struct(model) -> _Model:
    vp, jw, c_floor, R, q, gain, load_gain, relaxed = model
    return _Model(*(_addr(arr) for arr in model[:-1]), _addr_or_null(relaxed))


def _int32s(flags) -> ctypes.Array:
    return (c_int32 * len(flags))(*(int(bool(f)) for f in flags))


def _dims(x, mu, b) -> _Dims:
    n, nx = x.shape
    return _Dims(n, nx, mu.shape[1], b.shape[1])


# ---- `kernels`' entry points --------------------------------------------------------------------------------
def predict_weigh(own, scratch, inputs, model, scalars, flags, nc, sizes):
    """`kernels.predict_weigh` in C (the same arguments; `sizes` is not needed: the C code picks its
    unrolled bodies by the sizes themselves)."""
    lib = library()
    u_prev, uk, y, avail, w_prev, logw, noise, noise_scale, redraw = inputs
    dims = _cached(own[0], lambda x: _dims(x, own[4], own[1]))
    sc, out = (c_double * 7)(*scalars), _OUT4()  # (bound to names: alive during the call)
    _check(lib.mpf_predict_weigh_np(dims, _cached(own, _own_struct), _cached(scratch, _scratch_struct), u_prev, uk, y,
                                    avail, w_prev, logw, noise, noise_scale, redraw, _cached(model, _model_struct),
                                    sc, _cached(flags, _int32s), nc, out),
           "predict_weigh", "u_prev uk y avail w_prev logw noise noise_scale redraw")
    return out[0], out[1], int(out[2]), out[3]


def resample_gate(logw, u0, resample, idx, own, spares, af, ar, full, pin_lo, pin_hi, qw):
    """`kernels.resample_gate` in C."""
    lib = library()
    dims, out = _cached(own[0], lambda x: _dims(x, own[4], own[1])), _OUT4()
    _check(lib.mpf_resample_gate_np(dims, logw, u0, bool(resample), idx, _cached(own, _own_struct),
                                    _cached(spares, _own_struct), af, ar, bool(full), pin_lo, pin_hi, qw, out),
           "resample_gate", "logw idx af ar pin_lo pin_hi . . qw")
    return out[0], out[1], out[2], bool(out[3])


def sample_update(idx, own, scratch, draws, w, obs, learning, flags, nc_, out, sizes):
    """`kernels.sample_update` in C."""
    lib = library()
    z, chi, nu_draw, infl = draws
    R, avail, y = obs
    bound, drift_a, lo, hi = learning
    drift_state, mom, qw, k_roll = out
    dims = _cached(own[0], lambda x: _dims(x, own[4], own[1]))
    fl, res = (c_int32 * 4)(*(bool(f) for f in flags)), _OUT4()
    _check(lib.mpf_sample_update_np(dims, idx, _cached(own, _own_struct), _cached(scratch, _scratch_struct), z, chi,
                                    nu_draw, infl, w, R, avail, y, bound, drift_a, lo, hi, fl, nc_, drift_state, mom,
                                    qw, k_roll, res),
           "sample_update", "idx z chi nu_draw infl w R avail y lo hi drift_state mom qw k_roll")
    return res[0], res[1], res[2]


def estimate_moments(logw, x, gamma, mu, Lam, nu, b, mom):
    """`kernels.estimate_moments` in C."""
    library().mpf_estimate_moments(_dims(x, mu, b), _addr(logw), _addr(x), _addr(gamma), _addr(mu), _addr(Lam),
                                   _addr(nu), _addr(b), _addr(mom), mom.shape[1])


def match_state_noise(logw_pred, logw, x, scale, dt, a, q_state):
    """`kernels.match_state_noise` in C (at most 8 states)."""
    scale = _c(scale)
    _check(library().mpf_match_state_noise_np(logw_pred, logw, x, scale, dt, a, q_state), "match_state_noise",
           "logw_pred logw x scale q_state")


def mixture_moments_chol(logw, e, Lc, nu, cols, out):
    """`predictive.mixture_moments_chol` in C (the model check's one-step predictive)."""
    n, m = e.shape
    if cols.shape[0] > MAX_DIM or out.shape != (2, cols.shape[0]):
        raise ValueError("mixture_moments_chol: at most 4 columns, out (2, columns)")
    library().mpf_mixture_moments_chol(n, m, _addr(logw), _addr(e), _addr(Lc), _addr(nu), _addr(cols, _I64),
                                       cols.shape[0], _addr(out))


def walk_roll(k, z, c, lo, hi, g, gain):
    """`kernels.walk_roll` in C."""
    _check(library().mpf_walk_roll_np(k, z, c, lo, hi, g, gain), "walk_roll", "k z gain")


# ---- `vehicle.single_track_numba`'s model kernels (the filter's reference path) -----------------------------
def _c(a) -> np.ndarray:
    return np.ascontiguousarray(a, float)


def accelerations(x, u, vp, full, rear_drive, n_w, lg, rel, h):
    """`single_track_numba.accelerations` in C: a (N, 3), B (N, 3, n_w), af, ar (N,), slip (2, N)."""
    x, u, vp, lg, rel = _c(x), _c(u), _c(vp), _c(lg), _c(rel)  # (bound to names: alive during the call)
    n, nx = x.shape
    a, B, af, ar, slip = np.empty((n, 3)), np.empty((n, 3, n_w)), np.empty(n), np.empty(n), np.empty((2, n))
    library().st_accelerations(n, nx, n_w, _addr(x), _addr(u), _addr(vp), bool(full), bool(rear_drive), _addr(lg),
                               _addr(rel) if rel.shape[1] == n else None, h, _addr(a), _addr(B), _addr(af),
                               _addr(ar), _addr(slip))
    return a, B, af, ar, slip


def propagate(x, u, w, first, dt, max_step, heun, vp, full, rear_drive, n_w, particle):
    """`single_track_numba.propagate` in C: x_{k+1} (N, nx)."""
    a, B, slip = (_c(arr) for arr in first)
    x, u, w, vp = _c(x), _c(u), _c(w), _c(vp)
    lg, rel = (_c(arr) for arr in particle)
    n, nx = x.shape
    out = np.empty((n, nx))
    library().st_propagate(n, nx, n_w, _addr(x), _addr(u), _addr(w), _addr(a), _addr(B), _addr(slip), dt, max_step,
                           bool(heun), _addr(vp), bool(full), bool(rear_drive), _addr(lg),
                           _addr(rel) if rel.shape[1] == n else None, _addr(out))
    return out


def slip_over_step(x, u0, u1, w, first, dt, vp, jw, c_floor, rear_drive, n_w, particle):
    """`single_track_numba.slip_over_step` in C: (a, B, af, ar, slip) at x with the interval slip."""
    a, B, slip = (_c(arr) for arr in first)
    x, u0, u1, w, vp, jw, c_floor = _c(x), _c(u0), _c(u1), _c(w), _c(vp), _c(jw), _c(c_floor)
    lg, rel = (_c(arr) for arr in particle)
    n = x.shape[0]
    a2, B2, af, ar, out = np.empty((n, 3)), np.empty((n, 3, n_w)), np.empty(n), np.empty(n), np.empty((2, n))
    library().st_slip_over_step(n, n_w, _addr(x), _addr(u0), _addr(u1), _addr(w), _addr(a), _addr(B), _addr(slip),
                                dt, _addr(vp), _addr(jw), _addr(c_floor), bool(rear_drive), _addr(lg),
                                _addr(rel) if rel.shape[1] == n else None, _addr(a2), _addr(B2), _addr(af),
                                _addr(ar), _addr(out))
    return a2, B2, af, ar, out
