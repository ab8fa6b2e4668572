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
    p = np.asarray(power, dtype=np.float64)
    db = 10 * np.log10(np.maximum(p / max(p.max(), 1e-300), 10 ** (-dynamic_range_db / 10 - 1)))
    fig, ax = plt.subplots(figsize=(7.5, 5.0), dpi=110)
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


def _save(fig, path):
    plt = _plt()
    fig.tight_layout()
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp)
    finally:
        plt.close(fig)
