"""Tests for fwdlook_cli.metrics: closed forms and physics oracles."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import quad
from scipy.signal import resample
from scipy.signal.windows import hamming

from fwdlook_cli.dsp.profile import ideal_sinc_islr_db, ideal_sinc_pslr_db, profile_metrics
from fwdlook_cli.dsp.peaks import image_peak_2d, interpolate_peak, oversample_profile, oversample_range

C_MPS = 299_792_458.0
B_HZ = 100e6  # pulse bandwidth
FS_HZ = 1.2 * B_HZ  # 1.2 samples per resolution cell
RES_M = C_MPS / (2 * B_HZ)  # range resolution cell, c / (2 B)
SPACING_M = C_MPS / (2 * FS_HZ)  # range sample spacing, c / (2 fs)
SAMPLES_PER_CELL = FS_HZ / B_HZ
SINC_WIDTH_CELLS = 0.885893  # half-power width of sinc(x)**2


def sinc_profile(offset, half_cells=40):
    """Ideal range profile sinc((r - r0) / res) sampled at c / (2 fs), +/- half_cells cells."""
    half = int(round(half_cells * SAMPLES_PER_CELL))
    k = np.arange(2 * half + 1)
    centre = half + offset
    return np.sinc((k - centre) / SAMPLES_PER_CELL), centre


def weighted_profile(weights, n_fft, centre):
    """Profile = inverse FFT of a weighted flat spectrum of len(weights) bins, peak at centre."""
    n_bins = len(weights)
    bins = np.arange(n_bins) - n_bins // 2  # signed frequency bins
    spectrum = np.zeros(n_fft, dtype=complex)
    spectrum[bins % n_fft] = weights * np.exp(-2j * np.pi * bins * centre / n_fft)
    return np.fft.ifft(spectrum) * n_fft / np.sum(weights)  # unit peak


# --- oversample_profile ---------------------------------------------------------------------

@pytest.mark.parametrize("n", [1, 2, 7, 8, 33])
@pytest.mark.parametrize("factor", [1, 3, 16])
def test_oversample_keeps_input_samples(n, factor):
    rng = np.random.default_rng(n * 100 + factor)
    x = rng.standard_normal(n) + 1j * rng.standard_normal(n)
    y = oversample_profile(x, factor)
    assert y.shape == (n * factor,)
    np.testing.assert_allclose(y[::factor], x, rtol=0, atol=1e-12)


@pytest.mark.parametrize("n", [31, 32])
def test_oversample_band_limited_sinusoid(n):
    factor = 8
    t = np.arange(n * factor) / factor  # positions in input samples
    # complex tone plus a real cosine, both periodic in n samples and inside the band
    tone = lambda s: np.exp(2j * np.pi * 5 * s / n) + 0.5 * np.cos(2 * np.pi * 11 * s / n + 0.3)
    y = oversample_profile(tone(np.arange(n)), factor)
    np.testing.assert_allclose(y, tone(t), rtol=0, atol=1e-12)


def test_oversample_even_nyquist_is_split():
    # (-1)**k has all its energy in the Nyquist bin; splitting it gives cos(pi t), real
    n, factor = 16, 4
    y = oversample_profile((-1.0) ** np.arange(n), factor)
    t = np.arange(n * factor) / factor
    np.testing.assert_allclose(y, np.cos(np.pi * t), rtol=0, atol=1e-12)


@pytest.mark.parametrize("n", [9, 10])
def test_oversample_matches_scipy_resample(n):
    rng = np.random.default_rng(n)
    x = rng.standard_normal(n) + 1j * rng.standard_normal(n)
    np.testing.assert_allclose(oversample_profile(x, 5), resample(x, 5 * n), rtol=0, atol=1e-12)


@pytest.mark.parametrize("factor", [0, -2, 2.0, True])
def test_oversample_rejects_bad_factor(factor):
    with pytest.raises(ValueError, match="factor"):
        oversample_profile(np.ones(4), factor)


def test_oversample_rejects_empty():
    with pytest.raises(ValueError, match="empty"):
        oversample_profile(np.array([]), 2)


# --- oversample_range: the fused form over rows (ducc0), against the two above ------------------

def _rows_by_profile(x, factor):
    """oversample_profile (numpy.fft, complex128) of every row: the independent reference."""
    flat = np.asarray(x, dtype=np.complex128).reshape(-1, x.shape[-1])
    return np.array([oversample_profile(row, factor) for row in flat]).reshape(x.shape[:-1] + (-1,))


@pytest.mark.parametrize("shape", [(7, 280), (3, 5, 33), (4, 1), (5, 2), (6, 64)])
@pytest.mark.parametrize("factor", [1, 2, 3, 4])
def test_fused_range_oversampling_is_the_zero_padded_spectrum(shape, factor):
    """dsp.peaks.oversample_range (one fused resampling per row) gives oversample_profile's numbers,
    the Nyquist bin of an even n split, to the float32 rounding of its complex64 input (a few eps32
    x log2 n relative to the peak), and scipy.signal.resample's; the native samples come back."""
    rng = np.random.default_rng(sum(shape) * 10 + factor)
    x = (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)).astype(np.complex64)
    y = oversample_range(x, factor)
    ref = _rows_by_profile(x, factor)
    assert y.dtype == np.complex64 and y.shape == shape[:-1] + (shape[-1] * factor,)
    assert np.max(np.abs(y - ref)) <= 2e-6 * np.max(np.abs(ref))
    np.testing.assert_allclose(resample(x.astype(np.complex128), shape[-1] * factor, axis=-1), ref,
                               rtol=0, atol=1e-12)
    np.testing.assert_allclose(y[..., ::factor], x, rtol=0, atol=2e-6 * np.max(np.abs(x)))


