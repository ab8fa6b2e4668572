"""``fwdlook sweep``: grids of runs, summary tables, speed-accuracy chart and stability maps.

A sweep file::

    name: methods
    scenarios: [scenarios/paper_fig5_a0.yaml, scenarios/paper_fig6_a50.yaml]   # relative to the file
    set: ["noise.seed=1"]                        # optional overrides applied to every run
    grid:                                        # every combination is one run
      processing.method: [traditional, decimation, tracking]
      processing.t_ref: [start, centre]

Each grid point is resolved like ``--set`` overrides; a raw cube is simulated once per distinct
simulation (everything but ``processing``) and shared by the runs that process it.  Outputs:
``DIR/<scenario>/<key=value,...>/`` run directories, ``DIR/summary.json``, ``DIR/summary.csv``,
``DIR/summary.md``, ``DIR/speed_accuracy.png`` and, for a two-key grid, ``DIR/stability.png``.
Each run's stage files are deleted once it is summarised (``keep_stages: true`` keeps them).
"""
from __future__ import annotations

import copy
import csv
import io as _io
import itertools
import json
from pathlib import Path

from .config import scenario_hash, yaml_load
from .errors import BadInput

SUMMARY_KEYS = ("detected", "n_targets", "max_abs_range_error_m", "median_abs_range_error_m",
                "rms_range_error_m", "max_abs_azimuth_error_deg", "rms_azimuth_error_deg", "median_islr_db",
                "median_pslr_db", "median_peak_loss_db")


def load_sweep(path: str) -> dict:
    p = Path(path)
    try:
        raw = yaml_load(p.read_text(encoding="utf-8"), str(p))
    except FileNotFoundError:
        raise BadInput(f"{path}: sweep file not found") from None
    if not isinstance(raw, dict):
        raise BadInput(f"{path}: top level: expected a mapping")
    allowed = {"name", "scenarios", "set", "grid", "config", "combine", "keep_stages"}
    extra = sorted(set(raw) - allowed)
    if extra:
        raise BadInput(f"{path}: {extra[0]}: unknown key; allowed: {', '.join(sorted(allowed))}")
    scen = raw.get("scenarios")
    if not isinstance(scen, list) or not scen or not all(isinstance(s, str) for s in scen):
        raise BadInput(f"{path}: scenarios: expected a non-empty list of scenario files")
    grid = raw.get("grid") or {}
    if not isinstance(grid, dict) or not all(isinstance(v, list) and v for v in grid.values()):
        raise BadInput(f"{path}: grid: expected a mapping of key.path to a non-empty list of values")
    sets = raw.get("set") or []
    if not isinstance(sets, list):
        raise BadInput(f"{path}: set: expected a list of KEY.PATH=VALUE strings")
    combine = raw.get("combine") or []
    if not isinstance(combine, list) or any(c not in grid for c in combine):
        raise BadInput(f"{path}: combine: expected a list of grid keys; allowed: {', '.join(grid)}")
    base = p.parent
    return {"name": str(raw.get("name", p.stem)), "scenarios": [str((base / s).resolve()) for s in scen],
            "combine": combine, "keep_stages": bool(raw.get("keep_stages", False)),
            "set": [str(s) for s in sets], "grid": grid,
            "config": str((base / raw["config"]).resolve()) if raw.get("config") else None}


def _label(point: dict) -> str:
    return ",".join(f"{k.split('.')[-1]}={json.dumps(v) if not isinstance(v, str) else v}"
                    for k, v in point.items()) or "base"


def plan_runs(sweep: dict, out_dir: Path) -> list[dict]:
    """Every run of the sweep, resolved (raises BadInput on a bad grid value before anything runs)."""
    from .process import resolve_with_config

    keys = list(sweep["grid"])
    runs = []
    for scen_path in sweep["scenarios"]:
        try:
            raw = yaml_load(Path(scen_path).read_text(encoding="utf-8"), scen_path) or {}
        except FileNotFoundError:
            raise BadInput(f"{scen_path}: scenario file not found") from None
        for values in itertools.product(*(sweep["grid"][k] for k in keys)):
            point = dict(zip(keys, values))
            sets = list(sweep["set"]) + [f"{k}={json.dumps(v)}" for k, v in point.items()]
            scn = resolve_with_config(copy.deepcopy(raw), scen_path, sweep["config"], sets)
            sim_key = scenario_hash({k: v for k, v in scn.items() if k != "processing"})
            runs.append({"scenario": scn["name"], "scenario_path": scen_path, "point": point, "sets": sets,
                         "sim_key": sim_key, "run_dir": str(out_dir / scn["name"] / _label(point)),
                         "resolved": scn})
    return runs


def _simulate(args):
    scn, path = args
    from .io import write_raw

    if scn["kind"] == "isar":
        from .isar import simulate_isar_scenario as sim
    else:
        from .simulate import simulate_scenario as sim
    cube, _ = sim(scn)
    write_raw(path, cube)
    return path


def _process(run):
    import shutil

    from .io import read_raw

    cube = read_raw(run["raw"])
    if run["resolved"]["kind"] == "isar":
        from .isar import process_isar_cube as proc
    else:
        from .process import process_cube as proc
    metrics = proc(cube, run["resolved"], run["run_dir"], quiet=True, png=False)
    if not run["keep_stages"]:
        # a sweep keeps each run's metrics.json, image.h5 and scenario.yaml; its stage files (about
        # 60 MB per paper-size run) would fill a disk over hundreds of runs
        shutil.rmtree(Path(run["run_dir"]) / "stages", ignore_errors=True)
    return row_of(run, metrics)


