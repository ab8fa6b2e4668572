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


def test_a_title_the_font_cannot_draw_warns_no_one(tmp_path):
    """A scenario name in a script the font lacks (CJK, an emoji, a tab) is drawn as boxes without
    matplotlib's UserWarning for each character: the quick look (``draw_image_png``, which its painter runs)
    and the report's image panels (``report.plots.image_panels``); the warning's two lines had reached the
    terminal of a run that succeeded."""
    import warnings

    from fwdlook_cli.io.quicklook import draw_image_png
    from fwdlook_cli.report.plots import image_panels

    power = np.ones((20, 30), np.float32)
    power[10, 15] = 100.0
    x, y = np.arange(30.0), np.arange(20.0)
    title = "中文 😀\tname"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        draw_image_png(tmp_path / "a.png", power, x, y, xlabel="x", ylabel="y", title=title)
        image_panels(tmp_path / "b.png", [{"power": power, "x": x, "y": y, "title": title}], suptitle=title)
    assert (tmp_path / "a.png").stat().st_size > 0 and (tmp_path / "b.png").stat().st_size > 0
    assert [str(w.message) for w in caught if "Glyph" in str(w.message)] == []
