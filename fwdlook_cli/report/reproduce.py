"""``python -m fwdlook_cli.report.reproduce --out DIR --scale {quick,full}`` (``make reproduce``).

Regenerates the papers' tables and figures with ours beside theirs, into ``DIR/REPRODUCE.md``:

a. Li & Li (2023) Sec. 4.1 numbers (ambiguity numbers, residual velocities) from ``geometry.py``;
b. Fig. 5 and Fig. 6 image panels, run on the paper scenarios with the ``configs/`` presets, for
   t_ref = start (as the paper) and centre, with max/median range error per panel;
c. Fig. 7 range profiles through the target at (x, y) = (-300, 1700) m, displacement and ISLR;
d. the methods table (``configs/sweeps/methods.yaml``: every method x t_ref x acceleration);
e. where each method breaks down (``configs/sweeps/accel.yaml``, ``configs/sweeps/q.yaml``);
f. the ISAR second-order keystone table and figures (Serafin et al.);
g. Fig. 8, the extended road scene of Sec. 4.2 with scene metrics per method (``fig8.py``).

Every number in a table is read back from a file this script generated (``metrics.json``,
``summary.json``, ``sec41.json``), never typed by hand; the only typed numbers are the papers' own
claims, kept in :data:`PAPER_CLAIMS` with the section or figure each comes from.  ``--scale quick``
runs a reduced version (a = 50 only, t_ref = centre, fewer grid points) for CI-like checks in well
under a minute; ``full`` runs everything (several minutes on 2 cores).  Progress goes to stderr.
"""
from __future__ import annotations

import argparse
import copy
import json
import math
import shutil
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from ..errors import BadInput
from ..io.h5 import atomic_write_text
from .experiments import CONFIGS, ISAR_SCENARIOS, PANELS, PAPER_CLAIMS, QUICK_PANELS, REPO, SCENARIOS, SWEEPS
from .isar_tables import isar_correction_table, save_isar_figures
from .tables import md_table
from .render import _fmt, _read_json, breakdown, fig7, methods_table, panel_figure, panel_rows, render_sec41



def _log(msg: str) -> None:
    print(f"reproduce: {msg}", file=sys.stderr, flush=True)


def _write_json(path: Path, obj) -> None:
    atomic_write_text(path, json.dumps(obj, indent=1, allow_nan=False, default=float))


