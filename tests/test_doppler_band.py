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
from fwdlook_cli.dsp.geometry import C_MPS, unit_vector
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


@pytest.mark.parametrize("theta, expected_cells", [(20.0, None), (0.0, 16), (80.0, None)])
def test_auto_doppler_cells_sample_the_widest_band_at_four_per_resolution_cell(theta, expected_cells):
    """``processing.n_doppler: auto`` against the closed form: forward flight at 240 m/s, the beam at
    theta, depression phi: the band is 2 v cos(phi) (cos(theta - h) - cos(theta + h)) / lambda
    = 4 v cos(phi) sin(theta) sin(h) / lambda (h half the 3 dB beamwidth), at least 4 resolution cells
    PRF / cpi: ceil(4 cpi band / PRF) cells (16 on boresight, where the band is the 4-cell minimum)."""
    from fwdlook_cli.forward.motion import auto_doppler_cells, widest_cpi_band_hz

    def auto(data, **kw):
        return auto_doppler_cells(widest_cpi_band_hz(data, **kw), cpi=CPI, prf_hz=PRF)

    v, phi, n_cpi = 240.0, 3.0, 3
    m = n_cpi * CPI
    data = {"slow_time_s": np.arange(m) / PRF, "scan_angle_deg": np.full(m, theta),
            "velocity_mps": np.tile([0.0, v, 0.0], (m, 1))}
    band = 4.0 * v * np.cos(np.radians(phi)) * np.sin(np.radians(theta)) * np.sin(np.radians(BW / 2)) / LAM
    band = min(max(band, 4.0 * PRF / CPI), PRF)
    want = int(np.ceil(4.0 * CPI * band / PRF - 1e-9))
    assert expected_cells is None or want == expected_cells
    got = auto(data, cpi=CPI, follow_speed=True, depression_deg=phi, fc_hz=FC, beamwidth_deg=BW, prf_hz=PRF)
    assert got == want
    # a scan: the widest CPI band sets the one count of every CPI
    scan = dict(data, scan_angle_deg=np.repeat([0.0, theta, -0.5 * theta], CPI))
    assert auto(scan, cpi=CPI, follow_speed=True, depression_deg=phi, fc_hz=FC, beamwidth_deg=BW,
                prf_hz=PRF) == max(want, 16)


WHOLE_PRF = dict(velocity_mps=[0.0, 600.0, 0.0], scan_deg=60.0, depression_deg=3.0, beamwidth_deg=30.0)


def _whole_prf_auto_cells():
    """(band, auto count) of two CPIs of fast flight (600 m/s) with a 30 deg beam at 60 deg, where every
    CPI's band is the whole PRF."""
    from fwdlook_cli.forward.motion import auto_doppler_cells, widest_cpi_band_hz

    m = 2 * CPI
    data = {"slow_time_s": np.arange(m) / PRF, "scan_angle_deg": np.full(m, WHOLE_PRF["scan_deg"]),
            "velocity_mps": np.tile(WHOLE_PRF["velocity_mps"], (m, 1))}
    band = widest_cpi_band_hz(data, cpi=CPI, follow_speed=True, depression_deg=WHOLE_PRF["depression_deg"], fc_hz=FC,
                              beamwidth_deg=WHOLE_PRF["beamwidth_deg"], prf_hz=PRF)
    return band, auto_doppler_cells(band, cpi=CPI, prf_hz=PRF)


def test_auto_doppler_cells_of_a_band_of_the_whole_prf():
    """Where the band reaches the PRF (fast flight, wide beam) auto gives 4 cells per resolution cell over
    it: 4 cpi cells."""
    band, auto = _whole_prf_auto_cells()
    assert band == pytest.approx(PRF) and auto == 4 * CPI


def _power_interpolated(power, f_lo_hz, f_new_hz, degree):
    """A power spectrum sampled at M cells (k + 1/2) PRF / M from ``f_lo_hz`` over the whole PRF, taken as
    the trigonometric polynomial of ``degree`` through the samples and evaluated at ``f_new_hz``: numpy
    alone (a direct sum over the samples; nothing of the stage)."""
    m = power.shape[-1]
    u = (np.arange(m) + 0.5) / m                                            # cell centres, cycles of the PRF
    lags = np.arange(-degree, degree + 1)
    coef = np.exp(-2j * np.pi * np.outer(lags, u)) @ power.T / m             # [lags, rows]
    u_new = (np.asarray(f_new_hz) - f_lo_hz) / PRF
    return np.real(np.exp(2j * np.pi * np.outer(u_new, lags)) @ coef).T


