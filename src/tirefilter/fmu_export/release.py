"""Unloading a Python FMU from a Python process without corrupting the heap at exit.

The FMU binaries of pythonfmu 0.7 and pythonfmu3 0.3 keep the embedded interpreter's state
in a namespace-scope `std::shared_ptr<PyState>` (`pyState`), set on the first instantiation
and reset by the binary's exported `finalizePythonInterpreter`, which the binary runs from a
library destructor (`__attribute__((destructor))`) when it is unloaded. A binary that is
still loaded when the process exits runs that destructor in `_dl_fini`, and `exit()` has by
then already run the C++ static destructors (registered with `__cxa_atexit`), `pyState`'s
among them. The reset so releases a shared_ptr that no longer exists: it decrements the use
count inside the freed control block (128 bytes, from `make_shared` in
`CppfmuInstantiateSlave`), and calls its destructor again when the count reads 1. Once glibc
has put that block in a bin, the decremented word is its `bk` link, and a later free at
exit aborts ("corrupted double-linked list", "free(): corrupted unsorted chunks"):
intermittently, since it depends on where the block landed. valgrind shows it on every run:
"Invalid read of size 4 at finalizePythonInterpreter (in .../TirefilterMPF.so) by _dl_fini
... inside a block of size 128 free'd by operator delete from __run_exit_handlers, alloc'd
by CppfmuInstantiateSlave". (Upstream: the static came with PythonFMU pull request 213, "keep
the PyState alive until the library is unloaded"; PythonFMU issue 228 reports the abort
after an fmpy simulation.)

Binaries stay loaded past the host's dlclose (fmpy's `freeLibrary`) on Linux in two cases:
the first pythonfmu binary a process loads defines STB_GNU_UNIQUE symbols (libstdc++'s regex
and make_shared tags) that later binaries bind to, and glibc makes it non-deletable; and a
binary whose instance failed (fmi2Fatal) is not unloaded by its host at all. Every other
binary is unloaded by the dlclose, runs its destructor then, with `pyState` alive, and is
harmless.

The remedy is the binary's own: call `finalizePythonInterpreter` once its instances are
freed and before the library is unloaded, while `pyState` is alive. With a Python host the
interpreter was initialised before the FMU (`Py_IsInitialized()`), so `PyState` owns no
interpreter: the call only drops the shared_ptr and joins the PyState's thread, which ended
right after it started; it never finalises Python. An instance still alive keeps its own
copy of the shared_ptr, so the call is safe at any time. Afterwards `pyState` is empty, and
both its static destructor and the destructor's reset at exit do nothing.

`release_embedded_python(dll)` does it for one loaded binary (`FMUHost.close`);
`python_fmus_released()` for every binary that a block of code loaded (fmpy's
`simulate_ssp`, which loads and frees the SSP's FMUs itself).
"""

from __future__ import annotations

import ctypes
import os
from contextlib import contextmanager

RELEASE_SYMBOL = "finalizePythonInterpreter"  # exported by pythonfmu's and pythonfmu3's FMU binaries


def release_embedded_python(dll: ctypes.CDLL) -> bool:
    """Reset the embedded-interpreter state of the loaded FMU binary `dll` (a pythonfmu or
    pythonfmu3 binary: its `finalizePythonInterpreter`); returns False for a binary without
    one (any other FMU), which is left alone. Call it after the binary's instances are
    freed and before it is unloaded."""
    try:
        release = getattr(dll, RELEASE_SYMBOL)
    except AttributeError:
        return False
    release.argtypes = []
    release.restype = None
    release()
    return True


class _PhdrInfo(ctypes.Structure):  # the leading fields of `struct dl_phdr_info` (<link.h>)
    _fields_ = [("dlpi_addr", ctypes.c_void_p), ("dlpi_name", ctypes.c_char_p)]


_PHDR_CALLBACK = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.POINTER(_PhdrInfo), ctypes.c_size_t, ctypes.c_void_p)


def loaded_objects() -> dict[str, int]:
    """The shared objects loaded in this process (`dl_iterate_phdr`): file name -> load
    address. Empty where the C library has no `dl_iterate_phdr` (Windows, macOS: there the
    FMU binary is unloaded by the host's FreeLibrary/dlclose, and its destructor runs then)."""
    try:
        iterate = ctypes.CDLL(None).dl_iterate_phdr
    except (AttributeError, OSError, TypeError):
        return {}
    objects: dict[str, int] = {}

    def visit(info, size, data):
        if info.contents.dlpi_name:
            objects[os.fsdecode(info.contents.dlpi_name)] = info.contents.dlpi_addr or 0
        return 0

    iterate(_PHDR_CALLBACK(visit), None)
    return objects


def release_loaded(path: str) -> bool:
    """`release_embedded_python` for the shared object `path` if it is still loaded (by
    the name it was loaded under; the file itself may be gone); False when it is not
    loaded or is no pythonfmu binary."""
    try:
        dll = ctypes.CDLL(path, mode=os.RTLD_NOLOAD | os.RTLD_LAZY)
    except OSError:
        return False
    try:
        return release_embedded_python(dll)
    finally:
        import _ctypes

        _ctypes.dlclose(dll._handle)  # the reference RTLD_NOLOAD took


@contextmanager
def python_fmus_released():
    """Run a block that loads and frees FMUs through code of its own (fmpy's
    `simulate_ssp`); afterwards, each pythonfmu binary the block left loaded is released
    (`release_embedded_python`)."""
    before = loaded_objects()
    try:
        yield
    finally:
        for path in loaded_objects().keys() - before.keys():
            release_loaded(path)
