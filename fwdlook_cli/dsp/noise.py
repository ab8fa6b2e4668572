"""Receiver noise of the range-compressed cube, band-limited to the signal's bandwidth.

The echo of a point target is the compressed pulse, whose spectrum occupies |f| <= B/2 of the complex
sampling band fs (NOTES.md "Corrections": fs = 1.2 B in the paper scenarios).  Receiver noise after the
matched filter is confined to the same band, so it is generated here as circular complex white Gaussian
noise filtered in range frequency to |f_r| <= B/2 (an ideal low-pass on the FFT grid of each pulse) and
scaled so that its variance per range sample is exactly ``sigma^2``:

    n = IFFT( W(f_r) FFT(w) ) sqrt(N / N_B),      W = 1 for |f_r| <= B/2, 0 elsewhere,

with ``w`` white of variance sigma^2 per sample, N range samples and N_B of them in band.  Then every
range sample has E|n|^2 = sigma^2, and all of it lies in band: the per-sample SNR a^2 / sigma^2 is also
the in-band SNR (white noise over fs would put (fs - B)/fs of sigma^2 out of band, 0.8 dB at fs = 1.2 B,
and let it into the range oversampling).  Neighbouring samples are correlated (fs > B), as they are in a
real receiver.
"""
from __future__ import annotations

import numpy as np
import scipy.fft


def in_band_mask(n_range: int, fs_hz: float, bandwidth_hz: float) -> np.ndarray:
    """Range-frequency bins (FFT order) inside the signal band |f_r| <= B/2."""
    fr = scipy.fft.fftfreq(n_range, 1.0 / fs_hz)
    return np.abs(fr) <= 0.5 * min(bandwidth_hz, fs_hz) * (1.0 + 1e-12)


def band_limited_noise(rng: np.random.Generator, n_pulses: int, n_range: int, *, sigma: float, fs_hz: float,
                       bandwidth_hz: float) -> np.ndarray:
    """Circular complex Gaussian noise [n_pulses, n_range] (complex64), variance ``sigma^2`` per sample,
    its spectrum along range zero outside |f_r| <= B/2 (module docstring)."""
    white = rng.standard_normal((n_pulses, 2 * n_range), dtype=np.float32).view(np.complex64)
    mask = in_band_mask(n_range, fs_hz, bandwidth_hz)
    spec = scipy.fft.fft(white, axis=1, workers=-1)
    # E|w|^2 = 2 per sample (unit real and imaginary parts): scale to sigma^2 and restore the band's share
    gain = np.float32(sigma / np.sqrt(2.0) * np.sqrt(n_range / max(int(mask.sum()), 1)))
    spec *= (mask * gain).astype(np.float32)[None, :]
    return scipy.fft.ifft(spec, axis=1, workers=-1, overwrite_x=True).astype(np.complex64, copy=False)


NOISE_BLOCK_BYTES = 8 << 20     # white draws per block of pulses (:func:`add_band_limited_noise`)


def add_band_limited_noise(rng: np.random.Generator, echo, *, sigma: float, fs_hz: float, bandwidth_hz: float,
                           block_bytes: int = NOISE_BLOCK_BYTES) -> None:
    """``echo += band_limited_noise(rng, *echo.shape, ...)`` in blocks of pulses, in place: the same
    numbers bit for bit (the generator's draws are a sequence, each pulse is filtered on its own), with
    temporaries of ``block_bytes`` instead of three cube-sized arrays, and ``echo`` may be file-backed
    (``io.backing``: a cube larger than memory)."""
    n_pulses, n_range = echo.shape
    step = max(1, int(block_bytes) // (8 * max(1, n_range)))
    for p0 in range(0, n_pulses, step):
        p1 = min(n_pulses, p0 + step)
        echo[p0:p1] += band_limited_noise(rng, p1 - p0, n_range, sigma=sigma, fs_hz=fs_hz,
                                          bandwidth_hz=bandwidth_hz)
