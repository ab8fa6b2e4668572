"""Point-target quality metrics: peak position, 3 dB width, PSLR and ISLR.

Pure functions over numpy arrays, no I/O.  A profile is a complex (or real) 1-D cut through a
focused point target, sampled at ``spacing`` physical units per sample (metres for a range cut,
for example).  The metrics follow the paper's ISLR definition, eq. (27),

    ISLR = 10 log10((P_total - P_main) / P_main),

with the main lobe taken between the first minima (nulls) on either side of the peak of the
band-limited (FFT zero-padded) oversampled power, and P_total the energy inside the analysis
window (the whole profile, or +/- ``window_cells`` input samples around the peak).

Closed forms for an unweighted sinc (:func:`ideal_sinc_pslr_db`, :func:`ideal_sinc_islr_db`) are
provided as test oracles.
"""

from __future__ import annotations

import math
import numbers

import ducc0
import numpy as np

from .blas import worker_threads

__all__ = ["oversample_profile", "oversample_range", "interpolate_peak", "image_peak_2d"]

# Fraction of the peak power that defines the 3 dB (half-power) width.
_HALF_POWER = 0.5


def _check_factor(factor):
    if isinstance(factor, (bool, np.bool_)) or not isinstance(factor, numbers.Integral):
        raise ValueError(f"factor must be an integer >= 1, got {factor!r}")
    if factor < 1:
        raise ValueError(f"factor must be an integer >= 1, got {factor!r}")
    return int(factor)


def oversample_profile(profile, factor):
    """Band-limited oversampling of a 1-D profile by FFT zero-padding.

    Parameters
    ----------
    profile : array_like, shape (n,)
        Complex or real samples, ``n >= 1``.
    factor : int
        Integer oversampling factor, ``>= 1``.

    Returns
    -------
    numpy.ndarray, complex, shape (n * factor,)
        Samples of the periodic band-limited interpolant at positions ``m / factor``
        (in input samples), ``m = 0 .. n*factor - 1``.  ``out[::factor]`` equals ``profile``
        to rounding error.

    Raises
    ------
    ValueError
        If ``profile`` is not 1-D, is empty or is not finite, or ``factor`` is not an integer
        ``>= 1``.

    Notes
    -----
    The length-``n`` DFT is zero-padded in the middle of its FFT-ordered spectrum (that is, at the
    highest frequencies of the centred spectrum), so the interpolant is the trigonometric
    polynomial of lowest degree through the samples, assuming the profile is one period of a
    periodic signal.  For even ``n`` the Nyquist bin ``X[n/2]`` is split in two halves placed at
    ``+n/2`` and ``-n/2``; this keeps a real input's interpolant real and the input samples
    exact.  The last ``factor - 1`` output samples lie between the last and the (wrapped) first
    input sample.  The result agrees with :func:`scipy.signal.resample`.

    References
    ----------
    .. [1] A. V. Oppenheim, R. W. Schafer, *Discrete-Time Signal Processing*, 3rd ed.,
       Prentice Hall, 2010, sec. 4.6 (upsampling) and sec. 8.6 (DFT zero-padding).
    """
    x = np.asarray(profile)
    factor = _check_factor(factor)
    if x.ndim != 1:
        raise ValueError(f"profile must be 1-D, got shape {x.shape}")
    n = x.size
    if n == 0:
        raise ValueError("profile must not be empty, got length 0")
    if not np.all(np.isfinite(x)):
        raise ValueError("profile must be finite, got NaN or inf")
    x = x.astype(np.complex128)
    if factor == 1:
        return x.copy()
    m = n * factor
    spec = np.fft.fft(x)
    padded = np.zeros(m, dtype=np.complex128)
    if n % 2:
        half = (n + 1) // 2  # bins 0 .. (n-1)/2 are non-negative frequencies
        padded[:half] = spec[:half]
        padded[m - (n - half):] = spec[half:]
    else:
        half = n // 2
        padded[:half] = spec[:half]
        if half > 0:
            padded[m - half + 1:] = spec[half + 1:]
        # even n: split the Nyquist bin between +n/2 and -n/2
        padded[half] += 0.5 * spec[half]
        padded[m - half] += 0.5 * spec[half]
    return np.fft.ifft(padded) * factor


