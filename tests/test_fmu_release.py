"""Python FMUs leave nothing for their library destructor to do at process exit
(tirefilter.fmu_export.release: the destructor of a pythonfmu binary still loaded at exit
resets its static `std::shared_ptr<PyState>`, which has been destroyed by then, and so
corrupts the heap, intermittently).

Checked deterministically, where it happens: with the binary kept loaded past the host's
unloading (as glibc keeps the first pythonfmu binary of a process, and as a host keeps a
binary whose instance failed), its static `pyState` (the anonymous-namespace
`_ZN12_GLOBAL__N_17pyStateE` of the binary's symbol table; a shared_ptr: object and control
block pointers) must be empty once the host is done with it. Linux only: elsewhere the
binary is unloaded by the host and its destructor runs then."""

from __future__ import annotations

import ctypes
import os
import struct
import sys
from pathlib import Path

import pytest

pytest.importorskip("pythonfmu")
pytest.importorskip("pythonfmu3")
if not sys.platform.startswith("linux"):
    pytest.skip("the exit-time destructor of a pythonfmu binary matters where dlclose cannot unload it (Linux)",
                allow_module_level=True)

from tirefilter.fmu_export.host import FMUHost  # noqa: E402
from tirefilter.fmu_export.release import RELEASE_SYMBOL, loaded_objects  # noqa: E402

PY_STATE = b"_ZN12_GLOBAL__N_17pyStateE"  # (anonymous namespace)::pyState of PySlaveInstance.cpp


def _symbol_value(path: Path, name: bytes) -> int:
    """The value (address in the object) of symbol `name` in the symbol table (.symtab) of
    the ELF64 little-endian shared object `path`."""
    data = Path(path).read_bytes()
    assert data[:6] == b"\x7fELF\x02\x01", f"{path}: not an ELF64 little-endian object"
    (shoff,) = struct.unpack_from("<Q", data, 0x28)
    shentsize, shnum = struct.unpack_from("<HH", data, 0x3A)
    # (sh_name, sh_type, sh_flags, sh_addr, sh_offset, sh_size, sh_link, sh_info, sh_addralign, sh_entsize)
    sections = [struct.unpack_from("<IIQQQQIIQQ", data, shoff + i * shentsize) for i in range(shnum)]
    for sh in sections:
        if sh[1] != 2:  # SHT_SYMTAB
            continue
        strtab = sections[sh[6]][4]
        for off in range(sh[4], sh[4] + sh[5], 24):  # Elf64_Sym
            st_name, _, _, _, st_value, _ = struct.unpack_from("<IBBHQQ", data, off)
            if data[strtab + st_name:data.index(b"\0", strtab + st_name)] == name:
                return st_value
    raise AssertionError(f"{path} has no symbol {name.decode()}")


def _package_binary(fmi: str) -> Path:
    """The binary pythonfmu (FMI 2.0) or pythonfmu3 (FMI 3.0) copies into its FMUs."""
    import pythonfmu
    import pythonfmu3

    if fmi == "2":
        return Path(pythonfmu.__file__).parent / "resources" / "binaries" / "linux64" / "libpythonfmu-export.so"
    return Path(pythonfmu3.__file__).parent / "resources" / "binaries" / "x86_64-linux" / "libpythonfmu-export.so"


def _py_state(path: str, fmi: str) -> tuple[int, int]:
    """The two pointers of the `pyState` shared_ptr in the loaded FMU binary `path`."""
    base = loaded_objects()[path]
    words = (ctypes.c_void_p * 2).from_address(base + _symbol_value(_package_binary(fmi), PY_STATE))
    return words[0] or 0, words[1] or 0


def _hold(path: str) -> ctypes.CDLL:
    """A reference of our own to the loaded object `path`: it stays loaded until `_drop`."""
    return ctypes.CDLL(path, mode=os.RTLD_NOLOAD | os.RTLD_LAZY)


def _drop(dll: ctypes.CDLL) -> None:
    import _ctypes

    _ctypes.dlclose(dll._handle)


@pytest.mark.parametrize("fmi", ["2", "3"])
@pytest.mark.parametrize("fails", [False, True], ids=["closed", "after-fatal"])
def test_closing_the_host_leaves_the_binary_nothing_to_reset_at_exit(python_fmu, fmi, fails):
    from fmpy.fmi1 import FMICallException

    host = FMUHost(python_fmu("mpf", fmi))
    path = host.slave.dll._name
    assert Path(path).read_bytes() == _package_binary(fmi).read_bytes()  # the symbol table read is the binary's
    held = _hold(path)
    try:
        if fails:  # fmi2Fatal: the host makes no further calls and does not unload the binary
            with pytest.raises(FMICallException):
                host.initialize({"particles": 0})
        else:
            host.initialize({"model": 2})
            host.step(0.01, {"u.vx": 20.0, "y.ay": 0.2})
        assert all(_py_state(path, fmi)), "the instantiation set the binary's interpreter state"
        host.close()
        assert path in loaded_objects()
        assert _py_state(path, fmi) == (0, 0)
    finally:
        _drop(held)


def test_run_ssp_leaves_the_python_fmus_it_loaded_nothing_to_reset_at_exit(fmu_paths, tmp_path, monkeypatch):
    """fmpy's simulate_ssp loads, frees and unloads the driver and estimator FMUs (FMI 2.0)
    itself; each binary is held here just before fmpy frees it."""
    import fmpy.ssp.simulation as simulation

    from tirefilter.fmu_export.ssp import build_ssp, run_ssp

    held = {}
    free_fmu = simulation.free_fmu

    def hold_then_free(component):
        held[component.fmu.dll._name] = _hold(component.fmu.dll._name)
        free_fmu(component)

    monkeypatch.setattr(simulation, "free_fmu", hold_then_free)
    path = build_ssp("snow-sine", tmp_path / "snow-sine.ssp", seed=1, particles=8, stop_time=0.05)
    try:
        assert len(run_ssp(path)) == 5
        python = {p for p in held if hasattr(held[p], RELEASE_SYMBOL)}
        assert sorted(Path(p).name for p in python) == ["TirefilterDriver.so", "TirefilterMPF.so"]
        assert {p: _py_state(p, "2") for p in python} == dict.fromkeys(python, (0, 0))
    finally:
        for dll in held.values():
            _drop(dll)