def row_of(run: dict, metrics: dict) -> dict:
    """One summary row: the point's keys, its summary metrics, its time and run directory."""
    return {"scenario": run["scenario"], **{k: v for k, v in run["point"].items()},
            **{k: metrics["summary"].get(k) for k in SUMMARY_KEYS},
            **{k: metrics["summary"][k] for k in metrics["summary"] if k not in SUMMARY_KEYS},
            "total_s": metrics["timing_s"]["total"], "run_dir": run["run_dir"]}


def run_sweep(path: str, out_dir: str | Path, *, workers: int = 1, quiet: bool = False,
              scheduler: str = "local") -> list[dict]:
    """Run every point (finished ones skipped, failures recorded; ``sweep_exec``), write the summary."""
    from .sweep_exec import execute

    sweep = load_sweep(path)
    rows = execute(sweep, Path(out_dir), workers=workers, quiet=quiet, scheduler=scheduler)
    if sweep["combine"]:
        rows = combine_rows(rows, sweep)
    write_summary(Path(out_dir), sweep, rows)
    return rows


def combine_rows(rows: list[dict], sweep: dict) -> list[dict]:
    """Merge the runs that differ only in the ``combine`` keys: the summary is recomputed over the
    union of their targets (e.g. a lattice processed as interleaved column subsets), times add up."""
    from .evaluate import summarize

    keep = [k for k in sweep["grid"] if k not in sweep["combine"]]
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault((r["scenario"], *(json.dumps(r[k]) for k in keep)), []).append(r)
    out = []
    for members in groups.values():
        failed = [r for r in members if r.get("status") == "failed"]
        if failed:     # a union with a member missing is not the union: the group is failed too
            out.append({"scenario": members[0]["scenario"], **{k: members[0][k] for k in keep},
                        "status": "failed", "error": "; ".join(f"{Path(r['run_dir']).name}: {r['error']}" for r in failed),
                        "runs": len(members), "run_dir": str(Path(members[0]["run_dir"]).parent)})
            continue
        targets = []
        for r in members:
            targets += json.loads((Path(r["run_dir"]) / "metrics.json").read_text())["targets"]
        summary = summarize(targets)
        out.append({"scenario": members[0]["scenario"], **{k: members[0][k] for k in keep},
                    **{k: summary.get(k) for k in SUMMARY_KEYS},
                    **{k: v for k, v in summary.items() if k not in SUMMARY_KEYS},
                    "runs": len(members), "total_s": sum(r["total_s"] for r in members), "status": "ok",
                    "run_dir": str(Path(members[0]["run_dir"]).parent)})
    return out


def _fmt(v, nd=3):
    return "-" if v is None else (f"{v:.{nd}f}" if isinstance(v, float) else str(v))


def write_summary(out: Path, sweep: dict, rows: list[dict]) -> None:
    from .io import atomic_write_text

    atomic_write_text(out / "summary.json", json.dumps({"sweep": sweep["name"], "grid": sweep["grid"],
                                                        "rows": rows}, indent=1))
    cols = list(dict.fromkeys(k for r in rows for k in r))      # union: failed rows have fewer keys
    buf = _io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=cols)
    writer.writeheader()
    writer.writerows(rows)
    atomic_write_text(out / "summary.csv", buf.getvalue())
    keys = [k for k in sweep["grid"] if k not in sweep["combine"]]
    failed = [r for r in rows if r.get("status") == "failed"]
    text = markdown_table(rows, ["scenario", *keys])
    if failed:
        text += "\n**Failed points** (rerun the sweep to retry them; finished points are skipped):\n\n"
        text += "".join(f"- `{r['run_dir']}`: {r['error']}\n" for r in failed)
    atomic_write_text(out / "summary.md", text)
    done = [r for r in rows if r.get("status") != "failed"]
    if done:
        from .plots import speed_accuracy_chart, stability_map

        speed_accuracy_chart(out / "speed_accuracy.png", done, keys)
        if len(keys) == 2:
            stability_map(out / "stability.png", done, keys)


def markdown_table(rows, key_cols) -> str:
    show = [*key_cols, "detected", "max_abs_range_error_m", "median_abs_range_error_m",
            "max_abs_range_error_resolved_m", "rms_azimuth_error_deg", "rms_azimuth_error_resolved_deg",
            "median_islr_db", "total_s"]
    names = {"max_abs_range_error_m": "max abs range error (m)", "median_abs_range_error_m": "median (m)",
             "max_abs_range_error_resolved_m": "max, resolved targets (m)",
             "rms_azimuth_error_deg": "rms azimuth error (deg)", "rms_azimuth_error_resolved_deg": "rms, resolved (deg)",
             "median_islr_db": "median ISLR (dB)", "total_s": "time (s)"}
    heads = [names.get(c, c.split(".")[-1]) for c in show]
    lines = ["| " + " | ".join(heads) + " |", "|" + "---|" * len(show)]
    for r in rows:
        cells = [_fmt(r.get(c), 2 if c.endswith("db") else 3) for c in show]
        if r.get("status") == "failed":
            cells[len(key_cols)] = "FAILED"
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
