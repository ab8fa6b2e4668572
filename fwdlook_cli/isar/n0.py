"""Estimation of the range-minimum shift n0 from the data (eq. 12-13): image sharpness search."""
from __future__ import annotations


import numpy as np
import scipy.fft as sfft

from ..dsp.geometry import C_MPS
from ..dsp.keystone_common import _cis
from ..io.stagefile import StageData
from .geometry import LineModel
from .stages import _doppler_line, _keystone, _to_freq, _to_time
from .track import peak_track
from ..dsp.geometry import ambiguity_number
from .stages import _ambiguity_rows
from ..errors import BadInput

TRACK_GATE_SAMPLES = 2.0   # a lone scatterer's per-pulse peak stays within a sample of its curve (0.05 at 20 dB)
MIN_TRACK_INLIERS = 0.5    # most pulses must be the reference's for a curve to be fitted at all


# ----------------------------------------------------------------------------------------------
# n0 estimation
# ----------------------------------------------------------------------------------------------
def _sharpness(cells, t_rel, fc, r0, rdot, v2_grid):
    """Image sharpness sum|I|^4 / (sum|I|^2)^2 for every |v|^2 candidate (model phase, then FFT)."""
    tau = t_rel[:, None]
    rm = np.sqrt(np.maximum(r0**2 + 2.0 * r0 * rdot * tau + v2_grid[None, :] * tau**2, 0.0)) - r0
    ref = _cis(2.0 * fc * rm / C_MPS).astype(np.complex64)             # [N, J]
    z = cells[:, :, None] * ref[:, None, :]                             # [N, C, J]
    spec = sfft.fft(z, axis=0, workers=-1)
    p = spec.real.astype(np.float64) ** 2 + spec.imag.astype(np.float64) ** 2
    return np.sum(p**2, axis=(0, 1)) / np.sum(p, axis=(0, 1)) ** 2


