"""A stand-in for CuPy in tests: numpy underneath, but device arrays of their own type that refuse
host arrays in their arithmetic, as CuPy does (``TypeError: Unsupported type <class 'numpy.ndarray'>``).

Installed as ``cupy`` and ``cupyx.scipy.fft`` in ``sys.modules``, it lets the GPU code path run its CuPy
branches (``dsp.xp`` sees a module that is not numpy): every host array that reaches device arithmetic
without ``xp.asarray``, every device array that reaches the host without ``.get()`` through a checked
path, and every FFT called with scipy-only arguments (``workers``) fails here as it would on a GPU.
It cannot tell whether CuPy's own kernels round like numpy's (they do not quite): that needs a GPU.
"""
from __future__ import annotations

import types

import numpy as np
import scipy.fft


class DeviceArray(np.ndarray):
    """A 'device' array: arithmetic with a host ndarray (not a scalar) raises, as in CuPy."""

    def __array_ufunc__(self, ufunc, method, *inputs, out=None, **kwargs):
        for x in inputs + (out or ()):
            if isinstance(x, np.ndarray) and not isinstance(x, DeviceArray):
                raise TypeError(f"fake cupy: host array {x.shape} {x.dtype} in device {ufunc.__name__}")
        args = [x.view(np.ndarray) if isinstance(x, DeviceArray) else x for x in inputs]
        if out is not None:
            kwargs["out"] = tuple(o.view(np.ndarray) for o in out)
        result = getattr(ufunc, method)(*args, **kwargs)
        if out is not None:
            return out[0] if len(out) == 1 else out
        return _dev(result)

    def __setitem__(self, key, value):
        if isinstance(value, np.ndarray) and not isinstance(value, DeviceArray) and value.ndim:
            raise TypeError(f"fake cupy: host array {value.shape} assigned into a device array")
        super().__setitem__(key, value)

    def get(self):
        return np.array(self.view(np.ndarray))


def _dev(x):
    if isinstance(x, tuple):
        return tuple(_dev(v) for v in x)
    if isinstance(x, np.ndarray):
        return x.view(DeviceArray)
    return x


def _checked(fn, name, forbid=()):
    def wrapper(x, *args, **kwargs):
        if not isinstance(x, DeviceArray):
            raise TypeError(f"fake cupy: {name} of a host {type(x).__name__}")
        bad = set(kwargs) & set(forbid)
        if bad:
            raise TypeError(f"fake cupy: {name}() got an unexpected keyword argument {bad.pop()!r}")
        return _dev(fn(x.view(np.ndarray), *args, **kwargs))
    return wrapper


def asarray(x, dtype=None):
    if isinstance(x, DeviceArray):
        return x if dtype is None else x.astype(dtype, copy=False)
    return np.array(x, dtype=dtype).view(DeviceArray)


def install(monkeypatch):
    """Put the fake into sys.modules as cupy and cupyx.scipy.fft (undone by ``monkeypatch``)."""
    import sys

    cp = types.ModuleType("cupy")
    cp.ndarray = DeviceArray
    cp.asarray = asarray
    for name in ("float32", "float64", "complex64", "complex128", "int64", "rint", "cos", "sin", "maximum",
                 "matmul"):
        setattr(cp, name, getattr(np, name))
    for name in ("empty", "zeros"):
        setattr(cp, name, lambda shape, dtype=float, _f=getattr(np, name): _f(shape, dtype).view(DeviceArray))
    cp.arange = lambda *a, **k: np.arange(*a, **k).view(DeviceArray)
    cp.ascontiguousarray = _checked(np.ascontiguousarray, "ascontiguousarray")
    cp.sort = _checked(np.sort, "sort")
    cp.nonzero = _checked(np.nonzero, "nonzero")
    cp.fft = types.SimpleNamespace(fftshift=_checked(np.fft.fftshift, "fftshift"))
    device = types.SimpleNamespace(id=0, synchronize=lambda: None)
    cp.cuda = types.SimpleNamespace(Device=lambda *a: device, runtime=types.SimpleNamespace(
        getDeviceCount=lambda: 1, getDeviceProperties=lambda i: {"name": b"fake cupy (numpy)"}))
    fft = types.ModuleType("cupyx.scipy.fft")
    for name in ("fft", "ifft", "fft2"):
        setattr(fft, name, _checked(getattr(scipy.fft, name), name, forbid=("workers",)))
    fft.next_fast_len = scipy.fft.next_fast_len
    cupyx, cupyx_scipy = types.ModuleType("cupyx"), types.ModuleType("cupyx.scipy")
    cupyx.scipy, cupyx_scipy.fft = cupyx_scipy, fft
    for name, mod in (("cupy", cp), ("cupyx", cupyx), ("cupyx.scipy", cupyx_scipy), ("cupyx.scipy.fft", fft)):
        monkeypatch.setitem(sys.modules, name, mod)
    return cp
