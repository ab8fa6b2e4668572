"""``make bench`` / ``fwdlook bench``: timings measured in one process, reported as ratios.

These machines are noisy, so every figure is the median of several repeats and is also given as a
ratio to one plain 2-D FFT of the same cube (``fft2_s``) measured in the same process.
"""
from __future__ import annotations

import importlib
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


from .bench_pages import page_cost
from .benchtools import (chain_peak_rss, clean_process_fft2, command_runs, environment, median_time as _median_time,
                         time_chain, wall_times as _times)

FFT2_REPEATS = 21          # the reference: median of at least 20 plain 2-D FFTs, before and after
FFT2_BETWEEN = 3           # and this many before each chain run of the rounds (after one untimed)
CLEAN_PROCESSES = 3        # plain interpreters timing the reference, before and after the chains each


def run_bench(paper_scenario=SCENARIOS / "paper_fig6_a50.yaml", tiny_scenario=SCENARIOS / "tiny.yaml",
              chain_repeats: int = 3):
    """All timings in one process, so that the ratios to ``fft2_s`` are meaningful.

    ``chain_s`` / ``chain_tracking_s`` and every ``stage_<method>_<stage>_s`` are medians over
    ``chain_repeats`` runs of the chain exactly as ``fwdlook process`` runs it (plans built inside the
    stage, stage files written); ``chain_<method>_keep_none_s`` the same CPI chains with
    ``--keep-stages none`` (no stage file: their difference is what the files cost);
    ``chain_<method>_peak_rss_x_cube`` is its peak RSS above the RSS before it, as a multiple of the
    cube (both channels), and ``chain_<method>_peak_rss_over_tiny_peak_x_cube`` the same above the
    tiny run's own peak (the README's ``/usr/bin/time`` base); ``chain_<method>_cores_busy`` the process's CPU time during the chain over
    its wall time (median of the rounds), ``chain_<method>_user_cpu_ms`` and ``_system_cpu_ms`` that CPU
    time split into the process's own code and the kernel's work for it (medians, in ms: not ratios),
    and ``chain_<method>_stage_files_user_cpu_ms`` and ``_system_cpu_ms`` the part of it that the
    stage-file writer thread spent on its own (every file's HDF5 objects and bytes; Linux);
    ``command_<method>_s`` the wall time of ``fwdlook process`` of the same cube in a fresh interpreter
    and ``command_<method>_chain_s`` the (cold) chain inside it (:func:`benchtools.command_runs`);
    ``page_cost`` what a new page costs this machine, probed before the cube is simulated
    (:func:`bench_pages.page_cost`: ms per MiB, and the kernel's free page reporting)."""
    from ..forward.chain import build_forward_stages
    from ..forward.process import start_fit_spawner
    from ..scenario.loader import load_scenario
    from ..dsp.keystone_czt import KeystonePlan
    from ..dsp.keystone import keystone_dft, keystone_sinc
    from ..forward.simulate import simulate_scenario

    n = 12
    # the dwell chain's joint fit forks its workers from a spawner (dsp/spawner.py), which the command
    # forks before it reads the cube: here before the cube is simulated
    start_fit_spawner({"imaging": "dwell", "dwell_fit": "joint"})
    _step(1, n, "what a new page costs here; simulating the paper cube")
    page_probe = page_cost()                 # bench_pages.py: before the cube and the chains touch memory
    paper = load_scenario(paper_scenario)
    tiny = load_scenario(tiny_scenario)
    cube, stats = simulate_scenario(paper)
    out = {"cube_shape": list(cube.sum.shape), "n_targets": int(len(cube.truth["x_m"])),
           "pairs_kept": stats.n_pairs_kept, "pairs_total": stats.n_pairs, "page_cost": page_probe}
    x = cube.sum
    _step(2, n, "plain 2-D FFT and simulation timings")
    scipy.fft.fft2(x, workers=-1)                          # warm-up: scipy's plan cache, pages
    fft2_times = _times(lambda: scipy.fft.fft2(x, workers=-1), FFT2_REPEATS)
    out["fft2_s"] = statistics.median(fft2_times)
    # and in plain interpreters beside this one, before and after the chains (benchtools.clean_process_fft2)
    clean_before = clean_process_fft2(x, FFT2_REPEATS, CLEAN_PROCESSES)
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
    out["keystone_czt_with_plan_s"] = _median_time(
        lambda: KeystonePlan(p_len, alpha, t0_index=t0)(sub, ambiguity=ks["ambiguity"]), repeats=5)
    out["keystone_czt_plan_s"] = _median_time(lambda: KeystonePlan(p_len, alpha, t0_index=t0), repeats=5)
    plan = KeystonePlan(p_len, alpha, t0_index=t0)
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

    # whole chains, both channels, as `fwdlook process` runs them (medians of chain_repeats runs);
    # dwell: the tracking chain with processing.imaging = dwell and the joint fit near the flight axis
    # (the tracking preset, forward/dwell.py, dwell_fit.py); dwell_nofit: the same without the fit.
    # The repeats are interleaved (round r runs every chain once), so that a drift of the machine's
    # speed during the bench falls on every chain alike; the dwell / tracking ratio is also the median
    # of the rounds' own ratios
    chains = (("decimation", "cpi", "none"), ("tracking", "cpi", "none"), ("dwell", "dwell", "joint"),
              ("dwell_nofit", "dwell", "none"))
    scenarios = {}
    for method, imaging, fit in chains:
        proc = dict(paper["processing"], method="tracking" if imaging == "dwell" else method, imaging=imaging,
                    dwell_fit=fit)
        scenarios[method] = dict(paper, processing=proc)
    rounds = {method: [] for method in scenarios}
    # the same CPI chains with --keep-stages none: what writing the stage files costs the chain
    no_files = {f"{method}_keep_none": scenarios[method] for method in ("decimation", "tracking")}
    rounds.update({key: [] for key in no_files})
    importlib.import_module("fwdlook_cli.forward.dwell")     # imported before the clock runs: not the chain's
    _step(6, n, f"whole chains as fwdlook process runs them, {chain_repeats} interleaved rounds")
    # the reference is also sampled between the chain runs: a 2-D FFT of a few ms samples the machine's
    # speed of that moment (its medians of 21 before and 21 after the chains differ by up to 2.6 x here,
    # while a chain of 200-270 ms averages it), so the reference sees the moments the chains see
    fft2_between = []

    def reference_between():
        scipy.fft.fft2(x, workers=-1)                      # untimed: the chain's memory had the caches
        fft2_between.extend(_times(lambda: scipy.fft.fft2(x, workers=-1), FFT2_BETWEEN))

    for r in range(max(1, int(chain_repeats))):
        for method, scn in scenarios.items():
            reference_between()
            rounds[method].append(time_chain(cube, scn, repeats=1, rss=False))
        for key, scn in no_files.items():
            reference_between()
            rounds[key].append(time_chain(cube, scn, repeats=1, rss=False, keep_stages="none"))
        log.info(f"  round {r + 1}: " + ", ".join(f"{m} {v[-1]['total_s']:.2f} s" for m, v in rounds.items()))
    for key in no_files:
        out[f"chain_{key}_s"] = statistics.median(t["total_s"] for t in rounds[key])
    # the cores a chain keeps busy: its process's CPU time (every thread) over its wall time, median
    # of the rounds (2.0 on two cores would be every core busy all the time)
    # and where that CPU goes: the user's code (numpy, pocketfft, HDF5, Python) or the kernel's work for
    # the process (page faults on first-touched memory, the stage files' copies into the page cache)
    for key, runs in rounds.items():
        busy = [t["cores_busy"] for t in runs if t.get("cores_busy") is not None]
        out[f"chain_{key}_cores_busy"] = statistics.median(busy) if busy else None
        for clock in ("user", "system"):
            spent = [t[f"{clock}_cpu_s"] for t in runs if t.get(f"{clock}_cpu_s") is not None]
            out[f"chain_{key}_{clock}_cpu_ms"] = 1e3 * statistics.median(spent) if spent else None
            # of which the stage-file writer thread's own (every file's HDF5 objects and bytes)
            files = [t[f"stage_files_{clock}_cpu_s"] for t in runs if t.get(f"stage_files_{clock}_cpu_s") is not None]
            if files:
                out[f"chain_{key}_stage_files_{clock}_cpu_ms"] = 1e3 * statistics.median(files)
    _step(7, n, "peak memory of each chain (a fresh interpreter each)")
    bases = []
    for method in scenarios:
        key = "chain_s" if method == "decimation" else f"chain_{method}_s"
        out[key] = statistics.median(t["total_s"] for t in rounds[method])
        for stage in rounds[method][0]["stages_s"]:
            out[f"stage_{method}_{stage}_s"] = statistics.median(t["stages_s"][stage] for t in rounds[method])
        t = chain_peak_rss(cube, scenarios[method])
        out[f"chain_{method}_peak_rss_x_cube"] = t["peak_rss_x_cube"]
        out[f"chain_{method}_peak_rss_over_tiny_peak_x_cube"] = t["peak_rss_over_tiny_peak_x_cube"]
        out[f"chain_{method}_peak_rss_mib"] = (None if t["peak_rss_above_base_bytes"] is None
                                               else t["peak_rss_above_base_bytes"] / 2**20)
        bases.append((t.get("interpreter_base_bytes") or 0) / 2**20)
    out["interpreter_base_mib"] = statistics.median(bases)    # each probe's fresh interpreter, their median
    out["chain_dwell_over_tracking"] = statistics.median(
        d["total_s"] / t["total_s"] for d, t in zip(rounds["dwell"], rounds["tracking"]))
    # the CPI chains as one-shot commands: a fresh `fwdlook process` each, its chain cold (imports on
    # first use, FFT plans, first-touched memory); the command's wall time is what a user waits for
    _step(8, n, f"fwdlook process as a command, {chain_repeats} fresh interpreters per chain")
    commands = command_runs(cube, {method: {"method": method, "imaging": "cpi", "dwell_fit": "none"}
                                   for method in ("decimation", "tracking")}, repeats=chain_repeats)
    for method, t in commands.items():
        out[f"command_{method}_s"] = t["wall_s"]
        out[f"command_{method}_chain_s"] = t["chain_s"]
    # the floor: the transforms and stage-file bytes the chain cannot avoid, timed alone (bench_floor.py)
    from .bench_floor import chain_floor

    _step(9, n, "the floor: the chain's transforms and stage bytes alone")
    for method in ("decimation", "tracking"):
        n_doppler, range_oversample = _resolved_image_sizes(paper, cube, method)
        floor = chain_floor(*cube.sum.shape, method=method, q=paper["processing"]["q"],
                            cpi=paper["processing"]["cpi"], n_doppler=n_doppler, range_oversample=range_oversample)
        for item, seconds in floor.items():
            out[f"floor_{method}_{item}"] = seconds
        # how near the chain is to its floor: both long (70-210 ms) and timed in the same process, so the
        # quotient does not inherit the moment of a reference of a few ms (issue 11's 35 x an fft2 is
        # 35 / (floor / fft2) x this floor)
        chain_key = "chain_s" if method == "decimation" else f"chain_{method}_s"
        out[f"chain_{method}_over_floor"] = out[chain_key] / floor["total_s"]
    # the reference and the CPI chains again with every thread on one core (bench_cores.py): the
    # chain's work apart from how it spreads over the cores, and what the second core buys each
    _step(10, n, "the reference and the CPI chains on one core")
    from .bench_cores import one_core_timings, second_core_gains

    one_core = {"chain": scenarios["decimation"], "chain_tracking": scenarios["tracking"]}
    out["one_core"] = one_core_timings(
        x, one_core, lambda scn: time_chain(cube, scn, repeats=1, rss=False)["total_s"],
        fft2_repeats=FFT2_REPEATS, fft2_between=FFT2_BETWEEN, rounds=chain_repeats)
    # the reference again after the chains (load drifts on a shared machine): median of both sets
    _step(11, n, "plain 2-D FFT again")
    fft2_after = _times(lambda: scipy.fft.fft2(x, workers=-1), FFT2_REPEATS)
    out["fft2_median_before_after"] = [out["fft2_s"], statistics.median(fft2_after)]
    out["fft2_median_between_chains"] = statistics.median(fft2_between)
    out["fft2_s"] = statistics.median(fft2_times + fft2_between + fft2_after)
    out["fft2_repeats"] = len(fft2_times) + len(fft2_between) + len(fft2_after)
    if out["one_core"]:                     # each one-core time over this run's own (fft2_s now complete)
        out["one_core"].update(second_core_gains(out["one_core"], out))
    # the same fft2 on one thread: what the reference gains from this machine's second core (2.8 ms on
    # two free cores against 5.6 ms on one: docs/SPEED_HISTORY.md, seventh round), which every ratio
    # above inherits while the chain keeps 1.4-1.6 cores busy; its ratio to fft2_s is that gain
    out["fft2_one_thread_s"] = statistics.median(_times(lambda: scipy.fft.fft2(x, workers=1), FFT2_REPEATS))
    # the plain interpreter's reference: this process's allocator (one arena for every thread, set by the
    # command line for the stages' memory) slows the fft2's worker threads; the chains' ratios to it
    clean_after = clean_process_fft2(x, FFT2_REPEATS, CLEAN_PROCESSES)
    clean = clean_before["times"] + clean_after["times"]
    out["fft2_clean_process_s"] = statistics.median(clean) if clean else None
    out["fft2_clean_process_medians"] = clean_before["medians"] + clean_after["medians"]   # one per child
    out["cube_mib"] = (cube.sum.nbytes + cube.diff.nbytes) / 2**20
    out["chain_repeats"] = chain_repeats
    out["environment"] = environment()
    _step(12, n, "done")
    out["ratios_to_fft2"] = {k[:-2]: out[k] / out["fft2_s"] for k in list(out) if k.endswith("_s")
                             and k != "fft2_s" and out[k] is not None}
    if out["fft2_clean_process_s"]:
        out["chain_ratios_to_clean_fft2"] = {k[:-2]: out[k] / out["fft2_clean_process_s"] for k in list(out)
                                             if k.startswith("chain_") and k.endswith("_s")}
    out["targets"] = bench_targets(out)
    return out