def _parabola_vertex(y_minus, y_0, y_plus):
    """Vertex offset and value of the parabola through (-1, y-), (0, y0), (1, y+)."""
    curvature = y_minus - 2.0 * y_0 + y_plus
    if not curvature < 0.0:  # not concave (or NaN): no interior maximum
        return 0.0, y_0
    offset = 0.5 * (y_minus - y_plus) / curvature
    offset = min(max(offset, -1.0), 1.0)  # stay inside the fitted span
    slope = 0.5 * (y_plus - y_minus)
    value = y_0 + slope * offset + 0.5 * curvature * offset * offset
    return offset, value


def _interp3(p_minus, p_0, p_plus):
    """Three-point peak fit; returns (offset, peak_power, used_log)."""
    if p_minus > 0.0 and p_0 > 0.0 and p_plus > 0.0:
        offset, log_peak = _parabola_vertex(math.log(p_minus), math.log(p_0), math.log(p_plus))
        return offset, math.exp(log_peak), True
    offset, peak = _parabola_vertex(p_minus, p_0, p_plus)
    return offset, peak, False


def _check_power_1d(power, name="power"):
    p = np.asarray(power)
    if p.ndim != 1 or p.size == 0:
        raise ValueError(f"{name} must be a non-empty 1-D array, got shape {p.shape}")
    if np.iscomplexobj(p):
        raise ValueError(f"{name} must be real (a power, not a complex amplitude), got dtype {p.dtype}")
    return p.astype(np.float64)


def _check_index(index, size, name="index"):
    if isinstance(index, (bool, np.bool_)) or not isinstance(index, numbers.Integral):
        raise ValueError(f"{name} must be an integer, got {index!r}")
    if not 0 <= index < size:
        raise ValueError(f"{name} must be in [0, {size - 1}], got {index!r}")
    return int(index)


def interpolate_peak(power, index):
    """Sub-sample peak location by a three-point parabolic fit to log power.

    Parameters
    ----------
    power : array_like of float, shape (n,)
        Power samples (``|amplitude|**2``, linear units, not dB).
    index : int
        Index of a local maximum of ``power``.

    Returns
    -------
    fractional_index : float
        Interpolated peak location in samples, within ``index - 1 .. index + 1``.
    peak_power : float
        Interpolated peak power, linear units.

    Raises
    ------
    ValueError
        If ``power`` is not a non-empty real 1-D array or ``index`` is not an integer inside it.

    Notes
    -----
    A parabola is fitted to ``ln(power)`` at ``index - 1, index, index + 1``; this is exact for a
    Gaussian peak and close for the main lobe of a sinc.  If any of the three values is not
    positive the parabola is fitted to the linear power instead (exact for a parabola).  At
    either end of the array (``index == 0`` or ``n - 1``), or if the three points are not
    strictly concave, no fit is made and ``(float(index), power[index])`` is returned.  The offset
    is limited to +/- 1 sample (it stays within +/- 0.5 when ``index`` is a local maximum).

    References
    ----------
    .. [1] M. A. Richards, *Fundamentals of Radar Signal Processing*, 2nd ed., McGraw-Hill,
       2014, sec. 5.3 (parabolic and Gaussian peak interpolation).
    """
    p = _check_power_1d(power)
    i = _check_index(index, p.size)
    if i == 0 or i == p.size - 1:
        return float(i), float(p[i])
    offset, peak, _ = _interp3(p[i - 1], p[i], p[i + 1])
    return i + offset, float(peak)


