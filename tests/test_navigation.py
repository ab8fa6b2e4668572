"""io/navigation.py's pieces against closed forms and brute force: the sliding excursion, the symmetric
smoothing, the positions' derivative, the fused track and the roughness estimate."""
import numpy as np
import pytest

from fwdlook_cli.io.navigation import (centred_mean, fused_track, largest_excursion, position_roughness_m,
                                       velocity_from_positions)


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


def test_the_smoothing_holds_at_the_tracks_ends():
    """Within a window of an end the smoothing is the least-squares line through the end's whole window
    (a window shrunk to one sample had left the derivative of 1 mm of position noise 6 m/s off at the last
    pulses, 0.17 m/s in the middle; a review): the ends' error within 3 times the middle's RMS, and the
    fused track's too."""
    t, p, v = _track(jitter=0.0)
    noisy = p + 0.001 * np.random.default_rng(4).standard_normal(p.shape)
    for got in (velocity_from_positions(t, noisy), fused_track(t, noisy, v)[1]):
        err = got - v
        middle = np.sqrt(np.mean(err[200:-200] ** 2))
        assert np.max(np.abs(np.concatenate([err[:5], err[-5:]]))) < 3 * 3 * middle, (middle, err[:5], err[-5:])


def _checked(t, p, v, scan, caplog, **kw):
    from fwdlook_cli.io.navigation import check_navigation

    caplog.clear()
    with caplog.at_level("WARNING"):
        out = check_navigation(t, p, v, scan_angle_deg=scan, beamwidth_deg=6.0, fc_hz=18e9, source="x", **kw)
    return out, [r.getMessage() for r in caplog.records]


