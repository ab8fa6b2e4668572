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

from .dsp.blas import on_one_blas_thread      # (no numpy at its import: the API's import stays light)

EXPORTS = {
    "load_scenario": "scenario.loader", "resolve_scenario": "scenario.loader",
    "scenario_hash": "scenario.loader", "dump_scenario": "scenario.loader",
    "plan_for_scenario": "forward.plan", "simulate_cube": "api", "simulate_scenario": "forward.simulate",
    "read_raw": "io.raw", "write_raw": "io.raw", "RawCube": "io.cube",
    "build_forward_stages": "forward.chain", "range_fft": "forward.chain", "decimate": "forward.chain",
    "keystone_stage": "forward.chain", "regroup": "forward.chain", "range_curvature": "forward.chain",
    "doppler_spectra": "forward.chain", "monopulse_image": "forward.chain", "run_chain": "api",
    "StageData": "io.stagefile", "stage_to_xarray": "io.xr", "build_isar_stages": "isar.chain",
    "run_isar_stages": "isar.chain", "isar_outputs": "isar.evaluate", "measure": "api",
    "target_metrics": "forward.evaluate", "summarize": "forward.evaluate", "profile_metrics": "dsp.profile",
    "interpolate_peak": "dsp.peaks", "ideal_sinc_islr_db": "dsp.profile", "ideal_sinc_pslr_db": "dsp.profile",
    "process_cube": "forward.process", "BadInput": "errors",
}


def simulate_cube(scn: dict):
    """The raw cube of a resolved scenario (forward-looking or ``kind: isar``), in memory."""
    if scn.get("kind") == "isar":
        from .isar.simulate import simulate_isar_scenario

        return simulate_isar_scenario(scn)[0]
    from .forward.simulate import simulate_scenario

    return simulate_scenario(scn)[0]


def _forward_processing(cube, processing: dict) -> dict:
    if processing["method"] == "auto":
        from .forward.plan import plan_for_cube

        return dict(processing, **plan_for_cube(cube, processing)["processing"])
    return processing


@on_one_blas_thread                     # as process_cube (dsp/blas.py: no idle BLAS thread spinning)
def run_chain(cube, processing: dict):
    """Every stage of the chain in memory, no files; returns the last stage's StageData.

    Forward-looking: ``image`` on (``range_m``, ``angle_deg``), ``real_beam``, the projected cells;
    ISAR (``processing.correction`` present): the ISAR image on (``range_m``, ``doppler_hz``).
    """
    if "correction" in processing:
        from .isar.chain import run_isar_stages

        return run_isar_stages(cube, processing)[0]
    from .forward.chain import build_forward_stages

    data, stages, _ = build_forward_stages(cube, _forward_processing(cube, processing))
    for st in stages:
        data = st.fn(data, **st.params)
    return data


def measure(cube, final, processing: dict, spectra=None) -> dict:
    """``{"targets": [...], "summary": {...}}`` of a forward-looking image against the cube's truth: the
    rows and summary metrics.json holds for the same image (``forward.run_metrics.target_rows``: the
    peak refined on its cuts, detection 10 dB over the median, the resolved flags, and ISLR/PSLR/width/
    peak loss from each target's range profile over its dwell).  Those need the chain's Doppler
    spectra: ``spectra`` (the ``doppler_spectra`` stage's output; under ``imaging: dwell`` the
    ``range_curvature`` stage's, whose spectra are computed on the targets' windows), else computed
    here by running the chain up to that stage once more."""
    from .forward.chain import build_forward_stages
    from .forward.evaluate import summarize
    from .forward.run_metrics import target_rows

    if cube.truth_xyz_m() is None:
        return {"targets": [], "summary": {"n_targets": 0, "detected": 0}}
    proc = _forward_processing(cube, processing)
    data, stages, geo = build_forward_stages(cube, proc)
    names = [st.name for st in stages]
    source = "doppler_spectra" if "doppler_spectra" in names else "range_curvature"
    if spectra is None:
        for st in stages:
            data = st.fn(data, **st.params)
            if st.name == source:
                spectra = data
                break
    given = lambda: spectra  # noqa: E731
    rows, islr_from = target_rows(cube, final, proc, geo, **{
        "spectra_of" if source == "doppler_spectra" else "compensated_of": given})
    return {"targets": rows, "summary": {**summarize(rows), "islr_from": islr_from}}
