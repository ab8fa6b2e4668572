"""The ISAR correction table and the paper's figures (Serafin et al. Sec. 4)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..scenario.isar import CORRECTIONS
from ..isar.chain import run_isar_stages
from ..isar.evaluate import isar_outputs
from ..isar.process import _save_image_quicklook
from ..isar.simulate import simulate_isar_scenario


# ----------------------------------------------------------------------------------------------
# The correction table and the paper's figures
# ----------------------------------------------------------------------------------------------
PAPER_SCENARIOS = ("isar_theta3.yaml", "isar_theta5.yaml")


def _scenario_dir() -> Path:
    return Path(__file__).resolve().parents[2] / "scenarios"


def isar_correction_table(scn_paths=None, corrections=CORRECTIONS, overrides=()):
    """For each scenario and correction, run the stages in memory; returns a list of row dicts with
    keys scenario, correction, migration_span_cells (resolution cells c / (2 B)), migration_span_samples
    (range samples c / (2 fs)), migration_span_m, integration_gain_db, n0_true, n0_est (n0_est only
    for keystone2_n0_est; pulses from the middle of the observation)."""
    from ..scenario.loader import load_scenario

    paths = [Path(p) for p in (scn_paths or [_scenario_dir() / name for name in PAPER_SCENARIOS])]
    rows = []
    for path in paths:
        scn = load_scenario(path, overrides)
        cube, _ = simulate_isar_scenario(scn)
        for corr in corrections:
            proc = dict(scn["processing"], correction=corr)
            final, _ = run_isar_stages(cube, proc)
            _, met = isar_outputs(final, cube, proc)
            s = met["summary"]
            rows.append({"scenario": scn["name"], "correction": corr,
                         "migration_span_cells": s["migration_span_cells"],
                         "migration_span_samples": s["migration_span_samples"],
                         "migration_span_m": s["migration_span_m"],
                         "integration_gain_db": s["integration_gain_db"],
                         "n0_true": s["n0_true_pulses"], "n0_est": s["n0_est_pulses"]})
    return rows


def format_isar_table(rows) -> str:
    """Markdown table of :func:`isar_correction_table` rows."""
    lines = ["| scenario | correction | migration span (resolution cells c/2B) | migration span (samples c/2fs) "
             "| migration span (m) | integration gain (dB) | n0 true | n0 est |",
             "|---|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        est = "" if r["n0_est"] is None else f"{r['n0_est']:.1f}"
        true = "" if r["n0_true"] is None else f"{r['n0_true']:.1f}"
        samples = r.get("migration_span_samples")
        span_m = r.get("migration_span_m")
        lines.append(f"| {r['scenario']} | {r['correction']} | {r['migration_span_cells']:.2f} | "
                     f"{'' if samples is None else f'{samples:.2f}'} | {'' if span_m is None else f'{span_m:.3f}'} | "
                     f"{r['integration_gain_db']:.2f} | {true} | {est} |")
    return "\n".join(lines)


def save_isar_figures(out_dir, scn_paths=None, *, correction="keystone2_n0", overrides=(), max_columns=1000):
    """Figures like the paper's Fig. 3-6: raw echo magnitude (range x slow time) before and after the
    range-migration compensation, and the ISAR image, for each scenario (default: theta0 = 3 and 5 deg).

    Writes ``<name>_echo_before.png``, ``<name>_echo_after.png`` and ``<name>_image.png`` per scenario
    into ``out_dir``; returns the paths.
    """
    from ..scenario.loader import load_scenario
    from ..io.quicklook import save_image_png

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [Path(p) for p in (scn_paths or [_scenario_dir() / name for name in PAPER_SCENARIOS])]
    written = []
    for path in paths:
        scn = load_scenario(path, overrides)
        cube, _ = simulate_isar_scenario(scn)
        proc = dict(scn["processing"], correction=correction)
        final, _ = run_isar_stages(cube, proc)
        image, _ = isar_outputs(final, cube, proc)
        step = max(1, cube.n_pulses // max_columns)
        t = cube.slow_time_s[::step]
        th = scn["target"]["theta0_deg"]
        for tag, echo, what in (("before", cube.sum, "before"),
                                ("after", final["echo_rc"], f"after {correction}")):
            p = np.abs(echo[::step]).T.astype(np.float64) ** 2
            fname = out_dir / f"{scn['name']}_echo_{tag}.png"
            save_image_png(fname, p, t, cube.range_m, xlabel="slow time (s)", ylabel="slant range (m)",
                           title=f"{scn['name']}: raw echo {what} range-migration compensation, "
                                 f"theta0 = {th:g} deg", dynamic_range_db=40)
            written.append(fname)
        fname = out_dir / f"{scn['name']}_image.png"
        _save_image_quicklook(fname, image, title=f"{scn['name']}: ISAR image, {correction}")
        written.append(fname)
    return written