def test_the_checks_see_along_track_below_a_steep_window_and_float32_noise(caplog):
    """Lines of sight at the far range's depression: a window whose middle range lies below the platform
    (2 km up, 768-3000 m) had turned them straight down, blind to an along-track bias of 0.2 m/s (the
    review read 0 rad); now b cos(phi_far) x span x dt.  A stepped scan's dwell is its mean step's, not the
    whole record.  Float32 positions kept as stored still have their roughness told (quadrature with the
    rounding's step / sqrt(12))."""
    t, p, v = _track(jitter=0.0)
    p = p + [0.0, 0.0, 1900.0]
    scan = np.linspace(-15.0, 15.0, len(t))
    out, said = _checked(t, p, v + [0.0, 0.2, 0.0], scan, caplog, range_m=np.array([768.0, 3000.0]))
    cos_far = np.cos(np.arcsin(np.median(p[:, 2]) / 3000.0))
    span = int(np.ceil(6.0 / (30.0 / (len(t) - 1))))
    assert out["dwell_pulses"] == span
    assert out["disagreement_m"] == pytest.approx(0.2 * cos_far * span / 2500.0, rel=1e-3)
    assert any("disagree:" in m for m in said)
    stepped = np.repeat(np.linspace(-15.0, 15.0, len(t) // 10), 10)           # ten pulses per position
    out, _ = _checked(t, p, v, stepped, caplog, range_m=np.array([768.0, 3000.0]))
    assert out["dwell_pulses"] == int(np.ceil(6.0 / (30.0 / (len(t) - 1))))
    noisy32 = (p + 0.001 * np.random.default_rng(5).standard_normal(p.shape)).astype(np.float32).astype(float)
    step = float(np.spacing(np.float32(np.max(np.abs(noisy32)))))
    out, said = _checked(t, noisy32, v, scan, caplog, range_m=np.array([768.0, 3000.0]), rounding_m=step)
    assert out["roughness_m"] == pytest.approx(0.001, rel=0.1) and any("position_m is rough" in m for m in said)


def test_the_chain_applies_the_navigation_once(monkeypatch):
    """build_forward_stages replaces the track once and plans on that track (the plan had applied
    `fused` a second time: 0.08 mm and 0.17 m/s off the stages' own track on 1 mm of noise, a review):
    the plan is given the cube the chain built, and a cube already given a mode comes back as it is."""
    from fwdlook_cli.forward import chain, plan
    from fwdlook_cli.forward.simulate import simulate_scenario
    from fwdlook_cli.io.navigation import with_navigation
    from fwdlook_cli.testing import tiny_scenario

    planned = []
    real = plan.plan_geometry
    monkeypatch.setattr(plan, "plan_geometry", lambda t, p, v, *a, **k: planned.append((p, v)) or real(t, p, v, *a, **k))
    scn = tiny_scenario()
    cube, _ = simulate_scenario(scn)
    cube.position_m = cube.position_m + 0.001 * np.random.default_rng(8).standard_normal(cube.position_m.shape)
    src, _, _ = chain.build_forward_stages(cube, dict(scn["processing"], imaging="cpi", navigation="fused"))
    once = with_navigation(cube, "fused")
    assert with_navigation(once, "fused") is once
    (p, v), = planned
    np.testing.assert_array_equal(p, once.position_m)
    np.testing.assert_array_equal(v, once.velocity_mps)
    np.testing.assert_array_equal(src["velocity_mps"], once.velocity_mps)


def test_the_roughness_is_exact_on_a_staggered_train_and_three_pulses_give_the_velocity():
    """Each divided difference over its own white-noise gain: on a train staggered 1 : 1.5 the noise of
    positions (third order) and velocities (second) reads within 5 % (a median interval's gain had read
    0.55 and 0.68 of it, a review); three pulses of a constant acceleration give its velocity exactly."""
    rng = np.random.default_rng(6)
    n = 16384
    t = np.concatenate([[0.0], np.cumsum(np.where(np.arange(n - 1) % 2 == 0, 1.0, 1.5))]) / 2500.0
    p = np.column_stack([0 * t, 240 * t + 25 * t**2, 0 * t])
    v = np.column_stack([0 * t, 240 + 50 * t, 0 * t])
    los = np.array([[0.0, 1.0, 0.0]])
    assert position_roughness_m(t, p + 0.001 * rng.standard_normal(p.shape), los) == pytest.approx(0.001, rel=0.05)
    from fwdlook_cli.io.navigation import roughness

    assert roughness(t, v + 0.05 * rng.standard_normal(v.shape), los, 2) == pytest.approx(0.05, rel=0.05)
    np.testing.assert_allclose(velocity_from_positions(t[:3], p[:3]), v[:3], rtol=0, atol=1e-9)


def test_the_lines_of_sight_stay_level_where_no_range_reaches_the_ground_and_float32_steps_are_per_axis(caplog):
    """A platform higher than the window's far range: no depression reaches the ground, and level lines
    of sight keep an along-track bias in view (clipped depressions had pointed them straight down: 2e-18 m
    read for 0.2 m/s).  Float32 positions kept as stored lose their own axis's rounding along each line
    of sight: an easting of 4e5 m (steps of 0.03 m) no longer hides 3 mm of noise along a northward track."""
    t, p, v = _track(jitter=0.0)
    scan = np.linspace(-15.0, 15.0, len(t))
    high = p + [0.0, 0.0, 2400.0]
    out, said = _checked(t, high, v + [0.0, 0.2, 0.0], scan, caplog, range_m=np.array([768.0, 2000.0]))
    span = out["dwell_pulses"]
    assert out["disagreement_m"] == pytest.approx(0.2 * span / 2500.0, rel=1e-3)
    east = p + [4e5, 0.0, 0.0] + 0.003 * np.random.default_rng(7).standard_normal(p.shape)
    stored = east.astype(np.float32)
    step = np.spacing(np.max(np.abs(stored), axis=0))
    from fwdlook_cli.io.navigation import kept_float32_step

    rounding = kept_float32_step(np.float32, stored.astype(np.float64), stored.astype(np.float64))
    np.testing.assert_array_equal(rounding, step)
    assert not kept_float32_step(np.float32, stored.astype(np.float64), east).any()      # restored: none
    out, said = _checked(t, stored.astype(np.float64), v, scan, caplog, range_m=np.array([1000.0, 1200.0]),
                         rounding_m=rounding)
    assert out["roughness_m"] == pytest.approx(0.003, rel=0.1)
