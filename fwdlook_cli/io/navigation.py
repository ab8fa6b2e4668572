"""The recorded navigation against itself: velocities against positions, and each record's roughness.

The chain takes its Doppler histories (the ``tracking`` keystone's, the dwell focus's Doppler bins, the
CPI bands) from ``/platform/velocity_mps`` and its range histories (the dwell image's exact ranges,
``bulk`` and ``beam``) from ``/platform/position_m``.  Three checks along the scan's lines of sight (its
ends and its middle at the far range's depression), each one warning where it matters:

* *Disagreement.*  d(t) = p(t) - p(0) - integral of v (trapezoids), smoothed over ``SMOOTHING_S`` (white
  position noise is the next check's), and its largest excursion within any beam dwell (the pulses the
  beam takes to cross a point: the span over which a Doppler history is integrated against range
  histories).  Every lag up to the dwell counts, not only the dwell's ends: positions interpolated from
  a 50 Hz solution repeat their error every 20 ms, and a dwell of whole periods had read 0 (an
  independent study).  Over ``VELOCITY_PHASE_RAD`` of round-trip phase (half the dwell's Doppler
  resolution): a velocity bias, a lag of one record against the other, velocities held at a lower rate.
* *Rough positions.*  Their pulse-to-pulse noise, from third divided differences (:func:`roughness`:
  robust, so the kinks of positions interpolated linearly from a navigation solution, a few samples in
  each period, do not count), as round-trip phase; over ``ROUGHNESS_PHASE_RAD`` the dwell image's exact
  ranges carry it (1 mm at 18 GHz, 0.75 rad: the study measured the isolated scene's dwell image -8.4
  dB from the clean one).
* *Rough velocities.*  The same from second divided differences, as a Doppler error against the
  resolution of ``SMOOTHING_S`` (a sub-aperture or a CPI reads the Doppler of one velocity), past half
  of it (``VELOCITY_PHASE_RAD`` over ``SMOOTHING_S``, as the disagreement over a dwell): 0.21 m/s at 18
  GHz (0.05 m/s had put the dwell image -9 to -18 dB from the clean one, its targets unchanged).

None sees a lag common to both records (a time-tag offset against the radar): they agree with each
other; the echoes show it where the platform accelerates (``forward/echo_navigation.py``), and
``processing.navigation_delay_s`` moves both records by it (:func:`delayed_track`).

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

from ..dsp.geometry import C_MPS, unit_vector
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
    """``x`` (along axis 0) smoothed over 2 half + 1 samples: the centred mean where the whole window fits,
    and within ``half`` samples of an end the least-squares line through the end's whole window (a
    window shrunk to one sample had left the ends' noise as it was: 6 m/s at the last pulses of a
    derivative whose middle was good to 0.17 m/s, a review).  A linear function of the sample index is
    kept exactly, everywhere; a record shorter than a window is its own least-squares line."""
    x = np.asarray(x, dtype=np.float64)
    n, half = x.shape[0], int(half)
    if half <= 0 or n < 3:
        return x.copy()
    width = 2 * half + 1
    if n < width:
        return _line_through(x, np.arange(n))
    c = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(x, axis=0)])
    out = np.empty_like(x)
    out[half:n - half] = (c[width:] - c[:n - width + 1]) / width
    out[:half] = _line_through(x[:width], np.arange(half))
    out[n - half:] = _line_through(x[n - width:], np.arange(width - half, width))
    return out


def _line_through(x, at) -> np.ndarray:
    """The least-squares line through ``x`` (along axis 0, samples 0, 1, ...) at the sample indices ``at``."""
    m = np.arange(x.shape[0], dtype=np.float64)
    m_bar = m.mean()
    x_bar = x.mean(axis=0)
    slope = np.tensordot(m - m_bar, x - x_bar, axes=(0, 0)) / np.sum((m - m_bar) ** 2)
    return x_bar + np.multiply.outer(np.asarray(at, dtype=np.float64) - m_bar, slope)


def _half_window(slow_time_s, seconds: float) -> int:
    t = np.asarray(slow_time_s, dtype=np.float64)
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    return int(round(0.5 * seconds / dt)) if dt > 0 else 0


def lines_of_sight(scan_angle_deg, depression_deg: float) -> np.ndarray:
    """Unit vectors towards the scan's two ends and its middle at ``depression_deg`` ([3, 3])."""
    scan = np.asarray(scan_angle_deg, dtype=np.float64)
    return unit_vector([scan.min(), 0.5 * (scan.min() + scan.max()), scan.max()], depression_deg)


