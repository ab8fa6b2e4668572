"""The recorded navigation against itself: velocities against positions, and the positions' roughness.

The chain takes its Doppler histories (the ``tracking`` keystone's, the dwell focus's Doppler bins, the
CPI bands) from ``/platform/velocity_mps`` and its range histories (the dwell image's exact ranges,
``bulk`` and ``beam``) from ``/platform/position_m``.  Two checks, each one warning where it matters:

* *Disagreement.*  d(t) = p(t) - p(0) - integral of v (trapezoids), smoothed over ``SMOOTHING_S`` (white
  position noise is the next check's), projected on the lines of sight of the scan (its ends and its
  middle at the window's depression), and its largest excursion within any beam dwell (the pulses the
  beam takes to cross a point: the span over which a Doppler history is integrated against range
  histories).  Every lag up to the dwell counts, not only the dwell's ends: positions interpolated from
  a 50 Hz solution repeat their error every 20 ms, and a dwell of whole periods had read 0 (an
  independent study).  Over ``VELOCITY_PHASE_RAD`` of round-trip phase (half the dwell's Doppler
  resolution): a velocity bias, a lag of one record against the other, velocities held at a lower rate.
* *Roughness.*  The positions' pulse-to-pulse noise, from their third divided differences along the
  lines of sight (robust: the median absolute deviation, so the kinks of positions interpolated linearly from a
  navigation solution, a few samples in each period, do not count), as round-trip phase; over
  ``ROUGHNESS_PHASE_RAD`` the dwell image's exact ranges carry it (1 mm at 18 GHz, 0.75 rad: the study
  measured the isolated scene's dwell image -8.4 dB from the clean one).

Neither sees a lag common to both records (a time-tag offset against the radar): they agree with each
other; only the echoes could show it (README, "Raw cube files").

``processing.navigation`` then chooses what the chain takes (:func:`with_navigation`): ``recorded``
(both as stored), ``positions`` (the velocities from the positions' smoothed derivative: right where
the velocities are the bad record, wrong where the positions are noisy) or ``fused`` (a complementary
blend: the low frequencies of the positions, the high ones of the velocities' integral, crossing over
at ``FUSED_CROSSOVER_S``; both records replaced by one consistent track).
"""
from __future__ import annotations

import dataclasses
import logging

import numpy as np

from ..dsp.geometry import C_MPS
from ..errors import BadInput

log = logging.getLogger(__name__)

VELOCITY_PHASE_RAD = np.pi     # velocities against positions within a beam dwell: half its Doppler resolution
ROUGHNESS_PHASE_RAD = 0.5      # the positions' pulse-to-pulse noise as round-trip phase (exp(-0.25): -1.1 dB)
SMOOTHING_S = 0.02             # the smoothing of the disagreement and of the positions' derivative
FUSED_CROSSOVER_S = 0.05       # navigation: fused: the positions below 1 / (this) Hz, the velocities above
NAVIGATION_MODES = ("recorded", "positions", "fused")


def velocity_integral_m(slow_time_s, velocity_mps) -> np.ndarray:
    """The recorded velocities' trapezoidal integral from the first pulse, [n_pulses, 3] metres (exact for
    a constant acceleration)."""
    t = np.asarray(slow_time_s, dtype=np.float64)
    v = np.asarray(velocity_mps, dtype=np.float64)
    return np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t)[:, None], axis=0)])


def centred_mean(x, half: int) -> np.ndarray:
    """The mean of ``x`` (along axis 0) over 2 half + 1 samples centred on each, the window shrunk
    symmetrically at the ends: a linear function is kept exactly, everywhere."""
    x = np.asarray(x, dtype=np.float64)
    n = x.shape[0]
    if half <= 0 or n < 3:
        return x.copy()
    i = np.arange(n)
    h = np.minimum(np.minimum(i, n - 1 - i), int(half))
    c = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(x, axis=0)])
    return (c[i + h + 1] - c[i - h]) / (2 * h + 1).reshape((-1,) + (1,) * (x.ndim - 1))


def _half_window(slow_time_s, seconds: float) -> int:
    t = np.asarray(slow_time_s, dtype=np.float64)
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    return int(round(0.5 * seconds / dt)) if dt > 0 else 0


def lines_of_sight(scan_angle_deg, depression_deg: float) -> np.ndarray:
    """Unit vectors towards the scan's two ends and its middle at ``depression_deg`` ([3, 3])."""
    scan = np.asarray(scan_angle_deg, dtype=np.float64)
    th = np.radians([scan.min(), 0.5 * (scan.min() + scan.max()), scan.max()])
    ph = np.radians(depression_deg)
    return np.stack([np.sin(th) * np.cos(ph), np.cos(th) * np.cos(ph), np.full(3, -np.sin(ph))], axis=1)


