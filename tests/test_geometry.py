"""Closed-form facts of the forward-looking geometry (paper eq. 1, 16, 17, 19, 20)."""
import numpy as np
import pytest

from fwdlook_cli.dsp.geometry import C_MPS, ambiguity_number, depression_deg, doppler_centroid_hz, platform_state, residual_velocity_mps, slant_range_m

FC, PRF, V, H, Y0 = 18e9, 2500.0, 240.0, 50.0, 1700.0


def paper_doppler(theta_deg):
    phi = np.degrees(np.arctan2(H, Y0))
    return doppler_centroid_hz(V, FC, theta_deg, phi)


@pytest.mark.parametrize("theta_deg", [0.0, 5.0, -10.0, 14.0])
def test_doppler_centroid_is_minus_2_over_lambda_times_exact_range_rate(theta_deg):
    # target at ground range 1700 m, azimuth theta; range rate from the exact eq. (1) by differences
    ground = Y0
    target = np.array([[ground * np.sin(np.radians(theta_deg)), ground * np.cos(np.radians(theta_deg)), 0.0]])
    dt = 1e-6
    pos, _ = platform_state(np.array([-dt, dt]), V, [0, 0, 0], H)
    r = slant_range_m(pos, target)[0]
    fd_exact = -2.0 * FC / C_MPS * (r[1] - r[0]) / (2 * dt)
    phi = depression_deg(platform_state(np.array([0.0]), V, [0, 0, 0], H)[0], target)[0, 0]
    assert doppler_centroid_hz(V, FC, theta_deg, phi) == pytest.approx(fd_exact, rel=1e-7)


def test_paper_ambiguity_numbers_need_low_platform():
    # paper Sec. 4: F = 12 at 0 deg and 11 at 10 deg at PRF 2500 Hz (NOTES.md: h = 50 m)
    assert ambiguity_number(paper_doppler(0.0), PRF) == 12
    assert ambiguity_number(paper_doppler(10.0), PRF) == 11
    # and at Q = 25 the change of ambiguity number at 10 deg is 4 (paper Sec. 4.1)
    assert ambiguity_number(paper_doppler(0.0), PRF / 25) - ambiguity_number(paper_doppler(10.0), PRF / 25) == 4
    # a high platform (h = 500 m) would not give the paper's F = 12 on boresight
    phi_high = np.degrees(np.arctan2(500.0, Y0))
    assert ambiguity_number(doppler_centroid_hz(V, FC, 0.0, phi_high), PRF) != 12


def test_residual_velocity_eq19_eq20():
    assert residual_velocity_mps(PRF, FC) == pytest.approx(20.82, abs=0.01)  # paper: 20.8 m/s
    assert residual_velocity_mps(PRF, FC, q=25) == pytest.approx(0.833, abs=0.001)  # paper: 0.8 m/s


def test_ambiguity_number_rounds_symmetrically():
    assert list(ambiguity_number(np.array([-3749.0, -3751.0, 3749.0, 3751.0]), PRF)) == [-1, -2, 1, 2]


def test_exact_range_taylor_first_order():
    # eq. (2): R(t) = R0 - v t cos(theta) cos(phi) + O(t^2) for the exact eq. (1) range
    target = np.array([[300.0, 1700.0, 0.0]])
    t = np.array([0.0, 1e-3])
    pos, _ = platform_state(t, V, [0.0, 50.0, 0.0], H)
    r = slant_range_m(pos, target)[0]
    r0 = np.sqrt(300.0**2 + 1700.0**2 + H**2)
    cos_theta_cos_phi = 1700.0 / r0
    assert r[0] == pytest.approx(r0, rel=1e-14)
    assert (r[1] - r[0]) == pytest.approx(-V * 1e-3 * cos_theta_cos_phi, abs=1e-4)
