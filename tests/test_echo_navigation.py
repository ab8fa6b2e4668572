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
import yaml

import fwdlook_cli as fw
from cli_runner import run_cli
from fwdlook_cli.dsp.blas import on_one_blas_thread
from fwdlook_cli.dsp.geometry import C_MPS
from fwdlook_cli.forward.echo_navigation import MAX_BLEND_HZ, MIN_SIDE_CPIS, Cells, echo_navigation_check
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


def test_with_navigation_moves_the_track_and_the_scan_angles_once():
    """Both records at t + d (against the closed form of the simulator's constant acceleration, not the
    interpolation under test), the scan angles less the offset, the echoes shared; the same settings
    again give the cube back; other settings on a moved cube are refused (a second delay had compounded
    the first, a review); ``fused`` of the simulated track is that track."""
    cube = fw.simulate_cube(fw.load_scenario(ROOT / "scenarios" / "tiny.yaml"))
    assert with_navigation(cube, "recorded", 0.0) is cube
    accel = np.polyfit(cube.slow_time_s, cube.velocity_mps, 1)[0]
    moved = with_navigation(cube, "recorded", 0.004, 0.3)
    assert np.allclose(moved.position_m, cube.position_m + cube.velocity_mps * 0.004 + 0.5 * accel * 0.004 ** 2,
                       rtol=0, atol=1e-9)
    assert np.allclose(moved.velocity_mps, cube.velocity_mps + accel * 0.004, rtol=0, atol=1e-9)
    assert np.array_equal(moved.scan_angle_deg, cube.scan_angle_deg - 0.3) and moved.sum is cube.sum
    assert with_navigation(moved, "recorded", 0.004, 0.3) is moved
    with pytest.raises(ValueError):
        with_navigation(moved, "recorded", 0.002, 0.3)
    fused = with_navigation(cube, "fused", 0.004)
    assert np.allclose(fused.position_m, moved.position_m, rtol=0, atol=1e-6)


