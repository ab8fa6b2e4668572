"""Issue 11 item 5: the GPU backend (``processing.backend: gpu``) gives the CPU chain's results.

The xp stages (forward/gpu_stages.py, forward/gpu_imaging.py) are an implementation of their own of
the keystone CZT, the Doppler zoom and the image's cell selection, written against an array module.
Here they run with ``xp = numpy`` (``FWDLOOK_XP=numpy``) and are compared stage by stage with the CPU
stages on the same inputs, on the tiny scene and on a small cube of the paper's radar (Q = 25
sub-sequences of 20 pulses; the tracking keystone over 500 pulses); the CZT keystone also against the
direct DFT keystone (a third implementation).  Measured (complex64 both sides): keystone -130 to
-134 dB relative error power (or bit-identical), Doppler spectra -184 dB or better, the same image
cells with float32-rounding differences in power and position (the CPU's range oversampling is
ducc0's fused resampling, the xp one numpy's FFTs, as a GPU's would be cuFFT's; the paper cube itself:
the same 125 962 and 125 439 cells, fifty-first round).  With CuPy and a CUDA device the same
comparisons run on the GPU; without, they skip.
"""
from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest
import yaml

from fwdlook_cli.cli import main
from fwdlook_cli.dsp.keystone import keystone_dft
from fwdlook_cli.dsp.xp import ENV_XP, get_xp
from fwdlook_cli.errors import BadInput
from fwdlook_cli.forward.chain import build_forward_stages
from fwdlook_cli.forward.gpu_stages import czt_keystone, on_backend
from fwdlook_cli.forward.simulate import simulate_scenario
from fwdlook_cli.scenario.loader import resolve_scenario
from fwdlook_cli.testing import _merge, tiny_scenario

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"
BAR_DB = -100.0          # issue 11: the GPU path agrees with the CPU path to -100 dB


def rel_db(a, b):
    a, b = np.asarray(a, np.complex128), np.asarray(b, np.complex128)
    return 10 * np.log10(max(np.sum(np.abs(a - b) ** 2), 1e-300) / np.sum(np.abs(b) ** 2))


def _cupy_device():
    """cupy when it imports and sees a CUDA device, else skip."""
    cupy = pytest.importorskip("cupy")
    try:
        if cupy.cuda.runtime.getDeviceCount() < 1:
            pytest.skip("CuPy without a CUDA device")
    except Exception as exc:                    # no driver
        pytest.skip(f"CuPy without a CUDA device ({exc.__class__.__name__})")
    return cupy


def _no_gpu() -> bool:
    try:
        get_xp("gpu")
    except BadInput:
        return True
    return False


def paper_like(method: str):
    """The paper's radar (18 GHz, PRF 2500 Hz, 60 MHz, Q = 25) over its first 500 pulses, three points
    in the beam of the scan's start (-15 to -9 deg)."""
    base = yaml.safe_load((SCENARIOS / "paper_fig6_a50.yaml").read_text())
    pts = [[-360.0, 1690.0], [-330.0, 1720.0], [-380.0, 1660.0]]
    return resolve_scenario(_merge(base, {"radar": {"n_pulses": 500}, "scene": {"kind": "points", "points_m": pts},
                                          "processing": {"method": method}}), "<paper-like>")


CASES = {"tiny-decimation": lambda: tiny_scenario(processing={"method": "decimation"}),
         "tiny-tracking": lambda: tiny_scenario(processing={"method": "tracking"}),
         "tiny-traditional": lambda: tiny_scenario(processing={"method": "traditional"}),
         "paper-decimation": lambda: paper_like("decimation"),
         "paper-tracking": lambda: paper_like("tracking")}


def stage_pairs(scn, backend="gpu"):
    """Run the CPU chain; at each GPU stage also run the xp version on the CPU stage's input:
    {stage name: (cpu output, xp output)}."""
    cube, _ = simulate_scenario(scn)
    src, stages, _ = build_forward_stages(cube, dict(scn["processing"]))
    xp_stages = on_backend(stages, backend)
    data, pairs = src, {}
    for st, gs in zip(stages, xp_stages):
        out = st.fn(data, **st.params)
        if gs.fn is not st.fn:
            assert gs.params == dict(st.params, backend=backend)
            pairs[st.name] = (out, gs.fn(data, **gs.params))
        data = out
    return pairs