def test_fused_range_oversampling_of_real_double_strided_and_empty_rows():
    rng = np.random.default_rng(3)
    real = rng.standard_normal((3, 40)).astype(np.float32)
    y = oversample_range(real, 4)                              # complex64 out, imaginary part zero
    assert y.dtype == np.complex64 and np.max(np.abs(y.imag)) < 1e-6
    assert np.max(np.abs(y - _rows_by_profile(real, 4))) < 2e-6 * np.max(np.abs(real))
    double = rng.standard_normal((4, 30)) + 1j * rng.standard_normal((4, 30))
    np.testing.assert_allclose(oversample_range(double, 5), _rows_by_profile(double, 5), rtol=0, atol=1e-13)
    strided = (rng.standard_normal((6, 80)) + 1j * rng.standard_normal((6, 80))).astype(np.complex64)[::2, ::2]
    assert np.max(np.abs(oversample_range(strided, 4) - _rows_by_profile(strided, 4))) < 1e-5
    assert oversample_range(np.zeros((0, 16), np.complex64), 4).shape == (0, 64)
    swapped = strided.astype(strided.dtype.newbyteorder(">"))     # a big-endian file's array as read
    np.testing.assert_array_equal(oversample_range(swapped, 4), oversample_range(strided, 4))
    assert oversample_range(double, 1) is double                # factor 1: the input itself
    with pytest.raises(ValueError, match="factor"):
        oversample_range(double, 0)


# --- interpolate_peak / image_peak_2d --------------------------------------------------------

@pytest.mark.parametrize("vertex", [10.0, 10.2, 9.55, 10.4999])
def test_interpolate_peak_gaussian_exact(vertex):
    k = np.arange(21)
    power = 3.0 * np.exp(-((k - vertex) ** 2) / (2 * 1.7**2))
    index = int(np.argmax(power))
    frac, peak = interpolate_peak(power, index)
    assert abs(frac - vertex) < 1e-9
    assert abs(peak - 3.0) < 1e-9


def test_interpolate_peak_parabola_with_zero_neighbour():
    # a non-positive neighbour switches to the linear-power fit, exact for a parabola
    k = np.arange(5, dtype=float)
    power = 1.0 - (k - 2.3) ** 2  # negative at k = 1 (-0.69)
    frac, peak = interpolate_peak(power, 2)
    assert abs(frac - 2.3) < 1e-9
    assert abs(peak - 1.0) < 1e-9


@pytest.mark.parametrize("index", [0, 4])
def test_interpolate_peak_clamps_at_ends(index):
    power = np.array([5.0, 1.0, 0.5, 1.0, 6.0])
    assert interpolate_peak(power, index) == (float(index), power[index])


@pytest.mark.parametrize("index", [-1, 5, 1.0])
def test_interpolate_peak_rejects_bad_index(index):
    with pytest.raises(ValueError, match="index"):
        interpolate_peak(np.ones(5), index)


