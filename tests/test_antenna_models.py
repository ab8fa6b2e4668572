"""Antenna models: the design solver's root, the limits it names, the sinc and table families, and a
property test over designs (sum beamwidth 2-10 deg, crossover -1 to -6 dB, each family)."""
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from fwdlook_cli.dsp.antenna import AntennaDesignError, MonopulseAntenna, TableAntenna, crossover_db_of_rho, max_squint_deg, read_pattern_file, rho_limit
from fwdlook_cli.cli import main

sys.path.insert(0, str(Path(__file__).resolve().parent))
import independent_writer as writer  # noqa: E402

HALF_POWER_DB = -10 * np.log10(2.0)


def _cli(argv):
    try:
        main([str(a) for a in argv])
    except SystemExit as exc:
        return exc.code
    return 0


@pytest.mark.parametrize("bw", [2.0, 4.0, 6.0, 10.0])
def test_default_design_crosses_at_minus_3_db_for_any_beamwidth(bw):
    ant = MonopulseAntenna(bw)
    assert ant.crossover_db == pytest.approx(-3.0, abs=1e-9)
    assert 20 * np.log10(ant.sum_voltage(bw / 2)) == pytest.approx(HALF_POWER_DB, abs=1e-9)
    assert 20 * np.log10(ant.sum_voltage(-bw / 2)) == pytest.approx(HALF_POWER_DB, abs=1e-9)
    # each beam's own level at the boresight is the crossover (beams g+- = Sigma +- Delta, normalised)
    g_plus = (ant.sum_voltage(0.0) + ant.diff_voltage(0.0)) / (ant.sum_voltage(ant.squint_deg)
                                                              + ant.diff_voltage(ant.squint_deg))
    assert 20 * np.log10(g_plus) == pytest.approx(-3.0, abs=1e-9)


@pytest.mark.parametrize("bw", [4.0, 6.0])
def test_textbook_design_agrees_with_the_independent_writer(bw):
    """Half-power crossover: the slope of an independent bisection design (tests/independent_writer)."""
    ant = MonopulseAntenna(bw, crossover_db=HALF_POWER_DB)
    assert ant.slope_per_deg == pytest.approx(writer.true_slope_per_deg(bw), rel=1e-6)
    assert ant.squint_deg == pytest.approx(writer.element_beamwidth_deg(bw) / 2, rel=1e-6)
    # given by its squint, the solver takes the same root (of the two, the one nearer -3 dB)
    by_squint = MonopulseAntenna(bw, ant.squint_deg)
    assert by_squint.slope_per_deg == pytest.approx(ant.slope_per_deg, rel=1e-6)


def test_textbook_numbers_for_the_paper_beam():
    ant = MonopulseAntenna(6.0, crossover_db=HALF_POWER_DB)
    assert ant.squint_deg == pytest.approx(1.9226, abs=1e-4)
    assert ant.slope_per_deg == pytest.approx(0.3605, abs=1e-4)
    np.testing.assert_allclose(ant.ratio(np.linspace(-5, 5, 11)), np.tanh(ant.slope_per_deg * np.linspace(-5, 5, 11)),
                               atol=1e-12)


def test_squint_limit_is_the_fold_of_the_design_curve():
    s_max = max_squint_deg("gaussian2", 6.0)
    assert s_max == pytest.approx(0.32054 * 6.0, rel=1e-4)
    MonopulseAntenna(6.0, s_max * (1 - 1e-4))           # just inside: built
    with pytest.raises(AntennaDesignError, match=f"squint_deg <= {s_max:.4f}"):
        MonopulseAntenna(6.0, s_max * (1 + 1e-4))
    # the sum beam at the limit still has its 3 dB points at +-bw/2
    ant = MonopulseAntenna(6.0, s_max * (1 - 1e-4))
    assert 20 * np.log10(ant.sum_voltage(3.0)) == pytest.approx(HALF_POWER_DB, abs=1e-8)


