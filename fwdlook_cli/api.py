"""The Python API: ``import fwdlook_cli as fw``; everything on arrays, no run directory needed.

The names below are reached as attributes of the package (``fw.load_scenario``), imported on first
use, so that ``import fwdlook_cli`` (and ``fwdlook --help``) stays fast.  The README's "Python API"
section shows them in use; ``tests/test_api.py`` runs that example.

=================  ==================================================================================
scenarios          ``load_scenario(path, overrides=())``, ``resolve_scenario(mapping, ...)``,
                   ``scenario_hash``, ``dump_scenario``, ``plan_for_scenario``
cubes              ``simulate_cube(scn) -> RawCube`` (forward or ISAR), ``simulate_scenario`` (with stats),
                   ``read_raw``, ``write_raw``, ``RawCube`` (``.to_xarray()``)
stages             ``build_forward_stages(cube, processing) -> (source, [Stage], geometry)``, the
                   stage functions ``range_fft``, ``decimate``, ``keystone_stage``, ``regroup``,
                   ``range_curvature``, ``doppler_spectra``, ``monopulse_image``; ``run_chain(cube,
                   processing)`` runs them in memory; ``StageData``, ``stage_to_xarray``; ISAR:
                   ``build_isar_stages``, ``run_isar_stages``, ``isar_outputs``
metrics            ``measure(cube, final, processing)`` (per-target rows and summary, as metrics.json),
                   ``target_metrics``, ``summarize``, ``profile_metrics``, ``interpolate_peak``,
                   ``ideal_sinc_islr_db``, ``ideal_sinc_pslr_db``
runs on disk       ``process_cube(cube, scn, run_dir)`` (stage files, image.h5, metrics.json)
=================  ==================================================================================
"""
from __future__ import annotations

EXPORTS = {
    "load_scenario": "config", "resolve_scenario": "config", "scenario_hash": "config", "dump_scenario": "config",
    "plan_for_scenario": "plan",
    "simulate_cube": "api", "simulate_scenario": "simulate", "read_raw": "io", "write_raw": "io", "RawCube": "cube",
    "build_forward_stages": "chain", "range_fft": "chain", "decimate": "chain", "keystone_stage": "chain",
    "regroup": "chain", "range_curvature": "chain", "doppler_spectra": "chain", "monopulse_image": "chain",
    "run_chain": "api", "StageData": "pipeline", "stage_to_xarray": "xr",
    "build_isar_stages": "isar", "run_isar_stages": "isar", "isar_outputs": "isar",
    "measure": "api", "target_metrics": "evaluate", "summarize": "evaluate", "profile_metrics": "metrics",
    "interpolate_peak": "metrics", "ideal_sinc_islr_db": "metrics", "ideal_sinc_pslr_db": "metrics",
    "process_cube": "process", "BadInput": "errors",
}


def simulate_cube(scn: dict):
    """The raw cube of a resolved scenario (forward-looking or ``kind: isar``), in memory."""
    if scn.get("kind") == "isar":
        from .isar import simulate_isar_scenario

        return simulate_isar_scenario(scn)[0]
    from .simulate import simulate_scenario

    return simulate_scenario(scn)[0]


def _forward_processing(cube, processing: dict) -> dict:
    if processing["method"] == "auto":
        from .plan import plan_for_cube

        return dict(processing, **plan_for_cube(cube, processing)["processing"])
    return processing


def run_chain(cube, processing: dict):
    """Every stage of the chain in memory, no files; returns the last stage's StageData.

    Forward-looking: ``image`` on (``range_m``, ``angle_deg``), ``real_beam``, the projected cells;
    ISAR (``processing.correction`` present): the ISAR image on (``range_m``, ``doppler_hz``).
    """
    if "correction" in processing:
        from .isar import run_isar_stages

        return run_isar_stages(cube, processing)[0]
    from .chain import build_forward_stages

    data, stages, _ = build_forward_stages(cube, _forward_processing(cube, processing))
    for st in stages:
        data = st.fn(data, **st.params)
    return data


def measure(cube, final, processing: dict) -> dict:
    """``{"targets": [...], "summary": {...}}`` of a forward-looking image against the cube's truth,
    with metrics.json's definitions (image peak refined on its cuts, detection 10 dB over the median)."""
    from .chain import build_forward_stages
    from .evaluate import summarize, target_metrics

    truth = cube.truth_xyz_m()
    if truth is None:
        return {"targets": [], "summary": {"n_targets": 0, "detected": 0}}
    _, _, geo = build_forward_stages(cube, _forward_processing(cube, processing))
    rows = target_metrics(final["image"], final["range_m"], final["angle_deg"], truth, cube.truth["amplitude"],
                          geo["p_ref"], bandwidth_hz=cube.radar["bandwidth_hz"])
    return {"targets": rows, "summary": summarize(rows)}
