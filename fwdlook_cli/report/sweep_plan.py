"""Sweep points: reading a sweep file, planning its runs, one point simulated and processed, its summary row."""
from __future__ import annotations

import copy
import hashlib
import itertools
import json
from pathlib import Path

from ..errors import BadInput
from ..limits import shown
from ..scenario.fields import folder_name
from ..scenario.loader import scenario_hash
from ..scenario.readers import read_scenario_raw, read_yaml_file

SUMMARY_KEYS = ("detected", "n_targets", "max_abs_range_error_m", "median_abs_range_error_m",
                "rms_range_error_m", "max_abs_azimuth_error_deg", "rms_azimuth_error_deg", "median_islr_db",
                "median_pslr_db", "median_peak_loss_db")


def load_sweep(path: str) -> dict:
    p = Path(path)
    raw = read_yaml_file(p, "sweep")
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
    section = next((k for k in grid if "." not in str(k) and k != "name"), None)
    if section is not None:       # a whole section as a value would replace it, every key it does not name lost
        raise BadInput(f"{path}: grid key {shown(section)}: a whole section; allowed: key paths inside one "
                       f"(e.g. {section}.KEY), or name")
    sets = raw.get("set") or []
    if not isinstance(sets, list) or not all(isinstance(s, str) and "=" in s for s in sets):
        raise BadInput(f"{path}: set = {shown(sets)}: expected a list of KEY.PATH=VALUE strings")
    combine = raw.get("combine") or []
    if not isinstance(combine, list) or any(not isinstance(c, str) or c not in grid for c in combine):
        raise BadInput(f"{path}: combine = {shown(combine)}: expected a list of grid keys; allowed: "
                       f"{', '.join(grid)}")
    config = raw.get("config")
    if config is not None and (not isinstance(config, str) or not config.strip()):
        raise BadInput(f"{path}: config = {shown(config)}: expected a processing preset file (a path)")
    keep_stages = raw.get("keep_stages", False)
    if not isinstance(keep_stages, bool):
        raise BadInput(f"{path}: keep_stages = {shown(keep_stages)}: expected true or false")
    name = raw.get("name", p.stem)
    try:
        if not isinstance(name, str):
            raise ValueError("expected a string")
        folder_name(name)                 # the default output folder is runs/sweep-<name>
    except ValueError as exc:
        raise BadInput(f"{path}: name = {shown(name)}: {exc}") from None
    base = p.parent
    return {"name": name, "source": str(path), "scenarios": [str((base / s).resolve()) for s in scen],
            "combine": combine, "keep_stages": keep_stages, "set": list(sets), "grid": grid,
            "config": str((base / config).resolve()) if config else None}


LABEL_MAX_CHARS = 120


def _label(point: dict) -> str:
    """The point's folder name, ``key=value,...`` (last key component): one path component whatever the
    values hold (a value ``../../x`` had put the point's run outside the sweep's folder): '/', '\\',
    control characters and a leading '.' become '_', and a name over :data:`LABEL_MAX_CHARS` is cut and
    ends in a hash of the whole (a file name has at most 255 bytes)."""
    text = ",".join(f"{k.split('.')[-1]}={json.dumps(v) if not isinstance(v, str) else v}"
                    for k, v in point.items()) or "base"
    safe = "".join("_" if c in "/\\" or ord(c) < 32 or ord(c) == 127 else c for c in text)
    if safe.startswith("."):
        safe = "_" + safe[1:]
    if len(safe) > LABEL_MAX_CHARS:
        safe = safe[:LABEL_MAX_CHARS - 13] + "~" + hashlib.sha256(text.encode()).hexdigest()[:12]
    return safe


def plan_runs(sweep: dict, out_dir: Path, *, source: str | None = None) -> list[dict]:
    """Every run of the sweep, resolved (raises BadInput on a bad grid value before anything runs,
    naming the sweep file ``source`` and the point as well as the scenario)."""
    from ..scenario.overlay import resolve_with_config

    keys = list(sweep["grid"])
    runs = []
    for scen_path in sweep["scenarios"]:
        raw = read_scenario_raw(scen_path)
        for values in itertools.product(*(sweep["grid"][k] for k in keys)):
            point = dict(zip(keys, values))
            sets = list(sweep["set"]) + [f"{k}={json.dumps(v)}" for k, v in point.items()]
            try:
                scn = resolve_with_config(copy.deepcopy(raw), scen_path, sweep["config"], sets)
            except BadInput as exc:
                if source is None:
                    raise
                raise BadInput(f"{source}: the point {_label(point)} (set or grid): {exc}") from None
            sim_key = scenario_hash({k: v for k, v in scn.items() if k != "processing"})
            runs.append({"scenario": scn["name"], "scenario_path": scen_path, "point": point, "sets": sets,
                         "sim_key": sim_key, "run_dir": str(out_dir / scn["name"] / _label(point)),
                         "resolved": scn})
    _refuse_shared_folders(runs, source or sweep.get("source") or "sweep")
    return runs


