"""``make bench`` / ``fwdlook bench``: timings measured in one process, reported as ratios.

These machines are noisy, so every figure is the median of several repeats and is also given as a
ratio to one plain 2-D FFT of the same cube (``fft2_s``) measured in the same process.
"""
from __future__ import annotations

import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import scipy.fft

SCENARIOS = Path(__file__).resolve().parent.parent / "scenarios"


def _median_time(fn, repeats=5):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def run_bench(paper_scenario=SCENARIOS / "paper_fig6_a50.yaml", tiny_scenario=SCENARIOS / "tiny.yaml"):
    from .config import load_scenario
    from .simulate import simulate_scenario

    paper = load_scenario(paper_scenario)
    tiny = load_scenario(tiny_scenario)
    cube, stats = simulate_scenario(paper)
    out = {"cube_shape": list(cube.sum.shape), "n_targets": int(len(cube.truth["x_m"])),
           "pairs_kept": stats.n_pairs_kept, "pairs_total": stats.n_pairs}
    x = cube.sum
    out["fft2_s"] = _median_time(lambda: scipy.fft.fft2(x, workers=-1), repeats=9)
    out["simulate_s"] = _median_time(lambda: simulate_scenario(paper), repeats=3)
    out["simulate_tiny_s"] = _median_time(lambda: simulate_scenario(tiny), repeats=5)
    out["ratios_to_fft2"] = {k[:-2]: out[k] / out["fft2_s"] for k in list(out) if k.endswith("_s")
                             and k != "fft2_s"}
    return out


def print_bench(as_json: bool = False) -> None:
    result = run_bench()
    if as_json:
        print(json.dumps(result, indent=2))
    else:
        for key, value in result.items():
            if key == "ratios_to_fft2":
                for k, v in value.items():
                    print(f"  {k:<22s} {v:10.1f} x fft2")
            elif isinstance(value, float):
                print(f"{key:<24s} {value * 1e3:10.2f} ms")
            else:
                print(f"{key:<24s} {value}")


if __name__ == "__main__":
    print_bench("--json" in sys.argv[1:])
