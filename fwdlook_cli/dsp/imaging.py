"""Fast pieces of the monopulse image: the CPI noise floor, range oversampling of only the Doppler rows
the image can use, and the cell selection fused over those rows.

The image keeps a cell (CPI, Doppler cell, oversampled range) when its sum power exceeds the CPI's
level ``max(floor 10^(threshold/10), peak 10^(-dynamic_range/10))`` and its monopulse ratio is inside
the usable range.  Oversampling every Doppler row four times costs FFTs and memory over the whole
spectrum cube, yet most rows are noise far below the level.  Band-limited interpolation passes through
the native samples and, for a point target, falls at most 3.9 dB below its peak between them (a sinc at
half a sample), so a row whose native samples all lie more than ``margin_db`` (6 dB) below the level
cannot hold a kept cell: only the other rows are oversampled.  (Interpolated noise would need every
neighbour at its maximum with alternating signs to gain 6 dB.)  With the 12 dB threshold over the
median, a row of noise alone already reaches within about 3 dB of the level (its largest of 280
exponential samples), so at 20 dB SNR nearly every row is oversampled; noiseless or sparse data gain.  The result is the cell set of full
oversampling, with the floor taken on the native samples (below).
"""
from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from .peaks import oversample_range


def image_angle_grid(beam_deg, beamwidth_deg: float, angle_step_deg: float) -> np.ndarray:
    """The monopulse image's angle axis: ``angle_step_deg`` bins from a beamwidth below the lowest beam
    direction to a beamwidth above the highest (the CPI and the dwell image, and the chain's size check)."""
    a0 = np.floor((np.min(beam_deg) - beamwidth_deg) / angle_step_deg) * angle_step_deg
    n_a = int(np.ceil((np.max(beam_deg) + beamwidth_deg - a0) / angle_step_deg)) + 1
    return a0 + angle_step_deg * np.arange(n_a)


def auto_range_oversample(bandwidth_hz: float, fs_hz: float) -> int:
    """``processing.range_oversample: auto``: the smallest whole factor that samples the image's power
    at its Nyquist rate, ``ceil(2 B / fs)`` (1 to 16).

    A range-compressed echo of bandwidth B sampled at fs has a power |s|^2 whose spectrum (the
    autocorrelation of the echo's) spans -B..B: 2B wide, so the oversampled rate k fs must reach 2B
    for the power image to hold every range between its samples (no aliasing; the peak's log-parabola
    refinement, ``evaluate.target_metrics``, then interpolates it).  The paper's radar (B = 50 MHz,
    fs = 60 MHz): 2, a 1.25 m grid for its 3 m resolution; a point midway between two samples loses
    at most sinc^2(0.21) of its peak in the image, 0.62 dB (x 4: 0.16 dB).  The accuracy and the time
    against the factor are in the README ("Range oversampling: speed against accuracy")."""
    return int(min(16, max(1, math.ceil(2.0 * float(bandwidth_hz) / float(fs_hz) - 1e-9))))


def power_f32(z):
    """|z|^2 in float32, fused (no complex abs, no float64 temporaries)."""
    re, im = z.real, z.imag
    p = np.multiply(re, re, dtype=np.float32)
    p += np.square(im, dtype=np.float32)
    return p


def float32_floor(x):
    """The largest float32 <= ``x`` (float64): for float32 ``p``, ``p > x`` exactly when ``p > float32_floor(x)``
    (a float32 above the rounded-down level is at least the next float32, above ``x``), so the power
    test runs float32 against float32, with no cast of the cells to float64."""
    f = np.asarray(x, dtype=np.float64).astype(np.float32)
    return np.where(f.astype(np.float64) > x, np.nextafter(f, np.float32(-np.inf)), f)


MEDIAN_SAMPLE_STRIDE = 16      # the bracket of :func:`median_floor` comes from about every 16th cell


def median_sample_stride(row_length: int) -> int:
    """The sampling stride of :func:`median_floor`'s bracket: the first integer from
    ``MEDIAN_SAMPLE_STRIDE`` up that shares no factor with ``row_length``, so that the sample walks every
    column of the rows (every range cell of a [Doppler, range] CPI) equally.  A stride that divides
    into the row length samples a few columns only (16 over 280 range cells: 35 of them); where the
    power depends on the range cell (a target's range cells, bright in every Doppler row) the sample's
    median then strays from the whole group's by several of its standard deviations, and the bracket
    misses it (3 of the paper cube's 78 CPIs with 16, none with 17)."""
    stride = MEDIAN_SAMPLE_STRIDE
    while math.gcd(stride, max(1, int(row_length))) != 1:
        stride += 1
    return stride


