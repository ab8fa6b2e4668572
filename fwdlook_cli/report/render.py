"""Rendering the reproduction: markdown tables and figures from the files the runs wrote (``metrics.json``,
``summary.json``, ``sec41.json``), never from typed numbers."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from .experiments import PAPER_CLAIMS
from .tables import md_table


def _fmt(v, nd=3) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "nan" if not math.isfinite(v) else f"{v:.{nd}f}"
    return str(v)


def _read_json(path: Path):
    return json.loads(Path(path).read_text(encoding="utf-8"))


def render_sec41(rows: list[dict]) -> str:
    return md_table(["quantity", "paper", "ours", "unit", "paper's source", "ours from"],
                    [[r["quantity"], _fmt(r["paper"], 1) if r["paper"] is not None else "not given",
                      _fmt(r["ours"], 3), r["unit"] or "-", r["source"], f"`geometry.{r['how']}`"
                      if not r["how"].startswith("h =") else r["how"]] for r in rows])


# ----------------------------------------------------------------------------------------------
# Running panels (b, c) in parallel
# ----------------------------------------------------------------------------------------------
def half_range_cell_m(run_dir: Path) -> float:
    """Half the range resolution c / (2 B) of the run's scenario (the paper's accuracy criterion)."""
    from ..scenario.yamlio import yaml_load
    from ..dsp.geometry import C_MPS

    scn = yaml_load((Path(run_dir) / "scenario.yaml").read_text(encoding="utf-8"), str(run_dir))
    return C_MPS / (2.0 * float(scn["radar"]["bandwidth_hz"])) / 2.0


def accel_of(run_dir: Path) -> float:
    from ..scenario.yamlio import yaml_load

    scn = yaml_load((Path(run_dir) / "scenario.yaml").read_text(encoding="utf-8"), str(run_dir))
    return float(scn["platform"]["accel_mps2"][1])


def verdict(expect: str, max_err_m, half_cell_m: float) -> str:
    if max_err_m is None:
        return "no detections"
    ok = max_err_m <= half_cell_m
    if expect == "accurate":
        return "holds" if ok else f"does not hold (> {half_cell_m:.2f} m)"
    return "holds" if not ok else f"does not hold (all within {half_cell_m:.2f} m)"


def panel_rows(runs: dict, panel_ids, t_refs) -> list[list[str]]:
    rows = []
    for t_ref in t_refs:
        for pid in panel_ids:
            run_dir = runs[(pid, t_ref)]
            m = _read_json(run_dir / "metrics.json")
            s, p = m["summary"], m["params"]
            claim = PAPER_CLAIMS["panels"][pid]
            half = half_range_cell_m(run_dir)
            rows.append([claim["figure"], t_ref, _fmt(accel_of(run_dir), 0), m["method"],
                         _fmt(p.get("q")), "on" if p.get("range_curvature") else "off",
                         _fmt(p.get("ambiguity_number")), f"{s['detected']}/{s['n_targets']}",
                         _fmt(s.get("max_abs_range_error_m")), _fmt(s.get("median_abs_range_error_m")),
                         _fmt(s.get("rms_azimuth_error_deg")), claim["claim"],
                         verdict(claim["expect"], s.get("max_abs_range_error_m"), half)])
    return rows


def panel_figure(path: Path, runs: dict, panel_ids, t_ref: str, title: str, ncols: int) -> None:
    from .plots import image_panels
    from .report import crop_image, read_image, truth_markers

    panels = []
    for pid in panel_ids:
        run_dir = runs[(pid, t_ref)]
        m = _read_json(run_dir / "metrics.json")
        image, _ = read_image(run_dir)
        power, ang, rng = crop_image(image, m)
        p = m["params"]
        panels.append({"power": power, "x": ang, "y": rng, "markers": truth_markers(m),
                       "title": f"({pid}) a = {accel_of(run_dir):g} m/s$^2$: {m['method']}"
                                f"{' Q=' + str(p['q']) if m['method'] == 'decimation' else ''}, curvature "
                                f"{'on' if p['range_curvature'] else 'off'}\nmax |range err| "
                                f"{_fmt(m['summary']['max_abs_range_error_m'], 2)} m"})
    image_panels(path, panels, ncols=ncols, suptitle=title)


# ----------------------------------------------------------------------------------------------
# c. Fig. 7
# ----------------------------------------------------------------------------------------------
def fig7(out: Path, runs: dict, t_ref: str) -> list[list[str]]:
    """Fig. 7 profiles (a = 50) for one t_ref: the figure and its table rows (from metrics.json)."""
    from .plots import range_profile_panels
    from .report import Run, nearest_target, profile_through_target, read_image

    xy = PAPER_CLAIMS["fig7"]["target_xy_m"]["value"]
    curves, rows = {}, []
    for pid in ("6B", "6D", "6F"):
        run_dir = runs[(pid, t_ref)]
        m = _read_json(run_dir / "metrics.json")
        image, _ = read_image(run_dir)
        r, a, target = profile_through_target(Run(run_dir, pid, m, image), xy)
        curves[pid] = (r, a, target)
        t = nearest_target(m, xy)
        claim = PAPER_CLAIMS["fig7"][pid]
        rows.append([claim["curve"], f"6{pid[1]}", t_ref, f"({t['x_m']:g}, {t['y_m']:g})",
                     _fmt(t.get("range_error_m"), 2), claim["displacement_text"],
                     _fmt(t.get("islr_db"), 2), _fmt(t.get("image_islr_db"), 2), _fmt(claim["islr_db"], 2),
                     _fmt(t.get("pslr_db"), 2),
                     _fmt(t.get("range_width_3db_m"), 2), "yes" if t.get("detected") else "no"])
    truth = [curves["6F"][2]["true_range_m"]] if curves["6F"][2] else []

    def curve(pid, label, color):
        r, a, _ = curves[pid]
        return {"x": r, "amplitude": a, "label": label, "color": color}

    range_profile_panels(out / f"fig7_{t_ref}.png", [
        {"title": "(A) traditional against decimation (a = 50)",
         "curves": [curve("6B", "traditional (6B)", "tab:red"), curve("6F", "decimation + curvature (6F)", "tab:blue")],
         "truth": truth},
        {"title": "(B) decimation without / with curvature compensation",
         "curves": [curve("6D", "decimation, no curvature (6D)", "tab:red"),
                    curve("6F", "decimation + curvature (6F)", "tab:blue")], "truth": truth}],
        suptitle=f"Fig. 7: range profile of the target at (x, y) = ({xy[0]:g}, {xy[1]:g}) m, t_ref = {t_ref}, "
                 f"interpolated x{PAPER_CLAIMS['fig7']['interpolation']['value']}")
    return rows


# ----------------------------------------------------------------------------------------------
# d, e. Sweeps
# ----------------------------------------------------------------------------------------------
def member_run_dir(row: dict) -> Path | None:
    """A run directory behind a summary row: the row's own, or (a sweep with ``combine``) its first member."""
    d = Path(row["run_dir"])
    if (d / "metrics.json").exists():
        return d
    members = sorted(d.glob("*/metrics.json"))
    return members[0].parent if members else None


