"""The simulator against physics: peak at the exact slant range, carrier phase, monopulse ratio,
noise power, and that gating skips only negligible energy."""
import numpy as np
import pytest

from fwdlook_cli.dsp.antenna import MonopulseAntenna
from fwdlook_cli.dsp.geometry import C_MPS, azimuth_deg, slant_range_m
from fwdlook_cli.scenario.forward import scene_geometry
from fwdlook_cli.dsp.profile import profile_metrics
from fwdlook_cli.dsp.pulse import CompressedPulse
from fwdlook_cli.dsp.pulse import noise_sigma_for
from fwdlook_cli.forward.simulate import simulate_echo, simulate_scenario
from fwdlook_cli.testing import lone_target_scenario, tiny_scenario


@pytest.fixture(scope="module")
def lone():
    scn = lone_target_scenario(x_m=80.0, y_m=1000.0)
    cube, _ = simulate_scenario(scn)
    r_true = slant_range_m(cube.position_m, cube.truth_xyz_m())[0]
    return scn, cube, r_true


def test_per_pulse_peak_at_true_slant_range(lone):
    _, cube, r_true = lone
    dr = cube.range_spacing_m
    power = np.abs(cube.sum) ** 2
    strong = np.nonzero(power.max(axis=1) > 0.25 * power.max())[0]
    for n in strong[:: max(1, len(strong) // 12)]:
        m = profile_metrics(cube.sum[n], spacing=dr)
        assert abs(cube.range_m[0] + m.peak_pos - r_true[n]) < 0.1 * dr, n


def test_phase_history_is_minus_4pi_fc_r_over_c(lone):
    _, cube, r_true = lone
    fc = cube.radar["fc_hz"]
    power = np.abs(cube.sum) ** 2
    pulses = np.nonzero(power.max(axis=1) > 1e-3 * power.max())[0]
    nearest = np.rint((r_true[pulses] - cube.range_m[0]) / cube.range_spacing_m).astype(int)
    measured = np.angle(cube.sum[pulses, nearest])
    expected = -4 * np.pi * fc * r_true[pulses] / C_MPS
    # the compressed chirp is real and positive on its main lobe, so the phase is the carrier's
    residual = np.unwrap(measured - np.mod(expected, 2 * np.pi))
    assert np.max(np.abs(residual)) < 2e-3


def test_diff_over_sum_changes_sign_at_beam_centre_with_documented_slope(lone):
    _, cube, r_true = lone
    ant = MonopulseAntenna(cube.radar["beamwidth_3db_deg"], cube.antenna["squint_deg"])
    assert cube.antenna["monopulse_slope_per_deg"] == pytest.approx(ant.slope_per_deg)
    offset = azimuth_deg(cube.position_m, cube.truth_xyz_m())[0] - cube.scan_angle_deg
    near = np.nonzero(np.abs(offset) < 4.0)[0]
    idx = np.rint((r_true[near] - cube.range_m[0]) / cube.range_spacing_m).astype(int)
    ratio = (cube.diff[near, idx] / cube.sum[near, idx]).real
    np.testing.assert_allclose(ratio, np.tanh(ant.slope_per_deg * offset[near]), atol=2e-5)
    # sign change exactly where the beam crosses the target (scan increases with time)
    crossing = np.nonzero(np.diff(np.sign(ratio)) != 0)[0]
    assert len(crossing) == 1
    assert offset[near][crossing[0]] >= 0 >= offset[near][crossing[0] + 1]


def test_noise_power_matches_snr_definition():
    sigma = noise_sigma_for(20.0, [1.0, 0.5])
    assert sigma == pytest.approx(0.1)
    n_p, n_r = 400, 300
    t = np.arange(n_p) / 1000.0
    pos = np.zeros((n_p, 3))
    echo_sum, echo_diff, stats = simulate_echo(
        t, pos, np.zeros(n_p), 1000 + 2.5 * np.arange(n_r), np.zeros((0, 3)), np.zeros(0), fc_hz=1e10,
        pulse=CompressedPulse(20e6, 1e-6, 24e6), antenna=MonopulseAntenna(6, 1.5), noise_sigma=sigma, seed=3)
    for echo in (echo_sum, echo_diff):
        assert np.mean(np.abs(echo) ** 2) == pytest.approx(sigma**2, rel=0.05)
        assert abs(np.mean(echo.real**2) - np.mean(echo.imag**2)) < 0.05 * sigma**2  # circular
    assert stats.n_pairs_kept == 0


def test_seeded_noise_is_reproducible_and_seed_dependent():
    a, _ = simulate_scenario(tiny_scenario())
    b, _ = simulate_scenario(tiny_scenario())
    c, _ = simulate_scenario(tiny_scenario(noise={"seed": 8}))
    assert np.array_equal(a.sum, b.sum)
    assert not np.array_equal(a.sum, c.sum)


def test_gated_and_ungated_differ_by_less_than_minus_50_db():
    base = {"noise": {"snr_db": None}}
    gated, stats_g = simulate_scenario(tiny_scenario(**base))
    full, stats_f = simulate_scenario(tiny_scenario(**base, simulation={"gain_threshold_db": -1000.0}))
    assert stats_g.n_pairs_kept < stats_f.n_pairs_kept == stats_f.n_pairs
    for a, b in ((gated.sum, full.sum), (gated.diff, full.diff)):
        ratio_db = 10 * np.log10(np.sum(np.abs(a - b) ** 2) / np.sum(np.abs(b) ** 2))
        assert ratio_db < -50.0


def test_each_pair_touches_only_its_kernel():
    scn = tiny_scenario(noise={"snr_db": None})
    cube, stats = simulate_scenario(scn)
    width_m = (stats.kernel_samples - 1) / 2 * cube.range_spacing_m
    assert width_m == pytest.approx(C_MPS * scn["radar"]["pulse_width_s"] / 2, abs=cube.range_spacing_m)
    _, pos, _, targets, _ = scene_geometry(scn)
    r = slant_range_m(pos, targets)
    far = np.all(np.abs(cube.range_m[None, None, :] - r[:, :, None]) > width_m + cube.range_spacing_m, axis=0)
    assert np.all(cube.sum[far] == 0)