def test_image_peak_2d_separable_gaussian():
    i0, j0, amp = 7.31, 12.68, 2.5
    ii, jj = np.meshgrid(np.arange(16), np.arange(25), indexing="ij")
    img = amp * np.exp(-((ii - i0) ** 2) / (2 * 1.3**2) - ((jj - j0) ** 2) / (2 * 2.1**2))
    i, j = np.unravel_index(np.argmax(img), img.shape)
    fi, fj, peak = image_peak_2d(img, int(i), int(j))
    assert abs(fi - i0) < 1e-9
    assert abs(fj - j0) < 1e-9
    assert abs(peak - amp) < 1e-9


# --- closed forms ------------------------------------------------------------------------------

def test_ideal_sinc_pslr_against_dense_search():
    x = np.linspace(1.0, 2.0, 200_001)
    assert abs(ideal_sinc_pslr_db() - 20 * np.log10(np.abs(np.sinc(x)).max())) < 1e-6
    assert abs(ideal_sinc_pslr_db() - (-13.26)) < 0.005


@pytest.mark.parametrize("w_cells", [1.5, 2.0, 7.3, 32.0])
def test_ideal_sinc_islr_against_quadrature(w_cells):
    f = lambda x: np.sinc(x) ** 2
    main = 2 * quad(f, 0, 1)[0]
    side = 2 * quad(f, 1, w_cells, limit=400)[0]
    assert abs(ideal_sinc_islr_db(w_cells) - 10 * np.log10(side / main)) < 1e-6


def test_ideal_sinc_islr_infinite_window():
    main = 2 * quad(lambda x: np.sinc(x) ** 2, 0, 1)[0]
    assert abs(ideal_sinc_islr_db(math.inf) - 10 * np.log10((1 - main) / main)) < 1e-9
    assert abs(ideal_sinc_islr_db() - (-9.68)) < 0.005
    # the window matters at the 0.1 dB level: +/- 32 cells is 0.14 dB lower
    assert ideal_sinc_islr_db(32) < ideal_sinc_islr_db() - 0.1


@pytest.mark.parametrize("w_cells", [1.0, 0.5, -3.0, math.nan])
def test_ideal_sinc_islr_rejects_window_inside_main_lobe(w_cells):
    with pytest.raises(ValueError, match="half_window_cells"):
        ideal_sinc_islr_db(w_cells)


# --- profile_metrics on analytic profiles ------------------------------------------------------

def check_ideal_sinc(offset):
    profile, centre = sinc_profile(offset, half_cells=40)
    w_cells = 32.0
    m = profile_metrics(profile, spacing=SPACING_M, window_cells=w_cells * SAMPLES_PER_CELL)
    assert abs(m.peak_index - centre) < 0.01
    assert abs(m.peak_pos - centre * SPACING_M) < 0.01 * SPACING_M
    assert abs(m.peak_power - 1.0) < 1e-3
    assert abs(m.pslr_db - (-13.26)) < 0.1
    assert abs(m.islr_db - ideal_sinc_islr_db(w_cells)) < 0.1
    assert abs(m.width_3db / (SINC_WIDTH_CELLS * RES_M) - 1) < 0.01
    # main lobe between the first nulls at +/- 1 resolution cell
    assert abs(m.null_left_pos - (centre * SPACING_M - RES_M)) < 0.05 * RES_M
    assert abs(m.null_right_pos - (centre * SPACING_M + RES_M)) < 0.05 * RES_M


@pytest.mark.parametrize("offset", [0.0, 0.37, 0.5, -0.21])
def test_ideal_sinc_metrics(offset):
    check_ideal_sinc(offset)


@settings(max_examples=25, deadline=None)
@given(offset=st.floats(min_value=-0.5, max_value=0.5, allow_nan=False))
def test_ideal_sinc_metrics_any_offset(offset):
    check_ideal_sinc(offset)


def test_sidelobe_peak_is_interpolated():
    # the highest sidelobe is refined like the main peak: the oversampled grid alone
    # (1/19 cell) can miss it by up to 0.03 dB
    for offset in np.linspace(-0.5, 0.5, 11):
        profile, _ = sinc_profile(offset)
        m = profile_metrics(profile, spacing=SPACING_M, window_cells=32 * SAMPLES_PER_CELL)
        assert abs(m.pslr_db - ideal_sinc_pslr_db()) < 0.005


def test_ideal_sinc_whole_profile_window():
    # default window = whole profile, +/- 40 cells about the target
    profile, centre = sinc_profile(0.37, half_cells=40)
    m = profile_metrics(profile, spacing=SPACING_M)
    assert abs(m.islr_db - ideal_sinc_islr_db(40)) < 0.1
    assert m.window_left_pos == 0.0
    assert abs(m.window_right_pos - (profile.size - 1) * SPACING_M) < 1e-9