def beam_dwell_pulses(scan_angle_deg, beamwidth_deg: float) -> int:
    """The pulses the beam takes to cross a point (the whole record for a scan that does not move)."""
    scan = np.asarray(scan_angle_deg, dtype=np.float64)
    if len(scan) < 2:
        return 0
    # (a stepped scan's median step is 0: its mean step along the path then, not the whole record)
    steps = np.abs(np.diff(scan))
    step = float(np.median(steps)) or float(np.mean(steps))
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


def velocity_disagreement_m(slow_time_s, position_m, velocity_mps, *, span: int, los, rounding_m=0.0) -> float:
    """The largest excursion, within any ``span`` + 1 consecutive pulses and along any of the lines of
    sight ``los`` ([k, 3]), of the positions' displacement less the velocities' integral, smoothed over
    ``SMOOTHING_S`` (module docstring), metres; ``rounding_m`` (per axis: float32 positions kept as
    stored) taken off along each line of sight."""
    p = np.asarray(position_m, dtype=np.float64)
    if len(p) < 3:
        return 0.0
    d = centred_mean((p - p[0]) - velocity_integral_m(slow_time_s, velocity_mps),
                     _half_window(slow_time_s, SMOOTHING_S))
    width = int(min(max(span, 1), len(p) - 1)) + 1
    los = np.asarray(los, dtype=np.float64)
    step = np.broadcast_to(np.asarray(rounding_m, dtype=np.float64), (3,))
    return max(max(0.0, largest_excursion(d @ u, width) - float(np.sqrt(np.sum((u * step) ** 2)))) for u in los)


def roughness(slow_time_s, x, los, order: int, rounding=0.0) -> float:
    """The pulse-to-pulse noise of ``x`` ([n, 3]: positions with ``order`` 3, velocities with 2) along the
    lines of sight (the largest of them), in ``x``'s unit: its divided differences of that order over the
    actual pulse times (zero for a constant acceleration whatever the spacing: a pulse train jittered by
    1 % had read as a millimetre of position noise), each over its own white-noise gain sqrt(sum_j w_j^2),
    w_j = 1 / prod_{m != j} (t_j - t_m) (exact on any spacing: a median interval's gain had under-read a
    staggered train's noise by up to 45 %, a review), as a Gaussian sigma from the median absolute
    deviation (1.4826 MAD: a few kinks in each period, of a track interpolated linearly from a navigation
    solution, do not count).  ``rounding`` (per axis: float32 storage steps) taken off in quadrature,
    step / sqrt(12) along each line of sight."""
    t = np.asarray(slow_time_s, dtype=np.float64)
    los = np.asarray(los, dtype=np.float64)
    dd = np.asarray(x, dtype=np.float64) @ los.T                                        # [n, k]
    if len(t) < order + 2:
        return 0.0
    for k in range(1, order + 1):
        dd = np.diff(dd, axis=0) / (t[k:] - t[:-k])[:, None]
    n_w = len(t) - order                                  # windows t[i .. i + order]
    gain2 = np.zeros(n_w)
    for j in range(order + 1):
        w = np.ones(n_w)
        for m in range(order + 1):
            if m != j:
                w = w * (t[j:j + n_w] - t[m:m + n_w])
        gain2 += 1.0 / w**2
    unit = dd / np.sqrt(gain2)[:, None]
    sigma = 1.4826 * np.median(np.abs(unit - np.median(unit, axis=0)), axis=0)          # [k]
    step = np.broadcast_to(np.asarray(rounding, dtype=np.float64), (3,))
    quantum2 = np.sum((los * step) ** 2, axis=1) / 12.0
    return float(np.max(np.sqrt(np.maximum(sigma**2 - quantum2, 0.0))))


def position_roughness_m(slow_time_s, position_m, los, rounding_m=0.0) -> float:
    """The positions' pulse-to-pulse noise along the lines of sight, metres (:func:`roughness`)."""
    return roughness(slow_time_s, position_m, los, 3, rounding_m)


def kept_float32_step(stored_dtype, stored, position) -> np.ndarray:
    """The storage step, per axis, of positions stored as ``stored_dtype`` (read as ``stored``) where the
    reader kept them as stored (io/track.py; zeros for float64 ones and for restored ones, ``position``
    then differing: a restored track is the velocities' integral fitted through them, whose drift, a
    velocity bias against the positions, the disagreement then measures)."""
    if np.dtype(stored_dtype).itemsize >= 8 or not np.array_equal(stored, position):
        return np.zeros(3)
    return np.spacing(np.max(np.abs(np.asarray(stored)), axis=0).astype(np.float32)).astype(np.float64)


