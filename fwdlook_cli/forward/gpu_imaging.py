"""Stage 7 on the GPU backend (``processing.backend: gpu``): the monopulse image's cell selection on an
array module ``xp`` (CuPy, or numpy under ``FWDLOOK_XP=numpy``), the projection on the CPU.

Per block of whole CPIs, on the device: the native sum power, the CPI noise floor (the median of the
native power: the mean of its two middle order statistics), range oversampling of both channels by FFT
zero-padding (every row: on a GPU the FFTs cost less than choosing rows), the level
max(floor 10^(threshold/10), peak 10^(-dynamic_range/10)), the power test, the calibrated monopulse
ratio Re(d conj(s) / gamma) / |s|^2 and its bounds.  Only the kept cells (a few thousand) and the
native power summed over Doppler (the real-beam image) are copied back: the ground geometry of the
kept cells and the ``bincount`` projections are scattered, data-dependent and small, so they stay on
the CPU.  Cells come in the order of ``np.nonzero`` on the [cpi, doppler, range_os] mask, as in
:func:`dsp.imaging.kept_cells_block`.
"""
from __future__ import annotations

import numpy as np

from ..dsp.xp import fft_kwargs, fft_module, get_xp, is_numpy, to_device, to_host
from ..io.stagefile import StageData


def _power(xp, z):
    """|z|^2 in float32: re^2 + im^2 (the rounding of :func:`dsp.imaging.power_f32`)."""
    p = z.real * z.real
    p += z.imag * z.imag
    return p


