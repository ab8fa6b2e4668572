"""Keystone transform (linear range-walk correction) with Doppler-ambiguity correction.

The keystone of Li & Li (2023), eq. (8), rescales slow time separately in every
range-frequency bin ``f_r``::

    t_m = alpha * t'_m,        alpha = f_c / (f_c + f_r)                  # eq. (8)

so that the linear range walk (the ``f_r * v * t_m`` coupling of eq. (7)) becomes
independent of ``f_r``.  In discrete slow time (pulse index ``m``, unit spacing) each
column ``k`` of a ``[n_slow, n_cols]`` array is resampled at::

    tau[m', k] = alpha[k] * (m' - t0_index[k]) + t0_index[k]

where ``t0_index`` is the keystone time origin in samples (the reference time
``t_ref`` of the processing chain; it may be fractional and may differ per column, e.g.
for decimated sub-sequences that share one global time origin).

Resampling is the band-limited (periodic, DFT) interpolant of the column, with a
*centred* Doppler index (``numpy.fft.fftfreq`` order, ``k = -(n//2) .. (n-1)//2``)::

    X(k)   = sum_m x(m) exp(-j 2 pi k m / n)
    y(tau) = (1/n) sum_k X(k) exp(+j 2 pi k tau / n)

An uncentred index would give negative Dopplers a spurious extra ambiguity.

Doppler ambiguity (eq. 15-17).  The samples of a tone at the true frequency
``F + f`` cycles/pulse (``F`` integer, ``|f| < 1/2``) equal those of the baseband tone
``f``; the interpolant therefore returns the baseband tone at ``tau``, and the true tone
is recovered by multiplying with ``exp(j 2 pi F tau)``.  With ``t0_index = 0`` this is
``exp(j 2 pi F m' f_c / (f_c + f_r))``, the correction of the design NOTES.

Relation to the paper's eq. (21)-(22).  Eq. (21) (a chirp-Z transform, Bluestein's
algorithm) is garbled as printed: its ``W`` mixes ``f_c`` and ``f_r`` incorrectly.  Here
the CZT evaluates the scaled inverse DFT ``sum_k Y(k) W^(k m')`` with
``W = exp(+j 2 pi alpha / n)`` (:class:`KeystonePlan`).  Eq. (22) as printed multiplies by
``exp(j 2 pi F m')``, which is 1 for every integer ``m'`` and thus corrects nothing; the
correction applied here is ``exp(j 2 pi F tau)`` as derived above (NOTES, "Keystone with
Doppler ambiguity").

Three independent implementations are provided:

* :class:`KeystonePlan` -- CZT (Bluestein) with chirps precomputed once per geometry,
  batched FFTs over all columns (fast; the production path).
* :func:`keystone_dft` -- direct O(n^2) evaluation of the interpolant sum (reference).
* :func:`keystone_sinc` -- Kaiser-windowed sinc interpolation in slow time after
  demodulating a reference Doppler (the paper's "SINC interpolation" option).

:func:`keystone` is the one-off convenience wrapper taking ``f_r`` and ``f_c`` in Hz.

References
----------
.. [1] Z.-S. Li and Y.-L. Li, "Decimation keystone algorithm for forward-looking
   monopulse imaging on platforms with uniformly accelerated motion",
   Front. Signal Process. 2:1074053 (2023), doi:10.3389/frsip.2022.1074053.
.. [2] L. I. Rabiner, R. W. Schafer and C. M. Rader, "The chirp z-transform
   algorithm", IEEE Trans. Audio Electroacoust. 17(2), 86-92 (1969).
.. [3] R. P. Perry, R. C. DiPietro and R. L. Fante, "SAR imaging of moving targets",
   IEEE Trans. Aerosp. Electron. Syst. 35(1), 188-200 (1999).
"""

from __future__ import annotations

import numpy as np
from scipy.special import i0

from .keystone_common import _as_2d, _check_dtype, _cis, _n_cols, _per_column, keystone_positions
from .keystone_czt import KeystonePlan

__all__ = [
    "keystone_positions",
    "KeystonePlan",
    "keystone_dft",
    "keystone_sinc",
    "keystone",
    "KAISER_BETA",
]