def test_islr_depends_on_window():
    profile, _ = sinc_profile(0.37, half_cells=40)
    narrow = profile_metrics(profile, spacing=SPACING_M, window_cells=4 * SAMPLES_PER_CELL)
    wide = profile_metrics(profile, spacing=SPACING_M, window_cells=32 * SAMPLES_PER_CELL)
    assert abs(narrow.islr_db - ideal_sinc_islr_db(4)) < 0.1
    assert narrow.islr_db < wide.islr_db - 0.5


@pytest.mark.parametrize("offset", [0.0, 0.37])
def test_hamming_weighted_sinc(offset):
    n_bins, n_fft = 200, 240  # 1.2 samples per resolution cell
    centre = n_fft / 2 + offset
    profile = weighted_profile(hamming(n_bins), n_fft, centre)
    m = profile_metrics(profile, spacing=SPACING_M)
    assert abs(m.peak_index - centre) < 0.01
    assert abs(m.pslr_db - (-42.7)) < 1.0
    assert abs(m.width_3db / (1.30 * RES_M) - 1) < 0.02
    unweighted = profile_metrics(weighted_profile(np.ones(n_bins), n_fft, centre), spacing=SPACING_M)
    assert m.width_3db > 1.4 * unweighted.width_3db


def test_smeared_profile_loses_peak_and_widens():
    profile, centre = sinc_profile(0.37, half_cells=40)
    focused = profile_metrics(profile, spacing=SPACING_M)
    k = np.arange(profile.size)
    shifts = np.linspace(-1.0, 1.0, 5) * SAMPLES_PER_CELL  # +/- 1 resolution cell of smear
    smeared_profile = sum(np.sinc((k - centre - s) / SAMPLES_PER_CELL) for s in shifts) / len(shifts)
    smeared = profile_metrics(smeared_profile, spacing=SPACING_M)
    # coherent sum at the centre: (1 + 2 sinc(0.5) + 2 sinc(1)) / 5, squared
    expected_peak = ((1 + 2 * np.sinc(0.5) + 2 * np.sinc(1.0)) / 5) ** 2
    assert abs(smeared.peak_power / expected_peak - 1) < 1e-3
    assert smeared.peak_power < 0.25 * focused.peak_power
    assert smeared.width_3db > 1.5 * focused.width_3db
    assert abs(smeared.peak_index - centre) < 0.01  # symmetric smear keeps the centre


def test_raised_cosine_width_closed_form_and_open_main_lobe():
    # power (1 + cos(2 pi (k - n/2) / n))**2 falls monotonically to the profile ends:
    # no null inside the window, so PSLR and ISLR are NaN; the half-power width is exact
    n = 32
    profile = 1 + np.cos(2 * np.pi * (np.arange(n) - n / 2) / n)
    m = profile_metrics(profile, spacing=0.5)
    expected = 2 * np.arccos(np.sqrt(2) - 1) / (2 * np.pi) * n * 0.5
    assert abs(m.width_3db - expected) < 1e-3 * expected
    assert math.isnan(m.pslr_db) and math.isnan(m.islr_db)
    assert math.isnan(m.null_left_pos) and math.isnan(m.null_right_pos)
    assert abs(m.peak_pos - n / 2 * 0.5) < 1e-9


def test_window_inside_main_lobe_gives_nan():
    profile, _ = sinc_profile(0.37)
    m = profile_metrics(profile, spacing=SPACING_M, window_cells=0.5)
    assert math.isnan(m.pslr_db) and math.isnan(m.islr_db) and math.isnan(m.width_3db)
    assert abs(m.peak_power - 1.0) < 1e-3


def test_as_dict_keys_and_real_input_equals_complex():
    profile, _ = sinc_profile(0.37)
    d = profile_metrics(profile, spacing=SPACING_M).as_dict()
    assert set(d) == {
        "peak_index", "peak_pos", "peak_power", "width_3db", "pslr_db", "islr_db",
        "null_left_pos", "null_right_pos", "window_left_pos", "window_right_pos",
        "spacing", "oversample",
    }
    # a constant phase does not change any metric
    d2 = profile_metrics(profile * np.exp(1j * 0.7), spacing=SPACING_M).as_dict()
    for key in d:
        assert d2[key] == pytest.approx(d[key], rel=1e-9, abs=1e-12)