# ----------------------------------------------------------------------------------------------
# a. Sec. 4.1 numbers from the geometry
# ----------------------------------------------------------------------------------------------
def sec41_table(scenario_path: str | Path = SCENARIOS / "paper_fig5_a0.yaml", *, q: int | None = None,
                theta_deg: float = 10.0) -> list[dict]:
    """Paper Sec. 4.1 numbers against ours, computed from ``fwdlook_cli.dsp.geometry`` for the scenario.

    Targets at the scene centre's ground range, at azimuth 0 and ``theta_deg``, seen from the
    platform at t = 0 (the paper's eq. 16-20).  Returns rows with ``key``, ``quantity``, ``paper``,
    ``ours``, ``unit``, ``source`` and ``how``.
    """
    from ..scenario.loader import load_scenario
    from ..dsp.geometry import ambiguity_number, depression_deg, doppler_centroid_hz, platform_state, residual_velocity_mps

    claims = PAPER_CLAIMS["sec4.1"]
    q = int(claims["q"]["value"] if q is None else q)
    scn = load_scenario(scenario_path)
    radar, plat = scn["radar"], scn["platform"]
    fc, prf, v, h = radar["fc_hz"], radar["prf_hz"], plat["speed_mps"], plat["height_m"]
    ground = float(scn["scene"]["center_m"][1])
    pos0, _ = platform_state(np.array([0.0]), v, plat["accel_mps2"], h)
    th = np.radians(theta_deg)
    targets = np.array([[0.0, ground, 0.0], [ground * np.sin(th), ground * np.cos(th), 0.0]])
    phi = depression_deg(pos0, targets)[:, 0]
    f_dc = np.array([float(doppler_centroid_hz(v, fc, a, p)) for a, p in zip((0.0, theta_deg), phi)])
    big_f = ambiguity_number(f_dc, prf)
    big_f_q = ambiguity_number(f_dc, prf / q)
    cos_phi0 = math.cos(math.radians(phi[0]))
    dv = residual_velocity_mps(prf, fc) / cos_phi0                  # eq. (19) as Sec. 4.1 writes it
    dv_q = residual_velocity_mps(prf, fc, q) / cos_phi0             # eq. (20)
    where = f"h = {h:g} m, ground range {ground:g} m, v = {v:g} m/s, f_c = {fc / 1e9:g} GHz, PRF = {prf:g} Hz"
    rows = [
        {"key": "depression_deg", "quantity": "depression angle phi_0 at the scene centre", "paper": None,
         "ours": float(phi[0]), "unit": "deg", "source": "not given (NOTES.md: h = 50 m)", "how": where},
        {"key": "f_dc0_hz", "quantity": "boresight Doppler centroid f_dc0 (eq. 16)", "paper": None,
         "ours": float(f_dc[0]), "unit": "Hz", "source": "not given", "how": "doppler_centroid_hz"},
        {"key": "F_0deg", "quantity": "ambiguity number F at 0 deg (eq. 17)", "paper": claims["F_0deg"]["value"],
         "ours": int(big_f[0]), "unit": "", "source": claims["F_0deg"]["source"], "how": "ambiguity_number"},
        {"key": "F_10deg", "quantity": f"ambiguity number F at {theta_deg:g} deg (eq. 17)",
         "paper": claims["F_10deg"]["value"], "ours": int(big_f[1]), "unit": "",
         "source": claims["F_10deg"]["source"], "how": "ambiguity_number"},
        {"key": "residual_velocity_mps", "quantity": "residual velocity of one wrong F, c F_R / (2 f_c cos phi_0)",
         "paper": claims["residual_velocity_mps"]["value"], "ours": float(dv), "unit": "m/s",
         "source": claims["residual_velocity_mps"]["source"], "how": "residual_velocity_mps / cos phi_0"},
        {"key": "residual_velocity_q_mps", "quantity": f"the same at PRF/Q, Q = {q} (eq. 20)",
         "paper": claims["residual_velocity_q_mps"]["value"], "ours": float(dv_q), "unit": "m/s",
         "source": claims["residual_velocity_q_mps"]["source"], "how": "residual_velocity_mps(q) / cos phi_0"},
        {"key": "ambiguity_change_q_10deg",
         "quantity": f"change of ambiguity number 0 -> {theta_deg:g} deg at PRF/Q, Q = {q}",
         "paper": claims["ambiguity_change_q_10deg"]["value"], "ours": int(big_f_q[0] - big_f_q[1]), "unit": "",
         "source": claims["ambiguity_change_q_10deg"]["source"], "how": "ambiguity_number at prf/q"},
    ]
    return rows


def _simulate_job(args):
    scn, raw_path = args
    from ..io.raw import write_raw
    from ..forward.simulate import simulate_scenario

    cube, _ = simulate_scenario(scn)
    write_raw(raw_path, cube)
    return raw_path


def _process_job(args):
    scn, raw_path, run_dir, keep_stages = args
    from ..io.raw import read_raw
    from ..forward.process import process_cube

    process_cube(read_raw(raw_path), scn, run_dir, quiet=True, png=False)
    if not keep_stages:
        prune_stages(run_dir)
    return run_dir


def prune_stages(run_dir) -> None:
    """Remove a run's stage intermediates (image.h5 and metrics.json stay): a full reproduction
    would otherwise leave about 100 MB per run."""
    stages = Path(run_dir) / "stages"
    if stages.is_dir():
        shutil.rmtree(stages)


def _pool(workers):
    return ProcessPoolExecutor(workers) if workers > 1 else None


