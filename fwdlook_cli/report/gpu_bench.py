"""``fwdlook bench --backend gpu``: the GPU stages timed on the device, as ratios to one 2-D FFT of the
same cube on that device.

Every clock reading follows ``xp.cuda.Device().synchronize()`` (CuPy queues work asynchronously).  The
reference ``fft2_s`` is the median of at least 20 device FFTs of the sum channel (complex64, already on
the device); each stage is timed as the chain runs it, host arrays in and out (transfers included),
median of ``repeats`` runs after one warm-up (CuPy compiles its kernels and plans its FFTs on first use).
Without CuPy or a device, :func:`dsp.xp.get_xp` raises BadInput: exit 2, one line.
"""
from __future__ import annotations

import statistics
import time
from functools import partial
from pathlib import Path

import numpy as np

from ..dsp.xp import fft_module, get_xp, is_numpy, synchronize, to_device

SCENARIOS = Path(__file__).resolve().parents[2] / "scenarios"
FFT2_REPEATS = 21
GPU_STAGES = ("keystone", "doppler_spectra", "monopulse_image")


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


def run_gpu_bench(scenario=SCENARIOS / "paper_fig6_a50.yaml", repeats: int = 5, backend: str = "gpu") -> dict:
    """Device timings of the three GPU stages for ``decimation`` and ``tracking``: a dict with
    ``fft2_s`` (device), ``gpu_stage_<method>_<stage>_s`` and ``ratios_to_fft2``."""
    from ..forward.chain import build_forward_stages
    from ..forward.gpu_stages import on_backend
    from ..forward.simulate import simulate_scenario
    from ..scenario.loader import load_scenario

    xp = get_xp(backend)                         # BadInput (exit 2) without CuPy or a device
    scn = load_scenario(scenario) if not isinstance(scenario, dict) else scenario
    cube, _ = simulate_scenario(scn)
    out = {"backend": backend, "device": _device_name(xp), "cube_shape": list(cube.sum.shape)}
    fft2_times = _device_times(xp, partial(fft_module(xp).fft2, to_device(cube.sum, xp, np.complex64)),
                               FFT2_REPEATS)       # the reference: the cube's sum channel on the device
    out["fft2_repeats"] = len(fft2_times)
    out["fft2_s"] = statistics.median(fft2_times)
    for method in ("decimation", "tracking"):
        src, stages, _ = build_forward_stages(cube, dict(scn["processing"], method=method))
        xp_stages = on_backend(stages, backend)
        data = src
        for st, gs in zip(stages, xp_stages):
            if gs.name in GPU_STAGES and gs.fn is not st.fn:
                out[f"gpu_stage_{method}_{gs.name}_s"] = statistics.median(
                    _device_times(xp, lambda: gs.fn(data, **gs.params), max(1, repeats)))
            data = st.fn(data, **st.params)      # the next stage's input, from the CPU chain
        out[f"gpu_chain_{method}_three_stages_s"] = sum(
            out.get(f"gpu_stage_{method}_{name}_s", 0.0) for name in GPU_STAGES)
    out["ratios_to_fft2"] = {k[:-2]: out[k] / out["fft2_s"] for k in out if k.endswith("_s") and k != "fft2_s"}
    return out
