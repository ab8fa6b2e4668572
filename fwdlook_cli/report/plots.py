"""Plotting at the edge: quick-look PNGs with labelled axes (matplotlib, Agg backend)."""
from __future__ import annotations

import json

import numpy as np
from ..io.quicklook import _plt, _save


def speed_accuracy_chart(path, rows, grid_keys, *, error_key=None):
    """Processing time against the worst range error, one marker per run, labelled by grid point.

    The error is over the resolved targets when the runs report it (the full-lattice figure is bounded
    below by the image's neighbour mixing, the same for every method), else over all detected ones.  A
    run that missed targets is drawn hollow and labelled with how many (its error is over fewer targets:
    an independent review found a method that found 1 of 3 drawn as the most accurate).
    """
    plt = _plt()
    if error_key is None:
        resolved = any(r.get("max_abs_range_error_resolved_m") is not None for r in rows)
        error_key = "max_abs_range_error_resolved_m" if resolved else "max_abs_range_error_m"
    fig, ax = plt.subplots(figsize=(7.0, 4.6), dpi=110)
    scenarios = sorted({r["scenario"] for r in rows})
    markers = "osD^v<>"
    for si, scen in enumerate(scenarios):
        sel = [r for r in rows if r["scenario"] == scen and r.get(error_key) is not None]
        full = [r for r in sel if not missed_targets(r)]
        part = [r for r in sel if missed_targets(r)]
        dots = ax.scatter([r["total_s"] for r in full], [r[error_key] for r in full],
                          marker=markers[si % len(markers)], label=scen, alpha=0.8)
        ax.scatter([r["total_s"] for r in part], [r[error_key] for r in part], marker=markers[si % len(markers)],
                   facecolors="none", edgecolors=dots.get_facecolor()[:1] if full else None, alpha=0.8,
                   label=None if full else scen)
        for r in sel:
            missed = f" ({missed_targets(r)} missed)" if missed_targets(r) else ""
            ax.annotate(",".join(str(r[k]) for k in grid_keys) + missed, (r["total_s"], r[error_key]), fontsize=6,
                        xytext=(3, 2), textcoords="offset points")

    def why(r):
        return ("no target found" if not r.get("detected") else
                "no resolved target found" if error_key.endswith("_resolved_m") else "no error")

    lost = [",".join(str(r[k]) for k in grid_keys) + f" ({why(r)})" for r in rows if r.get(error_key) is None]
    if lost:          # no error to place on the axis: named under the chart, not dropped without a word
        ax.text(0.0, -0.16, f"not drawn: {'; '.join(lost)}", transform=ax.transAxes, fontsize=7, va="top",
                color="tab:blue")
    ax.set_xlabel("whole chain time (s), both channels, intermediates written")
    ax.set_ylabel(error_key.replace("max_abs_range_error", "max |range error|").replace("_resolved", ", resolved targets")
                  .replace("_m", " (m)").replace("_", " "))
    ax.set_yscale("log")
    from matplotlib.ticker import FuncFormatter

    ax.yaxis.set_major_formatter(FuncFormatter(lambda y, _: f"{y:g}"))
    ax.yaxis.set_minor_formatter(FuncFormatter(lambda y, _: f"{y:g}" if f"{y:.0e}"[0] in "25" else ""))
    ax.axhline(0.3, color="k", lw=0.7, ls="--")
    ax.legend(fontsize=7)
    ax.set_title("speed against accuracy", fontsize=10)
    _save(fig, path)


ERROR_NORM_M = (0.01, 30.0)      # fixed colour limits of the error maps (m): 1 cm to a lattice spacing
_UNIT_WORDS = (("_mps2", "m/s$^2$"), ("_mps", "m/s"), ("_deg", "deg"), ("_hz", "Hz"), ("_db", "dB"), ("_m", "m"),
               ("_s", "s"))


