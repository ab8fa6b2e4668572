"""The samples a data calibration fits (``forward/calibration.py``): strong isolated point returns seen
across the scan, each sampled on its predicted track, and the fit's residual against their noise.

A stationary point scatterer P, seen across the scan, returns at pulse n ``diff/sum = gamma R(delta_n -
b)`` with ``delta_n = az(P from p_n) - scan_n`` (the calibration module's docstring); here P is found
from the sum channel (its range peaks grouped by range from the t_ref antenna and scan angle), its
azimuth from the symmetric two-way sum envelope, and every pulse sampled on its predicted track.
Tracks that are no points (isolation tests; off their own range peak) are rejected.
"""
from __future__ import annotations

import numpy as np

from ..dsp.imaging import power_f32          # |x|^2 in float32 (the same numbers whole or in blocks)
from ..dsp.neighbours import label_cells, running_max
from ..dsp.order_stats import percentile_of_blocks

POWER_BLOCK_BYTES = 8 << 20    # the sum power of one block of pulses: the detection's memory, whatever the cube
SAMPLE_VALUES = 1 << 16        # power values (whole pulses, evenly spaced) that place the noise quartile's bracket


# A compressed pulse's range sidelobes lie 13.3 dB (no weighting) or more (any taper) below its peak, so a
# local maximum at least SIDELOBE_DB below a stronger return within SIDELOBE_REACH_CELLS resolution cells
# of it, in the same pulse, is taken for that return's sidelobe, not for a point of its own (at high SNR
# the sidelobes clear the detection threshold, and their tracks chained the points into "extended" and
# "neighbour" groups or ran between them: README, "Monopulse calibration")
SIDELOBE_DB = 10.0
SIDELOBE_REACH_CELLS = 8.0


def _detections(s, thr, step, sidelobe_reach):
    """Local range maxima of the sum power over ``thr`` that are no sidelobe of a stronger return (within
    ``sidelobe_reach`` samples, at least :data:`SIDELOBE_DB` below it): (pulse, sample) and the power at
    sample - 1, at it and at + 1, pulse block by pulse block (``step`` pulses); row-major, as
    ``np.nonzero`` of the whole cube's mask."""
    below = np.float32(10.0 ** (-SIDELOBE_DB / 10.0))
    parts = []
    for lo in range(0, s.shape[0], step):
        p = power_f32(s[lo:lo + step])
        mid = p[:, 1:-1]
        strongest = running_max(p, 2 * sidelobe_reach + 1, axis=1)[:, 1:-1]
        strongest *= below
        n_b, i_b = np.nonzero((mid > thr) & (mid >= p[:, :-2]) & (mid > p[:, 2:]) & (mid >= strongest))
        i_b += 1
        parts.append((n_b + lo, i_b, p[n_b, i_b - 1], p[n_b, i_b], p[n_b, i_b + 1]))
    return [np.concatenate([part[k] for part in parts]) for k in range(5)]


def _ground_point(position_m, range_m, azimuth_deg, target_height_m=0.0):
    """Ground point at slant ``range_m`` from ``position_m`` along ground azimuth ``azimuth_deg``."""
    dz = position_m[..., 2] - target_height_m
    g = np.sqrt(np.maximum(np.asarray(range_m) ** 2 - dz**2, 0.0))
    az = np.radians(azimuth_deg)
    return np.stack([position_m[..., 0] + g * np.sin(az), position_m[..., 1] + g * np.cos(az),
                     np.full_like(g, target_height_m)], axis=-1)


def _azimuth_deg(position_m, point_m):
    d = point_m - position_m
    return np.degrees(np.arctan2(d[..., 0], d[..., 1]))


POINT_PEAK_FRACTION = 0.9   # of a scatterer's strong samples on its own range peak, or it is no point
# A point's sum power follows the sum beam's two-way envelope as the beam scans past it.  Points in one
# range cell that the beam sees together (an unresolved cluster) interfere: their power departs from any
# one envelope.  The rms of that departure beyond the samples' noise, over the envelope's mean power:
# true points measured 0.02-0.15 (20-45 dB; fwdlook's Gaussian beams and the independent writer's; the
# model's Gaussian main lobe is within 8 % of a sinc's at the window's edge), the paper lattice's
# clusters at 10-12 dB 1.24-3.04 (README, "Monopulse calibration")
ENVELOPE_MISFIT = 0.5


