"""``fwdlook bench --backend gpu``: the GPU stages timed on the device, as ratios to one 2-D FFT of the
same cube on that device.

Every clock reading follows ``xp.cuda.Device().synchronize()`` (CuPy queues work asynchronously).  The
reference ``fft2_s`` is the median of at least 20 device FFTs of the sum channel (complex64, already on
the device); each stage is timed as the chain runs it, host arrays in and out (transfers included),
median of ``repeats`` runs after one warm-up (CuPy compiles its kernels and plans its FFTs on first use).
Without CuPy or a device, :func:`dsp.xp.get_xp` raises BadInput: exit 2, one line.

Beside the times, what the device computed against the CPU stage on the same input (issue 11: to
-100 dB): ``gpu_vs_cpu_<method>_<stage>_<var>_db``, the relative error power of each complex output,
and the image's kept cells on both sides (``..._cells_cpu``, ``..._cells_gpu``, ``..._cells_same``).
Then the whole chain as ``fwdlook process`` runs it (stage files written on the host), on the CPU and
with ``processing.backend: gpu``, medians of ``repeats`` runs: ``chain_<backend>_<method>_s``, with
the host's own fft2 (``host_fft2_s``, ``scipy.fft``, every core) as the CPU chain's reference.
"""
from __future__ import annotations

import statistics
import time
from functools import partial
from pathlib import Path

import numpy as np

from ..dsp.xp import fft_module, get_xp, is_numpy, synchronize, to_device
from .benchtools import environment

SCENARIOS = Path(__file__).resolve().parents[2] / "scenarios"
FFT2_REPEATS = 21
GPU_STAGES = ("keystone", "doppler_spectra", "monopulse_image")
COMPLEX_OUTPUTS = {"keystone": ("sum_f", "diff_f"), "doppler_spectra": ("sum_z", "diff_z")}
CELL_KEYS = ("cell_x_m", "cell_y_m", "cell_power")


def relative_error_db(test, ref) -> float:
    """10 log10(sum |test - ref|^2 / sum |ref|^2), in complex128; -300 dB at least (identical arrays)."""
    test, ref = np.asarray(test, np.complex128), np.asarray(ref, np.complex128)
    err, power = float(np.sum(np.abs(test - ref) ** 2)), float(np.sum(np.abs(ref) ** 2))
    return -300.0 if err == 0 else max(-300.0, float(10 * np.log10(err / max(power, 1e-300))))


def agreement(stage: str, cpu, gpu) -> dict:
    """The device's output of ``stage`` against the CPU's on the same input (StageData both)."""
    out = {f"{stage}_{key}_db": relative_error_db(gpu[key], cpu[key]) for key in COMPLEX_OUTPUTS.get(stage, ())}
    if stage == "monopulse_image":
        out["cells_cpu"], out["cells_gpu"] = len(cpu["cell_power"]), len(gpu["cell_power"])
        out["cells_same"] = bool(out["cells_cpu"] == out["cells_gpu"] and all(
            np.allclose(gpu[k], cpu[k], rtol=1e-5, atol=0 if k == "cell_power" else 1e-2) for k in CELL_KEYS))
        out["image_db"] = relative_error_db(gpu["image"], cpu["image"])
    return out


def _device_times(xp, fn, repeats: int) -> list:
    fn()                                         # warm-up: kernels compiled, FFT plans cached
    synchronize(xp)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        synchronize(xp)
        times.append(time.perf_counter() - t0)
    return times


def _device_name(xp) -> str:
    if is_numpy(xp):
        return "numpy (FWDLOOK_XP=numpy: the GPU code run on the host, not a GPU figure)"
    props = xp.cuda.runtime.getDeviceProperties(xp.cuda.Device().id)
    name = props.get("name", b"?")
    return name.decode() if isinstance(name, bytes) else str(name)


