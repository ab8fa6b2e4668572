"""Quick-look PNGs of images (dB scale, labelled axes; matplotlib, Agg backend)."""
from __future__ import annotations

import contextlib
import os
import warnings
from pathlib import Path

import numpy as np

from .outputs import _unlink_quietly, atomic_path, make_parent, mapped_os_errors, partial_path
from . import signals
from .partial import claim_partial


MISSING_GLYPH = r"Glyph \d+ .*missing from font"     # matplotlib's UserWarning for a character its font lacks


@contextlib.contextmanager
def quiet_missing_glyphs():
    """matplotlib's warning for a character its font lacks left out while a figure is drawn: a scenario name
    in a script the font does not cover (CJK, emoji, control characters) is drawn as boxes, and the warning's
    two lines for each such character had reached the user's terminal from a run that succeeded."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=MISSING_GLYPH, category=UserWarning)
        # (matplotlib 3.9-3.10 follow a missing glyph of an Indic script with this one too)
        warnings.filterwarnings("ignore", message=r"Matplotlib currently does not support .* natively",
                                category=UserWarning)
        yield


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_image_png(path, power, x_axis, y_axis, *, xlabel, ylabel, title, dynamic_range_db=40.0,
                   markers=None, aspect="auto"):
    """Save ``power`` [len(y_axis), len(x_axis)] as a dB image (peak at 0 dB), atomically.

    ``markers``: optional (x, y) arrays of truth positions drawn as open circles.  Drawn by the
    command's painter where one is running (``io/painter.py``: a child that imported matplotlib while
    the chain ran), else here (:func:`draw_image_png`).
    """
    start_image_png(path, power, x_axis, y_axis, xlabel=xlabel, ylabel=ylabel, title=title,
                    dynamic_range_db=dynamic_range_db, markers=markers, aspect=aspect).finish()


def start_image_png(path, power, x_axis, y_axis, **kwargs) -> "PendingPng":
    """:func:`save_image_png` begun: with a painter running, the child draws it meanwhile; else it is
    drawn in this process by :meth:`PendingPng.finish`."""
    from . import painter

    args = (path, power, x_axis, y_axis)
    child, tmp = painter.active(), None
    if child is not None:
        make_parent(path)
        with mapped_os_errors(path):           # the partial name claimed here, drawn there (io/partial.py),
            tmp = signals.call_held(_claim_for_painter, path)     # with signals held until it is known
        signals.raise_pending()
        try:       # by name: the child's own draw_image_png, left partial (renamed by finish)
            child.submit("fwdlook_cli.io.quicklook:draw_image_png", *args, rename=False, partial=str(tmp), **kwargs)
        except painter.PainterGone:
            child = None
    return PendingPng(child, args, kwargs, tmp)


_UNCLAIMED: set = set()     # the painter's drawings (partial_path) begun and not yet renamed or discarded by their command


def _claim_for_painter(path) -> Path:
    """The drawing's partial name claimed and entered in :data:`_UNCLAIMED` (whose names a stopped command
    removes) in one step: called with signals held, none can come between the two."""
    tmp = claim_partial(partial_path(path))
    _UNCLAIMED.add(str(tmp))
    return tmp


@contextlib.contextmanager
def painting():
    """Within the block, quick looks are drawn by a forked child (``io/painter.py``) that has imported
    matplotlib and drawn one small figure (:func:`warm_up`) meanwhile. At its end, once the child has
    finished its job, a drawing its command never claimed (stopped between metrics.json and the
    rename: SIGTERM, Ctrl-C) is removed: it had stayed as ``image.partial.png``."""
    from . import painter

    try:
        with painter.painting(warm_up=WARM_UP) as child:
            yield child
    finally:
        while _UNCLAIMED:
            _unlink_quietly(_UNCLAIMED.pop())


WARM_UP = f"{__name__}:warm_up"       # the painter's warm-up, by name (cli.QUICKLOOK_WARM_UP forks with it)


def warm_up() -> None:
    """matplotlib imported and one small quick look drawn into memory: the first figure loads the fonts
    and caches (about 0.1 s here), which the command's image then finds loaded."""
    import io

    axis = np.arange(8.0)
    draw_image_png(io.BytesIO(), np.ones((8, 8)), axis, axis, xlabel="x", ylabel="y", title="t",
                   markers=(axis[:2], axis[:2]))


class PendingPng:
    """A quick look begun by :func:`start_image_png`."""

    def __init__(self, child, args, kwargs, tmp=None):
        self.child, self.args, self.kwargs, self.tmp = child, args, kwargs, tmp

    def finish(self) -> None:
        """Return once the PNG is written (raise what drawing it raised)."""
        from . import painter

        child, self.child = self.child, None
        if self.tmp is not None:
            _UNCLAIMED.discard(str(self.tmp))
        if child is not None:
            path = Path(self.args[0])
            try:
                child.result()
                with mapped_os_errors(path):
                    os.replace(self.tmp, path)
                return None
            except painter.PainterGone:
                _unlink_quietly(self.tmp)   # the child is gone: drawn here
            except BaseException:
                _unlink_quietly(self.tmp)
                raise
        elif self.tmp is not None:           # claimed, then the child was gone before the job
            _unlink_quietly(self.tmp)
        return draw_image_png(*self.args, **self.kwargs)

    def discard(self) -> None:
        """The command failed after the PNG was begun: wait for the child, leave no PNG behind."""
        child, self.child = self.child, None
        if child is not None:
            with contextlib.suppress(Exception):
                child.result()
            _unlink_quietly(self.args[0])
        if self.tmp is not None:
            _unlink_quietly(self.tmp)
            _UNCLAIMED.discard(str(self.tmp))


