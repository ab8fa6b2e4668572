"""Exact percentiles of values produced block by block: memory bounded by one block, not by the data.

The data calibration's noise estimate is a percentile of the sum channel's power over the whole cube
(``forward/point_returns.py``).  Held at once, that power is half a channel; an out-of-core run has
less memory than the cube (``io/backing.py``).  Here the order statistics a percentile needs are found
in passes over blocks: a bracket [lo, hi] around them is read off a sample of the values, one pass
counts the values under ``lo`` and keeps those inside the bracket (a small fraction), and the
statistics are then read off the kept values, sorted.  A bracket that misses (the sample was not
representative) is moved and the pass repeated; the result is exact whatever the sample, and the same
number as ``np.percentile`` of all the values (its ``linear`` method, interpolated as numpy does).
"""
from __future__ import annotations

import numpy as np

BRACKET_SIGMAS = 6.0          # the bracket's half-width in standard deviations of the sample quantile's rank
KEEP_CAP = 1 << 22            # values kept from one pass at most (16 MB of float32)
MAX_PASSES = 64


def numpy_lerp(a, b, gamma: float, dtype):
    """numpy's ``_lerp`` of ``np.percentile`` (``linear``) for a Python-float percentile, in the data's
    float ``dtype``: ``a + (b - a) t``, or ``b - (b - a)(1 - t)`` for t >= 1/2, with t the Python float
    ``gamma`` (a weak scalar: each product rounded in ``dtype``, ``1 - t`` taken in float64 first)."""
    a, b = np.asarray(a, dtype=dtype), np.asarray(b, dtype=dtype)
    t = float(gamma)
    diff_b_a = b - a
    out = np.add(a, diff_b_a * t, out=np.empty((), dtype=dtype))
    if t >= 0.5:
        np.subtract(b, diff_b_a * (1 - t), out=out)
    return out[()]


def _bracket_pass(blocks, lo, hi, cap):
    """(values < lo, values in [lo, hi], the values in [lo, hi]: all of them where they are no more than
    ``cap``, else every k-th in the blocks' order, k a power of two, at most ``cap`` of them)."""
    below = inside = 0
    kept, n_kept, stride = [], 0, 1
    for x in blocks():
        x = np.asarray(x).reshape(-1)
        below += int(np.count_nonzero(x < lo))
        sel = x[(x >= lo) & (x <= hi)]
        part = sel[(-inside) % stride::stride]        # the bracket's values whose index is a multiple of k
        inside += sel.size
        kept.append(part)
        n_kept += part.size
        while n_kept > cap:                           # every other one kept: multiples of 2 k
            every = np.concatenate(kept)[::2]
            kept, n_kept, stride = [every], every.size, 2 * stride
    values = np.concatenate(kept) if kept else np.zeros(0)
    return below, inside, values


def _sample_bracket(sample, f_lo, f_hi):
    """[lo, hi] around the quantiles ``f_lo`` <= ``f_hi`` (fractions of the data) read off ``sample``:
    its order statistics +- :data:`BRACKET_SIGMAS` standard deviations of their ranks."""
    m = sample.size
    if m == 0:
        return -np.inf, np.inf
    f = 0.5 * (f_lo + f_hi)
    margin = BRACKET_SIGMAS * np.sqrt(m * max(f * (1.0 - f), 1.0 / m)) + 2.0
    i_lo, i_hi = int(np.floor(f_lo * (m - 1) - margin)), int(np.ceil(f_hi * (m - 1) + margin))
    picks = sorted({min(max(i_lo, 0), m - 1), min(max(i_hi, 0), m - 1)})
    part = np.partition(sample, picks)
    lo = part[i_lo] if i_lo >= 0 else -np.inf
    hi = part[i_hi] if i_hi <= m - 1 else np.inf
    return lo, hi


def order_statistics_of_blocks(blocks, n: int, k_lo: int, k_hi: int, sample, *, cap: int = KEEP_CAP):
    """The ``k_lo``-th and ``k_hi``-th smallest (0-based, ``k_lo <= k_hi``) of the ``n`` values that
    ``blocks()`` yields (an iterable of arrays, the same every call), exactly.  ``sample``: some of the
    values (any subset: it only places the first bracket).  Where no bracket closes within
    :data:`MAX_PASSES` passes (the kept values cannot narrow it), the values are taken at once."""
    if not 0 <= k_lo <= k_hi < n:
        raise ValueError(f"order statistics {k_lo}, {k_hi} of {n} values")
    lo, hi = _sample_bracket(np.asarray(sample).reshape(-1), k_lo / max(n - 1, 1), k_hi / max(n - 1, 1))
    for _ in range(MAX_PASSES):
        below, inside, values = _bracket_pass(blocks, lo, hi, cap)
        if below > k_lo:                       # the bracket begins above the statistics: look below it
            lo, hi = -np.inf, lo
            continue
        if below + inside <= k_hi:             # it ends below them: look above it
            lo, hi = hi, np.inf
            continue
        if lo == hi:                           # every value inside is lo (ties)
            return values.dtype.type(lo), values.dtype.type(lo)
        if values.size == inside:              # it holds both, and every value inside was kept
            values.sort()
            return values[k_lo - below], values[k_hi - below]
        # too many inside to keep: a narrower bracket from the values kept (an even sample of the bracket)
        span = max(inside - 1, 1)
        new_lo, new_hi = _sample_bracket(values, (k_lo - below) / span, (k_hi - below) / span)
        new_lo, new_hi = max(new_lo, lo), min(new_hi, hi)
        if not (new_lo > lo or new_hi < hi):
            break
        lo, hi = new_lo, new_hi
    every = np.concatenate([np.asarray(x).reshape(-1) for x in blocks()])
    every.partition([k_lo, k_hi])
    return every[k_lo], every[k_hi]


def percentile_of_blocks(blocks, n: int, q: float, sample, dtype, *, cap: int = KEEP_CAP):
    """``np.percentile(all values, q)`` (``linear``, ``q`` a Python float) of the ``n`` values of float
    dtype ``dtype`` that ``blocks()`` yields, bit for bit, with memory bounded by a block and the values
    of one bracket."""
    qf = np.true_divide(float(q), 100)
    v = (n - 1) * qf                           # numpy's virtual index, and its floor and gamma
    k0 = int(np.floor(v))
    k1 = min(k0 + 1, n - 1)
    gamma = float(v - np.floor(v))
    a, b = order_statistics_of_blocks(blocks, n, k0, k1, sample, cap=cap)
    return numpy_lerp(a, b, gamma, dtype)
