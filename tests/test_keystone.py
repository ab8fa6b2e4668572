"""Tests for fwdlook_cli.keystone: closed forms, then agreement between implementations."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fwdlook_cli.dsp.keystone_czt import KeystonePlan
from fwdlook_cli.dsp.keystone import keystone, keystone_dft, keystone_sinc
from fwdlook_cli.dsp.keystone_common import keystone_positions

FC_HZ = 18e9  # the paper's Ku-band carrier


def err_db(y, ref):
    """Energy of the difference relative to the energy of `ref`, in dB."""
    y, ref = np.asarray(y, np.complex128), np.asarray(ref, np.complex128)
    return 10 * np.log10(max(np.sum(np.abs(y - ref) ** 2), 1e-300) / np.sum(np.abs(ref) ** 2))


def alphas(n_cols, fr_max_hz=30e6):
    """eq. (8) scale factors for range frequencies spanning +-fr_max_hz."""
    fr = np.linspace(-fr_max_hz, fr_max_hz, n_cols)
    return FC_HZ / (FC_HZ + fr)


def windowed_tone(t, n, nu, width=12.0):
    """Gaussian-windowed tone exp(j 2 pi nu t) centred on the sequence (vanishes at its ends)."""
    return np.exp(-0.5 * ((t - n / 2) / (n / width)) ** 2) * np.exp(2j * np.pi * nu * t)


def random_data(rng, n, c):
    return rng.standard_normal((n, c)) + 1j * rng.standard_normal((n, c))


# ------------------------------------------------------------------------ closed forms
def test_positions_closed_form():
    a = np.array([0.9, 1.0, 1.1])
    tau = keystone_positions(5, a, t0_index=[2.0, 0.5, -1.0])
    m = np.arange(5)[:, None]
    assert tau.shape == (5, 3)
    t0 = np.array([2.0, 0.5, -1.0])
    np.testing.assert_allclose(tau, a * (m - t0) + t0, rtol=0, atol=1e-15)
    # the origin is a fixed point of the time scaling
    np.testing.assert_allclose(keystone_positions(8, 1.2, t0_index=3.0)[3], 3.0, atol=1e-15)


@pytest.mark.parametrize("dtype, tol", [(np.complex64, 1e-5), (np.complex128, 1e-12)])
@pytest.mark.parametrize("n", [63, 64])
@pytest.mark.parametrize("t0", [0.0, 31.5, 7.3, -40.0])
@pytest.mark.parametrize("ambiguity", [0, 12])
def test_alpha_one_is_identity(dtype, tol, n, t0, ambiguity):
    # alpha = 1: tau = m' is an integer, the interpolant returns the samples, and
    # exp(j 2 pi F tau) = 1 (this is why eq. (22) as printed, exp(j 2 pi F m'), corrects nothing)
    x = random_data(np.random.default_rng(n), n, 6).astype(dtype)
    y = KeystonePlan(n, 1.0, t0_index=t0, dtype=dtype)(x, ambiguity=ambiguity)
    assert y.dtype == dtype and y.shape == x.shape
    assert np.linalg.norm(y - x) / np.linalg.norm(x) < tol


@pytest.mark.parametrize("n", [256, 255])
@pytest.mark.parametrize("t0", [0.0, 128.0, 100.25])
@pytest.mark.parametrize("nu", [12 - 0.39, 1 + 0.37, -7 + 0.05, 0.2])
def test_tone_at_true_frequency(n, t0, nu):
    # samples of a tone at F + f equal the baseband tone f; with the right F the keystone
    # returns the true tone at tau = alpha (m' - t0) + t0
    F = int(np.round(nu))
    a = alphas(5)
    m = np.arange(n, dtype=float)[:, None]
    x = windowed_tone(m, n, nu) * np.ones(a.size)
    tau = keystone_positions(n, a, t0)
    y = KeystonePlan(n, a, t0_index=t0, dtype=np.complex128)(x, ambiguity=F)
    inner = slice(n // 8, n - n // 8)
    assert err_db(y[inner], windowed_tone(tau, n, nu)[inner]) < -60


def test_wrong_ambiguity_misses_exactly_exp_j2pi_tau():
    # sign and origin check with F = 1: F = 0 leaves the baseband tone (exp(-j 2 pi tau)
    # too little), F = 2 adds exp(+j 2 pi tau); tau is counted with the time origin t0
    n, t0, f = 256, 90.5, 0.3
    a = alphas(4, fr_max_hz=300e6)  # large scaling so tau is far from m'
    m = np.arange(n, dtype=float)[:, None]
    x = windowed_tone(m, n, 1 + f) * np.ones(a.size)
    tau = keystone_positions(n, a, t0)
    truth = windowed_tone(tau, n, 1 + f)
    plan = KeystonePlan(n, a, t0_index=t0, dtype=np.complex128)
    y0, y1, y2 = (plan(x, ambiguity=F) for F in (0, 1, 2))
    inner = slice(n // 8, n - n // 8)
    assert err_db(y1[inner], truth[inner]) < -60
    assert err_db(y0[inner], (truth * np.exp(-2j * np.pi * tau))[inner]) < -60
    assert err_db(y2[inner], (truth * np.exp(2j * np.pi * tau))[inner]) < -60
    assert err_db(y0[inner], truth[inner]) > 0  # i.e. the wrong F really is wrong
    big = np.abs(y1) > 1e-3
    np.testing.assert_allclose((y2 / y1)[big], np.exp(2j * np.pi * tau)[big], atol=1e-9)


def test_zero_doppler_target_unchanged():
    # no range walk, no ambiguity: a constant slow-time signal is a fixed point
    n = 200
    a = alphas(7)
    rng = np.random.default_rng(3)
    x = np.ones((n, 1)) * (rng.standard_normal(7) + 1j * rng.standard_normal(7))
    for t0 in (0.0, n / 2):
        assert err_db(KeystonePlan(n, a, t0_index=t0)(x), x) < -60  # everywhere
        assert err_db(keystone_dft(x, a, t0_index=t0), x) < -60
        inner = slice(n // 8, n - n // 8)  # sinc sees zeros beyond the ends
        assert err_db(keystone_sinc(x, a, t0_index=t0)[inner], x[inner]) < -60


def test_decimated_subsequences_with_global_origin():
    # Sec. 3.2: sub-sequence q holds pulses q, q+Q, ...; with one global origin
    # (t0 = -q/Q in sub-sequence samples) the regrouped keystone output equals the
    # keystone of the full sequence: the true tone at alpha * (global pulse index)
    n, Q, nu = 512, 4, 3.05  # nu cycles/pulse; per sub-sequence Q*nu = 12.2, F = 12
    P = n // Q
    a = alphas(3)
    g = np.arange(n, dtype=float)[:, None]
    full = windowed_tone(g, n, nu) * np.ones(a.size)
    sub = full.reshape(P, Q, a.size)  # [p, q, col]: pulse p*Q + q
    tiled = sub.reshape(P, Q * a.size)  # columns (q, col)
    alpha_t = np.tile(a, Q)
    t0_t = np.repeat(-np.arange(Q) / Q, a.size)
    F_sub = int(np.round(Q * nu))
    y = KeystonePlan(P, alpha_t, t0_index=t0_t, dtype=np.complex128)(tiled, ambiguity=F_sub)
    regrouped = y.reshape(P, Q, a.size).reshape(n, a.size)
    truth = windowed_tone(a * g, n, nu)
    inner = slice(n // 8, n - n // 8)
    assert err_db(regrouped[inner], truth[inner]) < -60


# ------------------------------------------------------------------------ CZT vs DFT vs sinc
@pytest.mark.parametrize("n", [96, 97])
@pytest.mark.parametrize("t0", ["zero", "half", 33.7])
@pytest.mark.parametrize("ambiguity", [0, 12, "per-column"])
def test_czt_matches_dft(n, t0, ambiguity):
    c = 8
    rng = np.random.default_rng(n)
    x = random_data(rng, n, c)
    a = FC_HZ / (FC_HZ + rng.uniform(-30e6, 30e6, c))
    t0 = {"zero": 0.0, "half": n / 2}.get(t0, t0)
    F = np.arange(c) - 3 + 12 if ambiguity == "per-column" else ambiguity
    y = KeystonePlan(n, a, t0_index=t0, dtype=np.complex128)(x, ambiguity=F)
    ref = keystone_dft(x, a, t0_index=t0, ambiguity=F)
    assert err_db(y, ref) < -100
    y32 = KeystonePlan(n, a, t0_index=t0)(x.astype(np.complex64), ambiguity=F)
    assert y32.dtype == np.complex64
    assert err_db(y32, ref) < -100


@settings(max_examples=40, deadline=None)
@given(
    n=st.integers(1, 40),
    c=st.integers(1, 4),
    alpha=st.floats(0.8, 1.25),
    t0=st.floats(-50, 80),
    F=st.integers(-30, 30),
    seed=st.integers(0, 2**32 - 1),
)
def test_czt_matches_dft_property(n, c, alpha, t0, F, seed):
    rng = np.random.default_rng(seed)
    x = random_data(rng, n, c)
    a = alpha * (1 + 0.01 * rng.uniform(-1, 1, c))
    t0s = t0 + rng.uniform(-1, 1, c)
    y = KeystonePlan(n, a, t0_index=t0s, dtype=np.complex128)(x, ambiguity=F)
    assert err_db(y, keystone_dft(x, a, t0_index=t0s, ambiguity=F)) < -100


def test_plan_columns_are_independent_and_scalar_plans_broadcast():
    n, c = 50, 5
    rng = np.random.default_rng(7)
    x = random_data(rng, n, c)
    a, t0, F = alphas(c, 1e9), rng.uniform(0, n, c), np.arange(c)
    y = KeystonePlan(n, a, t0_index=t0, dtype=np.complex128)(x, ambiguity=F)
    for k in range(c):
        plan_k = KeystonePlan(n, a[k], t0_index=t0[k], dtype=np.complex128)
        yk = plan_k(x[:, k : k + 1], ambiguity=F[k])
        np.testing.assert_allclose(y[:, k : k + 1], yk, atol=1e-12)
    # a scalar-geometry plan applies to any number of columns, with per-column F
    plan = KeystonePlan(n, a[0], t0_index=t0[0], dtype=np.complex128)
    ref = np.column_stack([plan(x[:, k : k + 1], ambiguity=F[k])[:, 0] for k in range(c)])
    np.testing.assert_allclose(plan(x, ambiguity=F), ref, atol=1e-12)


def test_sinc_needs_demodulation_near_nyquist():
    # baseband Doppler near the Nyquist edge (F = 12, f = -0.48, as at the paper's
    # boresight): sinc interpolation works only after demodulating the true Doppler
    n, F, f = 512, 12, -0.48
    a = alphas(5)
    m = np.arange(n, dtype=float)[:, None]
    x = windowed_tone(m, n, F + f) * np.ones(a.size)
    for t0 in (0.0, n / 2 + 0.3):
        ref = KeystonePlan(n, a, t0_index=t0, dtype=np.complex128)(x, ambiguity=F)
        inner = slice(n // 8, n - n // 8)
        good = err_db(keystone_sinc(x, a, t0_index=t0, doppler_ref=a * (F + f))[inner], ref[inner])
        # demodulating only the ambiguity number leaves the signal at -0.48 cycles/pulse
        poor = err_db(keystone_sinc(x, a, t0_index=t0, doppler_ref=F)[inner], ref[inner])
        plain = err_db(keystone_sinc(x, a, t0_index=t0, doppler_ref=0.0)[inner], ref[inner])
        assert good < -20
        if t0 == 0.0:  # fractional shifts up to 0.43 samples: fails outright
            assert poor > -20
        assert poor > good + 30
        assert plain > good + 30


def test_sinc_reference_is_the_output_doppler():
    # doppler_ref is the true Doppler of the OUTPUT (alpha times the input Doppler);
    # with it the sinc keystone returns the true tone at tau, like the CZT with the right F
    n, nu, t0 = 256, 10.0 + 0.21, 128.0
    a = np.array([0.8, 0.9, 1.1, 1.25])  # strong scaling: alpha * nu differs from nu by cycles
    m = np.arange(n, dtype=float)[:, None]
    x = windowed_tone(m, n, nu) * np.ones(a.size)
    tau = keystone_positions(n, a, t0)
    inner = slice(n // 4, n - n // 4)
    y = keystone_sinc(x, a, t0_index=t0, doppler_ref=a * nu)
    assert err_db(y[inner], windowed_tone(tau, n, nu)[inner]) < -50


# ------------------------------------------------------------------------ convenience, validation
def test_keystone_convenience_matches_components():
    n, c = 64, 6
    rng = np.random.default_rng(11)
    x = random_data(rng, n, c)
    fr = np.linspace(-30e6, 30e6, c)
    a = FC_HZ / (FC_HZ + fr)
    kw = dict(ambiguity=12, t0_index=20.5)
    ref = keystone_dft(x, a, **kw)
    for method in ("czt", "dft"):
        y = keystone(x, fr, FC_HZ, method=method, dtype=np.complex128, **kw)
        assert y.dtype == np.complex128
        assert err_db(y, ref) < -100
    y = keystone(x, fr, FC_HZ, method="sinc", **kw)  # doppler_ref defaults to ambiguity
    assert y.dtype == np.complex64
    np.testing.assert_allclose(y, keystone_sinc(x, a, t0_index=20.5, doppler_ref=12), atol=1e-5)


@pytest.mark.parametrize("method", ["CZT", "bluestein", ""])
def test_bad_method_names_allowed_values(method):
    with pytest.raises(ValueError, match="czt.*dft.*sinc"):
        keystone(np.ones((8, 2)), 0.0, FC_HZ, method=method)


@pytest.mark.parametrize("shape", [(8,), (8, 2, 2), ()])
def test_x_must_be_2d(shape):
    x = np.ones(shape, complex)
    with pytest.raises(ValueError, match="2-D"):
        keystone(x, 0.0, FC_HZ)
    with pytest.raises(ValueError, match="2-D"):
        KeystonePlan(8, 1.0)(x)
    with pytest.raises(ValueError, match="2-D"):
        keystone_dft(x, 1.0)
    with pytest.raises(ValueError, match="2-D"):
        keystone_sinc(x, 1.0)


def test_other_validation():
    x = np.ones((8, 3), complex)
    with pytest.raises(ValueError, match="ambiguity"):
        KeystonePlan(8, 1.0)(x, ambiguity=0.5)
    with pytest.raises(ValueError, match="slow-time"):
        KeystonePlan(9, 1.0)(x)
    with pytest.raises(ValueError, match="columns"):
        KeystonePlan(8, [1.0, 1.0])(x)
    with pytest.raises(ValueError, match="alpha"):
        KeystonePlan(8, -1.0)
    with pytest.raises(ValueError, match="n_slow"):
        KeystonePlan(0, 1.0)
    with pytest.raises(ValueError, match="dtype"):
        KeystonePlan(8, 1.0, dtype=np.float64)
    with pytest.raises(ValueError, match="n_taps"):
        keystone_sinc(x, 1.0, n_taps=7)
    with pytest.raises(ValueError, match="fc_hz"):
        keystone(x, 0.0, -1.0)
    with pytest.raises(ValueError, match="fr_hz"):
        keystone(x, [-20e9, 0.0, 0.0], FC_HZ)