def axis_label(key: str) -> str:
    """``platform.accel_mps2`` -> ``platform accel (m/s^2)``; ``processing.method`` -> ``method``."""
    section, _, name = key.rpartition(".")
    for suffix, unit in _UNIT_WORDS:
        if name.endswith(suffix):
            name = f"{name[: -len(suffix)]} ({unit})"
            break
    name = name.replace("_", " ")
    return name if section in ("", "processing") else f"{section.split('.')[-1]} {name}"


def value_label(value) -> str:
    """A grid value as a tick label: vectors such as accel [0, 50, 0] as 0, 50, 0."""
    if isinstance(value, str):
        try:
            value = json.loads(value)
        except ValueError:
            return value
    if isinstance(value, list):
        return ", ".join(f"{v:g}" if isinstance(v, (int, float)) else str(v) for v in value)
    return f"{value:g}" if isinstance(value, float) else str(value)


def missed_targets(row) -> int:
    """Targets a run's summary row counts and did not detect (0 where it does not say)."""
    n, d = row.get("n_targets"), row.get("detected")
    return int(n) - int(d) if isinstance(n, (int, float)) and isinstance(d, (int, float)) else 0


def error_map(ax, grid, x_labels, y_labels, *, xlabel, ylabel, title, threshold=None, fmt="{:.2f}", missed=None):
    """One panel of errors (m) on a logarithmic colour norm with the fixed limits ERROR_NORM_M; ``missed``
    (the same shape): targets a cell's run did not find, written under its error in a dashed frame."""
    from matplotlib.colors import LogNorm

    plt = _plt()
    cmap = plt.get_cmap("magma_r").with_extremes(bad="0.85")
    norm = LogNorm(*ERROR_NORM_M, clip=True)
    v = np.asarray(grid, dtype=np.float64)
    mesh = ax.imshow(np.where(v > 0, v, np.nan), origin="lower", aspect="auto", cmap=cmap, norm=norm)
    ax.set_xticks(range(len(x_labels)), x_labels, rotation=30 if max(map(len, x_labels), default=0) > 4 else 0,
                  ha="right" if max(map(len, x_labels), default=0) > 4 else "center", fontsize=8)
    ax.set_yticks(range(len(y_labels)), y_labels, fontsize=8)
    for (i, j), val in np.ndenumerate(v):
        lost = 0 if missed is None else int(missed[i][j])
        if not np.isfinite(val) and lost:      # a point that found none of its targets: no error to colour
            ax.text(j, i, f"none found\n{lost} missed", ha="center", va="center", fontsize=7, color="k")
            ax.add_patch(plt.Rectangle((j - 0.45, i - 0.45), 0.9, 0.9, fill=False, ec="tab:blue", lw=1.2, ls="--"))
        if np.isfinite(val):
            dark = norm(min(max(val, ERROR_NORM_M[0]), ERROR_NORM_M[1])) > 0.55
            ax.text(j, i, fmt.format(val) + (f"\n{lost} missed" if lost else ""), ha="center", va="center",
                    fontsize=7, color="w" if dark else "k")
            if lost:
                ax.add_patch(plt.Rectangle((j - 0.45, i - 0.45), 0.9, 0.9, fill=False, ec="tab:blue", lw=1.2,
                                           ls="--"))
            if threshold is not None and val > threshold:
                ax.add_patch(plt.Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, ec="tab:red", lw=1.4))
    ax.set_xlabel(xlabel, fontsize=9)
    ax.set_ylabel(ylabel, fontsize=9)
    ax.set_title(title, fontsize=9)
    return mesh


def error_colorbar(fig, mesh, ax, label):
    from matplotlib.ticker import FixedLocator, FuncFormatter

    cb = fig.colorbar(mesh, ax=ax, label=label, extend="both")
    cb.locator = FixedLocator([0.01, 0.03, 0.1, 0.3, 1, 3, 10, 30])
    cb.formatter = FuncFormatter(lambda x, _: f"{x:g}")
    cb.update_ticks()
    return cb


