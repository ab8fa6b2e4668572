"""The per-CPI Doppler band of ``doppler_spectra`` from the full velocity vector (issue 8, item 5).

A scatterer on the beam axis (theta_beam, phi_0) has the Doppler centroid f = 2 v . u(theta, phi_0) / lambda
(eq. 25 with the INS velocity vector).  Transverse motion adds 2 v_x sin(theta) cos(phi_0) / lambda, vertical
motion -2 v_z sin(phi_0) / lambda: with the forward component alone the band misses such a scatterer.  The
stage is fed a pure slow-time tone at that closed-form Doppler; its zoomed spectrum must peak there.
"""
from __future__ import annotations

import numpy as np
import pytest

from fwdlook_cli.forward.chain import cpi_doppler_band_hz, doppler_spectra
from fwdlook_cli.dsp.geometry import C_MPS
from fwdlook_cli.forward.motion import unit_vector
from fwdlook_cli.io.stagefile import StageData

FC, PRF, CPI, BW = 18.0e9, 2500.0, 32, 6.0
LAM = C_MPS / FC


def centroid_hz(v, theta_deg, phi_deg):
    return 2.0 * float(np.dot(v, unit_vector(theta_deg, phi_deg))) / LAM


def tone_stage(v, theta_deg, f_hz, n_cpi=2, n_range=4):
    m = n_cpi * CPI
    t = np.arange(m) / PRF
    d = StageData()
    d.add("slow_time_s", t, ("slow_time_s",), "s", "")
    d.add("range_m", 1000.0 + 2.5 * np.arange(n_range), ("range_m",), "m", "")
    d.add("xyz", np.arange(3), ("xyz",), "1", "")
    d.add("scan_angle_deg", np.full(m, theta_deg), ("slow_time_s",), "deg", "")
    d.add("velocity_mps", np.tile(np.asarray(v, float), (m, 1)), ("slow_time_s", "xyz"), "m/s", "")
    d.add("position_m", np.zeros((m, 3)), ("slow_time_s", "xyz"), "m", "")
    x = np.zeros((m, n_range), np.complex64)
    x[:, 1] = np.exp(2j * np.pi * np.mod(f_hz * t, 1.0))
    d.add("sum", x, ("slow_time_s", "range_m"), "1", "")
    d.add("diff", np.zeros_like(x), ("slow_time_s", "range_m"), "1", "")
    return d


CASES = [  # velocity [v_x, v_y, v_z] (m/s), beam azimuth (deg), depression phi_0 (deg)
    ([30.0, 240.0, 0.0], 12.0, 1.7),       # crab: transverse 30 m/s, +750 Hz at 12 deg
    ([-30.0, 240.0, 0.0], 12.0, 1.7),
    ([0.0, 240.0, -15.0], 5.0, 20.0),      # descending at 15 m/s, steep look: +616 Hz
    ([20.0, 240.0, 12.0], -9.0, 10.0),     # both
    ([0.0, 240.0, 0.0], 10.0, 1.7),        # the paper's case: unchanged
]


@pytest.mark.parametrize("v, theta, phi", CASES)
def test_band_is_centred_on_the_closed_form_centroid(v, theta, phi):
    f0 = centroid_hz(v, theta, phi)
    lo, hi = cpi_doppler_band_hz(np.array([v]), np.array([theta]), phi, FC, BW, PRF, CPI)
    lo, hi = float(lo[0]), float(hi[0])
    half = BW / 2
    # the band is [f(theta - h), f(theta + h)] (heading outside the beam here), f(theta') = 2 v.u(theta')/lambda
    ends = sorted([centroid_hz(v, theta - half, phi), centroid_hz(v, theta + half, phi)])
    width = max(ends[1] - ends[0], 4.0 * PRF / CPI)
    assert 0.5 * (lo + hi) == pytest.approx(0.5 * (ends[0] + ends[1]), abs=1e-6)
    assert hi - lo == pytest.approx(width, abs=1e-6)
    # its centre is the centroid up to the cos(h) of averaging a cosine over the beam:
    # mean of A cos(theta' - psi) over theta +- h = A cos(theta - psi) cos(h), C unchanged
    c0 = -2.0 * v[2] * np.sin(np.radians(phi)) / LAM
    assert 0.5 * (lo + hi) == pytest.approx(c0 + (f0 - c0) * np.cos(np.radians(half)), abs=1e-6)
    assert lo < f0 < hi


@pytest.mark.parametrize("v, theta, phi", CASES)
def test_zoomed_spectrum_peaks_at_the_closed_form_doppler(v, theta, phi):
    f0 = centroid_hz(v, theta, phi)
    out = doppler_spectra(tone_stage(v, theta, f0), cpi=CPI, n_doppler=64, window="none", fc_hz=FC,
                          beamwidth_deg=BW, depression_deg=phi, prf_hz=PRF, follow_speed=True)
    f_z = out["doppler_hz"]
    spacing = f_z[0, 1] - f_z[0, 0]
    for i in range(f_z.shape[0]):
        assert f_z[i, 0] < f0 < f_z[i, -1]
        k = int(np.argmax(np.abs(out["sum_z"][i, :, 1])))
        assert abs(f_z[i, k] - f0) <= spacing
        # and at the coherent gain of the rectangular CPI (unit tone: CPI), the grid's scalloping aside
        assert abs(out["sum_z"][i, k, 1]) >= 0.98 * CPI
    np.testing.assert_allclose(out["cpi_velocity_mps"], np.tile(v, (f_z.shape[0], 1)))


def test_heading_inside_the_beam_gives_the_maximum_doppler():
    # crab of 5 deg: the velocity's heading lies inside a beam pointed at 4 deg, so the band's top is the
    # largest Doppler of any direction, 2 |v_h| cos(phi_0) / lambda, not one of the band's ends
    v = np.array([240.0 * np.sin(np.radians(5.0)), 240.0 * np.cos(np.radians(5.0)), 0.0])
    lo, hi = cpi_doppler_band_hz(v[None], np.array([4.0]), 1.7, FC, BW, PRF, CPI)
    top = 2 * 240.0 * np.cos(np.radians(1.7)) / LAM
    low = min(centroid_hz(v, 1.0, 1.7), centroid_hz(v, 7.0, 1.7))
    width = max(top - low, 4 * PRF / CPI)
    assert 0.5 * (lo[0] + hi[0]) == pytest.approx(0.5 * (top + low), abs=1e-6)
    assert hi[0] - lo[0] == pytest.approx(width, abs=1e-6)
