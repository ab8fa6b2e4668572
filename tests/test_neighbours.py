"""dsp.neighbours against scipy.ndimage, the code it stands in for (independent: scipy's C filters and
its two-pass labelling share nothing with the doubling maxima and the label lowering)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import label, maximum_filter1d

from fwdlook_cli.dsp.neighbours import label_cells, running_max


@pytest.mark.parametrize("shape", [(1, 1), (1, 2), (3, 7), (5, 1), (40, 280)])
def test_running_max_is_scipys_maximum_filter_with_nearest_edges(shape):
    """Every window size from 1 to beyond the axis (odd and even: scipy's window with origin 0, i - size//2
    .. i + (size - 1)//2), both axes, float32 and float64, values with ties."""
    rng = np.random.default_rng(sum(shape))
    for dtype in (np.float32, np.float64):
        x = rng.standard_normal(shape).astype(dtype)
        x[::2] = np.round(x[::2])                           # ties
        for axis in (0, 1, -1):
            for size in range(1, 2 * max(shape) + 3):
                got = running_max(x, size, axis=axis)
                want = maximum_filter1d(x, size, axis=axis, mode="nearest")
                assert got.dtype == want.dtype
                np.testing.assert_array_equal(got, want, err_msg=f"size {size}, axis {axis}")


def test_running_max_of_a_lone_spike_is_the_window_around_it():
    """Closed form: a spike at sample k covers output samples k - (size-1)//2 .. k + size//2."""
    for size in (2, 5, 16, 17):
        x = np.zeros(50)
        x[20] = 1.0
        lit = np.flatnonzero(running_max(x, size))
        np.testing.assert_array_equal(lit, np.arange(20 - (size - 1) // 2, 20 + size // 2 + 1))


def test_running_max_of_a_window_far_wider_than_the_axis_is_the_row_maximum():
    """A window of 10^9 samples over 77 (the calibration's sidelobe reach, 8 resolution cells, of a cube
    whose band is narrow against its sampling rate): every window holds the whole row, so the answer is
    the row's maximum, as scipy's for a window just past twice the axis, without padding the row by
    the window (which once asked for 191 GiB)."""
    x = np.random.default_rng(3).standard_normal((4, 77)).astype(np.float32)
    got = running_max(x, 10**9, axis=1)
    np.testing.assert_array_equal(got, maximum_filter1d(x, 2 * 77 + 1, axis=1, mode="nearest"))
    np.testing.assert_array_equal(got, np.broadcast_to(x.max(axis=1, keepdims=True), x.shape))


def test_running_max_rejects_an_empty_window():
    with pytest.raises(ValueError, match="size 0"):
        running_max(np.ones(4), 0)


def _scipy_groups(row, col):
    grid = np.zeros((row.max() + 1, col.max() + 1), dtype=bool)
    grid[row, col] = True
    labels, n = label(grid, structure=np.ones((3, 3)))
    return labels[row, col] - 1, n


@pytest.mark.parametrize("density", [0.03, 0.2, 0.45, 0.8])
def test_label_cells_numbers_the_groups_as_scipy_label_does(density):
    """Random grids from sparse to nearly full (chains, rings, diagonal contacts), cells given in a
    shuffled order with repeats: the same group of every cell and the same numbering."""
    rng = np.random.default_rng(int(density * 100))
    for _ in range(60):
        h, w = rng.integers(1, 45, size=2)
        r, c = np.nonzero(rng.random((h, w)) < density)
        if r.size == 0:
            continue
        pick = rng.integers(0, r.size, 2 * r.size)
        got, n = label_cells(r[pick], c[pick])
        want, n_want = _scipy_groups(r[pick], c[pick])
        assert n == n_want
        np.testing.assert_array_equal(got, want)


def test_label_cells_links_diagonals_and_not_across_rows():
    """Diagonal neighbours are one group; the last column of a row and the first of the next are not
    neighbours (the cells' keys leave a margin so that a step of one column never wraps)."""
    group, n = label_cells([0, 1, 2, 5, 6], [0, 1, 0, 4, 0])
    assert n == 3
    assert group[0] == group[1] == group[2]
    assert len({group[0], group[3], group[4]}) == 3
    group, n = label_cells([0, 1], [7, 0])                 # end of row 0, start of row 1
    assert n == 2


def test_label_cells_of_a_long_snake_is_one_group():
    """A one-cell-wide path that doubles back (the worst case for lowering labels hop by hop)."""
    rows, cols = [], []
    for r in range(0, 40, 2):
        span = range(30) if (r // 2) % 2 == 0 else range(29, -1, -1)
        rows += [r] * 30
        cols += list(span)
        rows.append(r + 1)
        cols.append(29 if (r // 2) % 2 == 0 else 0)
    group, n = label_cells(rows, cols)
    assert n == 1 and np.all(group == 0)


def test_label_cells_edge_cases():
    group, n = label_cells([], [])
    assert n == 0 and group.size == 0
    group, n = label_cells([3], [4])
    assert n == 1 and group.tolist() == [0]
    with pytest.raises(ValueError, match="non-negative"):
        label_cells([0, -1], [0, 0])
    with pytest.raises(ValueError, match="cells"):
        label_cells([0, 1], [0])