def point_returns(echo_sum, echo_diff, range_m, scan_angle_deg, position_m, *, beamwidth_deg, t_ref_index=None,
                  threshold_db=13.0, max_scatterers=24, n_iter=4, samples_per_resolution=1.0):
    """Strong isolated point-like returns seen across the scan, and their samples.

    Returns a dict of pooled per-pulse samples (``scatterer``, ``pulse``, ``offset_deg`` = delta_n,
    ``z`` = diff/sum, ``weight``, ``den`` and ``pow3`` of :func:`noise_chi2_per_sample`) and
    per-scatterer ``x_m``, ``y_m``, ``peak_snr_db``, plus the per-sample noise power ``noise_power``.
    Targets are taken on the ground (z = 0).  ``samples_per_resolution``: fs / B, the range samples per
    resolution cell c / (2 B), which sizes the range-peak test (a point's track lies on its own peak).
    """
    s = np.asarray(echo_sum)            # a file-backed cube (--out-of-core) stays a map: read in blocks
    dz = np.asarray(echo_diff)
    n_p, n_r = s.shape
    dr = float(range_m[1] - range_m[0])
    # the sum power |s|^2 is never held whole (half a channel): pulse blocks of POWER_BLOCK_BYTES
    step = max(1, POWER_BLOCK_BYTES // (4 * n_r))

    def powers():
        return (power_f32(s[lo:lo + step]) for lo in range(0, n_p, step))

    # noise power per sample: the lower quartile of |s|^2 is sigma^2 ln(4/3) for noise alone, and
    # barely moved by the returns' range sidelobes (which lift the median); np.percentile's number
    rows = np.unique(np.linspace(0, n_p - 1, min(n_p, -(-SAMPLE_VALUES // n_r))).astype(np.int64))
    noise = float(percentile_of_blocks(powers, n_p * n_r, 25.0, power_f32(s[rows]), np.float32)) / np.log(4.0 / 3.0)
    if not noise > 0:                   # (noiseless data with a quarter of exact zeros)
        noise = sum(float(np.sum(p, dtype=np.float64)) for p in powers()) / (n_p * n_r) * 1e-6 + 1e-30
    thr = noise * 10.0 ** (threshold_db / 10.0)
    n_idx, i_idx, p_before, p_at, p_after = _detections(
        s, thr, step, max(1, int(np.ceil(SIDELOBE_REACH_CELLS * samples_per_resolution))))
    empty = {"scatterer": np.zeros(0, int), "pulse": np.zeros(0, int), "offset_deg": np.zeros(0),
             "z": np.zeros(0, complex), "weight": np.zeros(0), "x_m": np.zeros(0), "y_m": np.zeros(0),
             "den": np.zeros(0), "pow3": np.zeros(0), "peak_snr_db": np.zeros(0), "noise_power": noise,
             "n_candidates": 0, "rejected": {}}
    if len(n_idx) < 10:
        return empty
    m_ref = n_p // 2 if t_ref_index is None else int(t_ref_index)
    p_ref = position_m[m_ref]
    # peak range, parabolic interpolation on |s|
    a, b, c = np.sqrt(p_before), np.sqrt(p_at), np.sqrt(p_after)
    frac = 0.5 * (a - c) / np.where(np.abs(a - 2 * b + c) > 0, a - 2 * b + c, 1.0)
    r_meas = range_m[0] + dr * (i_idx + np.clip(frac, -0.5, 0.5))
    # coarse point along the beam centre: its range from the t_ref antenna barely depends on the azimuth
    coarse = _ground_point(position_m[n_idx], r_meas, scan_angle_deg[n_idx])
    rho = np.linalg.norm(coarse - p_ref, axis=1)
    scan = scan_angle_deg[n_idx]
    scan_step = beamwidth_deg / 40.0
    ir = np.floor((rho - rho.min()) / dr).astype(np.int64)
    ia = np.floor((scan - scan.min()) / scan_step).astype(np.int64)
    lab, n_lab = label_cells(ir, ia)            # 8-connected groups on the (range, scan) grid
    counts = np.bincount(lab, minlength=n_lab)
    pw = p_at
    peak = np.full(n_lab, 0.0)
    np.maximum.at(peak, lab, pw)
    scan_lo, scan_hi = np.full(n_lab, np.inf), np.full(n_lab, -np.inf)
    np.minimum.at(scan_lo, lab, scan)
    np.maximum.at(scan_hi, lab, scan)
    rho_c = np.bincount(lab, weights=rho * pw, minlength=n_lab) / np.bincount(lab, weights=pw, minlength=n_lab)
    peak_db = 10 * np.log10(peak / noise)
    # a lone point stays above the threshold over 2 x (bw/2) sqrt(L / 6.02 dB), L = peak - threshold
    # (two-way Gaussian-like beam); longer: several scatterers merged
    expect = beamwidth_deg * np.sqrt(np.maximum(peak_db - threshold_db, 0.0) / 6.02)
    extent = scan_hi - scan_lo
    scan_all_lo, scan_all_hi = scan_angle_deg.min(), scan_angle_deg.max()
    rejected = {"weak": 0, "extended": 0, "scan_edge": 0, "neighbour": 0, "not_a_point": 0, "unresolved": 0,
                "residual": 0}
    ok = np.ones(n_lab, bool)
    weak = (counts < 16) | (peak_db < threshold_db + 6.0)
    rejected["weak"] = int(np.sum(weak))
    ok &= ~weak
    extended = ok & (extent > 1.3 * expect + 4 * scan_step)
    rejected["extended"] = int(np.sum(extended))
    ok &= ~extended
    edge = ok & ((scan_lo - scan_all_lo < 2 * scan_step) | (scan_all_hi - scan_hi < 2 * scan_step))
    rejected["scan_edge"] = int(np.sum(edge))
    ok &= ~edge
    # any other strong return (kept or not) near in range while the beam sees both: not isolated
    strong = np.nonzero(~weak | (peak_db > threshold_db + 3.0))[0]
    near = np.zeros(n_lab, bool)
    for j in np.nonzero(ok)[0]:
        other = strong[strong != j]
        close = (np.abs(rho_c[other] - rho_c[j]) < 4.0 * dr) & (scan_lo[other] < scan_hi[j]) \
            & (scan_hi[other] > scan_lo[j])
        near[j] = bool(np.any(close))
    rejected["neighbour"] = int(np.sum(near & ok))
    ok &= ~near
    keep = np.nonzero(ok)[0]
    keep = keep[np.argsort(-peak[keep])][:max_scatterers]
    if not len(keep):
        out = dict(empty)
        out.update(n_candidates=int(n_lab), rejected=rejected)
        return out

    # each scatterer's first position: the median of its beam-centre points
    n_s = len(keep)
    pt = np.zeros((n_s, 3))
    for j, k in enumerate(keep):
        pt[j] = np.median(coarse[lab == k], axis=0)
    # then sample every pulse on the scatterer's PREDICTED track (INS geometry), never on the detections
    # (a sample kept because it is above a threshold is biased high), and put the sum-beam axis where
    # the sum power envelope is symmetric: its power-weighted centroid in delta is zero
    window = 0.6 * beamwidth_deg
    pos = position_m[None, :, :]
    taps = np.arange(-1, 2)
    for it in range(n_iter + 1):
        az = _azimuth_deg(pos, pt[:, None, :])                     # [n_s, n_p]
        delta = az - scan_angle_deg[None, :]
        r = np.linalg.norm(pt[:, None, :] - pos, axis=2)
        idx = np.rint((r - range_m[0]) / dr).astype(np.int64)
        inside = (np.abs(delta) < window) & (idx >= 1) & (idx < n_r - 1)
        j_i, n_i = np.nonzero(inside)
        cols = idx[j_i, n_i][:, None] + taps[None, :]
        s3 = s[n_i[:, None], cols].astype(np.complex128)
        pow3 = np.sum(np.abs(s3) ** 2, axis=1)
        w_env = pow3 / 3.0 - noise                                  # unbiased signal power
        d_i = delta[j_i, n_i]
        centre = np.bincount(j_i, weights=w_env * d_i, minlength=n_s) / np.maximum(
            np.bincount(j_i, weights=w_env, minlength=n_s), 1e-30)
        if it == n_iter:
            break
        az_ref = _azimuth_deg(p_ref, pt) - centre
        rho_j = np.linalg.norm(pt - p_ref, axis=1)
        pt = _ground_point(np.broadcast_to(p_ref, (n_s, 3)), rho_j, az_ref)
    # envelope model (two-way, Gaussian-like) for the weights and the sample selection: not the data
    peak_pow = peak[keep] - noise
    model_pow = peak_pow[j_i] * 2.0 ** (-2.0 * (2.0 * d_i / beamwidth_deg) ** 2)
    d3 = dz[n_i[:, None], cols].astype(np.complex128)
    num = np.sum(np.conj(s3) * d3, axis=1)
    den = pow3 - 3.0 * noise
    # a point's track lies on its own range peak: the largest power within +-2.5 resolution cells is
    # within half a cell (at least one sample) of the predicted one in its strong samples (10 dB over
    # the noise: in every one of every true point measured, 20-40 dB).  A track that runs through a
    # neighbour's range sidelobes or between two points (what the detection takes for a point at high
    # SNR) is on a peak in 0-68 % of them (README, "Monopulse calibration"); 90 % is asked for
    reach = max(3, int(np.ceil(2.5 * samples_per_resolution)))
    tol = max(1, int(round(0.5 * samples_per_resolution)))
    at = np.clip(idx[j_i, n_i][:, None] + np.arange(-reach, reach + 1)[None, :], 0, n_r - 1)
    lobe = np.argmax(power_f32(s[n_i[:, None], at]), axis=1) - reach
    strong = den > 10.0 * noise
    n_strong = np.bincount(j_i, weights=strong, minlength=n_s)
    on_peak = np.bincount(j_i, weights=strong & (np.abs(lobe) <= tol), minlength=n_s)
    point_like = on_peak >= POINT_PEAK_FRACTION * n_strong
    rejected["not_a_point"] = int(np.sum(~point_like))
    # and a point's sum power follows the sum beam's envelope: one that departs from it is an unresolved
    # cluster, whose interfering ratios fit a flatter curve (the lattice at 10-12 dB: 51-67 % low)
    cluster = point_like & (envelope_misfit(j_i, d_i, w_env, noise, beamwidth_deg, n_s) > ENVELOPE_MISFIT)
    rejected["unresolved"] = int(np.sum(cluster))
    point_like &= ~cluster
    renum = np.cumsum(point_like) - 1                               # the kept scatterers, 0 .. n-1
    good = (model_pow > 10.0 * noise) & (den > 0.2 * pow3) & point_like[j_i]
    j_i = renum[j_i]
    pt, keep = pt[point_like], keep[point_like]
    # z = num / den is biased at low SNR (by more than noise/den: the samples' noise is correlated), but
    # num - m den is not (E num = m E den for the model ratio m): the fit's residual is (z - m) den,
    # so its weight is den^2 / var(num - m den), var = noise P3 (1 + |m|^2) with P3 the model power
    z = num[good] / den[good]
    sc, ni, delta = j_i[good], n_i[good], d_i[good]
    weight = den[good] ** 2 / (noise * 3.0 * model_pow[good])
    return {"scatterer": sc, "pulse": ni, "offset_deg": delta, "z": z, "weight": weight,
            "den": den[good], "pow3": pow3[good],
            "x_m": pt[:, 0], "y_m": pt[:, 1], "peak_snr_db": peak_db[keep], "noise_power": noise,
            "n_candidates": int(n_lab), "rejected": rejected}


def envelope_misfit(j_i, d_i, signal, noise_power, beamwidth_deg, n_s):
    """Per scatterer: the rms departure of its sum power (``signal``: each sample's noise-corrected power
    per tap, at beam offset ``d_i`` from its power centroid) from the two-way envelope
    A 2^(-2 (2 d / bw)^2) fitted to it (A by weighted least squares), beyond what the samples' noise
    explains (variance (noise^2 + 2 S noise) / 3 each, S the envelope's power), over the envelope's mean
    power; NaN where no envelope fits (no signal)."""
    total = np.bincount(j_i, weights=signal, minlength=n_s)
    centre = np.bincount(j_i, weights=signal * d_i, minlength=n_s) / np.where(total > 0, total, np.inf)
    env = 2.0 ** (-2.0 * (2.0 * (d_i - centre[j_i]) / beamwidth_deg) ** 2)
    var = (noise_power ** 2 + 2.0 * np.maximum(signal, 0.0) * noise_power) / 3.0
    amp = np.bincount(j_i, weights=signal * env / var, minlength=n_s) / np.maximum(
        np.bincount(j_i, weights=env * env / var, minlength=n_s), 1e-300)
    model = amp[j_i] * env
    var_model = (noise_power ** 2 + 2.0 * np.maximum(model, 0.0) * noise_power) / 3.0
    count = np.maximum(np.bincount(j_i, minlength=n_s), 1)
    excess = np.bincount(j_i, weights=(signal - model) ** 2 - var_model, minlength=n_s) / count
    mean_model = np.bincount(j_i, weights=model, minlength=n_s) / count
    ok = (total > 0) & (mean_model > 0)
    return np.where(ok, np.sqrt(np.maximum(excess, 0.0)) / np.where(ok, mean_model, 1.0), np.nan)


def noise_chi2_per_sample(z, model_z, den, pow3, noise_power) -> float:
    """Mean of |z - m|^2 over the noise variance of z = num/den at the model ratio m: 1 where the samples
    depart from the curve by their noise alone.

    Per pulse, r = num - m den = sum over the three taps of conj(s) (d - m s) + m (3 noise - |n_s|^2);
    with s = S + n_s and d = m S + n_d (noise power ``noise_power`` per channel and sample) its variance
    is noise (1 + |m|^2) (sum |S|^2 + 3 noise) = noise (1 + |m|^2) pow3, so var z = that / den^2.
    Interference the curve does not hold (a neighbour's range sidelobes under a 'point', merged
    scatterers, a curve of the wrong shape) adds to the residual and not to the noise."""
    var_z = noise_power * pow3 * (1.0 + np.abs(model_z) ** 2) / den ** 2
    return float(np.mean(np.abs(z - model_z) ** 2 / var_z))
