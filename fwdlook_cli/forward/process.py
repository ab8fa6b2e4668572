"""Driving a run: settings, the stage runner, image.h5, image.png, metrics.json (I/O at the edge)."""
from __future__ import annotations

import hashlib
import importlib
import logging
import time
from pathlib import Path

import numpy as np

from .. import __version__
from ..scenario.loader import dump_scenario, scenario_hash
from ..dsp import spawner
from ..dsp.blas import on_one_blas_thread, worker_threads
from ..dsp.geometry import C_MPS
from ..errors import BadInput
from ..io.h5 import GzipChunks, atomic_h5, atomic_write_text, json_text, put_scale, put_sparse_gzip, set_attrs
from ..io import backing, pending, signals
from ..io.cube import cube_hash

log = logging.getLogger(__name__)


def tail_percentiles(x, q_lo: float, q_hi: float):
    """``np.percentile(x, [q_lo, q_hi])`` (linear method) for a low and a high percentile of a large
    array, without partitioning all of it: the order statistics that the two need are taken from the
    few values under (over) a threshold read off a strided sample, then interpolated as numpy does
    (``_lerp``).  Bit-identical to ``np.percentile`` (tested); it falls back to it when the sample's
    threshold does not hold enough values, or on non-finite data."""
    x = np.asarray(x).reshape(-1)
    if x.dtype != np.float32:            # float32 (the cells' positions) is read as it is: its order
        x = x.astype(np.float64, copy=False)   # statistics are its float64 values' (no copy of the array)
    n = x.size
    qs = np.true_divide(np.array([q_lo, q_hi], dtype=np.float64), 100)
    if n < 4096 or not (0.0 <= qs[0] <= 0.05 and 0.95 <= qs[1] <= 1.0):
        return np.percentile(x.astype(np.float64, copy=False), [q_lo, q_hi])
    v = (n - 1) * qs
    prev = np.floor(v)
    gamma = v - prev
    prev = prev.astype(np.intp)
    nxt = np.minimum(prev + 1, n - 1)
    sample = np.sort(x[:: max(1, n // 4096)])
    m = sample.size
    t_lo = sample[min(m - 1, int(np.ceil((qs[0] * 2 + 2e-3) * m)) + 2)]     # values of x: exact in its dtype
    t_hi = sample[max(0, int(np.floor((1 - (1 - qs[1]) * 2 - 2e-3) * m)) - 3)]
    low, high = x[x <= t_lo], x[x >= t_hi]
    need_lo, need_hi = int(nxt[0]) + 1, n - int(prev[1])
    if (not (np.isfinite(t_lo) and np.isfinite(t_hi)) or low.size < need_lo or high.size < need_hi
            or not (np.isfinite(low).all() and np.isfinite(high).all()) or np.isnan(x).any()):
        return np.percentile(x.astype(np.float64, copy=False), [q_lo, q_hi])
    low = np.partition(low, [int(prev[0]), int(nxt[0])])
    off = n - high.size                                # high[j] is order statistic off + j
    high = np.partition(high, [int(prev[1]) - off, int(nxt[1]) - off])
    a = np.array([low[prev[0]], high[prev[1] - off]], dtype=np.float64)
    b = np.array([low[nxt[0]], high[nxt[1] - off]], dtype=np.float64)
    diff_b_a = b - a                                  # numpy's _lerp, exactly
    out = np.add(a, diff_b_a * gamma)
    np.subtract(b, diff_b_a * (1 - gamma), out=out, where=gamma >= 0.5)
    return out


def _grid_index(coord_m, origin_m, step_m):
    """``np.rint((coord_m - origin_m) / step_m)`` in float64, in one buffer (whole numbers, exact in
    float64 up to 2^53: the caller converts only the indices it keeps)."""
    t = np.subtract(coord_m, origin_m, dtype=np.float64)
    t /= step_m
    np.rint(t, out=t)
    return t


GROUND_BLOCK_CELLS = 1 << 16     # cells per block of the ground image's binning
GROUND_MAX_BINS = 1 << 24        # the ground grid's most bins (64 MiB of float32); a wider scene gets a coarser step


def ground_image(cell_x_m, cell_y_m, cell_power, step_m):
    """Bin the projected cells' power on a ground (x, y) grid of ``step_m``, coarsened by a whole factor where
    the cells span more than ``GROUND_MAX_BINS`` bins (a scene 800 km across had asked for 23e9 bins, an
    85.7 GiB allocation and a traceback); the axes returned give the step used."""
    if len(cell_x_m) == 0:
        return np.zeros((1, 1), np.float32), np.zeros(1), np.zeros(1)
    x_lo, x_hi = tail_percentiles(cell_x_m, 0.1, 99.9)
    y_lo, y_hi = tail_percentiles(cell_y_m, 0.1, 99.9)

    def grid(step):                          # (x0, y0, nx, ny) of the box, 5 margin bins each side
        x0, y0 = np.floor(x_lo / step) * step - 5 * step, np.floor(y_lo / step) * step - 5 * step
        return x0, y0, int(np.ceil((x_hi - x0) / step)) + 10, int(np.ceil((y_hi - y0) / step)) + 10

    x0, y0, nx, ny = grid(step_m)
    # the smallest whole factor that fits: none below the root of the excess can (each axis shrinks by at most
    # the factor); a thin box, whose short axis is mostly margin, needs up to the excess itself
    base, factor = step_m, max(2, int(np.sqrt(nx * ny / GROUND_MAX_BINS)))
    while nx * ny > GROUND_MAX_BINS:
        step_m = base * factor
        x0, y0, nx, ny = grid(step_m)
        factor += 1
    # accumulated in float32, the image's own precision (np.add.at: no grid-sized float64 temporary,
    # whose fresh pages cost more than the sums here), in blocks of cells taken in order (the same
    # sums): the bins' float64 temporaries of a block, not of every cell, while the outputs still hold
    # the Doppler spectra (the CPI chains' high-water mark was here: README, "Memory")
    img = np.zeros(nx * ny, np.float32)
    for c0 in range(0, len(cell_x_m), GROUND_BLOCK_CELLS):
        cells = slice(c0, c0 + GROUND_BLOCK_CELLS)
        ix, iy = _grid_index(cell_x_m[cells], x0, step_m), _grid_index(cell_y_m[cells], y0, step_m)
        ok = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
        iy *= nx
        iy += ix                                       # the flat bin, a whole number in float64
        np.add.at(img, iy[ok].astype(np.int64), np.asarray(cell_power[cells], np.float32)[ok])
    return img.reshape(ny, nx), x0 + step_m * np.arange(nx), y0 + step_m * np.arange(ny)


def write_image_h5(path, final, ground, ground_x, ground_y, *, scenario_yaml, t_ref_s, method, packed=None):
    """image.h5 (CONTRACT.md 4).  The images are gzip level 1 (mostly empty: 8 % of the bytes; shuffle
    is 1.6x slower for the same size) in chunks of 16 rows, the all-zero chunks not written
    (``io.h5.put_sparse_gzip``: the same arrays on reading).  ``packed``: {name: io.h5.GzipChunks}
    of ``image``, ``real_beam``, ``ground_image`` compressed beforehand (:func:`process_cube` starts
    them before the metrics, which run beside the compression)."""
    packed = packed or {}
    with atomic_h5(path) as f:
        set_attrs(f, {"format": "fwdlook-image", "method": method, "t_ref_s": t_ref_s, "scenario": scenario_yaml})
        r = put_scale(f, "range_m", final["range_m"], "m", "slant range from the antenna at t_ref")
        a = put_scale(f, "angle_deg", final["angle_deg"], "deg", "azimuth atan2(dx, dy) from the antenna at t_ref")
        rn = put_scale(f, "range_native_m", final["range_native_m"], "m", "slant range, native sampling")
        put_sparse_gzip(f, "image", packed.get("image", final["image"]), "1",
                        "monopulse image: sum power in (range, angle)", dims=(r, a))
        put_sparse_gzip(f, "real_beam", packed.get("real_beam", final["real_beam"]), "1",
                        "real-beam image: sum power against beam angle", dims=(rn, a))
        gx = put_scale(f, "ground_x_m", ground_x, "m", "ground cross-range x")
        gy = put_scale(f, "ground_y_m", ground_y, "m", "ground forward y")
        put_sparse_gzip(f, "ground_image", packed.get("ground_image", ground), "1",
                        "monopulse image projected on the ground (y, x)", dims=(gy, gx))


def start_fit_spawner(proc: dict) -> None:
    """Where the processing settings ask for the dwell image's joint fit and the fit forks its workers
    (more than one worker thread: not in a sweep's one-thread workers): their spawner forked now
    (``dsp/spawner.py``: before the chain's data exist, so that neither this process nor the workers
    pay for the other's pages), with the fit's modules imported first (the workers need them)."""
    if (proc.get("imaging") == "dwell" and proc.get("dwell_fit") == "joint" and spawner.current() is None
            and worker_threads() > 1):
        importlib.import_module("fwdlook_cli.forward.dwell_fit")
        spawner.start()


def check_settings_for_cube(cube, proc: dict, source: str) -> None:
    """The processing settings the cube itself bounds (``fwdlook validate CUBE --set`` checks them too)."""
    if cube.diff is None:
        raise BadInput(f"{source}: /echo/diff: the forward-looking chain needs both channels")
    if cube.n_pulses % (proc["q"] if proc["method"] == "decimation" else 1):
        raise BadInput(f"{source}: processing.q = {proc['q']}: must divide the cube's pulse count {cube.n_pulses}")
    if proc["cpi"] > cube.n_pulses:
        raise BadInput(f"{source}: processing.cpi = {proc['cpi']}: longer than the cube's {cube.n_pulses} pulses")


def check_cube_overrides(source, cube, overrides) -> None:
    """``fwdlook validate CUBE --set ...``: the settings ``process`` would take from the ``--set``s (the cube
    decides the rest), resolved and checked against the cube as ``process`` checks them."""
    if not overrides:
        return
    from ..scenario.overlay import resolve_with_config

    isar = cube.diff is None or cube.attrs.get("scenario_kind") == "isar"
    scn = resolve_with_config({"name": Path(source).stem, **({"kind": "isar"} if isar else {})}, str(source),
                              None, overrides, check_pulses=False)
    if not isar:           # (auto's plan takes a q that divides the pulses: the q check is decimation's only)
        check_settings_for_cube(cube, scn["processing"], str(source))


def refuse_out_of_core_settings(proc: dict, source: str) -> None:
    """``--out-of-core`` runs the stages that work in blocks only (io/backing.py): the processing settings
    that need whole arrays refused in one line (the CLI calls this before a cube is simulated or read)."""
    if proc.get("backend", "cpu") != "cpu":
        raise BadInput(f"{source}: processing.backend = {proc['backend']} with --out-of-core: the GPU stages "
                       f"take whole arrays; allowed with --out-of-core: processing.backend = cpu")
    if proc.get("doppler_estimator", "fft") != "fft" and proc.get("imaging", "cpi") == "cpi":
        raise BadInput(f"{source}: processing.doppler_estimator = {proc['doppler_estimator']} with "
                       f"--out-of-core: IAA takes whole CPIs of every range cell; allowed with "
                       f"--out-of-core: fft")


@on_one_blas_thread
def process_cube(cube, scn: dict, run_dir: str | Path, *, force=False, from_stage=None, quiet=False,
                 png=True, source: str = "raw cube", keep_stages: str = "all", release_cube: bool = False,
                 stage_cpu: dict | None = None, file_cpu: dict | None = None, scenario_note: str = "",
                 raw_staged: bool = False) -> dict:
    """Run the chain of the resolved scenario's processing settings on ``cube``; returns metrics.
    ``scenario_note``: comment lines that head scenario.yaml (what of it the chain did not use).
    ``stage_cpu``: as :func:`runner.run_stages` (each computed stage's user and system CPU time), and
    ``outputs`` (the metrics, image.h5 and metrics.json).  ``file_cpu``: as :func:`runner.run_stages`
    (the writer thread's CPU time for each stage file).

    The run directory's outputs of an earlier run stay until this chain has finished (a rerun that fails
    or is refused on the way leaves them whole: they and their scenario.yaml are one finished run), are
    removed then, and ``scenario.yaml`` is written last, so the folder never holds outputs that look
    complete for other settings (the stage files carry their own hashes, reused only where they match).

    The BLAS runs on one thread throughout (``dsp/blas.py``: its idle threads spin on the cores the
    stages' own threads need; the command line has it so from its start).
    """
    from .chain import build_forward_stages
    from ..runner import cpu_split_s, run_stages

    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    proc = scn["processing"]
    if proc["method"] == "auto":
        from .plan import plan_for_cube

        proc = dict(proc, **plan_for_cube(cube, proc)["processing"])
    check_settings_for_cube(cube, proc, source)
    if backing.active():
        refuse_out_of_core_settings(proc, source)
    t_start = time.perf_counter()
    try:
        src, stages, geo = build_forward_stages(cube, proc)
    except BadInput as exc:       # the data's own refusals (no calibration from it) name the file too
        raise BadInput(str(exc) if str(exc).startswith(f"{source}:") else f"{source}: {exc}") from None
    names = [st.name for st in stages]
    if "fit_region" in geo:
        start_fit_spawner(proc)
    if from_stage is not None and from_stage not in names:
        raise BadInput(f"--from-stage {from_stage}: unknown stage; allowed: {', '.join(names)}")
    # the dwell-profile metrics read the CPI Doppler spectra, or under imaging: dwell the compensated data
    # (stage 5), whose spectra they compute on the targets' range windows (run_metrics.profile_spectra)
    # (and the echoes' Doppler against the navigation reads the same: forward/echo_navigation.py)
    captured = ({"doppler_spectra": None} if "doppler_spectra" in names else
                {"range_curvature": None} if "range_curvature" in names else {})
    src_key, holder = cube_hash(cube), [src]
    if proc.get("navigation", "recorded") != "recorded":      # the source's track is not the cube's own
        src_key = hashlib.sha256(f"{src_key}|navigation={proc['navigation']}".encode()).hexdigest()
    for key in ("navigation_delay_s", "scan_angle_offset_deg"):   # nor where its time tags or scan angles move
        if proc.get(key, 0.0):
            src_key = hashlib.sha256(f"{src_key}|{key}={float(proc[key])!r}".encode()).hexdigest()
    del src
    if release_cube:         # the CLI's cube: its echoes are needed by stage 1 only (memory: README, Speed);
        # zero-stride stand-ins keep the shapes (n_pulses, n_range) and hold no memory
        cube.sum = np.broadcast_to(np.zeros((), cube.sum.dtype), cube.sum.shape)
        cube.diff = np.broadcast_to(np.zeros((), cube.diff.dtype), cube.diff.shape)
    writes = []            # the last stage files are written while the outputs below are computed
    final, timings, keys = run_stages(stages, holder.pop(), src_key, run_dir, force=force, from_stage=from_stage,
                                      quiet=quiet, keep=keep_stages, captured=captured, pending_writes=writes,
                                      stage_cpu=stage_cpu, file_cpu=file_cpu)
    t_out = time.perf_counter()
    cpu_out = cpu_split_s() if stage_cpu is not None else None
    pending.discard(run_dir, raw=False)      # a killed run's staged outputs (not this run's staged cube)
    pending_png = []
    with pending.discarded_on_failure(run_dir, raw=raw_staged):     # every output staged (io/pending.py)
        try:
            metrics, scenario_yaml = _outputs(cube, scn, proc, run_dir, final, geo, timings, keys, names, captured,
                                              writes, t_start, t_out, png, pending_png, scenario_note)
            if cpu_out is not None:
                cpu_end = cpu_split_s()
                stage_cpu["outputs"] = (cpu_end[0] - cpu_out[0], cpu_end[1] - cpu_out[1])
        finally:
            while writes:                    # waited for even when the outputs failed (then re-raised), a second
                signals.call_held(writes.pop())   # signal held meanwhile (runner.run_stages)
            signals.raise_pending()
            while pending_png:               # begun and not finished: the outputs failed, no PNG left
                pending_png.pop().discard()
        atomic_write_text(pending.staged(run_dir, "scenario.yaml"), scenario_note + scenario_yaml)
        pending.commit(run_dir, raw=raw_staged)      # the earlier run's outputs replaced, scenario.yaml last
    return metrics


def _start_quicklook(run_dir, final, truth, scn, proc, geo):
    """image.png begun (:func:`io.quicklook.start_image_png`): the image's rows that hold anything, the
    truth as circles (at t_ref: the metrics' ``true_azimuth_deg``, ``true_range_m``)."""
    from ..io.quicklook import start_image_png
    from .evaluate import truth_at_t_ref

    markers = None
    if truth is not None:
        r_true, az_true = truth_at_t_ref(truth, np.asarray(geo["p_ref"]))
        markers = (az_true, r_true)
    sel = np.any(final["image"] > 0, axis=1)
    rows_idx = np.nonzero(sel)[0]
    lo, hi = (rows_idx[0], rows_idx[-1] + 1) if len(rows_idx) else (0, len(final["range_m"]))
    return start_image_png(pending.staged(run_dir, "image.png"), final["image"][lo:hi], final["angle_deg"],
                           final["range_m"][lo:hi],
                           xlabel="azimuth at t_ref (deg)", ylabel="slant range at t_ref (m)",
                           title=f"{scn['name']}: {proc['method']} (q={geo['q']}, "
                                 f"{proc['keystone']}), t_ref = {proc['t_ref']}", markers=markers)


def _strong_column_spectra(compensated, geo, bandwidth_hz: float):
    """Both channels' CPI spectra on the compensated data's strongest range columns (imaging: dwell)."""
    from .echo_navigation import echo_margin_cells, strong_columns
    from .run_metrics import column_spectra

    return column_spectra(compensated, geo["doppler_params"], strong_columns(compensated, margin=echo_margin_cells(
        compensated["range_m"], C_MPS / (2.0 * bandwidth_hz))), channels=("sum", "diff"))


def _echo_navigation(spectra_of, cube, proc, geo) -> dict:
    """metrics.json's ``echo_navigation`` of the CPI Doppler spectra ``spectra_of()`` (formed only where
    they are read), its warnings logged."""
    from .echo_navigation import echo_navigation_of, echo_navigation_warnings

    if not proc["doppler_centroid"]:      # the CPI bands then follow the initial velocity: the echoes' Doppler
        # falls outside them and aliases by whole PRFs (-5 kHz on the paper cube), so there is nothing to read
        return {"cells": 0, "doppler_offset_hz": None,
                "not_read": "processing.doppler_centroid false: the CPI Doppler bands do not follow the track"}
    check = echo_navigation_of(spectra_of(), geo["calibration"], fc_hz=float(cube.radar["fc_hz"]),
                               beamwidth_deg=float(cube.radar["beamwidth_3db_deg"]), prf_hz=float(cube.radar["prf_hz"]),
                               cpi=int(proc["cpi"]), position_ref_m=geo["p_ref"],
                               speed_mps=float(np.linalg.norm(geo["v_ref"])),
                               range_spacing_m=float(cube.range_spacing_m),
                               range_resolution_m=C_MPS / (2.0 * float(cube.radar["bandwidth_hz"])),
                               range_error_m=float(geo.get("range_error_m", 0.0)))
    for line in echo_navigation_warnings(check, range_spacing_m=float(cube.range_spacing_m),
                                         angle_step_deg=float(proc["angle_step_deg"]),
                                         delay_set_s=float(proc.get("navigation_delay_s", 0.0)),
                                         scan_offset_set_deg=float(proc.get("scan_angle_offset_deg", 0.0))):
        log.warning(line)
    return check


def _outputs(cube, scn, proc, run_dir, final, geo, timings, keys, names, captured, writes, t_start, t_out, png,
             pending_png, scenario_note=""):
    """image.h5, metrics.json, image.png of a finished chain; returns (metrics, scenario YAML).
    ``pending_png``: a list that holds image.png while it is drawn (the caller discards it on failure)."""
    from .chain import KEYSTONE_METHODS
    from .evaluate import summarize
    from .run_metrics import target_rows

    truth = cube.truth_xyz_m()
    if png:        # begun first: a painter running (io/painter.py) draws it beside the metrics and files
        # below; without one it is drawn at the end, once the Doppler spectra are released
        pending_png.append(_start_quicklook(run_dir, final, truth, scn, proc, geo))
    ground, gx, gy = ground_image(final["cell_x_m"], final["cell_y_m"], final["cell_power"],
                                  step_m=float(cube.range_spacing_m) / 2)
    packed = {name: GzipChunks(a) for name, a in (("image", final["image"]), ("real_beam", final["real_beam"]),
                                                  ("ground_image", ground)) if a.ndim == 2 and a.size}
    # the Doppler spectra (2 x the cube, in memory when this run computed them), or under imaging: dwell
    # the compensated data: the only reference left is the one target_rows reads and drops
    spectra_of, compensated_of = captured.pop("doppler_spectra", None), captured.pop("range_curvature", None)
    # the echoes' Doppler against the navigation's, from the same spectra (or compensated data), read once:
    # target_rows takes them from the holder, which then drops them
    echo_nav = None
    if spectra_of is not None:
        held = [spectra_of()]
        echo_nav, spectra_of = _echo_navigation(lambda: held[0], cube, proc, geo), held.pop
    elif compensated_of is not None:
        held = [compensated_of()]
        echo_nav = _echo_navigation(lambda: _strong_column_spectra(held[0], geo, float(cube.radar["bandwidth_hz"])),
                                    cube, proc, geo)
        compensated_of = held.pop
    held = None
    rows, islr_from = target_rows(cube, final, proc, geo, spectra_of=spectra_of, compensated_of=compensated_of)
    spectra_of = compensated_of = None
    scenario_yaml = dump_scenario(scn)
    waited = sum(writes.pop()() for _ in range(len(writes)))       # every stage file written before these
    # (image.h5 carries scenario.yaml's note too: a recorded cube's unused default radar had read as its own)
    write_image_h5(pending.staged(run_dir, "image.h5"), final, ground, gx, gy,
                   scenario_yaml=scenario_note + scenario_yaml,
                   t_ref_s=geo["t_ref_s"], method=proc["method"], packed=packed)
    del packed
    timings["outputs"] = time.perf_counter() - t_out - waited      # (the wait counts to the last stage)
    timing = {k: float(v) for k, v in timings.items()}
    timing["total"] = time.perf_counter() - t_start
    metrics = {
        "fwdlook_version": __version__,
        "scenario": scn["name"],
        "method": proc["method"],
        # what ran: the keystone implementation of a keystone method (None for none, bulk, beam), the
        # curvature stage's model ("off" where the method or the setting skips it)
        "params": {"q": geo["q"], "keystone": proc["keystone"] if proc["method"] in KEYSTONE_METHODS else None,
                   "range_curvature": geo["curvature_model"] != "off", "curvature_model": geo["curvature_model"],
                   "t_ref": proc["t_ref"],
                   "doppler_centroid": bool(proc["doppler_centroid"]), "cpi": proc["cpi"],
                   "imaging": proc.get("imaging", "cpi"), "doppler_estimator": proc.get("doppler_estimator", "fft"),
                   "ambiguity_number": geo["ambiguity_number"],
                   "boresight_doppler_hz": geo["f_dc0_hz"], "depression_deg": geo["depression_deg"],
                   "radial_accel_mps2": geo["radial_accel_mps2"],
                   "doppler_spread_hz": geo.get("doppler_spread_hz"),
                   # the keystone stage's range sub-swaths (1: one reference depression for the window)
                   "subswaths": geo.get("subswaths", 1),
                   "navigation": proc.get("navigation", "recorded"),
                   "navigation_delay_s": float(proc.get("navigation_delay_s", 0.0)),
                   "scan_angle_offset_deg": float(proc.get("scan_angle_offset_deg", 0.0)),
                   # the zoomed Doppler cells per CPI (n_doppler: auto resolved), where a CPI Doppler stage ran
                   "n_doppler": geo.get("n_doppler") if "doppler_spectra" in names else None,
                   # the image's range oversampling (range_oversample: auto resolved)
                   "range_oversample": geo.get("range_oversample")},
        "t_ref_s": geo["t_ref_s"],
        "calibration": geo["calibration"].to_json(),
        "scenario_sha256": scenario_hash(scn),
        "stage_sha256": keys,
        "targets": rows,
        "summary": ({**summarize(rows), "islr_from": islr_from} if rows else {"n_targets": 0, "detected": 0}),
        "timing_s": timing,
    }
    if echo_nav is not None:      # the echoes' Doppler against the navigation's (forward/echo_navigation.py)
        metrics["echo_navigation"] = echo_nav
    if scn["scene"]["kind"] == "image":                  # extended scene: metrics against its map
        from .scene_metrics import scene_metrics

        metrics["scene"] = scene_metrics(final["image"], final["range_m"], final["angle_deg"], geo["p_ref"], scn)
    atomic_write_text(pending.staged(run_dir, "metrics.json"), json_text(metrics))
    if pending_png:
        pending_png.pop().finish()
    return metrics, scenario_yaml