def stability_map(path, rows, grid_keys, *, error_key="max_abs_range_error_m"):
    """Worst range error (m) over a two-key grid, one panel per scenario, on a logarithmic colour norm
    with fixed limits (ERROR_NORM_M), so that colours mean the same metres on every map; a run that missed
    targets says how many in its cell (its error is over the ones it found)."""
    plt = _plt()
    k1, k2 = grid_keys
    scenarios = sorted({r["scenario"] for r in rows})
    fig, axes = plt.subplots(1, len(scenarios), figsize=(4.6 * len(scenarios) + 0.6, 4.0), dpi=110, squeeze=False)
    for ax, scen in zip(axes[0], scenarios):
        sel = [r for r in rows if r["scenario"] == scen]
        key = lambda v: json.dumps(v)  # noqa: E731  (list values such as accel_mps2 are not hashable)
        v1 = list(dict.fromkeys(key(r[k1]) for r in sel))
        v2 = list(dict.fromkeys(key(r[k2]) for r in sel))
        grid = np.full((len(v2), len(v1)), np.nan)
        missed = np.zeros(grid.shape, dtype=np.int64)
        for r in sel:
            if r.get(error_key) is not None:
                grid[v2.index(key(r[k2])), v1.index(key(r[k1]))] = r[error_key]
            missed[v2.index(key(r[k2])), v1.index(key(r[k1]))] = missed_targets(r)     # (none found too)
        mesh = error_map(ax, grid, [value_label(v) for v in v1], [value_label(v) for v in v2],
                         xlabel=axis_label(k1), ylabel=axis_label(k2), title=scen, missed=missed)
        error_colorbar(fig, mesh, ax, error_key.replace("max_abs_range_error", "max |range error|")
                       .replace("_resolved", ", resolved").replace("_m", " (m)").replace("_", " "))
    _save(fig, path)


# ----------------------------------------------------------------------------------------------
# Report and reproduce figures (fwdlook report, python -m fwdlook_cli.report.reproduce)
# ----------------------------------------------------------------------------------------------
def _db(power, ref, dynamic_range_db):
    p = np.asarray(power, dtype=np.float64)
    return 10 * np.log10(np.maximum(p / max(float(ref), 1e-300), 10 ** (-dynamic_range_db / 10 - 1)))


