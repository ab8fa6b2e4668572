"""The tabulated compressed chirp against its closed form (two independent computations)."""
import numpy as np
import pytest

from fwdlook_cli.dsp.pulse import CompressedPulse, lfm_compressed_closed_form


def test_unweighted_table_matches_closed_form():
    p = CompressedPulse(50e6, 1e-6, 60e6)
    tau = np.linspace(-1.2e-6, 1.2e-6, 20001)
    err = np.abs(p(tau) - lfm_compressed_closed_form(tau, 50e6, 1e-6))
    assert err.max() < 2e-3
    assert abs(p(np.array([0.0]))[0] - 1.0) < 1e-4


def test_kernel_is_zero_beyond_the_pulse_width():
    p = CompressedPulse(20e6, 1e-6, 24e6, "hamming")
    assert p.support_s == pytest.approx(1e-6, rel=1e-3)
    assert np.all(p(np.array([-1.01e-6, 1.01e-6, 3e-6])) == 0)


def test_hamming_weighting_lowers_sidelobes_and_widens_mainlobe():
    plain, ham = CompressedPulse(50e6, 1e-6, 60e6), CompressedPulse(50e6, 1e-6, 60e6, "hamming")
    tau = np.linspace(0, 1e-6, 40001)
    a, b = np.abs(plain(tau)), np.abs(ham(tau)) / np.abs(ham(np.array([0.0])))[0]
    half = lambda x: tau[np.argmax(x < 10 ** (-3 / 20))]  # noqa: E731
    assert half(b) > 1.3 * half(a)
    # peak sidelobe: the unweighted sinc's first sidelobe (-13.3 dB) just beyond its first null at 1/B;
    # Hamming's lies below -35 dB beyond its wider main lobe (first null near 2/B)
    assert 20 * np.log10(a[tau > 1.0 / 50e6].max()) == pytest.approx(-13.26, abs=0.3)
    assert 20 * np.log10(b[tau > 2.1 / 50e6].max()) < -35.0
