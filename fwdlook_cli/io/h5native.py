"""HDF5's object calls of the stage files made through ``ctypes``, so that they run without the GIL.

h5py holds the GIL through every HDF5 call.  The stage files are written on a writer thread while
the next stage computes (``runner._StageWriter``), and their HDF5 objects (datasets, attributes,
dimension scales, the metadata flush, and h5py's Python around them: about 3.5 ms a file here) held the GIL for all of that
time, so the stage computing beside the writer waited for them: each of its numpy calls needs the
GIL between two arrays.  The paper cube's ``decimation`` chain took 27-39 ms longer with every
stage file written than with the same bytes and digests written without HDF5 (medians of five
alternated sets; issue 11, thirty-first round, docs/SPEED_HISTORY.md).  These functions make the same calls into the same library (the ``libhdf5``
and ``libhdf5_hl`` that h5py has loaded, found in ``/proc/self/maps``), with the identifiers and
types of h5py's own objects, through ``ctypes``, which releases the GIL for the length of each call.
h5py's lock (``phil``) is held around each one, as h5py holds it around its own, so no two threads
are ever inside HDF5 at once.  The file's bytes are what h5py writes (``tests/test_h5native.py``
compares them); the file itself is still created, flushed through :class:`outputs.FailSafeSink` and
closed by h5py.

Where the library cannot be found (no ``/proc``, a platform other than Linux) or any of its calls
cannot be bound, :func:`enabled` is False and the callers use h5py as before.  ``FWDLOOK_H5_NATIVE=0``
turns it off.
"""
from __future__ import annotations

import ctypes
import os

import numpy as np

HID = ctypes.c_int64
HERR = ctypes.c_int
H5P_DEFAULT = 0
H5S_ALL = 0
H5S_SCALAR = 0
H5F_SCOPE_GLOBAL = 1


class NativeError(RuntimeError):
    """An HDF5 call made here returned an error."""


def _loaded_libraries() -> dict:
    """{"core": path of libhdf5, "hl": path of libhdf5_hl} as loaded in this process (by h5py)."""
    import importlib

    importlib.import_module("h5py.h5ds")            # loads libhdf5_hl
    with open("/proc/self/maps", encoding="utf-8", errors="replace") as maps:
        return hdf5_paths(maps)


def hdf5_paths(map_lines) -> dict:
    """{"core": ..., "hl": ...}: the one path of each HDF5 library among the mapped files'
    ``map_lines`` (``/proc/self/maps``); a library mapped from two paths is left out."""
    found: dict = {"core": set(), "hl": set()}
    for line in map_lines:
        path = line.split()[-1] if "/" in line else ""
        name = path.rsplit("/", 1)[-1]
        if name.startswith("libhdf5_hl") and name[len("libhdf5_hl"):][:1] in ("-", "."):
            found["hl"].add(path)
        elif name.startswith("libhdf5") and name[len("libhdf5"):][:1] in ("-", "."):
            found["core"].add(path)
    # one of each, or we cannot tell which is h5py's (another package may bundle its own HDF5)
    return {k: next(iter(v)) for k, v in found.items() if len(v) == 1}


_SIGNATURES = {     # name: (library, restype, argtypes)
    "H5Screate_simple": ("core", HID, [ctypes.c_int, ctypes.POINTER(ctypes.c_uint64), ctypes.c_void_p]),
    "H5Screate": ("core", HID, [ctypes.c_int]),
    "H5Sclose": ("core", HERR, [HID]),
    "H5Dcreate2": ("core", HID, [HID, ctypes.c_char_p, HID, HID, HID, HID, HID]),
    "H5Dwrite": ("core", HERR, [HID, HID, HID, HID, HID, ctypes.c_void_p]),
    "H5Aexists": ("core", ctypes.c_int, [HID, ctypes.c_char_p]),
    "H5Acreate2": ("core", HID, [HID, ctypes.c_char_p, HID, HID, HID, HID]),
    "H5Awrite": ("core", HERR, [HID, HID, ctypes.c_void_p]),
    "H5Aclose": ("core", HERR, [HID]),
    "H5Fflush": ("core", HERR, [HID, ctypes.c_int]),
    "H5Iis_valid": ("core", ctypes.c_int, [HID]),
    "H5DSset_scale": ("hl", HERR, [HID, ctypes.c_char_p]),
    "H5DSattach_scale": ("hl", HERR, [HID, HID, ctypes.c_uint]),
}


