"""``make bench`` / ``fwdlook bench``: timings measured in one process, reported as ratios.

These machines are noisy, so every figure is the median of several repeats and is also given as a
ratio to one plain 2-D FFT of the same cube (``fft2_s``) measured in the same process.
"""
from __future__ import annotations

import json
import logging
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import scipy.fft

SCENARIOS = Path(__file__).resolve().parents[2] / "scenarios"
log = logging.getLogger(__name__)
_T0 = [0.0]


def _step(i: int, n: int, what: str) -> None:
    """Progress on stderr (logging): step i of n, elapsed time."""
    if i == 1:
        _T0[0] = time.perf_counter()
    log.info(f"bench [{i}/{n}] {what} ({time.perf_counter() - _T0[0]:.1f} s elapsed)")


def _median_time(fn, repeats=5):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def run_bench(paper_scenario=SCENARIOS / "paper_fig6_a50.yaml", tiny_scenario=SCENARIOS / "tiny.yaml"):
    """All timings in one process, so that the ratios to ``fft2_s`` are meaningful."""
    import tempfile

    from ..forward.chain import build_forward_stages
    from ..scenario.loader import load_scenario
    from ..dsp.keystone_czt import KeystonePlan
    from ..dsp.keystone import keystone_dft, keystone_sinc
    from ..forward.process import process_cube
    from ..forward.simulate import simulate_scenario

    n = 9
    _step(1, n, "simulating the paper cube")
    paper = load_scenario(paper_scenario)
    tiny = load_scenario(tiny_scenario)
    cube, stats = simulate_scenario(paper)
    out = {"cube_shape": list(cube.sum.shape), "n_targets": int(len(cube.truth["x_m"])),
           "pairs_kept": stats.n_pairs_kept, "pairs_total": stats.n_pairs}
    x = cube.sum
    _step(2, n, "plain 2-D FFT and simulation timings")
    out["fft2_s"] = _median_time(lambda: scipy.fft.fft2(x, workers=-1), repeats=21)
    out["simulate_s"] = _median_time(lambda: simulate_scenario(paper), repeats=3)
    out["simulate_tiny_s"] = _median_time(lambda: simulate_scenario(tiny), repeats=5)

    # keystones on the sum channel in the paper's decimated layout (Q = 25, P = 100 pulses)
    _step(3, n, "CZT keystone (Q = 25 layout)")
    proc = dict(paper["processing"], method="decimation", q=25)
    src, stages, geo = build_forward_stages(cube, proc)
    data = src
    for st in stages[:2]:
        data = st.fn(data, **st.params)
    p_len, q, n_f = data["sum_f"].shape
    sub = np.ascontiguousarray(data["sum_f"].reshape(p_len, q * n_f))
    fr = data["fr_hz"]
    alpha = np.tile(cube.radar["fc_hz"] / (cube.radar["fc_hz"] + fr), q)
    t0 = np.repeat((geo["t_ref_s"] * cube.radar["prf_hz"] - np.arange(q)) / q, n_f)
    ks = stages[2].params
    t_build = time.perf_counter()
    plan = KeystonePlan(p_len, alpha, t0_index=t0)
    out["keystone_czt_plan_s"] = time.perf_counter() - t_build
    plan(sub, ambiguity=ks["ambiguity"])                   # output chirp of this F, cached
    out["keystone_czt_s"] = _median_time(lambda: plan(sub, ambiguity=ks["ambiguity"]), repeats=15)
    # complex64 is enough: the same keystone in complex128 differs by this much (energy ratio)
    y64 = plan(sub, ambiguity=ks["ambiguity"]).astype(np.complex128)
    y128 = KeystonePlan(p_len, alpha, t0_index=t0, dtype=np.complex128)(sub.astype(np.complex128),
                                                                        ambiguity=ks["ambiguity"])
    out["keystone_c64_vs_c128_db"] = float(10 * np.log10(np.sum(np.abs(y64 - y128) ** 2) / np.sum(np.abs(y128) ** 2)))
    _step(4, n, "direct DFT keystone, O(M^2): the slow one")
    out["keystone_dft_s"] = _median_time(lambda: keystone_dft(sub, alpha, t0_index=t0, ambiguity=ks["ambiguity"]),
                                         repeats=1)
    _step(5, n, "demodulated sinc keystone")
    ref = ks["doppler_ref_hz"] / (cube.radar["prf_hz"] / q)
    out["keystone_sinc_s"] = _median_time(lambda: keystone_sinc(sub, alpha, t0_index=t0, doppler_ref=ref),
                                          repeats=1)

    # whole chains, both channels, every intermediate written
    # (dwell: the tracking chain with processing.imaging = dwell, forward/dwell.py)
    for step, (method, imaging) in enumerate((("decimation", "cpi"), ("tracking", "cpi"), ("dwell", "dwell")), 6):
        _step(step, n, f"whole chain, {method}, intermediates written")
        proc = dict(paper["processing"], method="tracking" if method == "dwell" else method, imaging=imaging)
        scn = dict(paper, processing=proc)
        with tempfile.TemporaryDirectory() as tmp:
            metrics = process_cube(cube, scn, tmp, force=True, quiet=True, png=False)
        key = "chain_s" if method == "decimation" else f"chain_{method}_s"
        out[key] = metrics["timing_s"]["total"]
        for stage, seconds in metrics["timing_s"].items():
            if stage != "total":
                out[f"stage_{method}_{stage}_s"] = seconds
    _step(9, n, "done")
    out["ratios_to_fft2"] = {k[:-2]: out[k] / out["fft2_s"] for k in list(out) if k.endswith("_s")
                             and k != "fft2_s" and not k.startswith("stage_")}
    return out


def print_bench(as_json: bool = False, scene: bool = False) -> None:
    result = run_bench()
    if scene:                                  # scene_bench.py: one child process per scene size
        from .scene_bench import run_scene_bench

        result.update(run_scene_bench())
    if as_json:
        print(json.dumps(result, indent=2))
    else:
        for key, value in result.items():
            if key == "ratios_to_fft2":
                for k, v in value.items():
                    print(f"  {k:<22s} {v:10.1f} x fft2")
            elif isinstance(value, dict):
                for k, v in value.items():
                    print(f"{key}[{k}]".ljust(24) + f" {v:10.1f}")
            elif key.endswith("_db"):
                print(f"{key:<24s} {value:10.1f} dB")
            elif isinstance(value, float):
                print(f"{key:<24s} {value * 1e3:10.2f} ms")
            else:
                print(f"{key:<24s} {value}")


if __name__ == "__main__":
    print_bench("--json" in sys.argv[1:])
