"""Neighbourhood operations the calibration and the report need, in numpy: a running maximum along an
axis and the 8-connected groups of grid cells.

They stand in for ``scipy.ndimage.maximum_filter1d`` and ``scipy.ndimage.label``, whose module costs
about 30 ms to import (with scipy's own machinery already loaded), paid by every ``fwdlook process`` and
``run`` for one call each (the calibration check of every cube, ``forward/point_returns.py``).  Both
give scipy's numbers exactly (a maximum is exact; the groups are numbered as scipy numbers them), and
``tests/test_neighbours.py`` checks them against scipy.
"""
from __future__ import annotations

import numpy as np


def running_max(x, size: int, axis: int = -1):
    """The maximum over a window of ``size`` samples along ``axis``, the edges extended by their own
    value: ``scipy.ndimage.maximum_filter1d(x, size, axis, mode="nearest")`` for finite ``x`` (output
    sample i covers i - size // 2 .. i + (size - 1) // 2, scipy's window with origin 0).

    Windows of 2, 4, 8, ... samples by doubling, then two overlapping ones for ``size``: about
    log2(size) + 1 element-wise maxima of the array (5 for 17 samples), exact."""
    size = int(size)
    if size < 1:
        raise ValueError(f"size {size}: must be >= 1")
    x = np.asarray(x)
    if size == 1 or x.size == 0:
        return x.copy()
    axis = axis % x.ndim
    if size >= 2 * x.shape[axis] - 1:           # every window holds the whole row (a narrow band's
        return np.broadcast_to(x.max(axis=axis, keepdims=True), x.shape).copy()   # reach, in samples)
    pad = [(0, 0)] * x.ndim
    pad[axis] = (size // 2, size - 1 - size // 2)
    out = np.pad(x, pad, mode="edge")

    def cut(a, lo, hi):                         # a[..., lo:hi, ...] along the axis
        sl = [slice(None)] * a.ndim
        sl[axis] = slice(lo, hi)
        return a[tuple(sl)]

    width = 1                                   # out[j] = max of the padded samples j .. j + width - 1
    while 2 * width <= size:
        n = out.shape[axis]
        out = np.maximum(cut(out, 0, n - width), cut(out, width, n))
        width *= 2
    if width < size:                            # two windows of ``width`` overlapping on ``size`` samples
        n = out.shape[axis]
        out = np.maximum(cut(out, 0, n - (size - width)), cut(out, size - width, n))
    return out


def label_cells(row, col):
    """The 8-connected groups of the grid cells (``row[i]``, ``col[i]``) (non-negative integers; a cell
    given twice is one cell): (group of each given cell, from 0, number of groups).  The groups are
    numbered in the raster order of their first cell, as ``scipy.ndimage.label`` of the boolean grid
    with a 3 x 3 structure numbers them (from 1 there).

    The cells sorted in raster order, each linked to its four forward neighbours that are cells too,
    and every cell's label lowered to its neighbours' and to its label's label until nothing changes:
    each group ends labelled with its first cell.  Work in the number of cells, not of the grid."""
    row = np.asarray(row, dtype=np.int64).reshape(-1)
    col = np.asarray(col, dtype=np.int64).reshape(-1)
    if row.shape != col.shape:
        raise ValueError(f"row has {row.size} cells, col {col.size}")
    if row.size == 0:
        return np.zeros(0, dtype=np.int64), 0
    if row.min() < 0 or col.min() < 0:
        raise ValueError("cells must have non-negative row and column")
    width = int(col.max()) + 3                  # col + 1 in 1 .. width - 2: a step of -1 or +1 never wraps
    keys = row * width + (col + 1)
    cells, inverse = np.unique(keys, return_inverse=True)          # raster order
    n = cells.size
    u, v = [], []
    for step in (1, width - 1, width, width + 1):                  # right, and the three below
        target = cells + step
        at = np.minimum(np.searchsorted(cells, target), n - 1)
        hit = cells[at] == target
        u.append(np.flatnonzero(hit))
        v.append(at[hit])
    u, v = np.concatenate(u), np.concatenate(v)
    label = np.arange(n)                        # always a cell of the same group, never after the cell
    while u.size:
        low = np.minimum(label[u], label[v])
        new = label.copy()
        np.minimum.at(new, u, low)
        np.minimum.at(new, v, low)
        new = new[new]
        if np.array_equal(new, label):
            break
        label = new
    first, group = np.unique(label, return_inverse=True)
    return group.reshape(-1)[inverse.reshape(-1)], int(first.size)
