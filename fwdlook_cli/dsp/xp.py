"""The array module of a processing backend: numpy on the CPU, CuPy on a GPU (``processing.backend``).

The GPU stages (:mod:`forward.gpu_stages`) are written once against an array module ``xp`` and its FFT
module: ``numpy`` with ``scipy.fft`` (``workers=-1``), or ``cupy`` with ``cupyx.scipy.fft``.  CuPy is
an optional dependency (``pip install -e .[gpu]``); nothing here imports it unless ``gpu`` is asked for,
so fwdlook imports and runs without it.

``FWDLOOK_XP=numpy`` in the environment makes ``get_xp("gpu")`` return numpy: the GPU code path, run on
the host (a test hook; the results are those of the GPU code, computed by numpy).
"""
from __future__ import annotations

import os

import numpy as np
import scipy.fft

from ..errors import BadInput

BACKENDS = ("cpu", "gpu")
ENV_XP = "FWDLOOK_XP"
INSTALL = "pip install -e .[gpu]"


def _no_gpu(reason: str, key: str) -> BadInput:
    return BadInput(f"{key} = gpu: {reason}; allowed on this machine: cpu "
                    f"(gpu needs CuPy and a CUDA device: {INSTALL})")


def get_xp(backend: str = "cpu", key: str = "processing.backend"):
    """The array module of ``backend``: numpy for ``cpu``, cupy for ``gpu``.

    Raises :class:`BadInput` (one line naming ``key``, the setting or option that asked for it, what
    this machine allows and the install line) when ``gpu`` is asked and CuPy or a CUDA device is missing.
    """
    if backend == "cpu":
        return np
    if backend != "gpu":
        raise BadInput(f"processing.backend = {backend!r}: unknown backend; allowed: {', '.join(BACKENDS)}")
    forced = os.environ.get(ENV_XP, "")
    if forced == "numpy":
        return np
    if forced not in ("", "cupy"):
        raise BadInput(f"${ENV_XP} = {forced!r}: allowed: numpy, cupy (or unset)")
    try:
        import cupy
    except Exception as exc:                    # ImportError, or a broken CUDA install
        raise _no_gpu(f"CuPy cannot be imported ({exc.__class__.__name__})", key) from None
    try:
        n_dev = cupy.cuda.runtime.getDeviceCount()
    except Exception as exc:                    # CUDARuntimeError: no driver, no device
        raise _no_gpu(f"no CUDA device ({exc.__class__.__name__})", key) from None
    if n_dev < 1:
        raise _no_gpu("no CUDA device", key)
    return cupy


def require_backend(scn: dict, source: str) -> None:
    """The scenario's ``processing.backend`` available here, or one BadInput line naming ``source`` (before
    a command simulates: ``run`` had written raw.h5 and then refused the GPU)."""
    try:
        get_xp((scn.get("processing") or {}).get("backend", "cpu"))
    except BadInput as exc:
        raise BadInput(f"{source}: {exc}") from None


def is_numpy(xp) -> bool:
    return xp is np


def fft_module(xp):
    """``scipy.fft`` for numpy, ``cupyx.scipy.fft`` for cupy (same names: fft, ifft, next_fast_len)."""
    if is_numpy(xp):
        return scipy.fft
    import cupyx.scipy.fft

    return cupyx.scipy.fft


def fft_kwargs(xp) -> dict:
    """Extra FFT arguments: every core for scipy (``workers=-1``), none for CuPy."""
    return {"workers": -1} if is_numpy(xp) else {}


def to_device(x, xp, dtype=None):
    """``x`` (numpy, or anything ``np.asarray`` reads: an h5py dataset slice) as an ``xp`` array."""
    if is_numpy(xp) or not hasattr(x, "__cuda_array_interface__"):
        x = np.asarray(x, dtype=dtype)          # a host array (reads an h5py dataset)
    return xp.asarray(x, dtype=dtype)


def to_host(x):
    """An ``xp`` array as a numpy array (a copy from the device for CuPy)."""
    get = getattr(x, "get", None)               # cupy.ndarray.get: the copy to the host
    return np.asarray(x) if get is None else get()


def synchronize(xp) -> None:
    """Wait for the device's queued work (CuPy runs asynchronously); nothing for numpy."""
    if not is_numpy(xp):
        xp.cuda.Device().synchronize()


def cis(xp, cycles, dtype=np.complex64):
    """``exp(j 2 pi cycles)`` on ``xp``: the phase reduced to [-1/2, 1/2] cycle in float64 first, the
    cosine and sine then taken in float32 for complex64 (2e-7 rad, below its resolution)."""
    ph = xp.asarray(cycles, dtype=xp.float64)
    ph = ph - xp.rint(ph)
    ph *= 2.0 * np.pi
    if np.dtype(dtype) == np.complex64:
        ph = ph.astype(xp.float32)
    out = xp.empty(ph.shape, dtype=dtype)
    out.real = xp.cos(ph)
    out.imag = xp.sin(ph)
    return out
