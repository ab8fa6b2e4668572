"""The keystone family applied to both monopulse channels with every chirp computed once per geometry.

Sum and difference share the geometry (alpha = f_c/(f_c+f_r) per column, the time origin, the predicted
Doppler history), so the CZT plan, the tracking demodulation and the remodulation are built once and
applied to each channel in turn; nothing is concatenated, nothing computed twice.  All phases are formed
and reduced modulo one cycle in float64 (:func:`dsp.keystone_common._cis`), the cosines and sines then
taken in float32 for the complex64 data.
"""
from __future__ import annotations

import contextlib
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..dsp.blas import one_blas_thread, worker_threads
from ..dsp.keystone import keystone_dft, keystone_sinc
from ..dsp.keystone_common import OuterPhasors, _cis, outer_grid
from ..dsp.keystone_czt import KeystonePlan
from ..io import backing


def history_taylor(hist, t_s):
    """Psi and its first four time derivatives on the pulse grid ``t_s`` (rad, rad/s, ...).

    Psi is the antiderivative of a cubic spline (a piecewise quartic, C^3), so its Taylor series about a
    pulse to fourth order is the piece itself; across a knot only the jump of the fourth derivative
    enters (below 1e-9 cycles for shifts of a few pulses).
    """
    anti = hist._anti
    two_pi = 2.0 * np.pi
    return [two_pi * (anti(t_s) - hist._offset)] + [two_pi * anti(t_s, nu) for nu in (1, 2, 3, 4)]


def remodulation_cycles(derivs, t0_index: float, alpha, scale, prf_hz: float, chirp_rows=None, chirp_cols=None):
    """The tracking keystone's remodulation phase in cycles, [n_pulses, n_cols] float64:
    ``scale_k Psi(t_m + dt_mk) / (2 pi)`` with ``dt_mk = (m - t0)(alpha_k - 1) / PRF`` (eq. 8), plus, where
    given, the CZT's output chirp ``chirp_rows[m] chirp_cols[k]`` (:meth:`KeystonePlan.post_cycles_f0_factors`).

    With one time origin for every column (the whole sequence, q = 1) the fourth-order Taylor series
    of Psi about each pulse is a sum of outer products, ``sum_n Psi_n(m) u_m^n / n! * beta_k^n`` with
    ``u_m = m - t0`` and ``beta_k = (alpha_k - 1) / PRF``, and so is the output chirp: the whole phase
    is one [n_pulses, 6] x [6, n_cols] float64 matrix product instead of a Horner pass per order over
    every element (:func:`history_phase_shifted`; the same sum, rounded in another order: about 2e-12
    cycles from the spline at phases of 3e3 cycles, as the Horner form)."""
    p = derivs[0].shape[0]
    u = np.arange(p, dtype=np.float64) - float(t0_index)
    alpha = np.asarray(alpha, dtype=np.float64)
    n_terms = 5 if chirp_rows is None else 6
    rows = np.empty((p, n_terms))
    cols = np.empty((n_terms, alpha.shape[0]))
    power = np.ones(p)
    beta = (alpha - 1.0) / prf_hz
    beta_power = np.asarray(scale, dtype=np.float64) / (2.0 * np.pi) * np.ones_like(beta)
    factorial = 1.0
    for n in range(5):
        if n:
            power *= u
            factorial *= n
            beta_power = beta_power * beta
        rows[:, n] = derivs[n] * power / factorial
        cols[n] = beta_power
    if chirp_rows is not None:
        rows[:, 5] = chirp_rows
        cols[5] = chirp_cols
    if cols.shape[1] == 1:      # numpy takes a one-column product to gemv, which sums in another order than
        # gemm: the out-of-core keystone's one-column super-blocks then differed from the whole in float32's
        # last bit (2 of 130 000 samples, a steep window's sub-swath); as two columns, gemm's sum
        return (rows @ np.repeat(cols, 2, axis=1))[:, :1]
    return rows @ cols


