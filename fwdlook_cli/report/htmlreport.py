"""``fwdlook report`` as one self-contained ``index.html`` (figures embedded as base64 PNG).

Beside report.md and its PNGs, the report directory gets ``index.html``: no external file, script or
style sheet, so it can be mailed or archived as one file.  It shows, in order: the runs at a glance
(every number read from each run's metrics.json), the figures of :func:`report.write_figures`, the
ground-plane (x, y) image of each forward-looking run with its truth, the ISAR figures of each ISAR run
(the raw echo before and after the range-migration correction and the ISAR image, as
``isar.save_isar_figures`` and ``make reproduce`` draw them, from the run's own files), the stability
map and speed-accuracy chart of each sweep directory given, and each run's full summary table.
"""
from __future__ import annotations

import base64
import html
import json
import logging
import math
import re
from pathlib import Path

import numpy as np

from ..errors import BadInput

log = logging.getLogger(__name__)

GROUND_MARGIN_M = 40.0


def is_sweep_dir(path) -> bool:
    p = Path(path)
    return (p / "summary.json").is_file() and not (p / "metrics.json").exists()


def _slug(label: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", label).strip("_") or "run"


# ----------------------------------------------------------------------------------------------
# Figures the Markdown report does not draw
# ----------------------------------------------------------------------------------------------
def ground_figure(run, out: Path) -> tuple[str | None, str]:
    """The run's ground-plane (x, y) image with truth markers; (file name or None, note)."""
    import h5py

    from .plots import image_panels
    from ..io.describe import checked_axis, checked_grid

    path = Path(run.path) / "image.h5"
    with h5py.File(path, "r") as f:
        if not all(isinstance(f.get(k), h5py.Dataset) for k in ("ground_image", "ground_x_m", "ground_y_m")):
            return None, f"{path}: no /ground_image; ground-plane figure skipped"
        gx, gy = checked_axis(f, path, "ground_x_m"), checked_axis(f, path, "ground_y_m")
        img = checked_grid(f, path, "ground_image", "ground_y_m", "ground_x_m")
    targets = run.metrics.get("targets") or []
    markers = None
    if targets:
        tx, ty = np.array([t["x_m"] for t in targets]), np.array([t["y_m"] for t in targets])
        markers = (tx, ty)
        xi = (gx >= tx.min() - GROUND_MARGIN_M) & (gx <= tx.max() + GROUND_MARGIN_M)
        yi = (gy >= ty.min() - GROUND_MARGIN_M) & (gy <= ty.max() + GROUND_MARGIN_M)
        if xi.any() and yi.any():
            img, gx, gy = img[np.ix_(yi, xi)], gx[xi], gy[yi]
    name = f"ground_{_slug(run.label)}.png"
    image_panels(out / name, [{"power": img, "x": gx, "y": gy, "markers": markers,
                               "xlabel": "ground cross-range x (m)", "ylabel": "ground forward y (m)",
                               "title": f"{run.label}: monopulse image on the ground plane"}],
                 reference="each", panel_size=(6.0, 4.6), suptitle="ground plane (x, y), truth: open circles")
    return name, ""


def isar_figures(run, out: Path) -> tuple[dict, list[str]]:
    """The raw echo before/after the correction and the ISAR image of an ISAR run, from its files."""
    from ..isar.process import _save_image_quicklook
    from ..io.stagefile import read_stage, stage_file_key
    from ..io.quicklook import save_image_png

    figs, notes = {}, []
    run_dir = Path(run.path)
    slug = _slug(run.label)
    corr = (run.metrics.get("params") or {}).get("correction", run.metrics.get("method"))
    stages = sorted((run_dir / "stages").glob("*_azimuth_compress.h5"))
    if stages and stage_file_key(stages[-1]) != (run.metrics.get("stage_sha256") or {}).get("azimuth_compress"):
        stages = []            # of a later run that failed after it: the outputs are the earlier run's
    final = read_stage(stages[-1]) if stages else None
    raw = run_dir / "raw.h5"
    max_columns = 1000
    if raw.exists() and final is not None and "echo_rc" in final:
        from ..io.raw import read_raw

        cube = read_raw(raw)
        step = max(1, cube.n_pulses // max_columns)
        for tag, echo, what in (("before", cube.sum, "before"), ("after", final["echo_rc"], f"after {corr}")):
            name = f"isar_{slug}_echo_{tag}.png"
            save_image_png(out / name, np.abs(echo[::step]).T.astype(np.float64) ** 2, cube.slow_time_s[::step],
                           cube.range_m, xlabel="slow time (s)", ylabel="slant range (m)",
                           title=f"{run.label}: raw echo {what} range-migration compensation", dynamic_range_db=40)
            figs[name] = (f"`{run.label}`: raw echo (range x slow time) {what} range-migration compensation "
                          f"(paper Fig. 3-6)")
    else:
        notes.append(f"{run_dir}: no raw.h5 or no stage files (pruned by a sweep?): ISAR echo figures skipped")
    image = read_stage(run_dir / "image.h5")
    if "image" in image and "doppler_hz" in image:
        name = f"isar_{slug}_image.png"
        _save_image_quicklook(out / name, image, title=f"{run.label}: ISAR image, {corr}")
        figs[name] = f"`{run.label}`: ISAR image (range x cross-range), {corr}"
    return figs, notes


def read_sweep_summary(sweep_dir) -> dict:
    """A sweep folder's summary.json, checked for what the report draws from it (an object with its
    ``grid`` and ``rows``; each finished row with its scenario, grid values, time and worst range
    error); BadInput in one line naming the file and the key otherwise."""
    from ..io.describe import read_json_text
    from ..limits import shown
    from .tables import is_number

    path = Path(sweep_dir) / "summary.json"
    summary = read_json_text(path)
    if not isinstance(summary, dict) or not isinstance(summary.get("rows"), list) \
            or not isinstance(summary.get("grid"), dict):
        raise BadInput(f"{path}: expected a sweep summary written by fwdlook sweep (an object with grid and "
                       f"rows)")
    for i, row in enumerate(summary["rows"]):
        if not isinstance(row, dict) or not isinstance(row.get("scenario"), str):
            raise BadInput(f"{path}: rows[{i}]: expected an object with its scenario's name")
        if row.get("status") == "failed":
            continue
        for key in ("total_s", "max_abs_range_error_m"):
            value = row.get(key)
            if (value is not None or key == "total_s") and not (is_number(value) and math.isfinite(value)):
                raise BadInput(f"{path}: rows[{i}].{key} = {shown(value)}: expected a number")
        combined = summary.get("combine") if isinstance(summary.get("combine"), list) else []
        missing = [k for k in summary["grid"] if k not in row and k not in combined]   # (combined: merged away)
        if missing:
            raise BadInput(f"{path}: rows[{i}]: the grid key {missing[0]} is missing")
    return summary


def sweep_figures(sweep_dir: Path, out: Path, summary: dict | None = None) -> tuple[dict, list[dict], list[str]]:
    """Redraw a sweep's stability map and speed-accuracy chart from its summary.json (``summary``:
    already read by :func:`read_sweep_summary`)."""
    from .plots import speed_accuracy_chart, stability_map

    summary = read_sweep_summary(sweep_dir) if summary is None else summary
    rows = [r for r in summary.get("rows", []) if r.get("status") != "failed"]
    keys = [k for k in summary.get("grid", {}) if rows and k in rows[0]]
    slug = _slug(sweep_dir.name)
    figs = {}
    if rows:
        name = f"sweep_{slug}_speed_accuracy.png"
        speed_accuracy_chart(out / name, rows, keys)
        figs[name] = f"sweep `{sweep_dir.name}`: processing time against the worst range error"
        if len(keys) == 2:
            name = f"sweep_{slug}_stability.png"
            stability_map(out / name, rows, keys)
            figs[name] = (f"sweep `{sweep_dir.name}`: max |range error| over {keys[0]} x {keys[1]}, logarithmic "
                          f"colours with fixed limits (m)")
    return figs, summary.get("rows", []), keys


def extra_figures(runs, out: Path) -> tuple[dict, list[str]]:
    """Ground-plane figures of the forward runs and the ISAR figures of the ISAR runs."""
    figs, notes = {}, []
    for run in runs:
        if run.image is not None:
            name, note = ground_figure(run, out)
            if name:
                figs[name] = f"`{run.label}`: monopulse image projected on the ground (x, y), truth as open circles"
            if note:
                notes.append(note)
        elif "migration_span_cells" in (run.metrics.get("summary") or {}):
            more, more_notes = isar_figures(run, out)
            figs.update(more)
            notes += more_notes
    return figs, notes


# ----------------------------------------------------------------------------------------------
# The page
# ----------------------------------------------------------------------------------------------
STYLE = """
body{font:15px/1.45 system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:0;color:#1d2430;background:#f6f7f9}
header{background:#1d2b44;color:#fff;padding:14px 28px}header h1{margin:0;font-size:22px}
header p{margin:4px 0 0;color:#c9d3e6;font-size:13px}main{padding:8px 28px 40px;max-width:1400px}
h2{font-size:18px;border-bottom:1px solid #d5d9e0;padding-bottom:4px;margin-top:28px}
table{border-collapse:collapse;background:#fff;font-size:13px;margin:6px 0}
th,td{border:1px solid #d5d9e0;padding:3px 8px;text-align:right}th{background:#eef1f5}
td:first-child,th:first-child{text-align:left}figure{background:#fff;border:1px solid #d5d9e0;margin:10px 0;
padding:8px;display:inline-block;max-width:100%}figure img{max-width:100%;height:auto}
figcaption{font-size:13px;color:#4a5568;max-width:900px}nav a{margin-right:14px}code{font-size:12px}
details{margin:8px 0}.bad{color:#b00020;font-weight:600}.note{color:#7a5b00}
"""

CHECK_SCRIPT = """
window.addEventListener('load', function () {
  var imgs = document.images, ok = 0;
  for (var i = 0; i < imgs.length; i++) { if (imgs[i].complete && imgs[i].naturalWidth > 0) ok++; }
  document.body.setAttribute('data-images', String(imgs.length));
  document.body.setAttribute('data-images-decoded', String(ok));
});
"""


def _e(text) -> str:
    return html.escape(str(text), quote=True)


def _table(heads, rows) -> str:
    out = ["<table><thead><tr>" + "".join(f"<th>{_e(h)}</th>" for h in heads) + "</tr></thead><tbody>"]
    for row in rows:
        out.append("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>")
    return "".join(out) + "</tbody></table>"


def _num(value, nd) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.{nd}f}" if np.isfinite(value) else "nan"
    return _e(value)


def glance_rows(runs) -> list[list[str]]:
    rows = []
    for r in runs:
        s, p = r.metrics.get("summary") or {}, r.metrics.get("params") or {}
        isar = "migration_span_cells" in s
        rows.append([f"<code>{_e(r.label)}</code>", _e(r.metrics.get("scenario", "")), _e(r.metrics["method"]),
                     _e(p.get("t_ref", "-")), f"{s.get('detected', '-')}/{s.get('n_targets', '-')}",
                     _num(s.get("max_abs_range_error_m"), 2), _num(s.get("max_abs_range_error_resolved_m"), 2),
                     _num(s.get("rms_azimuth_error_deg"), 3),
                     _num(s.get("migration_span_cells"), 2) if isar else "-",
                     _num(s.get("integration_gain_db"), 2) if isar else "-",
                     _num((r.metrics.get("timing_s") or {}).get("total"), 2)])
    return rows


GLANCE_HEADS = ("run", "scenario", "method", "t_ref", "detected", "max |range error| (m)",
                "max, resolved (m)", "rms azimuth error (deg)", "ISAR migration span (cells)",
                "ISAR integration gain (dB)", "time (s)")


def _figure(out: Path, name: str, caption: str) -> str:
    data = base64.b64encode((out / name).read_bytes()).decode("ascii")
    cap = re.sub(r"`([^`]+)`", r"<code>\1</code>", _e(caption))
    return (f'<figure id="{_e(name)}"><img alt="{_e(name)}" src="data:image/png;base64,{data}">'
            f"<figcaption><b>{_e(name)}</b>: {cap}</figcaption></figure>")


def render_html(runs, figures: dict, notes: list[str], out: Path, sweeps=()) -> str:
    from .. import __version__
    from .tables import fmt_value, summary_rows

    n = len(runs)
    parts = [f"<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>fwdlook report</title>"
             f"<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\"><style>{STYLE}</style>"
             f"<script>{CHECK_SCRIPT}</script></head><body>",
             f"<header><h1>fwdlook report</h1><p>{n} run{'s' if n != 1 else ''}"
             f"{f', {len(sweeps)} sweep(s)' if sweeps else ''}; fwdlook {__version__}; every number is read from "
             f"the run's metrics.json (CONTRACT.md section 5)</p></header><main>",
             "<nav>" + "".join(f'<a href="#{a}">{t}</a>' for a, t, shown in (
                 ("glance", "runs", runs), ("figures", "figures", figures), ("sweeps", "sweeps", sweeps),
                 ("details", "details", runs)) if shown) + "</nav>"]
    if runs:
        parts += ['<h2 id="glance">Runs at a glance</h2>', _table(GLANCE_HEADS, glance_rows(runs))]
    if figures:
        parts.append('<h2 id="figures">Figures</h2>')
        parts += [_figure(out, name, cap) for name, cap in figures.items()]
    if sweeps:
        parts.append('<h2 id="sweeps">Sweeps</h2>')
        for sweep_dir, figs, rows, keys in sweeps:
            parts.append(f"<h3>{_e(Path(sweep_dir).name)}</h3>")
            heads = ["scenario", *keys, "detected", "max |range error| (m)", "max, resolved (m)",
                     "rms azimuth error (deg)", "time (s)", "status"]
            body = [[_e(r.get("scenario")), *[_e(json.dumps(r.get(k)) if not isinstance(r.get(k), str) else r.get(k))
                                             for k in keys],
                     f"{r.get('detected', '-')}/{r.get('n_targets', '-')}", _num(r.get("max_abs_range_error_m"), 2),
                     _num(r.get("max_abs_range_error_resolved_m"), 2), _num(r.get("rms_azimuth_error_deg"), 3),
                     _num(r.get("total_s"), 2),
                     _e(r.get("status", "ok")) if r.get("status") != "failed"
                     else f'<span class="bad">failed: {_e(r.get("error", ""))}</span>'] for r in rows]
            parts.append(_table(heads, body))
            parts += [_figure(out, name, cap) for name, cap in figs.items()]
    if runs:
        parts.append('<h2 id="details">Each run in full</h2>')
        for r in runs:
            parts.append(f"<details><summary>run <code>{_e(r.label)}</code> (<code>{_e(r.path)}</code>)</summary>"
                         + _table(["key", "value"], [[_e(k), _e(v)] for k, v in summary_rows(r.metrics)]))
            timing = r.metrics.get("timing_s") or {}
            parts.append(_table(["stage", "time (s)"], [[_e(k), _e(fmt_value(v))] for k, v in timing.items()])
                         + "</details>")
    if notes:
        parts.append("<h2>Notes</h2><ul>" + "".join(f'<li class="note">{_e(x)}</li>' for x in notes) + "</ul>")
    parts.append("</main></body></html>\n")
    return "\n".join(parts)


def write_html(path: Path, runs, figures: dict, notes: list[str], sweep_dirs=(), summaries=None) -> Path:
    """index.html; ``summaries``: {sweep folder: its summary.json, read by :func:`read_sweep_summary`}."""
    from ..io.h5 import atomic_write_text

    out = Path(path).parent
    sweeps = []
    for d in sweep_dirs:
        figs, rows, keys = sweep_figures(Path(d), out, (summaries or {}).get(d))
        sweeps.append((d, figs, rows, keys))
    atomic_write_text(path, render_html(runs, figures, notes, out, sweeps))
    log.debug("wrote %s", path)
    return Path(path)