def check_pairs(pairs):
    """Same vars, dims, attrs; complex results to -100 dB; the same kept cells, with float32-rounding
    differences in power and position (the two sides' FFTs round differently: ducc0's oversampling on
    the CPU, numpy's or cuFFT's on the xp side). Returns the measured dB."""
    assert sorted(pairs) == ["doppler_spectra", "keystone", "monopulse_image"]
    measured = {}
    for name, (cpu, gpu) in pairs.items():
        assert list(gpu.vars) == list(cpu.vars) and gpu.attrs == cpu.attrs
        for key, var in cpu.vars.items():
            assert gpu.vars[key].dims == var.dims and gpu.vars[key].units == var.units
            assert gpu[key].shape == cpu[key].shape and gpu[key].dtype == cpu[key].dtype, key
    for name, keys in (("keystone", ("sum_f", "diff_f")), ("doppler_spectra", ("sum_z", "diff_z"))):
        cpu, gpu = pairs[name]
        for key in keys:
            measured[f"{name}.{key}"] = rel_db(gpu[key], cpu[key])
            assert measured[f"{name}.{key}"] < BAR_DB, (name, key, measured[f"{name}.{key}"])
    cpu, gpu = pairs["doppler_spectra"]
    np.testing.assert_allclose(gpu["doppler_hz"], cpu["doppler_hz"], rtol=1e-12)
    cpu, gpu = pairs["monopulse_image"]
    assert len(cpu["cell_power"]) > 20                      # the targets gave cells
    for key in ("cell_x_m", "cell_y_m", "cell_power"):        # the same cells in the same order
        np.testing.assert_allclose(gpu[key], cpu[key], rtol=1e-5, atol=1e-2 if key != "cell_power" else 0)
    for key in ("image", "real_beam"):
        np.testing.assert_allclose(gpu[key], cpu[key], rtol=1e-6, atol=1e-6 * float(cpu[key].max()))
    return measured


# ----------------------------------------------------------------------------------------------
# xp = numpy: the GPU code path run by numpy
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("case", sorted(CASES))
def test_xp_stages_equal_the_cpu_stages(case, monkeypatch):
    monkeypatch.setenv(ENV_XP, "numpy")
    measured = check_pairs(stage_pairs(CASES[case]()))
    # complex64 on both sides: what remains is float32 rounding, far below the bar
    assert max(measured.values()) < -130


@pytest.mark.parametrize("n, ambiguity", [(100, 11), (257, -3)])
def test_xp_czt_keystone_equals_the_direct_dft(n, ambiguity):
    """The Bluestein CZT on xp against the O(n^2) sum of eq. (21)-(22), per column alpha and t0."""
    rng = np.random.default_rng(11)
    cols = 12
    alpha = 18e9 / (18e9 + np.linspace(-30e6, 30e6, cols))
    t0 = rng.uniform(0, n, cols)
    x = (rng.standard_normal((n, cols)) + 1j * rng.standard_normal((n, cols))).astype(np.complex64)
    y = czt_keystone(np, np.ascontiguousarray(x.T), alpha=alpha, t0_index=t0, ambiguity=ambiguity).T
    ref = keystone_dft(x.astype(np.complex128), alpha, t0_index=t0, ambiguity=ambiguity)
    assert y.dtype == np.complex64
    assert rel_db(y, ref) < -120


@pytest.mark.parametrize("n", [280, 33, 2, 1])
def test_xp_range_oversampling_is_the_cpus(n):
    """The xp image's zero-padded oversampling (numpy's FFTs here, cuFFT on a GPU) splits the Nyquist
    bin of an even n as the CPU's fused one (dsp.peaks.oversample_range) does: float32 rounding apart."""
    from fwdlook_cli.dsp.peaks import oversample_range as cpu_oversample
    from fwdlook_cli.forward.gpu_imaging import oversample_range as xp_oversample

    rng = np.random.default_rng(n)
    x = (rng.standard_normal((9, n)) + 1j * rng.standard_normal((9, n))).astype(np.complex64)
    for factor in (1, 2, 4):
        y, ref = xp_oversample(np, x, factor), cpu_oversample(x, factor)
        assert y.dtype == np.complex64 and y.shape == ref.shape
        assert rel_db(y, ref) < -120


