"""Monopulse imaging over each direction's whole beam dwell (``processing.imaging: dwell``).

The paper forms its image per 32-pulse CPI: neighbours closer in Doppler than PRF/32 share a cell and
their monopulse ratio mixes (NOTES.md, Corrections).  A scanning beam covers a direction for the
whole two-way dwell, about 350 pulses (two-way width 4.25 deg at 30 deg/s), so the Doppler
resolution available is 1/T_dwell, and the angular one lambda / (2 v T_dwell |sin theta| cos phi):
0.16-0.8 deg for |theta| >= 1 deg.  This module uses it.

Design (sub-aperture back-projection).  The input is the motion-compensated range-time cube (stage 5:
every scatterer's envelope at its slant range from the antenna at t_ref, its carrier phase the full
history -4 pi R(t)/lambda).  The image grid is the monopulse image's: slant range r from the antenna
at t_ref and azimuth theta at t_ref; grid point (r, theta) is the ground point P(r, theta), whose exact
range history R_P(t) = |P - p(t)| comes from the INS positions ``position_m``.

1. **Monopulse rotation.**  For the two squinted Gaussian beams the echoes are a Sigma^2 (sum) and
   a Sigma Delta (difference) with Delta/Sigma = tanh(k d), d the offset from the beam axis.  For a
   direction whose offset from the axis of pulse n is delta_n (known: scan and INS), the rotated pair
   S'_n = s cosh(k delta_n) - d sinh(k delta_n),  D'_n = d cosh(k delta_n) - s sinh(k delta_n)
   equals a Sigma e^{-beta d^2} (cosh, sinh)(k eps) with eps = d - delta_n the target's offset from
   that direction: the same for every pulse of the dwell although the beam sweeps across it.  So the
   coherent dwell sums keep Re(D'/S') = tanh(k eps) exactly and the angle inside the resolved cell is
   theta + atanh(Re(D'/S'))/k, k the chain's monopulse slope (``chain.monopulse_slope``).
2. **Sub-apertures.**  Slow time is cut into sub-apertures over which the beam moves 0.48 deg
   (``SUB_APERTURE_DEG``: 40 pulses for the paper).  Each is dechirped by the Doppler rate of the
   point on its beam axis (acceleration and geometry: 6 kHz/s at a = 50) and FFT-ed over the whole
   PRF with x8 zero padding, both channels.
3. **Dwell.**  For every sub-aperture j, every direction within ``dwell_half_width_deg`` (0.75 two-way
   widths, 3.2 deg) of its beam seen from its antenna (``dwell_grid.subaperture_windows``; the directions
   are the image's, and finer where the dwell's angle lobe is narrower than a bin:
   ``dwell_grid.focus_per_bin``) and every range, the spectrum is read (linear interpolation) at the
   Doppler of P at the sub-aperture centre, rotated (step 1, delta of P itself: parallax makes it
   range dependent), phased with the exact exp(+j 4 pi (|P - p(t_j)| - r) / lambda) and summed over
   the dwell with the matched-filter weight w = Sigma(delta) e^{-beta delta^2} a target in that
   direction has (a Gaussian taper: low Doppler sidelobes): a back-projection whose inner sums are the
   sub-apertures.  The -r keeps the focused image smooth in range, so it is band-limited-oversampled
   like the CPI image, where the depression is low; where it is steep the phases' range slopes widen
   the image's range band beyond the native rate, and the dwell is focused on the oversampled grid
   (``dwell_range.focus_range_oversample``).
4. **Twins.**  With the flight along +y, theta and -theta have the same range history (mirror Doppler):
   no Doppler processing separates them, only the scan does (the beam reaches -theta before +theta).
   Where the twin lies inside the dwell and its envelope is distinct (correlation^2 < 0.9), the
   weights are made orthogonal to the twin's envelope and its first time moment over the dwell
   (``twin_null``).  It cancels a twin at the mirror direction; pairs closer than about 2.5 deg to
   each other, and x = 0 against +-30 m of the paper lattice (5 Hz apart, 1/T_dwell = 7 Hz), still mix.
5. **Projection.**  Cells above ``threshold_db`` over the image's median power (the noise floor),
   within ``dynamic_range_db`` of its peak and with |eps| under half a beamwidth put |S'|^2 at the
   azimuth theta + eps seen from the dwell's mean antenna position, moved to the t_ref frame exactly
   (``dsp.geometry.azimuth_at_t_ref``): one target's resolved cell lands on one angle bin.

6. **Joint fit near the flight axis** (``processing.dwell_fit: joint``, ``dwell_fit.py``).  Within
   ``FIT_REGION_BEAMS`` dwell half-widths of the flight axis (4.8 deg) the mirror pairs and the
   neighbours closer than 1/T_dwell still mix in steps 3-4; there the range cells around every range
   peak are fitted jointly (a group OMP over the dictionary of predicted [Sigma, Delta] histories,
   continuous angles, RELAX) and the fitted scatterers replace those directions' cells in the image.

Cost (``fwdlook bench``, paper cube, idle machine, without step 6): the ``dwell_image`` stage is about
40 plain 2-D FFTs of one channel (2 x 62 FFTs of 320 x 280, then per sub-aperture x direction x range,
8.8 k x 280 cells, one interpolated read, the phase, the rotation and one sparse sum over the dwell),
run over blocks of sub-apertures on the stage thread pool (bounded memory); the whole chain 1.12-1.17 x
``chain_tracking_s`` (issue 11's twenty-fourth round).  Step 6 (the tracking preset's default) adds
130-150 ms on the paper lattice (started on forked workers before this stage projects its own
cells), the whole chain 1.88-2.01 x ``chain_tracking_s`` then, 2.8 x now (README, "Imaging over each
direction's whole dwell"; ``dwell_fit.py`` says where it goes).
"""
from __future__ import annotations

