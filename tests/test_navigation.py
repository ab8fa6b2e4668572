"""io/navigation.py's pieces against closed forms and brute force: the sliding excursion, the symmetric
smoothing, the positions' derivative, the fused track and the roughness estimate."""
import numpy as np
import pytest

from fwdlook_cli.io.navigation import (centred_mean, fused_track, largest_excursion, position_roughness_m,
                                       velocity_from_positions, velocity_integral_m)


def test_the_largest_excursion_is_the_brute_force_one():
    rng = np.random.default_rng(1)
    for n in (1, 2, 5, 17, 100, 1000):
        x = rng.standard_normal(n)
        for width in {1, 2, 3, 7, 16, 33, n}:
            if width <= n:
                brute = max(np.ptp(x[i:i + width]) for i in range(n - width + 1))
                assert largest_excursion(x, width) == pytest.approx(brute, abs=1e-12), (n, width)


def _track(n=3000, prf=2500.0, jitter=0.005, seed=0):
    """A constant-acceleration track on pulse times jittered by 0.5 % of the interval."""
    rng = np.random.default_rng(seed)
    t = (np.arange(n) + jitter * rng.uniform(-1, 1, n)) / prf
    v0, a = np.array([3.0, 240.0, -1.0]), np.array([0.5, 50.0, 0.2])
    return t, 100.0 + v0 * t[:, None] + 0.5 * a * t[:, None] ** 2, v0 + a * t[:, None]


def test_smoothing_and_the_derivative_keep_a_constant_acceleration_exactly():
    """A symmetric window keeps a linear function of the pulse index (to rounding), at the ends too; the
    positions' derivative, averaged, is the velocity of a constant acceleration on a uniform train, and
    on one jittered by 0.5 % within the acceleration times the pulse's and the window's jitter (2 a dt x 0.005)."""
    t, p, v = _track(jitter=0.0)
    line = 3.0 + 2.0 * np.arange(len(t))
    np.testing.assert_allclose(centred_mean(line, 25), line, rtol=0, atol=1e-9)
    np.testing.assert_allclose(velocity_from_positions(t, p), v, rtol=0, atol=1e-7)
    t, p, v = _track()
    np.testing.assert_allclose(velocity_from_positions(t, p), v, rtol=0, atol=2 * 50.0 * 0.005 / 2500.0)


def test_the_fused_track_takes_a_velocity_bias_off_and_smooths_position_noise():
    """Velocities biased by b and positions with white noise sigma: the fused velocities are the true
    ones to well under b (the bias is a linear drift of the positions against the velocities' integral,
    kept by the low-pass), the fused positions' noise well under sigma; exact inputs come out unchanged
    (a uniform pulse train: the low-pass averages by pulse)."""
    t, p, v = _track(jitter=0.0)
    fp, fv = fused_track(t, p, v)
    np.testing.assert_allclose(fv, v, rtol=0, atol=1e-6)
    np.testing.assert_allclose(fp - fp[0], p - p[0], rtol=0, atol=1e-6)
    bias = np.array([0.0, 0.2, 0.05])
    fp, fv = fused_track(t, p, v + bias)                            # the bias alone: taken off exactly
    np.testing.assert_allclose(fv, v, rtol=0, atol=1e-6)
    sigma = 0.002
    fp, fv = fused_track(t, p + sigma * np.random.default_rng(2).standard_normal(p.shape), v + bias)
    inner = slice(200, -200)                                         # (the low-pass's ends see half a window)
    # white noise through two boxcars of 25 ms: the derivative's RMS under sigma / 25 ms / 4 (one boxcar's
    # sigma / 25 ms, the second's averaging), and no bias left beyond that over the record
    err = (fv - v)[inner]
    assert np.sqrt(np.mean(err**2)) < sigma / 0.025 / 4 and np.max(np.abs(np.mean(err, axis=0))) < 0.005
    assert np.std((fp - p)[inner] - np.mean((fp - p)[inner], axis=0)) < 0.25 * sigma


def test_the_roughness_estimate_is_the_noise_sigma_and_ignores_sparse_kinks():
    """Third differences of white noise have 20 times its variance: the MAD estimate is sigma within 5 %
    on 3000 pulses; positions interpolated linearly from a 50 Hz solution (a kink every 50 pulses) read
    as smooth (under 1 % of the kinks' step)."""
    t, p, v = _track()
    los = np.array([[0.0, 1.0, 0.0]])
    noisy = p + 0.003 * np.random.default_rng(3).standard_normal(p.shape)
    assert position_roughness_m(t, noisy, los) == pytest.approx(0.003, rel=0.05)
    assert position_roughness_m(t, p, los) < 1e-9                   # jittered times, a smooth track: none
    knots = np.arange(t[0], t[-1] + 0.02, 0.02)
    kinked = np.stack([np.interp(t, knots, np.interp(knots, t, p[:, i])) for i in range(3)], axis=-1)
    sag_m = 50.0 * 0.02**2 / 8                                      # a chord's sag over a 20 ms interval, a T^2 / 8
    assert position_roughness_m(t, kinked, los) < 0.01 * sag_m
    assert velocity_integral_m(t, v).shape == p.shape