def test_column_blocks_change_nothing(monkeypatch):
    from fwdlook_cli.forward.gpu_stages import keystone_pair

    monkeypatch.setenv(ENV_XP, "numpy")
    rng = np.random.default_rng(2)
    xs, xd = (rng.standard_normal((2, 64, 40)) + 1j * rng.standard_normal((2, 64, 40))).astype(np.complex64)
    kw = dict(alpha=np.tile(1 + np.linspace(-1e-3, 1e-3, 8), 5), t0_index=np.repeat(np.arange(5) * 3.5, 8),
              ambiguity=4)
    whole = keystone_pair(xs, xd, **kw)
    blocks = keystone_pair(xs, xd, block_bytes=1, **kw)       # one column per block
    for a, b in zip(whole, blocks):
        np.testing.assert_array_equal(a, b)


def _run(argv):
    with pytest.raises(SystemExit) as info:
        main([str(a) for a in argv])
    return info.value.code


def test_whole_run_with_the_gpu_backend_gives_the_cpu_metrics(tmp_path, monkeypatch):
    """``fwdlook run`` with processing.backend = gpu (forced onto numpy): the metrics' targets of cpu."""
    monkeypatch.setenv(ENV_XP, "numpy")
    scenario = SCENARIOS / "tiny.yaml"
    assert _run(["run", scenario, "-o", tmp_path / "cpu", "-q"]) == 0
    assert _run(["run", scenario, "-o", tmp_path / "gpu", "-q", "--set", "processing.backend=gpu"]) == 0
    a, b = (json.loads((tmp_path / d / "metrics.json").read_text()) for d in ("cpu", "gpu"))
    assert a["targets"]
    same_targets(a["targets"], b["targets"])


def same_targets(rows_a, rows_b):
    """The same targets, flags and numbers; the numbers to 1e-5: what a -140 dB difference of the two
    complex64 keystones leaves (measured on the tiny scene: at most 4e-7 m in range, 3e-9 deg in
    azimuth, 1e-6 dB in ISLR, PSLR and peak loss; the range cell is 6.2 m, the angle bin 0.05 deg)."""
    assert [r["id"] for r in rows_a] == [r["id"] for r in rows_b]
    for ra, rb in zip(rows_a, rows_b):
        assert ra.keys() == rb.keys()
        for key, va in ra.items():
            if isinstance(va, float) and not isinstance(va, bool):
                assert rb[key] == pytest.approx(va, rel=1e-5, abs=1e-5), key
            else:
                assert rb[key] == va, key


def test_stages_without_a_gpu_path_stay_on_the_cpu(monkeypatch, caplog):
    monkeypatch.setenv(ENV_XP, "numpy")
    scn = tiny_scenario(processing={"keystone": "dft", "method": "traditional"})
    cube, _ = simulate_scenario(scn)
    with caplog.at_level(logging.INFO, logger="fwdlook_cli.forward.gpu_stages"):
        _, stages, _ = build_forward_stages(cube, dict(scn["processing"], backend="gpu"))
    fns = {st.name: st.fn.__module__ for st in stages}
    assert fns["keystone"] == "fwdlook_cli.forward.chain"
    assert fns["doppler_spectra"] == "fwdlook_cli.forward.gpu_stages"
    assert fns["monopulse_image"] == "fwdlook_cli.forward.gpu_imaging"
    assert any("keystone runs on the CPU" in r.getMessage() and "dft" in r.getMessage() for r in caplog.records)


def test_dwell_imaging_keeps_its_stages_and_moves_the_keystone(monkeypatch):
    monkeypatch.setenv(ENV_XP, "numpy")
    scn = tiny_scenario(processing={"method": "tracking", "imaging": "dwell"})
    cube, _ = simulate_scenario(scn)
    _, cpu, _ = build_forward_stages(cube, dict(scn["processing"]))
    _, gpu, _ = build_forward_stages(cube, dict(scn["processing"], backend="gpu"))
    assert [st.name for st in gpu] == [st.name for st in cpu]
    moved = [st.name for st, sc in zip(gpu, cpu) if st.fn is not sc.fn]
    assert moved == ["keystone"] and gpu[2].fn.__module__ == "fwdlook_cli.forward.gpu_stages"


# ----------------------------------------------------------------------------------------------
# the CuPy branches with a stand-in device module (tests/fake_cupy.py: numpy arrays of their own
# type that refuse host arrays in device arithmetic, FFTs that refuse scipy's `workers`)
# ----------------------------------------------------------------------------------------------
@pytest.fixture
def fake_cupy(monkeypatch):
    import fake_cupy

    monkeypatch.delenv(ENV_XP, raising=False)
    return fake_cupy.install(monkeypatch)


