"""The echoes against the navigation (forward/echo_navigation.py) and processing.navigation_delay_s
(io/navigation.py::delayed_track).

A navigation that lags the radar by d passes every check of the navigation against itself; its velocity
at radar time t is v(t - d) = v(t) - a d, so the echoes' Doppler at their monopulse angles sits
2 (a . u) d / lambda above the record's prediction.  The lagged cubes here are written by the closed form
of the simulator's constant acceleration (p - v d + a d^2 / 2, v - a d), not by the code under test.
"""
from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

import fwdlook_cli as fw
from cli_runner import run_cli
from fwdlook_cli.dsp.geometry import C_MPS
from fwdlook_cli.forward.echo_navigation import MAX_BLEND_HZ, MIN_CPIS, echo_navigation_check
from fwdlook_cli.io.navigation import delayed_track, with_navigation

ROOT = Path(__file__).resolve().parents[1]


def _track(t, p0=(10.0, -5.0, 50.0), v0=(3.0, 240.0, 1.0), a=(1.0, 50.0, -2.0)):
    p0, v0, a = map(np.asarray, (p0, v0, a))
    return p0 + v0 * t[:, None] + 0.5 * a * t[:, None] ** 2, v0 + a * t[:, None]


@pytest.mark.parametrize("delay_s", [0.005, -0.005, 1.3e-4, -0.0123, 0.0])
def test_delayed_track_is_the_track_at_the_later_time(delay_s):
    """Cubic Hermite positions and linear velocities are exact for a constant acceleration, inside the
    record and beyond its ends (the end's acceleration), on a uniform and on a random pulse train."""
    for t in (np.arange(2500) / 2500.0, np.sort(np.random.default_rng(1).uniform(0.0, 1.0, 500))):
        p, v = _track(t)
        p_d, v_d = delayed_track(t, p, v, delay_s)
        p_true, v_true = _track(t + delay_s)
        assert np.abs(p_d - p_true).max() < 1e-9 and np.abs(v_d - v_true).max() < 1e-9


def test_delayed_track_extrapolates_along_the_velocities_least_squares_line():
    """Beyond the record's end the velocity follows the least-squares line of the velocities over the
    end's 20 ms: with white velocity noise sigma its error 5 ms out has the line's prediction sigma,
    sigma sqrt(1 / n + (d + span / 2)^2 / sum (t - t_mean)^2) (the last two samples' slope had carried the
    noise about 15 times: 0.45 m/s for 0.02 m/s)."""
    t = np.arange(2500) / 2500.0
    p, v = _track(t)
    rng = np.random.default_rng(5)
    sigma, d = 0.02, 0.005
    end = t[np.abs(t - t[-1]) <= 0.02]
    predicted = sigma * np.sqrt(1 / len(end) + (t[-1] + d - end.mean()) ** 2 / np.sum((end - end.mean()) ** 2))
    errors = [delayed_track(t, p, v + rng.standard_normal(v.shape) * sigma, d)[1][-1] - _track(t[-1:] + d)[1][0]
              for _ in range(100)]
    assert np.sqrt(np.mean(np.square(errors))) == pytest.approx(predicted, rel=0.15)


def test_with_navigation_delays_before_the_source_and_only_once():
    cube = fw.simulate_cube(fw.load_scenario(ROOT / "scenarios" / "tiny.yaml"))
    assert with_navigation(cube, "recorded", 0.0) is cube
    moved = with_navigation(cube, "recorded", 0.004)
    p_true, v_true = delayed_track(cube.slow_time_s, cube.position_m, cube.velocity_mps, 0.004)
    assert np.array_equal(moved.position_m, p_true) and np.array_equal(moved.velocity_mps, v_true)
    assert with_navigation(moved, "recorded", 0.004) is moved and moved.sum is cube.sum
    fused = with_navigation(cube, "fused", 0.004)
    assert np.allclose(fused.position_m, p_true, atol=1e-6)      # the simulated track blends to itself