def beam_dwell_pulses(scan_angle_deg, beamwidth_deg: float) -> int:
    """The pulses the beam takes to cross a point (the whole record for a scan that does not move)."""
    scan = np.asarray(scan_angle_deg, dtype=np.float64)
    step = float(np.median(np.abs(np.diff(scan)))) if len(scan) > 1 else 0.0
    return len(scan) - 1 if step <= 0 else int(min(len(scan) - 1, np.ceil(beamwidth_deg / step)))


def largest_excursion(x, width: int) -> float:
    """max over every ``width`` consecutive samples of ``x`` of their max - min, in O(n log width): the
    maxima and minima of blocks of doubling length, then each window as two overlapping blocks (no
    scipy.ndimage import at a command's start, 0.1 s)."""
    x = np.asarray(x, dtype=np.float64)
    width = int(min(max(width, 1), len(x)))
    hi, lo, k = x, x, 1
    while 2 * k <= width:
        hi, lo, k = np.maximum(hi[:-k], hi[k:]), np.minimum(lo[:-k], lo[k:]), 2 * k
    j = width - k                                     # block i covers x[i:i + k]; window i, blocks i and i + j
    return float(np.max(np.maximum(hi[:len(hi) - j], hi[j:]) - np.minimum(lo[:len(lo) - j], lo[j:])))


def velocity_disagreement_m(slow_time_s, position_m, velocity_mps, *, span: int, los) -> float:
    """The largest excursion, within any ``span`` + 1 consecutive pulses and along any of the lines of
    sight ``los`` ([k, 3]), of the positions' displacement less the velocities' integral, smoothed over
    ``SMOOTHING_S`` (module docstring), metres."""
    p = np.asarray(position_m, dtype=np.float64)
    if len(p) < 3:
        return 0.0
    d = centred_mean((p - p[0]) - velocity_integral_m(slow_time_s, velocity_mps),
                     _half_window(slow_time_s, SMOOTHING_S))
    width = int(min(max(span, 1), len(p) - 1)) + 1
    return max(largest_excursion(d @ u, width) for u in np.asarray(los, dtype=np.float64))


def position_roughness_m(slow_time_s, position_m, los) -> float:
    """The positions' pulse-to-pulse noise along the lines of sight (the largest of them), metres: their
    third divided differences over the actual pulse times (zero for any constant-acceleration track,
    whatever the spacing: a pulse train jittered by 1 % had read as a millimetre of noise), times 6 dt^3
    (dt the median interval: the third difference on a uniform train), as a Gaussian sigma from the
    median absolute deviation (1.4826 MAD), over sqrt(20) (a third difference of white noise has 20 times
    its variance)."""
    t = np.asarray(slow_time_s, dtype=np.float64)
    p = np.asarray(position_m, dtype=np.float64) @ np.asarray(los, dtype=np.float64).T      # [n, k]
    if len(t) < 5:
        return 0.0
    dd = p
    for order in (1, 2, 3):
        dd = np.diff(dd, axis=0) / (t[order:] - t[:-order])[:, None]
    third = dd * 6.0 * float(np.median(np.diff(t))) ** 3
    mad = np.median(np.abs(third - np.median(third, axis=0)), axis=0)
    return float(np.max(1.4826 * mad / np.sqrt(20.0)))


def kept_float32_step(stored, position) -> float:
    """The storage step of float32 positions the reader kept as stored (io/track.py; 0 for float64 ones and
    for restored ones: a restored track is the velocities' integral fitted through them, whose drift, a
    velocity bias against the positions, the disagreement then measures)."""
    if np.dtype(stored.dtype).itemsize >= 8:
        return 0.0
    kept = np.asarray(stored[()], dtype=np.float64)
    if not np.array_equal(kept, position):
        return 0.0
    return float(np.spacing(np.float32(np.max(np.abs(kept)))))