@pytest.mark.parametrize("case", ["paper-decimation", "paper-tracking", "tiny-traditional"])
def test_cupy_branches_keep_host_and_device_apart(case, fake_cupy):
    assert get_xp("gpu") is fake_cupy
    check_pairs(stage_pairs(CASES[case]()))


def test_fake_device_refuses_host_arrays(fake_cupy):
    """The stand-in is strict where CuPy is (else the test above proves nothing)."""
    dev = fake_cupy.asarray(np.ones(4))
    with pytest.raises(TypeError, match="host array"):
        dev + np.ones(4)
    with pytest.raises(TypeError, match="host"):
        __import__("cupyx.scipy.fft").scipy.fft.fft(np.ones(4))
    with pytest.raises(TypeError, match="workers"):
        __import__("cupyx.scipy.fft").scipy.fft.fft(dev, workers=-1)
    assert type(dev.get()) is np.ndarray and type(dev * 2.0) is fake_cupy.ndarray


def test_whole_run_and_bench_through_the_cupy_branches(tmp_path, fake_cupy):
    from fwdlook_cli.report.gpu_bench import run_gpu_bench

    scenario = SCENARIOS / "tiny.yaml"
    assert _run(["run", scenario, "-o", tmp_path / "cpu", "-q"]) == 0
    assert _run(["run", scenario, "-o", tmp_path / "gpu", "-q", "--set", "processing.backend=gpu"]) == 0
    a, b = (json.loads((tmp_path / d / "metrics.json").read_text()) for d in ("cpu", "gpu"))
    same_targets(a["targets"], b["targets"])
    out = run_gpu_bench(tiny_scenario(), repeats=1)
    assert out["device"] == "fake cupy (numpy)" and len(out["ratios_to_fft2"]) == 10
    # what the device computed against the CPU stages on the same inputs: the figures a GPU run reports
    for method in ("decimation", "tracking"):
        for stage, keys in (("keystone", ("sum_f", "diff_f")), ("doppler_spectra", ("sum_z", "diff_z"))):
            for key in keys:
                assert out[f"gpu_vs_cpu_{method}_{stage}_{key}_db"] < -130     # numpy both sides
        assert out[f"gpu_vs_cpu_{method}_cells_same"] is True
        assert out[f"gpu_vs_cpu_{method}_cells_cpu"] == out[f"gpu_vs_cpu_{method}_cells_gpu"] > 20
        assert out[f"gpu_vs_cpu_{method}_image_db"] < -120
        for which in ("cpu", "gpu"):
            assert out[f"chain_{which}_{method}_s"] > 0
    assert out["host_ratios_to_fft2"]["chain_cpu_decimation"] == pytest.approx(
        out["chain_cpu_decimation_s"] / out["host_fft2_s"])


def test_bench_agreement_measures_what_it_names():
    """relative_error_db against a closed form: an error of amplitude eps everywhere is 20 log10(eps)."""
    from fwdlook_cli.report.gpu_bench import relative_error_db

    ref = np.exp(1j * np.linspace(0, 7, 1000))
    assert relative_error_db(ref * (1 + 1e-4), ref) == pytest.approx(-80.0, abs=1e-6)
    assert relative_error_db(ref, ref) == -300.0
    assert relative_error_db(ref + 1e-200, ref) == -300.0


