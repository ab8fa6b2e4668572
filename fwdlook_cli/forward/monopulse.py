"""Stage 7, the monopulse image (Sec. 3.2 end; NOTES.md): the kept cells of the Doppler spectra, each
at its monopulse angle in the t_ref frame, accumulated on (range, angle), and the real-beam image.

The cell selection runs on the CPU (:func:`dsp.imaging.iter_kept_cells`, blocks of CPIs on a thread
pool) or is passed in as ``cell_blocks`` (the GPU backend's, ``forward/gpu_imaging.py``); the
projection is this one function for both.
"""
from __future__ import annotations

import numpy as np

from ..dsp.blas import worker_threads
from ..dsp.geometry import azimuth_at_t_ref
from ..dsp.imaging import azimuth_at_t_ref_cells, image_angle_grid, iter_kept_cells
from ..io import backing
from ..io.stagefile import StageData


def _concat_column(parts: list, k: int):
    """Concatenate item ``k`` of every tuple in ``parts``, dropping each part's reference as it goes."""
    arrays = []
    for i, part in enumerate(parts):
        arrays.append(part[k])
        parts[i] = part[:k] + (None,) + part[k + 1:]
    return np.concatenate(arrays)


def monopulse_image(data: StageData, *, slope_per_deg: float, beamwidth_deg: float, angle_step_deg: float,
                    range_oversample: int, threshold_db: float, dynamic_range_db: float,
                    position_ref_m: list, max_offset_beamwidths: float = 0.5, ratio_model: str = "tanh",
                    ratio_offset_deg=None, ratio=None, boresight_offset_deg: float = 0.0,
                    diff_gain_db: float = 0.0, diff_phase_deg: float = 0.0, cell_blocks=None) -> StageData:
    """Monopulse imaging from sum/difference Doppler estimates (Sec. 3.2 end; NOTES.md).

    Per CPI, Doppler cell and range: the difference channel is divided by the calibration's imbalance
    10^(g/20) exp(j phi), and the offset is d = R^-1(Re(diff/sum)) + b with R the ratio curve in use
    (``ratio_model`` tanh: atanh(.)/k, exact for Gaussian beams; table: the monotone table
    ``ratio_offset_deg``, ``ratio``) and b the boresight offset; angle = CPI beam angle + d, moved to the t_ref frame; the sum power is accumulated in a
    (range, angle) image.  Cells below ``threshold_db`` over the CPI's median power (noise floor) or
    more than ``dynamic_range_db`` under its peak, or with |d| beyond ``max_offset_beamwidths`` x the
    beamwidth, are not projected.  The real-beam image (CPI sum power at the beam angle) is made too.
    """
    range_m = data["range_m"]
    dr = (range_m[1] - range_m[0]) / range_oversample
    range_os = range_m[0] + dr * np.arange(range_m.shape[0] * range_oversample)
    half = max_offset_beamwidths * beamwidth_deg
    max_ratio = np.tanh(slope_per_deg * half)
    if ratio_model == "tanh":
        bounds = (-max_ratio, max_ratio)
    elif ratio_model == "table":
        tab_d, tab_r = np.asarray(ratio_offset_deg, np.float64), np.asarray(ratio, np.float64)
        bounds = (float(np.interp(-half, tab_d, tab_r)), float(np.interp(half, tab_d, tab_r)))
    else:
        raise ValueError(f"ratio model {ratio_model!r}; allowed: tanh, table")
    p_ref = np.asarray(position_ref_m, dtype=np.float64)
    beam_all = np.asarray(data["cpi_beam_deg"])
    pos_all = np.asarray(data["cpi_position_m"])
    angle_deg = image_angle_grid(beam_all, beamwidth_deg, angle_step_deg)
    a0, n_a = angle_deg[0], len(angle_deg)
    rb_power = np.zeros(data["sum_z"].shape[::2])                              # [n_cpi, n_r]
    cells = []
    # cells over the CPI level, oversampling only the Doppler rows that can hold one, one block of
    # whole CPIs at a time (dsp.imaging): geometry and projection per block (in the block's thread),
    # the image accumulated in CPI order
    def project(block):
        c0, i_cpi, i_r, ratio_kept, power_kept, rb_rows = block
        if ratio_model == "tanh":
            offset = np.arctanh(ratio_kept) / slope_per_deg        # exact inverse for the Gaussian beams
        else:
            offset = np.interp(ratio_kept, tab_r, tab_d)          # the monotone ratio table
        offset = offset + boresight_offset_deg
        beam = beam_all[i_cpi]
        az_ref, gx, gy = azimuth_at_t_ref_cells(range_os[i_r], beam + offset, pos_all, p_ref, index=i_cpi)
        ok = np.isfinite(az_ref)
        if not ok.all():              # a cell with no ground point at its range (rare): left out
            az_ref, gx, gy, power_kept, i_r = az_ref[ok], gx[ok], gy[ok], power_kept[ok], i_r[ok]
        a_idx = np.rint((az_ref - a0) / angle_step_deg).astype(np.int64)
        flat = i_r * n_a
        flat += a_idx
        w = power_kept
        inside = (a_idx >= 0) & (a_idx < n_a)
        if not inside.all():
            flat, w = flat[inside], w[inside]
        # the cells' ground positions and power kept in float32 (1 mm at 10 km, the image's own
        # precision): half the bytes of the stage file's cell arrays and of their memory
        return c0, rb_rows, (gx.astype(np.float32), gy.astype(np.float32), power_kept, flat, w)

    select = dict(range_oversample=range_oversample, threshold_db=threshold_db,
                  dynamic_range_db=dynamic_range_db, ratio_bounds=bounds, diff_gain_db=diff_gain_db,
                  diff_phase_deg=diff_phase_deg)
    if cell_blocks is None:
        def summed(block):            # the native power summed over Doppler: the real-beam rows
            return project(block[:5] + (block[5].sum(axis=1, dtype=np.float64),))

        blocks = iter_kept_cells(data["sum_z"], data["diff_z"], max_ratio=max_ratio, threads=worker_threads(),
                                 post=summed, **select)
    else:       # another cell selection (the GPU's, forward/gpu_imaging.py): the same blocks, rows summed
        blocks = map(project, cell_blocks(data["sum_z"], data["diff_z"], **select))
    # each block's cells summed into the float32 image as the block arrives, in CPI order (np.add.at:
    # one sequential sum per bin), without holding every cell's bin and weight to the end (the CPI
    # chains' high-water mark was there: README, "Memory") nor a float64 image beside the output (twice
    # its size).  A bin sums a few cells (335 615 cells on 934 080 bins, paper cube): float32 sums of k
    # terms are within k - 1 roundings (k 2^-24 relative) of the float64 sums, the image's own precision
    image = np.zeros(len(range_os) * n_a, np.float32)
    for c0, rb_rows, part in blocks:
        rb_power[c0:c0 + len(rb_rows)] = rb_rows
        np.add.at(image, part[3], part[4])
        cells.append(part[:3])
        del part
    image = image.reshape(len(range_os), n_a)
    gx, gy, w = _concat_column(cells, 0), _concat_column(cells, 1), _concat_column(cells, 2)

    # real-beam image: incoherent CPI sum power at the beam angle (same t_ref angle mapping)
    n_cpi, n_r = rb_power.shape
    rb_az, _, _ = azimuth_at_t_ref(np.broadcast_to(range_m, (n_cpi, n_r)),
                                   np.broadcast_to(beam_all[:, None], (n_cpi, n_r)),
                                   pos_all[:, None, :], p_ref)
    rb_idx = np.rint((rb_az - a0) / angle_step_deg)
    good = np.isfinite(rb_idx) & (rb_idx >= 0) & (rb_idx < n_a)
    rb_flat = (np.broadcast_to(np.arange(n_r), (n_cpi, n_r))[good] * n_a + rb_idx[good].astype(np.int64))
    real_beam = np.bincount(rb_flat, weights=rb_power[good], minlength=n_r * n_a).reshape(n_r, n_a).astype(np.float32)

    out = StageData(attrs=dict(data.attrs))
    out.add("range_m", range_os, ("range_m",), "m", "slant range from the antenna at t_ref")
    out.add("angle_deg", angle_deg, ("angle_deg",), "deg", "azimuth from the antenna at t_ref")
    out.add("range_native_m", range_m, ("range_native_m",), "m", "slant range, native sampling")
    out.add("image", image, ("range_m", "angle_deg"), "1", "monopulse image, sum power")
    out.add("real_beam", real_beam, ("range_native_m", "angle_deg"), "1",
            "real-beam image, sum power against beam angle")
    # kept cells, for the ground projection and diagnostics
    out.add("cell", np.arange(len(w), dtype=np.int32), ("cell",), "1", "projected Doppler cell")
    out.add("cell_x_m", gx, ("cell",), "m", "ground x of each projected cell")
    out.add("cell_y_m", gy, ("cell",), "m", "ground y of each projected cell")
    out.add("cell_power", np.asarray(w, np.float32), ("cell",), "1", "sum power of each projected cell")
    out.attrs.update(range_oversample=range_oversample, angle_step_deg=angle_step_deg,
                     slope_per_deg=slope_per_deg, position_ref_m=list(map(float, p_ref)))
    return out


