"""The quick-look raster keeps what a one-cell target shows: the block maximum, not a resampled sample."""
import numpy as np

from fwdlook_cli.io.quicklook import _display_raster


def test_one_cell_peak_survives_the_display_reduction():
    db = np.full((2700, 720), -60.0, dtype=np.float32)          # a dwell image: 4x range, 0.05 deg bins
    db[1203, 511] = 0.0                                          # one target, one cell
    x = -18.0 + 0.05 * np.arange(720)
    y = 1200.0 + 0.625 * np.arange(2700)
    out, extent = _display_raster(db, x, y, -40.0)
    assert out.max() == 0.0                                      # the peak is kept by the block maximum
    assert out.shape[0] <= 420 and out.shape[1] <= 640
    assert extent[0] <= x[511] <= extent[1] and extent[2] <= y[1203] <= extent[3]   # and framed
    assert (extent[1] - extent[0]) < (x[-1] - x[0])              # cropped to the part above the floor


def test_an_empty_raster_keeps_its_axes():
    db = np.full((10, 12), -60.0, dtype=np.float32)
    x, y = np.arange(12.0), np.arange(10.0)
    out, extent = _display_raster(db, x, y, -40.0)
    assert out.shape == (10, 12) and extent == [-0.5, 11.5, -0.5, 9.5]
