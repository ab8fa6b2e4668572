"""The dwell image's focus directions (``forward/dwell_grid.py``): finer than the image's angle bins where the
dwell resolves finer, and each sub-aperture's window of them taken from its own antenna position."""
from pathlib import Path

import numpy as np

from fwdlook_cli.forward import dwell_grid as G
from fwdlook_cli.forward.dwell import dwell_focus
from fwdlook_cli.forward.dwell_range import ground_points
from fwdlook_cli.forward.process import process_cube
from fwdlook_cli.forward.simulate import simulate_scenario
from fwdlook_cli.scenario.overlay import resolve_with_config
from fwdlook_cli.testing import w_band_raw

ROOT = Path(__file__).resolve().parent.parent
C = 299_792_458.0


def test_the_lobe_width_of_a_gaussian_dwell_is_its_closed_form():
    """With no squint slope (k = 0) the weight is the Gaussian exp(-2 beta d^2), so w^2 over time is
    exp(-a t^2) with a = 4 beta rate^2, whose transform's power exp(-2 pi^2 f^2 / a) falls to ``level`` at
    f = sqrt(a ln(1 / level) / (2 pi^2)); the window (+-40 beamwidths) truncates nothing."""
    beta, rate = 0.049, 30.0
    a = 4.0 * beta * rate**2
    for level in (0.5, 0.25):
        f = G.lobe_half_width_hz(beta, 0.0, 40.0, rate, level=level)
        np.testing.assert_allclose(f, np.sqrt(a * np.log(1.0 / level) / (2.0 * np.pi**2)), rtol=1e-4)


def test_focus_directions_sample_the_lobe_and_keep_the_image_bins():
    """Per bin, m = ceil(step / width) with width = 2 f lambda / (2 v |sin theta|) (deg); the directions of
    bin i are its own and m - 1 more evenly spaced towards the next, weighted 1/m."""
    angle = np.round(np.arange(-20.0, 20.0001, 0.05), 10)
    m = G.focus_oversample_per_bin(angle, axis_deg=0.0, speed_mps=250.0, lobe_hz=3.7, fc_hz=94e9)
    lam = C / 94e9
    width = np.degrees(2 * 3.7 * lam / (2 * 250.0 * np.abs(np.sin(np.radians(angle))) + 1e-300))
    np.testing.assert_array_equal(m, np.clip(np.ceil(0.05 / width - 1e-9), 1, G.MAX_FOCUS_OVERSAMPLE))
    assert m[np.argmin(np.abs(angle))] == 1 and m.max() > 4
    dirs, bins, first, weight = G.focus_directions(angle, m)
    np.testing.assert_array_equal(dirs[first], angle)                    # every bin's own direction kept
    assert np.all(np.diff(dirs) > 0) and len(dirs) == m.sum()
    np.testing.assert_allclose(np.bincount(bins, weights=weight), 1.0)    # 1/m per bin: the image's scale
    np.testing.assert_allclose(np.diff(dirs)[bins[:-1] == bins[1:]], (0.05 / m[bins])[:-1][bins[:-1] == bins[1:]])