def methods_table(summary_path: Path) -> str:
    """methods_table.md: the numbers from the sweep's summary.json, the method, Q, t_ref and a_y from
    the runs' own metrics.json and scenario.yaml."""
    rows_in = _read_json(summary_path)["rows"]
    claim_of = {("traditional", 0.0): "5A", ("decimation", 0.0): "5B", ("traditional", 10.0): "6A",
                ("traditional", 50.0): "6B", ("decimation", 10.0): "6E", ("decimation", 50.0): "6F"}
    resolved = any(r.get("max_abs_range_error_resolved_m") is not None for r in rows_in)
    keyed = []
    for r in rows_in:
        run_dir = member_run_dir(r)
        if run_dir is None:
            continue
        keyed.append((accel_of(run_dir), r, _read_json(run_dir / "metrics.json"), run_dir))
    keyed.sort(key=lambda k: k[0])                       # stable: grid order within an acceleration
    rows = []
    for a, r, m, run_dir in keyed:
        method = m["method"]
        pid = claim_of.get((method, a))
        claim = PAPER_CLAIMS["panels"][pid] if pid else None
        row = [_fmt(a, 0), method + (f" (Q={m['params']['q']})" if method == "decimation" else ""),
               m["params"]["t_ref"], _fmt(r.get("max_abs_range_error_m")), _fmt(r.get("median_abs_range_error_m"))]
        if resolved:
            row.append(_fmt(r.get("max_abs_range_error_resolved_m")))
        row += [_fmt(r.get("rms_azimuth_error_deg")), f"{r.get('detected')}/{r.get('n_targets')}",
                _fmt(r.get("total_s"), 2), f"{claim['figure']}: {claim['expect']}" if claim else "-",
                verdict(claim["expect"], r.get("max_abs_range_error_m"), half_range_cell_m(run_dir))
                if claim else "-"]
        rows.append(row)
    heads = ["a_y (m/s^2)", "method", "t_ref", "max abs range error (m)", "median abs range error (m)"]
    if resolved:
        heads.append("max abs range error, resolved targets (m)")
    heads += ["rms azimuth error (deg)", "detected", "chain time (s)", "paper's claim", "claim holds?"]
    return md_table(heads, rows)


