"""Plotting at the edge: quick-look PNGs with labelled axes (matplotlib, Agg backend)."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np


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
    path = Path(path)
    tmp = path.with_name(path.stem + ".partial.png")
    fig.savefig(tmp)
    plt.close(fig)
    os.replace(tmp, path)


def _save(fig, path):
    plt = _plt()
    path = Path(path)
    tmp = path.with_name(path.stem + ".partial.png")
    fig.tight_layout()
    fig.savefig(tmp)
    plt.close(fig)
    os.replace(tmp, path)


def speed_accuracy_chart(path, rows, grid_keys, *, error_key="max_abs_range_error_m"):
    """Processing time against the worst range error, one marker per run, labelled by grid point."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7.0, 4.6), dpi=110)
    scenarios = sorted({r["scenario"] for r in rows})
    markers = "osD^v<>"
    for si, scen in enumerate(scenarios):
        sel = [r for r in rows if r["scenario"] == scen and r.get(error_key) is not None]
        ax.scatter([r["total_s"] for r in sel], [r[error_key] for r in sel], marker=markers[si % len(markers)],
                   label=scen, alpha=0.8)
        for r in sel:
            ax.annotate(",".join(str(r[k]) for k in grid_keys), (r["total_s"], r[error_key]), fontsize=6,
                        xytext=(3, 2), textcoords="offset points")
    ax.set_xlabel("whole chain time (s), both channels, intermediates written")
    ax.set_ylabel(error_key.replace("_", " "))
    ax.set_yscale("log")
    ax.axhline(0.3, color="k", lw=0.7, ls="--")
    ax.legend(fontsize=7)
    ax.set_title("speed against accuracy", fontsize=10)
    _save(fig, path)


def stability_map(path, rows, grid_keys, *, error_key="max_abs_range_error_m"):
    """Worst range error over a two-key grid (one panel per scenario)."""
    plt = _plt()
    k1, k2 = grid_keys
    scenarios = sorted({r["scenario"] for r in rows})
    fig, axes = plt.subplots(1, len(scenarios), figsize=(4.2 * len(scenarios), 3.8), dpi=110, squeeze=False)
    for ax, scen in zip(axes[0], scenarios):
        sel = [r for r in rows if r["scenario"] == scen]
        v1 = list(dict.fromkeys(r[k1] for r in sel))
        v2 = list(dict.fromkeys(r[k2] for r in sel))
        grid = np.full((len(v2), len(v1)), np.nan)
        for r in sel:
            if r.get(error_key) is not None:
                grid[v2.index(r[k2]), v1.index(r[k1])] = r[error_key]
        mesh = ax.imshow(np.log10(grid), origin="lower", aspect="auto", cmap="magma_r")
        ax.set_xticks(range(len(v1)), [str(v) for v in v1], rotation=45, fontsize=7)
        ax.set_yticks(range(len(v2)), [str(v) for v in v2], fontsize=7)
        for (i, j), val in np.ndenumerate(grid):
            if np.isfinite(val):
                ax.text(j, i, f"{val:.2f}", ha="center", va="center", fontsize=6, color="c")
        ax.set_xlabel(k1)
        ax.set_ylabel(k2)
        ax.set_title(scen, fontsize=9)
        fig.colorbar(mesh, ax=ax, label=f"log10 {error_key}")
    _save(fig, path)
