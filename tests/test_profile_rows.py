"""The batched point-target measures (``dsp.profile_rows``) against the scalar code they replace in the
per-target metrics: ``dsp.profile.profile_metrics`` (its general path, complex input), ``dsp.peaks.
interpolate_peak`` and the one-target 3 dB width of ``tests/reference_metrics.py``, row by row, on
sinc main lobes, noise, quantised rows full of ties, peaks at either end, and the rows the scalar code
refuses (fewer than 3 samples, all zero, constant, not finite)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from fwdlook_cli.dsp.peaks import interpolate_peak
from fwdlook_cli.dsp.profile import profile_metrics
from fwdlook_cli.dsp.profile_rows import half_power_width_rows, peak3_rows, power_metrics_rows
from reference_metrics import _width


def _rows(seed, n_rows=400, width=41):
    """Power rows of varying valid length n (the rest filled with junk the batched code must not read)."""
    rng = np.random.default_rng(seed)
    out = np.full((n_rows, width), 7.0e9)
    n = rng.integers(1, width + 1, n_rows)
    for t in range(n_rows):
        m = int(n[t])
        x = np.arange(m) - rng.uniform(0, m)
        kind = t % 6
        if kind == 0:      # a sinc main lobe and sidelobes, a little noise
            row = np.sinc(x / rng.uniform(1.5, 6.0)) ** 2 + 1e-4 * rng.random(m)
        elif kind == 1:    # noise alone
            row = rng.exponential(size=m)
        elif kind == 2:    # quantised: ties everywhere
            row = np.round(4 * rng.random(m)) / 4
        elif kind == 3:    # monotone: the peak at an end, no null on one side
            row = np.exp(rng.choice([-1, 1]) * 0.3 * np.arange(m))
        elif kind == 4:    # a Gaussian peak with zeros around it (the linear fit where a sample is zero)
            row = np.where(np.abs(x) < 3, np.exp(-x**2), 0.0)
        else:              # the rows the scalar code refuses, or nearly
            row = rng.choice([np.zeros(m), np.full(m, 2.5), np.full(m, np.nan), rng.random(m)])
        out[t, :m] = row
    return out, n


def _same(a, b, rtol=1e-9):
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return a == pytest.approx(b, rel=rtol, abs=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_power_metrics_rows_equal_profile_metrics_row_by_row(seed):
    power, n = _rows(seed)
    amp = np.sqrt(power)
    pslr, islr, width = power_metrics_rows(amp * amp, n, 0.375)
    measured = 0
    for t in range(len(n)):
        try:        # the general path: complex input, the oversampling machinery with factor 1
            pm = profile_metrics(amp[t, :n[t]].astype(np.complex128), spacing=0.375, oversample=1)
            want = (pm.pslr_db, pm.islr_db, pm.width_3db)
        except ValueError:
            want = (math.nan,) * 3
        got = (float(pslr[t]), float(islr[t]), float(width[t]))
        assert all(_same(g, w) for g, w in zip(got, want)), (t, n[t], power[t, :n[t]], got, want)
        measured += not math.isnan(want[1])
    assert measured > 50            # the comparison covered measured rows, not only refused ones


@pytest.mark.parametrize("seed", [3, 4])
def test_peak3_and_width_rows_equal_the_scalar_fits(seed):
    power, n = _rows(seed)
    ok = np.array([np.isfinite(power[t, :n[t]]).all() and power[t, :n[t]].max() > 0 for t in range(len(n))])
    power, n = power[ok], n[ok]
    k = np.array([int(np.argmax(power[t, :n[t]])) for t in range(len(n))])
    frac, peak = peak3_rows(power, k, n)
    full = np.where(np.arange(power.shape[1])[None, :] < n[:, None], power, 0.0)
    width = half_power_width_rows(full, k, n, 0.5)
    for t in range(len(n)):
        f, p = interpolate_peak(power[t, :n[t]], int(k[t]))
        assert _same(float(frac[t]), f) and _same(float(peak[t]), p), (t, power[t, :n[t]])
        assert _same(float(width[t]), _width(power[t, :n[t]], int(k[t]), 0.5)), (t, power[t, :n[t]])


def test_power_metrics_rows_on_an_ideal_sinc():
    """A closed form: an unweighted sinc sampled 8 times per resolution cell over +-5 cells has its
    first sidelobe 13.26 dB down (to the sampling) and a 3 dB width of 0.886 cells."""
    x = np.arange(-40, 41) / 8.0
    power = np.sinc(x)[None, :] ** 2
    pslr, islr, width = power_metrics_rows(power, np.array([81]), 1.0 / 8)
    assert pslr[0] == pytest.approx(-13.26, abs=0.05)
    assert width[0] == pytest.approx(0.8859, abs=0.01)
    assert -11.5 < islr[0] < -9.5