def oversample_range(xp, x, factor: int):
    """Band-limited oversampling of the last axis by FFT zero-padding, amplitudes kept, the Nyquist
    bin of an even n split between +n/2 and -n/2 (the CPU's :func:`dsp.peaks.oversample_range`)."""
    if factor == 1:
        return x.copy()
    fx, kw = fft_module(xp), fft_kwargs(xp)
    n = x.shape[-1]
    m = n * factor
    lo = (n + 1) // 2                                      # bins 0 .. lo-1 at the start
    spec = fx.fft(x, axis=-1, norm="forward", **kw)        # X/n, then an unscaled inverse (as the CPU's)
    pad = xp.zeros(spec.shape[:-1] + (m,), dtype=spec.dtype)
    pad[..., :lo] = spec[..., :lo]
    pad[..., m - (n - lo):] = spec[..., lo:]
    if n % 2 == 0 and n > 0:                               # the Nyquist bin: half at +n/2, half at -n/2
        pad[..., m - n // 2] *= 0.5
        pad[..., n // 2] = pad[..., m - n // 2]
    del spec
    return fx.ifft(pad, axis=-1, overwrite_x=True, norm="forward", **kw)


def kept_cells_xp(xp, sum_z, diff_z, *, range_oversample: int, threshold_db: float, dynamic_range_db: float,
                  ratio_bounds, diff_gain_db: float = 0.0, diff_phase_deg: float = 0.0):
    """Kept cells of one block of CPIs (``sum_z``, ``diff_z``: [cpi, doppler, range] complex64 on ``xp``):
    host arrays (i_cpi, i_range_os, ratio, power) in ``np.nonzero`` order, and the native sum power
    summed over Doppler [cpi, range] (float64)."""
    n_cpi, n_dop, n_r = sum_z.shape
    p0 = _power(xp, sum_z)
    srt = xp.sort(p0.reshape(n_cpi, -1), axis=1)
    k0, k1 = (n_dop * n_r - 1) // 2, (n_dop * n_r) // 2
    floor = 0.5 * (srt[:, k0].astype(xp.float64) + srt[:, k1].astype(xp.float64))   # the median
    del srt
    s = oversample_range(xp, sum_z, range_oversample)
    power = _power(xp, s)
    peak = power.reshape(n_cpi, -1).max(axis=1).astype(xp.float64)
    level = xp.maximum(floor * 10 ** (threshold_db / 10), peak * 10 ** (-dynamic_range_db / 10))
    i_cpi, i_dop, i_r = xp.nonzero(power > level[:, None, None])
    sk, pk = s[i_cpi, i_dop, i_r], power[i_cpi, i_dop, i_r]
    del s, power
    dk = oversample_range(xp, diff_z, range_oversample)[i_cpi, i_dop, i_r]
    ratio = dk.real * sk.real                          # Re(d conj s), float32
    ratio += dk.imag * sk.imag
    if diff_gain_db or diff_phase_deg:
        # Re(d conj(s) / gamma), gamma = 10^(g/20) exp(j phi): the calibrated ratio
        c, sn = np.float32(np.cos(np.radians(diff_phase_deg))), np.float32(np.sin(np.radians(diff_phase_deg)))
        im_q = dk.imag * sk.real - dk.real * sk.imag
        ratio = np.float32(10.0 ** (-diff_gain_db / 20.0)) * (c * ratio + sn * im_q)
    ratio /= xp.maximum(pk, np.float32(1e-30))
    lo, hi = ratio_bounds
    ok = (ratio > lo) & (ratio < hi)
    return (to_host(i_cpi[ok]), to_host(i_r[ok]), to_host(ratio[ok]), to_host(pk[ok]),
            to_host(p0.sum(axis=1, dtype=xp.float64)))


def iter_kept_cells_xp(sum_z, diff_z, *, backend: str = "gpu", block_cells: int | None = None, **kw):
    """:func:`kept_cells_xp` over blocks of whole CPIs of host arrays or open datasets, each block moved
    to the device; yields (first CPI, i_cpi (global), i_range_os, ratio, power, native power per range)."""
    xp = get_xp(backend)
    n_cpi, n_dop, n_r = sum_z.shape
    if block_cells is None:                            # oversampled cells per block: 256 MB on a GPU
        block_cells = (1 << 22) if is_numpy(xp) else (1 << 25)
    step = max(1, int(block_cells) // max(1, n_dop * n_r * kw["range_oversample"]))
    for c0 in range(0, n_cpi, step):
        blk = [to_device(z[c0:c0 + step], xp, np.complex64) for z in (sum_z, diff_z)]
        i_cpi, i_r, ratio, power, rb = kept_cells_xp(xp, *blk, **kw)
        yield c0, i_cpi + c0, i_r, ratio, power, rb


def monopulse_image(data: StageData, *, slope_per_deg: float, beamwidth_deg: float, angle_step_deg: float,
                    range_oversample: int, threshold_db: float, dynamic_range_db: float,
                    position_ref_m: list, max_offset_beamwidths: float = 0.5, ratio_model: str = "tanh",
                    ratio_offset_deg=None, ratio=None, boresight_offset_deg: float = 0.0,
                    diff_gain_db: float = 0.0, diff_phase_deg: float = 0.0, backend: str = "gpu") -> StageData:
    """Stage 7 with the cell selection on ``backend`` (:func:`kept_cells_xp`): the vars of
    :func:`forward.chain.monopulse_image`, the same parameters (offset d = R^-1(ratio) + b, R the tanh
    curve atanh(.)/k or the monotone table; angle = CPI beam angle + d in the t_ref frame)."""
    from functools import partial

    from .monopulse import monopulse_image as project_cells     # the CPU stage's projection

    return project_cells(data, slope_per_deg=slope_per_deg, beamwidth_deg=beamwidth_deg,
                         angle_step_deg=angle_step_deg, range_oversample=range_oversample,
                         threshold_db=threshold_db, dynamic_range_db=dynamic_range_db,
                         position_ref_m=position_ref_m, max_offset_beamwidths=max_offset_beamwidths,
                         ratio_model=ratio_model, ratio_offset_deg=ratio_offset_deg, ratio=ratio,
                         boresight_offset_deg=boresight_offset_deg, diff_gain_db=diff_gain_db,
                         diff_phase_deg=diff_phase_deg,
                         cell_blocks=partial(iter_kept_cells_xp, backend=backend))
