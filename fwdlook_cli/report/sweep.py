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

import csv
import io as _io
import json
from pathlib import Path

from .sweep_plan import SUMMARY_KEYS, _fmt, load_sweep  # noqa: F401  (load_sweep: the CLI's entry)



def run_sweep(path: str, out_dir: str | Path, *, workers: int = 1, quiet: bool = False,
              scheduler: str = "local", overwrite: bool = False) -> list[dict]:
    """Run every point (finished ones skipped, failures recorded; ``sweep_exec``), write the summary.
    The output folder is checked first (``io.outputs.prepare_sweep_dir``): a folder holding summary
    files that fwdlook did not write is refused unless ``overwrite``."""
    from ..io.outputs import folder_lock, prepare_sweep_dir
    from .sweep_exec import execute
    from .sweep_plan import check_point_folders, plan_runs

    sweep = load_sweep(path)
    # every point resolved and its folder checked before anything is made (a refusal changes nothing)
    check_point_folders(plan_runs(sweep, Path(out_dir), source=sweep["source"]), overwrite=overwrite)
    out_dir = prepare_sweep_dir(out_dir, overwrite=overwrite)
    with folder_lock(out_dir, "sweep folder"):      # a second sweep into it is refused, not interleaved
        rows = execute(sweep, Path(out_dir), workers=workers, quiet=quiet, scheduler=scheduler)
        if sweep["combine"]:
            rows = combine_rows(rows, sweep)
        write_summary(Path(out_dir), sweep, rows)
    return rows


def combine_rows(rows: list[dict], sweep: dict) -> list[dict]:
    """Merge the runs that differ only in the ``combine`` keys: the summary is recomputed over the
    union of their targets (e.g. a lattice processed as interleaved column subsets), times add up."""
    from ..forward.evaluate import summarize

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


def write_summary(out: Path, sweep: dict, rows: list[dict]) -> None:
    from ..io.h5 import atomic_write_text

    atomic_write_text(out / "summary.json", json.dumps({"sweep": sweep["name"], "grid": sweep["grid"],
                                                        "combine": sweep["combine"], "rows": rows}, indent=1))
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
        if r.get("n_resolved") is not None and r.get("n_resolved") == r.get("n_targets"):   # every target
            r = {**r, "max_abs_range_error_resolved_m": r.get("max_abs_range_error_m"),       # resolved: the
                 "rms_azimuth_error_resolved_deg": r.get("rms_azimuth_error_deg")}             # same figures
        cells = [_fmt(r.get(c), 2 if c.endswith("db") else 3) for c in show]
        if isinstance(r.get("detected"), int) and isinstance(r.get("n_targets"), int):   # found of counted
            cells[show.index("detected")] = f"{r['detected']}/{r['n_targets']}"
        if r.get("status") == "failed":
            cells[len(key_cols)] = "FAILED"
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