def test_the_two_sides_give_the_offset_and_the_pointing_error_exactly():
    """m = c0 + F sin(psi) b on each side of the flight axis: synthetic cells with exactly that residual
    give c0 and b back to rounding, and the delay c0 lambda / (2 a_los); without acceleration along the
    lines of sight no delay, nor where it pins the delay to no better than a range sample's shift (a
    0.05 m/s bias with 0.02 m/s^2 had read a 2.5 s delay and an unsettable setting, a review); one side
    alone gives c0 and the pointing error that would read the same (c0 / g); a side of fewer than
    MIN_SIDE_CPIS CPIs does not count (one CPI's MAD is 0: a review's sigma had read 0.09 Hz)."""
    rng = np.random.default_rng(3)
    fc, c0, b_deg = 18e9, 7.5, 0.3
    lam = C_MPS / fc
    n_cpi, per = 40, 25
    cpi = np.repeat(np.arange(n_cpi), per)
    psi = np.radians(np.where(cpi < n_cpi // 2, -12.0, 11.0) + rng.uniform(-2, 2, cpi.size))
    f_span = 2 * rng.uniform(240.0, 290.0, n_cpi)[cpi] / lam           # F per CPI (its speed)
    residual = c0 + f_span * np.sin(psi) * np.radians(b_deg)
    los = np.stack([np.sin(psi), np.cos(psi), np.zeros_like(psi)], axis=1)

    def check(mask, accel=(0.0, 50.0, 0.0), values=residual):
        return echo_navigation_check(Cells(cpi[mask], values[mask], los[mask], np.sin(psi[mask]), f_span[mask]),
                                     fc_hz=fc, accel_mps2=accel, speed_mps=265.0, range_spacing_m=2.5)

    out = check(slice(None))
    # each CPI's cells share F; the sides' medians of F sin(psi) are one CPI's, the model's exactly
    assert out["sides"] == 2 and out["pointing_error_deg"] == pytest.approx(b_deg, rel=1e-9)
    assert out["doppler_offset_hz"] == pytest.approx(c0, rel=1e-9) and out["pointing_alternative_deg"] is None
    accel_los = np.median(50.0 * np.cos(psi))
    assert out["delay_s"] == pytest.approx(lam * out["doppler_offset_hz"] / 2 / accel_los, rel=1e-12)
    assert check(slice(None), accel=(0.0, 0.0, 0.0))["delay_s"] is None
    faint = check(slice(None), accel=(0.0, 0.02, 0.0))     # sigma_delay x 265 m/s far over a range sample
    assert faint["doppler_offset_hz"] == out["doppler_offset_hz"] and faint["delay_s"] is None
    right = psi > 0
    one = check(right, values=np.full(cpi.size, c0) + f_span * np.sin(psi) * np.radians(b_deg))
    lever = np.median(f_span[right][::per] * np.median(np.sin(psi[right]).reshape(-1, per), axis=1))
    assert one["sides"] == 1 and one["pointing_error_deg"] is None
    assert one["pointing_alternative_deg"] == pytest.approx(np.degrees(one["doppler_offset_hz"] / lever), rel=1e-12)
    lopsided = right | (cpi == 0)              # one CPI on the left: the right side alone counts
    assert check(lopsided)["sides"] == 1
    assert check(cpi < MIN_SIDE_CPIS - 1)["doppler_offset_hz"] is None


@pytest.mark.parametrize("c0_hz, b_deg", [(1230.0, 0.3), (1248.0, 0.0), (-1249.0, 0.0), (1000.0, 1.0)])
def test_an_offset_near_half_the_prf_reads_as_one_cluster(c0_hz, b_deg):
    """The residuals are known modulo the PRF (2500 Hz): an offset near +-1250 Hz puts the cells of one
    side on both ends of the wrap.  Their medians, spreads and the two-side solve had read 1230 Hz with
    a 0.3 deg pointing error as -76.5 +- 0.4 Hz and -11 deg, and 1248 Hz as 1243 +- 0.4 Hz (a review); now
    each side is taken about its circular mean and the sides within half a PRF of each other: the offset
    and the pointing error within 3 sigma (cells with 5 Hz of Gaussian scatter; 1000 Hz with a 1 deg
    pointing error, no side across the wrap, read right before too)."""
    from fwdlook_cli.forward.echo_navigation import wrapped_hz

    rng = np.random.default_rng(3)
    fc, prf = 18e9, 2500.0
    lam = C_MPS / fc
    n_cpi, per = 40, 25
    cpi = np.repeat(np.arange(n_cpi), per)
    psi = np.radians(np.where(cpi < n_cpi // 2, -12.0, 11.0) + rng.uniform(-2, 2, cpi.size))
    f_span = 2 * rng.uniform(240.0, 290.0, n_cpi)[cpi] / lam
    los = np.stack([np.sin(psi), np.cos(psi), np.zeros_like(psi)], axis=1)
    residual = c0_hz + f_span * np.sin(psi) * np.radians(b_deg) + 5.0 * rng.standard_normal(cpi.size)
    out = echo_navigation_check(Cells(cpi, wrapped_hz(residual, prf), los, np.sin(psi), f_span, prf), fc_hz=fc,
                                accel_mps2=(0.0, 50.0, 0.0), speed_mps=265.0, range_spacing_m=2.5)
    assert abs(wrapped_hz(out["doppler_offset_hz"] - c0_hz, prf)) <= 3 * out["sigma_hz"], out
    assert abs(out["pointing_error_deg"] - b_deg) <= 3 * out["sigma_pointing_deg"], out


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


@on_one_blas_thread          # as process_cube runs the chain (an OpenBLAS pool woken here had slowed later tests)
def _check_of(scn, *, lag_s=0.0, scan_offset_deg=0.0, **processing):
    """The chain run to its Doppler stage on the simulated cube of ``scn`` (its track lagged by ``lag_s``
    in the closed form, its scan angles moved), and ``echo_navigation_of`` with the chain's own inputs."""
    import dataclasses

    from fwdlook_cli.forward.chain import build_forward_stages
    from fwdlook_cli.forward.echo_navigation import echo_navigation_of

    cube = fw.simulate_cube(scn)
    accel = np.polyfit(cube.slow_time_s, cube.velocity_mps, 1)[0]
    cube = dataclasses.replace(cube, position_m=cube.position_m - cube.velocity_mps * lag_s + 0.5 * accel * lag_s ** 2,
                               velocity_mps=cube.velocity_mps - accel * lag_s,
                               scan_angle_deg=cube.scan_angle_deg + scan_offset_deg)
    proc = dict(scn["processing"], imaging="cpi", dwell_fit="none", **processing)
    src, stages, geo = build_forward_stages(cube, proc)
    data = src
    for stage in stages[:[st.name for st in stages].index("doppler_spectra") + 1]:
        data = stage.fn(data, **stage.params)
    check = echo_navigation_of(data, geo["calibration"], fc_hz=cube.radar["fc_hz"],
                               beamwidth_deg=cube.radar["beamwidth_3db_deg"], prf_hz=cube.radar["prf_hz"],
                               cpi=proc["cpi"], position_ref_m=geo["p_ref"], speed_mps=float(np.linalg.norm(geo["v_ref"])),
                               range_spacing_m=float(cube.range_spacing_m),
                               range_resolution_m=C_MPS / (2 * cube.radar["bandwidth_hz"]),
                               range_error_m=geo["range_error_m"])
    return check, geo, cube


def _within(check, truth_s, fc_hz):
    """The offset within 3 sigma of the truth, or within 3 sigma + the blend bound below it."""
    error_hz = check["doppler_offset_hz"] - 2 * check["accel_los_mps2"] * truth_s / (C_MPS / fc_hz)
    return -(3 * check["sigma_hz"] + MAX_BLEND_HZ) <= error_hz <= 3 * check["sigma_hz"]


def test_at_steep_depression_only_a_method_that_holds_its_ranges_is_read():
    """At 800 m height the predicted Doppler moves 4.3-5.1 Hz per metre of range (through the depression),
    and `decimation`'s budget leaves metres of range error there (a review: +16 Hz, a false delay of 2.6
    ms, from its range errors): its cells are not counted (no estimate), while `tracking`, which holds
    its ranges (range_error_m 0), reads the clean cube's offset within its bounds."""
    scn = fw.load_scenario(ROOT / "scenarios" / "paper_fig6_a50.yaml", overrides=["platform.height_m=800"])
    for method, held in (("decimation", False), ("tracking", True)):
        check, geo, cube = _check_of(scn, method=method, q=25)
        if held:
            assert geo["range_error_m"] == 0.0 and check["cells"] > 200 and _within(check, 0.0, cube.radar["fc_hz"])
        else:
            half_sample = 0.5 * cube.range_spacing_m
            assert geo["range_error_m"] > half_sample and check["doppler_offset_hz"] is None, (geo, check)


def _band_limited_point(offsets_samples, fs_over_b: float, taper):
    """The compressed pulse of a point (a band of B with the spectral ``taper`` of f / B, sampled at fs =
    ``fs_over_b`` B) at the range samples ``offsets_samples`` from its peak: the inverse Fourier integral
    of its spectrum, by quadrature (shares nothing with the code under test)."""
    f = np.linspace(-0.5, 0.5, 4001)
    x = np.asarray(offsets_samples, float)
    return np.trapezoid(taper(f)[None, :] * np.exp(2j * np.pi * f[None, :] * x[:, None] / fs_over_b), f, axis=1)


@pytest.mark.parametrize("taper, parabola_worst", [(np.ones_like, 0.2), (lambda f: 0.54 + 0.46 * np.cos(2 * np.pi * f), 0.09)])
def test_a_points_range_peak_is_found_to_a_fiftieth_of_a_sample(taper, parabola_worst):
    """The range peak the check reads is the band-limited profile's own: from +-3 samples at the paper's
    1.2 samples per resolution cell, within 0.02 samples of the truth at every sub-sample offset, for an
    unweighted and a Hamming-tapered pulse, where a parabola through the three native powers (the
    version before) is off by up to 0.21 and 0.10 samples (at 3000 m of height, 14 Hz per metre of range
    in the predicted Doppler: a false 7 Hz offset on a clean cube, a review)."""
    from fwdlook_cli.dsp.profile_rows import parabola_vertex_rows
    from fwdlook_cli.forward.echo_navigation import range_peak_offsets

    truth = np.linspace(-0.5, 0.5, 41)
    around = np.stack([_band_limited_point(np.arange(-3, 4) - d, 1.2, taper) for d in truth])
    assert np.max(np.abs(range_peak_offsets(around) - truth)) <= 0.02
    power = np.abs(around[:, 2:5]) ** 2
    assert np.max(np.abs(parabola_vertex_rows(power[:, 0], power[:, 1], power[:, 2])[0] - truth)) >= parabola_worst


def test_a_residual_is_taken_within_half_a_prf():
    """The pulses sample the Doppler modulo the PRF: residuals whole PRFs apart are one residual."""
    from fwdlook_cli.forward.echo_navigation import wrapped_hz

    prf = 2500.0
    residual = np.array([-3.0, 7.5, 1249.0, -1250.0])
    for k in (-2, -1, 1, 3):
        assert np.allclose(wrapped_hz(residual + k * prf, prf), residual, atol=1e-9)


@pytest.mark.parametrize("height_m, lag_s", [(1000.0, 0.0), (1000.0, 0.005), (3000.0, 0.0)])
def test_at_a_steeper_depression_the_echoes_read_the_navigations_offset(height_m, lag_s):
    """At 1000 m and 3000 m of height the window's Doppler spreads over two PRFs and more (5.4 kHz across
    1.5-1.9 km at 1000 m), and the echoes at its ends lie in their CPI's band whole PRFs from their
    Doppler: read without the wrap, a clean cube gave -1226 Hz and a 15.8 deg pointing error (a review).
    At 3000 m the predicted Doppler moves 14 Hz per metre of range, and a parabola's range peak had read
    a clean cube 7 Hz high.  Now the isolated points, `tracking`, read the truth within the bounds,
    lagged 5 ms or not, and no pointing error beyond 3 sigma."""
    scn = fw.load_scenario(ROOT / "scenarios" / "isolated_a50.yaml", overrides=[f"platform.height_m={height_m}"])
    check, _, cube = _check_of(scn, method="tracking", q=1, lag_s=lag_s)
    assert check["sides"] == 2 and check["cells"] >= 25 and _within(check, lag_s, cube.radar["fc_hz"]), check
    assert abs(check["pointing_error_deg"]) <= 3 * check["sigma_pointing_deg"], check


def test_no_strong_range_column_reads_nothing_and_says_nothing():
    """A dwell chain computes the check's spectra on its strong range columns only; with none (a 3 deg
    beam, 5 dB of SNR: a review) the check had taken a median over no samples, and numpy's two
    RuntimeWarnings reached the terminal.  Now no cell, no warning."""
    import warnings

    from fwdlook_cli.forward.echo_navigation import cell_residuals_hz

    n_cpi, n_doppler = 12, 16
    empty = np.zeros((n_cpi, n_doppler, 0), np.complex64)
    doppler_hz = np.tile(np.linspace(-1000.0, 1000.0, n_doppler), (n_cpi, 1))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        cells = cell_residuals_hz(empty, empty, doppler_hz, np.linspace(-15.0, 15.0, n_cpi),
                                  np.tile([0.0, 240.0, 0.0], (n_cpi, 1)), np.zeros((n_cpi, 3)) + [0.0, 0.0, 50.0],
                                  np.zeros(0), fc_hz=18e9, beamwidth_deg=6.0, prf_hz=2500.0, cpi=32,
                                  offset_of_ratio=lambda r: r, position_ref_m=[0.0, 0.0, 50.0])
    assert len(cells.residual_hz) == 0


@pytest.mark.parametrize("angles_deg", [[0.0, 0.5, 1.1, 1.6, 2.2, 3.2, 4.3, 6.5, 8.6, 10.7, 12.8], [12.8], [10.7, 12.8]])
def test_a_noiseless_cube_reads_only_its_targets_own_peaks(angles_deg):
    """Equal noiseless points off the flight axis (one side), `tracking`: in the CPIs whose beam is aimed
    away from every target the spectra hold only the processing's residue, 80-150 dB under the targets,
    with a monopulse ratio all the same, and a target's range cells in CPIs that see it only far off the
    beam's axis hold it tens of dB down: these had read +60 to +79 Hz (eleven points; a warned 0.76 deg
    pointing error in the dwell chain), a lone point -59.5 Hz and 0.37 deg (a review, against a first
    version's gate at each CPI's median floor).  Counted now: peaks within 12 dB of the strongest at their
    range over the scan and within 100 dB of the strongest of all; the offset within 3 sigma + the blend
    bound of 0, the warning's own test (a lone point reads -0.27 +- 0.06 Hz: noiseless sigmas are tiny)."""
    import math

    from fwdlook_cli.scenario.overlay import resolve_with_config

    points = [[round((1500 + 40 * k) * math.sin(math.radians(a)), 2), round((1500 + 40 * k) * math.cos(math.radians(a)), 2)]
              for k, a in enumerate(angles_deg)]
    spec = yaml.safe_load((ROOT / "scenarios" / "isolated_a50.yaml").read_text())
    spec["scene"]["points_m"], spec["noise"]["snr_db"] = points, None
    scn = resolve_with_config(spec, "noiseless", str(ROOT / "configs" / "tracking.yaml"), [])
    check, _, _ = _check_of(scn, method="tracking", q=1)
    assert check["cells"] >= 10 and abs(check["doppler_offset_hz"]) <= 3 * check["sigma_hz"] + MAX_BLEND_HZ, check


def test_beside_a_very_strong_point_the_others_still_count():
    """One point 80 dB over the others (amplitude 1e4, the scene's bound), the others at 20 dB of SNR, lagged
    5 ms: a gate at 60 dB under the strongest peak had left 6 cells on one side (a review); the main-beam
    gate counts by range, so the weak points at their own ranges count and both sides read the lag within
    the bounds."""
    amplitudes = [1.0] * 11
    amplitudes[5] = 1e4
    scn = fw.load_scenario(ROOT / "scenarios" / "isolated_a50.yaml",
                           overrides=["noise.snr_db=100", f"scene.amplitude={amplitudes}"])
    check, _, cube = _check_of(scn, method="decimation", q=25, lag_s=0.005)
    assert check["sides"] == 2 and check["cells"] > 100 and _within(check, 0.005, cube.radar["fc_hz"]), check


def test_a_strong_points_sidelobes_are_not_read_as_echoes():
    """One point in a CPI's spectrum, its response written here in closed form (a rectangular window's
    Dirichlet kernel in Doppler at 4 cells per resolution cell, an unweighted pulse's sinc in range at 1.2
    samples per resolution cell) over a floor 120 dB down: its far sidelobes are local maxima of a
    single scatterer's curvature, 20 dB and more over the floor, beyond the dominance tests' 2 resolution
    cells.  With the sidelobe envelopes only the point's own peak counts; without them its sidelobes did."""
    from fwdlook_cli.forward.echo_navigation import _peaks, sidelobe_envelopes, single_scatterer_curvature

    prf_hz, cpi, n_doppler, n_range, spacing_m, resolution_m = 2500.0, 32, 48, 64, 2.5, 3.0
    step_hz = prf_hz / cpi / 4
    n = np.arange(cpi)
    doppler = np.exp(2j * np.pi * ((np.arange(n_doppler) - 23.3) * step_hz / prf_hz)[:, None] * n).sum(axis=1) / cpi
    pulse = np.sinc((np.arange(n_range) - 31.6) * spacing_m / resolution_m)
    rng = np.random.default_rng(0)
    z = (doppler[:, None] * pulse[None, :]
         + 1e-6 * (rng.standard_normal((n_doppler, n_range)) + 1j * rng.standard_normal((n_doppler, n_range))))[None]
    range_cells = int(np.ceil(2 * resolution_m / spacing_m))
    doppler_cells = int(np.ceil(2.0 * (prf_hz / cpi) / step_hz))
    eligible = (np.arange(n_range) >= range_cells) & (np.arange(n_range) < n_range - range_cells)
    kw = dict(range_cells=range_cells, doppler_cells=doppler_cells, eligible=eligible,
              min_curvature=0.8 * single_scatterer_curvature(np.ones(cpi), step_hz, prf_hz))
    envelopes = sidelobe_envelopes(np.ones(cpi), step_hz, prf_hz, n_doppler, n_range, spacing_m, resolution_m)
    found = _peaks(z.astype(np.complex64), 20.0, envelopes=envelopes, **kw)
    assert (found[1].tolist(), found[2].tolist()) == ([23], [32])           # the point's own cell only
    assert len(_peaks(z.astype(np.complex64), 20.0, **kw)[0]) > 1          # its sidelobes, without them


def test_only_point_like_peaks_count_in_a_dense_scene():
    """The extended scene (Fig. 8: a road image, scatterers everywhere): without the peak tests its
    sidelobes and blends had read 7-9 Hz low, outside the bounds (a review; the code with the range or
    the Doppler dominance, or the curvature test, removed reads 4.6-13.5 Hz low on these two cases). With
    them, `tracking` lagged 5 ms and `decimation` clean lie within their bounds."""
    scn = fw.load_scenario(ROOT / "scenarios" / "paper_fig8_a50.yaml")
    for method, lag_s in (("tracking", 0.005), ("decimation", 0.0)):
        check, _, cube = _check_of(scn, method=method, q=25, lag_s=lag_s)
        assert check["sides"] == 2 and check["cells"] > 1000 and _within(check, lag_s, cube.radar["fc_hz"]), check


def test_the_stated_sigma_is_the_spread_over_noise_seeds():
    """Ten noise seeds of the isolated scene, clean: the offsets' standard deviation against the median
    stated sigma within the chi-square interval of ten Gaussian samples at 99.9 % (0.36-1.82), and their
    mean within 3 standard errors of 0."""
    from scipy.stats import chi2

    offsets, sigmas = [], []
    for seed in range(1, 11):
        scn = fw.load_scenario(ROOT / "scenarios" / "isolated_a50.yaml", overrides=[f"noise.seed={seed}"])
        check, _, _ = _check_of(scn, method="decimation", q=25)
        offsets.append(check["doppler_offset_hz"])
        sigmas.append(check["sigma_hz"])
    spread = np.std(offsets, ddof=1)
    lo, hi = np.sqrt(chi2.ppf([0.0005, 0.9995], len(offsets) - 1) / (len(offsets) - 1))
    assert lo <= spread / np.median(sigmas) <= hi, (offsets, sigmas)
    assert abs(np.mean(offsets)) <= 3 * spread / np.sqrt(len(offsets)), offsets


def test_one_side_of_the_flight_axis_says_both_readings():
    """With every counted echo on one side of the flight axis (a scene 300 m off it), scan angles 0.1 deg
    off read as an offset (a review: a false 1.65 ms delay, whose setting moved the targets 0.43 m the
    wrong way): the warning names both readings and both settings, the pointing one as what it is."""
    from fwdlook_cli.forward.echo_navigation import echo_navigation_warnings

    scn = fw.load_scenario(ROOT / "scenarios" / "paper_fig6_a50.yaml", overrides=["scene.center_m=[300,1700]"])
    check, _, cube = _check_of(scn, method="decimation", q=25, scan_offset_deg=0.1)
    assert check["sides"] == 1 and check["pointing_error_deg"] is None
    # b_alt = c0 / g: its sigma is b_alt sigma_c0 / c0, and c0 may read up to the blend bound low
    alt = check["pointing_alternative_deg"]
    allowed = alt * (3 * check["sigma_hz"] + MAX_BLEND_HZ) / check["doppler_offset_hz"]
    assert abs(alt - 0.1) <= allowed, (alt, allowed)
    (line,) = echo_navigation_warnings(check, range_spacing_m=cube.range_spacing_m, angle_step_deg=0.05)
    assert "one side of the flight axis" in line and "processing.scan_angle_offset_deg" in line
    assert "and the pointing is known" in line


@pytest.mark.parametrize("imaging", ["cpi", "dwell"])
def test_without_the_doppler_centroid_the_echoes_are_not_read(tiny_raw, tmp_path, capsys, monkeypatch, imaging):
    """processing.doppler_centroid: false keeps the initial velocity's band for every CPI: the echoes'
    Doppler falls outside it and aliases by whole PRFs (-5 kHz on the paper cube), so the check says it
    read nothing, and warns nothing; under dwell imaging the strong columns' spectra are not formed."""
    from fwdlook_cli.forward import process

    def not_wanted(*args, **kwargs):
        raise AssertionError("spectra formed for a check that reads none")

    monkeypatch.setattr(process, "_strong_column_spectra", not_wanted)
    code, _, err = run_cli(["process", tiny_raw, "-o", tmp_path / "run", "--set", "processing.doppler_centroid=false",
                            "--set", f"processing.imaging={imaging}"], capsys)
    assert code == 0, err
    check = json.loads((tmp_path / "run" / "metrics.json").read_text())["echo_navigation"]
    assert check["doppler_offset_hz"] is None and "doppler_centroid" in check["not_read"]
    assert "echoes' Doppler" not in err


def _suggested_settings(lines):
    """Every ``processing.<key>: <value>`` a warning suggests, as --set overrides."""
    return [f"processing.{k}={v}" for line in lines for k, v in re.findall(r"processing\.(\w+): (-?[0-9.]+)", line)]


@pytest.mark.parametrize("sides,estimate_deg,set_deg", [(2, 0.7, 0.0), (2, 4.0, 8.5), (2, -12.5, 0.0),
                                                        (1, 0.3, 0.0), (1, 3.0, -9.0), (1, 11.0, 0.0)])
def test_every_setting_a_warning_suggests_is_one_the_schema_takes(sides, estimate_deg, set_deg):
    """The warnings name a setting plus the estimate (processing.scan_angle_offset_deg, navigation_delay_s);
    where that total lies outside the setting's range (+-10 deg, +-1 s), a warning that named it had sent
    the user to a value the scenario loader refuses (the fifty-sixth round noticed the one-sided form; the
    two-sided one did the same). Each suggestion here is loaded as an override: none is refused, and a
    pointing estimate beyond the range is still said, with the recorded scan angles to check instead."""
    from fwdlook_cli.forward.echo_navigation import echo_navigation_warnings

    check = {"doppler_offset_hz": 40.0, "sigma_hz": 1.0, "blend_bound_hz": MAX_BLEND_HZ, "delay_s": 0.9,
             "sigma_delay_s": 0.01, "shift_m": 200.0, "velocity_error_mps": 0.3, "accel_los_mps2": 50.0,
             "cells": 300, "cpis": 60, "sides": sides,
             "pointing_alternative_deg": estimate_deg if sides == 1 else None,
             "pointing_error_deg": estimate_deg if sides == 2 else None,
             "sigma_pointing_deg": 0.01 if sides == 2 else None}
    lines = echo_navigation_warnings(check, range_spacing_m=2.5, angle_step_deg=0.05, delay_set_s=0.3,
                                     scan_offset_set_deg=set_deg)
    settings = _suggested_settings(lines)
    total = set_deg + estimate_deg
    scan = [s for s in settings if "scan_angle_offset_deg" in s]
    assert len(scan) == (1 if abs(total) <= 10.0 else 0), lines
    assert not any("navigation_delay_s" in s for s in settings), lines      # 0.3 + 0.9 s: beyond +-1 s
    for setting in settings:
        fw.load_scenario(ROOT / "scenarios" / "tiny.yaml", overrides=[setting])
    if sides == 2:
        (line,) = [x for x in lines if "pointing error" in x]
        assert (f"{total:.4f}" in line) and (("check the recorded scan angles" in line) == (abs(total) > 10.0))
