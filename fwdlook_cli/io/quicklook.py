"""Quick-look PNGs of images (dB scale, labelled axes; matplotlib, Agg backend)."""
from __future__ import annotations


import numpy as np

from .outputs import atomic_path


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_image_png(path, power, x_axis, y_axis, *, xlabel, ylabel, title, dynamic_range_db=40.0,
                   markers=None, aspect="auto"):
    """Save ``power`` [len(y_axis), len(x_axis)] as a dB image (peak at 0 dB), atomically.

    ``markers``: optional (x, y) arrays of truth positions drawn as open circles.
    """
    plt = _plt()
    p = np.asarray(power, dtype=np.float32)         # a picture: float32 dB, computed in place
    db = p / np.float32(max(float(p.max()), 1e-30))
    np.maximum(db, np.float32(10 ** (-dynamic_range_db / 10 - 1)), out=db)
    np.log10(db, out=db)
    db *= np.float32(10.0)
    fig, ax = plt.subplots(figsize=(7.5, 5.0), dpi=110)
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
    fig.colorbar(mesh, ax=ax, label="dB")
    fig.tight_layout()
    try:
        with atomic_path(path) as tmp:          # partial removed and OSError one line on failure
            fig.savefig(tmp)
    finally:
        plt.close(fig)


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
    fig.tight_layout()
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp)
    finally:
        plt.close(fig)
