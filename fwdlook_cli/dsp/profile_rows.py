"""The point-target measures of ``dsp.profile`` and ``dsp.peaks`` on many profiles at once: one row per
target, each row's valid samples first (``n[t]`` of them), the rest padding that is never read.

Every sample-by-sample walk of the scalar code (the first local minimum either side of the peak, the
half-power crossings) is the same walk written as a search over the row: a walk down from ``k0`` that
stops at the first ``k`` with ``stop[k]`` ends at the largest ``k <= k0`` with ``stop[k]``, and a walk up
at the smallest ``k >= k0``.  The arithmetic is the scalar code's, element by element; only the sums
(numpy's pairwise order over a zero-padded row instead of over the slice) and ``np.log`` against
``math.log`` can differ, in the last bits (``tests/test_profile_rows.py`` holds them to the scalar code).
"""
from __future__ import annotations

import numpy as np

from .peaks import _HALF_POWER


def _last_at_or_below(stop, k0):
    """Per row the largest index ``k <= k0[row]`` with ``stop[row, k]`` (-1 where there is none)."""
    idx = np.arange(stop.shape[1])
    return np.where(stop & (idx[None, :] <= k0[:, None]), idx[None, :], -1).max(axis=1)


def _first_at_or_above(stop, k0):
    """Per row the smallest index ``k >= k0[row]`` with ``stop[row, k]`` (the row length where none)."""
    idx = np.arange(stop.shape[1])
    return np.where(stop & (idx[None, :] >= k0[:, None]), idx[None, :], stop.shape[1]).min(axis=1)


def _at(rows, k):
    """``rows[t, k[t]]`` for every row (``k`` clipped into the row: the callers mask what it reads)."""
    k = np.clip(k, 0, rows.shape[1] - 1)
    return np.take_along_axis(rows, k[:, None], axis=1)[:, 0]


def parabola_vertex_rows(y_minus, y_0, y_plus):
    """``dsp.peaks._parabola_vertex`` element-wise: (offset, value); no fit where not concave."""
    curvature = y_minus - 2.0 * y_0 + y_plus
    concave = curvature < 0.0
    safe = np.where(concave, curvature, -1.0)
    offset = np.clip(0.5 * (y_minus - y_plus) / safe, -1.0, 1.0)
    slope = 0.5 * (y_plus - y_minus)
    value = y_0 + slope * offset + 0.5 * safe * offset * offset
    return np.where(concave, offset, 0.0), np.where(concave, value, y_0)


