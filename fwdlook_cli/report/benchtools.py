"""Measuring tools for ``fwdlook bench``: medians of repeats, the chain timed as it runs (stage files,
plans and all), its peak resident memory, and the scaling series behind ``--scaling``.

Peak RSS of a block of code is read in-process: writing ``5`` to ``/proc/self/clear_refs`` resets the
kernel's high-water mark ``VmHWM`` to the current RSS (Linux >= 4.0), so ``VmHWM`` after the block minus
``VmRSS`` before it is the block's own peak above what was already resident (interpreter, libraries,
the cube).  Where that is not available (not Linux) the figure is None, never a guess.
"""
from __future__ import annotations

import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def environment() -> dict:
    """What a bench's figures depend on besides the code: the versions of the libraries that compute
    (pocketfft is scipy's, the fused oversampling ducc0's, the Doppler zoom's products the BLAS), the
    processor, the cores this process may use, its cgroup's CPU limit and ``scipy.fft``'s count for
    ``workers=-1``.  Strings, for the JSON."""
    import platform

    import h5py
    import scipy

    from .. import __version__
    from ..dsp.blas import available_cores, fft_workers, scipy_fft_backend
    from ..dsp.cgroups import cached_cpu_limit

    env = {"fwdlook": __version__, "python": platform.python_version(), "numpy": np.__version__,
           "scipy": scipy.__version__, "h5py": h5py.version.version, "hdf5": h5py.version.hdf5_version,
           "machine": platform.machine()}
    try:
        import ducc0

        env["ducc0"] = ducc0.__version__
    except ImportError:                     # pragma: no cover (a core dependency)
        env["ducc0"] = "missing"
    env["cores"] = str(available_cores())
    limit = cached_cpu_limit()           # the cgroup's CPU limit, in CPUs (dsp/cgroups.py)
    env["cpu_limit"] = "none" if limit is None else f"{limit:g}"
    workers = fft_workers()
    env["fft_workers"] = "unknown" if workers is None else str(workers)
    env["fft_backend"] = scipy_fft_backend()
    # the commands' timings (command_runs) include compiling fwdlook's modules where no bytecode is
    # cached (a shell with PYTHONDONTWRITEBYTECODE and no `make bytecode`: 0.13-0.15 s a command)
    ours = [m for name, m in list(sys.modules.items()) if name.startswith("fwdlook_cli") and getattr(m, "__file__", None)]
    cached = sum(1 for m in ours if getattr(m, "__cached__", None) and os.path.exists(m.__cached__))
    env["fwdlook_bytecode"] = f"{cached} of {len(ours)} modules compiled"
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            models = [line.split(":", 1)[1].strip() for line in f if line.startswith("model name")]
        env["cpu"] = models[0] if models else platform.processor() or "unknown"
    except OSError:
        env["cpu"] = platform.processor() or "unknown"
    try:
        from threadpoolctl import threadpool_info

        libs = [p for p in threadpool_info() if p.get("user_api") == "blas"]
        env["blas"] = ", ".join(sorted({f"{p.get('internal_api')} {p.get('version')}" for p in libs})) or "none found"
        env["blas_threads"] = ", ".join(sorted({str(p.get("num_threads")) for p in libs})) or "none found"
    except Exception:                       # noqa: BLE001  pragma: no cover (informational only)
        env["blas"] = env["blas_threads"] = "unknown"
    from ..dsp import spawner

    # who forks the joint fit's workers (the dwell chain): a spawner (dsp/spawner.py) where this process
    # runs one, else the process itself (as before the thirty-fifth round), where it runs the fit at all
    env["fit_workers"] = "spawner" if spawner.current() is not None else "no spawner"
    return env