def check_navigation(slow_time_s, position_m, velocity_mps, *, scan_angle_deg, beamwidth_deg: float, fc_hz: float,
                     range_m, source: str, rounding_m=0.0) -> dict:
    """The checks (module docstring), each said in one warning past its phase; returns their numbers.
    The lines of sight at the depressions of the window's near and far ranges (``range_m``) that reach
    the ground from the track's median height, level where none does (a middle range below the platform
    had turned them straight down, blind to an along-track bias).  ``rounding_m`` (per axis): the
    positions' storage step where they are kept in float32 (taken off the disagreement, and off their
    roughness in quadrature, step / sqrt(12))."""
    lam = C_MPS / fc_hz
    height = float(np.median(np.asarray(position_m)[:, 2]))
    reach = [abs(float(r)) for r in (range_m[0], range_m[-1]) if abs(float(r)) > abs(height)]
    depressions = sorted({float(np.degrees(np.arcsin(height / r))) for r in reach}) or [0.0]
    los = np.concatenate([lines_of_sight(scan_angle_deg, d) for d in depressions])
    span = beam_dwell_pulses(scan_angle_deg, beamwidth_deg)
    gap_m = velocity_disagreement_m(slow_time_s, position_m, velocity_mps, span=span, los=los, rounding_m=rounding_m)
    rough_m = position_roughness_m(slow_time_s, position_m, los, rounding_m)
    vel_rough_mps = roughness(slow_time_s, velocity_mps, los, 2)
    gap_rad, rough_rad = 4.0 * np.pi * gap_m / lam, 4.0 * np.pi * rough_m / lam
    vel_rough_rad = 4.0 * np.pi * vel_rough_mps * SMOOTHING_S / lam
    ghz = f"{fc_hz / 1e9:.4g} GHz"
    if gap_rad > VELOCITY_PHASE_RAD:
        log.warning(f"{source}: /platform/velocity_mps and /platform/position_m disagree: the velocities' integral "
                    f"departs from the positions by up to {gap_m * 1e3:.3g} mm along a line of sight within a beam "
                    f"dwell ({span} pulses), {gap_rad:.3g} rad of round-trip phase at {ghz} ({gap_rad / (2.0 * np.pi):.2g} "
                    f"of the dwell's Doppler resolution): a velocity bias, a lag of one record against the other or a "
                    f"lower logging rate; processing.navigation: positions takes the velocities from the positions, "
                    f"fused blends the two (README, \"Raw cube files\")")
    if rough_rad > ROUGHNESS_PHASE_RAD:
        log.warning(f"{source}: /platform/position_m is rough: {rough_m * 1e3:.3g} mm of pulse-to-pulse noise along "
                    f"a line of sight, {rough_rad:.3g} rad of round-trip phase at {ghz}, which the dwell image's "
                    f"ranges carry; processing.navigation: fused takes the positions' low frequencies only (README, "
                    f"\"Raw cube files\")")
    if vel_rough_rad > VELOCITY_PHASE_RAD:
        log.warning(f"{source}: /platform/velocity_mps is rough: {vel_rough_mps:.3g} m/s of pulse-to-pulse noise "
                    f"along a line of sight, a Doppler error of {vel_rough_rad / (2.0 * np.pi):.2g} of the "
                    f"resolution of {SMOOTHING_S * 1e3:.0f} ms at {ghz} ({vel_rough_rad:.3g} rad over it; a "
                    f"sub-aperture or a CPI reads the Doppler of one velocity); processing.navigation: positions "
                    f"takes the velocities from the positions (README, \"Raw cube files\")")
    return {"disagreement_m": gap_m, "disagreement_rad": gap_rad, "roughness_m": rough_m, "roughness_rad": rough_rad,
            "velocity_roughness_mps": vel_rough_mps, "velocity_roughness_rad": vel_rough_rad, "dwell_pulses": span}


def velocity_from_positions(slow_time_s, position_m) -> np.ndarray:
    """The positions' time derivative, [n_pulses, 3] m/s: central differences over the actual pulse times
    (exact for a constant acceleration on any spacing), smoothed over ``SMOOTHING_S`` (:func:`centred_mean`:
    exact on a uniform train, within the acceleration times the pulses' jitter on another; white position
    noise sigma gives about sigma / SMOOTHING_S, not sigma / (sqrt(2) dt)), the first and last pulses one
    step along their ends' lines."""
    t = np.asarray(slow_time_s, dtype=np.float64)
    p = np.asarray(position_m, dtype=np.float64)
    if len(t) < 4:            # (exact for a constant acceleration from 3 pulses; 2 give their chord, 1 zero)
        return (np.gradient(p, t, axis=0, edge_order=2 if len(t) == 3 else 1) if len(t) >= 2
                else np.zeros_like(p))
    # central differences at pulses 1 .. n-2 (the one-sided ones at the ends carry sqrt(13) times their
    # noise: their weight in the ends' lines had left 0.5 m/s there), smoothed, then one step of each
    # end's line outwards
    inner = centred_mean((p[2:] - p[:-2]) / (t[2:] - t[:-2])[:, None], _half_window(t, SMOOTHING_S))
    return np.concatenate([2 * inner[:1] - inner[1:2], inner, 2 * inner[-1:] - inner[-2:-1]])


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