def history_phase_shifted(derivs, dt_s):
    """Psi(t_m + dt[m, k]) from the per-pulse derivatives (Horner, float64): the tracking keystone's
    remodulation at the resampled times tau (eq. 8), without evaluating the spline at every (m, k)."""
    p0, p1, p2, p3, p4 = (d[:, None] for d in derivs)
    acc = p4 * (dt_s / 24.0)
    acc += p3 / 6.0
    acc *= dt_s
    acc += p2 / 2.0
    acc *= dt_s
    acc += p1
    acc *= dt_s
    acc += p0
    return acc


# At least this many columns per block (one 64-byte cache line of complex64): a block reads and writes
# its columns strided through [pulses, columns] arrays, so a narrower block uses part of every line it
# fetches, and two threads' blocks write into the same lines.  Narrower blocks are what the byte budget
# left for long sequences: there the tracking keystone's user CPU grew from 69 to 1135 ms over
# 2500-20000 pulses (2.4-3.2 x per doubling from 5000), with this floor from 75 to 508 ms (README,
# Speed: "Scaling").
MIN_BLOCK_COLUMNS = 8
BLOCK_BYTES = 2 << 20       # CZT work buffer per column block (L x columns x 8 bytes): ~50 columns at L = 5000


def keystone_both(x_sum, x_diff, *, alpha, t0_index, implementation, ambiguity, doppler_ref=0.0,
                  n_taps=16, tracking=None, block_bytes: int = BLOCK_BYTES, period: int | None = None,
                  min_columns: int = MIN_BLOCK_COLUMNS, demod_grid="auto"):
    """Keystone of both channels ([n_slow, n_cols] each) sharing one geometry; returns (y_sum, y_diff).

    ``tracking``: None, or (hist, slow_time_s, prf_hz, scale) for the tracking keystone: demodulate by
    exp(-j Psi(t) scale), resample with F = 0, remodulate by exp(j Psi(t0 + tau/PRF) scale) with
    scale = (f_c + f_r)/f_c per column.  Columns are independent, so the work runs over blocks of
    range-frequency columns (plan, chirps and buffers of one block at a time: bounded memory, the
    same numbers).  ``period``: the columns are groups of ``period`` (the decimated layout [Q, n_fr]:
    column q n_fr + k has the alpha of range frequency k); a block then takes range frequencies
    k0..k1 of every group, so that each alpha's chirps and filter are computed once, not once per
    block its columns fall in.  ``min_columns``: the narrowest block (of each group), whatever
    ``block_bytes`` leaves (:data:`MIN_BLOCK_COLUMNS`; 1 lets the byte budget alone decide).
    ``demod_grid``: the tracking demodulation's frequency grid (:func:`dsp.keystone_common.outer_grid`
    of every column's scale, from a caller that passes a part of them: the same phasors).
    """
    p, n_cols = x_sum.shape
    alpha = np.broadcast_to(np.asarray(alpha, dtype=np.float64), (n_cols,))
    t0_index = np.broadcast_to(np.asarray(t0_index, dtype=np.float64), (n_cols,))
    nfft = 2 * p if implementation == "czt" else p
    step = max(1, int(block_bytes) // (8 * nfft))
    groups = n_cols // period if period and n_cols % period == 0 and n_cols > period else 1
    width = n_cols // groups                   # a block: columns [k0, k1) of each of the groups
    # a thread pool over the column blocks (FFTs one thread each; the command line shares one
    # allocator arena among the threads, dsp.blas, so the blocks in flight cost what one block did)
    per_block = max(1, step // groups, min(width, int(min_columns)))
    threads = min(worker_threads(), -(-width // per_block)) if implementation == "czt" else 1
    per_block = max(1, per_block // threads, min(width, int(min_columns)))   # the blocks in flight hold
    # what one block did, unless that is narrower than min_columns
    y_sum = backing.empty((p, n_cols), np.complex64)      # file-backed when out of core (io/backing.py)
    y_diff = backing.empty((p, n_cols), np.complex64)

    if tracking is not None:             # the history's derivatives and the phasor grid: once, all blocks
        hist, t, prf_hz, scale = tracking
        scale = np.broadcast_to(np.asarray(scale, dtype=np.float64), (n_cols,))
        derivs = history_taylor(hist, t)
        demod = OuterPhasors(-derivs[0], scale, demod_grid)   # the phase is linear in scale = 1 + f_r/f_c

    def cols(a, k):                      # a per-column array's block: columns k of every group
        return a[k] if groups == 1 else a.reshape(groups, width)[:, k].reshape(-1)

    def block(lo):                       # columns are independent: each block in its own thread
        k = slice(lo, min(width, lo + per_block))
        trk = None
        if tracking is not None:
            trk = (derivs, demod.columns(cols(np.arange(n_cols), k)), prf_hz, cols(scale, k))
        # the block's columns read and written where they lie (views: [p, cols] or [p, groups, cols])
        if groups == 1:
            views = [a[:, k] for a in (x_sum, x_diff, y_sum, y_diff)]
        else:
            views = [a.reshape(p, groups, width)[:, :, k] for a in (x_sum, x_diff, y_sum, y_diff)]
        _keystone_block(
            views[0], views[1], alpha=cols(alpha, k), t0_index=cols(t0_index, k),
            implementation=implementation, doppler_ref=doppler_ref, n_taps=n_taps, tracking=trk,
            ambiguity=ambiguity if np.ndim(ambiguity) == 0 else cols(np.asarray(ambiguity), k),
            fft_workers=1 if threads > 1 else -1, period=k.stop - k.start if groups > 1 else None,
            out=(views[2], views[3]))

    # the tracking remodulation's matrix products (remodulation_cycles) with the BLAS on one thread:
    # the blocks are the parallel work (dsp.blas)
    with one_blas_thread() if tracking is not None else contextlib.nullcontext():
        if threads > 1:
            with ThreadPoolExecutor(max_workers=threads) as pool:
                list(pool.map(block, range(0, width, per_block)))
        else:
            for lo in range(0, width, per_block):
                block(lo)
    return y_sum, y_diff


SUPERBLOCK_BYTES = 64 << 20   # out of core: the bytes of one channel's columns read from the file at once


def keystone_both_blocked(x_sum, x_diff, *, alpha, t0_index, period=None, tracking=None,
                          superblock_bytes: int | None = None, **kw):
    """:func:`keystone_both` of file-backed arrays (``--out-of-core``, io/backing.py), in super-blocks of
    range frequencies: each super-block's columns (of every group, for ``period``) are read from the
    file at once into memory, transformed there and written back.  A column block of a [pulses,
    columns] file touches every pulse's page, so the super-block is as wide as ``superblock_bytes``
    (default :data:`SUPERBLOCK_BYTES`, read when called) allows (512 columns at 16384 pulses): each page of the input is then read about once, not once per
    narrow block.  The same numbers as the whole (every column is its own)."""
    p, n_cols = x_sum.shape
    groups = n_cols // period if period and n_cols % period == 0 and n_cols > period else 1
    width = n_cols // groups
    alpha = np.broadcast_to(np.asarray(alpha, dtype=np.float64), (n_cols,))
    t0_index = np.broadcast_to(np.asarray(t0_index, dtype=np.float64), (n_cols,))
    scale = None if tracking is None else np.broadcast_to(np.asarray(tracking[3], dtype=np.float64), (n_cols,))
    y_sum, y_diff = backing.empty((p, n_cols), np.complex64), backing.empty((p, n_cols), np.complex64)
    step = max(1, int(SUPERBLOCK_BYTES if superblock_bytes is None else superblock_bytes) // (8 * p * groups))
    if tracking is not None:             # the demodulation's grid of every column, as the whole has it
        rate = history_taylor(tracking[0], tracking[1])[0]
        kw["demod_grid"] = outer_grid(scale, float(np.max(np.abs(rate), initial=0.0)))

    def cols(a, k):                      # a per-column array's super-block: columns k of every group
        return a.reshape(groups, width)[:, k].reshape(-1)

    for k0 in range(0, width, step):
        k = slice(k0, min(width, k0 + step))
        n_k = k.stop - k.start
        xs, xd = (np.ascontiguousarray(a.reshape(p, groups, width)[:, :, k]).reshape(p, groups * n_k)
                  for a in (x_sum, x_diff))
        trk = None if tracking is None else tuple(tracking[:3]) + (cols(scale, k),)
        with backing.in_memory():
            ys, yd = keystone_both(xs, xd, alpha=cols(alpha, k), t0_index=cols(t0_index, k),
                                   period=n_k if groups > 1 else None, tracking=trk, **kw)
        y_sum.reshape(p, groups, width)[:, :, k] = ys.reshape(p, groups, n_k)
        y_diff.reshape(p, groups, width)[:, :, k] = yd.reshape(p, groups, n_k)
    return y_sum, y_diff


def _keystone_block(x_sum, x_diff, *, alpha, t0_index, implementation, ambiguity, doppler_ref, n_taps,
                    tracking, fft_workers=-1, period=None, out=None):
    """The keystone of one block of columns of both channels ([p, cols] or [p, groups, cols] each, the
    columns in C order); written into ``out`` = (sum, diff) of the same shapes where given (strided
    views of the whole output), else returned."""
    p = x_sum.shape[0]
    demod = remod = None
    plan = (KeystonePlan(p, alpha, t0_index=t0_index, workers=fft_workers, period=period)
            if implementation == "czt" else None)
    if tracking is not None:
        derivs, demod, prf_hz, scale = tracking
        t0 = np.asarray(t0_index, dtype=np.float64).reshape(-1)
        if t0.size and np.all(t0 == t0[0]):      # one time origin (q = 1): one matrix product
            chirp = plan.post_cycles_f0_factors() if plan is not None else (None, None)
            cycles = remodulation_cycles(derivs, t0[0], np.broadcast_to(alpha, t0.shape), scale, prf_hz, *chirp)
        else:
            # tau = alpha (m - t0) + t0 (eq. 8): the shift from pulse m is (alpha - 1)(m - t0) pulses
            dt_s = np.subtract.outer(np.arange(p, dtype=np.float64), t0_index) * ((alpha - 1.0) / prf_hz)
            cycles = history_phase_shifted(derivs, dt_s)
            cycles *= scale / (2.0 * np.pi)
            del dt_s
            if plan is not None:
                cycles += plan.post_cycles_f0()
        if plan is not None:         # remodulation folded into the CZT's output chirp: one pass
            post = _cis(cycles, np.complex64)
            post *= np.float32(1.0 / p)
        else:
            remod = _cis(cycles, np.complex64)
        del cycles
    if implementation == "czt":
        if tracking is not None:
            run = lambda x, o: plan.apply(x, post=post, out=o)                  # noqa: E731
        else:
            run = lambda x, o: plan.apply(x, ambiguity=ambiguity, out=o)        # noqa: E731
    elif implementation == "dft":
        direct = lambda x: keystone_dft(x, alpha, t0_index=t0_index,             # noqa: E731
                                        ambiguity=ambiguity).astype(np.complex64)
    elif implementation == "sinc":
        direct = lambda x: keystone_sinc(x, alpha, t0_index=t0_index, doppler_ref=doppler_ref,  # noqa: E731
                                         n_taps=n_taps).astype(np.complex64)
    else:
        raise ValueError(f"keystone implementation {implementation!r}; allowed: czt, dft, sinc")
    if implementation != "czt":          # 2-D in, 2-D out: into ``o`` in the block's layout
        run = lambda x, o: _put(direct(x.reshape(p, -1)).reshape(x.shape), o)   # noqa: E731
    results = []
    for x, o in zip((x_sum, x_diff), out or (None, None)):
        if demod is not None:
            x = x * demod.reshape(x.shape)
        y = run(x, o)
        if remod is not None:
            y *= remod.reshape(y.shape)
        results.append(y)
    return results[0], results[1]


def _put(y, out):
    """``y`` written into ``out`` (returned), or ``y`` itself where there is no ``out``."""
    if out is None:
        return y
    out[...] = y
    return out