# the bounds the issues set on this bench's figures: (what, key or ratio of two keys, at most, issue)
TARGETS = (("chain_s / fft2_s", ("chain_s", "fft2_s"), 35.0, 11),
           ("chain_tracking_s / fft2_s", ("chain_tracking_s", "fft2_s"), 40.0, 11),
           ("chain_decimation_peak_rss_over_tiny_peak_x_cube", "chain_decimation_peak_rss_over_tiny_peak_x_cube", 4.0, 11),
           ("chain_tracking_peak_rss_over_tiny_peak_x_cube", "chain_tracking_peak_rss_over_tiny_peak_x_cube", 4.0, 11),
           ("chain_dwell_over_tracking", "chain_dwell_over_tracking", 2.0, 9))


def bench_targets(result: dict) -> dict:
    """{what: {"value", "at_most", "issue", "met"}} for each of :data:`TARGETS` the result holds (the
    peaks are the bench's own probe, "Memory" in the README gives the commands' ``/usr/bin/time``)."""
    out = {}
    for name, key, bound, issue in TARGETS:
        if isinstance(key, tuple):
            num, den = result.get(key[0]), result.get(key[1])
            value = num / den if num is not None and den else None
        else:
            value = result.get(key)
        if value is not None:
            out[name] = {"value": float(value), "at_most": bound, "issue": issue, "met": bool(value <= bound)}
    return out


