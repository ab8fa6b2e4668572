"""Per-pulse peak range track of a range-compressed echo and its migration span."""
from __future__ import annotations

import numpy as np
import scipy.fft as sfft
import math

SPAN_SMOOTH_PULSES = 32        # running mean of the per-pulse peak range before max - min
TRACK_OVERSAMPLE = 4           # band-limited oversampling of each pulse's range profile


def _oversample_rows(x, factor):
    """Band-limited oversampling of every row (axis 1), as metrics.oversample_profile row by row."""
    x = np.asarray(x)
    n = x.shape[1]
    m = n * factor
    spec = sfft.fft(x, axis=1, workers=-1)
    padded = np.zeros((x.shape[0], m), dtype=np.complex64 if x.dtype == np.complex64 else np.complex128)
    if n % 2:
        half = (n + 1) // 2
        padded[:, :half] = spec[:, :half]
        padded[:, m - (n - half):] = spec[:, half:]
    else:
        half = n // 2
        padded[:, :half] = spec[:, :half]
        padded[:, m - half + 1:] = spec[:, half + 1:]
        padded[:, half] += 0.5 * spec[:, half]
        padded[:, m - half] += 0.5 * spec[:, half]
    return sfft.ifft(padded, axis=1, workers=-1, overwrite_x=True) * factor


def peak_track(echo_rc, factor=TRACK_OVERSAMPLE, gate=None):
    """Per-pulse interpolated peak of range-time data ``[n_pulses, n_range]``.

    Each pulse's range profile is oversampled ``factor`` times (band-limited), its maximum (within
    ``gate = (lo, hi)`` range samples if given) refined by a three-point parabola on log power.
    Returns (position in range samples [n_pulses], peak power).
    """
    fine = _oversample_rows(echo_rc, factor)
    p = (fine.real.astype(np.float64) ** 2 + fine.imag.astype(np.float64) ** 2)
    del fine
    m = p.shape[1]
    rows = np.arange(p.shape[0])
    if gate is None:
        k = np.argmax(p, axis=1)
    else:
        lo = max(0, int(np.floor(gate[0] * factor)))
        hi = min(m, int(np.ceil(gate[1] * factor)) + 1)
        k = lo + np.argmax(p[:, lo:hi], axis=1)
    tiny = 1e-300
    lm = np.log(np.maximum(p[rows, (k - 1) % m], tiny))
    l0 = np.log(np.maximum(p[rows, k], tiny))
    lp = np.log(np.maximum(p[rows, (k + 1) % m], tiny))
    curv = lm - 2.0 * l0 + lp
    with np.errstate(divide="ignore", invalid="ignore"):
        off = np.where(curv < 0.0, 0.5 * (lm - lp) / curv, 0.0)
    off = np.clip(off, -1.0, 1.0)
    peak = np.exp(l0 + 0.5 * (lp - lm) * off + 0.5 * curv * off**2)
    return (k + off) / factor, peak


def migration_span_cells(echo_rc, *, smooth=SPAN_SMOOTH_PULSES, gate=None):
    """Migration span (module docstring, Metrics): max minus min of the smoothed per-pulse peak range,
    in range samples, over the pulses where the target is present.  ``gate = (lo, hi)`` (range samples)
    restricts the peak search to one scatterer's track.  Returns (span, positions, present).
    """
    pos, peak = peak_track(echo_rc, gate=gate)
    present = peak >= 0.25 * np.median(peak)
    track = pos[present]
    if smooth > 1 and track.size >= smooth:
        track = np.convolve(track, np.ones(smooth) / smooth, mode="valid")
    span = float(track.max() - track.min()) if track.size else math.nan
    return span, pos, present