def test_each_subaperture_window_is_taken_from_its_own_antenna():
    """The matched-filter gain of a direction (no twin null) is sum_j w(delta_j)^2 over every sub-aperture
    whose offset delta_j of the direction from its beam, seen from its own antenna, lies in the dwell
    window: computed here independently by plain geometry.  The paper's flight (a = 50, scan -15..15 deg
    at 30 deg/s) puts the antenna up to 139 m from p_ref; taking the window in the t_ref frame lost up to
    8 % of the gain 5-15 deg off the axis (one side of the dwell cut off by the parallax)."""
    prf, n_p, v0, acc, h = 2500.0, 2500, 240.0, 50.0, 50.0
    t = np.arange(n_p) / prf
    pos = np.stack([np.zeros(n_p), v0 * t + 0.5 * acc * t**2, np.full(n_p, h)], axis=-1)
    vel = np.stack([np.zeros(n_p), v0 + acc * t, np.zeros(n_p)], axis=-1)
    scan = -15.0 + 30.0 * t
    p_ref = pos[n_p // 2]
    range_m = np.linspace(1590.0, 1610.0, 8)
    angle = np.round(np.arange(-21.0, 21.0001, 0.05), 10)
    beta, k, half, L = 0.04897, 0.1469, 3.19, 40
    zeros = np.zeros((n_p, len(range_m)), np.complex64)
    _, _, gain, _, _ = dwell_focus(zeros, zeros, slow_time_s=t, scan_angle_deg=scan, position_m=pos, velocity_mps=vel,
                                   range_m=range_m, angle_deg=angle, fc_hz=18e9, prf_hz=prf, slope_per_deg=k,
                                   beta_per_deg2=beta, position_ref_m=p_ref, sub_pulses=L, dwell_half_width_deg=half,
                                   twin_null=False)
    # independent: every (sub-aperture, direction), the direction's offset from the antenna at its centre
    n_sub = n_p // L
    centre = (np.arange(n_sub) + 0.5) * L - 0.5
    pc = np.stack([np.interp(centre, np.arange(n_p), pos[:, i]) for i in range(3)], axis=-1)
    beam = scan[: n_sub * L].reshape(n_sub, L).mean(axis=1)
    P = ground_points(0.5 * (range_m[0] + range_m[-1]), angle, p_ref)
    delta = np.degrees(np.arctan2(P[None, :, 0] - pc[:, None, 0], P[None, :, 1] - pc[:, None, 1])) - beam[:, None]
    w = np.exp(-2 * beta * delta**2) * np.cosh(k * delta) * (np.abs(delta) <= half)
    expect = np.sum(w**2, axis=0)
    seen = expect > 0.5 * expect.max()
    np.testing.assert_allclose(gain[seen], expect[seen], rtol=1e-9)


def test_points_between_the_image_directions_at_w_band_are_focused(tmp_path):
    """94 GHz, a = 20, six equal points 10 deg off the flight axis, 0 to 0.021 deg from an image direction
    (0.05 deg bins).  There the dwell's angle lobe is 0.011 deg wide at half power: focused only on the
    image's directions, the points between them were seen in their sidelobes, 17-33 dB down and 0.46-1.13
    m off in range (one not detected at this SNR).  Every point now within 0.1 m (3 % of the 3 m
    resolution; 0.031 m measured) and its bin (0.03 deg), the six peaks within 3 dB (0.14 dB measured)."""
    y_ref = 240.0 * 0.5 + 0.5 * 20.0 * 0.25
    azimuths = [10.0, 10.0042, 10.0083, 10.0125, 10.0167, 10.0208]
    pts = [[g * np.sin(np.radians(a)), y_ref + g * np.cos(np.radians(a))]
           for g, a in zip(1500.0 + 45.0 * np.arange(6), azimuths)]
    raw = w_band_raw("w-band-between", pts, snr_db=40.0, seed=3, processing={"dwell_fit": "none"})
    scn = resolve_with_config(raw, "w-band-between", str(ROOT / "configs" / "tracking.yaml"), [])
    cube, _ = simulate_scenario(scn)
    m = process_cube(cube, scn, tmp_path, quiet=True, png=False)
    rows = m["targets"]
    assert all(r["detected"] for r in rows)
    assert max(abs(r["range_error_m"]) for r in rows) < 0.1
    assert max(abs(r["azimuth_error_deg"]) for r in rows) < 0.03
    peaks = [r["peak_power"] for r in rows]
    assert max(peaks) / min(peaks) < 2.0


def test_the_directions_focused_are_held_to_the_size_limit_before_the_chain(tmp_path, monkeypatch):
    """The focus's arrays are per focused direction, up to 16 times the image's bins (here, 94 GHz, about
    2,400 directions for 841 bins, on the x 4 range grid the dwell takes).  A size limit that the image
    grid passes (841 x 960 cells at 32 bytes: 24.6 MiB) but the focused directions do not is one clear
    error naming them, before any stage runs (limits.check_processing_sizes)."""
    import re

    import pytest

    from fwdlook_cli.errors import BadInput

    raw = w_band_raw("w-band-size", [[100.0, 1720.0]], snr_db=40.0, seed=1, processing={"dwell_fit": "none"})
    scn = resolve_with_config(raw, "w-band-size", str(ROOT / "configs" / "tracking.yaml"), [])
    cube, _ = simulate_scenario(scn)
    monkeypatch.setenv("FWDLOOK_MAX_CUBE_BYTES", str(40 * 2**20))
    with pytest.raises(BadInput, match=r"the dwell focused in [\d,]+ directions .* x 960 ranges .* allowed: a "
                                       r"coarser range oversampling") as err:
        process_cube(cube, scn, tmp_path / "run", quiet=True, png=False)
    n_focus = int(re.search(r"focused in ([\d,]+) directions", str(err.value)).group(1).replace(",", ""))
    assert 2 * 841 < n_focus <= 16 * 841
    assert not (tmp_path / "run" / "stages").exists()
    monkeypatch.setenv("FWDLOOK_MAX_CUBE_BYTES", str(128 * 2**20))
    assert process_cube(cube, scn, tmp_path / "run", quiet=True, png=False)["targets"][0]["detected"]


def test_the_cap_on_focus_directions_is_said_with_a_step_that_samples_the_lobe(caplog):
    """Beyond MAX_FOCUS_OVERSAMPLE directions per bin the lobe is not sampled: the log says where (degrees
    off the flight axis, not signed angles) and an angle step, rounded down, under which it would be;
    that step then needs no more than the cap, and no warning."""
    import logging
    import re

    lobe = dict(axis_deg=0.0, speed_mps=300.0, lobe_hz=2.6, fc_hz=94e9)
    with caplog.at_level(logging.WARNING, logger="fwdlook_cli.forward.dwell_grid"):
        m = G.focus_oversample_per_bin(np.round(np.arange(-40.0, 40.0001, 0.05), 10), **lobe)
    assert m.max() == G.MAX_FOCUS_OVERSAMPLE
    text = caplog.text
    off = re.search(r"([\d.]+) to ([\d.]+) deg off the flight axis", text)
    assert off and 0.0 < float(off.group(1)) < float(off.group(2)) == 40.0
    step = float(re.search(r"angle_step_deg <= ([\d.]+)", text).group(1))
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="fwdlook_cli.forward.dwell_grid"):
        m = G.focus_oversample_per_bin(np.round(np.arange(-40.0, 40.0001, step), 10), **lobe)
    assert m.max() <= G.MAX_FOCUS_OVERSAMPLE and "dwell image" not in caplog.text
