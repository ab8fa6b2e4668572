"""Shared pieces of the keystone family: argument checks, exp(j 2 pi cycles), the resampling positions
of eq. (8) ``tau = alpha (m' - t0) + t0``."""
from __future__ import annotations

import numpy as np


def min_carrier_hz(fs_hz: float) -> float:
    """The lowest carrier the keystone family can resample for: its scale alpha = (fc + f_r) / fc
    (eq. 8) must stay positive over the whole range-frequency band, f_r in [-fs/2, fs/2)."""
    return 0.5 * float(fs_hz)


def carrier_floor_text(fc_hz: float, fs_hz: float) -> str | None:
    """Why ``fc_hz`` is too low for ``fs_hz`` (the allowed range, for a one-line message), or None."""
    if fc_hz > min_carrier_hz(fs_hz):
        return None
    return (f"must be > fs_hz / 2 = {min_carrier_hz(fs_hz):g} (the keystone's scale (fc + f_r) / fc, "
            f"eq. 8, must stay positive over the range-frequency band +-fs/2)")


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


OUTER_GRID_MAX_ERROR_RAD = 1e-7     # the largest phase error the grid factorisation may add


def cis_outer(rate, freq, grid="auto"):
    """``exp(j rate[m] freq[k])`` in complex64, shape [len(rate), len(freq)] (``rate`` in rad per unit
    of ``freq``): a phase linear in the frequency per row, as every range-frequency compensation is.

    On a grid ``freq = f0 + df u`` (u non-negative integers: ``fftfreq`` in any order, or any part of
    it), u is split as ``a + K b`` and ``exp(j r (f0 + df K b)) * exp(j r df a)`` is built from two
    tables of about sqrt(span) phases per row, each reduced modulo one cycle in float64 (:func:`_cis`):
    one complex64 product per element instead of a cosine and a sine (the product of two unit phasors
    rounded to complex64: error below 4e-7, -128 dB).  ``grid``: ``(f0, df, K)`` from
    :func:`outer_grid` of the whole frequency axis (found once by a caller working in blocks of rows);
    ``"auto"`` takes it from ``freq``; None, or a ``freq`` off any grid, gives the direct
    :func:`cis_rad` of the outer product.  A caller working in blocks of columns keeps the tables
    instead (:class:`OuterPhasors`)."""
    tables = OuterPhasors(rate, freq, grid)
    if tables.u is None:
        return tables.columns(slice(None))
    u, n = tables.u - tables.k * tables.b_lo, tables.u.size
    table = np.multiply(tables.high[:, :, None], tables.low[:, None, :]).reshape(len(tables.rate), -1)  # u - K b_lo
    first = int(u[0])
    if np.array_equal(u, np.arange(first, first + n)):          # one run of the grid: a slice
        return table[:, first:first + n]
    shift = n - first                                           # fftfreq order: a rotation, two slices
    if table.shape[1] >= n and np.array_equal(u, (np.arange(n) + first) % n):
        out = np.empty((len(tables.rate), n), np.complex64)
        out[:, :shift] = table[:, first:n]
        out[:, shift:] = table[:, :first]
        return out
    return np.take(table, u, axis=1)


class OuterPhasors:
    """:func:`cis_outer`'s two phase tables for the rows ``rate`` and the frequencies ``freq``, built
    once, for a caller that works in blocks of columns (the tracking keystone's demodulation):
    :meth:`columns` gathers each block's phasors from them, one complex64 product per element, the same
    numbers for any blocking.  The tables hold rows x 2 sqrt(span) phasors (16 MB for 16384 pulses x
    4096 range bins); off any grid (``u`` None) every block takes the direct :func:`cis_rad`."""

    def __init__(self, rate, freq, grid="auto"):
        self.rate = np.asarray(rate, dtype=np.float64).reshape(-1)
        self.freq = np.asarray(freq, dtype=np.float64).reshape(-1)
        max_rate = float(np.max(np.abs(self.rate), initial=0.0))
        if isinstance(grid, str):
            grid = outer_grid(self.freq, max_rate)
        self.u = None if grid is None else _on_grid(self.freq, grid, max_rate)
        if self.u is not None:
            f0, df, k = grid
            two_pi = 2.0 * np.pi
            self.k, self.b_lo = k, int(self.u.min()) // k
            self.a, self.b = self.u % k, self.u // k - self.b_lo
            self.low = _cis(np.multiply.outer(self.rate * (df / two_pi), np.arange(k, dtype=np.float64)),
                            np.complex64)
            b_values = np.arange(self.b_lo, self.b_lo + int(self.b.max()) + 1, dtype=np.float64)
            self.high = _cis(np.multiply.outer(self.rate / two_pi, f0 + df * k * b_values), np.complex64)

    def columns(self, sel):
        """exp(j rate freq[sel]) [rows, columns of ``sel``] (a slice or an index array)."""
        if self.u is None:
            return cis_rad(np.multiply.outer(self.rate, self.freq[sel]))
        return np.take(self.high, self.b[sel], axis=1) * np.take(self.low, self.a[sel], axis=1)


def outer_grid(freq, max_rate: float):
    """(f0, df, K) of :func:`cis_outer` for the frequencies ``freq`` (the whole axis), or None when they
    are not on a grid ``f0 + df u`` to within a phase error of :data:`OUTER_GRID_MAX_ERROR_RAD` at
    ``max_rate``, are sparse on it, or too few to gain (16)."""
    freq = np.asarray(freq, dtype=np.float64).reshape(-1)
    if freq.size < 16 or not np.all(np.isfinite(freq)):
        return None
    steps = np.diff(np.sort(freq))
    if not np.all(steps > 0):
        return None
    f0, df = float(freq.min()), float(steps.min())
    span = int(np.rint((float(freq.max()) - f0) / df)) + 1
    if span > 4 * freq.size:                     # sparse: the tables would outgrow the direct phases
        return None
    grid = (f0, df, int(np.ceil(np.sqrt(span))))
    return grid if _on_grid(freq, grid, max_rate) is not None else None


def _on_grid(freq, grid, max_rate: float):
    """The integers u >= 0 with ``freq = f0 + df u`` within the phase tolerance, else None."""
    f0, df, _ = grid
    u = np.rint((freq - f0) / df)
    if u.size == 0 or u.min() < 0 or float(np.max(np.abs(f0 + df * u - freq))) * max_rate > OUTER_GRID_MAX_ERROR_RAD:
        return None
    return u.astype(np.intp)


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