def _bind():
    """The bound calls (a namespace of ctypes functions) and h5py's lock, or None."""
    if os.environ.get("FWDLOOK_H5_NATIVE", "1") == "0" or not os.path.exists("/proc/self/maps"):
        return None
    try:
        import h5py
        from h5py._objects import phil

        if h5py.version.hdf5_version_tuple < (1, 10, 0):        # hid_t is 64 bits from 1.10 on
            return None
        paths = _loaded_libraries()
        if set(paths) != {"core", "hl"}:
            return None
        libs = {k: ctypes.CDLL(p) for k, p in paths.items()}     # already loaded: the same handles
        calls = {}
        for name, (lib, restype, argtypes) in _SIGNATURES.items():
            fn = getattr(libs[lib], name)
            fn.restype, fn.argtypes = restype, argtypes
            calls[name] = fn
        # the same library as h5py's: an identifier h5py made is valid in it
        probe = h5py.h5s.create(h5py.h5s.SCALAR)
        if calls["H5Iis_valid"](probe.id) <= 0:
            return None
    except (OSError, AttributeError, ImportError, ValueError):
        return None
    return type("H5Calls", (), {k: staticmethod(v) for k, v in calls.items()}), phil


LIB = None           # the bound calls, once :func:`enabled` has bound them (None: h5py's calls)
_PHIL = None
_TRIED = False


def enabled() -> bool:
    """Whether the native calls are in use (bound at the first call: 3 ms, not paid at import)."""
    global LIB, _PHIL, _TRIED
    if not _TRIED:
        _TRIED = True
        bound = _bind()
        if bound is not None:
            LIB, _PHIL = bound
    return LIB is not None


def _call(name: str, *args, what: str = ""):
    """``LIB.name(*args)`` under h5py's lock (the GIL released by ctypes); a negative result raises."""
    with _PHIL:
        result = getattr(LIB, name)(*args)
    if result < 0:
        raise NativeError(f"HDF5 {name} failed{' for ' + what if what else ''}")
    return result


def new_dataset(loc_id: int, name: str, a: np.ndarray, file_type_id: int, mem_type_id: int, dcpl_id: int) -> int:
    """A contiguous dataset ``name`` under ``loc_id`` holding the C-contiguous array ``a`` (as
    ``h5d.create`` + ``DatasetID.write(ALL, ALL, a)``); returns its identifier (the caller owns it)."""
    if a.ndim:
        dims = (ctypes.c_uint64 * a.ndim)(*a.shape)
        space = _call("H5Screate_simple", a.ndim, dims, None, what=name)
    else:
        space = _call("H5Screate", H5S_SCALAR, what=name)
    try:
        did = _call("H5Dcreate2", loc_id, name.encode(), file_type_id, space, H5P_DEFAULT, dcpl_id, H5P_DEFAULT,
                    what=name)
    finally:
        _call("H5Sclose", space)
    if a.size:
        _call("H5Dwrite", did, mem_type_id, H5S_ALL, H5S_ALL, H5P_DEFAULT, a.ctypes.data, what=name)
    return did


def write_scalar_attr(obj_id: int, name: str, kind: str, value, file_type_id: int, mem_type_id: int,
                      scalar_space_id: int) -> bool:
    """A scalar attribute (``kind`` str: variable-length UTF-8, float: float64, int: int64) in the scalar
    dataspace ``scalar_space_id``, as ``h5a.create`` + ``AttrID.write``; False (nothing written) when
    ``name`` is already there."""
    key = name.encode()
    if _call("H5Aexists", obj_id, key, what=name) > 0:
        return False
    if kind == "str":
        buf = ctypes.c_char_p(value.encode("utf-8"))
    elif kind == "float":
        buf = ctypes.c_double(value)
    else:
        buf = ctypes.c_int64(value)
    aid = _call("H5Acreate2", obj_id, key, file_type_id, scalar_space_id, H5P_DEFAULT, H5P_DEFAULT, what=name)
    try:
        _call("H5Awrite", aid, mem_type_id, ctypes.byref(buf), what=name)
    finally:
        _call("H5Aclose", aid)
    return True


def set_scale(dataset_id: int, name: str) -> None:
    _call("H5DSset_scale", dataset_id, name.encode(), what=name)


def attach_scale(dataset_id: int, scale_id: int, axis: int) -> None:
    _call("H5DSattach_scale", dataset_id, scale_id, axis)


def flush(file_id: int) -> None:
    """The file's metadata written out (as ``H5Fflush``), so that h5py's close has little left to do."""
    _call("H5Fflush", file_id, H5F_SCOPE_GLOBAL)