def run_panels(out: Path, panel_ids, t_refs, *, workers: int, keep_stages: bool, extra_sets=()) -> dict:
    """Simulate each paper scenario once, run every (panel, t_ref); returns {(panel, t_ref): run_dir}."""
    from ..scenario.loader import scenario_hash
    from ..scenario.yamlio import yaml_load
    from ..scenario.overlay import resolve_with_config

    jobs, sims = [], {}
    for pid in panel_ids:
        scen_file, preset, sets = PANELS[pid]
        scen_path = SCENARIOS / scen_file
        raw = yaml_load(scen_path.read_text(encoding="utf-8"), str(scen_path)) or {}
        for t_ref in t_refs:
            scn = resolve_with_config(copy.deepcopy(raw), str(scen_path), str(CONFIGS / preset),
                                      [*extra_sets, *sets, f"processing.t_ref={t_ref}"])
            sim_key = scenario_hash({k: v for k, v in scn.items() if k != "processing"})[:16]
            raw_path = out / "raw" / f"{scn['name']}-{sim_key}.h5"
            sims.setdefault(str(raw_path), scn)
            jobs.append(((pid, t_ref), (scn, str(raw_path), str(out / t_ref / pid), keep_stages)))
    (out / "raw").mkdir(parents=True, exist_ok=True)
    todo = [(scn, p) for p, scn in sims.items() if not Path(p).exists()]
    pool = _pool(workers)
    mapper = pool.map if pool else map
    try:
        for p in mapper(_simulate_job, todo):
            _log(f"  simulated {Path(p).name}")
        for (key, _), run_dir in zip(jobs, mapper(_process_job, [j for _, j in jobs])):
            _log(f"  processed {key[0]} t_ref={key[1]} -> {run_dir}")
    finally:
        if pool:
            pool.shutdown()
    return {key: Path(job[2]) for key, job in jobs}


# ----------------------------------------------------------------------------------------------
# b. Fig. 5 and Fig. 6
# ----------------------------------------------------------------------------------------------
def derived_sweep(src: Path, dst: Path, *, name=None, grid=None, scenarios=None, sets=None) -> Path:
    """A reduced copy of a sweep file (quick scale): scenarios made absolute, grid values replaced."""
    import yaml

    from ..scenario.yamlio import yaml_load

    spec = yaml_load(src.read_text(encoding="utf-8"), str(src))
    spec["scenarios"] = [str((src.parent / s).resolve()) for s in (scenarios or spec["scenarios"])]
    if name:
        spec["name"] = name
    if grid:
        spec["grid"] = {k: grid.get(k, v) for k, v in spec["grid"].items()}
    if sets:
        spec["set"] = list(spec.get("set") or []) + list(sets)
    header = f"# generated by fwdlook_cli.report.reproduce (--scale quick) from {src.relative_to(REPO)}\n"
    atomic_write_text(dst, header + yaml.safe_dump(spec, sort_keys=False, default_flow_style=None))
    return dst


def run_sweep_dir(sweep_file: Path, out: Path, *, workers: int, keep_stages: bool) -> list[dict]:
    from .sweep import run_sweep

    rows = run_sweep(str(sweep_file), out, workers=workers, quiet=False)
    failed = [r for r in rows if r.get("status") == "failed"]
    if failed:      # the tables below need every point: stop here, naming them (a rerun skips the rest)
        raise RuntimeError(f"{sweep_file}: {len(failed)} point(s) failed: " +
                           "; ".join(f"{r['run_dir']}: {r['error']}" for r in failed[:3]))
    summary = _read_json(out / "summary.json")
    if not keep_stages:
        for row in summary["rows"]:
            prune_stages(row["run_dir"])
            for sub in Path(row["run_dir"]).glob("*/stages"):
                prune_stages(sub.parent)
    return summary["rows"]


def isar_section(out: Path) -> list[str]:
    """The ISAR correction table and figures (``isar_tables.py``)."""
    lines = ["## f. ISAR: second-order keystone (Serafin et al., Sec. 4)", ""]
    scns = [SCENARIOS / s for s in ISAR_SCENARIOS]
    absent = [str(s.relative_to(REPO)) for s in scns if not s.exists()]
    if absent:
        return lines + [f"Skipped: scenario file(s) {', '.join(absent)} missing.", ""]
    isar_dir = out / "isar"
    isar_dir.mkdir(parents=True, exist_ok=True)
    _log("f. ISAR correction table and figures")
    table = isar_correction_table([str(s) for s in scns])
    figs = save_isar_figures(isar_dir, [str(s) for s in scns])
    if isinstance(table, str):
        lines += [table, ""]
    else:
        rows = table.get("rows", table) if isinstance(table, dict) else table
        rows = list(rows)
        _write_json(isar_dir / "isar_table.json", rows)
        if rows and isinstance(rows[0], dict):
            heads = list(rows[0])
            lines += [md_table(heads, [[_fmt(r.get(h), 3) for h in heads] for r in rows])]
    paths = [Path(p) for p in figs] if isinstance(figs, (list, tuple)) else sorted(isar_dir.glob("*.png"))
    for p in paths:
        rel = Path(p).resolve().relative_to(out.resolve()) if Path(p).resolve().is_relative_to(out.resolve()) else p
        lines.append(f"![{Path(p).name}]({rel})")
    return lines + [""]


