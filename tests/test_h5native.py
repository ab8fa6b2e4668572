"""The stage files' HDF5 calls made through ctypes (io/h5native.py): the same bytes as h5py's calls,
bound only to h5py's own library, and a failed call a clean error with no file left behind."""
from __future__ import annotations

import ctypes
import datetime
import os
import subprocess
import sys

import h5py
import numpy as np
import pytest

import fwdlook_cli.io.h5 as h5mod
from fwdlook_cli.io import h5native
from fwdlook_cli.io.stagefile import StageData, load_verified, read_stage, write_stage

native_only = pytest.mark.skipif(not h5native.enabled(), reason="no /proc/self/maps or h5py's HDF5 not bindable")


class _FixedClock:
    """``io.h5``'s ``_dt`` with a fixed ``created_utc``, so that two writes of the same data compare bytewise."""
    timezone = datetime.timezone

    class datetime:
        @staticmethod
        def now(tz=None):
            return datetime.datetime(2026, 12, 5, 9, 0, 0, tzinfo=tz)


def _stage_data():
    rng = np.random.default_rng(7)
    n_t, n_r = 37, 11
    d = StageData(attrs={"gain": 1.25, "count": 3, "label": "säum", "flag": True, "pair": [1.0, 2.0]})
    d.add("slow_time_s", np.linspace(0.0, 1.0, n_t), ("slow_time_s",), "s", "slow time")
    d.add("range_m", np.arange(n_r, dtype=np.float32) * 1.5, ("range_m",), "m", "slant range")
    d.add("xyz", np.array([b"x", b"y", b"z"]), ("xyz",), "1", "axis")                     # a string coordinate
    z = (rng.standard_normal((n_t, n_r)) + 1j * rng.standard_normal((n_t, n_r))).astype(np.complex64)
    d.add("sum", z, ("slow_time_s", "range_m"), "1", "sum channel")
    d.add("diff", z.astype(np.complex128) * 0.5, ("slow_time_s", "range_m"), "1", "difference channel")
    d.add("index", np.arange(n_t, dtype=np.int32), ("slow_time_s",), "1", "pulse index")
    d.add("mask", rng.random(n_t) > 0.5, ("slow_time_s",), "1", "kept")
    d.add("position_m", rng.standard_normal((n_t, 3)), ("slow_time_s", "xyz"), "m", "antenna position")
    d.add("nothing", np.zeros((0, n_r), np.float32), ("none", "range_m"), "1", "empty")
    d.add("none", np.zeros(0), ("none",), "1", "an empty axis")
    return d


def _write(path, data):
    write_stage(path, data, stage="test", key="k" * 64, input_key="i" * 64, params={"a": 1, "b": [1.5, "x"]},
                extra_attrs={"compute_s": 0.25})


@native_only
def test_stage_files_are_the_bytes_h5py_writes(tmp_path, monkeypatch):
    monkeypatch.setattr(h5mod, "_dt", _FixedClock)
    data = _stage_data()
    _write(tmp_path / "native.h5", data)
    monkeypatch.setattr(h5native, "LIB", None)        # every call through h5py, as before
    assert not h5native.enabled()
    _write(tmp_path / "h5py.h5", data)
    a, b = (tmp_path / "native.h5").read_bytes(), (tmp_path / "h5py.h5").read_bytes()
    assert len(a) == len(b) and a == b
    back = read_stage(tmp_path / "native.h5")
    for name, var in data.vars.items():
        assert np.array_equal(np.asarray(back[name]), var.data), name
        assert back.vars[name].dims == var.dims, name
    with h5py.File(tmp_path / "native.h5", "r") as f:           # dimension scales attached, as h5py does
        assert f["sum"].dims[0][0].name == "/slow_time_s" and f["sum"].dims[1][0].name == "/range_m"
        assert f["sum"].attrs["units"] == "1" and f.attrs["label"] == "säum"


@native_only
def test_a_native_stage_file_is_reused(tmp_path):
    _write(tmp_path / "s.h5", _stage_data())
    loaded, reason = load_verified(tmp_path / "s.h5", "k" * 64)
    assert reason is None and loaded is not None


@native_only
def test_a_failed_native_call_raises_and_leaves_no_file(tmp_path, monkeypatch):
    real = h5native._call

    def failing(name, *args, what=""):
        if name == "H5Dwrite":
            return real("H5Dwrite", -1, *args[1:], what=what)     # an invalid identifier: HDF5 refuses
        return real(name, *args, what=what)

    monkeypatch.setattr(h5native, "_call", failing)
    with pytest.raises(h5native.NativeError, match="H5Dwrite"):
        _write(tmp_path / "s.h5", _stage_data())
    assert os.listdir(tmp_path) == []          # neither the file nor its .partial


@native_only
def test_the_calls_release_the_gil():
    # ctypes releases the GIL around a call into a CDLL function, never around a PyDLL one
    for name in h5native._SIGNATURES:
        assert not getattr(h5native.LIB, name)._flags_ & ctypes._FUNCFLAG_PYTHONAPI, name


def test_only_one_hdf5_library_of_each_kind_is_bound():
    lines = ["7f00-7f01 r-xp 0 00:00 1 /site/h5py.libs/libhdf5-9e18f0c6.so.320.0.0",
             "7f02-7f03 r--p 0 00:00 1 /site/h5py.libs/libhdf5-9e18f0c6.so.320.0.0",
             "7f04-7f05 r-xp 0 00:00 2 /site/h5py.libs/libhdf5_hl-69da89c9.so.320.0.0",
             "7f06-7f07 r-xp 0 00:00 3 /usr/lib/libhdf5_cpp.so.200",
             "7f08-7f09 rw-p 0 00:00 0 [heap]"]
    assert h5native.hdf5_paths(lines) == {"core": "/site/h5py.libs/libhdf5-9e18f0c6.so.320.0.0",
                                          "hl": "/site/h5py.libs/libhdf5_hl-69da89c9.so.320.0.0"}
    # a second libhdf5 (another package's own): which one h5py uses cannot be told from the paths
    two = lines + ["7f0a-7f0b r-xp 0 00:00 4 /site/netCDF4.libs/libhdf5-1a2b3c4d.so.310.3.0"]
    assert h5native.hdf5_paths(two) == {"hl": "/site/h5py.libs/libhdf5_hl-69da89c9.so.320.0.0"}


def test_the_native_calls_can_be_turned_off():
    code = "from fwdlook_cli.io import h5native; print(h5native.enabled())"
    out = subprocess.run([sys.executable, "-c", code], env={**os.environ, "FWDLOOK_H5_NATIVE": "0"},
                         capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