def image_peak_2d(image_power, i, j):
    """Separable 2-D parabolic interpolation of a peak in a power image.

    Parameters
    ----------
    image_power : array_like of float, shape (ni, nj)
        Power image (linear units).
    i, j : int
        Row and column of a local maximum.

    Returns
    -------
    fi, fj : float
        Interpolated peak row and column (fractional indices).
    peak_power : float
        Interpolated peak power.

    Raises
    ------
    ValueError
        If the image is not a non-empty real 2-D array or ``(i, j)`` is outside it.

    Notes
    -----
    ``fi`` comes from :func:`interpolate_peak` on column ``j`` about row ``i`` and ``fj`` from
    row ``i`` about column ``j`` (the same log-power fit, the same clamping at the edges).  The
    peak value assumes a separable peak without a cross term: with the log fit,
    ``ln P = ln P_i + ln P_j - ln P[i, j]`` (exact for a separable Gaussian); when the linear fit
    is used on either axis (a non-positive neighbour), ``P = P_i + P_j - P[i, j]``.
    """
    img = np.asarray(image_power)
    if img.ndim != 2 or img.size == 0:
        raise ValueError(f"image_power must be a non-empty 2-D array, got shape {img.shape}")
    if np.iscomplexobj(img):
        raise ValueError(f"image_power must be real, got dtype {img.dtype}")
    img = img.astype(np.float64)
    i = _check_index(i, img.shape[0], "i")
    j = _check_index(j, img.shape[1], "j")
    centre = float(img[i, j])

    def axis_fit(line, k):
        if k == 0 or k == line.size - 1:
            return 0.0, centre, None
        return _interp3(line[k - 1], line[k], line[k + 1])

    di, pi_, log_i = axis_fit(img[:, j], i)
    dj, pj, log_j = axis_fit(img[i, :], j)
    if log_i is False or log_j is False:
        peak = pi_ + pj - centre
    elif centre > 0.0:
        peak = pi_ * pj / centre
    else:  # both axes clamped and a non-positive centre
        peak = centre
    return i + di, j + dj, float(peak)


def oversample_range(x, factor: int, workers: int = -1, out=None):
    """Band-limited oversampling of the last (range) axis by ``factor`` (amplitudes kept: the native
    samples come back at every ``factor``-th output sample), complex output of ``x``'s precision.

    Each row's n-point spectrum is zero-padded to ``n factor`` points, the Nyquist bin of an even n
    split in halves between +n/2 and -n/2 (as :func:`oversample_profile` and
    ``scipy.signal.resample``: the interpolant of least energy, real rows stay real), then inverted.
    The three steps run fused, row by row while the row is in the cache, in
    ``ducc0.fft.convolve_axis`` (a unit impulse as its kernel: a resampling alone), with no padded
    spectrum in memory: about half the time of a forward FFT, a padded copy and an inverse FFT of the
    whole block (README, Speed).  ``workers``: threads (-1: :func:`dsp.blas.worker_threads`, the
    cores this process may use as the stages' pools take them, ``FWDLOOK_THREADS`` and a sweep
    worker's ``OMP_NUM_THREADS`` obeyed).  ``out``: where to write it (of the output's shape and
    ``x``'s complex dtype, rows contiguous), else a new array."""
    factor = _check_factor(factor)
    x = np.asarray(x)
    if not np.iscomplexobj(x):
        x = x.astype(np.result_type(x.dtype, np.complex64))
    elif not x.dtype.isnative:                 # a big-endian file's array, read as it lies: ducc0 takes
        x = x.astype(x.dtype.newbyteorder("="))  # the machine's byte order only
    if factor == 1:
        return x
    n = x.shape[-1]
    impulse = np.zeros(n, dtype=x.dtype)
    impulse[0] = 1
    if out is None:
        out = np.empty(x.shape[:-1] + (n * factor,), dtype=x.dtype)
    if out.size == 0:
        return out
    threads = worker_threads() if workers == -1 else int(workers)
    return ducc0.fft.convolve_axis(x, out, x.ndim - 1, impulse, nthreads=threads)
