"""The uniform-grid not-a-knot spline's antiderivative (dsp/spline.py) against scipy's CubicSpline,
which shares no code with it: values and the first four derivatives at the knots, between them and
beyond the ends, to rounding; and the spline's defining properties on its own."""
import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from fwdlook_cli.dsp.spline import MIN_KNOTS, UniformSplineAntiderivative, is_uniform, not_a_knot_slopes


def _history(n, prf_hz=2000.0, seed=0):
    """A Doppler history like the chain's: a drift, an acceleration term and a scan wiggle (Hz)."""
    rng = np.random.default_rng(seed)
    t = (np.arange(n) - n / 2) / prf_hz
    y = 9000.0 + 400.0 * t + 30.0 * t ** 2 + 5.0 * np.sin(2 * np.pi * 0.7 * t + 1.0) + rng.normal(0, 0.01, n)
    return t, y


@pytest.mark.parametrize("n", [MIN_KNOTS, 9, 10, 57, 2500])
def test_the_antiderivative_is_scipys_at_knots_between_and_beyond(n):
    t, y = _history(n)
    ours, theirs = UniformSplineAntiderivative(t, y), CubicSpline(t, y).antiderivative()
    h = t[1] - t[0]
    probe = np.concatenate([t, t[:-1] + 0.37 * h, [t[0] - 2.5 * h, t[-1] + 3.1 * h]])
    for nu in range(5):
        want = theirs(probe, nu)
        scale = np.abs(want).max()
        np.testing.assert_allclose(ours(probe, nu), want, rtol=0, atol=1e-11 * scale, err_msg=f"nu={nu}")
    even = probe[: 2 * (len(probe) // 2)]
    assert ours(t[3]).shape == () and ours(even.reshape(2, -1), 1).shape == (2, len(even) // 2)


def test_the_slopes_make_a_c2_not_a_knot_interpolant():
    """On its own: the interpolant passes through the data, its second derivative is continuous at
    every interior knot and its third at x_1 and x_{n-2} (the not-a-knot conditions)."""
    t, y = _history(40, seed=3)
    anti = UniformSplineAntiderivative(t, y)
    h = t[1] - t[0]
    eps = 1e-7 * h
    np.testing.assert_allclose(anti(t, 1), y, rtol=0, atol=1e-9 * np.abs(y).max())
    left, right = anti(t[1:-1] - eps, 3), anti(t[1:-1] + eps, 3)
    np.testing.assert_allclose(left, right, rtol=0, atol=1e-5 * np.abs(left).max())
    d3 = lambda x: anti(x, 4)                                   # noqa: E731 (the spline's third derivative)
    for knot in (t[1], t[-2]):
        assert d3(knot - eps) == pytest.approx(d3(knot + eps), rel=1e-8)
    assert abs(d3(t[2] - eps) - d3(t[2] + eps)) > 1e-3 * abs(d3(t[2] + eps))   # a true knot: it jumps


def test_a_cubic_is_reproduced_exactly():
    """Not-a-knot reproduces any cubic: the slopes are its derivative at the knots."""
    t = np.linspace(-1.0, 2.0, 31)
    y = 2.0 - t + 0.5 * t ** 2 - 0.25 * t ** 3
    np.testing.assert_allclose(not_a_knot_slopes(y, t[1] - t[0]), -1.0 + t - 0.75 * t ** 2, atol=1e-12)


def test_non_uniform_or_short_grids_are_refused():
    assert is_uniform(np.arange(10.0)) and not is_uniform(np.r_[0.0, 1.0, 2.5, 3.0])
    with pytest.raises(ValueError, match="uniform"):
        UniformSplineAntiderivative(np.r_[0.0, 1.0, 2.5, 3.0, 4, 5, 6, 7], np.zeros(8))
    with pytest.raises(ValueError, match="at least"):
        not_a_knot_slopes(np.zeros(MIN_KNOTS - 1), 1.0)


def test_the_history_takes_the_closed_form_on_a_uniform_grid_and_scipys_elsewhere():
    """forward.motion.spline_antiderivative: a recorded cube's jittered pulse times go to scipy's
    spline; both evaluate alike (value and derivatives) where they overlap."""
    from fwdlook_cli.forward.motion import spline_antiderivative

    t, y = _history(200, seed=5)
    uniform = spline_antiderivative(t, y)
    assert isinstance(uniform, UniformSplineAntiderivative)
    jitter = t + np.random.default_rng(1).uniform(-0.05, 0.05, t.size) * (t[1] - t[0])
    other = spline_antiderivative(jitter, y)
    assert not isinstance(other, UniformSplineAntiderivative)
    want = CubicSpline(jitter, y).antiderivative()
    for nu in range(5):
        np.testing.assert_array_equal(other(jitter, nu), want(jitter, nu))
    for anti, knots in ((uniform, t), (other, jitter)):          # each interpolates the history at its knots
        np.testing.assert_allclose(anti(knots, 1), y, rtol=0, atol=1e-9 * np.abs(y).max())