def median_bracket(flat, stride: int):
    """[lo, hi] per row of ``flat`` [n_groups, n] around its median: the order statistics +-4 standard
    deviations of the sample median's rank (sqrt(m)/2 each) of every ``stride``-th cell, sorted."""
    sample = np.sort(flat[:, ::stride], axis=1)
    m = sample.shape[1]
    half = int(np.ceil(2.0 * np.sqrt(m))) + 2
    lo = sample[:, max(0, m // 2 - half)][:, None]
    hi = sample[:, min(m - 1, m // 2 + half)][:, None]
    return lo, hi


def median_floor(power, axis_cells, row_length: int | None = None):
    """Exact median over the trailing cells of ``power`` reshaped [n_groups, -1].

    A bracket [lo, hi] around the median is read from a strided sample (:func:`median_bracket`, the
    stride :func:`median_sample_stride` of ``row_length``, the length of the rows the cells are laid
    out in: ``axis_cells`` where not given), the cells below ``lo`` are counted, and only
    the cells inside the bracket (about a tenth) are sorted, every group's in one row of a padded
    array, for the two middle order statistics: the same number as ``np.median``, at a quarter of the
    work of partitioning every cell.  A group whose bracket misses the median (about 6e-5 for a sample
    that represents the group: the 4-sigma tails) is partitioned whole."""
    flat = power.reshape(power.shape[0], axis_cells)
    n_groups, n = flat.shape
    k0, k1 = (n - 1) // 2, n // 2
    out = np.empty(n_groups)
    lo, hi = median_bracket(flat, median_sample_stride(axis_cells if row_length is None else row_length))
    under = flat < lo
    below = np.count_nonzero(under, axis=1)
    inside = np.greater(flat <= hi, under)             # lo <= x <= hi (True > False)
    del under
    count = np.count_nonzero(inside, axis=1)
    r0, r1 = k0 - below, k1 - below                    # the middle ranks among each group's bracket
    held = (r0 >= 0) & (r1 < count)
    # each group's bracket in one row (+inf after it), sorted row by row: one call for every group
    pad = np.full((n_groups, max(1, int(count.max(initial=0)))), np.inf, dtype=flat.dtype)
    pad[np.arange(pad.shape[1]) < count[:, None]] = flat.reshape(-1).take(np.flatnonzero(inside))   # (a
    # boolean index of the whole array costs three times the index list and the take)
    pad.sort(axis=1)
    g = np.flatnonzero(held)
    out[g] = 0.5 * (pad[g, r0[g]].astype(np.float64) + pad[g, r1[g]].astype(np.float64))
    for g in np.flatnonzero(~held):                    # the bracket missed: the whole group
        cand = np.array(flat[g], dtype=np.float32)
        cand.partition([k0, k1])
        out[g] = 0.5 * (float(cand[k0]) + float(cand[k1]))
    return out


BLOCK_CELLS = 1 << 19       # oversampled cells per block (all threads): temporaries of a few MB, reused from the heap


def kept_cells(sum_z, diff_z, *, range_oversample: int, threshold_db: float, dynamic_range_db: float,
               max_ratio: float, margin_db: float = 6.0, block_cells: int = BLOCK_CELLS):
    """:func:`kept_cells_block` over blocks of whole CPIs, concatenated (see :func:`iter_kept_cells`)."""
    parts = list(iter_kept_cells(sum_z, diff_z, range_oversample=range_oversample, threshold_db=threshold_db,
                                 dynamic_range_db=dynamic_range_db, max_ratio=max_ratio, margin_db=margin_db,
                                 block_cells=block_cells))
    return tuple(np.concatenate([p[k] for p in parts]) for k in range(1, 6))


def iter_kept_cells(sum_z, diff_z, *, range_oversample: int, threshold_db: float, dynamic_range_db: float,
                    max_ratio: float, margin_db: float = 6.0, block_cells: int = BLOCK_CELLS, threads: int = 1,
                    post=None, **calibration):
    """Per block of whole CPIs (every quantity is per CPI, so blocking changes nothing but the size of
    the temporaries): (first CPI, i_cpi, i_range_os, ratio, power, native power) with global CPI
    indices, in CPI order; ``post(tuple)`` instead where given (run in the block's thread).

    ``threads`` > 1 runs the blocks on a thread pool (the FFTs then one thread each): the same numbers,
    the blocks' results handed over in order.
    """
    n_cpi, n_dop, n_r = sum_z.shape
    # the blocks in flight together hold what one block of ``block_cells`` would (the same memory)
    step = max(1, int(block_cells) // max(1, threads * n_dop * n_r * range_oversample))
    workers = 1 if threads > 1 else -1

    def one(c0):
        i_cpi, i_r, ratio, power, p0 = kept_cells_block(
            sum_z[c0:c0 + step], diff_z[c0:c0 + step], range_oversample=range_oversample,
            threshold_db=threshold_db, dynamic_range_db=dynamic_range_db, max_ratio=max_ratio,
            margin_db=margin_db, fft_workers=workers, **calibration)
        block = (c0, i_cpi + c0, i_r, ratio, power, p0)
        return block if post is None else post(block)

    starts = range(0, n_cpi, step)
    if threads <= 1 or len(starts) == 1:
        yield from map(one, starts)
        return
    with ThreadPoolExecutor(max_workers=threads) as pool:
        pending = []                     # at most `threads` blocks in flight, handed over in order
        for c0 in starts:
            pending.append(pool.submit(one, c0))
            if len(pending) >= threads:
                yield pending.pop(0).result()
        for fut in pending:
            yield fut.result()


def kept_cells_block(sum_z, diff_z, *, range_oversample: int, threshold_db: float, dynamic_range_db: float,
                     max_ratio: float, margin_db: float = 6.0, ratio_bounds=None, diff_gain_db: float = 0.0,
                     diff_phase_deg: float = 0.0, fft_workers: int = -1):
    """Cells of the monopulse image: (i_cpi, i_range_os, ratio, power) of every kept cell, ordered as
    ``np.nonzero`` on the full [cpi, doppler, range_os] mask orders them, and the native sum power
    [cpi, doppler, range] (for the real-beam image).

    The noise floor is the median of the CPI's native-resolution sum power (every ``range_oversample``-th
    oversampled sample: the same quantity as the median of all of them, within the statistical error
    of a median of n_doppler x n_range samples, about 1/(ln 2 sqrt(n)) = 1.1 % for 64 x 280).
    """
    n_cpi, n_dop, n_r = sum_z.shape
    p0 = power_f32(sum_z)                                            # native sum power
    floor = median_floor(p0, n_dop * n_r, row_length=n_r)
    peak0 = p0.reshape(n_cpi, -1).max(axis=1).astype(np.float64)
    thr, dyn = 10 ** (threshold_db / 10), 10 ** (-dynamic_range_db / 10)
    level_lo = np.maximum(floor * thr, peak0 * dyn)                  # <= the level (peak0 <= peak)
    row_max = p0.max(axis=2)                                         # [cpi, doppler]
    rows = np.flatnonzero(row_max.reshape(-1) >= level_lo.repeat(n_dop) * 10 ** (-margin_db / 10))
    row_cpi = rows // n_dop
    s = oversample_range(sum_z.reshape(-1, n_r)[rows], range_oversample, workers=fft_workers)
    power = power_f32(s)
    # exact oversampled peak per CPI from the selected rows (the peak row is always among them)
    peak = np.zeros(n_cpi)
    if len(rows):
        np.maximum.at(peak, row_cpi, power.max(axis=1).astype(np.float64))
    level = np.maximum(floor * thr, peak * dyn)
    # power test first, on the whole selected rows; the difference channel is oversampled only in
    # the rows with a cell that passes it (signal rows), the ratio only on those cells
    n_os = power.shape[1]
    flat = np.flatnonzero(power > float32_floor(level)[row_cpi][:, None])
    i_row, i_r = np.divmod(flat, n_os)
    sk, pk = s.reshape(-1)[flat], power.reshape(-1)[flat]
    del s, power
    # i_row is sorted (flatnonzero order): its distinct rows and each cell's place among them by one
    # comparison and a cumulative sum, not np.unique + searchsorted
    new_row = np.empty(len(i_row), dtype=bool)
    new_row[:1] = True
    np.not_equal(i_row[1:], i_row[:-1], out=new_row[1:])
    hit = i_row[new_row]
    d = oversample_range(diff_z.reshape(-1, n_r)[rows[hit]], range_oversample, workers=fft_workers)
    at = np.cumsum(new_row)                 # each cell's flat index in d: (its hit row) n_os + i_r, one
    at -= 1                                 # 1-D take (a 2-D fancy index of the two arrays costs
    at *= n_os                              # about ten times as much here)
    at += i_r
    dk = d.reshape(-1).take(at)
    del d, at
    ratio = np.multiply(dk.real, sk.real)                   # Re(d conj s) / |s|^2, float32
    ratio += dk.imag * sk.imag
    if diff_gain_db or diff_phase_deg:
        # Re(d conj(s) / gamma) / |s|^2, gamma = 10^(g/20) exp(j phi): the calibrated ratio
        c, sn = np.float32(np.cos(np.radians(diff_phase_deg))), np.float32(np.sin(np.radians(diff_phase_deg)))
        im_q = dk.imag * sk.real - dk.real * sk.imag
        ratio = np.float32(10.0 ** (-diff_gain_db / 20.0)) * (c * ratio + sn * im_q)
    ratio /= np.maximum(pk, np.float32(1e-30))
    lo, hi = (-max_ratio, max_ratio) if ratio_bounds is None else ratio_bounds
    ok = (ratio > lo) & (ratio < hi)
    return row_cpi[i_row[ok]], i_r[ok], ratio[ok], pk[ok], p0


def azimuth_at_t_ref_cells(range_m, azimuth_deg, position_at_measure_m, position_ref_m, index=None):
    """:func:`dsp.geometry.azimuth_at_t_ref` for 1-D cell arrays, with fewer temporaries: the ground
    point P = g_c + s u(theta) with |P - p_ref| = R (a quadratic in s); NaN where none.  ``index``:
    ``position_at_measure_m`` is then one row per group (CPI) and cell i is measured from row
    ``index[i]`` (the per-group terms taken once per group).

    The azimuth of e = P - p_ref is theta plus the parallax atan((u_y d_x - u_x d_y) / (e . u)), with
    e . u = s + b = sqrt(b^2 - c) >= 0: one arctan instead of an arctan2 (the same angle; for a beam
    within 90 deg of the reference direction, as every forward-looking one is)."""
    az = np.radians(azimuth_deg)
    ux, uy = np.sin(az), np.cos(az)
    pos = np.asarray(position_at_measure_m, dtype=np.float64)
    dx, dy = pos[:, 0] - position_ref_m[0], pos[:, 1] - position_ref_m[1]
    c = dx * dx
    c += dy * dy
    c += position_ref_m[2] ** 2
    if index is not None:
        dx, dy, c = dx[index], dy[index], c[index]
    c -= np.square(range_m)
    b = dx * ux
    b += dy * uy
    disc = b * b
    disc -= c
    disc[disc < 0] = np.nan
    root = np.sqrt(disc)                           # e . u
    cross = uy * dx
    cross -= ux * dy
    cross /= root
    az_ref = np.degrees(np.arctan(cross))
    az_ref += azimuth_deg
    s = root
    s -= b
    ex = s * ux
    ex += dx                                       # gx - p_ref_x
    ey = s * uy
    ey += dy
    return az_ref, ex + position_ref_m[0], ey + position_ref_m[1]


def oversample_profiles(x, factor: int):
    """:func:`dsp.peaks.oversample_profile` of every row of ``x`` [rows, n] at once (complex128, the same
    zero-padding and Nyquist split)."""
    x = np.asarray(x, dtype=np.complex128)
    if factor == 1:
        return x.copy()
    n = x.shape[-1]
    m = n * factor
    spec = np.fft.fft(x, axis=-1)
    padded = np.zeros(x.shape[:-1] + (m,), dtype=np.complex128)
    if n % 2:
        half = (n + 1) // 2
        padded[..., :half] = spec[..., :half]
        padded[..., m - (n - half):] = spec[..., half:]
    else:
        half = n // 2
        padded[..., :half] = spec[..., :half]
        if half > 0:
            padded[..., m - half + 1:] = spec[..., half + 1:]
        padded[..., half] += 0.5 * spec[..., half]
        padded[..., m - half] += 0.5 * spec[..., half]
    return np.fft.ifft(padded, axis=-1) * factor
