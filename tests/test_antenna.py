"""Monopulse antenna: the sum beam's 3 dB width, the exact tanh ratio, its sign convention."""
import numpy as np
import pytest

from fwdlook_cli.dsp.antenna import MonopulseAntenna


@pytest.mark.parametrize("beamwidth, squint", [(6.0, 1.5), (6.0, 0.5), (3.0, 0.7)])
def test_sum_beam_one_way_3db_width_is_the_scenario_beamwidth(beamwidth, squint):
    ant = MonopulseAntenna(beamwidth, squint)
    assert ant.sum_voltage(0.0) == pytest.approx(1.0)
    assert 20 * np.log10(ant.sum_voltage(beamwidth / 2)) == pytest.approx(-3.0103, abs=1e-6)
    assert 20 * np.log10(ant.sum_voltage(-beamwidth / 2)) == pytest.approx(-3.0103, abs=1e-6)


def test_ratio_is_tanh_and_positive_towards_plus_x():
    ant = MonopulseAntenna(6.0, 1.5)
    d = np.linspace(-8, 8, 161)
    ratio = ant.diff_voltage(d) / ant.sum_voltage(d)
    np.testing.assert_allclose(ratio, np.tanh(ant.slope_per_deg * d), atol=1e-12)
    assert np.all(ratio[d > 0] > 0) and np.all(ratio[d < 0] < 0)
    # the slope is the derivative of the ratio on boresight
    eps = 1e-5
    deriv = (ant.diff_voltage(eps) / ant.sum_voltage(eps) - ant.diff_voltage(-eps) / ant.sum_voltage(-eps)) / (2 * eps)
    assert deriv == pytest.approx(ant.slope_per_deg, rel=1e-8)
    np.testing.assert_allclose(ant.ratio_to_offset_deg(ratio[np.abs(d) < 5]), d[np.abs(d) < 5], atol=1e-9)


def test_two_way_width_is_about_beamwidth_over_sqrt2():
    ant = MonopulseAntenna(6.0, 1.5)
    assert ant.two_way_3db_width_deg() == pytest.approx(6.0 / np.sqrt(2), rel=0.01)


def test_individual_beams_are_the_squinted_gaussians():
    ant = MonopulseAntenna(6.0, 1.5)
    d = np.linspace(-6, 6, 25)
    g_plus = (ant.sum_voltage(d) + ant.diff_voltage(d))
    g_minus = (ant.sum_voltage(d) - ant.diff_voltage(d))
    b, s = ant.beta_per_deg2, ant.squint_deg
    norm = np.exp(b * s * s)
    np.testing.assert_allclose(g_plus, norm * np.exp(-b * (d - s) ** 2), rtol=1e-12)
    np.testing.assert_allclose(g_minus, norm * np.exp(-b * (d + s) ** 2), rtol=1e-12)


def test_too_large_squint_is_rejected():
    with pytest.raises(ValueError, match="allowed"):
        MonopulseAntenna(6.0, 2.0)


def test_two_way_width_for_is_each_designs_own_found_once():
    """The cached two-way width is the design's own root (each design its own value, asked in any
    order), and a cube without a usable squint gets the -3 dB crossover design of its beamwidth."""
    from fwdlook_cli.dsp.antenna import two_way_width_for

    designs = [(6.0, {"pattern": "gaussian2", "squint_deg": 1.5}), (6.0, {"pattern": "sinc2", "squint_deg": 1.5}),
               (6.0, {"pattern": "gaussian2", "squint_deg": 1.8}), (4.0, {"pattern": "gaussian2", "squint_deg": 1.0})]
    direct = [MonopulseAntenna(bw, a["squint_deg"], pattern=a["pattern"]).two_way_3db_width_deg() for bw, a in designs]
    for _ in range(2):                       # the second pass is served from the cache
        assert [two_way_width_for(bw, a) for bw, a in designs] == direct
    assert len(set(direct)) == len(direct)
    assert two_way_width_for(6.0, None) == MonopulseAntenna(6.0).two_way_3db_width_deg()
    assert two_way_width_for(6.0, {"pattern": "table"}) == MonopulseAntenna(6.0).two_way_3db_width_deg()