def _doppler_peak_hz(cells, t_rel, fc, r0, rdot, v2, prf):
    """Interpolated Doppler of the peak of the model-compensated image of ``cells``."""
    from ..dsp.peaks import interpolate_peak, oversample_profile

    ref = _cis(2.0 * fc * (LineModel(r0, rdot, v2, 0.0).range_m(t_rel) - r0) / C_MPS)
    spec = sfft.fftshift(sfft.fft(cells * ref[:, None].astype(np.complex64), axis=0), axes=0)
    c = int(np.argmax(np.sum(np.abs(spec) ** 2, axis=0)))
    line = _doppler_line(spec[:, c])
    factor = 8
    fine = np.abs(oversample_profile(line, factor)) ** 2
    k = int(np.argmax(fine))
    k = min(max(k, 1), fine.size - 2)
    idx, _ = interpolate_peak(fine, k)
    n = len(line)
    return (idx / factor - n // 2) * prf / n


def _refine_max(grid, values):
    """Parabolic refinement of a sampled maximum (on log values); returns (x, index of the max)."""
    j = int(np.argmax(values))
    if 0 < j < len(grid) - 1 and np.all(values[j - 1:j + 2] > 0):
        lm, l0, lp = np.log(values[j - 1:j + 2])
        curv = lm - 2.0 * l0 + lp
        if curv < 0:
            off = float(np.clip(0.5 * (lm - lp) / curv, -1.0, 1.0))
            return grid[j] + off * (grid[j + 1] - grid[j]), j
    return float(grid[j]), j


def estimate_n0(data: StageData, *, half_span_lobes: float = 4.0, points_per_lobe: int = 6, passes: int = 2,
                ambiguity="auto", keystone: str = "czt") -> StageData:
    """Estimate n0 from the data (module docstring, Estimating n0); the echo passes through.

    Adds the attributes ``n0_est_pulses``, ``n0_coarse_pulses``, ``model_r0_m``, ``model_rdot_mps``,
    ``model_v2_m2ps2``, ``model_t_mid_s``, ``doppler_centroid_hz``, ``ambiguity_centre`` and the last
    search grid (``n0_search_pulses`` and ``n0_search_sharpness``).
    """
    out = StageData(dict(data.vars), dict(data.attrs))
    echo = data["echo"]
    t = np.asarray(data["slow_time_s"], dtype=np.float64)
    rng = np.asarray(data["range_m"], dtype=np.float64)
    fc, prf, fs = float(data.attrs["fc_hz"]), float(data.attrs["prf_hz"]), float(data.attrs["fs_hz"])
    lam = C_MPS / fc
    n = echo.shape[0]
    t_mid = 0.5 * (t[0] + t[-1])
    t_rel = t - t_mid
    dwell = t[-1] - t[0] + 1.0 / prf
    dr = rng[1] - rng[0]

    # (1) coarse: quadratic fit of the per-pulse peak range
    pos, peak = peak_track(echo)
    ok = peak >= 0.25 * np.median(peak)
    track = rng[0] + pos * dr
    c2, c1, c0 = np.polyfit(t_rel[ok], track[ok], 2)
    # the pulses whose peak is the reference's (within TRACK_GATE_SAMPLES of the curve), the curve fitted
    # again on them: where noise wins a pulse (10 dB per sample: 12 % of them, up to 30 m off) the first
    # fit is pulled; where it wins most of them the track is noise (an independent review's 0 dB gave
    # n0 = 117 045 for 4 318 with exit 0, -10 dB a traceback): refused
    for _ in range(2):
        inliers = ok & (np.abs(track - np.polyval([c2, c1, c0], t_rel)) <= TRACK_GATE_SAMPLES * dr)
        if inliers.sum() < MIN_TRACK_INLIERS * ok.sum():
            raise BadInput(f"processing.correction = keystone2_n0_est: the per-pulse peak track follows no curve "
                           f"({int(inliers.sum())} of {int(ok.sum())} pulses within {TRACK_GATE_SAMPLES:g} range "
                           f"samples of its fit; allowed: at least {MIN_TRACK_INLIERS:.0%}): the reference is under "
                           f"the noise in each pulse; use keystone2_n0 (n0 from the geometry) or a stronger reference")
        if inliers.sum() == ok.sum():
            break
        c2, c1, c0 = np.polyfit(t_rel[inliers], track[inliers], 2)
    r0, rdot, rddot = float(c0), float(c1), 2.0 * float(c2)
    lobe_v2 = lam * r0 / (2.0 * dwell**2)                              # |v|^2 error of one lobe
    if r0 * rddot < lobe_v2:
        # the track's curvature (the tangential |v|^2 = r0 R'') under one lobe: the dwell's aperture, v_t T,
        # spans less than one cross-range resolution cell, lambda r0 / (2 v_t T), and no image sharpness
        # can tell n0 (a 32-pulse dwell had given n0 = 1 010 089 for 4 318, exit 0, the target lost)
        raise BadInput(f"processing.correction = keystone2_n0_est: the dwell ({n} pulses, {dwell:.3g} s) is too "
                       f"short to measure the object's cross-range motion (its range track's curvature gives "
                       f"|v_t|^2 = {max(r0 * rddot, 0.0):.3g} m^2/s^2, under the {lobe_v2:.3g} the dwell resolves); "
                       f"use keystone2_n0 (n0 from the geometry), keystone1, or a longer dwell")
    v2 = max(r0 * rddot + rdot**2, rdot**2 + lobe_v2)
    n0_coarse = -r0 * rdot * prf / v2

    # (2) n0-shifted second-order keystone at the coarse n0, range cells of the target
    fr = sfft.fftshift(sfft.fftfreq(echo.shape[1], 1.0 / fs))
    rows = _ambiguity_rows(ambiguity, -2.0 * rdot / lam, fr, fc, prf)
    y = _to_time(_keystone(_to_freq(echo), fr, fc, order=2, t0_index=(n - 1) / 2.0 + n0_coarse,
                           ambiguity_rows=rows, method=keystone))
    energy = np.sum(np.abs(y) ** 2, axis=0)
    top = int(np.argmax(energy))
    sel = np.nonzero(energy >= 0.1 * energy[top])[0]
    sel = sel[np.abs(sel - top) <= 4]
    cells = y[:, sel]

    # (3)-(4) sharpness search over the model (one |v|^2 per candidate n0), then Doppler refinement
    half, step = half_span_lobes * lobe_v2, lobe_v2 / points_per_lobe
    grid = sharp = None
    for _ in range(passes):
        for _shift in range(8):                                         # follow a maximum at the edge
            grid = v2 + np.arange(-half, half + 0.5 * step, step)
            grid = grid[grid > rdot**2]
            if len(grid) < 3:            # no |v|^2 over rdot^2 left to search: a model the data do not hold
                raise BadInput("processing.correction = keystone2_n0_est: the n0 search found no candidate "
                               "(|v|^2 under the radial speed's square); use keystone2_n0 (n0 from the geometry)")
            sharp = _sharpness(cells, t_rel, fc, r0, rdot, grid)
            j = int(np.argmax(sharp))
            if 0 < j < len(grid) - 1:
                break
            v2 = float(grid[j])
        v2, _ = _refine_max(grid, sharp)
        rdot -= lam * _doppler_peak_hz(cells, t_rel, fc, r0, rdot, v2, prf) / 2.0
        half, step = 2.0 * step, step / 4.0
    model = LineModel(r0, rdot, v2, t_mid)
    n0_grid = -r0 * rdot * prf / grid
    out.add("n0_candidate", np.arange(len(grid)), ("n0_candidate",), "1", "index of the candidate")
    out.add("n0_search_pulses", n0_grid, ("n0_candidate",), "1", "n0 of each candidate of the last pass")
    out.add("n0_search_sharpness", sharp, ("n0_candidate",), "1", "image sharpness sum|I|^4/(sum|I|^2)^2")
    out.attrs.update(n0_est_pulses=model.n0_pulses(prf), n0_coarse_pulses=float(n0_coarse),
                     doppler_centroid_hz=model.doppler_hz(fc),
                     ambiguity_centre=int(ambiguity_number(model.doppler_hz(fc), prf)),
                     **{f"model_{k}": v for k, v in model.as_dict().items()})
    return out
