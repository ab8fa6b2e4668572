"""Receiver noise band-limited like the signal (issue 8, item 5; NOTES.md "Corrections").

The noise of a simulated cube is the cube minus the same scene simulated without noise (the simulator is
linear).  Its range spectrum must be zero outside |f_r| <= B/2, and its power per sample, all of it in
band, must be sigma^2 = a_max^2 / 10^(snr_db/10): the stated per-sample SNR is then the in-band SNR.
White noise over fs fails both: (fs - B)/fs of its power lies out of band (1/6 at fs = 1.2 B), and its
in-band SNR is 10 log10(fs/B) = 0.79 dB better than stated.
"""
from __future__ import annotations

import numpy as np
import pytest

from fwdlook_cli.isar.simulate import simulate_isar_scenario
from fwdlook_cli.scenario.loader import resolve_scenario
from fwdlook_cli.dsp.noise import band_limited_noise, in_band_mask
from fwdlook_cli.forward.simulate import simulate_scenario
from fwdlook_cli.testing import tiny_scenario
from fft_backend import assert_same_to_fft_rounding


def spectrum_split(noise, fs_hz, bandwidth_hz):
    """(in-band power per sample, out-of-band power per sample) from the range spectrum (Parseval)."""
    n_r = noise.shape[1]
    spec = np.abs(np.fft.fft(noise.astype(np.complex128), axis=1)) ** 2 / n_r**2    # per bin, per sample
    mask = in_band_mask(n_r, fs_hz, bandwidth_hz)
    per_pulse = spec.sum(axis=0) / noise.shape[0]
    return float(per_pulse[mask].sum()), float(per_pulse[~mask].sum())


def check(noise, sigma, fs_hz, bandwidth_hz):
    p_in, p_out = spectrum_split(noise, fs_hz, bandwidth_hz)
    n_in = int(in_band_mask(noise.shape[1], fs_hz, bandwidth_hz).sum())
    # the in-band power estimate has n_pulses x n_in independent complex bins: relative std 1/sqrt of that
    rel_std = 1.0 / np.sqrt(noise.shape[0] * n_in)
    snr_err_db = 10 * np.log10(sigma**2 / p_in)                 # measured in-band SNR minus the stated one
    assert abs(snr_err_db) <= 4 * 10 * np.log10(1 + rel_std), (snr_err_db, rel_std)
    assert p_out <= 1e-10 * p_in                                # nothing out of band (float32 rounding)
    # the per-sample power (the SNR definition) is the same number: all the noise is in band
    assert np.mean(np.abs(noise) ** 2) == pytest.approx(p_in, rel=1e-6)


def test_generator_band_limited_and_scaled():
    rng = np.random.default_rng(5)
    fs, b, sigma = 60e6, 50e6, 0.1
    n = band_limited_noise(rng, 500, 280, sigma=sigma, fs_hz=fs, bandwidth_hz=b)
    assert n.dtype == np.complex64 and n.shape == (500, 280)
    check(n, sigma, fs, b)
    # circular: real and imaginary parts carry half the power each, uncorrelated
    assert np.mean(n.real**2) == pytest.approx(np.mean(n.imag**2), rel=0.02)
    assert abs(np.mean(n.real * n.imag)) < 0.02 * sigma**2


def test_forward_cube_noise_in_band_at_the_stated_snr():
    scn = tiny_scenario(noise={"snr_db": 20.0, "seed": 4})
    quiet = tiny_scenario(noise={"snr_db": None})
    cube, _ = simulate_scenario(scn)
    clean, _ = simulate_scenario(quiet)
    sigma = cube.noise["sigma"]
    assert sigma == pytest.approx(0.1)                            # a_max = 1, 20 dB
    fs, b = scn["radar"]["fs_hz"], scn["radar"]["bandwidth_hz"]
    assert fs / b == pytest.approx(1.2)
    for ch in ("sum", "diff"):
        check(getattr(cube, ch).astype(np.complex128) - getattr(clean, ch), sigma, fs, b)


def test_isar_cube_noise_in_band_at_the_stated_snr():
    raw = {"name": "isar_noise", "kind": "isar",
           "radar": {"fc_hz": 3.0e9, "bandwidth_hz": 300.0e6, "fs_hz": 360.0e6, "pulse_width_s": 0.1e-6,
                     "prf_hz": 3000.0, "n_pulses": 2000},
           "target": {"range_m": 1100.0, "theta0_deg": 3.0, "velocity_mps": [0.0, 40.0, 0.0]},
           "noise": {"snr_db": 15.0, "seed": 2}}
    cube, _ = simulate_isar_scenario(resolve_scenario(raw, "<test>"))
    raw["noise"] = {"snr_db": None, "seed": 2}
    clean, _ = simulate_isar_scenario(resolve_scenario(raw, "<test>"))
    sigma = cube.noise["sigma"]
    assert sigma == pytest.approx(10 ** (-15 / 20))
    check(cube.sum.astype(np.complex128) - clean.sum, sigma, 360.0e6, 300.0e6)


@pytest.mark.parametrize("n_pulses,n_range,block_pulses", [(400, 280, 7), (333, 77, 1), (64, 4096, 5),
                                                             (50, 280, 1000)])
def test_noise_added_in_pulse_blocks_is_the_whole_draw_bit_for_bit(n_pulses, n_range, block_pulses):
    """``add_band_limited_noise`` adds the noise block by block of pulses (the simulator's, so that a cube
    larger than memory gets its noise without cube-sized temporaries): the generator's draws are one
    sequence and each pulse is filtered on its own, so any block size adds the same numbers as one
    draw of the whole, and leaves the generator where the whole draw leaves it (the difference channel
    draws next).  Bit for bit where scipy.fft computes each transform alone; with scipy 1.18's ducc,
    whose rounding depends on a row's place in its batch, to the rounding of the filter's two transforms
    (tests/fft_backend.py)."""
    from fwdlook_cli.dsp.noise import add_band_limited_noise

    fs, b, sigma = 60e6, 50e6, 0.3
    echo = np.random.default_rng(1).standard_normal((n_pulses, 2 * n_range)).astype(np.float32).view(np.complex64)
    whole, blocked = echo.copy(), echo.copy()
    rng_whole, rng_blocked = np.random.default_rng(9), np.random.default_rng(9)
    whole += band_limited_noise(rng_whole, n_pulses, n_range, sigma=sigma, fs_hz=fs, bandwidth_hz=b)
    add_band_limited_noise(rng_blocked, blocked, sigma=sigma, fs_hz=fs, bandwidth_hz=b,
                           block_bytes=8 * n_range * block_pulses)
    assert_same_to_fft_rounding(blocked, whole, n_range, n_range)
    assert rng_blocked.bit_generator.state == rng_whole.bit_generator.state
