"""``processing.range_oversample: auto``: the image's range grid at the power image's Nyquist rate.

The power |s|^2 of a range-compressed echo of bandwidth B has a spectrum 2B wide (the autocorrelation of
the echo's), so its samples at k fs hold it whole once k fs >= 2B: band-limited interpolation of the
power samples then gives the power between them.  Below that rate it aliases and does not."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fwdlook_cli.dsp.imaging import auto_range_oversample
from fwdlook_cli.dsp.peaks import oversample_range


@pytest.mark.parametrize("bandwidth_hz, fs_hz, want", [
    (50e6, 60e6, 2),        # the paper's radar: 100 / 60 -> 2
    (20e6, 24e6, 2),        # tiny.yaml
    (50e6, 100e6, 1),       # fs = 2B: the native grid already samples the power at its Nyquist rate
    (50e6, 99e6, 2),
    (50e6, 50e6, 2),        # critically sampled echo
    (60e6, 40e6, 3),
    (1e9, 1e6, 16),         # capped
])
def test_auto_factor_is_the_power_nyquist_rate(bandwidth_hz, fs_hz, want):
    assert auto_range_oversample(bandwidth_hz, fs_hz) == want


def _power_interpolated(power, factor):
    """Band-limited interpolation of real power samples by ``factor`` (numpy's FFT, zero padding; the
    Nyquist bin split as scipy.signal.resample does): an implementation that shares nothing with
    ``oversample_range``."""
    n = power.shape[-1]
    spec = np.fft.fft(power.astype(np.float64), axis=-1)
    m = n * factor
    out = np.zeros(power.shape[:-1] + (m,), complex)
    h = n // 2
    out[..., :h] = spec[..., :h]
    out[..., m - h:] = spec[..., n - h:]
    if n % 2 == 0:
        out[..., h] = out[..., m - h] = spec[..., h] / 2
    else:
        out[..., h] = spec[..., h]
    return np.fft.ifft(out, axis=-1).real * factor


@pytest.mark.parametrize("bandwidth_hz, fs_hz", [(50e6, 60e6), (20e6, 24e6), (50e6, 50e6)])
def test_power_on_the_auto_grid_holds_the_power_between_its_samples(bandwidth_hz, fs_hz):
    """Point echoes at random sub-sample delays (periodic, band-limited to B at fs): their power on the
    auto grid, interpolated x 4 more, equals the power of the echo oversampled straight to that finer
    grid to float32 rounding; one factor below auto it misses by a large fraction of the peak."""
    n, rng = 256, np.random.default_rng(5)
    f = np.fft.fftfreq(n, 1 / fs_hz)
    delays = rng.uniform(100, 150, 16) / fs_hz
    spectrum = np.where(np.abs(f) <= bandwidth_hz / 2, 1.0, 0.0) * np.exp(-2j * np.pi * f * delays[:, None])
    echo = np.fft.ifft(spectrum, axis=-1).astype(np.complex64)
    k = auto_range_oversample(bandwidth_hz, fs_hz)
    for factor, agrees in ((k, True), (k - 1, False)):
        if factor < 1:
            continue
        fine = np.abs(oversample_range(echo, 4 * factor)) ** 2
        coarse = np.abs(oversample_range(echo, factor)) ** 2
        err = np.max(np.abs(_power_interpolated(coarse, 4) - fine)) / fine.max()
        assert (err < 1e-5) if agrees else (err > 0.05), (factor, err)


def test_the_chain_resolves_auto_and_reports_it(tmp_path):
    """The default (auto) on tiny.yaml's radar (20 MHz at 24 MHz): x 2, the image's range axis at half
    the native spacing, metrics.json's ``params.range_oversample`` 2; an explicit factor is kept."""
    from fwdlook_cli.forward.process import process_cube
    from fwdlook_cli.forward.simulate import simulate_scenario
    import h5py

    from fwdlook_cli.testing import tiny_scenario

    scn = tiny_scenario()
    assert scn["processing"]["range_oversample"] == "auto"
    cube, _ = simulate_scenario(scn)
    native = float(cube.range_m[1] - cube.range_m[0])
    for setting, want in (("auto", 2), (3, 3)):
        scn["processing"]["range_oversample"] = setting
        run = tmp_path / str(setting)
        m = process_cube(cube, scn, run, force=True, quiet=True, png=False, keep_stages="none")
        assert m["params"]["range_oversample"] == want
        with h5py.File(run / "image.h5", "r") as f:
            range_m = f["range_m"][()]
        assert np.allclose(np.diff(range_m), native / want)


def test_plan_gives_the_auto_factor():
    """``fwdlook plan`` reports the factor auto takes: x 2 for the paper's radar (50 MHz at 60 MHz)."""
    from fwdlook_cli.forward.plan import format_plan, plan_for_scenario
    from fwdlook_cli.scenario.loader import load_scenario
    root = Path(__file__).resolve().parents[1]
    plan = plan_for_scenario(load_scenario(root / "scenarios" / "paper_fig6_a50.yaml"))
    assert plan["range_oversample_auto"] == 2
    assert "range oversampling   x 2" in format_plan(plan, "paper")


def test_the_scaling_series_holds_the_doppler_cells_fixed(monkeypatch):
    """``fwdlook bench --scaling`` times the chain at a fixed count of zoomed Doppler cells: with
    ``n_doppler: auto`` the count follows the band in CPI resolution cells, cpi B / PRF, which falls as
    the series raises the PRF with the pulse count (the exponents would then measure the scene)."""
    from fwdlook_cli.forward.chain import build_forward_stages
    from fwdlook_cli.report import benchtools
    from fwdlook_cli.scenario.loader import load_scenario

    root = Path(__file__).resolve().parents[1]
    paper = load_scenario(root / "scenarios" / "paper_fig6_a50.yaml")
    seen = []

    def fake_time_chain(cube, scn, repeats=3, rss=True, keep_stages="all"):
        _, _, geo = build_forward_stages(cube, scn["processing"])
        seen.append((cube.n_pulses, geo["n_doppler"], geo["range_oversample"]))
        stage = {"range_fft": 1e-3}
        return {"stages_s": stage, "total_s": 1e-3, "stages_user_cpu_s": stage, "user_cpu_s": 1e-3,
                "stages_system_cpu_s": stage, "system_cpu_s": 1e-3}

    monkeypatch.setattr(benchtools, "time_chain", fake_time_chain)
    benchtools.scaling_series(paper, methods=("tracking",), pulses=(1250, 5000), range_bins=(128, 256))
    assert {(n, d) for n, d, _ in seen} == {(1250, benchtools.SCALING_N_DOPPLER), (5000, benchtools.SCALING_N_DOPPLER),
                                          (2500, benchtools.SCALING_N_DOPPLER)}
    assert {k for _, _, k in seen} == {2}
    # what auto would have given: fewer cells as the PRF rises
    auto = [build_forward_stages(*_cube_and_proc(benchtools, paper, n))[2]["n_doppler"] for n in (1250, 5000)]
    assert auto[0] > auto[1]


def _cube_and_proc(benchtools, paper, n_pulses):
    from fwdlook_cli.forward.simulate import simulate_scenario

    scn = benchtools.scaling_scenario(paper, n_pulses, 128)
    cube, _ = simulate_scenario(scn)
    return cube, dict(scn["processing"], method="tracking")
