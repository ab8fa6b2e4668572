"""The forward-looking processing chain (issue 3), stage by stage and end to end.

Every check is a physical or numerical fact: agreement between independent keystone implementations,
a keystone that must leave a steady target alone, the closed-form residual walk of a wrong Doppler
ambiguity number (eq. 19-20), the closed-form residual curvature a keystone leaves under acceleration
(eq. 12), the exact monopulse inverse of two squinted Gaussian beams, the Doppler band of eq. (25), and
the CONTRACT.md outputs of a run.  Scenes are the tiny radar (``fwdlook_cli.testing``) with the
parameters each check needs stated next to it; nothing here touches the 2500-pulse paper cube.

Stage functions are driven through :func:`fwdlook_cli.forward.chain.build_forward_stages`, so the tests use the
same parameters the runner would; only the keystone's implementation / ambiguity number and the
processing settings are varied.  Range peaks are measured with this file's own band-limited
interpolator (zero-padding in range frequency, then a 3-point parabola on log power), not with the
package's helpers.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import h5py
import numpy as np
import pytest

from fwdlook_cli.dsp.antenna import MonopulseAntenna
from fwdlook_cli.forward.chain import build_forward_stages, decimate, range_fft, regroup
from fwdlook_cli.cli import main
from fwdlook_cli.scenario.loader import load_scenario
from fwdlook_cli.dsp.geometry import C_MPS
from fwdlook_cli.forward.simulate import simulate_scenario
from fwdlook_cli.testing import lone_target_scenario, tiny_scenario

ROOT = Path(__file__).resolve().parents[1]
TINY_YAML = ROOT / "scenarios" / "tiny.yaml"
STAGES = ("range_fft", "decimate", "keystone", "regroup", "range_curvature", "doppler_spectra",
          "monopulse_image")


# ----------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------
def err_db(y, ref):
    """Energy of the difference relative to the energy of ``ref``, in dB."""
    y, ref = np.asarray(y, np.complex128), np.asarray(ref, np.complex128)
    return 10 * np.log10(max(float(np.sum(np.abs(y - ref) ** 2)), 1e-300) / float(np.sum(np.abs(ref) ** 2)))


def run_chain(cube, proc, *, until=None, overrides=None):
    """Run the stages ``build_forward_stages`` makes, in memory; ``overrides`` = {stage: {param: value}}.

    Returns ({stage name: output StageData}, geometry dict, {stage name: params used}).
    """
    src, stages, geo = build_forward_stages(cube, proc)
    outs, params, data = {}, {}, src
    for st in stages:
        p = dict(st.params, **(overrides or {}).get(st.name, {}))
        data = st.fn(data, **p)
        outs[st.name], params[st.name] = data, p
        if st.name == until:
            break
    return outs, geo, params


def platform_position_m(scn, t_s):
    """Closed-form antenna position (0,0,h) + v t y + a t^2/2 (paper Fig. 1), independent of the chain."""
    t = np.asarray(t_s, dtype=np.float64)[..., None]
    a = np.asarray(scn["platform"]["accel_mps2"])
    p0 = np.array([0.0, 0.0, scn["platform"]["height_m"]])
    v0 = np.array([0.0, scn["platform"]["speed_mps"], 0.0])
    return p0 + v0 * t + 0.5 * a * t**2


def range_peaks_m(x, range_m, oversample=8):
    """Per-pulse interpolated peak of |x|^2 (x: [pulse, range], range time), in metres.

    Band-limited x8 interpolation (the range spectrum zero-padded), then the vertex of a parabola
    through the log power at the peak sample and its two neighbours: the bias is a few thousandths of
    a range sample, far below the 0.1-sample tolerances used here.
    """
    spec = np.fft.fft(np.asarray(x, np.complex128), axis=1)
    m, n = spec.shape
    big = np.zeros((m, n * oversample), np.complex128)
    h = n // 2
    big[:, : n - h] = spec[:, : n - h]
    big[:, n * oversample - h:] = spec[:, n - h:]
    p = np.abs(np.fft.ifft(big, axis=1)) ** 2
    i = np.clip(np.argmax(p, axis=1), 1, n * oversample - 2)
    rows = np.arange(m)
    lm, l0, lp = (np.log(p[rows, i + k]) for k in (-1, 0, 1))
    delta = 0.5 * (lm - lp) / (lm - 2.0 * l0 + lp)
    dr = range_m[1] - range_m[0]
    return range_m[0] + (i + delta) / oversample * dr


def interior(n):
    """Pulses away from both ends of a keystoned sequence.

    The band-limited (DFT) keystone interpolant is periodic: a sample within a few pulses of either end
    mixes with the other end of a sequence that is not periodic (wrap-around ringing).  The first and
    last 1 % of the pulses are therefore left out of per-pulse range checks.
    """
    k = max(1, n // 100)
    return slice(k, n - k)


def doppler_cycles_per_pulse(scn, target_xyz, t_s, prf_hz):
    """Exact two-way Doppler -2 dR/dt / lambda of a target, in cycles per pulse at ``prf_hz``."""
    t = np.asarray(t_s, dtype=np.float64)
    a = np.asarray(scn["platform"]["accel_mps2"])
    vel = np.array([0.0, scn["platform"]["speed_mps"], 0.0]) + a * t[..., None]
    d = np.asarray(target_xyz) - platform_position_m(scn, t)
    r_dot = -np.sum(d * vel, axis=-1) / np.linalg.norm(d, axis=-1)
    return -2.0 * r_dot * scn["radar"]["fc_hz"] / C_MPS / prf_hz


def run_main(argv, capsys):
    """``fwdlook ARGV`` in-process: (exit code, stdout, stderr)."""
    with pytest.raises(SystemExit) as info:
        main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return info.value.code, out, err


# ----------------------------------------------------------------------------------------------
# keystone implementations agree (issue 3: CZT = DFT to -100 dB, demodulated sinc to -20 dB)
# ----------------------------------------------------------------------------------------------
# The tiny radar (fc 10 GHz, PRF 2 kHz) with the platform unaccelerated and the scene kept within
# +-3.5 deg of boresight: the boresight Doppler f_dc0 = 2 v cos(phi) / lambda = 9994 Hz is 4.997 PRF and
# 39.98 PRF/8, i.e. within 0.03 cycle of an integer at both rates, and every target's Doppler (cos(theta)
# >= 0.998, times (fc + f_r)/fc = 1 +- 0.0012 across the range band) stays within 0.15 cycle of that
# integer at PRF/8 (0.02 at PRF).  So the ambiguity number of eq. (17)/(20) is right for every target and
# range frequency, and the 16-tap sinc (good to |f| <= 0.35 cycle about its reference, keystone.py) works far
# from the Nyquist edge where it cannot interpolate (NOTES.md).  The tiny scene itself (a = 10 m/s^2,
# targets at +-8.7 deg) spreads the Doppler over 39.5-40.5 cycles at PRF/8, up to the band edge, hence the
# override.
KEYSTONE_SCENE = dict(platform={"accel_mps2": [0.0, 0.0, 0.0]},
                      scene={"points_m": [[-60.0, 1000.0], [0.0, 1030.0], [50.0, 990.0]]},
                      noise={"snr_db": None})


@pytest.fixture(scope="module")
def keystone_scene():
    scn = tiny_scenario(**KEYSTONE_SCENE)
    cube, _ = simulate_scenario(scn)
    return scn, cube


@pytest.mark.parametrize("method, q", [("traditional", 1), ("decimation", 8)])
def test_keystone_czt_dft_sinc_agree(keystone_scene, method, q):
    scn, cube = keystone_scene
    prf, fc, fs = scn["radar"]["prf_hz"], scn["radar"]["fc_hz"], scn["radar"]["fs_hz"]
    proc = dict(scn["processing"], method=method, q=q)
    outs = {}
    for impl in ("czt", "dft", "sinc"):
        o, geo, params = run_chain(cube, dict(proc, keystone=impl), until="keystone")
        outs[impl] = o["keystone"]
    ambiguity = params["keystone"]["ambiguity"]
    # premise: the ambiguity number holds for every target over the scan and the range band
    t = cube.slow_time_s
    for x, y in scn["scene"]["points_m"]:
        f = doppler_cycles_per_pulse(scn, [x, y, 0.0], t, prf / q)
        for scale in (1 - fs / 2 / fc, 1 + fs / 2 / fc):
            assert np.all(np.abs(f * scale - ambiguity) < 0.35), (x, y, ambiguity)
    assert abs(geo["f_dc0_hz"] / (prf / q) - ambiguity) < 0.05
    for ch in ("sum_f", "diff_f"):
        assert err_db(outs["czt"][ch], outs["dft"][ch]) < -100.0, ch
        assert err_db(outs["sinc"][ch], outs["czt"][ch]) < -20.0, ch


# ----------------------------------------------------------------------------------------------
# a target with no range walk and no ambiguity is left alone (issue 3: < -60 dB)
# ----------------------------------------------------------------------------------------------
# A stationary platform (speed 0, no acceleration: ambiguity number 0, no range walk) and a beam that
# stays put (scanning 1.00 -> 1.02 deg over 0.2 s): every range-frequency column is constant in slow time
# apart from a 0.02 deg gain drift, and the time scaling of eq. (8) must return it unchanged.  (With the
# tiny scene's 100 deg/s scan the echo is amplitude-modulated by the beam, and a time scaling of that
# envelope is a real change, -40 to -55 dB: not what this checks.)
STEADY_SCENE = dict(platform={"speed_mps": 0.0, "accel_mps2": [0.0, 0.0, 0.0]},
                    antenna={"scan_start_deg": 1.0, "scan_stop_deg": 1.02, "scan_rate_dps": 0.1},
                    noise={"snr_db": None})
SINC_TAPS = 16


@pytest.fixture(scope="module")
def steady_scene():
    scn = tiny_scenario(**STEADY_SCENE)
    cube, _ = simulate_scenario(scn)
    return scn, cube


def _steady(steady_scene, method, q, impl, t_ref):
    scn, cube = steady_scene
    proc = dict(scn["processing"], method=method, q=q, keystone=impl, t_ref=t_ref)
    o, _, params = run_chain(cube, proc, until="keystone")
    assert params["keystone"]["ambiguity"] == 0
    return o["decimate"], o["keystone"]


@pytest.mark.parametrize("t_ref", ["start", "centre"])
@pytest.mark.parametrize("method, q, impl", [("traditional", 1, "czt"), ("decimation", 8, "czt"),
                                             ("decimation", 8, "dft")])
def test_keystone_leaves_steady_target_unchanged(steady_scene, method, q, impl, t_ref):
    before, after = _steady(steady_scene, method, q, impl, t_ref)
    for ch in ("sum_f", "diff_f"):
        assert err_db(after[ch], before[ch]) < -60.0, ch


@pytest.mark.parametrize("t_ref", ["start", "centre"])
@pytest.mark.parametrize("method, q", [("traditional", 1), ("decimation", 8)])
def test_sinc_keystone_leaves_steady_target_unchanged_inside(steady_scene, method, q, t_ref):
    # The sinc kernel reaches n_taps/2 samples either side of a sample position that moves by at most
    # (1 - alpha) |m - t0| < 1 sample: pulses that far from the ends of each sub-sequence see all their taps.
    before, after = _steady(steady_scene, method, q, "sinc", t_ref)
    keep = slice(SINC_TAPS // 2 + 1, before["sum_f"].shape[0] - SINC_TAPS // 2 - 1)
    for ch in ("sum_f", "diff_f"):
        assert err_db(after[ch][keep], before[ch][keep]) < -60.0, ch


def test_sinc_keystone_leaves_steady_target_unchanged_at_the_ends(steady_scene):
    before, after = _steady(steady_scene, "traditional", 1, "sinc", "start")
    assert err_db(after["sum_f"], before["sum_f"]) < -60.0


# ----------------------------------------------------------------------------------------------
# the ambiguity correction: sign and time origin (eq. 15-22, NOTES.md), F = 1
# ----------------------------------------------------------------------------------------------
# One target at boresight, the platform at 150 m/s unaccelerated, PRF 8 kHz: f_d / PRF = 9994 / 8000 =
# 1.25, so F = 1 (the baseband Doppler is +0.25 cycle, well inside the band).  The beam scans only
# -1 -> +1 deg so the target is lit over the whole 0.2 s (1600 pulses); the range walk is 30 m (5 cells).
AMBIGUITY_PRF_HZ = 8000.0
AMBIGUITY_SCENE = dict(radar={"prf_hz": AMBIGUITY_PRF_HZ}, platform={"accel_mps2": [0.0, 0.0, 0.0]},
                       antenna={"scan_start_deg": -1.0, "scan_stop_deg": 1.0, "scan_rate_dps": 10.0})


@pytest.fixture(scope="module")
def ambiguity_scene():
    scn = lone_target_scenario(0.0, 1000.0, **AMBIGUITY_SCENE, processing={"q": 1})
    cube, _ = simulate_scenario(scn)
    return scn, cube


def _walk(scn, cube, t_ref, method, q, ambiguity=None):
    """(per-pulse peak range, t - t_ref, R(t_ref), range sample) after keystone + regroup + IFFT."""
    proc = dict(scn["processing"], method=method, q=q, t_ref=t_ref, range_curvature=False)
    overrides = {"keystone": {"ambiguity": ambiguity}} if ambiguity is not None else None
    o, geo, params = run_chain(cube, proc, until="range_curvature", overrides=overrides)
    t_ref_s = geo["t_ref_s"]
    r_ref = float(np.linalg.norm(np.array([0.0, 1000.0, 0.0]) - platform_position_m(scn, t_ref_s)))
    peaks = range_peaks_m(o["range_curvature"]["sum"], cube.range_m)
    return peaks, cube.slow_time_s - t_ref_s, r_ref, cube.range_spacing_m, params


@pytest.mark.parametrize("t_ref", ["start", "centre"])
def test_right_ambiguity_number_holds_target_at_t_ref_range(ambiguity_scene, t_ref):
    scn, cube = ambiguity_scene
    f = doppler_cycles_per_pulse(scn, [0.0, 1000.0, 0.0], cube.slow_time_s, AMBIGUITY_PRF_HZ)
    assert np.all(np.abs(f - 1.0) < 0.4)                      # premise: F = 1 over the whole dwell
    peaks, _, r_ref, dr, params = _walk(scn, cube, t_ref, "traditional", 1)
    assert params["keystone"]["ambiguity"] == 1               # eq. (17) from the INS speed
    # unkeystoned, the target walks 5 cells; keystoned with the right F it stays at R(t_ref)
    dev = (peaks - r_ref) / dr
    assert np.max(np.abs(dev[interior(len(dev))])) < 0.1


@pytest.mark.parametrize("t_ref", ["start", "centre"])
@pytest.mark.parametrize("wrong_f", [0, 2])
def test_wrong_ambiguity_number_leaves_closed_form_walk(ambiguity_scene, t_ref, wrong_f):
    # One ambiguity number off leaves a Doppler error of -+PRF, i.e. a residual radial velocity of
    # c PRF / (2 fc) (eq. 19): dR/dt = +(F_used - F_true) c PRF / (2 fc), about the keystone origin t_ref.
    scn, cube = ambiguity_scene
    peaks, t, r_ref, dr, _ = _walk(scn, cube, t_ref, "traditional", 1, ambiguity=wrong_f)
    v_res = C_MPS * AMBIGUITY_PRF_HZ / (2.0 * scn["radar"]["fc_hz"])
    k = interior(len(t))
    slope, intercept = np.polyfit(t[k], peaks[k], 1)
    expected = (wrong_f - 1) * v_res
    assert slope == pytest.approx(expected, rel=0.10)
    # the walk is pinned at t_ref (the origin of the correction), where the target is at R(t_ref)
    assert abs(intercept - r_ref) < 0.1 * dr


def test_decimation_keystone_holds_target_at_t_ref_range(ambiguity_scene):
    # Q = 8: PRF/Q = 1 kHz, f_d / (PRF/Q) = 9.99 -> F = 10 for every sub-sequence; the regrouped pulses of
    # all eight sub-sequences sit at R(t_ref).
    scn, cube = ambiguity_scene
    peaks, _, r_ref, dr, params = _walk(scn, cube, "centre", "decimation", 8)
    assert params["keystone"]["ambiguity"] == 10
    dev = (peaks - r_ref) / dr
    assert np.max(np.abs(dev[interior(len(dev))])) < 0.1


def test_decimation_keystone_equals_traditional_with_one_global_origin(ambiguity_scene):
    # With the right ambiguity number at both rates (F = 1 at PRF, F = 10 at PRF/8) both keystones are the
    # same band-limited time scaling of the same signal, so the regrouped decimation output must equal the
    # whole-sequence one.  They differ only by the wrap-around ringing of two differently periodic
    # interpolants, which falls off away from the ends (-62 dB over the middle 80 % of the pulses).  A
    # sub-sequence keystoned about its own time origin (off by q/PRF) leaves a phase error
    # 2 pi F (1 - alpha) q/Q across the range band and disagrees at about -35 dB.
    scn, cube = ambiguity_scene
    out = {}
    for method, q in (("traditional", 1), ("decimation", 8)):
        o, _, params = run_chain(cube, dict(scn["processing"], method=method, q=q, t_ref="centre"),
                                 until="regroup")
        out[method] = o["regroup"]
    n = cube.n_pulses
    mid = slice(n // 10, n - n // 10)
    for ch in ("sum_f", "diff_f"):
        assert err_db(out["decimation"][ch][mid], out["traditional"][ch][mid]) < -50.0, ch


# ----------------------------------------------------------------------------------------------
# decimation and regrouping (Sec. 3.2, Fig. 3)
# ----------------------------------------------------------------------------------------------
def test_decimate_layout_and_regroup_is_identity(keystone_scene):
    scn, cube = keystone_scene
    src, stages, _ = build_forward_stages(cube, dict(scn["processing"], method="decimation", q=8))
    f = range_fft(src, **stages[0].params)
    d = decimate(f, q=8)
    n_p = cube.n_pulses
    for ch in ("sum_f", "diff_f"):
        x, y = f[ch], d[ch]
        assert y.shape == (n_p // 8, 8, x.shape[1])
        for q in (0, 3, 7):                                   # sub-sequence q = pulses q, q+Q, q+2Q, ...
            assert np.array_equal(y[:, q, :], x[q::8, :])
        assert np.array_equal(regroup(d)[ch], x)              # bit-exact inverse
    assert np.array_equal(regroup(d)["slow_time_s"], cube.slow_time_s)


# ----------------------------------------------------------------------------------------------
# range curvature, eq. (12)
# ----------------------------------------------------------------------------------------------
# Lone target at boresight, v = 150 m/s, a_y = 50 m/s^2, a 1 s dwell (beam -1 -> +1 deg).  After an exact
# keystone the range history R_ref - v_r t - a_r t^2/2 becomes R_ref + a_r t^2/2 (the time scaling by
# alpha = fc/(fc + f_r) turns (fc + f_r) a t^2 into fc alpha a t^2, whose f_r part has the opposite sign),
# a_r = a cos(phi): 6.2 m = 1 range cell at t = +-0.5 s, which eq. (12) removes.  The tracking keystone
# runs at PRF 2 kHz (it follows the 3.3 kHz Doppler drift); the traditional one needs one ambiguity
# number over the dwell: at PRF 6 kHz the Doppler goes from 1.67 to 2.22 PRF, F = 2 throughout.
@pytest.mark.parametrize("model", ["eq12", "chain default"])
@pytest.mark.parametrize("method, prf_hz", [("tracking", 2000.0), ("traditional", 6000.0)])
def test_range_curvature_residual_and_its_compensation(method, prf_hz, model):
    a_y = 50.0
    scn = lone_target_scenario(0.0, 1000.0, radar={"prf_hz": prf_hz},
                               platform={"speed_mps": 150.0, "accel_mps2": [0.0, a_y, 0.0]},
                               antenna={"scan_start_deg": -1.0, "scan_stop_deg": 1.0, "scan_rate_dps": 2.0},
                               processing={"method": method, "q": 1, "t_ref": "centre"})
    cube, _ = simulate_scenario(scn)
    proc = dict(scn["processing"])
    if model == "eq12" and "curvature_model" in proc:        # the paper's eq. (12), whatever the default
        proc["curvature_model"] = "eq12"
    target = np.array([0.0, 1000.0, 0.0])
    if method == "traditional":
        f = doppler_cycles_per_pulse(scn, target, cube.slow_time_s, prf_hz)
        assert np.all(np.abs(f - 2.0) < 0.4)                  # premise: F = 2 holds over the dwell
    dr = cube.range_spacing_m
    result = {}
    for curvature in (False, True):
        o, geo, _ = run_chain(cube, dict(proc, range_curvature=curvature), until="range_curvature")
        p_ref = platform_position_m(scn, geo["t_ref_s"])
        r_ref = float(np.linalg.norm(target - p_ref))
        t = cube.slow_time_s - geo["t_ref_s"]
        result[curvature] = (range_peaks_m(o["range_curvature"]["sum"], cube.range_m) - r_ref, t)
    k = interior(cube.n_pulses)
    # without eq. (12): the quadratic a cos(phi) t^2 / 2, phi the depression at t_ref.  The eq. (12) model
    # neglects the geometric curvature v^2 sin^2(phi)/R (0.07 m/s^2 here, 0.15 %) and O(f_r/fc) terms.
    dev, t = result[False]
    phi = math.asin(p_ref[2] / r_ref)
    c2 = np.polyfit(t[k], dev[k], 2)[0]
    assert c2 == pytest.approx(a_y * math.cos(phi) / 2.0, rel=0.05)
    assert np.max(np.abs(dev[k])) > 0.5 * dr                  # a visible walk, half a cell or more
    # with eq. (12): flat
    dev, _ = result[True]
    assert np.max(np.abs(dev[k])) < 0.1 * dr


# ----------------------------------------------------------------------------------------------
# monopulse angle per CPI (NOTES.md: Re(diff/sum) = tanh(k delta) exactly)
# ----------------------------------------------------------------------------------------------
# The beam moves scan_rate * cpi / PRF within one CPI and the estimate is the gain-weighted mean offset
# over the CPI: at the tiny scene's 100 deg/s that is 0.8 deg and biases the estimate by up to 0.017 deg at
# 2 deg off the beam; at 25 deg/s (0.2 deg per CPI) the bias is below 0.002 deg.  The tracking keystone
# keeps the target's Doppler history intact for any azimuth (a fixed decimation ambiguity number does not
# for targets away from boresight, whose Doppler crosses the PRF/Q band edge).
@pytest.mark.parametrize("method, x_m, y_m", [("tracking", 0.0, 1000.0), ("tracking", 120.0, 990.0),
                                              ("tracking", -150.0, 1000.0), ("decimation", 0.0, 1000.0)])
def test_monopulse_angle_per_cpi(method, x_m, y_m):
    scn = lone_target_scenario(x_m, y_m, antenna={"scan_rate_dps": 25.0},
                               processing={"method": method, "q": 8 if method == "decimation" else 1})
    cube, _ = simulate_scenario(scn)
    o, _, _ = run_chain(cube, scn["processing"], until="doppler_spectra")
    spec = o["doppler_spectra"]
    ant = scn["antenna"]
    k = MonopulseAntenna(ant["beamwidth_3db_deg"], ant["squint_deg"]).slope_per_deg
    t_c = spec["cpi_time_s"]
    beam = spec["cpi_beam_deg"]
    pos = platform_position_m(scn, t_c)
    az_true = np.degrees(np.arctan2(x_m - pos[:, 0], y_m - pos[:, 1]))
    near = np.nonzero(np.abs(az_true - beam) <= 2.0)[0]
    assert len(near) >= 10
    errors = []
    for i in near:
        p = np.abs(spec["sum_z"][i]) ** 2
        j, r = np.unravel_index(np.argmax(p), p.shape)
        ratio = np.real(spec["diff_z"][i, j, r] / spec["sum_z"][i, j, r])
        errors.append(np.arctanh(ratio) / k + beam[i] - az_true[i])
    assert np.max(np.abs(errors)) < 0.01, np.round(errors, 4)


# ----------------------------------------------------------------------------------------------
# Doppler centroid per CPI, eq. (25): what is lost without it
# ----------------------------------------------------------------------------------------------
def dirichlet_peak_sidelobe(n):
    """Highest sidelobe of the rectangular-window DFT response |sin(n pi f)/(n sin(pi f))| (power ratio)."""
    f = np.linspace(1.0 / n, 0.5, 20001)
    resp = np.abs(np.sin(n * np.pi * f) / (n * np.sin(np.pi * f)))
    return float(resp.max() ** 2)


def test_doppler_centroid_following_speed_keeps_energy():
    # a = 50 m/s^2; a target at about 10.3 deg azimuth lit by the beam from t = 0.18 to 0.23 s (scan -10 ->
    # +15 deg at 100 deg/s), when v has grown by 9-11 m/s: its Doppler is 2 a t cos(theta) cos(phi) / lambda
    # = 540-840 Hz above the centre of the band eq. (25)-(26) would use with the initial speed, 290-600 Hz
    # beyond its edge.  Rectangular CPI window, so the response outside its main lobe (+-PRF/cpi = 125 Hz)
    # is at most the Dirichlet kernel's first sidelobe (-13.1 dB for 16 pulses).
    cpi = 16
    scn = lone_target_scenario(176.0, 1000.0, platform={"accel_mps2": [0.0, 50.0, 0.0]},
                               antenna={"scan_stop_deg": 15.0},
                               processing={"method": "tracking", "q": 1, "cpi": cpi, "doppler_window": "none"})
    cube, _ = simulate_scenario(scn)
    prf = scn["radar"]["prf_hz"]
    res = {}
    for follow in (True, False):
        o, _, _ = run_chain(cube, dict(scn["processing"], doppler_centroid=follow))
        res[follow] = o
    spec = res[False]["doppler_spectra"]
    t_c = spec["cpi_time_s"]
    pos = platform_position_m(scn, t_c)
    az = np.degrees(np.arctan2(176.0 - pos[:, 0], 1000.0 - pos[:, 1]))
    lit = np.abs(az - spec["cpi_beam_deg"]) <= scn["antenna"]["beamwidth_3db_deg"] / 2
    assert lit.sum() >= 4
    # premise: without eq. (25) the target's main lobe lies wholly above the band in every lit CPI
    f_true = doppler_cycles_per_pulse(scn, [176.0, 1000.0, 0.0], t_c, 1.0)
    band_top = spec["doppler_hz"].max(axis=1)
    assert np.all(f_true[lit] - band_top[lit] > prf / cpi)
    psl = dirichlet_peak_sidelobe(cpi)                        # -13.1 dB
    # stage 6: the CPI spectra of the lit CPIs keep at most the sidelobe level
    z_true = np.abs(res[True]["doppler_spectra"]["sum_z"]) ** 2
    z_false = np.abs(spec["sum_z"]) ** 2
    assert np.all(z_false[lit].max(axis=(1, 2)) <= psl * z_true[lit].max(axis=(1, 2)))
    # the image: peak and total projected power lose more than the sidelobe level
    img_t, img_f = res[True]["monopulse_image"]["image"], res[False]["monopulse_image"]["image"]
    assert img_f.max() < psl * img_t.max()
    assert img_f.sum() < psl * img_t.sum()
    # and eq. (25) puts the target where it is
    spec_t = res[True]["doppler_spectra"]
    assert np.all((f_true[lit] > spec_t["doppler_hz"].min(axis=1)[lit])
                  & (f_true[lit] < spec_t["doppler_hz"].max(axis=1)[lit]))


# ----------------------------------------------------------------------------------------------
# end to end: fwdlook run scenarios/tiny.yaml (CONTRACT.md sections 4-5)
# ----------------------------------------------------------------------------------------------
CONTRACT_TOP = {"fwdlook_version", "scenario", "method", "params", "t_ref_s", "targets", "summary", "timing_s"}
CONTRACT_PARAMS = {"q", "keystone", "range_curvature"}
CONTRACT_TARGET = {"id", "x_m", "y_m", "true_range_m", "true_azimuth_deg", "meas_range_m", "meas_azimuth_deg",
                   "range_error_m", "azimuth_error_deg", "islr_db", "pslr_db"}
CONTRACT_SUMMARY = {"n_targets", "detected", "max_abs_range_error_m", "rms_range_error_m",
                    "max_abs_azimuth_error_deg", "median_islr_db"}
RUNS = [(m, t) for m in ("tracking", "decimation") for t in ("centre", "start")]


@pytest.fixture(scope="module")
def tiny_runs(tmp_path_factory):
    base = tmp_path_factory.mktemp("tiny_runs")
    out = {}
    for method, t_ref in RUNS:
        run_dir = base / f"{method}_{t_ref}"
        with pytest.raises(SystemExit) as info:
            main(["run", str(TINY_YAML), "-o", str(run_dir), "-q", "--set", f"processing.method={method}",
                  "--set", f"processing.t_ref={t_ref}"])
        assert info.value.code == 0
        out[method, t_ref] = run_dir
    return out


def _tiny_yaml():
    """The resolved tiny scenario (YAML 1.1 reads '24.0e6' as a string: resolve, don't safe_load)."""
    return load_scenario(TINY_YAML)


@pytest.mark.parametrize("method, t_ref", RUNS)
def test_run_tiny_metrics_contract_and_accuracy(tiny_runs, method, t_ref):
    run_dir = tiny_runs[method, t_ref]
    m = json.loads((run_dir / "metrics.json").read_text())
    assert CONTRACT_TOP <= set(m)
    assert CONTRACT_PARAMS <= set(m["params"])
    assert CONTRACT_SUMMARY <= set(m["summary"])
    assert m["method"] == method and m["scenario"] == "tiny"
    raw = _tiny_yaml()
    n = len(raw["scene"]["points_m"])
    assert len(m["targets"]) == n and m["summary"]["n_targets"] == n
    assert m["summary"]["detected"] == n
    half_cell = C_MPS / (2.0 * raw["radar"]["fs_hz"]) / 2.0            # 3.12 m
    tenth_beam = raw["antenna"]["beamwidth_3db_deg"] / 10.0             # 0.6 deg
    for row in m["targets"]:
        assert CONTRACT_TARGET <= set(row)
        assert abs(row["range_error_m"]) < half_cell, row
        assert abs(row["azimuth_error_deg"]) < tenth_beam, row
        assert row["range_error_m"] == pytest.approx(row["meas_range_m"] - row["true_range_m"], abs=1e-9)
        assert row["azimuth_error_deg"] == pytest.approx(row["meas_azimuth_deg"] - row["true_azimuth_deg"],
                                                         abs=1e-9)
    assert m["summary"]["max_abs_range_error_m"] == pytest.approx(
        max(abs(r["range_error_m"]) for r in m["targets"]), abs=1e-9)
    # one timing per stage, and the total (which bounds every part)
    assert set(STAGES) | {"total"} <= set(m["timing_s"])
    assert all(v >= 0 for v in m["timing_s"].values())
    assert m["timing_s"]["total"] >= sum(m["timing_s"][s] for s in STAGES)




@pytest.mark.parametrize("method, t_ref", RUNS)
def test_run_tiny_peak_loss_is_bounded(tiny_runs, method, t_ref):
    # Peak loss (issue 3): the target's best zoomed-Doppler sample against an ideally focused one.  It
    # cannot exceed the ideal by more than the noise (30 dB SNR: +0.3 dB), and on this well-focused scene
    # it loses at most the range straddle of a sample half a cell off the peak, |sinc(B / (2 fs))|^2 =
    # -2.6 dB, plus that noise (Doppler scalloping on 64 zoom cells over a >= 4-cell band is < 0.1 dB).
    m = json.loads((tiny_runs[method, t_ref] / "metrics.json").read_text())
    raw = _tiny_yaml()
    straddle_db = 20 * math.log10(np.sinc(raw["radar"]["bandwidth_hz"] / (2 * raw["radar"]["fs_hz"])))
    for row in m["targets"]:
        assert straddle_db - 0.4 < row["peak_loss_db"] < 0.4, row


@pytest.mark.parametrize("method, t_ref", RUNS[:1])
def test_run_tiny_image_files(tiny_runs, method, t_ref):
    run_dir = tiny_runs[method, t_ref]
    png = (run_dir / "image.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 1000
    assert (run_dir / "scenario.yaml").is_file()
    with h5py.File(run_dir / "image.h5", "r") as f:
        assert f["range_m"].attrs["units"] == "m" and f["angle_deg"].attrs["units"] == "deg"
        assert h5py.h5ds.is_scale(f["range_m"].id) and h5py.h5ds.is_scale(f["angle_deg"].id)
        img = f["image"]
        assert "units" in img.attrs and "long_name" in img.attrs
        assert img.shape == (f["range_m"].shape[0], f["angle_deg"].shape[0])
        assert img.dims[0][0].name == "/range_m" and img.dims[1][0].name == "/angle_deg"
        assert np.all(np.diff(f["range_m"][()]) > 0) and np.all(np.diff(f["angle_deg"][()]) > 0)
        assert float(f.attrs["t_ref_s"]) == pytest.approx(
            json.loads((run_dir / "metrics.json").read_text())["t_ref_s"], abs=1e-12)


@pytest.mark.parametrize("method, t_ref", RUNS)
def test_t_ref_and_truth_at_t_ref(tiny_runs, method, t_ref):
    run_dir = tiny_runs[method, t_ref]
    m = json.loads((run_dir / "metrics.json").read_text())
    raw = _tiny_yaml()
    prf = raw["radar"]["prf_hz"]
    n_pulses = round((raw["antenna"]["scan_stop_deg"] - raw["antenna"]["scan_start_deg"])
                     / raw["antenna"]["scan_rate_dps"] * prf)          # scan duration x PRF = 400
    t_first, t_last = 0.0, (n_pulses - 1) / prf                       # t = 0 at the first pulse (eq. 1)
    with h5py.File(run_dir / "raw.h5", "r") as f:
        assert f["axes/slow_time_s"][0] == t_first and f["axes/slow_time_s"][-1] == pytest.approx(t_last)
    expected = t_first if t_ref == "start" else 0.5 * (t_first + t_last)
    assert m["t_ref_s"] == pytest.approx(expected, abs=1e-12)
    # the scan centre (beam at (start + stop)/2) is within half a pulse of the centre of the recorded pulses
    if t_ref == "centre":
        t_beam_centre = (raw["antenna"]["scan_stop_deg"] - raw["antenna"]["scan_start_deg"]) / 2 \
            / raw["antenna"]["scan_rate_dps"]
        assert abs(m["t_ref_s"] - t_beam_centre) <= 0.5 / prf + 1e-12
    scn = tiny_scenario()
    p_ref = platform_position_m(scn, m["t_ref_s"])
    for row in m["targets"]:
        d = np.array([row["x_m"], row["y_m"], 0.0]) - p_ref
        assert row["true_range_m"] == pytest.approx(float(np.linalg.norm(d)), abs=1e-5)
        assert row["true_azimuth_deg"] == pytest.approx(math.degrees(math.atan2(d[0], d[1])), abs=1e-6)


# ----------------------------------------------------------------------------------------------
# bad input through main: exit 2, one line naming the file and key, nothing that looks complete
# ----------------------------------------------------------------------------------------------
def _nan_cube(src, dst):
    dst.write_bytes(src.read_bytes())
    with h5py.File(dst, "r+") as f:
        a = f["echo/sum"][()]
        a[7, 11] = np.nan
        f["echo/sum"][...] = a
    return dst


def _no_diff_cube(src, dst):
    dst.write_bytes(src.read_bytes())
    with h5py.File(dst, "r+") as f:
        del f["echo/diff"]
    return dst


def assert_bad_input(code, out, err, names):
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, lines
    assert lines[0].startswith("fwdlook: error:") and "Traceback" not in err
    for name in names:
        assert str(name) in lines[0], (name, lines[0])


def assert_no_outputs(run_dir):
    for name in ("metrics.json", "image.h5", "image.png"):
        assert not (run_dir / name).exists(), name
    if run_dir.exists():
        assert not list(run_dir.rglob("*.partial"))
        assert not list(run_dir.glob("stages/*.h5"))


@pytest.mark.parametrize("case", ["nan", "no_diff"])
@pytest.mark.parametrize("command", ["process", "run"])
def test_bad_cube_exits_2(tiny_raw, tmp_path, capsys, case, command):
    bad = tmp_path / f"{case}.h5"
    key = "/echo/sum" if case == "nan" else "/echo/diff"
    (_nan_cube if case == "nan" else _no_diff_cube)(tiny_raw, bad)
    run_dir = tmp_path / "run"
    argv = [command, bad, "-o", run_dir] if command == "process" else [command, TINY_YAML, "--raw", bad, "-o", run_dir]
    code, out, err = run_main(argv, capsys)
    assert_bad_input(code, out, err, [bad, key])
    assert_no_outputs(run_dir)


def test_q_not_dividing_pulse_count_exits_2(tiny_raw, tmp_path, capsys):
    run_dir = tmp_path / "run"
    code, out, err = run_main(["process", tiny_raw, "-o", run_dir, "--set", "processing.q=3"], capsys)
    assert_bad_input(code, out, err, [tiny_raw, "processing.q", "3"])
    assert_no_outputs(run_dir)


def test_q_is_checked_against_the_cubes_pulse_count(tiny_raw, tmp_path, capsys):
    code, out, err = run_main(["process", tiny_raw, "-o", tmp_path / "bad", "--set", "processing.q=3"], capsys)
    assert code == 2 and "400" in err, err                   # the cube's pulse count is named
    # q = 16 divides the cube's 400 pulses: a valid setting for this cube
    code, out, err = run_main(["process", tiny_raw, "-o", tmp_path / "ok", "-q", "--set", "processing.q=16"], capsys)
    assert code == 0, err


@pytest.mark.parametrize("command", ["run", "process"])
def test_unknown_method_exits_2(tmp_path, capsys, command):
    run_dir = tmp_path / "run"
    code, out, err = run_main([command, TINY_YAML, "-o", run_dir, "--set", "processing.method=magic"], capsys)
    assert_bad_input(code, out, err, [TINY_YAML, "processing.method", "magic", "decimation"])
    assert_no_outputs(run_dir)


def test_cube_without_truth_processes(tiny_raw, tmp_path, capsys):
    """CONTRACT.md 3: a recorded cube has no /truth; it is imaged, with no per-target metrics."""
    import shutil

    import h5py

    raw = tmp_path / "recorded.h5"
    shutil.copy(tiny_raw, raw)
    with h5py.File(raw, "a") as f:
        del f["truth"]
    code, out, err = run_main(["process", str(raw), "-o", str(tmp_path / "run"), "-q"], capsys)
    assert code == 0, err
    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert m["targets"] == [] and m["summary"]["n_targets"] == 0
    with h5py.File(tmp_path / "run" / "image.h5", "r") as f:
        assert f["image"][()].max() > 0


def test_steep_depression_cpi_band_covers_the_range_window(tmp_path):
    """At 1000 m of height the boresight Doppler changes by 11.6 Hz per metre of range: the CPI Doppler
    band computed at the window's middle depression (eq. 25, phi ~ phi_0) left out points 30 m and more
    from the middle range (each alone, in a window centred on it, was found; two points 100 m apart
    in range: neither, 0.15 and 0.40 deg off). The band now covers the window's depressions where they
    differ by more than a Doppler cell; the paper's windows (15 Hz across, a cell is 78 Hz) keep phi_0."""
    import json
    import sys

    from fwdlook_cli.cli import main
    from fwdlook_cli.forward.motion import doppler_band_depressions

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import independent_writer as writer

    assert doppler_band_depressions(50.0, 1000.0, 1400.0, 2.4, [0.0, 240.0, 0.0], 18e9, 2500.0, 32) == 2.4
    wide = doppler_band_depressions(1000.0, 1277.0, 1801.0, 40.0, [0.0, 240.0, 0.0], 18e9, 2500.0, 32)
    assert wide == pytest.approx([33.7, 51.6], abs=0.1)
    raw = tmp_path / "steep_pair.h5"
    writer.write_cube(raw, "paper", [[-80.0, 1250.0], [70.0, 1150.0]], height_m=1000.0, snr_db=20.0, n_pulses=675)
    for preset in ("decimation", "tracking"):
        run_dir = tmp_path / preset
        with pytest.raises(SystemExit) as exc:
            main(["process", str(raw), "-o", str(run_dir), "-q", "-c", str(ROOT / "configs" / f"{preset}.yaml"),
                  "--set", "processing.imaging=cpi",
                  "--set", f"processing.monopulse_calibration={writer.true_slope_per_deg(6.0)}"])
        assert exc.value.code == 0
        m = json.loads((run_dir / "metrics.json").read_text())
        assert m["summary"]["detected"] == 2, m["targets"]
        assert max(abs(t["azimuth_error_deg"]) for t in m["targets"]) < 0.06
        assert max(abs(t["range_error_m"]) for t in m["targets"]) < 0.15 * 3.0