def _refuse_shared_folders(runs: list[dict], source: str) -> None:
    """Two points whose runs would share one folder (two scenarios of one name, grid values with one
    label such as 8 and "8"): the second overwrote the first, and its summary row showed the other's
    results; or that resolve to one scenario."""
    seen: dict[str, dict] = {}
    for run in runs:
        first = seen.setdefault(run["run_dir"], run)
        if first is run:
            continue
        if first["scenario_path"] != run["scenario_path"]:
            why = (f"the scenarios {first['scenario_path']} and {run['scenario_path']} are both named "
                   f"{shown(run['scenario'])}")
        else:
            why = f"the points {_label_text(first['point'])} and {_label_text(run['point'])} of {run['scenario_path']}"
        raise BadInput(f"{source}: {why}: their runs would share the folder {run['run_dir']}; allowed: "
                       f"scenarios with distinct names and grid values with distinct labels")
    # two labels that resolve to one scenario (4 and 4.0 of an integer key): the same run twice, two rows
    # of one result (an independent review)
    resolved: dict[str, dict] = {}
    for run in runs:
        key = scenario_hash(run["resolved"])
        first = resolved.setdefault(key, run)
        if first is not run:
            raise BadInput(f"{source}: the points {_label_text(first['point'])} and {_label_text(run['point'])} of "
                           f"{run['scenario_path']} resolve to one scenario (sha256 {key[:12]}), the same run twice; "
                           f"allowed: grid values that differ once read (4 and 4.0 of an integer key are one value)")


def _label_text(point: dict) -> str:
    return ",".join(f"{k}={json.dumps(v)}" for k, v in point.items()) or "(no grid)"


def check_point_folders(runs: list[dict], *, overwrite: bool = False) -> None:
    """Each point's run folder checked as ``fwdlook run -o`` checks its folder (``io.outputs``), before
    anything runs: a folder holding files a run would replace that fwdlook did not write is refused
    unless ``overwrite`` (a sweep had overwritten a user's metrics.json and removed their stages/)."""
    from ..io.outputs import check_run_dir

    for run in runs:
        check_run_dir(run["run_dir"], overwrite=overwrite)


def _simulate(args):
    scn, path = args
    from ..io.raw import write_raw

    if scn["kind"] == "isar":
        from ..isar.simulate import simulate_isar_scenario as sim
    else:
        from ..forward.simulate import simulate_scenario as sim
    cube, _ = sim(scn)
    write_raw(path, cube)
    return path


def _process(run):
    from ..io.extra_outputs import remove_stage_files
    from ..io.raw import read_raw

    cube = read_raw(run["raw"])
    if run["resolved"]["kind"] == "isar":
        from ..isar.process import process_isar_cube as proc
    else:
        from ..forward.process import process_cube as proc
    metrics = proc(cube, run["resolved"], run["run_dir"], quiet=True, png=False)
    if not run["keep_stages"]:
        # a sweep keeps each run's metrics.json, image.h5 and scenario.yaml; its stage files (about
        # 60 MB per paper-size run) would fill a disk over hundreds of runs
        remove_stage_files(run["run_dir"])
    return row_of(run, metrics)


def row_of(run: dict, metrics: dict) -> dict:
    """One summary row: the point's keys, its summary metrics, its time and run directory."""
    return {"scenario": run["scenario"], **{k: v for k, v in run["point"].items()},
            **{k: metrics["summary"].get(k) for k in SUMMARY_KEYS},
            **{k: metrics["summary"][k] for k in metrics["summary"] if k not in SUMMARY_KEYS},
            "total_s": metrics["timing_s"]["total"], "run_dir": run["run_dir"]}


def _fmt(v, nd=3):
    return "-" if v is None else (f"{v:.{nd}f}" if isinstance(v, float) else str(v))