def test_the_two_sides_give_the_offset_and_the_pointing_error_exactly():
    """m = c0 + F sin(theta) b on each side of the flight axis: synthetic cells with exactly that residual
    give c0 and b back to rounding, and the delay c0 lambda / (2 a_los); without acceleration along the
    lines of sight no delay; one side alone gives c0 only; fewer than MIN_CPIS CPIs, nothing."""
    rng = np.random.default_rng(3)
    fc, c0, b_deg = 18e9, 7.5, 0.3
    lam = C_MPS / fc
    n_cpi, per = 40, 25
    cpi = np.repeat(np.arange(n_cpi), per)
    theta = np.radians(np.where(cpi < n_cpi // 2, -12.0, 11.0) + rng.uniform(-2, 2, cpi.size))
    f_span = 2 * rng.uniform(240.0, 290.0, n_cpi)[cpi] / lam           # F per CPI (its speed)
    residual = c0 + f_span * np.sin(theta) * np.radians(b_deg)
    los = np.stack([np.sin(theta), np.cos(theta), np.zeros_like(theta)], axis=1)
    out = echo_navigation_check(cpi, residual, los, np.sin(theta), f_span, fc_hz=fc, accel_mps2=[0.0, 50.0, 0.0],
                                speed_mps=265.0)
    # each CPI's cells share F; the sides' medians of F sin(theta) are one CPI's, the model's exactly
    assert out["sides"] == 2 and out["pointing_error_deg"] == pytest.approx(b_deg, rel=1e-9)
    assert out["doppler_offset_hz"] == pytest.approx(c0, rel=1e-9)
    accel_los = np.median(50.0 * np.cos(theta))
    assert out["delay_s"] == pytest.approx(lam * out["doppler_offset_hz"] / 2 / accel_los, rel=1e-12)
    still = echo_navigation_check(cpi, residual, los, np.sin(theta), f_span, fc_hz=fc, accel_mps2=[0.0, 0.0, 0.0],
                                  speed_mps=265.0)
    assert still["delay_s"] is None and still["doppler_offset_hz"] == out["doppler_offset_hz"]
    right = theta > 0
    one = echo_navigation_check(cpi[right], np.full(right.sum(), c0), los[right], np.sin(theta[right]),
                                f_span[right], fc_hz=fc, accel_mps2=[0.0, 50.0, 0.0], speed_mps=265.0)
    assert one["sides"] == 1 and one["doppler_offset_hz"] == c0 and one["pointing_error_deg"] is None
    few = cpi < MIN_CPIS - 1
    assert echo_navigation_check(cpi[few], residual[few], los[few], np.sin(theta[few]), f_span[few], fc_hz=fc,
                                 accel_mps2=[0.0, 50.0, 0.0], speed_mps=265.0)["doppler_offset_hz"] is None


def _rewritten(src, dst, *, lag_s=0.0, scan_offset_deg=0.0):
    shutil.copy(src, dst)
    with h5py.File(dst, "a") as f:
        t, p, v = f["axes/slow_time_s"][()], f["platform/position_m"][()], f["platform/velocity_mps"][()]
        a = np.polyfit(t, v, 1)[0]                       # the simulator's constant acceleration
        f["platform/position_m"][...] = p - v * lag_s + 0.5 * a * lag_s ** 2
        f["platform/velocity_mps"][...] = v - a * lag_s
        f["axes/scan_angle_deg"][...] = f["axes/scan_angle_deg"][()] + scan_offset_deg
    return dst


def test_the_echoes_measure_a_navigation_lag_and_a_pointing_error(tmp_path, capsys):
    """The paper's cube (a = 50 m/s^2, 18 GHz: 2 a d / lambda = 6 Hz per ms), `decimation`, CPI imaging.
    Each estimate within 3 of its own sigmas of the truth, the offset also within the blind zone's bound
    below it (MAX_BLEND_HZ: blended cells read low).  The simulated cube: no delay and no pointing error
    said; lagged by 5 ms (the targets 1.2-1.4 m off): the delay, and the warning naming
    processing.navigation_delay_s, under dwell imaging too (its CPI spectra on the strongest range
    columns); that setting at the true lag gives the simulated cube's image (the delayed track is exact
    for a constant acceleration); scan angles recorded 0.3 deg off: the pointing error, said, and no
    delay; processing.scan_angle_offset_deg at 0.3 gives the simulated cube's image."""
    cube = fw.simulate_cube(fw.load_scenario(ROOT / "scenarios" / "paper_fig6_a50.yaml"))
    src = tmp_path / "paper.h5"
    fw.write_raw(src, cube)
    sets = ["-c", str(ROOT / "configs" / "decimation.yaml")]

    def run(path, name, *extra):
        code, out, err = run_cli(["process", str(path), "-o", str(tmp_path / name)] + sets + list(extra), capsys)
        assert code == 0, err
        with h5py.File(tmp_path / name / "image.h5") as f:
            image = f["image"][()].astype(np.float64)
        return json.loads((tmp_path / name / "metrics.json").read_text()), err, image

    def delay_within(check, truth_s):
        per_hz = 2 * check["accel_los_mps2"] / (C_MPS / cube.radar["fc_hz"])     # Hz per second of delay
        error_hz = (check["delay_s"] - truth_s) * per_hz
        return -(3 * check["sigma_hz"] + MAX_BLEND_HZ) <= error_hz <= 3 * check["sigma_hz"]

    clean, err, clean_image = run(src, "clean")
    check = clean["echo_navigation"]
    assert check["sides"] == 2 and check["cells"] > 200 and delay_within(check, 0.0), check
    assert abs(check["pointing_error_deg"]) <= 3 * check["sigma_pointing_deg"], check
    assert "echoes' Doppler" not in err
    lagged = _rewritten(src, tmp_path / "lagged.h5", lag_s=0.005)
    metrics, err, _ = run(lagged, "lagged")
    check = metrics["echo_navigation"]
    assert delay_within(check, 0.005) and check["shift_m"] > 1.0, check
    assert "processing.navigation_delay_s" in err and "lagging the radar" in err
    metrics, err, _ = run(lagged, "partly", "--set", "processing.navigation_delay_s=0.002")
    check = metrics["echo_navigation"]          # what the setting left, and the warning names the sum
    assert delay_within(check, 0.003), check
    said = float(re.search(r"set processing.navigation_delay_s: (-?[0-9.]+)", err).group(1))
    assert said == pytest.approx(0.002 + check["delay_s"], abs=1e-5)
    metrics, err, image = run(lagged, "undone", "--set", "processing.navigation_delay_s=0.005")
    assert metrics["params"]["navigation_delay_s"] == 0.005 and "lagging the radar" not in err
    assert np.sum((image - clean_image) ** 2) < 1e-10 * np.sum(clean_image ** 2)
    metrics, err, _ = run(lagged, "dwell", "--set", "processing.imaging=dwell")   # spectra of its strong columns
    check = metrics["echo_navigation"]
    assert delay_within(check, 0.005) and "lagging the radar" in err, check
    pointed = _rewritten(src, tmp_path / "pointed.h5", scan_offset_deg=0.3)
    metrics, err, _ = run(pointed, "pointed")
    check = metrics["echo_navigation"]
    assert abs(check["pointing_error_deg"] - 0.3) <= 3 * check["sigma_pointing_deg"], check
    assert delay_within(check, 0.0) and "pointing error" in err and "lagging the radar" not in err, check
    assert "processing.scan_angle_offset_deg" in err
    metrics, err, image = run(pointed, "pointed_undone", "--set", "processing.scan_angle_offset_deg=0.3")
    assert metrics["params"]["scan_angle_offset_deg"] == 0.3 and "pointing error" not in err
    assert np.sum((image - clean_image) ** 2) < 1e-10 * np.sum(clean_image ** 2)


def test_at_steep_depression_only_a_method_that_holds_its_ranges_is_read():
    """At 800 m height the predicted Doppler moves about 4 Hz per metre of range (through the depression),
    and `decimation`'s budget leaves metres of range error there (a review: +16 Hz, a false delay of 2.6
    ms, from its range errors): its cells are not counted (no estimate), while `tracking`, which holds
    its ranges (range_error_m 0), reads the clean cube's delay within its bounds."""
    from fwdlook_cli.forward.chain import build_forward_stages
    from fwdlook_cli.forward.echo_navigation import echo_navigation_of

    scn = fw.load_scenario(ROOT / "scenarios" / "paper_fig6_a50.yaml", overrides=["platform.height_m=800"])
    cube = fw.simulate_cube(scn)
    for method, held in (("decimation", False), ("tracking", True)):
        proc = dict(scn["processing"], method=method, q=25, imaging="cpi", dwell_fit="none")
        src, stages, geo = build_forward_stages(cube, proc)
        data = src
        for stage in stages[:stages.index(next(s for s in stages if s.name == "doppler_spectra")) + 1]:
            data = stage.fn(data, **stage.params)
        check = echo_navigation_of(data, geo["calibration"], fc_hz=cube.radar["fc_hz"],
                                   beamwidth_deg=cube.radar["beamwidth_3db_deg"], prf_hz=cube.radar["prf_hz"],
                                   cpi=proc["cpi"], position_ref_m=geo["p_ref"],
                                   speed_mps=float(np.linalg.norm(geo["v_ref"])),
                                   range_resolution_m=C_MPS / (2 * cube.radar["bandwidth_hz"]),
                                   range_error_m=geo["range_error_m"])
        if held:
            assert geo["range_error_m"] == 0.0 and check["cells"] > 200, check
            assert -(3 * check["sigma_hz"] + MAX_BLEND_HZ) <= check["doppler_offset_hz"] <= 3 * check["sigma_hz"]
        else:
            assert geo["range_error_m"] > 1.25 and check["doppler_offset_hz"] is None, (geo["range_error_m"], check)