@pytest.mark.parametrize("pattern, limit_db", [("gaussian2", -10 * np.log10(np.e)), ("sinc2", None)])
def test_crossover_limit_is_the_boresight_dip(pattern, limit_db):
    c_lim = float(crossover_db_of_rho(pattern, rho_limit(pattern)))
    if limit_db is not None:
        assert c_lim == pytest.approx(limit_db, abs=1e-9)       # Gaussian: 2 beta s^2 = 1
    ant = MonopulseAntenna(6.0, pattern=pattern, crossover_db=c_lim + 1e-6)
    d = np.linspace(-1e-2, 1e-2, 5)
    assert np.all(ant.sum_voltage(d) <= ant.sum_voltage(0.0) + 1e-9)   # no dip on boresight
    with pytest.raises(AntennaDesignError, match=f"crossover_db >= {c_lim:.3f}"):
        MonopulseAntenna(6.0, pattern=pattern, crossover_db=c_lim - 0.01)


def test_sinc_beams_are_uniform_aperture_patterns():
    ant = MonopulseAntenna(6.0, pattern="sinc2")
    d = np.linspace(-8, 8, 81)
    g_plus = ant.sum_voltage(d) + ant.diff_voltage(d)
    w = ant.element_halfwidth_deg
    x3 = 0.442946470689452                  # np.sinc(x3)^2 = 1/2
    norm = np.sinc(x3 * ant.rho)
    np.testing.assert_allclose(g_plus, np.sinc(x3 * (d - ant.squint_deg) / w) / norm, atol=1e-12)
    assert 20 * np.log10(ant.sum_voltage(3.0)) == pytest.approx(HALF_POWER_DB, abs=1e-9)
    # the ratio is not tanh; its table inverse is exact to the table's interpolation
    r = ant.ratio(np.linspace(-2.5, 2.5, 51))
    np.testing.assert_allclose(ant.ratio_to_offset_deg(r), np.linspace(-2.5, 2.5, 51), atol=2e-4)
    offs, rat = ant.ratio_table
    assert np.all(np.diff(rat) > 0) and offs[-1] >= 3.0


def test_table_pattern_from_csv_and_hdf5(tmp_path):
    ref = MonopulseAntenna(6.0, pattern="sinc2", crossover_db=-4.0)
    d = np.linspace(-10, 10, 2001)
    csv = tmp_path / "pattern.csv"
    csv.write_text("offset_deg,sum,diff\n" + "\n".join(f"{a:.5f},{s:.10f},{g:.10f}" for a, s, g in
                                                       zip(d, ref.sum_voltage(d), ref.diff_voltage(d))))
    h5 = tmp_path / "pattern.h5"
    with h5py.File(h5, "w") as f:
        for name, col in (("offset_deg", d), ("sum", ref.sum_voltage(d)), ("diff", ref.diff_voltage(d))):
            f[name] = col
    for path in (csv, h5):
        tab = read_pattern_file(path, 6.0)
        x = np.linspace(-2.5, 2.5, 26)
        np.testing.assert_allclose(tab.ratio(x), ref.ratio(x), atol=1e-4)
        assert tab.slope_per_deg == pytest.approx(ref.slope_per_deg, rel=1e-3)
        np.testing.assert_allclose(tab.ratio_to_offset_deg(ref.ratio(x)), x, atol=2e-3)
    with pytest.raises(AntennaDesignError, match="within 5 %"):
        read_pattern_file(csv, 7.0)
    with pytest.raises(AntennaDesignError, match="strictly increasing"):
        TableAntenna(d[::-1], ref.sum_voltage(d), ref.diff_voltage(d))