def subaperture_real_beam(data, beam, sub_pulses, range_m, angle_deg, angle_step_deg, p_ref):
    """The dwell imaging's real-beam image: incoherent sum power of each sub-aperture of ``sub_pulses``
    pulses at its beam angle (t_ref mapping; forward/dwell.py)."""
    n_sub = len(beam) // sub_pulses
    mm = n_sub * sub_pulses
    x = data["sum"][:mm].reshape(n_sub, sub_pulses, -1)
    # in blocks of sub-apertures (no cube-sized temporary; file-backed out of core, io/backing.py)
    rb_power = backing.map_blocks(lambda j: np.sum(x[j].real**2 + x[j].imag**2, axis=1), n_sub,
                                  (n_sub, x.shape[2]), np.float32, x[0].nbytes)
    beam_j = beam[:mm].reshape(n_sub, sub_pulses).mean(axis=1)
    pos_j = data["position_m"][:mm].reshape(n_sub, sub_pulses, 3).mean(axis=1)
    n_r, n_a = len(range_m), len(angle_deg)
    rb_az, _, _ = azimuth_at_t_ref(np.broadcast_to(range_m, (n_sub, n_r)),
                                   np.broadcast_to(beam_j[:, None], (n_sub, n_r)), pos_j[:, None, :], p_ref)
    rb_idx = np.rint((rb_az - angle_deg[0]) / angle_step_deg)
    good = np.isfinite(rb_idx) & (rb_idx >= 0) & (rb_idx < n_a)
    rb_flat = np.broadcast_to(np.arange(n_r), (n_sub, n_r))[good] * n_a + rb_idx[good].astype(np.int64)
    return np.bincount(rb_flat, weights=rb_power[good], minlength=n_r * n_a).reshape(n_r, n_a)