def check_navigation(slow_time_s, position_m, velocity_mps, *, scan_angle_deg, beamwidth_deg: float, fc_hz: float,
                     range_m, source: str, rounding_m: float = 0.0) -> dict:
    """Both checks (module docstring), each said in one warning past its phase; returns their numbers.
    The lines of sight at the depression of the window's middle range (``range_m``) from the track's median
    height.  ``rounding_m``: the positions' storage step where they are kept in float32 (taken off the
    disagreement; their roughness is then the float32 warning's)."""
    lam = C_MPS / fc_hz
    r_mid = 0.5 * (float(range_m[0]) + float(range_m[-1]))
    height = float(np.median(np.asarray(position_m)[:, 2]))
    depression_deg = float(np.degrees(np.arcsin(np.clip(height / r_mid, -1.0, 1.0)))) if r_mid > 0 else 0.0
    los = lines_of_sight(scan_angle_deg, depression_deg)
    span = beam_dwell_pulses(scan_angle_deg, beamwidth_deg)
    gap_m = max(0.0, velocity_disagreement_m(slow_time_s, position_m, velocity_mps, span=span, los=los) - rounding_m)
    rough_m = position_roughness_m(slow_time_s, position_m, los) if rounding_m == 0.0 else 0.0
    gap_rad, rough_rad = 4.0 * np.pi * gap_m / lam, 4.0 * np.pi * rough_m / lam
    if gap_rad > VELOCITY_PHASE_RAD:
        log.warning(f"{source}: /platform/velocity_mps and /platform/position_m disagree: the velocities' integral "
                    f"departs from the positions by up to {gap_m * 1e3:.3g} mm along a line of sight within a beam "
                    f"dwell ({span} pulses), {gap_rad:.3g} rad of round-trip phase at {fc_hz / 1e9:.4g} GHz "
                    f"({gap_rad / (2.0 * np.pi):.2g} of the dwell's Doppler resolution): a velocity bias, a lag of one "
                    f"record against the other or a lower logging rate; processing.navigation: positions takes the "
                    f"velocities from the positions, fused blends the two (README, \"Raw cube files\")")
    if rough_rad > ROUGHNESS_PHASE_RAD:
        log.warning(f"{source}: /platform/position_m is rough: {rough_m * 1e3:.3g} mm of pulse-to-pulse noise along "
                    f"a line of sight, {rough_rad:.3g} rad of round-trip phase at {fc_hz / 1e9:.4g} GHz, which the "
                    f"dwell image's ranges carry; processing.navigation: fused takes the positions' low frequencies "
                    f"only (README, \"Raw cube files\")")
    return {"disagreement_m": gap_m, "disagreement_rad": gap_rad, "roughness_m": rough_m, "roughness_rad": rough_rad,
            "dwell_pulses": span}


def velocity_from_positions(slow_time_s, position_m) -> np.ndarray:
    """The positions' time derivative, [n_pulses, 3] m/s: central differences over the actual pulse times
    (second order at the ends, ``np.gradient``: exact for a constant acceleration on any spacing),
    averaged over ``SMOOTHING_S`` (symmetric windows: exact on a uniform train, within the acceleration
    times the window's mean jitter on another; white position noise sigma gives about sigma /
    SMOOTHING_S, not sigma / (sqrt(2) dt))."""
    t = np.asarray(slow_time_s, dtype=np.float64)
    p = np.asarray(position_m, dtype=np.float64)
    if len(t) < 3:
        return np.gradient(p, t, axis=0) if len(t) == 2 else np.zeros_like(p)
    return centred_mean(np.gradient(p, t, axis=0, edge_order=2), _half_window(t, SMOOTHING_S))


def fused_track(slow_time_s, position_m, velocity_mps) -> tuple[np.ndarray, np.ndarray]:
    """(positions, velocities) blended: the velocities' integral plus the low-passed difference of the
    positions from it (two centred means of ``FUSED_CROSSOVER_S`` / 2: a triangular window), and that
    difference's derivative added to the velocities.  A velocity bias or drift and the positions' noise
    go; a constant acceleration is kept exactly."""
    t = np.asarray(slow_time_s, dtype=np.float64)
    p = np.asarray(position_m, dtype=np.float64)
    v = np.asarray(velocity_mps, dtype=np.float64)
    if len(t) < 3:
        return p.copy(), v.copy()
    moved = velocity_integral_m(t, v)
    half = _half_window(t, 0.5 * FUSED_CROSSOVER_S)
    low = centred_mean(centred_mean(p - moved, half), half)
    return moved + low, v + np.gradient(low, t, axis=0, edge_order=2)


def with_navigation(cube, mode: str):
    """``cube``, or a shallow copy whose navigation ``processing.navigation`` replaces (module docstring;
    the echoes and everything else shared)."""
    if mode == "recorded":
        return cube
    if mode == "positions":
        return dataclasses.replace(cube, velocity_mps=velocity_from_positions(cube.slow_time_s, cube.position_m))
    if mode == "fused":
        p, v = fused_track(cube.slow_time_s, cube.position_m, cube.velocity_mps)
        return dataclasses.replace(cube, position_m=p, velocity_mps=v)
    raise BadInput(f"processing.navigation = {mode!r}; allowed: {', '.join(NAVIGATION_MODES)}")