# ----------------------------------------------------------------------------------------------
# property test over designs: every feasible one simulates and processes, an infeasible one exits 2
# ----------------------------------------------------------------------------------------------
def _scenario(tmp, bw, crossover_db, pattern):
    ant = {"beamwidth_3db_deg": float(bw), "scan_start_deg": -1.2 * bw, "scan_stop_deg": 1.2 * bw,
           "scan_rate_dps": 20.0 * bw}
    if pattern == "table":
        try:
            ref = MonopulseAntenna(bw, pattern="sinc2", crossover_db=crossover_db)
        except AntennaDesignError:
            ref = None
        if ref is not None:
            d = np.linspace(-3 * bw, 3 * bw, 1201)
            np.savetxt(tmp / "pat.csv", np.column_stack([d, ref.sum_voltage(d), ref.diff_voltage(d)]),
                       delimiter=",", header="offset_deg,sum,diff")
        ant.update(pattern="table", pattern_file="pat.csv")
    else:
        ant.update(pattern=pattern, crossover_db=float(crossover_db))
    scn = {"name": "design", "radar": {"fc_hz": 10e9, "bandwidth_hz": 20e6, "prf_hz": 2000.0, "fs_hz": 24e6},
           "antenna": ant, "platform": {"speed_mps": 150.0, "height_m": 50.0},
           "scene": {"kind": "points", "points_m": [[0.0, 1000.0]]}, "noise": {"snr_db": 30.0},
           "processing": {"method": "bulk", "q": 8, "cpi": 16, "monopulse_calibration": "cube"}}
    path = tmp / "design.yaml"
    path.write_text(yaml.safe_dump(scn))
    return path, ref if pattern == "table" else None


