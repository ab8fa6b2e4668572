"""A Kaiser-windowed FIR low-pass and its linear convolution by FFTs (the joint fit's slow-time
decimation, ``forward.dwell_fit_plan.decimation_plan``), without scipy.signal (its import alone is over a
second, paid by every run that fits)."""
from __future__ import annotations

import numpy as np
import scipy.fft


def kaiser_lowpass(n_taps, cutoff_hz, fs_hz, beta=8.0):
    """The windowed-sinc low-pass of ``n_taps`` (odd) taps cut at ``cutoff_hz``, a Kaiser (``beta``)
    window, unit gain at DC: scipy.signal.firwin(n_taps, cutoff, window=("kaiser", beta), fs=fs) (test),
    without importing scipy.signal (over a second, in every run that fits)."""
    m = np.arange(n_taps) - 0.5 * (n_taps - 1)
    c = 2.0 * cutoff_hz / fs_hz
    h = c * np.sinc(c * m) * np.kaiser(n_taps, beta)
    return h / np.sum(h)


def filter_same(x, taps):
    """Each row of ``x`` [B, n] convolved with ``taps`` (odd length), the central n samples: the
    ``mode="same"`` linear convolution, by FFTs of a length with no wrap-around (complex128)."""
    n, t = x.shape[1], len(taps)
    size = scipy.fft.next_fast_len(n + t - 1)
    spec = scipy.fft.fft(np.asarray(x, np.complex128), size, axis=1) * scipy.fft.fft(taps, size)[None, :]
    return scipy.fft.ifft(spec, axis=1, overwrite_x=True)[:, (t - 1) // 2:(t - 1) // 2 + n]
