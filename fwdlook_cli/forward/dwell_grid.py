"""The directions the dwell image focuses (``dwell.dwell_focus``), and each sub-aperture's window of them.

**Focus directions finer than the image's angle bins where the dwell resolves finer.**  A direction's
dwell sum is a matched filter over its beam dwell, so its response to a point off that direction by x
falls as the Doppler offset 2 v cos(phi) |sin(theta - axis)| x / lambda leaves the dwell's Doppler lobe
(half-power half-width :func:`lobe_half_width_hz`: 2.6 Hz for the paper's beam and scan, whatever the
carrier).  The lobe in angle, lambda / (2 v |sin theta|) times that, is 0.05 deg wide at 18 GHz 10 deg
off the flight axis, but 0.011 deg at 94 GHz: there a point between two of the image's 0.05 deg
directions was seen only in their sidelobes (an independent review, forty-ninth round; measured in the
fiftieth, 94 GHz, a = 20, six points 10 deg off the axis: 17-33 dB down and 0.46-1.13 m off in range
between the directions, against 0.031 m and peaks within 0.14 dB now).  So every image bin is focused
in m directions, evenly spaced, m the least that puts a direction at least every half-power width of
the lobe there (:func:`focus_per_bin`; at -6 dB the six points were still 0.17 m off), and each focused
cell's power counts 1/m in its bin.  Near the flight axis and at lower carriers m = 1, the image's own
directions; the paper's 18 GHz flight at a = 50 takes m = 2 at 10.4-13.9 deg (a = 0 and 10: none).

**Each sub-aperture's window** (:func:`subaperture_windows`) holds the directions whose offset from its
beam, seen from its own antenna position, lies within the dwell window.  It was taken in the t_ref frame
before (the image grid around the beam angle), which 0.57 deg of parallax (the antenna 91 m from p_ref
when the paper's a = 50 beam passes 10 deg, 1.6 km away) cut on one side of the window: up to 8 % of a direction's
matched-filter gain lost 5-15 deg off the axis on the paper's flight, 19 % near the scan's start.

The rule samples the lobe's power; a point's range between two directions is more sensitive (at 94 GHz
and 15 deg/s, up to 0.56 m off: README, "Where the focus directions are still not enough").
"""
from __future__ import annotations

import logging

import numpy as np

from ..dsp.imaging import image_angle_grid
from ..dsp.neighbours import running_max
from ..limits import check_processing_sizes
from .dwell_range import flight_axis_deg

log = logging.getLogger(__name__)

MAX_FOCUS_OVERSAMPLE = 16        # focus directions per image bin at most (the review's 94 GHz scene: 5 at most)
LOBE_LEVEL = 0.5                 # a focus direction at least every half-power width of the lobe: at -6 dB
                                 # (0.25: 3 dB of power at worst, the two neighbours together) the W-band points
                                 # between them were still 0.17 m off in range and 4.3 dB apart (fiftieth round)


def lobe_half_width_hz(beta_per_deg2: float, slope_per_deg: float, half_width_deg: float, scan_rate_dps: float,
                       level: float = LOBE_LEVEL) -> float:
    """Half-width in Hz, at ``level`` of its peak power, of a direction's dwell response against a Doppler
    offset f: |sum_t w(t)^2 exp(j 2 pi f t)|^2 / (sum_t w(t)^2)^2 = level, with w the dwell's matched-filter
    weight (:func:`pattern_weight` of the beam offset scan_rate * t, within the dwell window)."""
    t_half = half_width_deg / max(scan_rate_dps, 1e-12)
    t = np.linspace(-t_half, t_half, 513)
    w2 = pattern_weight(scan_rate_dps * t, beta_per_deg2, slope_per_deg) ** 2
    w2 /= np.sum(w2)

    def response(f):              # the weight is even in t: its transform is real
        return (np.cos(2.0 * np.pi * np.asarray(f)[..., None] * t) @ w2) ** 2

    rms_s = float(np.sqrt(np.sum(w2 * t**2)))             # the weight's rms duration: the lobe lies within
    coarse = np.linspace(0.0, 2.0 / max(rms_s, 1e-12), 201)    # 2 / rms (0.13-0.19 / rms at 1/2 to 1/4)
    below = np.flatnonzero(response(coarse) < level)
    if not below.size:
        return float(coarse[-1])
    lo, hi = float(coarse[below[0] - 1]), float(coarse[below[0]])
    for _ in range(40):                                  # bisection to the level
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if response(mid) >= level else (lo, mid)
    return 0.5 * (lo + hi)


