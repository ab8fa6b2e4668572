"""Shared pieces of the keystone family: argument checks, exp(j 2 pi cycles), the resampling positions
of eq. (8) ``tau = alpha (m' - t0) + t0``."""
from __future__ import annotations

import numpy as np


# --------------------------------------------------------------------------- helpers
def _as_2d(x, name="x"):
    x = np.asarray(x)
    if x.ndim != 2:
        raise ValueError(
            f"{name} must be 2-D [n_slow, n_cols], got {x.ndim}-D with shape {x.shape}"
        )
    if x.shape[0] < 1:
        raise ValueError(f"{name} needs at least one slow-time sample, got shape {x.shape}")
    return x


def _per_column(value, name, *, positive=False, integer=False):
    """Return ``value`` as a float64 array of shape (n,) or (1,), validated."""
    a = np.asarray(value, dtype=np.float64)
    if a.ndim > 1:
        raise ValueError(f"{name} must be a scalar or 1-D per-column array, got shape {a.shape}")
    a = np.atleast_1d(a)
    if a.size == 0:
        raise ValueError(f"{name} must not be empty")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite, got {value!r}")
    if positive and np.any(a <= 0):
        raise ValueError(f"{name} must be > 0, got min {a.min()!r}")
    if integer and np.any(a != np.round(a)):
        bad = a[a != np.round(a)][0]
        raise ValueError(f"{name} must be integer-valued (Doppler ambiguity number), got {bad!r}")
    return a


def _n_cols(*arrays, n_cols=None):
    """Common column count of per-column arrays (1 when all are scalars)."""
    sizes = {a.size for a in arrays if a.size != 1}
    if n_cols is not None and n_cols != 1:
        sizes.add(n_cols)
    if len(sizes) > 1:
        raise ValueError(f"per-column lengths disagree: {sorted(sizes)}")
    return sizes.pop() if sizes else 1


def _cis(cycles, dtype=np.complex128, reduce_in=np.float64):
    """``exp(j 2 pi cycles)`` with the phase reduced mod 1 cycle in float64 first; the cosine and sine
    are then taken in the output's precision (float32 for complex64: 2e-7 rad, below its resolution).
    ``reduce_in=np.float32`` keeps float32 cycles in float32 throughout (for a caller whose phase is
    already only that precise: a few hundred cycles keep 1e-4 cycle)."""
    dtype = np.dtype(dtype)
    ph = np.asarray(cycles, dtype=reduce_in)
    ph = ph - np.rint(ph)            # reduced to [-1/2, 1/2] cycle (np.mod is ~30 times slower)
    ph *= 2.0 * np.pi
    real = np.float32 if dtype == np.complex64 else np.float64
    ph = ph.astype(real, copy=False)
    out = np.empty(ph.shape, dtype=dtype)
    out.real = np.cos(ph)            # contiguous cos/sin, then one strided copy each (faster than
    out.imag = np.sin(ph)            # writing the ufunc's output through the strided view)
    return out


def cis_rad(phase_rad):
    """exp(j phase) in complex64, the phase (radians) reduced modulo one cycle in float64 first."""
    return _cis(np.asarray(phase_rad) / (2.0 * np.pi), np.complex64)


def _check_dtype(dtype):
    dtype = np.dtype(dtype)
    if dtype not in (np.dtype(np.complex64), np.dtype(np.complex128)):
        raise ValueError(f"dtype must be complex64 or complex128, got {dtype}")
    return dtype


# --------------------------------------------------------------------------- positions
def keystone_positions(n_slow, alpha, t0_index=0.0):
    """Slow-time positions at which the keystone samples each column.

    Parameters
    ----------
    n_slow : int
        Number of slow-time samples (pulses).
    alpha : float or array_like, shape (n_cols,)
        Time-scale factor per column, ``f_c / (f_c + f_r)`` for the keystone (eq. 8).
    t0_index : float or array_like, shape (n_cols,), optional
        Keystone time origin in samples (may be fractional).

    Returns
    -------
    tau : ndarray of float64, shape (n_slow, n_cols)
        ``tau[m', k] = alpha[k] * (m' - t0_index[k]) + t0_index[k]``; ``n_cols`` is 1
        when both ``alpha`` and ``t0_index`` are scalars.

    Notes
    -----
    Eq. (8) of [1]_, ``t_m = alpha t'_m``, written about the time origin ``t0_index``
    rather than about the first pulse.

    References
    ----------
    .. [1] Z.-S. Li and Y.-L. Li, Front. Signal Process. 2:1074053 (2023).
    """
    n_slow = _check_n(n_slow)
    alpha = _per_column(alpha, "alpha", positive=True)
    t0 = _per_column(t0_index, "t0_index")
    _n_cols(alpha, t0)
    m = np.arange(n_slow, dtype=np.float64)[:, None]
    return alpha * (m - t0) + t0  # eq. (8) about t0


def _check_n(n_slow):
    if isinstance(n_slow, (bool, np.bool_)) or int(n_slow) != n_slow or n_slow < 1:
        raise ValueError(f"n_slow must be a positive integer, got {n_slow!r}")
    return int(n_slow)