import logging
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import scipy.fft
import scipy.sparse

from ..dsp.antenna import two_way_width_for
from ..dsp.geometry import C_MPS, azimuth_at_t_ref
from ..dsp.blas import worker_threads
from ..dsp.imaging import float32_floor, image_angle_grid, median_floor
from ..io import backing
from .monopulse import subaperture_real_beam
from ..dsp.peaks import oversample_range
from ..dsp.keystone_common import _cis as _cis_cycles, cis_rad as _cis
from ..io.stagefile import StageData
from .calibration import Calibration, check_slope_forms_a_beam, pattern_beta_per_deg2
from .dwell_fit import start_fit_region
from .dwell_fit_plan import fit_cell_model_holds, fit_models_antenna
from .dwell_grid import check_focus_sizes, focus_directions, focus_per_bin, pattern_weight, subaperture_windows
from .dwell_range import (auto_focus_range_oversample, dwell_duration_s, dwell_stage_params, flight_axis_deg,
                          ground_points, iso_doppler_range, oversample_focus_input)

log = logging.getLogger(__name__)


SUB_APERTURE_DEG = 0.48          # scan per sub-aperture: its rotation and weight are taken at its centre
DWELL_HALF_WIDTH_BEAMS = 0.75    # dwell of a direction: offsets within 0.75 two-way widths (3.2 deg, paper)
FIT_REGION_BEAMS = 1.5           # dwell_fit: the joint fit owns directions within 1.5 dwell half-widths of the
                                 # flight axis (4.8 deg: the mirror pairs closer than the dwell window and beyond)