def run_gpu_bench(scenario=SCENARIOS / "paper_fig6_a50.yaml", repeats: int = 5, backend: str = "gpu",
                  chains: bool = True) -> dict:
    """Device timings of the three GPU stages for ``decimation`` and ``tracking``: a dict with
    ``fft2_s`` (device), ``gpu_stage_<method>_<stage>_s``, their agreement with the CPU stages,
    (``chains``) the whole chains on both backends, and ``ratios_to_fft2`` (of the device fft2)."""
    from ..forward.chain import build_forward_stages
    from ..forward.gpu_stages import on_backend
    from ..forward.simulate import simulate_scenario
    from ..scenario.loader import load_scenario

    xp = get_xp(backend)                         # BadInput (exit 2) without CuPy or a device
    scn = load_scenario(scenario) if not isinstance(scenario, dict) else scenario
    cube, _ = simulate_scenario(scn)
    out = {"backend": backend, "device": _device_name(xp), "cube_shape": list(cube.sum.shape),
           "environment": environment()}
    if not is_numpy(xp):
        out["environment"]["cupy"] = str(getattr(xp, "__version__", "unknown"))
    fft2_times = _device_times(xp, partial(fft_module(xp).fft2, to_device(cube.sum, xp, np.complex64)),
                               FFT2_REPEATS)       # the reference: the cube's sum channel on the device
    out["fft2_repeats"] = len(fft2_times)
    out["fft2_s"] = statistics.median(fft2_times)
    for method in ("decimation", "tracking"):
        src, stages, _ = build_forward_stages(cube, dict(scn["processing"], method=method))
        xp_stages = on_backend(stages, backend)
        data = src
        for st, gs in zip(stages, xp_stages):
            cpu_out = st.fn(data, **st.params)   # the next stage's input, from the CPU chain
            if gs.name in GPU_STAGES and gs.fn is not st.fn:
                out[f"gpu_stage_{method}_{gs.name}_s"] = statistics.median(
                    _device_times(xp, lambda: gs.fn(data, **gs.params), max(1, repeats)))
                for key, value in agreement(gs.name, cpu_out, gs.fn(data, **gs.params)).items():
                    out[f"gpu_vs_cpu_{method}_{key}"] = value
            data = cpu_out
        out[f"gpu_chain_{method}_three_stages_s"] = sum(
            out.get(f"gpu_stage_{method}_{name}_s", 0.0) for name in GPU_STAGES)
    if chains:
        out.update(whole_chains(cube, scn, backend, repeats))
    out["ratios_to_fft2"] = {k[:-2]: out[k] / out["fft2_s"] for k in out if k.endswith("_s")
                             and k not in ("fft2_s", "host_fft2_s") and not k.startswith("chain_cpu_")}
    return out


def whole_chains(cube, scn: dict, backend: str, repeats: int) -> dict:
    """Both CPI chains as ``fwdlook process`` runs them, on the CPU and on ``backend``, interleaved
    (round r runs each once): medians of ``repeats`` rounds, and the host's fft2 of the sum channel."""
    import scipy.fft

    from .benchtools import median_time, time_chain

    runs: dict = {}
    for _ in range(max(1, repeats)):
        for method in ("decimation", "tracking"):
            for which in ("cpu", backend):
                proc = dict(scn["processing"], method=method, imaging="cpi", dwell_fit="none", backend=which)
                runs.setdefault((which, method), []).append(time_chain(cube, dict(scn, processing=proc),
                                                                       repeats=1, rss=False)["total_s"])
    out = {f"chain_{which}_{method}_s": statistics.median(times) for (which, method), times in runs.items()}
    scipy.fft.fft2(cube.sum, workers=-1)
    out["host_fft2_s"] = median_time(lambda: scipy.fft.fft2(cube.sum, workers=-1), repeats=FFT2_REPEATS)
    out["host_ratios_to_fft2"] = {f"chain_cpu_{m}": out[f"chain_cpu_{m}_s"] / out["host_fft2_s"]
                                  for m in ("decimation", "tracking")}
    return out
