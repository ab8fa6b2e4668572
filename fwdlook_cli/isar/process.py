"""ISAR run directory: stages, image.h5, image.png, metrics.json (I/O at the edge)."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..io.stagefile import StageData
from .chain import build_isar_stages
from .evaluate import isar_outputs


# ----------------------------------------------------------------------------------------------
# Run directory (called by ``fwdlook run`` / ``fwdlook process`` for kind: isar)
# ----------------------------------------------------------------------------------------------
def process_isar_cube(cube, scn: dict, run_dir, *, force=False, from_stage=None, quiet=False,
                      png=True, scenario_note: str = "", raw_staged: bool = False) -> dict:
    """Run the ISAR chain with its stage files, write image.h5, image.png and metrics.json
    (``scenario_note``: comment lines that head scenario.yaml)."""
    from ..scenario.loader import dump_scenario, scenario_hash
    from ..io.h5 import atomic_h5, atomic_write_text, json_text, put, put_scale
    from ..runner import run_stages
    from ..io.cube import cube_hash

    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    proc = scn["processing"]
    t_start = time.perf_counter()
    src, stages = build_isar_stages(cube, proc)
    names = [st.name for st in stages]
    if from_stage is not None and from_stage not in names:
        from ..errors import BadInput

        raise BadInput(f"--from-stage {from_stage}: unknown stage; allowed: {', '.join(names)}")
    final, timings, keys = run_stages(stages, src, cube_hash(cube), run_dir, force=force,
                                      from_stage=from_stage, quiet=quiet)
    from ..io import pending

    pending.discard(run_dir, raw=False)     # a killed run's staged outputs; each output staged (io/pending.py)
    with pending.discarded_on_failure(run_dir, raw=raw_staged):
        t_out = time.perf_counter()
        image, metrics = isar_outputs(final, cube, proc)
        with atomic_h5(pending.staged(run_dir, "image.h5")) as f:
            for k, v in image.attrs.items():
                f.attrs[k] = v
            f.attrs["scenario"] = dump_scenario(scn)
            r = put_scale(f, "range_m", image["range_m"], "m", image.vars["range_m"].long_name)
            d = put_scale(f, "doppler_hz", image["doppler_hz"], "Hz", image.vars["doppler_hz"].long_name)
            put(f, "cross_range_m", image["cross_range_m"], "m", image.vars["cross_range_m"].long_name, dims=(d,))
            put(f, "image", image["image"], "1", image.vars["image"].long_name, dims=(r, d))
        timings["outputs"] = time.perf_counter() - t_out
        timing = {k: float(v) for k, v in timings.items()}
        timing["total"] = time.perf_counter() - t_start
        metrics.update(scenario=scn["name"], scenario_sha256=scenario_hash(scn), stage_sha256=keys,
                       timing_s=timing)
        atomic_write_text(pending.staged(run_dir, "metrics.json"), json_text(metrics))
        if png:
            _save_image_quicklook(pending.staged(run_dir, "image.png"), image,
                                  title=f"{scn['name']}: ISAR {proc['correction']}")
        atomic_write_text(pending.staged(run_dir, "scenario.yaml"), scenario_note + dump_scenario(scn))
        pending.commit(run_dir, raw=raw_staged)       # the earlier run's outputs replaced, scenario.yaml last
    return metrics


def _save_image_quicklook(path, image: StageData, *, title, half_bins=48):
    from ..io.quicklook import save_image_png

    p = image["image"]
    i, j = np.unravel_index(int(np.argmax(p)), p.shape)
    lo, hi = max(0, j - half_bins), min(p.shape[1], j + half_bins + 1)
    x = image["cross_range_m"][lo:hi]
    label = "cross-range (m)"
    if not np.all(np.isfinite(x)):
        x, label = image["doppler_hz"][lo:hi], "Doppler (Hz)"
    order = np.argsort(x)
    save_image_png(path, p[:, lo:hi][:, order], x[order], image["range_m"], xlabel=label,
                   ylabel="slant range at t_ref (m)", title=title)