def test_auto_cells_hold_the_cpi_power_spectrum_whole():
    """``n_doppler: auto`` samples the CPI's power spectrum past its Nyquist rate.  The power spectrum of a
    CPI is a trigonometric polynomial of degree cpi - 1, so the stage's power at 2 cpi cells over the PRF
    (2 per resolution cell) gives, interpolated (numpy, :func:`_power_interpolated`), the power the same
    stage computes at 16 cells per resolution cell, to 1e-5 of the peak (4.4e-7 here), for echoes at
    arbitrary Doppler frequencies; so does auto's 4 cpi (4.7e-7).  On the native grid (1 per cell: the
    complex spectrum's Nyquist rate, not the power's) the same interpolation misses by more than 5 % of
    the peak (47 % here)."""
    _, auto = _whole_prf_auto_cells()
    m = 2 * CPI
    t = np.arange(m) / PRF
    rng = np.random.default_rng(7)
    n_range = 6
    d = tone_stage(WHOLE_PRF["velocity_mps"], WHOLE_PRF["scan_deg"], 0.0, n_cpi=2, n_range=n_range)
    x = np.zeros((m, n_range), np.complex128)
    for r in range(n_range):                     # three echoes per range cell, random Doppler and amplitude
        for f, a in zip(rng.uniform(0, PRF, 3), rng.normal(size=3) + 1j * rng.normal(size=3)):
            x[:, r] += a * np.exp(2j * np.pi * np.mod(f * t, 1.0))
    d.vars["sum"].data[...] = x.astype(np.complex64)
    kw = dict(cpi=CPI, window="none", fc_hz=FC, prf_hz=PRF, follow_speed=True,
              depression_deg=WHOLE_PRF["depression_deg"], beamwidth_deg=WHOLE_PRF["beamwidth_deg"])

    def power(n_doppler):
        out = doppler_spectra(d, n_doppler=n_doppler, **kw)
        z = np.asarray(out["sum_z"], np.complex128)                         # [cpi, cell, range]
        return np.abs(np.moveaxis(z, 1, 2)) ** 2, np.asarray(out["doppler_hz"])

    fine, f_fine = power(16 * CPI)
    peak = float(fine.max())
    for cells, ok in ((auto, True), (2 * CPI, True), (CPI, False)):
        coarse, f_coarse = power(cells)
        f_lo = float(f_coarse[0, 0]) - 0.5 * PRF / cells
        assert float(f_fine[0, 0]) - 0.5 * PRF / (16 * CPI) == pytest.approx(f_lo, abs=1e-6)   # the same band
        est = np.stack([_power_interpolated(coarse[i], f_lo, f_fine[i], min(CPI - 1, (cells - 1) // 2))
                        for i in range(coarse.shape[0])])
        err = float(np.max(np.abs(est - fine))) / peak
        assert (err < 1e-5) if ok else (err > 0.05), (cells, err)


def test_n_doppler_auto_in_the_chain_is_the_stages_own_band(tmp_path):
    """On the paper cube (a = 50) auto resolves to the Doppler stage's own widest band, 926.5 Hz = 11.9
    resolution cells of 78.1 Hz: 48 cells; the stage runs with them, metrics.json reports them, fwdlook
    plan predicts them, and it is the default (since issue 11's thirty-sixth round; 64 before)."""
    import json

    from fwdlook_cli.forward.chain import build_forward_stages
    from fwdlook_cli.forward.process import process_cube
    from fwdlook_cli.forward.simulate import simulate_scenario
    from fwdlook_cli.scenario.loader import load_scenario

    root = __import__("pathlib").Path(__file__).resolve().parents[1]
    scn = load_scenario(root / "scenarios" / "paper_fig6_a50.yaml", overrides=["processing.n_doppler=auto"])
    cube, _ = simulate_scenario(scn)
    src, stages, geo = build_forward_stages(cube, scn["processing"])
    data = src
    for st in stages:
        data = st.fn(data, **st.params)
        if st.name == "doppler_spectra":
            break
    n = st.params["n_doppler"]
    assert n == geo["n_doppler"] == 48 and data["sum_z"].shape[1] == n
    f_z = data["doppler_hz"]                                   # cell centres (i + 1/2) band / n from f_lo
    widest = float(np.max((f_z[:, -1] - f_z[:, 0]) * n / (n - 1)))
    cpi, prf = scn["processing"]["cpi"], cube.radar["prf_hz"]
    assert widest == pytest.approx(926.5, abs=0.5)
    assert n == int(np.ceil(4 * widest * cpi / prf - 1e-9))
    # fwdlook plan predicts the same band and count, from the scenario alone and from the cube
    from fwdlook_cli.forward.plan import plan_for_cube, plan_for_scenario

    for plan in (plan_for_scenario(scn), plan_for_cube(cube, scn["processing"])):
        assert plan["n_doppler_auto"] == 48 and plan["doppler_band_widest_hz"] == pytest.approx(widest, rel=1e-3)
    m = process_cube(cube, scn, tmp_path / "auto", png=False, quiet=True)
    assert m["params"]["n_doppler"] == 48
    assert json.loads((tmp_path / "auto" / "metrics.json").read_text())["params"]["n_doppler"] == 48
    default = load_scenario(root / "scenarios" / "paper_fig6_a50.yaml")
    assert default["processing"]["n_doppler"] == "auto"
