"""Per-pulse peak range track of a range-compressed echo and its migration span."""
from __future__ import annotations

import math

import numpy as np

from ..dsp.peaks import oversample_range

SPAN_SMOOTH_PULSES = 32        # running mean of the per-pulse peak range before max - min
TRACK_OVERSAMPLE = 4           # band-limited oversampling of each pulse's range profile


def peak_track(echo_rc, factor=TRACK_OVERSAMPLE, gate=None):
    """Per-pulse interpolated peak of range-time data ``[n_pulses, n_range]``.

    Each pulse's range profile is oversampled ``factor`` times (band-limited), its maximum (within
    ``gate = (lo, hi)`` range samples if given) refined by a three-point parabola on log power.
    Returns (position in range samples [n_pulses], peak power).
    """
    fine = oversample_range(echo_rc, factor)      # every pulse's range profile
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
    n_range = np.shape(echo_rc)[1]
    if gate is not None and not (gate[1] >= 0 and gate[0] <= n_range - 1):   # the track is off the axis
        return math.nan, np.full(np.shape(echo_rc)[0], math.nan), np.zeros(np.shape(echo_rc)[0], bool)
    pos, peak = peak_track(echo_rc, gate=gate)
    present = peak >= 0.25 * np.median(peak)
    track = pos[present]
    if smooth > 1 and track.size >= smooth:
        track = np.convolve(track, np.ones(smooth) / smooth, mode="valid")
    span = float(track.max() - track.min()) if track.size else math.nan
    return span, pos, present
