"""``fwdlook bench --scene``: scene-simulator time and peak memory against the number of scatterers.

Each size runs in its own child process (``python -m fwdlook_cli.report.scene_bench --one N``), which
simulates N scatterers of random position (uniform over the 600 m x 600 m Fig. 8 scene area centred
at ground (0, 1700) m) and random phase, with the paper radar and motion (``paper_fig6_a50.yaml``:
2500 pulses, a = 50 m/s^2, -60 dB gain gate), both channels, no noise, and reports the wall time of
the simulation (range axis included) and its own peak RSS (``resource.getrusage(RUSAGE_SELF)``:
the whole process, Python and numpy included).
"""
from __future__ import annotations

import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

SIZES = (1_000, 10_000, 100_000, 1_000_000)
SCENARIO = Path(__file__).resolve().parents[2] / "scenarios" / "paper_fig6_a50.yaml"
AREA_X_M = (-300.0, 300.0)
AREA_Y_M = (1400.0, 2000.0)


def run_one(n_scatterers: int, seed: int = 0, **kwargs) -> dict:
    from ..dsp.antenna import MonopulseAntenna
    from ..scenario.loader import load_scenario
    from ..dsp.geometry import scan_angle_deg
    from ..scenario.forward import scene_geometry
    from ..dsp.pulse import CompressedPulse
    from ..dsp.geometry import range_extent_m
    from ..forward.scene_sim import simulate_scene_echo
    from ..dsp.pulse import auto_range_axis_m

    scn = load_scenario(SCENARIO)
    radar, ant = scn["radar"], scn["antenna"]
    t, pos, _, _, _ = scene_geometry(scn)
    rng = np.random.default_rng(seed)
    n = int(n_scatterers)
    tg = np.column_stack([rng.uniform(*AREA_X_M, n), rng.uniform(*AREA_Y_M, n), np.zeros(n)])
    amps = np.exp(2j * np.pi * rng.uniform(size=n))
    pulse = CompressedPulse(radar["bandwidth_hz"], radar["pulse_width_s"], radar["fs_hz"])
    antenna = MonopulseAntenna(ant["beamwidth_3db_deg"], ant["squint_deg"])
    beam = scan_angle_deg(t, ant["scan_start_deg"], ant["scan_rate_dps"])
    t0 = time.perf_counter()
    c0 = time.process_time()
    rm = auto_range_axis_m(*range_extent_m(pos, tg), radar["fs_hz"], pulse, positive=True)
    es, ed, st = simulate_scene_echo(t, pos, beam, rm, tg, amps, fc_hz=radar["fc_hz"], pulse=pulse,
                                     antenna=antenna, gain_threshold_db=scn["simulation"]["gain_threshold_db"],
                                     **kwargs)
    wall = time.perf_counter() - t0
    cpu = time.process_time() - c0
    return {"n": n, "seconds": wall, "cpu_seconds": cpu, "pairs_kept": st.n_pairs_kept,
            "cube_shape": list(es.shape),
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}


def run_scene_bench(sizes=SIZES, timeout_s=1800) -> dict:
    """``scene_sim_s`` and ``scene_sim_peak_rss_mb`` (count -> value), one child process per size."""
    out = {"scene_sim_s": {}, "scene_sim_cpu_s": {}, "scene_sim_peak_rss_mb": {}, "scene_sim_pairs": {}}
    for n in sizes:
        proc = subprocess.run([sys.executable, "-m", "fwdlook_cli.report.scene_bench", "--one", str(int(n))],
                              capture_output=True, text=True, timeout=timeout_s, check=True)
        rec = json.loads(proc.stdout.strip().splitlines()[-1])
        key = f"{int(n):.0e}".replace("e+0", "e")
        out["scene_sim_s"][key] = rec["seconds"]
        out["scene_sim_cpu_s"][key] = rec["cpu_seconds"]
        out["scene_sim_peak_rss_mb"][key] = rec["peak_rss_mb"]
        out["scene_sim_pairs"][key] = rec["pairs_kept"]
        print(f"scene bench: {n} scatterers {rec['seconds']:.1f} s, {rec['peak_rss_mb']:.0f} MB",
              file=sys.stderr, flush=True)
    return out


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--one":
        print(json.dumps(run_one(int(float(sys.argv[2])))))
    else:
        sizes = [int(float(s)) for s in sys.argv[1:]] or SIZES
        print(json.dumps(run_scene_bench(sizes), indent=1))