# ----------------------------------------------------------------------------------------------
# without CuPy or a device: one line, exit 2
# ----------------------------------------------------------------------------------------------
def test_gpu_backend_without_cupy_is_bad_input_exit_2(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv(ENV_XP, raising=False)
    if not _no_gpu():
        pytest.skip("a GPU is present: the backend works here")
    code = _run(["run", SCENARIOS / "tiny.yaml", "-o", tmp_path / "run", "-q", "--set", "processing.backend=gpu"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and "Traceback" not in err
    assert "processing.backend = gpu" in err and "allowed on this machine: cpu" in err
    assert "pip install -e .[gpu]" in err


def test_bench_backend_gpu_without_a_gpu_exits_2(monkeypatch, capsys):
    monkeypatch.delenv(ENV_XP, raising=False)
    if not _no_gpu():
        pytest.skip("a GPU is present")
    assert _run(["bench", "--backend", "gpu"]) == 2
    err = capsys.readouterr().err.strip()
    # the option named (not processing.backend, which the command line did not use), before any timing
    assert "\n" not in err and err.startswith("fwdlook: error: --backend = gpu:") and "pip install -e .[gpu]" in err


def test_without_cupy_fwdlook_imports_and_gpu_is_bad_input(monkeypatch):
    """Whatever is installed: with ``import cupy`` failing, the chain's modules import, cpu works, and
    gpu is the one-line BadInput (never an ImportError)."""
    import importlib
    import sys

    monkeypatch.delenv(ENV_XP, raising=False)
    monkeypatch.setitem(sys.modules, "cupy", None)           # `import cupy` raises ImportError
    for name in ("fwdlook_cli.dsp.xp", "fwdlook_cli.forward.gpu_stages", "fwdlook_cli.forward.gpu_imaging",
                 "fwdlook_cli.report.gpu_bench", "fwdlook_cli.forward.chain"):
        importlib.import_module(name)
    assert get_xp("cpu") is np
    with pytest.raises(BadInput, match=r"processing\.backend = gpu: CuPy cannot be imported.*allowed on this "
                                       r"machine: cpu "):
        get_xp("gpu")


def test_unknown_forced_array_module_is_bad_input(monkeypatch):
    monkeypatch.setenv(ENV_XP, "torch")
    with pytest.raises(BadInput, match="FWDLOOK_XP"):
        get_xp("gpu")
    assert get_xp("cpu") is np


# ----------------------------------------------------------------------------------------------
# CuPy and a CUDA device: the same comparisons on the GPU
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("case", sorted(CASES))
def test_gpu_stages_equal_the_cpu_stages_on_the_device(case, monkeypatch):
    _cupy_device()
    monkeypatch.delenv(ENV_XP, raising=False)
    check_pairs(stage_pairs(CASES[case]()))


def test_gpu_czt_keystone_equals_the_direct_dft_on_the_device():
    cupy = _cupy_device()
    rng = np.random.default_rng(11)
    n, cols = 100, 12
    alpha = 18e9 / (18e9 + np.linspace(-30e6, 30e6, cols))
    t0 = rng.uniform(0, n, cols)
    x = (rng.standard_normal((n, cols)) + 1j * rng.standard_normal((n, cols))).astype(np.complex64)
    y = czt_keystone(cupy, cupy.asarray(np.ascontiguousarray(x.T)), alpha=alpha, t0_index=t0, ambiguity=11).T
    ref = keystone_dft(x.astype(np.complex128), alpha, t0_index=t0, ambiguity=11)
    assert rel_db(y.get(), ref) < -120


def test_whole_run_on_the_device_gives_the_cpu_metrics(tmp_path, monkeypatch):
    _cupy_device()
    monkeypatch.delenv(ENV_XP, raising=False)
    scenario = SCENARIOS / "tiny.yaml"
    assert _run(["run", scenario, "-o", tmp_path / "cpu", "-q"]) == 0
    assert _run(["run", scenario, "-o", tmp_path / "gpu", "-q", "--set", "processing.backend=gpu"]) == 0
    a, b = (json.loads((tmp_path / d / "metrics.json").read_text()) for d in ("cpu", "gpu"))
    same_targets(a["targets"], b["targets"])


def test_gpu_bench_reports_device_ratios(monkeypatch):
    """The bench's GPU path (forced onto numpy, tiny scene): a median of >= 20 fft2, every GPU stage of
    both methods, ratios to that fft2."""
    from fwdlook_cli.report.gpu_bench import GPU_STAGES, run_gpu_bench

    monkeypatch.setenv(ENV_XP, "numpy")
    out = run_gpu_bench(tiny_scenario(), repeats=1)
    assert out["fft2_repeats"] >= 20 and out["fft2_s"] > 0 and "not a GPU figure" in out["device"]
    for method in ("decimation", "tracking"):
        for name in GPU_STAGES:
            key = f"gpu_stage_{method}_{name}"
            assert out[key + "_s"] > 0
            assert out["ratios_to_fft2"][key] == pytest.approx(out[key + "_s"] / out["fft2_s"])


def test_gpu_bench_on_the_device():
    from fwdlook_cli.report.gpu_bench import GPU_STAGES, run_gpu_bench

    _cupy_device()
    out = run_gpu_bench(tiny_scenario(), repeats=3)
    assert out["fft2_repeats"] >= 20 and "not a GPU figure" not in out["device"]
    assert all(out["ratios_to_fft2"][f"gpu_stage_{m}_{n}"] > 0 for m in ("decimation", "tracking") for n in GPU_STAGES)