@settings(max_examples=6, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(bw=st.floats(2.0, 10.0), crossover_db=st.floats(-6.0, -1.0),
       pattern=st.sampled_from(["gaussian2", "sinc2", "table"]))
def test_every_feasible_design_runs_and_an_infeasible_one_exits_2(tmp_path_factory, capsys, bw, crossover_db,
                                                                  pattern):
    tmp = tmp_path_factory.mktemp("design")
    capsys.readouterr()
    path, ref = _scenario(tmp, bw, crossover_db, pattern)
    family = "sinc2" if pattern == "table" else pattern
    c_lim = float(crossover_db_of_rho(family, rho_limit(family)))
    feasible = crossover_db >= c_lim
    assume(feasible or pattern != "table")   # a measured table has no design to be infeasible
    code = _cli(["run", path, "-o", tmp / "run"])
    if feasible:
        assert code == 0
        import json

        m = json.loads((tmp / "run" / "metrics.json").read_text())
        assert m["summary"]["detected"] == 1
        assert m["calibration"]["source"] == "cube"
        assert abs(m["targets"][0]["azimuth_error_deg"]) < 0.1 * bw
    else:
        assert code == 2
        err = capsys.readouterr().err
        key = "antenna.pattern_file" if pattern == "table" else "antenna.crossover_db"
        assert key in err and (pattern == "table" or f"crossover_db >= {c_lim:.3f}" in err), err


@pytest.mark.parametrize("pattern", ["gaussian2", "sinc2"])
def test_infeasible_crossover_exits_2_naming_its_limit(tmp_path, capsys, pattern):
    path, _ = _scenario(tmp_path, 6.0, -8.0, pattern)
    c_lim = float(crossover_db_of_rho(pattern, rho_limit(pattern)))
    assert _cli(["validate", path]) == 2
    err = capsys.readouterr().err
    assert "antenna.crossover_db = -8.0" in err and f"crossover_db >= {c_lim:.3f}" in err
    assert "Traceback" not in err


def test_contract_keys_only_with_a_4_deg_beam_validates_and_runs(tmp_path):
    """The issue's new user: a 10 GHz radar with a 4 deg beam, CONTRACT.md section 2 keys only."""
    scn = {"name": "xband_4deg",
           "radar": {"fc_hz": 10.0e9, "bandwidth_hz": 40.0e6, "pulse_width_s": 1.0e-6, "prf_hz": 2500,
                     "fs_hz": 48.0e6, "range_window_m": "auto"},
           "antenna": {"beamwidth_3db_deg": 4.0, "scan_start_deg": -4.0, "scan_stop_deg": 4.0,
                       "scan_rate_dps": 40.0},
           "platform": {"speed_mps": 240.0, "accel_mps2": [0.0, 10.0, 0.0], "height_m": 50.0},
           "scene": {"kind": "points", "center_m": [0.0, 1700.0], "points_m": [[-30.0, 1650.0], [40.0, 1750.0]],
                     "amplitude": 1.0},
           "noise": {"snr_db": 20.0, "seed": 1},
           "processing": {"method": "decimation", "q": 25, "keystone": "czt", "range_curvature": True,
                          "doppler_centroid": True, "cpi": 32, "t_ref": "centre", "monopulse_calibration": "auto"}}
    path = tmp_path / "xband.yaml"
    path.write_text(yaml.safe_dump(scn))
    assert _cli(["validate", path]) == 0
    assert _cli(["run", path, "-o", tmp_path / "run"]) == 0
    import json

    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert m["calibration"]["source"] == "cube"
    assert m["calibration"]["slope_per_deg"] == pytest.approx(MonopulseAntenna(4.0).slope_per_deg)
    assert m["summary"]["detected"] == 2


def test_the_design_solvers_root_is_scipys_brentq_root():
    """bracketed_root (Illinois with bisection, no scipy.optimize import) against scipy's brentq, which shares no
    code with it: the same roots to the tolerance asked, and whole designs to 1e-12."""
    from scipy.optimize import brentq

    from fwdlook_cli.dsp import antenna

    cases = [(lambda x: np.sinc(x) ** 2 - 0.5, 0.1, 0.9, 1e-15), (lambda x: x ** 3 - 2.0, 0.0, 3.0, 1e-14),
             (lambda x: np.cos(x) - x, 0.0, 1.0, 2e-12), (lambda x: np.exp(x) - 1e3, -1.0, 10.0, 1e-14)]
    for f, a, b, xtol in cases:
        ours, theirs = antenna.bracketed_root(f, a, b, xtol=xtol), brentq(f, a, b, xtol=xtol)
        assert abs(ours - theirs) <= 2 * xtol + 8 * np.finfo(float).eps * abs(theirs)
        assert (f(ours - 4 * xtol) < 0) != (f(ours + 4 * xtol) < 0)            # a sign change around it
    with pytest.raises(ValueError, match="same sign"):
        antenna.bracketed_root(lambda x: x * x + 1.0, -1.0, 1.0)
    # a triple root (false position alone crawls there; scipy's brentq gives up at 1e-14) and a step
    # of tanh: each within the tolerance, in at most about twice a bisection's evaluations
    for f, root in ((lambda x: (x - 0.2) ** 3, 0.2), (lambda x: np.tanh(50.0 * (x - 0.3)), 0.3)):
        calls = []
        found = antenna.bracketed_root(lambda x: calls.append(x) or f(x), 0.0, 1.0, xtol=1e-14)
        assert abs(found - root) <= 2e-14 and len(calls) <= 2.2 * np.ceil(np.log2(1.0 / 1e-14)) + 4
    designs = [dict(beamwidth_3db_deg=6.0), dict(beamwidth_3db_deg=3.0, squint_deg=0.9),
               dict(beamwidth_3db_deg=4.0, pattern="sinc2"),
               dict(beamwidth_3db_deg=8.0, squint_deg=2.0, pattern="sinc2"),
               dict(beamwidth_3db_deg=5.0, crossover_db=-1.5)]
    ours = [MonopulseAntenna(**d) for d in designs]
    mp = pytest.MonkeyPatch()
    try:
        mp.setattr(antenna, "bracketed_root", lambda f, a, b, xtol=2e-12: brentq(f, a, b, xtol=xtol))
        antenna._squint_curve.cache_clear()
        antenna.rho_limit.cache_clear()
        theirs = [MonopulseAntenna(**d) for d in designs]
    finally:
        mp.undo()
        antenna._squint_curve.cache_clear()
        antenna.rho_limit.cache_clear()
    for a, b in zip(ours, theirs):
        for name in ("rho", "element_halfwidth_deg", "squint_deg", "slope_per_deg", "crossover_db"):
            assert getattr(a, name) == pytest.approx(getattr(b, name), rel=1e-12, abs=1e-12), name
        assert a.two_way_3db_width_deg() == pytest.approx(b.two_way_3db_width_deg(), rel=1e-10)


@pytest.mark.parametrize("pattern", ["gaussian2", "sinc2"])
def test_the_sampled_squint_curve_is_within_its_margin_of_the_exact_one(pattern):
    """A squint more than 1e-4 (in half-beamwidths) below the sampled curve's maximum is accepted
    without the exact maximum (antenna._rho_for_squint): the sampled curve must be within 1e-5 of
    rho / v_h(rho) solved point by point, and its maximum below the exact one plus that."""
    from fwdlook_cli.dsp import antenna

    rho, q = antenna._squint_curve(pattern)
    exact = np.array([r / antenna._half_width_units(pattern, r) for r in rho[::5]])
    assert np.abs(q[::5] - exact).max() < 1e-5
    assert q.max() <= max_squint_deg(pattern, 2.0) + 1e-5         # max_squint_deg(bw = 2): in units of h


def test_the_squint_curve_is_computed_in_small_blocks_with_the_same_numbers():
    """Every command that designs an antenna computes the squint curve once (a 500 x 2001 grid): in row
    blocks its temporaries stay under 3 MiB (the whole grid at once: about 30 MiB, numpy's allocations
    as tracemalloc sees them), and each row is computed on its own, so any block size gives the same
    curve bit for bit."""
    import tracemalloc

    from fwdlook_cli.dsp import antenna

    curve = antenna._squint_curve.__wrapped__
    mp = pytest.MonkeyPatch()
    for pattern in ("gaussian2", "sinc2"):
        tracemalloc.start()
        try:
            rho, q = curve(pattern)
            peak_bytes = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert peak_bytes < 3 * 2**20, pattern
        try:
            mp.setattr(antenna, "_SQUINT_ROWS", 500)                       # the whole grid in one block
            rho_whole, q_whole = curve(pattern)
            mp.setattr(antenna, "_SQUINT_ROWS", 7)
            rho_small, q_small = curve(pattern)
        finally:
            mp.undo()
        assert np.array_equal(rho, rho_whole) and np.array_equal(q, q_whole) and np.array_equal(q, q_small)


def test_a_pattern_csv_row_that_is_not_numbers_is_named_and_a_header_holds_none(tmp_path):
    """A first row of numbers with one garbled cell had been dropped as a header (an independent review:
    exit 0); a header is a first row that holds no number. A bad row is refused naming its line."""
    v = lambda d: np.exp(-np.log(2.0) * d * d / 18.0)      # noqa: E731  one-way voltage, -3 dB power at +-3 deg
    good = "\n".join(f"{d},{v(d)},{np.tanh(0.3 * d) * v(d)}" for d in np.linspace(-6, 6, 13))
    (tmp_path / "ok.csv").write_text("offset_deg,sum,diff\n" + good + "\n")
    assert len(read_pattern_file(tmp_path / "ok.csv", 6.0)._d) == 13
    (tmp_path / "garbled.csv").write_text("-7abc,0.01,-0.01\n" + good + "\n")
    with pytest.raises(AntennaDesignError, match=r"line 1: '-7abc,0.01,-0.01'"):
        read_pattern_file(tmp_path / "garbled.csv", 6.0)
    (tmp_path / "middle.csv").write_text("offset_deg,sum,diff\n" + good + "\nx,0.9,0.1\n")
    with pytest.raises(AntennaDesignError, match=r"line 15: 'x,0.9,0.1'"):
        read_pattern_file(tmp_path / "middle.csv", 6.0)