def _grid_values(rows, key):
    return list(dict.fromkeys(json.dumps(r[key]) for r in rows))


def breakdown(summary_path: Path, png: Path, *, row_key: str, col_key: str, row_name: str, title: str):
    """A stability map (rows x a_y) of max |range error| from summary.json; returns (markdown, lines)."""
    from .plots import grid_heatmap

    rows_in = _read_json(summary_path)["rows"]
    rvals = _grid_values(rows_in, row_key)
    cvals = _grid_values(rows_in, col_key)
    grid = np.full((len(rvals), len(cvals)), np.nan)
    det = [["-"] * len(cvals) for _ in rvals]
    half = None
    # the resolved targets' error where the runs report it: the full lattice's is bounded below by
    # the image's neighbour mixing near boresight, the same for every method
    resolved = any(r.get("max_abs_range_error_resolved_m") is not None for r in rows_in)
    key, det_key, n_key = (("max_abs_range_error_resolved_m", "detected_resolved", "n_resolved") if resolved
                           else ("max_abs_range_error_m", "detected", "n_targets"))
    for r in rows_in:
        i, j = rvals.index(json.dumps(r[row_key])), cvals.index(json.dumps(r[col_key]))
        if r.get(key) is not None:
            grid[i, j] = r[key]
        det[i][j] = f"{r.get(det_key) or 0}/{r.get(n_key) or 0}"     # (a point with no resolved target: 0/0)
        run_dir = member_run_dir(r)
        if run_dir is not None:
            half = half_range_cell_m(run_dir)
    if half is None:
        half = math.inf
    col_labels = [f"{json.loads(c)[1]:g}" if col_key.endswith("accel_mps2") else json.loads(c) for c in cvals]
    row_labels = [json.loads(v) for v in rvals]
    grid_heatmap(png, grid, row_labels, col_labels, xlabel="platform forward acceleration a_y (m/s^2)",
                 ylabel=row_name, title=title, cbar_label="max |range error| (m)", threshold=half)
    table = md_table([f"{row_name} \\ a_y (m/s^2)", *map(str, col_labels)],
                     [[str(row_labels[i])] + [f"{_fmt(grid[i, j] if np.isfinite(grid[i, j]) else None, 2)} "
                                              f"({det[i][j]})" for j in range(len(cvals))]
                      for i in range(len(rvals))])
    lines = []
    for i, rv in enumerate(row_labels):
        bad = [col_labels[j] for j in range(len(cvals)) if np.isfinite(grid[i, j]) and grid[i, j] > half]
        good = [col_labels[j] for j in range(len(cvals)) if np.isfinite(grid[i, j]) and grid[i, j] <= half]
        if not bad:
            lines.append(f"{row_name} {rv}: within half a range cell ({half:.2f} m) at every a_y tried "
                         f"({', '.join(map(str, good))}).")
        else:
            lines.append(f"{row_name} {rv}: over half a range cell ({half:.2f} m) at a_y = {', '.join(map(str, bad))}"
                         f"{'; within at ' + ', '.join(map(str, good)) if good else ''}.")
    return table, lines


# ----------------------------------------------------------------------------------------------
# f. ISAR
# ----------------------------------------------------------------------------------------------