# ----------------------------------------------------------------------------------------------
# The whole reproduction
# ----------------------------------------------------------------------------------------------
def reproduce(out: str | Path, *, scale: str = "full", workers: int = 2, keep_stages: bool = False) -> Path:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    quick = scale == "quick"
    t_all = time.perf_counter()
    times = {}
    md = ["# Reproducing Li & Li (2023) and Serafin et al. with fwdlook", "",
          f"Generated by `python -m fwdlook_cli.report.reproduce --out {out} --scale {scale}` (`make reproduce "
          f"SCALE={scale}`). Every number in the tables below is read back from a file this command wrote "
          f"(`sec41.json`, each run's `metrics.json`, each sweep's `summary.json`); the only hand-typed "
          f"numbers are the papers' claims, kept in `PAPER_CLAIMS` in `fwdlook_cli/report/experiments.py` with the "
          f"section or figure they come from.", ""]
    if quick:
        md += ["**Quick scale**: a reduced reproduction (a = 50 panels only, t_ref = centre, reduced sweep grids) "
               "for CI-like checks; run `make reproduce` (SCALE=full) for the paper's whole set.", ""]

    # a ---------------------------------------------------------------------------------------
    t0 = time.perf_counter()
    _log("a. Sec. 4.1 numbers from the geometry")
    rows = sec41_table()
    _write_json(out / "sec41.json", rows)
    rows = _read_json(out / "sec41.json")
    md += ["## a. Sec. 4.1 numbers (paper) against the geometry (ours)", "",
           "The paper gives no platform height; its ambiguity numbers only come out for a low platform, so the "
           f"paper scenarios use {rows[0]['how']} (NOTES.md). Residual velocities as Sec. 4.1 writes eq. (19)-(20), "
           "with cos(phi_0).", "", render_sec41(rows)]
    times["a"] = time.perf_counter() - t0

    # b, c ------------------------------------------------------------------------------------
    t0 = time.perf_counter()
    panel_ids = QUICK_PANELS if quick else tuple(PANELS)
    t_refs = ("centre",) if quick else ("start", "centre")
    _log(f"b. Fig. 5/6 panels {', '.join(panel_ids)} for t_ref = {', '.join(t_refs)}")
    runs = run_panels(out / "panels", panel_ids, t_refs, workers=workers, keep_stages=keep_stages)
    md += ["## b. Fig. 5 and Fig. 6: image panels and range errors", "",
           "Each panel is a run of the paper scenario (`scenarios/paper_fig*.yaml`) with the method preset "
           "(`configs/traditional.yaml`, `configs/decimation.yaml`; curvature switched off for 6C/6D). "
           "The traditional keystone includes eq. (12) curvature compensation as Sec. 3.1 describes it. "
           "The paper measures at t_ref = start (eq. 1, 14); NOTES.md asks for t_ref = centre too. "
           "'claim holds?' tests the paper's qualitative claim against half a range resolution cell "
           "(c / 4B): 'accurate' means every detected target within it, 'error' means at least one beyond it.",
           ""]
    heads = ["panel", "t_ref", "a_y (m/s^2)", "method", "Q", "curvature", "F used", "detected",
             "max abs range error (m)", "median abs range error (m)", "rms azimuth error (deg)",
             "paper's claim", "claim holds?"]
    md.append(md_table(heads, panel_rows(runs, panel_ids, t_refs)))
    from ..forward.evaluate import RANGE_WINDOW_M

    md += [f"Caveat: a target's image is searched within +-{RANGE_WINDOW_M:g} m of its true range (half the "
           "lattice spacing), so a displacement larger than that is not measured: the target is counted as "
           "undetected, or its neighbour's image is taken for it. Where the figure shows targets displaced "
           "by a whole lattice row, the max |range error| in the table understates the displacement.", ""]
    for t_ref in t_refs:
        fig5 = [p for p in panel_ids if p.startswith("5")]
        fig6 = [p for p in panel_ids if p.startswith("6")]
        if fig5:
            panel_figure(out / f"fig5_{t_ref}.png", runs, fig5, t_ref,
                         f"Fig. 5 (a = 0): traditional against decimation keystone, t_ref = {t_ref}", ncols=2)
            md.append(f"![Fig. 5, t_ref = {t_ref}](fig5_{t_ref}.png)\n")
        if fig6:
            panel_figure(out / f"fig6_{t_ref}.png", runs, fig6, t_ref,
                         f"Fig. 6: traditional; decimation without and with curvature compensation, "
                         f"t_ref = {t_ref}", ncols=2 if len(fig6) > 3 else len(fig6))
            md.append(f"![Fig. 6, t_ref = {t_ref}](fig6_{t_ref}.png)\n")
    times["b"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    _log("c. Fig. 7 range profiles")
    f7 = []
    for t_ref in t_refs:
        f7 += fig7(out, runs, t_ref)
    xy = PAPER_CLAIMS["fig7"]["target_xy_m"]["value"]
    md += ["## c. Fig. 7: range profile of the target at (x, y) = "
           f"({xy[0]:g}, {xy[1]:g}) m, a = 50", "",
           "Ours: the target's `range_error_m`, `islr_db` (eq. 27, main lobe between the first minima, "
           "window +-5 range resolution cells, on the profile summed over the target's dwell), "
           "`image_islr_db` (the same on the image's own range cut through the target: the paper's Fig. 7 "
           "profile, so the like-for-like one), `pslr_db` and 3 dB width from metrics.json; the plotted "
           "profile is the image's range cut through the target, interpolated x5.", "",
           md_table(["curve (paper)", "panel", "t_ref", "target (x, y) m", "our displacement (m)",
                     "paper's displacement", "our ISLR, dwell profile (dB)", "our ISLR, image cut (dB)",
                     "paper's ISLR (dB)", "our PSLR (dB)", "our 3 dB width (m)", "detected"], f7)]
    md += [f"![Fig. 7, t_ref = {t}](fig7_{t}.png)\n" for t in t_refs]
    times["c"] = time.perf_counter() - t0

    # d ---------------------------------------------------------------------------------------
    t0 = time.perf_counter()
    sweeps_dir = out / "sweeps"
    if quick:
        methods_file = derived_sweep(SWEEPS / "methods.yaml", sweeps_dir / "methods_quick.yaml",
                                     scenarios=[str(SCENARIOS / "paper_fig6_a50.yaml")],
                                     grid={"processing.method": ["traditional", "decimation", "tracking"],
                                           "processing.t_ref": ["centre"]})
    else:
        methods_file = SWEEPS / "methods.yaml"
    _log(f"d. methods sweep {methods_file}")
    run_sweep_dir(methods_file, out / "methods", workers=workers, keep_stages=keep_stages)
    table = methods_table(out / "methods" / "summary.json")
    atomic_write_text(out / "methods_table.md", table)
    md += ["## d. The methods table", "",
           f"`fwdlook sweep {methods_file.relative_to(REPO) if methods_file.is_relative_to(REPO) else methods_file}`: "
           "every method, both t_ref choices, the paper's three accelerations (scenario defaults: Q = 25, "
           "CZT keystone, eq. 12 curvature on, Doppler band following v_c). Errors over detected targets. "
           "Also in [methods_table.md](methods_table.md); the sweep's own summary is "
           "[methods/summary.md](methods/summary.md).", "", table,
           "![speed against accuracy](methods/speed_accuracy.png)", ""]
    times["d"] = time.perf_counter() - t0

    # d2 --------------------------------------------------------------------------------------
    t0 = time.perf_counter()
    if quick:
        placement_file = derived_sweep(SWEEPS / "placement.yaml", sweeps_dir / "placement_quick.yaml",
                                       scenarios=[str(SCENARIOS / "paper_fig6_a50.yaml")],
                                       grid={"scene.lattice.x_offset": [0, 10, 20],
                                             "processing.method": ["tracking"], "processing.t_ref": ["centre"]})
    else:
        placement_file = SWEEPS / "placement.yaml"
    _log(f"d2. placement sweep {placement_file}")
    run_sweep_dir(placement_file, out / "placement", workers=workers, keep_stages=keep_stages)
    md += ["## d2. Placement of every target, free of the image's neighbour mixing", "",
           f"`fwdlook sweep {placement_file.relative_to(REPO) if placement_file.is_relative_to(REPO) else placement_file}`:"
           " each lattice column processed on its own (its three targets are 30 m apart in range), the "
           "summary recomputed over the union of the targets. This measures where each method puts each "
           "target; the lattice image above also mixes neighbours that share a Doppler cell near boresight.",
           "", (out / "placement" / "summary.md").read_text(), ""]
    times["d2"] = time.perf_counter() - t0

    # e ---------------------------------------------------------------------------------------
    t0 = time.perf_counter()
    if quick:
        accel_file = derived_sweep(SWEEPS / "accel.yaml", sweeps_dir / "accel_quick.yaml",
                                   grid={"processing.method": ["decimation", "tracking"],
                                         "platform.accel_mps2": [[0, 0, 0], [0, 50, 0]]})
        q_file = derived_sweep(SWEEPS / "q.yaml", sweeps_dir / "q_quick.yaml",
                               grid={"processing.q": [5, 25], "platform.accel_mps2": [[0, 50, 0]]})
    else:
        accel_file, q_file = SWEEPS / "accel.yaml", SWEEPS / "q.yaml"
    (out / "breakdown").mkdir(parents=True, exist_ok=True)
    _log(f"e. acceleration sweep {accel_file}")
    run_sweep_dir(accel_file, out / "accel", workers=workers, keep_stages=keep_stages)
    acc_table, acc_lines = breakdown(out / "accel" / "summary.json", out / "breakdown" / "accel_stability.png",
                                     row_key="processing.method", col_key="platform.accel_mps2", row_name="method",
                                     title="max |range error| (m), t_ref = centre; red frame: over half a range cell")
    _log(f"e. Q sweep {q_file}")
    run_sweep_dir(q_file, out / "q", workers=workers, keep_stages=keep_stages)
    q_table, q_lines = breakdown(out / "q" / "summary.json", out / "breakdown" / "q_stability.png",
                                 row_key="processing.q", col_key="platform.accel_mps2", row_name="Q",
                                 title="decimation keystone: max |range error| (m) over Q, t_ref = centre")
    md += ["## e. Where each method breaks down", "",
           f"Platform forward acceleration against method (`{accel_file.name}`), t_ref = centre, the paper's "
           "Table 1 scene. Cells: max |range error| over the detected resolved targets, those no neighbour "
           "shares an image cell with (detected/resolved).", "", acc_table,
           *[f"- {ln}" for ln in acc_lines], "", "![acceleration stability map](breakdown/accel_stability.png)", "",
           f"Decimation factor Q against acceleration (`{q_file.name}`), decimation keystone, t_ref = centre.",
           "", q_table, *[f"- {ln}" for ln in q_lines], "", "![Q stability map](breakdown/q_stability.png)", ""]
    times["e"] = time.perf_counter() - t0

    # f ---------------------------------------------------------------------------------------
    t0 = time.perf_counter()
    md += isar_section(out)
    times["f"] = time.perf_counter() - t0

    # g ---------------------------------------------------------------------------------------
    t0 = time.perf_counter()
    from .fig8 import fig8_section

    _log("g. Fig. 8 extended scene")
    md += fig8_section(out, scale=scale, keep_stages=keep_stages)
    times["g"] = time.perf_counter() - t0

    total = time.perf_counter() - t_all
    md += ["## Run time", "", md_table(["section", "wall time (s)"],
                                       [[k, f"{v:.1f}"] for k, v in times.items()] + [["total", f"{total:.1f}"]])]
    path = out / "REPRODUCE.md"
    atomic_write_text(path, "\n".join(md).rstrip("\n") + "\n")
    _log(f"wrote {path} ({total:.1f} s)")
    return path


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m fwdlook_cli.report.reproduce", description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", required=True, help="output folder (REPRODUCE.md, figures, run directories)")
    parser.add_argument("--scale", choices=("quick", "full"), default="full",
                        help="quick: a reduced set for CI (< 1 min); full: everything (several minutes)")
    parser.add_argument("--workers", type=int, default=2, help="parallel processes (default 2)")
    parser.add_argument("--keep-stages", action="store_true",
                        help="keep every run's stages/*.h5 intermediates (about 100 MB per run)")
    args = parser.parse_args(argv)
    if args.workers < 1:
        parser.error(f"--workers {args.workers}: must be >= 1")
    try:
        path = reproduce(args.out, scale=args.scale, workers=args.workers, keep_stages=args.keep_stages)
    except BadInput as exc:
        print(f"fwdlook reproduce: error: {exc}", file=sys.stderr)
        sys.exit(2)
    print(path)


if __name__ == "__main__":  # pragma: no cover
    main()