def focus_oversample_per_bin(angle_deg, *, axis_deg: float, speed_mps, lobe_hz: float, fc_hz: float,
                             cos_depression: float = 1.0, warn: bool = True):
    """Focus directions per image bin (int array like ``angle_deg``): the least m with the bin's step / m
    at most the lobe's full width at :data:`LOBE_LEVEL` in angle, 2 lobe_hz lambda / (2 v cos(phi)
    |sin(theta - axis)|) (``lobe_hz``: its half-width in Doppler, :func:`lobe_half_width_hz`;
    ``speed_mps``: the horizontal speed while the beam dwells on each bin, an array like ``angle_deg`` or
    one number; ``lobe_hz`` likewise), capped at :data:`MAX_FOCUS_OVERSAMPLE` (``warn``: say so where the
    cap is reached, with the angle step that would not need it)."""
    angle = np.asarray(angle_deg, dtype=np.float64)
    step = float(angle[1] - angle[0]) if angle.size > 1 else 1.0
    lam = 299_792_458.0 / fc_hz
    grad = 2.0 * np.asarray(speed_mps, dtype=np.float64) * cos_depression \
        * np.abs(np.sin(np.radians(angle - axis_deg))) / lam                        # Hz per rad
    with np.errstate(over="ignore", divide="ignore"):              # (no dwell, or no gradient: one direction)
        width_deg = np.degrees(2.0 * np.asarray(lobe_hz, dtype=np.float64) / np.maximum(grad, 1e-300))
    need = np.ceil(step / width_deg - 1e-9)
    over = need > MAX_FOCUS_OVERSAMPLE
    if warn and over.any():
        finest = float(width_deg.min())
        digit = 10.0 ** (np.floor(np.log10(MAX_FOCUS_OVERSAMPLE * finest)) - 1)
        enough = np.floor(MAX_FOCUS_OVERSAMPLE * finest / digit) * digit                # two digits, rounded down
        off = np.abs(angle[over] - axis_deg)
        log.warning(f"dwell image: {float(off.min()):.1f} to {float(off.max()):.1f} deg off the flight axis the "
                    f"dwell's angle lobe is down to {finest:.2g} deg wide, more than {MAX_FOCUS_OVERSAMPLE} focus "
                    f"directions per {step:g} deg angle bin would need; points between them there lose power and may "
                    f"be placed off in range (processing.angle_step_deg <= {enough:.2g} samples it)")
    return np.clip(need, 1, MAX_FOCUS_OVERSAMPLE).astype(np.int64)


def focus_directions(angle_deg, per_bin):
    """The focused directions for ``per_bin`` directions in each image bin: bin i holds angle_deg[i] + s j /
    m_i, j < m_i (s the bin step; its own direction first).  Returns (directions, the bin of each, the
    index of each bin's own direction, each direction's weight 1 / m_i)."""
    angle = np.asarray(angle_deg, dtype=np.float64)
    m = np.asarray(per_bin, dtype=np.int64)
    step = float(angle[1] - angle[0]) if angle.size > 1 else 0.0
    bins = np.repeat(np.arange(angle.size), m)
    first = np.concatenate([[0], np.cumsum(m)[:-1]]).astype(np.int64)
    j = np.arange(bins.size) - first[bins]
    return angle[bins] + step * j / m[bins], bins, first, 1.0 / m[bins]      # (m = 1: the bins themselves)


def subaperture_windows(delta_deg, half_width_deg: float):
    """Each sub-aperture's window of directions: ``delta_deg`` [n_sub, n_dir] the offset of every direction
    from each sub-aperture's beam (seen from its antenna); the span of those within the dwell window
    (|delta| <= half_width_deg).  Returns (g [n_sub, n_loc] direction indices, valid [n_sub, n_loc], and
    each row's count), the valid entries a prefix of each row."""
    inside = np.abs(delta_deg) <= half_width_deg
    any_in = inside.any(axis=1)
    lo = np.where(any_in, np.argmax(inside, axis=1), 0)
    hi = np.where(any_in, inside.shape[1] - np.argmax(inside[:, ::-1], axis=1), 0)
    count = hi - lo
    n_loc = max(1, int(count.max()) if count.size else 1)
    g = lo[:, None] + np.arange(n_loc)[None, :]
    return g, g < hi[:, None], count


def pattern_weight(offset_deg, beta_per_deg2, slope_per_deg):
    """Amplitude of the rotated sum S' of a target on the imaged direction: Sigma(d) exp(-beta d^2)."""
    d = np.asarray(offset_deg, dtype=np.float64)
    return np.exp(-2.0 * beta_per_deg2 * d**2) * np.cosh(slope_per_deg * d)