def wall_times(fn, repeats: int) -> list[float]:
    """The wall time of each of ``repeats`` calls of ``fn`` (s)."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return times


def median_time(fn, repeats=5):
    """Median wall time of ``repeats`` calls of ``fn`` (s)."""
    return statistics.median(wall_times(fn, max(1, int(repeats))))


def process_cpu_split_s() -> tuple[float, float] | None:
    """(user, system) CPU time of this process, every thread, and of the children it has reaped (the
    joint fit's forked workers, ``dsp.forked``: a chain's own work done in other processes), with the
    workers forked for it by its spawner (``dsp.spawner``, which the workers report; once the spawner
    itself is reaped its children come in ``RUSAGE_CHILDREN`` as well: the bench's lives as long as
    the bench) (s); None where unsupported.  System time is the kernel's work for the process: page faults on memory it
    touches first (the pages cleared), the copies of written bytes into the page cache."""
    try:
        import resource
    except ImportError:              # pragma: no cover (not POSIX)
        return None
    from ..dsp.spawner import worker_cpu_split_s
    from ..runner import cpu_split_s            # the process itself, as each stage is charged

    user, system = cpu_split_s()
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    spawned = worker_cpu_split_s()
    return user + children.ru_utime + spawned[0], system + children.ru_stime + spawned[1]


def process_cpu_s() -> float | None:
    """User plus system CPU time of :func:`process_cpu_split_s` (s); None where unsupported."""
    split = process_cpu_split_s()
    return None if split is None else split[0] + split[1]


def _status_kib(field: str):
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith(field + ":"):
                    return int(line.split()[1])
    except OSError:
        return None
    return None


def reset_peak_rss() -> int | None:
    """Reset VmHWM to the current RSS; returns the current RSS in bytes (None where unsupported)."""
    try:
        with open("/proc/self/clear_refs", "w", encoding="ascii") as f:
            f.write("5")
    except OSError:
        return None
    rss = _status_kib("VmRSS")
    return None if rss is None else rss * 1024


def peak_rss_bytes() -> int | None:
    hwm = _status_kib("VmHWM")
    return None if hwm is None else hwm * 1024


def time_chain(cube, scn: dict, repeats: int = 3, rss: bool = True, keep_stages: str = "all") -> dict:
    """Run the whole chain ``repeats`` times as ``fwdlook process`` runs it (every stage recomputed,
    every stage file, image.h5 and metrics.json written; no PNG): medians per stage and in total.
    ``keep_stages``: as ``--keep-stages`` (``none``: no stage file written, what the files cost).
    ``cores_busy``, ``user_cpu_s`` and ``system_cpu_s``: the process's CPU time over the call's wall time
    (``wall_s``, around ``process_cube``), and that CPU time split (:func:`process_cpu_split_s`);
    ``stages_user_cpu_s`` and ``stages_system_cpu_s``: the same split per stage, medians (the
    process's CPU while the stage computed, ``runner.run_stages``); ``stage_files_user_cpu_s`` and
    ``stage_files_system_cpu_s``: the writer thread's own CPU time for all the stage files of a run
    (medians; None where no file was written or off Linux).  The digests of large arrays run on a
    helper thread beside it and are not in it (about 0.2 ms per 11 MB alone).
    With ``rss``, the chain's peak RSS is measured once more in a fresh interpreter
    (:func:`chain_peak_rss`), since a warm process reuses memory it already holds."""
    from ..forward.process import process_cube

    per_stage: dict[str, list[float]] = {}
    stage_user: dict[str, list[float]] = {}
    stage_system: dict[str, list[float]] = {}
    cores, user, system, walls = [], [], [], []
    files_user, files_system = [], []
    for _ in range(max(1, int(repeats))):
        stage_cpu: dict = {}
        file_cpu: dict = {}
        with tempfile.TemporaryDirectory() as tmp:
            cpu0, wall0 = process_cpu_split_s(), time.perf_counter()
            metrics = process_cube(cube, scn, tmp, force=True, quiet=True, png=False, keep_stages=keep_stages,
                                   stage_cpu=stage_cpu, file_cpu=file_cpu)
            cpu1, wall1 = process_cpu_split_s(), time.perf_counter()
        for stage, (u, s) in stage_cpu.items():
            stage_user.setdefault(stage, []).append(u)
            stage_system.setdefault(stage, []).append(s)
        if file_cpu:
            files_user.append(sum(u for u, _ in file_cpu.values()))
            files_system.append(sum(s for _, s in file_cpu.values()))
        walls.append(wall1 - wall0)
        if cpu0 is not None and cpu1 is not None:
            user.append(cpu1[0] - cpu0[0])
            system.append(cpu1[1] - cpu0[1])
            cores.append((user[-1] + system[-1]) / max(wall1 - wall0, 1e-9))
        for stage, seconds in metrics["timing_s"].items():
            per_stage.setdefault(stage, []).append(float(seconds))
    out = {k: statistics.median(v) for k, v in per_stage.items()}
    result = {"stages_s": {k: v for k, v in out.items() if k != "total"}, "total_s": out["total"],
              "cores_busy": statistics.median(cores) if cores else None,
              "user_cpu_s": statistics.median(user) if user else None,
              "system_cpu_s": statistics.median(system) if system else None,
              "wall_s": statistics.median(walls),
              "stages_user_cpu_s": {k: statistics.median(v) for k, v in stage_user.items()},
              "stages_system_cpu_s": {k: statistics.median(v) for k, v in stage_system.items()},
              "stage_files_user_cpu_s": statistics.median(files_user) if files_user else None,
              "stage_files_system_cpu_s": statistics.median(files_system) if files_system else None}
    if rss:
        result.update(chain_peak_rss(cube, scn))
    return result


def chain_peak_rss(cube, scn: dict) -> dict:
    """Peak RSS of ``process_cube`` in a fresh interpreter: after the imports and one warm-up run on the
    tiny cube (the interpreter base), the cube is read from HDF5 and the chain run once; the
    high-water mark minus the base, in bytes and as a multiple of the cube (both channels; the cube
    itself counts).  Two bases: the RSS after the tiny run (``peak_rss_x_cube``, the stricter: what
    the tiny run freed counts against the chain), and the tiny run's own peak
    (``peak_rss_over_tiny_peak_x_cube``: the README's ``/usr/bin/time`` convention, a tiny run's
    high-water mark as the base of the same command on the paper cube)."""
    import json
    import subprocess

    from ..io.raw import write_raw

    cube_bytes = cube.sum.nbytes + (cube.diff.nbytes if cube.diff is not None else 0)
    with tempfile.TemporaryDirectory() as tmp:
        raw = Path(tmp) / "raw.h5"
        write_raw(raw, cube)
        (Path(tmp) / "scn.json").write_text(json.dumps(scn, default=float))
        code = "from fwdlook_cli.report.benchtools import _rss_probe; _rss_probe()"
        res = subprocess.run([sys.executable, "-c", code, str(raw), str(Path(tmp) / "scn.json"), tmp],
                             capture_output=True, text=True, check=False)
    try:
        probe = json.loads(res.stdout.strip().splitlines()[-1])
    except (IndexError, ValueError):
        return {"peak_rss_above_base_bytes": None, "cube_bytes": cube_bytes, "peak_rss_x_cube": None,
                "peak_rss_over_tiny_peak_x_cube": None}
    above = probe["hwm"] - probe["base"] if probe["hwm"] and probe["base"] else None
    over_tiny = max(0, probe["hwm"] - probe["tiny_peak"]) if probe["hwm"] and probe.get("tiny_peak") else None
    return {"peak_rss_above_base_bytes": above, "cube_bytes": cube_bytes, "interpreter_base_bytes": probe["base"],
            "peak_rss_x_cube": None if above is None else above / cube_bytes,
            "tiny_run_peak_bytes": probe.get("tiny_peak"),
            "peak_rss_over_tiny_peak_x_cube": None if over_tiny is None else over_tiny / cube_bytes}


def _rss_probe() -> None:
    """Child of :func:`chain_peak_rss`: argv = RAW.h5 SCENARIO.json TMPDIR; prints {base, tiny_peak, hwm}."""
    import json

    from ..forward.process import process_cube
    from ..io.raw import read_raw
    import importlib

    for name in ("fwdlook_cli.forward.chain", "fwdlook_cli.forward.evaluate"):   # before the base
        importlib.import_module(name)

    from ..dsp.blas import share_one_allocator_arena

    share_one_allocator_arena()          # as the command line does
    raw, scn_path, tmp = sys.argv[1:4]
    scn = json.loads(Path(scn_path).read_text())
    # warm-up on the tiny cube (HDF5, FFT plans, BLAS pools, lazily imported modules in use), as the
    # tiny-cube base of the README's /usr/bin/time figures
    from ..forward.simulate import simulate_scenario
    from ..scenario.loader import load_scenario

    tiny = load_scenario(Path(__file__).resolve().parents[2] / "scenarios" / "tiny.yaml")
    tiny["processing"] = dict(tiny["processing"], method=scn["processing"]["method"])
    tiny_cube, _ = simulate_scenario(tiny)
    process_cube(tiny_cube, tiny, Path(tmp) / "warm", force=True, quiet=True, png=False, release_cube=True)
    del tiny_cube
    tiny_peak = peak_rss_bytes()         # the imports and the tiny run's high-water mark
    base = reset_peak_rss()
    cube = read_raw(raw)
    process_cube(cube, scn, Path(tmp) / "run", force=True, quiet=True, png=False, release_cube=True)
    print(json.dumps({"base": base, "tiny_peak": tiny_peak, "hwm": peak_rss_bytes()}))


_CLEAN_FFT2 = """
import json, sys, time
import numpy as np, scipy.fft
x = np.load(sys.argv[1])
y = scipy.fft.fft2(x, workers=-1)                     # warm-up: plan cache, pages
times = []
for _ in range(int(sys.argv[2])):
    t0 = time.perf_counter()
    scipy.fft.fft2(x, workers=-1)
    times.append(time.perf_counter() - t0)
print(json.dumps({"times": times, "abs_sum": float(np.abs(y).sum(dtype=np.float64))}))
"""


def clean_process_fft2(x, repeats: int = 21, processes: int = 1) -> dict:
    """The reference in plain interpreters: ``processes`` children one after the other, each timing
    ``repeats`` calls of ``scipy.fft.fft2(x, workers=-1)`` after one untimed call, with numpy and
    scipy.fft imported and glibc's allocator as it comes.  fwdlook's command line shares one allocator
    arena among all threads (``dsp.blas.share_one_allocator_arena``, for the stages' memory), and
    pocketfft's worker threads then contend for it.  Measured on this machine: about 2.1 ms in most
    plain interpreters and 3.6 ms in about one in four, 2.5-2.7 ms with the shared arena, and 3.4-3.7
    ms in the bench's own process after its simulation (docs/SPEED.md).  Several children average over
    that per-process spread.  Returns {"times": [s, every child's], "medians": [s, one per child],
    "abs_sum": sum |fft2(x)| from the last child (a test checks that it is this array's transform)};
    a child that fails adds nothing."""
    import json
    import subprocess

    from ..dsp.blas import plain_environment     # (not fwdlook's one BLAS thread: a plain interpreter's)

    out = {"times": [], "medians": [], "abs_sum": None}
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "x.npy"
        np.save(path, np.ascontiguousarray(x))
        for _ in range(max(1, int(processes))):
            res = subprocess.run([sys.executable, "-c", _CLEAN_FFT2, str(path), str(int(repeats))],
                                 capture_output=True, text=True, check=False, env=plain_environment())
            try:
                child = json.loads(res.stdout.strip().splitlines()[-1])
            except (IndexError, ValueError):
                continue
            out["times"] += child["times"]
            out["medians"].append(statistics.median(child["times"]))
            out["abs_sum"] = child["abs_sum"]
    return out


def command_runs(cube, settings: dict, repeats: int = 3) -> dict:
    """``fwdlook process RAW.h5 --set processing.KEY=VALUE ...`` as a user runs it: a fresh interpreter
    per run (its imports, the cube read from HDF5, the calibration check, the painter drawing
    image.png, every stage file), ``repeats`` rounds, each running every entry of ``settings``
    ({name: {processing key: value}}) once into a new folder.  The chain of such a run is cold: its
    modules imported on first use, its FFT plans made, its memory touched for the first time, which
    the bench's chains in one warm process (:func:`time_chain`) no longer pay.  Returns {name:
    {"wall_s": median wall time of the command, "chain_s": median of its metrics.json total}} (None
    where no run succeeded)."""
    import json
    import subprocess

    from ..io.raw import write_raw

    walls: dict = {name: [] for name in settings}
    chains: dict = {name: [] for name in settings}
    with tempfile.TemporaryDirectory() as tmp:
        raw = Path(tmp) / "raw.h5"
        write_raw(raw, cube)
        for r in range(max(1, int(repeats))):
            for name, sets in settings.items():
                run_dir = Path(tmp) / f"{name}_{r}"
                args = [sys.executable, "-m", "fwdlook_cli.cli", "-q", "process", str(raw), "-o", str(run_dir)]
                for key, value in sets.items():
                    args += ["--set", f"processing.{key}={value}"]
                t0 = time.perf_counter()
                res = subprocess.run(args, capture_output=True, text=True, check=False)
                wall = time.perf_counter() - t0
                if res.returncode != 0:
                    continue
                walls[name].append(wall)
                chains[name].append(json.loads((run_dir / "metrics.json").read_text())["timing_s"]["total"])
    return {name: {"wall_s": statistics.median(walls[name]) if walls[name] else None,
                   "chain_s": statistics.median(chains[name]) if chains[name] else None} for name in settings}


# ----------------------------------------------------------------------------------------------
# scaling series (fwdlook bench --scaling)
# ----------------------------------------------------------------------------------------------
PULSES = (1250, 2500, 5000, 10000, 20000)
RANGE_BINS = (256, 512, 1024, 2048, 4096)
SCALING_POINTS_M = [[-100.0, 1700.0], [0.0, 1730.0], [100.0, 1680.0]]


NOT_STAGES = ("shape", "user_cpu", "system_cpu", "keep_none")     # a scaling row's keys that are not stage times


SCALING_NEAR_MIN_M = 400.0   # the nearest slant range of a scaling window (the 1024-bin window's, 425 m)
SCALING_N_DOPPLER = 64       # zoomed Doppler cells per CPI held fixed over the series: n_doppler: auto (the
                             # default) falls as the PRF rises with the pulse count (48 cells at 2500 pulses,
                             # the 16-cell floor from 10000), and the exponents would then measure the scene's
                             # band, not the code's growth (the image's pulses exponent read 0.28-0.34)
SCALING_SUBSWATHS = "none"   # one reference depression over the series: the keystone's range sub-swaths
                             # (steep depression, forward/subswath.py) start where a window's Doppler spread
                             # passes a threshold, `decimation`'s at PRF / Q from 1024 range bins and 20000
                             # pulses here, and a fit across it would read that step as the code's growth
                             # (the keystone's range-bin exponent 1.44 in the fifty-third round's first series)


def scaling_scenario(paper: dict, n_pulses: int, n_range: int) -> dict:
    """The paper scenario with three points, ``n_pulses`` over the same 1 s scan (the PRF scales with
    the pulse count, so the geometry stays that of the paper) and ``n_range`` range samples, the
    points in the middle of the range window.  A window centred on the paper's points (1705 m) would
    start at a negative slant range from 2048 bins on (-855 m; -3415 m at 4096: a cube no reader
    accepts, ``io.raw``): such a window starts at :data:`SCALING_NEAR_MIN_M` instead and the points
    move out with its middle."""
    import copy

    from ..dsp.geometry import C_MPS

    scn = copy.deepcopy(paper)
    prf = paper["radar"]["prf_hz"] * n_pulses / 2500.0
    dr = C_MPS / (2.0 * scn["radar"]["fs_hz"])
    near = 1705.0 - 0.5 * n_range * dr
    shift_m = max(0.0, SCALING_NEAR_MIN_M - near)
    near += shift_m
    scn["radar"].update(prf_hz=prf, n_pulses=n_pulses, range_window_m=[near, near + (n_range - 0.5) * dr])
    scn["scene"].update(kind="points", points_m=[[x, y + shift_m] for x, y in SCALING_POINTS_M], amplitude=1.0)
    return scn


def fit_exponent(sizes, seconds) -> float:
    """Least-squares slope of log(seconds) against log(size)."""
    return float(np.polyfit(np.log(np.asarray(sizes, float)), np.log(np.asarray(seconds, float)), 1)[0])


def nlogn_exponent(sizes) -> float:
    """The exponent a pure N log N cost shows over the same sizes (the bar no stage may exceed)."""
    n = np.asarray(sizes, float)
    return fit_exponent(n, n * np.log(n))


def scaling_series(paper: dict, methods=("decimation", "tracking"), repeats: int = 3, plot_path=None,
                   pulses=PULSES, range_bins=RANGE_BINS, progress=None, keep_none: bool = True) -> dict:
    """Stage times over pulses (range bins fixed at 280) and range bins (pulses fixed at 2500); fitted
    exponents per stage and in total; a log-log plot when ``plot_path`` is given.  The Doppler cells
    per CPI are held at ``SCALING_N_DOPPLER``, and the keystone's window at one reference depression
    (``SCALING_SUBSWATHS``; the range oversampling, ``auto``, does not change over the series: the radar's
    bandwidth and sampling rate are fixed).

    ``exponents`` fit the wall times; ``exponents_user_cpu`` the stages' user CPU time (every thread),
    which leaves out the kernel's work for the process.  The two differ where a machine charges much
    for memory touched the first time: arrays above glibc's mmap threshold (32 MiB at most) get fresh
    pages on every allocation, smaller ones reuse the heap, so the wall time's cost per byte changes
    within the series (README, Speed: "Scaling").  With ``keep_none`` every point is timed a second
    time without stage files (``--keep-stages none``; the row's ``keep_none``) and
    ``exponents_keep_none`` fit those wall times: a stage's time in the chain includes the file of the
    stage before it, written beside it by the writer thread, so the two fits tell a stage's own growth
    from that of the file written meanwhile."""
    from ..forward.simulate import simulate_scenario

    result = {"pulses": list(pulses), "range_bins": list(range_bins), "series": {}, "exponents": {},
              "exponents_user_cpu": {}, "exponents_keep_none": {},
              "nlogn_exponent": {"pulses": nlogn_exponent(pulses), "range_bins": nlogn_exponent(range_bins)}}
    for axis, sizes in (("pulses", pulses), ("range_bins", range_bins)):
        for method in methods:
            rows = []
            for n in sizes:
                shape = (n, 280) if axis == "pulses" else (2500, n)
                scn = scaling_scenario(paper, *shape)
                scn["processing"] = dict(scn["processing"], method=method, n_doppler=SCALING_N_DOPPLER,
                                         subswaths=SCALING_SUBSWATHS)
                cube, _ = simulate_scenario(scn)
                t = time_chain(cube, scn, repeats=repeats, rss=False)
                rows.append({"shape": list(cube.sum.shape), **t["stages_s"], "total": t["total_s"],
                             "user_cpu": {**t["stages_user_cpu_s"], "total": t["user_cpu_s"]},
                             "system_cpu": {**t["stages_system_cpu_s"], "total": t["system_cpu_s"]}})
                if keep_none:        # the same chain without stage files (what the stages alone cost)
                    bare = time_chain(cube, scn, repeats=repeats, rss=False, keep_stages="none")
                    rows[-1]["keep_none"] = {**bare["stages_s"], "total": bare["total_s"]}
                if progress:
                    progress(f"scaling {axis} {method} {cube.sum.shape}: {t['total_s']:.2f} s"
                             + (f" ({rows[-1]['keep_none']['total']:.2f} s without stage files)" if keep_none else ""))
            key = f"{axis}_{method}"
            result["series"][key] = rows
            stages = [k for k in rows[0] if k not in NOT_STAGES]
            result["exponents"][key] = {
                k: fit_exponent(sizes, [max(r[k], 1e-6) for r in rows]) for k in stages
                if min(r[k] for r in rows) > 1e-4}
            result["exponents_user_cpu"][key] = {
                k: fit_exponent(sizes, [r["user_cpu"][k] for r in rows]) for k in stages
                if all(r["user_cpu"].get(k) is not None for r in rows)
                and min(r["user_cpu"][k] for r in rows) > 1e-3}
            if keep_none:
                result["exponents_keep_none"][key] = {
                    k: fit_exponent(sizes, [r["keep_none"][k] for r in rows]) for k in stages
                    if all(k in r["keep_none"] for r in rows) and min(r["keep_none"][k] for r in rows) > 1e-4}
    if plot_path is not None:
        _plot_scaling(result, Path(plot_path))
        result["plot"] = str(plot_path)
    result["environment"] = environment()
    return result


def _plot_scaling(result: dict, path: Path) -> None:
    """Log-log stage times per series: wall time (top row), the wall time without stage files (middle
    row, where the series measured it) and user CPU time (bottom row), one colour per stage in every
    panel, the fitted exponent in each label, N log N dashed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter

    keys = list(result["series"])
    stages = [k for k in result["series"][keys[0]][0] if k not in NOT_STAGES]
    colour = {stage: f"C{i}" for i, stage in enumerate(stages)}
    panels = [("wall", "wall time (s)", "exponents")]
    if result.get("exponents_keep_none"):
        panels.append(("keep_none", "wall time, no stage files (s)", "exponents_keep_none"))
    panels.append(("user_cpu", "user CPU time (s)", "exponents_user_cpu"))

    def times(r, what, stage):
        return r[stage] if what == "wall" else r[what][stage]

    fig, axes = plt.subplots(len(panels), len(keys), figsize=(4.2 * len(keys), 3.8 * len(panels)), squeeze=False)
    for col, key in enumerate(keys):
        rows = result["series"][key]
        axis = "pulses" if key.startswith("pulses") else "range_bins"
        n = np.asarray(result[axis], float)
        for row, (what, label, fits) in enumerate(panels):
            ax = axes[row][col]
            exps = result[fits][key]
            for stage in stages:
                if stage not in exps:
                    continue
                t = np.asarray([times(r, what, stage) for r in rows])
                ax.loglog(n, t, "o-", ms=3, lw=1, color=colour[stage], label=f"{stage} ({exps[stage]:.2f})")
            ref = n * np.log(n)
            top = max(times(r, what, "total") for r in rows)
            ax.loglog(n, ref / ref[-1] * top, "k--", lw=0.8,
                      label=f"N log N ({result['nlogn_exponent'][axis]:.2f})")
            ax.set_xticks(n)
            ax.set_xticklabels([f"{int(v)}" for v in n], fontsize=7)
            ax.xaxis.set_minor_formatter(NullFormatter())
            ax.set_xlabel(axis.replace("_", " "))
            ax.set_ylabel(label)
            ax.set_title(f"{key.replace('_', ' ')}: {label.rsplit(' (', 1)[0]}", fontsize=9)
            ax.legend(fontsize=6)
    fig.tight_layout()
    from ..io.extra_outputs import BENCH_PNG_SOFTWARE
    from ..io.outputs import atomic_path

    try:
        with atomic_path(path) as tmp:    # (its folder checked by the command before the series: bench_png_path)
            fig.savefig(tmp, dpi=64, metadata={"Software": BENCH_PNG_SOFTWARE})
    finally:
        plt.close(fig)


def write_scaling_cube(path, n_pulses: int, n_range: int, paper: dict | None = None) -> dict:
    """A cheap big cube for memory measurements: :func:`scaling_scenario` (three points, the paper's
    radar and motion, the PRF scaled with the pulse count) simulated and written as a raw cube.
    Returns the scenario (its ``processing`` section is the paper's, with the largest q up to the paper's
    25 that divides the pulses)."""
    from ..forward.simulate import simulate_scenario
    from ..io.raw import write_raw
    from ..scenario.loader import load_scenario

    paper = paper or load_scenario(Path(__file__).resolve().parents[2] / "scenarios" / "paper_fig6_a50.yaml")
    scn = scaling_scenario(paper, n_pulses, n_range)
    q = scn["processing"]["q"]
    if n_pulses % q:       # the scenario the cube records simulates and processes as it is (q divides the
        # pulses; the paper's 25 does not divide 16384: an independent review's re-simulation was refused)
        scn["processing"] = dict(scn["processing"], q=max(d for d in range(1, q + 1) if n_pulses % d == 0))
    cube, _ = simulate_scenario(scn)
    write_raw(path, cube)
    return scn