def delayed_track(slow_time_s, position_m, velocity_mps, delay_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(positions, velocities) at radar time t of a navigation that lags the radar by ``delay_s`` (its
    record tagged t holds the platform at t - delay): the records evaluated at t + delay.  Positions by
    cubic Hermite interpolation from the positions and velocities either side, velocities linearly, and
    beyond the record's ends along the velocities' least-squares line over the end's ``SMOOTHING_S``:
    exact for a constant acceleration, as the paper's platform (Fig. 1)."""
    t = np.asarray(slow_time_s, dtype=np.float64)
    p = np.asarray(position_m, dtype=np.float64)
    v = np.asarray(velocity_mps, dtype=np.float64)
    if delay_s == 0.0 or len(t) < 2:       # the records as they are (no caller writes into them)
        return p, v
    tq = t + delay_s
    k = np.clip(np.searchsorted(t, tq, side="right") - 1, 0, len(t) - 2)      # the interval [t_k, t_k+1]
    h = t[k + 1] - t[k]
    s = ((tq - t[k]) / h)[:, None]
    hh = h[:, None]
    pos = ((2 * s**3 - 3 * s**2 + 1) * p[k] + (s**3 - 2 * s**2 + s) * hh * v[k]
           + (-2 * s**3 + 3 * s**2) * p[k + 1] + (s**3 - s**2) * hh * v[k + 1])
    vel = (1 - s) * v[k] + s * v[k + 1]
    for end, outside in ((0, tq < t[0]), (len(t) - 1, tq > t[-1])):
        if outside.any():
            # the velocities' least-squares line over the end's SMOOTHING_S (at least two pulses): the
            # last two alone had carried their noise 15 times into 5 ms of extrapolation (a review)
            near = np.abs(t - t[end]) <= SMOOTHING_S
            near[[end, 1 if end == 0 else end - 1]] = True
            slope, at_end = np.polyfit(t[near] - t[end], v[near], 1)
            dt = (tq[outside] - t[end])[:, None]
            pos[outside] = p[end] + at_end * dt + 0.5 * slope * dt**2
            vel[outside] = at_end + slope * dt
    return pos, vel


def with_navigation(cube, mode: str, delay_s: float = 0.0, scan_angle_offset_deg: float = 0.0):
    """``cube``, or a shallow copy whose navigation ``processing.navigation`` replaces (module docstring;
    the echoes and everything else shared), after moving both records by ``processing.navigation_delay_s``
    (:func:`delayed_track`) and the scan angles by -``processing.scan_angle_offset_deg`` (recorded that
    far towards +x of where the antenna pointed), marked in its ``attrs`` so that a cube already given
    them comes back as it is (``fused`` is not idempotent: the chain plans on the cube it built, a review
    had found the plan blending it a second time); a cube moved with other settings is refused
    (ValueError: a second delay would compound the first, a review)."""
    delay_s, scan_angle_offset_deg = float(delay_s), float(scan_angle_offset_deg)
    mark = {"navigation": mode, "navigation_delay_s": delay_s, "scan_angle_offset_deg": scan_angle_offset_deg}
    held = {k: cube.attrs.get(k, 0.0 if k != "navigation" else "recorded") for k in mark}
    if held == mark:
        return cube
    if any(k in cube.attrs for k in mark):     # moved once already: a second move would compound the first
        raise ValueError(f"with_navigation: this cube already holds {held}; give it the recorded cube for {mark}")
    if mode not in NAVIGATION_MODES:
        raise BadInput(f"processing.navigation = {mode!r}; allowed: {', '.join(NAVIGATION_MODES)}")
    p, v = delayed_track(cube.slow_time_s, cube.position_m, cube.velocity_mps, delay_s)
    if mode == "positions":
        v = velocity_from_positions(cube.slow_time_s, p)
    elif mode == "fused":
        p, v = fused_track(cube.slow_time_s, p, v)
    scan = cube.scan_angle_deg - scan_angle_offset_deg if scan_angle_offset_deg else cube.scan_angle_deg
    return dataclasses.replace(cube, position_m=p, velocity_mps=v, scan_angle_deg=scan, attrs=dict(cube.attrs, **mark))


def navigation_of(proc: dict) -> tuple:
    """The arguments of :func:`with_navigation` from resolved ``processing`` settings."""
    return (proc.get("navigation", "recorded"), proc.get("navigation_delay_s", 0.0),
            proc.get("scan_angle_offset_deg", 0.0))