#: Kaiser window shape parameter of :func:`keystone_sinc`.  With 16 taps the
#: interpolator reproduces a (demodulated) Doppler ``|f| <= 0.35`` cycles/pulse with an
#: error below about -60 dB at any fractional shift, and fails towards the Nyquist edge
#: (about -5 dB at ``|f| = 0.48``), hence the demodulation step.
KAISER_BETA = 6.0

_METHODS = ("czt", "dft", "sinc")
_DFT_CHUNK_BYTES = 200 * 2**20  # memory bound of keystone_dft's kernel chunks
_SINC_CHUNK_ELEMS = 2**21  # taps gathered per chunk in keystone_sinc (~32 MB each)


# --------------------------------------------------------------------------- direct DFT
def keystone_dft(x, alpha, *, t0_index=0.0, ambiguity=0):
    """Keystone by direct evaluation of the band-limited interpolant (reference method).

    Parameters
    ----------
    x : array_like, shape (n_slow, n_cols)
        Slow time along axis 0.
    alpha : float or array_like, shape (n_cols,)
        Time-scale factor per column, ``f_c / (f_c + f_r)`` (eq. 8).
    t0_index : float or array_like, shape (n_cols,), optional
        Keystone time origin in samples.  Default 0.
    ambiguity : int or array_like of int, shape (n_cols,), optional
        Doppler ambiguity number ``F`` (eq. 15-17).  Default 0.

    Returns
    -------
    y : ndarray of complex128, shape (n_slow, n_cols)

    Notes
    -----
    Evaluates, in complex128 and without any chirp factorisation,
    ``y[m', k] = exp(j 2 pi F tau) (1/n) sum_c X_k(c) exp(j 2 pi c tau / n)`` at
    ``tau = alpha (m' - t0) + t0`` with the centred index ``c`` (the "DFT-IFFT" method
    that [1]_ lists beside SINC and CZT).  The cost is O(n^2) per column; the kernel is
    built in chunks of columns (and of output samples for long columns) of at most
    about 200 MB.  Use it to verify :class:`KeystonePlan`.

    References
    ----------
    .. [1] Z.-S. Li and Y.-L. Li, Front. Signal Process. 2:1074053 (2023).
    """
    x = _as_2d(x)
    n, nc = x.shape
    alpha = _per_column(alpha, "alpha", positive=True)
    t0 = _per_column(t0_index, "t0_index")
    F = _per_column(ambiguity, "ambiguity", integer=True)
    _n_cols(alpha, t0, F, n_cols=nc)
    alpha, t0, F = (np.broadcast_to(a, (nc,)) for a in (alpha, t0, F))

    X = np.fft.fft(x.astype(np.complex128), axis=0)  # FFT order
    c = np.fft.fftfreq(n, 1.0 / n)  # centred Doppler index in the same order
    m = np.arange(n, dtype=np.float64)
    y = np.empty((n, nc), dtype=np.complex128)
    per_elem = 32  # float64 phase + its reduction, complex128 kernel
    per_col = n * n * per_elem
    cols = max(1, _DFT_CHUNK_BYTES // per_col)
    rows = n if per_col <= _DFT_CHUNK_BYTES else max(1, _DFT_CHUNK_BYTES // (per_elem * n))
    for k0 in range(0, nc, cols):
        ks = slice(k0, min(nc, k0 + cols))
        for r0 in range(0, n, rows):
            rs = slice(r0, min(n, r0 + rows))
            tau = alpha[ks] * (m[rs, None] - t0[ks]) + t0[ks]  # (rows, cols), eq. (8)
            # kernel E[col, m', c] = exp(j 2 pi c tau / n)
            kern = _cis(tau.T[:, :, None] * (c / n))
            s = np.matmul(kern, X[:, ks].T[:, :, None])[:, :, 0].T / n
            y[rs, ks] = s * _cis(F[ks] * tau)  # ambiguity correction exp(j 2 pi F tau)
    return y


# --------------------------------------------------------------------------- windowed sinc
def keystone_sinc(x, alpha, *, t0_index=0.0, doppler_ref=0.0, n_taps=16):
    """Keystone by Kaiser-windowed sinc interpolation about a reference Doppler.

    Parameters
    ----------
    x : array_like, shape (n_slow, n_cols)
        Slow time along axis 0.
    alpha : float or array_like, shape (n_cols,)
        Time-scale factor per column, ``f_c / (f_c + f_r)`` (eq. 8).
    t0_index : float or array_like, shape (n_cols,), optional
        Keystone time origin in samples.  Default 0.
    doppler_ref : float or array_like, shape (n_cols,), optional
        True (unaliased) reference Doppler of the *output*, in cycles per pulse, e.g.
        the Doppler centroid ``f_dc / PRF`` of eq. (16) or the ambiguity number ``F``.
        Default 0 (no demodulation, no ambiguity correction).
    n_taps : int, optional
        Even number of interpolator taps.  Default 16.

    Returns
    -------
    y : ndarray of complex128, shape (n_slow, n_cols)

    Notes
    -----
    Per column, with ``f0 = doppler_ref / alpha`` (the reference Doppler before the
    time scaling):

    1. demodulate: ``x_d(m) = x(m) exp(-j 2 pi f0 (m - t0))``;
    2. interpolate ``x_d`` at ``tau = alpha (m' - t0) + t0`` with the kernel
       ``sinc(u) w(u)``, ``w`` a Kaiser window of half-width ``n_taps/2`` and
       ``beta = KAISER_BETA`` (6.0), taps normalised to unit sum; samples outside
       ``[0, n_slow - 1]`` are zero;
    3. remodulate: ``exp(j 2 pi f0 (tau - t0)) = exp(j 2 pi doppler_ref (m' - t0))``.

    A sinc interpolator cannot pass a Doppler near the Nyquist edge; the paper's
    boresight Doppler sits near ``-PRF/2`` at baseband, so the demodulation with the
    true Doppler centroid is what makes this method usable (NOTES).  With
    ``doppler_ref = F`` (integer) the result approximates
    ``KeystonePlan(...)(x, ambiguity=F)`` for signals well inside the baseband.

    The taps are gathered with fancy indexing over ``[rows, n_cols, n_taps]`` in
    chunks of slow-time rows; there is no Python loop over columns or samples.

    References
    ----------
    .. [1] Z.-S. Li and Y.-L. Li, Front. Signal Process. 2:1074053 (2023).
    """
    x = _as_2d(x)
    n, nc = x.shape
    if isinstance(n_taps, (bool, np.bool_)) or int(n_taps) != n_taps or n_taps < 2 or n_taps % 2:
        raise ValueError(f"n_taps must be an even integer >= 2, got {n_taps!r}")
    n_taps = int(n_taps)
    alpha = _per_column(alpha, "alpha", positive=True)
    t0 = _per_column(t0_index, "t0_index")
    fref = _per_column(doppler_ref, "doppler_ref")
    _n_cols(alpha, t0, fref, n_cols=nc)
    alpha, t0, fref = (np.broadcast_to(a, (nc,)) for a in (alpha, t0, fref))
    f0 = fref / alpha

    m = np.arange(n, dtype=np.float64)[:, None]
    # 1. demodulate about the reference Doppler (padded with one zero row for gathers)
    xd = np.zeros((n + 1, nc), dtype=np.complex128)
    np.multiply(x, _cis(-f0 * (m - t0)), out=xd[:n])
    xd_flat = xd.ravel()
    zero_index = n * nc  # flat index of a zero sample

    half = n_taps // 2
    j = np.arange(n_taps, dtype=np.int64) - (half - 1)
    beta = KAISER_BETA
    col = np.arange(nc, dtype=np.int64)
    y = np.empty((n, nc), dtype=np.complex128)
    rows = max(1, _SINC_CHUNK_ELEMS // (nc * n_taps))
    for r0 in range(0, n, rows):
        rs = slice(r0, min(n, r0 + rows))
        tau = alpha * (m[rs] - t0) + t0  # eq. (8) about t0
        base = np.floor(tau)
        taps = base.astype(np.int64)[:, :, None] + j  # (rows, nc, n_taps)
        u = tau[:, :, None] - taps
        w = np.sinc(u) * (i0(beta * np.sqrt(np.clip(1.0 - (u / half) ** 2, 0.0, None))) / i0(beta))
        outside = (taps < 0) | (taps >= n)
        w[outside] = 0.0
        # normalise by the taps inside the sequence: near the ends the demodulated (near-DC) signal
        # is extrapolated flat instead of being pulled towards zero
        norm = w.sum(axis=-1, keepdims=True)
        w /= np.where(norm != 0.0, norm, 1.0)   # a position with every tap outside gives 0
        flat = taps * nc + col[:, None]
        flat[outside] = zero_index
        # 2. interpolate, 3. remodulate exp(j 2 pi f0 (tau - t0))
        y[rs] = np.einsum("rct,rct->rc", xd_flat[flat], w) * _cis(f0 * (tau - t0))
    return y


# --------------------------------------------------------------------------- convenience
def keystone(
    x,
    fr_hz,
    fc_hz,
    *,
    ambiguity=0,
    t0_index=0.0,
    method="czt",
    doppler_ref=None,
    n_taps=16,
    dtype=np.complex64,
):
    """Keystone transform of range-frequency/slow-time data, eq. (8) with ambiguity.

    Parameters
    ----------
    x : array_like, shape (n_slow, n_cols)
        Range-frequency data, slow time along axis 0, one range-frequency bin (or one
        bin of one decimated sub-sequence) per column.
    fr_hz : float or array_like, shape (n_cols,)
        Range frequency of each column in Hz (centred, ``-fs/2 .. fs/2``).
    fc_hz : float
        Carrier frequency in Hz.
    ambiguity : int or array_like of int, shape (n_cols,), optional
        Doppler ambiguity number ``F`` (eq. 17).  Default 0.
    t0_index : float or array_like, shape (n_cols,), optional
        Keystone time origin in samples of axis 0.  Default 0.
    method : {"czt", "dft", "sinc"}, optional
        :class:`KeystonePlan` (default), :func:`keystone_dft` or :func:`keystone_sinc`.
    doppler_ref : float or array_like, optional
        Reference Doppler (cycles per pulse) for ``method="sinc"``; defaults to
        `ambiguity`.  Ignored by the other methods.
    n_taps : int, optional
        Interpolator length for ``method="sinc"``.  Default 16.
    dtype : {complex64, complex128}, optional
        Dtype of the result (and working precision of "czt").  Default complex64.

    Returns
    -------
    y : ndarray, shape (n_slow, n_cols), `dtype`

    Notes
    -----
    ``alpha = f_c / (f_c + f_r)`` per column, eq. (8) of [1]_.  For repeated calls
    with the same geometry build a :class:`KeystonePlan` once instead.

    References
    ----------
    .. [1] Z.-S. Li and Y.-L. Li, Front. Signal Process. 2:1074053 (2023).
    """
    if method not in _METHODS:
        raise ValueError(f"method must be one of {_METHODS}, got {method!r}")
    dtype = _check_dtype(dtype)
    x = _as_2d(x)
    fc = np.asarray(fc_hz, dtype=np.float64)
    if fc.ndim != 0 or not np.isfinite(fc) or fc <= 0:
        raise ValueError(f"fc_hz must be a positive finite scalar, got {fc_hz!r}")
    fr = _per_column(fr_hz, "fr_hz")
    if np.any(fc + fr <= 0):
        raise ValueError(f"fc_hz + fr_hz must be > 0, got min fr_hz {fr.min()!r}")
    alpha = fc / (fc + fr)  # eq. (8)
    if method == "czt":
        plan = KeystonePlan(x.shape[0], alpha, t0_index=t0_index, dtype=dtype)
        return plan(x, ambiguity=ambiguity)
    if method == "dft":
        y = keystone_dft(x, alpha, t0_index=t0_index, ambiguity=ambiguity)
    else:
        ref = ambiguity if doppler_ref is None else doppler_ref
        y = keystone_sinc(x, alpha, t0_index=t0_index, doppler_ref=ref, n_taps=n_taps)
    return y.astype(dtype, copy=False)