QUICKLOOK_MARGINS = dict(left=0.12, right=0.99, bottom=0.117, top=0.932)


def draw_image_png(path, power, x_axis, y_axis, *, xlabel, ylabel, title, dynamic_range_db=40.0,
                   markers=None, aspect="auto", rename=True, partial=None):
    """:func:`save_image_png` drawn in this process (a bare :class:`matplotlib.figure.Figure`: the same
    PNG as pyplot's figure, without importing pyplot, 0.05 s of the painter's start). ``rename=False``:
    left at ``NAME.partial.SUFFIX`` (the painter's drawing, which its command renames after the run's
    metrics.json, so that no PNG appears in a run before its metrics; ``partial``: the name its command
    claimed for it)."""
    from matplotlib.figure import Figure

    p = np.asarray(power, dtype=np.float32)         # a picture: float32 dB, computed in place
    db = p / np.float32(max(float(p.max()), 1e-30))
    np.maximum(db, np.float32(10 ** (-dynamic_range_db / 10 - 1)), out=db)
    np.log10(db, out=db)
    db *= np.float32(10.0)
    fig = Figure(figsize=(7.5, 5.0), dpi=110)
    # fixed margins, about what tight_layout finds for range ticks of up to six digits (tight_layout
    # lays the figure out by drawing it once more: a fifth of the drawing's time)
    fig.subplots_adjust(**QUICKLOOK_MARGINS)
    ax = fig.subplots()
    extent = _uniform_extent(x_axis, y_axis)
    if extent is not None:      # a raster: what pcolormesh draws cell by cell, at a fraction of the
        # memory (a quad mesh of ~1 M cells held about 90 MB while drawn) and of the time
        db, extent = _display_raster(db, np.asarray(x_axis, float), np.asarray(y_axis, float),
                                     -dynamic_range_db)
        mesh = ax.imshow(db, extent=extent, origin="lower", interpolation="nearest", vmin=-dynamic_range_db,
                         vmax=0, cmap="viridis")
    else:
        mesh = ax.pcolormesh(x_axis, y_axis, db, shading="nearest", vmin=-dynamic_range_db, vmax=0,
                             cmap="viridis")
    if markers is not None:
        ax.plot(markers[0], markers[1], "o", mfc="none", mec="w", ms=7, mew=0.8, label="truth")
        ax.legend(loc="upper right", fontsize=8)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.set_aspect(aspect)
    fig.colorbar(mesh, ax=ax, label="dB", fraction=0.15, pad=0.03)
    if not isinstance(path, (str, os.PathLike)):     # a file object (the painter's warm-up)
        fig.savefig(path, format="png")
        return
    with atomic_path(path, rename=rename, tmp=partial) as tmp, quiet_missing_glyphs():   # partial removed,
        fig.savefig(tmp, format="png")                                                # OSError one line


DISPLAY_PIXELS = (420, 640)     # (rows, columns) of a quick look's axes, about what the figure shows


def _display_raster(db, x_axis, y_axis, floor_db, *, margin=0.08, pixels=DISPLAY_PIXELS):
    """The part of a dB raster that holds anything above ``floor_db`` (plus a margin), reduced to about
    the display's pixels by a block maximum, so that a target one cell wide (the dwell image's 0.05 deg
    bins) stays visible instead of being dropped by the renderer's resampling.  Returns (raster, extent)."""
    def span(mask, n):
        idx = np.flatnonzero(mask)
        if len(idx) == 0:
            return 0, n
        pad = int(np.ceil(margin * (idx[-1] - idx[0] + 1))) + 1
        return max(0, idx[0] - pad), min(n, idx[-1] + pad + 1)

    above = db > floor_db
    r0, r1 = span(above.any(axis=1), db.shape[0])
    c0, c1 = span(above.any(axis=0), db.shape[1])
    sub = db[r0:r1, c0:c1]
    fy, fx = max(1, -(-sub.shape[0] // pixels[0])), max(1, -(-sub.shape[1] // pixels[1]))
    ny, nx = -(-sub.shape[0] // fy) * fy, -(-sub.shape[1] // fx) * fx
    padded = np.full((ny, nx), np.float32(floor_db - 10.0), dtype=np.float32)
    padded[:sub.shape[0], :sub.shape[1]] = sub
    pooled = padded.reshape(ny // fy, fy, nx // fx, fx).max(axis=(1, 3))
    dx, dy = x_axis[1] - x_axis[0], y_axis[1] - y_axis[0]
    extent = [x_axis[c0] - dx / 2, x_axis[c0] - dx / 2 + nx * dx, y_axis[r0] - dy / 2, y_axis[r0] - dy / 2 + ny * dy]
    return pooled, extent


def _uniform_extent(x_axis, y_axis):
    """imshow's extent for cell centres on uniform increasing axes (each cell one step wide), else None."""
    bounds = []
    for a in (np.asarray(x_axis, float), np.asarray(y_axis, float)):
        if a.ndim != 1 or len(a) < 2:
            return None
        step = np.diff(a)
        if not (step[0] > 0 and np.allclose(step, step[0], rtol=1e-6, atol=0)):
            return None
        bounds += [a[0] - step[0] / 2, a[-1] + step[0] / 2]
    return bounds


def _save(fig, path):
    plt = _plt()
    try:
        with quiet_missing_glyphs():
            fig.tight_layout()
            with atomic_path(path) as tmp:
                fig.savefig(tmp)
    finally:
        plt.close(fig)
