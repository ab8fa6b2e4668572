"""What this scipy.fft promises about its rounding, for the tests that compare a blocked computation with
the whole one (out of core, pulse blocks, column blocks, thread pools).

scipy up to 1.17 transforms with pocketfft, which computes each 1-D transform of a batch alone: the same
numbers whatever the batch, its blocks or the worker count, so those tests ask for equality bit for bit.
scipy 1.18 transforms with ducc, which computes a batch's complex64 transforms several at a time in SIMD
lanes (four on this project's machine) and the batch's remainder one at a time, and the two paths
round differently for many lengths (1024, 3000, 4096 and 5000 here, not 256, 280, 2500 or 8192): a
row's float32 result then depends on its place in the batch, so on the block sizes and the worker
count.  There the tests ask for what the FFT's rounding allows instead (:func:`fft_rounding_bound`).
"""
from __future__ import annotations

import functools

import numpy as np
import scipy.fft

EPS32 = float(np.finfo(np.float32).eps)


@functools.lru_cache(maxsize=1)
def batch_invariant() -> bool:
    """True where this scipy.fft computes each complex64 transform the same alone, in any batch and on
    any number of workers (probed on lengths that ducc's two paths round differently)."""
    rng = np.random.default_rng(0)
    for n in (1024, 3000, 4096):
        x = (rng.standard_normal((7, n)) + 1j * rng.standard_normal((7, n))).astype(np.complex64)
        batch = scipy.fft.fft(x, axis=1, workers=1)
        alone = np.stack([scipy.fft.fft(row, workers=1) for row in x])
        if not (np.array_equal(batch, alone) and np.array_equal(batch, scipy.fft.fft(x, axis=1, workers=2))):
            return False
    return True


def fft_rounding_bound(*lengths: int) -> float:
    """Relative RMS difference allowed between two float32 computations of the same chain of transforms
    of these lengths that differ only in rounding order: each radix pass rounds once (eps / 2 each way,
    eps for the two computations together), log2(n) passes per transform, plus one rounding for the
    element-wise product after each.  The errors adding in phase, the worst case of that model (the
    form of Higham's bound for the FFT, Accuracy and Stability of Numerical Algorithms, ch. 24); random
    ones add as the square root of the passes: the blocked keystones and noise of these tests differ
    by 0.01-0.07 of it under scipy 1.18."""
    return EPS32 * sum(np.log2(n) + 1.0 for n in lengths)


def assert_same_to_fft_rounding(actual, desired, *lengths: int, err_msg: str = "") -> None:
    """Bit for bit where :func:`batch_invariant`; otherwise the same shape and dtype and a relative RMS
    difference within :func:`fft_rounding_bound` of ``lengths`` (the transforms the path goes through)."""
    actual, desired = np.asarray(actual), np.asarray(desired)
    if batch_invariant():
        np.testing.assert_array_equal(actual, desired, err_msg=err_msg)
        return
    assert actual.shape == desired.shape and actual.dtype == desired.dtype, err_msg
    if not np.issubdtype(desired.dtype, np.inexact):
        np.testing.assert_array_equal(actual, desired, err_msg=err_msg)
        return
    a, d = actual.astype(np.complex128), desired.astype(np.complex128)
    scale = np.sqrt(np.mean(np.abs(d) ** 2)) if d.size else 0.0
    rms = np.sqrt(np.mean(np.abs(a - d) ** 2)) if d.size else 0.0
    assert rms <= fft_rounding_bound(*lengths) * scale, f"{err_msg}: RMS {rms:.3g} of {scale:.3g}"


def assert_targets_same_to_rounding(actual: list, desired: list, *, rel: float = 1e-5) -> None:
    """metrics.json's targets, equal where :func:`batch_invariant`; otherwise the same keys, the same
    flags, counts and ids, and every float within ``rel`` of its value (or ``rel`` in its unit near
    zero: metres, degrees, dB): a hundred times float32 rounding, 1e-5 of the paper radar's 2.5 m range
    cell.  The blocked chains of these tests differ by at most 3e-7 m and 2e-9 deg under scipy 1.18."""
    if batch_invariant():
        assert actual == desired
        return
    assert len(actual) == len(desired)
    for a, d in zip(actual, desired):
        assert a.keys() == d.keys()
        for key, value in d.items():
            if isinstance(value, float):
                assert abs(a[key] - value) <= rel * max(1.0, abs(value)), (d.get("id"), key, a[key], value)
            else:
                assert a[key] == value, (d.get("id"), key, a[key], value)