def dwell_focus(sum_rt, diff_rt, *, slow_time_s, scan_angle_deg, position_m, velocity_mps, range_m, angle_deg,
                fc_hz, prf_hz, slope_per_deg, beta_per_deg2, position_ref_m, sub_pulses=40,
                dwell_half_width_deg=3.2, fft_oversample=8, twin_null=True, twin_axis_deg=0.0, twin_orders=1,
                twin_max_corr2=0.9, block_cells=None):
    """Rotated sum and difference of every (direction, range) integrated over its dwell.

    Returns ``(s_rot, d_rot, gain, pos_dwell, plain_gain)``: complex64 [n_angle, n_range] images S', D'
    (module docstring, steps 1-4), the matched-filter gain sum_j w_j^2 of each direction (0 where the scan
    never looks), the gain-weighted antenna position over each direction's dwell [n_angle, 3], and the
    gain before the twin null (the scale of a point whose twin needs no null: the joint fit's points).
    """
    lam = C_MPS / fc_hz
    k = slope_per_deg
    block_cells = DWELL_BLOCK_CELLS if block_cells is None else block_cells
    m, n_r = sum_rt.shape
    n_a = len(angle_deg)
    L = sub_pulses
    n_sub = m // L
    beam_j = np.asarray(scan_angle_deg[: n_sub * L], dtype=np.float64).reshape(n_sub, L).mean(axis=1)
    p_ref = np.asarray(position_ref_m, dtype=np.float64)
    n = np.arange(m, dtype=np.float64)
    idx_c = (np.arange(n_sub) + 0.5) * L - 0.5                               # sub-aperture centre (pulses)
    pos_c = np.stack([np.interp(idx_c, n, position_m[:, i]) for i in range(3)], axis=-1)     # [n_sub, 3]
    # each sub-aperture's directions: those whose offset from its beam, seen from its antenna, lies in the
    # dwell window (dwell_grid.subaperture_windows); the valid ones a prefix of each row
    r_mid = 0.5 * (range_m[0] + range_m[-1])
    p_all = ground_points(r_mid, np.asarray(angle_deg, dtype=np.float64), p_ref)          # [n_a, 3]
    delta_all = np.degrees(np.arctan2(p_all[None, :, 0] - pos_c[:, None, 0], p_all[None, :, 1] - pos_c[:, None, 1])) \
        - beam_j[:, None]
    g, valid, count = subaperture_windows(delta_all, dwell_half_width_deg)    # [n_sub, n_loc] global index
    n_loc = g.shape[1]
    gi = np.clip(g, 0, n_a - 1)
    theta = np.asarray(angle_deg, dtype=np.float64)[gi]                      # direction at t_ref
    delta = np.take_along_axis(delta_all, gi, axis=1)
    del p_all, delta_all
    vel_c = np.stack([np.interp(idx_c, n, velocity_mps[:, i]) for i in range(3)], axis=-1)
    acc_c = np.gradient(vel_c, idx_c / prf_hz, axis=0)
    tau = (np.arange(L) - 0.5 * (L - 1)) / prf_hz                            # time from the centre

    # 1. dechirp each sub-aperture by the Doppler rate of a fixed point on its beam axis (the
    #    acceleration and the geometric term), then an oversampled FFT over the whole PRF
    bp = ground_points(r_mid, beam_j, p_ref) - pos_c
    rb = np.linalg.norm(bp, axis=1)
    ub = bp / rb[:, None]
    vr = np.einsum("ji,ji->j", vel_c, ub)
    rate_hz_s = 2.0 * (np.einsum("ji,ji->j", acc_c, ub) - (np.einsum("ji,ji->j", vel_c, vel_c) - vr**2) / rb) / lam
    chirp = _cis(-np.pi * rate_hz_s[:, None] * tau[None, :] ** 2)            # [n_sub, L]
    n_fft = int(fft_oversample * L)

    # 2. per (sub-aperture, direction): offset of the direction from the beam axis at the centre, the
    #    pattern weight, and the twin's envelope (over the whole dwell: small [n_sub, n_loc] arrays)
    w = pattern_weight(delta, beta_per_deg2, k) * (np.abs(delta) <= dwell_half_width_deg) * valid
    plain_gain = np.bincount(gi[valid], weights=(w**2)[valid], minlength=n_a)
    if twin_null:
        p_tw = ground_points(r_mid, 2.0 * twin_axis_deg - theta, p_ref)
        d_tw = np.degrees(np.arctan2(p_tw[..., 0] - pos_c[:, None, 0], p_tw[..., 1] - pos_c[:, None, 1])) \
            - beam_j[:, None]
        t_c = np.interp(idx_c, n, slow_time_s)
        w = _orthogonalise(w, pattern_weight(d_tw, beta_per_deg2, k) * (w != 0), g, n_a, t_c, twin_orders,
                           twin_max_corr2)
    gain = np.bincount(gi[valid], weights=(w**2)[valid], minlength=n_a)
    pos_dwell = np.stack([np.bincount(gi[valid], weights=(w**2 * pos_c[:, None, i])[valid], minlength=n_a)
                          for i in range(3)], axis=-1) / np.maximum(gain, 1e-300)[:, None]

    # 3-4. per block of sub-apertures (bounded memory: the spectra and the [sub-aperture, direction,
    #    range] temporaries of one block only), summed over the dwell into the global directions
    rr = np.asarray(range_m, dtype=np.float64)
    rho = np.sqrt(np.maximum(rr**2 - p_ref[2] ** 2, 0.0))                    # [n_r]
    rho32 = rho.astype(np.float32)
    s_rot = np.zeros((n_a, n_r), np.complex128)
    d_rot = np.zeros((n_a, n_r), np.complex128)
    threads = worker_threads()
    # the blocks in flight together hold what one block of ``block_cells`` would (the same memory), for
    # the mean window (the windows are wider where the bins are focused in more directions)
    n_mean = float(count.mean()) if count.size else float(n_loc)
    step = max(1, int(int(block_cells) // max(1.0, threads * (n_mean * n_r + n_fft * n_r))))

    def block(j0):                # one block's sums over its sub-apertures, in its own thread
        j = slice(j0, min(n_sub, j0 + step))
        n_b = int(count[j].max())             # the block's directions: as many as its widest window holds
        if n_b == 0:
            return 0, np.zeros((0, n_r), np.complex64), np.zeros((0, n_r), np.complex64)
        s_part, d_part = _focus_block(sum_rt, diff_rt, j, L=L, n_fft=n_fft, chirp=chirp[j], theta=theta[j, :n_b],
                                      w=w[j, :n_b], pos_c=pos_c[j], vel_c=vel_c[j], beam_j=beam_j[j], p_ref=p_ref,
                                      rr=rr, rho=rho, rho32=rho32, lam=lam, prf_hz=prf_hz, k=k,
                                      max_offset_deg=dwell_half_width_deg + NEAR_FIELD_MARGIN_DEG,
                                      fft_workers=1 if threads > 1 else -1)
        gj, vj = gi[j, :n_b].ravel(), valid[j, :n_b].ravel()
        lo = int(gj.min())                    # the block's directions: one band of rows of the image
        hi = int(gj.max()) + 1
        acc = scipy.sparse.csr_matrix((vj.astype(np.float32), (gj - lo, np.arange(gj.size))),
                                      shape=(hi - lo, gj.size))
        return lo, acc @ s_part.reshape(gj.size, n_r), acc @ d_part.reshape(gj.size, n_r)

    starts = range(0, n_sub, step)
    with ThreadPoolExecutor(max_workers=threads) as pool:     # the blocks' sums added in order
        for lo, s_blk, d_blk in pool.map(block, starts):
            s_rot[lo:lo + len(s_blk)] += s_blk
            d_rot[lo:lo + len(d_blk)] += d_blk
    return s_rot.astype(np.complex64), d_rot.astype(np.complex64), gain, pos_dwell, plain_gain


NEAR_FIELD_MARGIN_DEG = 1.0   # a sub-aperture sees P(r, theta) while its offset at r is within the dwell window + 1 deg
                              # (parallax across the paper's 1.5-1.8 km window: under 0.2 deg)
DWELL_BLOCK_CELLS = 1 << 19     # (sub-aperture x (direction + FFT bin) x range) cells per block of dwell_focus
                                # (2^18 before: the dwell image 319 against 293 ms, the blocks' Python overhead)


ATAN_SERIES_MAX = 0.3        # |x| up to which atan(x) is its odd series to x^9 (error x^11 / 11 < 2e-7 rad)


def _k_offset(theta, beam_j, dg, rho32, k, ground):
    """k times the offset (deg) of P(r, theta) from the beam axis seen from each sub-aperture centre
    [n_j, n_loc, n_r] (float32): P - p_j = rho u(theta) + dg, whose azimuth is theta + atan(x) with
    x = (dg_x cos theta - dg_y sin theta) / (rho + dg . u(theta)), the parallax.  For the ranges with
    a ground point (``ground`` [n_r]) |x| is small (130 m against 1.5 km: 0.09), so atan is its series,
    a few multiplications instead of an arctan2 per cell; where some |x| exceeds ATAN_SERIES_MAX or P
    lies behind the antenna (near field) the block takes arctan2 itself."""
    th = np.radians(theta)
    sin_t, cos_t = np.sin(th), np.cos(th)
    cross = (dg[:, None, 0] * cos_t - dg[:, None, 1] * sin_t).astype(np.float32)[:, :, None]
    along = rho32[None, None, :] + (dg[:, None, 0] * sin_t + dg[:, None, 1] * cos_t).astype(np.float32)[:, :, None]
    k_deg = np.float32(np.degrees(k))
    base = (k * (theta - beam_j[:, None])).astype(np.float32)[:, :, None]
    x = cross / along
    xg = x[:, :, ground]                    # (the others are not seen: their kd is dropped by the caller)
    if xg.size and (np.abs(xg).max() > ATAN_SERIES_MAX or along[:, :, ground].min() <= 0):
        return k_deg * np.arctan2(cross, along) + base
    np.clip(x, -1.0, 1.0, out=x)           # (no overflow where there is no ground point)
    x2 = x * x
    poly = np.float32(1.0 / 9.0) * x2                      # atan x = x (1 - x^2/3 + x^4/5 - x^6/7 + x^8/9)
    for c in (-1.0 / 7.0, 1.0 / 5.0, -1.0 / 3.0):
        poly += np.float32(c)
        poly *= x2
    poly += np.float32(1.0)
    poly *= x
    poly *= k_deg
    poly += base
    return poly


def _focus_block(sum_rt, diff_rt, j, *, L, n_fft, chirp, theta, w, pos_c, vel_c, beam_j, p_ref, rr, rho, rho32,
                 lam, prf_hz, k, max_offset_deg, fft_workers=-1):
    """Steps 1 and 3 of :func:`dwell_focus` for the sub-apertures ``j`` (a slice): their spectra, each
    direction's interpolated read at its Doppler, the exact phase and the rotation; returns the
    weighted S', D' parts [n_j, n_loc, n_r] (complex64)."""
    n_j = chirp.shape[0]
    n_r = sum_rt.shape[1]
    rows = slice(j.start * L, (j.start + n_j) * L)
    spec = []
    for x in (sum_rt, diff_rt):
        xs = np.asarray(x[rows]).reshape(n_j, L, n_r) * chirp[:, :, None]
        spec.append(scipy.fft.fft(xs, n=n_fft, axis=1, workers=fft_workers).reshape(-1))   # [n_j * n_fft * n_r]
    # exact range history of P(r, theta) at each sub-aperture centre: |P - p_j|^2 = rho^2 + 2 rho b + c
    u = np.stack([np.sin(np.radians(theta)), np.cos(np.radians(theta))], axis=-1)   # [n_j, n_loc, 2]
    dg = p_ref[None, :2] - pos_c[:, :2]                                      # [n_j, 2]
    b = np.einsum("jli,ji->jl", u, dg)
    c = np.sum(dg**2, axis=1) + pos_c[:, 2] ** 2
    r_jr = np.sqrt(rho**2 + 2.0 * rho * b[:, :, None] + c[:, None, None])   # [n_j, n_loc, n_r]
    # Doppler of P at the centre, 2 v.(P - p_j) / (lambda |P - p_j|), as an FFT bin (mod PRF): the factor
    # 2 n_fft / (lambda PRF) taken into the [sub-aperture, direction] terms before they are broadcast
    to_bin = 2.0 * n_fft / (lam * prf_hz)
    vd = (np.einsum("ji,ji->j", vel_c[:, :2], dg) - vel_c[:, 2] * pos_c[:, 2]) * to_bin
    vu = np.einsum("jli,ji->jl", u, vel_c[:, :2]) * to_bin
    pos_bin = rho * vu[:, :, None]
    pos_bin += vd[:, None, None]
    pos_bin /= r_jr
    # exact phase of P at t_j (minus the t_ref range), with the FFT's origin moved to the centre:
    # 2 (R - r) / lambda + f (L - 1) / (2 PRF), the second term pos_bin (L - 1) / (2 n_fft) (unwrapped)
    cycles = r_jr - rr
    cycles *= 2.0 / lam
    cycles += pos_bin * (0.5 * (L - 1) / n_fft)
    del r_jr
    pos_bin -= np.floor(pos_bin * (1.0 / n_fft)) * n_fft   # mod n_fft by a floor (np.mod: several times slower)
    pos_bin[pos_bin >= n_fft] -= n_fft                 # the floor's last-bit rounding: [0, n_fft) exactly
    i0 = np.floor(pos_bin).astype(np.int64)
    frac = (pos_bin - i0).astype(np.float32)
    base = (np.arange(n_j)[:, None, None] * n_fft) * n_r + np.arange(n_r)[None, None, :]
    f0 = base + i0 * n_r
    i0 += 1                                            # the next bin, i0 in [0, n_fft): wrapped at n_fft
    i0[i0 == n_fft] = 0
    f1 = base + i0 * n_r
    focus = _cis_cycles(cycles, np.complex64)
    del cycles, pos_bin, i0, base
    near = 1 - frac
    zs = spec[0][f0] * near + spec[0][f1] * frac                             # linear interpolation in Doppler
    zd = spec[1][f0] * near + spec[1][f1] * frac
    del spec, f0, f1, frac, near
    # rotation by the offset of P(r, theta) itself from the beam axis: parallax makes it range dependent
    # (the antenna is up to 130 m from p_ref when the beam passes a direction)
    kd = _k_offset(theta, beam_j, dg, rho32, k, rr > p_ref[2])                     # k delta [n_j, n_loc, n_r]
    # the weights w were taken at the window's middle range; where the offset at this range lies beyond
    # the dwell window (near field: the antenna's motion is not small against the range) or the range
    # has no ground point (r <= height, or a negative range of a recorded window), the sub-aperture does
    # not see P and cosh(k delta) would amplify noise without bound (e^26 behind the antenna): zeroed
    seen = (np.abs(kd) <= np.float32(k * max_offset_deg)) & (rr > p_ref[2])[None, None, :]
    kd = np.where(seen, kd, np.float32(0.0))
    ek = np.exp(kd)
    half_w = (0.5 * w[:, :, None]).astype(np.float32) * seen
    ch = half_w * (ek + 1.0 / ek)                                           # w cosh(k delta)
    sh = half_w * (ek - 1.0 / ek)                                           # w sinh(k delta)
    del kd, ek
    s_part = (ch * zs - sh * zd) * focus                                     # S' = s cosh - d sinh
    d_part = (ch * zd - sh * zs) * focus                                     # D' = d cosh - s sinh
    return s_part, d_part


def _orthogonalise(w, e, g, n_a, t_s, n_orders=1, max_corr2=0.9):
    """Make each direction's weights w [n_sub, n_loc] orthogonal, over its whole dwell, to the twin's
    envelope e and to e (t - t_dir)^p, p < n_orders (a twin slightly off the mirror direction has a
    residual Doppler: the first-order term nulls its leakage too).

    Only where the twin is distinct from the direction (envelope correlation^2 < 0.9): near the flight
    axis the twin is the direction itself and nulling it would null the target.
    """
    valid = (g >= 0) & (g < n_a)
    gi = np.clip(g, 0, n_a - 1)
    gv = gi[valid]

    def dsum(x):
        return np.bincount(gv, weights=x[valid], minlength=n_a)

    ww = dsum(w * w)
    t_dir = dsum(w * w * t_s[:, None]) / np.maximum(ww, 1e-300)
    tau = (t_s[:, None] - t_dir[gi]) / 0.05                                  # scaled, for conditioning
    basis = [e * tau**p for p in range(n_orders)]
    gram = np.stack([np.stack([dsum(bi * bj) for bj in basis], -1) for bi in basis], -2)   # [n_a, P, P]
    proj = np.stack([dsum(w * bi) for bi in basis], -1)                                   # [n_a, P]
    ee, we = gram[:, 0, 0], proj[:, 0]
    distinct = (ee * ww > 0) & (we**2 < max_corr2 * np.maximum(ee * ww, 1e-300))
    eye = np.eye(n_orders)
    coef = np.linalg.solve(np.where(distinct[:, None, None], gram, eye), proj[..., None])[..., 0]
    coef = np.where(distinct[:, None], coef, 0.0)
    return w - sum(coef[gi][..., p] * basis[p] for p in range(n_orders))


def dwell_image(data: StageData, *, fc_hz: float, prf_hz: float, slope_per_deg: float, beta_per_deg2: float,
                beamwidth_deg: float, angle_step_deg: float, range_oversample: int, threshold_db: float,
                dynamic_range_db: float, position_ref_m: list, sub_pulses: int = 40,
                dwell_half_width_deg: float = 3.2, twin_null: bool = True, twin_orders: int = 1,
                twin_max_corr2: float = 0.9, max_offset_beamwidths: float = 0.5, diff_gain_db: float = 0.0,
                diff_phase_deg: float = 0.0, boresight_offset_deg: float = 0.0,
                fit_half_width_deg: float = 0.0, iso_doppler_resolution_m: float = 0.0,
                dwell_s: float = 0.0, focus_oversample: int = 1) -> StageData:
    """Stage ``dwell_image``: the monopulse image from whole-dwell sums (module docstring).
    ``iso_doppler_resolution_m`` > 0 (the range resolution c / 2B; ``processing.dwell_range:
    iso_doppler``): each projected cell's range is moved along its iso-Doppler line as well
    (:func:`iso_doppler_range`, ``dwell_s`` the dwell time). ``focus_oversample`` > 1: the dwell focused
    on the range grid oversampled that many times (:func:`dwell_range.focus_range_oversample`).

    Same output variables and grid conventions as ``chain.monopulse_image`` (range at t_ref oversampled
    x ``range_oversample``, azimuth at t_ref on ``angle_step_deg`` bins, real-beam image, ground cells).
    """
    range_m = data["range_m"]
    beam = data["scan_angle_deg"]
    p_ref = np.asarray(position_ref_m, dtype=np.float64)
    angle_deg = image_angle_grid(beam, beamwidth_deg, angle_step_deg)
    vel = data["velocity_mps"]
    m_ref = int(np.argmin(np.abs(data["slow_time_s"] - data.attrs.get("t_ref_s", data["slow_time_s"][0]))))
    twin_axis = flight_axis_deg(vel[m_ref])
    # the focused directions: each image bin's own, and more where the dwell's angle lobe is narrower than
    # the bin (dwell_grid.py)
    per_bin = focus_per_bin(angle_deg, beam, vel, range_m, p_ref, fc_hz=fc_hz, prf_hz=prf_hz, axis_deg=twin_axis,
                            beta_per_deg2=beta_per_deg2, slope_per_deg=slope_per_deg,
                            dwell_half_width_deg=dwell_half_width_deg)
    dirs, _, first_dir, dir_weight = focus_directions(angle_deg, per_bin)
    diff = data["diff"]
    if diff_gain_db or diff_phase_deg:           # the calibration's channel imbalance divided out first
        imbalance = 10 ** (diff_gain_db / 20) * np.exp(1j * np.radians(diff_phase_deg))
        raw = diff               # in blocks of pulses (file-backed out of core, io/backing.py)
        diff = backing.map_blocks(lambda s: (raw[s] / np.complex64(imbalance)).astype(np.complex64),
                                  raw.shape[0], raw.shape, np.complex64, raw[0].nbytes)
    sum_in, focus_os, range_in, diff_native = data["sum"], int(focus_oversample), range_m, diff
    if focus_os > 1:           # the image is not band-limited at the native rate: focus on the fine grid
        sum_in = oversample_focus_input(sum_in, focus_os)        # (from the band-limited input; file-backed
        diff = oversample_focus_input(diff, focus_os)            # out of core)
        range_in = range_m[0] + (range_m[1] - range_m[0]) / focus_os * np.arange(sum_in.shape[1])
    s_rot, d_rot, gain, pos_dwell, plain_gain = dwell_focus(
        sum_in, diff, slow_time_s=data["slow_time_s"], scan_angle_deg=beam,
        position_m=data["position_m"], velocity_mps=vel, range_m=range_in, angle_deg=dirs, fc_hz=fc_hz,
        prf_hz=prf_hz,
        slope_per_deg=slope_per_deg, beta_per_deg2=beta_per_deg2, position_ref_m=p_ref,
        sub_pulses=sub_pulses, dwell_half_width_deg=dwell_half_width_deg, twin_null=twin_null,
        twin_axis_deg=twin_axis, twin_orders=twin_orders, twin_max_corr2=twin_max_corr2)
    del sum_in
    looked = gain > 0
    s = oversample_range(s_rot[looked], range_oversample // focus_os)
    dr = (range_m[1] - range_m[0]) / range_oversample
    range_os = range_m[0] + dr * np.arange(s.shape[1])
    # the power in float32 (its own precision), its exact median (dsp.imaging.median_floor: np.median's
    # number); the ratio only at the cells over the level, as float32 numerator over the float64 power
    # (the numbers of the whole-image float64 arrays, three of them 8 bytes a cell, no longer made)
    power32 = s.real**2 + s.imag**2
    floor = float(median_floor(power32.reshape(1, -1), power32.size, row_length=power32.shape[-1])[0])
    level = max(floor * 10 ** (threshold_db / 10), float(power32.max()) * 10 ** (-dynamic_range_db / 10))
    max_ratio = np.tanh(slope_per_deg * max_offset_beamwidths * beamwidth_deg)
    finish_fit = None
    in_fit = (np.abs(dirs[looked] - twin_axis) <= fit_half_width_deg) & (fit_half_width_deg > 0)
    if in_fit.any():                 # the joint fit owns the directions near the flight axis (dwell_fit.py):
        # started as soon as its inputs (the region's profile, the level) are known, it runs on other
        # processes while this one selects and projects the dwell image's cells (a scan that never comes
        # within fit_half_width_deg of the axis has no such direction, and no fit)
        p_nat = s_rot[looked][in_fit][:, ::focus_os]       # the native range samples (the fit's grid)
        finish_fit = start_fit_region(
            data["sum"], diff_native, scan_angle_deg=beam, position_m=data["position_m"], range_m=range_m,
            profile=np.max(p_nat.real**2 + p_nat.imag**2, axis=0), level=level, axis_deg=twin_axis,
            half_width_deg=fit_half_width_deg, dwell_half_width_deg=dwell_half_width_deg,
            angle_step_deg=angle_step_deg, fc_hz=fc_hz, prf_hz=prf_hz, slope_per_deg=slope_per_deg,
            beta_per_deg2=beta_per_deg2, position_ref_m=p_ref, boresight_offset_deg=boresight_offset_deg)
        del p_nat
    try:
        dz = oversample_range(d_rot[looked], range_oversample // focus_os)
        over = np.flatnonzero(power32 > float32_floor(level))              # power > level, exactly
        n_os = s.shape[1]
        s_c, dz_c = s.reshape(-1)[over], dz.reshape(-1)[over]
        power_c = power32.reshape(-1)[over].astype(np.float64)
        ratio_c = (dz_c.real * s_c.real + dz_c.imag * s_c.imag) / np.maximum(power_c, 1e-30)
        del s_c, dz_c, power32, s, dz          # (not held through the projection and the fit's end)
        ok = np.abs(ratio_c) < max_ratio
        i_dir, i_r = np.divmod(over[ok], n_os)                             # np.nonzero's order
        ratio_kept = ratio_c[ok]
        w = power_c[ok] * dir_weight[looked][i_dir]      # a bin focused in m directions: each cell counts 1/m
        del over, ok, ratio_c, power_c
        # the offset eps is seen from the antenna over the dwell: add it to the direction's azimuth from
        # the dwell's mean antenna position, then solve the point's azimuth from the t_ref antenna (chain)
        p_dw = pos_dwell[looked][i_dir]
        p_dir = ground_points(range_os[i_r], dirs[looked][i_dir], p_ref)
        az_dw = np.degrees(np.arctan2(p_dir[:, 0] - p_dw[:, 0], p_dir[:, 1] - p_dw[:, 1]))
        az, _, _ = azimuth_at_t_ref(range_os[i_r], az_dw + np.arctanh(ratio_kept) / slope_per_deg
                                    + boresight_offset_deg, p_dw, p_ref)
        az = np.where(np.isfinite(az), az, dirs[looked][i_dir])
        if iso_doppler_resolution_m > 0:       # processing.dwell_range: iso_doppler (steep depression)
            r_new = iso_doppler_range(range_os[i_r], dirs[looked][i_dir], az, p_dw, p_ref,
                                      vel[m_ref], lam_m=C_MPS / fc_hz, resolution_m=iso_doppler_resolution_m,
                                      dwell_s=dwell_s)
            i_r = np.clip(np.rint((r_new - range_os[0]) / dr).astype(np.int64), 0, n_os - 1)
        real_beam = subaperture_real_beam(data, beam, sub_pulses, range_m, angle_deg, angle_step_deg, p_ref)
    except BaseException:             # (an interrupt included) the fit's workers released, not waited for
        if finish_fit is not None:
            finish_fit.cancel()
        raise
    fit_done = None if finish_fit is None else finish_fit()
    if fit_done is not None:
        fit_theta, fit_prof, fitted = fit_done
        # in the fitted range cells the fit replaces the region's directions and what lands in the
        # region (elsewhere the dwell's cells stay)
        fitted_os = np.repeat(fitted, range_oversample)[:n_os]
        out_fit = (~(in_fit[i_dir] & fitted_os[i_r])
                   & ((np.abs(az - twin_axis) > fit_half_width_deg) | ~fitted_os[i_r]))
        az, w, i_r = az[out_fit], w[out_fit], i_r[out_fit]
        # fitted amplitudes on the dwell image's scale (a point on the imaged direction: S' = c L gain),
        # the gain before the twin null: the fit has parted the twins, so none of the null's loss (up to
        # 10 dB for x = +-30 m) is theirs
        col = np.clip(np.rint((fit_theta - angle_deg[0]) / angle_step_deg).astype(np.int64), 0, len(angle_deg) - 1)
        prof = oversample_range(fit_prof * (sub_pulses * plain_gain[first_dir[col]])[:, None].astype(np.float32),
                                range_oversample)
        p_fit = (prof.real**2 + prof.imag**2).astype(np.float64)
        k_fit, r_fit = np.nonzero(p_fit > level)
        az = np.concatenate([az, fit_theta[k_fit]])
        w = np.concatenate([w, p_fit[k_fit, r_fit]])
        i_r = np.concatenate([i_r, r_fit])
    n_a = len(angle_deg)
    step = angle_step_deg
    a_idx = np.rint((az - angle_deg[0]) / step).astype(np.int64)
    inside = (a_idx >= 0) & (a_idx < n_a)
    image = np.bincount(i_r[inside] * n_a + a_idx[inside], weights=w[inside],
                        minlength=len(range_os) * n_a).reshape(len(range_os), n_a)
    ground = ground_points(range_os[i_r[inside]], az[inside], p_ref)

    out = StageData(attrs=dict(data.attrs))
    out.add("range_m", range_os, ("range_m",), "m", "slant range from the antenna at t_ref")
    out.add("angle_deg", angle_deg, ("angle_deg",), "deg", "azimuth from the antenna at t_ref")
    out.add("range_native_m", range_m, ("range_native_m",), "m", "slant range, native sampling")
    out.add("image", image.astype(np.float32), ("range_m", "angle_deg"), "1",
            "monopulse image over each direction's dwell, rotated sum power")
    out.add("real_beam", real_beam.astype(np.float32), ("range_native_m", "angle_deg"), "1",
            "real-beam image: sum power against beam angle")
    out.add("dwell_gain", gain[first_dir], ("angle_deg",), "1", "matched-filter gain sum w^2 of each direction's dwell")
    out.add("focus_directions", per_bin.astype(np.int16), ("angle_deg",), "1",
            "directions focused per angle bin (dwell_grid.py: the dwell's angle lobe sampled)")
    out.add("cell", np.arange(int(inside.sum()), dtype=np.int32), ("cell",), "1", "projected cell")
    out.add("cell_x_m", ground[:, 0].astype(np.float32), ("cell",), "m", "ground x of each projected cell")
    out.add("cell_y_m", ground[:, 1].astype(np.float32), ("cell",), "m", "ground y of each projected cell")
    out.add("cell_power", w[inside].astype(np.float32), ("cell",), "1", "power of each projected cell")
    out.attrs.update(range_oversample=range_oversample, angle_step_deg=angle_step_deg,
                     slope_per_deg=slope_per_deg, position_ref_m=list(map(float, p_ref)), imaging="dwell",
                     sub_pulses=sub_pulses, dwell_half_width_deg=dwell_half_width_deg, twin_null=bool(twin_null))
    return out


def dwell_stages(cube, proc: dict, geo: dict):
    """The stage(s) that replace ``doppler_spectra`` + ``monopulse_image`` when imaging == dwell."""
    from ..runner import Stage

    geo["doppler_resolution_hz"] = 1.0 / dwell_duration_s(cube)
    if proc["range_oversample"] == "auto":     # at least x 4 where the dwell must be focused on the fine grid
        geo["range_oversample"] = auto_focus_range_oversample(cube, geo["p_ref"], geo["range_oversample"], geo)
    cal = geo["calibration"]                     # the chain's monopulse calibration (slope, imbalance, offset)
    two_way_deg = two_way_width_for(cube.radar["beamwidth_3db_deg"], cube.antenna)
    half_width_deg = DWELL_HALF_WIDTH_BEAMS * two_way_deg
    if cal.model != "tanh":                      # README, "An antenna fwdlook does not model"
        # the rotation is the two-Gaussian-beam one: the pair nearest the table over the dwell's offsets,
        # its imbalance and null offset included (they had been dropped: 0.14-0.4 deg on reviews' cubes)
        k, gain_db, offset_deg = cal.tanh_equivalent(half_width_deg)
        cal = Calibration("table", "tanh", k, boresight_offset_deg=offset_deg,      # (source: its refusals' text)
                          diff_gain_db=cal.diff_gain_db + gain_db, diff_phase_deg=cal.diff_phase_deg,
                          pattern=cal.pattern)
        table = geo["calibration"]
        log.warning(f"processing.imaging: dwell measures angles with the two-Gaussian-beam rotation; this cube's "
                    f"ratio curve is a {table.model} ({table.source}), taken as the nearest such pair "
                    f"(null {offset_deg:+.3f} deg, boresight slope {k * 10 ** (gain_db / 20):.4g} per deg): its shape "
                    "beyond that is not followed (0.01-0.06 deg on reviews' sinc and cosine-taper beams); imaging: cpi "
                    "reads the curve itself")
    check_slope_forms_a_beam(cal, cube)
    check_focus_sizes(cube, geo, proc, slope_per_deg=float(cal.slope_per_deg),
                      beta_per_deg2=pattern_beta_per_deg2(cube), dwell_half_width_deg=half_width_deg)
    step_deg = float(np.median(np.abs(np.diff(cube.scan_angle_deg))))          # scan per pulse
    # sub-aperture: the beam moves SUB_APERTURE_DEG (40 pulses for the paper's 30 deg/s at 2.5 kHz)
    sub_pulses = int(np.clip(round(SUB_APERTURE_DEG / max(step_deg, 1e-9)), 4, max(4, cube.n_pulses // 4)))
    # mirror directions (same Doppler) are parted only by the beam: inside one dwell window of each
    # other they are integrated together (resolved_flags' angle gate)
    geo["resolution_angle_gate_deg"] = 2.0 * DWELL_HALF_WIDTH_BEAMS * two_way_deg
    fit = (proc.get("dwell_fit", "none") == "joint" and fit_models_antenna(cube)
           and fit_cell_model_holds(cube, geo, (FIT_REGION_BEAMS + 1.0) * DWELL_HALF_WIDTH_BEAMS * two_way_deg))
    fit_half_width_deg = FIT_REGION_BEAMS * DWELL_HALF_WIDTH_BEAMS * two_way_deg if fit else 0.0
    if fit:                                               # the fit's own resolution (dwell_resolution.fit_resolved_flags)
        geo["fit_region"] = {"half_width_deg": fit_half_width_deg,
                             "dwell_half_width_deg": DWELL_HALF_WIDTH_BEAMS * two_way_deg,
                             "fc_hz": cube.radar["fc_hz"], "slope_per_deg": float(cal.slope_per_deg),
                             "beta_per_deg2": pattern_beta_per_deg2(cube),
                             "boresight_offset_deg": float(cal.boresight_offset_deg)}
    return [Stage("dwell_image", dwell_image, {
        "sub_pulses": sub_pulses, "dwell_half_width_deg": DWELL_HALF_WIDTH_BEAMS * two_way_deg,
        "fc_hz": cube.radar["fc_hz"], "prf_hz": cube.radar["prf_hz"], "slope_per_deg": float(cal.slope_per_deg),
        "diff_gain_db": float(cal.diff_gain_db), "diff_phase_deg": float(cal.diff_phase_deg),
        "boresight_offset_deg": float(cal.boresight_offset_deg),
        "beta_per_deg2": pattern_beta_per_deg2(cube), "beamwidth_deg": cube.radar["beamwidth_3db_deg"],
        "angle_step_deg": proc["angle_step_deg"], "range_oversample": geo["range_oversample"],
        "threshold_db": proc["threshold_db"], "dynamic_range_db": 60.0,
        "position_ref_m": [float(v) for v in geo["p_ref"]],
        "fit_half_width_deg": fit_half_width_deg, **dwell_stage_params(cube, proc, geo)})]