# --- bad input -------------------------------------------------------------------------------

@pytest.mark.parametrize(
    "profile, match",
    [
        (np.array([]), "at least 3"),
        (np.zeros(16), "all zero"),
        (np.zeros(16, dtype=complex), "all zero"),
        (np.full(16, 2.0 - 1.0j), "constant power"),
        (np.array([0.0, 1.0, np.nan, 0.0]), "finite"),
        (np.ones((4, 4)), "1-D"),
    ],
)
def test_profile_metrics_rejects_bad_profile(profile, match):
    with pytest.raises(ValueError, match=match):
        profile_metrics(profile, spacing=1.0)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"spacing": 0.0}, "spacing"),
        ({"spacing": -1.0}, "spacing"),
        ({"spacing": 1.0, "window_cells": 0.0}, "window_cells"),
        ({"spacing": 1.0, "oversample": 0}, "factor"),
    ],
)
def test_profile_metrics_rejects_bad_parameters(kwargs, match):
    profile, _ = sinc_profile(0.0, half_cells=8)
    with pytest.raises(ValueError, match=match):
        profile_metrics(profile, **kwargs)


def test_real_profile_fast_path_equals_the_general_path():
    """``profile_metrics`` of a real float64 profile at ``oversample=1`` (the per-target metrics' call)
    takes a list-based path; it gives the general path's numbers to the bit (the general path is
    the one a complex profile with zero imaginary part takes: the same power)."""
    import dataclasses

    from fwdlook_cli.dsp.profile import _real_profile_metrics

    rng = np.random.default_rng(8)
    cases = [np.abs(np.sinc(np.linspace(-5, 5, 41) - rng.uniform(-0.5, 0.5))) + rng.uniform(0, 0.05)
             for _ in range(60)]
    cases += [rng.random(rng.integers(3, 60)) for _ in range(60)]            # rough, plateaus, edges
    cases += [np.array([0.0, 1.0, 0.0]), np.array([1.0, 2.0, 3.0]), np.array([3.0, 2.0, 1.0, 2.0, 3.0]),
              np.array([1.0, 1.0, 2.0, 2.0, 1.0, 1.0])]
    for x in cases:
        fast = _real_profile_metrics(x, 0.25)
        general = profile_metrics(x.astype(np.complex128), spacing=0.25, oversample=1)
        dispatched = profile_metrics(x, spacing=0.25, oversample=1)          # the dispatch takes it
        for f in dataclasses.fields(fast):
            a, b, c = getattr(fast, f.name), getattr(general, f.name), getattr(dispatched, f.name)
            # field by field: a NaN equals no NaN (Python 3.13's dataclass __eq__ compares fields so,
            # where 3.12's compared tuples, whose identity check let one NaN object equal itself)
            assert (a == b == c) or (np.isnan(a) and np.isnan(b) and np.isnan(c)), (f.name, a, b, c, x)
    for bad, msg in ((np.zeros(5), "all zero"), (np.ones(5), "constant"), (np.array([1.0, np.nan, 1.0]), "finite")):
        with pytest.raises(ValueError, match=msg):
            profile_metrics(bad, spacing=1.0, oversample=1)


def test_peak_power_is_the_strongest_pixel_of_the_points_cell():
    """A projected image's cells are sparse: a point split over two adjacent rows and angle bins, A =
    (r0, a0) and B = (r0 + 1, a0 + 1), with a third pixel in row r0, puts the range cut's peak on row r0
    and the angle cut's on column a0 + 1, where the image holds nothing.  ``peak_power`` is the strongest
    pixel within the cuts' strips around the refined peak (B), not that empty pixel (it read 0)."""
    from fwdlook_cli.forward.evaluate import target_metrics

    range_m = 990.0 + 1.25 * np.arange(17)
    angle_deg = np.round(4.0 + 0.05 * np.arange(21), 10)
    image = np.zeros((17, 21), np.float32)
    r0, a0 = 8, 10
    image[r0, a0], image[r0 + 1, a0 + 1], image[r0, a0 + 3] = 100.0, 110.0, 30.0
    az = np.radians(angle_deg[a0] + 0.025)
    truth = np.array([[range_m[r0] * np.sin(az), range_m[r0] * np.cos(az), 0.0]])
    row, = target_metrics(image, range_m, angle_deg, truth, np.ones(1), np.zeros(3), bandwidth_hz=50e6)
    assert row["peak_power"] == 110.0