def print_bench(as_json: bool = False, scaling: bool = False, plot_path=None, repeats: int = 3,
                scene: bool = False, backend: str = "cpu") -> None:
    if scaling:
        from ..scenario.loader import load_scenario
        from .benchtools import scaling_series

        result = scaling_series(load_scenario(SCENARIOS / "paper_fig6_a50.yaml"), repeats=repeats,
                                plot_path=plot_path, progress=lambda m: print(m, file=sys.stderr))
        if as_json:
            print(json.dumps(result, indent=2))
        else:
            print(f"N log N shows as exponent {result['nlogn_exponent']['pulses']:.3f} over pulses, "
                  f"{result['nlogn_exponent']['range_bins']:.3f} over range bins")
            for key, exps in result["exponents"].items():
                print(f"{key:<22s} " + ", ".join(f"{k} {v:.2f}" for k, v in exps.items()))
            print("the same, fitted to each stage's user CPU time (the kernel's page work left out):")
            for key, exps in result["exponents_user_cpu"].items():
                print(f"{key:<22s} " + ", ".join(f"{k} {v:.2f}" for k, v in exps.items()))
            print("the same chains without stage files (--keep-stages none: no file written beside a stage):")
            for key, exps in result["exponents_keep_none"].items():
                print(f"{key:<22s} " + ", ".join(f"{k} {v:.2f}" for k, v in exps.items()))
        return
    if backend == "gpu":                       # gpu_bench.py: the GPU stages against a device fft2
        from .gpu_bench import run_gpu_bench

        result = run_gpu_bench(repeats=max(5, repeats))
    else:
        result = run_bench(chain_repeats=repeats)
    if scene:                                  # scene_bench.py: one child process per scene size
        from .scene_bench import run_scene_bench

        result.update(run_scene_bench())
    if as_json:
        print(json.dumps(result, indent=2))
    else:
        for key, value in result.items():
            if key == "targets":
                continue                           # last, as a summary
            if key == "one_core":
                for k, v in (value or {}).items():
                    shown = f"{v * 1e3:10.2f} ms" if k.endswith("_s") else (f"{v:10.2f} x" if isinstance(v, float) else f" {v}")
                    print(f"one_core[{k}]".ljust(24) + f" {shown}")
            elif key == "page_cost":
                for k, v in value.items():
                    shown = f"{v:10.2f} ms/MiB" if isinstance(v, float) else f" {v}"
                    print(f"page_cost[{k}]".ljust(34) + shown)
            elif key in ("ratios_to_fft2", "chain_ratios_to_clean_fft2"):
                unit = "fft2" if key == "ratios_to_fft2" else "fft2 in a plain interpreter"
                for k, v in value.items():
                    print(f"  {k:<22s} {v:10.1f} x {unit}")
            elif isinstance(value, dict):
                for k, v in value.items():
                    print(f"{key}[{k}]".ljust(24) + (f" {v:10.1f}" if isinstance(v, float) else f" {v}"))
            elif key.endswith("_db"):
                print(f"{key:<24s} {value:10.1f} dB")
            elif key.startswith(("fft2_median", "fft2_clean_process_medians")):          # the reference's sets, in seconds: shown in ms
                values = value if isinstance(value, list) else [value]
                print(f"{key:<24s} " + " ".join(f"{v * 1e3:10.2f}" for v in values) + " ms")
            elif value is None or not isinstance(value, float) or not key.endswith("_s"):
                print(f"{key:<24s} {value if not isinstance(value, float) else round(value, 3)}")
            elif isinstance(value, float):
                print(f"{key:<24s} {value * 1e3:10.2f} ms")
            else:
                print(f"{key:<24s} {value}")
        if result.get("targets"):
            print("targets (issue: bound; this run):")
            for name, t in result["targets"].items():
                print(f"  {name:<48s} {t['value']:8.2f}  at most {t['at_most']:g} (issue {t['issue']}): "
                      + ("met" if t["met"] else "NOT met"))
        one = result.get("one_core")
        if one and "second_core_gain_fft2" in one:
            print(f"on one core (bench_cores.py): chain_s / fft2_s {one['chain_over_fft2']:.1f}, chain_tracking_s / "
                  f"fft2_s {one['chain_tracking_over_fft2']:.1f}; the second core's gain (one-core time over "
                  f"two-core time): fft2 {one['second_core_gain_fft2']:.2f} x, the chains "
                  f"{one['second_core_gain_chain']:.2f} x and {one['second_core_gain_chain_tracking']:.2f} x")


def _resolved_image_sizes(scn: dict, cube, method: str) -> tuple[int, int]:
    """``processing.n_doppler`` and ``range_oversample`` as the chain resolves them for ``method``
    (``auto``: the widest CPI band's count, ``forward/motion.py``, and the power image's Nyquist rate,
    ``dsp/imaging.py``), from the chain's own geometry."""
    from ..forward.chain import build_forward_stages

    _, _, geo = build_forward_stages(cube, dict(scn["processing"], method=method))
    return int(geo["n_doppler"]), int(geo["range_oversample"])


if __name__ == "__main__":
    print_bench("--json" in sys.argv[1:], scaling="--scaling" in sys.argv[1:])