def focus_per_bin(angle_deg, beam_deg, velocity_mps, range_m, p_ref, *, fc_hz, prf_hz, axis_deg, beta_per_deg2,
                  slope_per_deg, dwell_half_width_deg, warn: bool = True):
    """Focus directions per image bin (:func:`focus_oversample_per_bin`), with the horizontal speed the
    platform has while the beam dwells on each bin (the largest over the pulses whose beam lies within the
    dwell window of it), the depression at the window's far end (the narrowest lobe), and each bin's own
    Doppler lobe: a bin the scan covers only part of the window of (near the scan's ends) has a shorter
    dwell and a wider lobe, the full dwell's lobe times the ratio of the rms durations of the weight
    over the whole window and over the part covered (within 0.3 % of the exact half-power width for
    any truncation of the paper's window)."""
    angle = np.asarray(angle_deg, dtype=np.float64)
    beam = np.asarray(beam_deg, dtype=np.float64)
    step = float(angle[1] - angle[0])
    rate_dps = float(np.median(np.abs(np.diff(beam)))) * prf_hz
    lobe_hz = lobe_half_width_hz(beta_per_deg2, slope_per_deg, dwell_half_width_deg, rate_dps)
    # the rms duration of the weight over the covered offsets (beam - theta within the scan's extent)
    d = np.linspace(-dwell_half_width_deg, dwell_half_width_deg, 257)
    w2 = pattern_weight(d, beta_per_deg2, slope_per_deg) ** 2
    covered = (d[None, :] >= beam.min() - angle[:, None]) & (d[None, :] <= beam.max() - angle[:, None])
    wc = w2[None, :] * covered
    total = wc.sum(axis=1)
    mean = (wc @ d) / np.maximum(total, 1e-300)
    rms = np.sqrt(np.maximum((wc @ d**2) / np.maximum(total, 1e-300) - mean**2, 0.0))
    rms_full = float(np.sqrt(np.sum(w2 * d**2) / np.sum(w2)))                 # (symmetric: mean 0)
    lobe_bin = np.where(rms > 0, lobe_hz * rms_full / np.maximum(rms, 1e-300), np.inf)
    speed = np.hypot(velocity_mps[:, 0], velocity_mps[:, 1])
    at = np.clip(np.rint((beam - angle[0]) / step).astype(np.int64), 0, len(angle) - 1)
    per_bin_speed = np.zeros(len(angle))
    np.maximum.at(per_bin_speed, at, speed)
    reach = int(np.ceil(dwell_half_width_deg / step))
    per_bin_speed = running_max(per_bin_speed, 2 * reach + 1)
    far = float(np.max(range_m))
    cos_dep = float(np.sqrt(max(1.0 - (p_ref[2] / far) ** 2, 0.0))) if far > abs(p_ref[2]) else 1.0
    return focus_oversample_per_bin(angle, axis_deg=axis_deg, speed_mps=per_bin_speed, lobe_hz=lobe_bin,
                                    fc_hz=fc_hz, cos_depression=cos_dep, warn=warn)


def check_focus_sizes(cube, geo: dict, proc: dict, *, slope_per_deg: float, beta_per_deg2: float,
                      dwell_half_width_deg: float) -> None:
    """The directions ``dwell.dwell_image`` will focus on this cube (:func:`focus_per_bin` summed), held to
    the chain's size check (``limits.check_processing_sizes``) before it starts: the focus's arrays are
    per direction, up to MAX_FOCUS_OVERSAMPLE times the image's bins."""
    angle = image_angle_grid(cube.scan_angle_deg, cube.radar["beamwidth_3db_deg"], proc["angle_step_deg"])
    per_bin = focus_per_bin(angle, cube.scan_angle_deg, np.asarray(cube.velocity_mps), cube.range_m,
                            np.asarray(geo["p_ref"], dtype=np.float64), fc_hz=cube.radar["fc_hz"],
                            prf_hz=cube.radar["prf_hz"], axis_deg=flight_axis_deg(geo["v_ref"]),
                            beta_per_deg2=beta_per_deg2, slope_per_deg=slope_per_deg,
                            dwell_half_width_deg=dwell_half_width_deg, warn=False)     # (dwell_image says it)
    check_processing_sizes(n_range=cube.n_range, range_oversample=int(geo["range_oversample"]), n_angle=len(angle),
                           n_focus=int(per_bin.sum()), angle_step_deg=proc["angle_step_deg"], imaging="dwell",
                           n_cpi=0, n_doppler=0)