def image_panels(path, panels, *, ncols=None, dynamic_range_db=40.0, suptitle=None, reference="common",
                 panel_size=(4.6, 3.9)):
    """Several (range, angle) power images side by side in dB on ONE colour scale, atomically.

    ``panels``: dicts with ``power`` [len(y), len(x)], ``x`` (deg or m), ``y`` (m), ``title``, ``xlabel``,
    ``ylabel`` and optional ``markers`` = (x, y) truth positions (open circles).  ``reference="common"``
    puts 0 dB at the brightest pixel of all panels (focusing losses show as darker panels);
    ``"each"`` normalises every panel to its own peak.
    """
    plt = _plt()
    n = len(panels)
    ncols = ncols or n
    nrows = int(np.ceil(n / ncols))
    fig, axes = plt.subplots(nrows, ncols, figsize=(panel_size[0] * ncols + 0.8, panel_size[1] * nrows + 0.4),
                             dpi=110, squeeze=False, layout="constrained")
    common = max((float(np.max(p["power"])) if np.size(p["power"]) else 0.0) for p in panels) or 1.0
    mesh = None
    for ax, p in zip(axes.flat, panels):
        ref = common if reference == "common" else (float(np.max(p["power"])) or 1.0)
        mesh = ax.pcolormesh(p["x"], p["y"], _db(p["power"], ref, dynamic_range_db), shading="nearest",
                             vmin=-dynamic_range_db, vmax=0, cmap="viridis", rasterized=True)
        if p.get("markers") is not None:
            ax.plot(p["markers"][0], p["markers"][1], "o", mfc="none", mec="w", ms=5, mew=0.7, label="truth")
            ax.legend(loc="upper right", fontsize=6)
        ax.set_xlabel(p.get("xlabel", "azimuth at t_ref (deg)"), fontsize=8)
        ax.set_ylabel(p.get("ylabel", "slant range at t_ref (m)"), fontsize=8)
        ax.set_title(p.get("title", ""), fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[n:]:
        ax.set_visible(False)
    if mesh is not None:
        label = "dB re brightest pixel of all panels" if reference == "common" else "dB re panel peak"
        fig.colorbar(mesh, ax=axes, label=label, shrink=0.85)
    if suptitle:
        fig.suptitle(suptitle, fontsize=10)
    from ..io.outputs import atomic_path
    from ..io.quicklook import quiet_missing_glyphs

    try:
        with atomic_path(path) as tmp, quiet_missing_glyphs():
            fig.savefig(tmp, bbox_inches="tight")
    finally:
        plt.close(fig)


def range_profile_panels(path, panels, *, xlabel="slant range at t_ref (m)", floor_db=-40.0, suptitle=None):
    """Normalised range profiles (paper Fig. 7 style), one axes per panel, atomically.

    ``panels``: dicts with ``title``, ``curves`` (dicts with ``x``, ``amplitude`` (linear, any scale;
    each curve is normalised to its own peak), ``label``, optional ``color``/``ls``) and ``truth``
    (a list of ranges drawn as vertical dashed lines).
    """
    plt = _plt()
    fig, axes = plt.subplots(1, len(panels), figsize=(5.6 * len(panels), 4.0), dpi=110, squeeze=False)
    for ax, p in zip(axes[0], panels):
        for c in p["curves"]:
            a = np.asarray(c["amplitude"], dtype=np.float64)
            db = 20 * np.log10(np.maximum(a / max(float(a.max()), 1e-300), 10 ** (floor_db / 20)))
            ax.plot(c["x"], db, label=c["label"], color=c.get("color"), ls=c.get("ls", "-"), lw=1.2)
        for i, r in enumerate(p.get("truth") or []):
            ax.axvline(r, color="k", ls="--", lw=0.8, label="truth" if i == 0 else None)
        ax.set_ylim(floor_db, 3)
        ax.set_xlabel(xlabel)
        ax.set_ylabel("normalised amplitude (dB)")
        ax.set_title(p.get("title", ""), fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="lower center")
    if suptitle:
        fig.suptitle(suptitle, fontsize=10)
    _save(fig, path)


def error_scatter(path, series, *, title=None):
    """Range error (m) and azimuth error (deg) per target against ground x, one series per run."""
    plt = _plt()
    fig, (ax_r, ax_a) = plt.subplots(2, 1, figsize=(7.5, 6.0), dpi=110, sharex=True)
    markers = "os^vD<>px*"
    for i, s in enumerate(series):
        m = markers[i % len(markers)]
        ax_r.plot(s["x_m"], s["range_error_m"], m, ms=4, alpha=0.75, label=s["label"])
        ax_a.plot(s["x_m"], s["azimuth_error_deg"], m, ms=4, alpha=0.75, label=s["label"])
    for ax in (ax_r, ax_a):
        ax.axhline(0.0, color="k", lw=0.6)
        ax.grid(alpha=0.3)
    ax_r.set_ylabel("range error at t_ref (m)")
    ax_a.set_ylabel("azimuth error at t_ref (deg)")
    ax_a.set_xlabel("target ground x (m)")
    ax_r.legend(fontsize=7)
    if title:
        ax_r.set_title(title, fontsize=10)
    _save(fig, path)


def grid_heatmap(path, values, row_labels, col_labels, *, xlabel, ylabel, title, cbar_label,
                 threshold=None, fmt="{:.2f}"):
    """A labelled grid of positive values on a log colour scale, the value printed in each cell.

    ``values`` [len(row_labels), len(col_labels)], NaN where missing (drawn blank).  Cells above
    ``threshold`` (e.g. half a range cell) get a red frame: the method broke down there.
    """
    plt = _plt()
    fig, ax = plt.subplots(figsize=(1.1 * len(col_labels) + 2.9, 0.55 * len(row_labels) + 1.8), dpi=110)
    mesh = error_map(ax, values, [str(c) for c in col_labels], [str(r) for r in row_labels], xlabel=xlabel,
                     ylabel=ylabel, title=title, threshold=threshold, fmt=fmt)
    error_colorbar(fig, mesh, ax, cbar_label)
    _save(fig, path)