def peak3_rows(power, k, n):
    """``dsp.peaks.interpolate_peak(power[t, :n[t]], k[t])`` for every row: (fractional index, power).

    The parabola goes through the log power where the three samples are positive, through the power
    otherwise; at either end of the row the sample itself."""
    p_m, p_0, p_p = _at(power, k - 1), _at(power, k), _at(power, k + 1)
    positive = (p_m > 0.0) & (p_0 > 0.0) & (p_p > 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        logs = [np.log(np.where(positive, p, 1.0)) for p in (p_m, p_0, p_p)]
    off_log, val_log = parabola_vertex_rows(*logs)
    off_lin, val_lin = parabola_vertex_rows(p_m, p_0, p_p)
    offset = np.where(positive, off_log, off_lin)
    value = np.where(positive, np.exp(val_log), val_lin)
    end = (k == 0) | (k == n - 1)
    return np.where(end, k.astype(np.float64), k + offset), np.where(end, p_0, value)


def half_power_width_rows(power, index, n, spacing):
    """The per-target metrics' 3 dB width of each row around ``index`` (the cuts' width: walks while the
    power over its value at ``index`` is above 0.5, linear interpolation at both crossings; NaN where a
    side does not cross; the one-row form is ``tests/reference_metrics.py::_width``)."""
    idx = np.arange(power.shape[1])[None, :]
    p = power / _at(power, index)[:, None]
    below = p <= 0.5
    left = _last_at_or_below(below | (idx == 0), index)
    right = _first_at_or_above(below | (idx >= n[:, None] - 1), index)
    p_l, p_l1 = _at(p, left), _at(p, left + 1)
    p_r, p_r1 = _at(p, right), _at(p, right - 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        xl = left + (0.5 - p_l) / (p_l1 - p_l)
        xr = right - (0.5 - p_r) / (p_r1 - p_r)
    closed = (p_l <= 0.5) & (p_r <= 0.5)
    return np.where(closed, (xr - xl) * spacing, np.nan)


def power_metrics_rows(power, n, spacing):
    """``dsp.profile.profile_metrics(sqrt(power[t, :n[t]]), spacing=spacing, oversample=1)`` for every row
    of a power array, as (pslr_db, islr_db, width_3db); NaN where that raises (fewer than 3 samples,
    not finite, all zero or of constant power) or where a measure is undefined."""
    power = np.asarray(power, dtype=np.float64)
    t, width = power.shape
    n = np.asarray(n, dtype=np.intp)
    idx = np.arange(width)[None, :]
    valid = idx < n[:, None]
    nan = np.full(t, np.nan)
    if t == 0:
        return nan, nan.copy(), nan.copy()
    masked_hi = np.where(valid, power, -np.inf)
    p_max = masked_hi.max(axis=1)
    p_min = np.where(valid, power, np.inf).min(axis=1)
    finite = np.where(valid, np.isfinite(power), True).all(axis=1)
    with np.errstate(invalid="ignore"):
        ok = (n >= 3) & finite & (p_max != 0.0) & ~(p_max - p_min <= 1e-12 * p_max)
    pw = np.where(valid & ok[:, None], power, 0.0)          # padding and failed rows: never measured
    k_peak = np.where(valid, pw, -np.inf).argmax(axis=1)       # the first maximum, as the scalar walk
    _, peak_power = peak3_rows(pw, k_peak, n)
    last = n - 1
    prev = np.concatenate([np.full((t, 1), np.inf), pw[:, :-1]], axis=1)      # pw[k - 1]
    nxt = np.concatenate([pw[:, 1:], np.full((t, 1), np.inf)], axis=1)        # pw[k + 1]
    # first local minima either side of the peak (walks while the neighbour is lower)
    k_null_left = _last_at_or_below((idx == 0) | (prev >= pw), k_peak)
    k_null_right = _first_at_or_above((idx >= last[:, None]) | (nxt >= pw), k_peak)
    has_nulls = (k_null_left > 0) & (k_null_right < last)
    # half-power crossings (walks while the power is at the level or over it)
    level = _HALF_POWER * peak_power
    under = pw < level[:, None]
    k_l = _last_at_or_below((idx == 0) | under, k_peak)
    k_r = _first_at_or_above((idx >= last[:, None]) | under, k_peak)
    p_l, p_l1 = _at(pw, k_l), _at(pw, k_l + 1)
    p_r, p_r1 = _at(pw, k_r), _at(pw, (k_r - 1) % np.maximum(n, 1))      # (index -1: Python's last)
    with np.errstate(divide="ignore", invalid="ignore"):
        left_x = k_l + (level - p_l) / (p_l1 - p_l)
        right_x = k_r - (level - p_r) / (p_r1 - p_r)
    crossed = (p_l < level) & (level <= p_l1) & (p_r < level) & (level <= p_r1)
    width_3db = np.where(crossed & ok, (right_x - left_x) * spacing, np.nan)
    # the main lobe between the nulls, the sidelobes the rest of the row; the highest sidelobe refined
    # where it is a local maximum
    main_mask = (idx >= k_null_left[:, None]) & (idx <= k_null_right[:, None])
    side_mask = valid & ~main_mask
    main = np.where(main_mask, pw, 0.0).sum(axis=1)
    side = np.where(side_mask, pw, 0.0).sum(axis=1)
    k_side = np.where(side_mask, pw, -np.inf).argmax(axis=1)
    side_peak = _at(pw, k_side)
    local_max = (k_side > 0) & (k_side < last) & (_at(pw, k_side - 1) <= side_peak) & (side_peak >= _at(pw, k_side + 1))
    side_peak = np.where(local_max, peak3_rows(pw, k_side, n)[1], side_peak)
    measured = ok & has_nulls
    with np.errstate(divide="ignore", invalid="ignore"):
        pslr_db = np.where(measured, 10.0 * np.log10(side_peak / peak_power), np.nan)
        islr_db = np.where(measured, 10.0 * np.log10(side / main), np.nan)      # eq. (27)
    return pslr_db, islr_db, width_3db
