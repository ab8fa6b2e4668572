"""Issue 11: the fast paths give the results of the straightforward ones; stage views, --keep-stages,
and the bench's measuring tools.

Each fast path is checked against an independent straightforward implementation written here (the
formulas of the chain before issue 11): the shared-chirp tracking keystone against demodulate /
concatenate / keystone / remodulate with the spline evaluated at every resampled time; the cell
selection against full 4x oversampling of every row with the same floor; the single-thread Doppler
products against ``np.matmul``.
"""
from __future__ import annotations

import dataclasses
import json
import os

import h5py
import numpy as np
import pytest
import scipy.fft

from fwdlook_cli.cli import main
from fwdlook_cli.dsp.blas import batched_matmul, batched_matmul_each
from fwdlook_cli.dsp.imaging import (azimuth_at_t_ref_cells, float32_floor, kept_cells, median_floor, oversample_profiles,
                                     power_f32)
from fwdlook_cli.dsp.keystone import keystone_dft
from fwdlook_cli.dsp.keystone_common import OuterPhasors, _cis, cis_outer
from fwdlook_cli.dsp.keystone_czt import KeystonePlan
from fwdlook_cli.dsp.geometry import azimuth_at_t_ref
from fwdlook_cli.dsp.peaks import oversample_range
from fwdlook_cli.forward.keystone_fast import keystone_both
from fwdlook_cli.forward.motion import DopplerPhaseHistory
from fwdlook_cli.report.benchtools import fit_exponent, nlogn_exponent, peak_rss_bytes, reset_peak_rss
from fft_backend import assert_same_to_fft_rounding


def rel_db(a, b):
    return 10 * np.log10(np.sum(np.abs(a - b) ** 2) / np.sum(np.abs(b) ** 2))


# ----------------------------------------------------------------------------------------------
# tracking keystone: chirps once, both channels
# ----------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def tracking_case():
    rng = np.random.default_rng(3)
    p, n_f, prf, fc = 512, 24, 2500.0, 18e9
    t = np.arange(p) / prf
    vel = np.column_stack([np.zeros(p), 240.0 + 50.0 * t, np.zeros(p)])
    beam = -15.0 + 30.0 * t / t[-1]
    fr = scipy.fft.fftfreq(n_f, 1 / 60e6)
    hist = DopplerPhaseHistory(t, vel, beam, 1.7, fc, t[p // 2])
    xs = (rng.standard_normal((p, n_f)) + 1j * rng.standard_normal((p, n_f))).astype(np.complex64)
    xd = (rng.standard_normal((p, n_f)) + 1j * rng.standard_normal((p, n_f))).astype(np.complex64)
    return dict(p=p, fr=fr, fc=fc, prf=prf, t=t, hist=hist, xs=xs, xd=xd, alpha=fc / (fc + fr),
                t0=np.full(n_f, p / 2.0), scale=1.0 + fr / fc)


def reference_tracking(c, implementation):
    """The pre-issue-11 formula: both channels side by side, every phase from the spline itself."""
    x = np.concatenate([c["xs"], c["xd"]], axis=1)
    alpha2, t02, scale2 = (np.tile(v, 2) for v in (c["alpha"], c["t0"], c["scale"]))
    x = x * _cis(-c["hist"].phase_rad(c["t"])[:, None] * scale2[None, :] / (2 * np.pi), np.complex128)
    if implementation == "czt":
        y = KeystonePlan(c["p"], alpha2, t0_index=t02, dtype=np.complex128)(x, ambiguity=0)
    else:
        y = keystone_dft(x, alpha2, t0_index=t02, ambiguity=0)
    tau = alpha2[None, :] * (np.arange(c["p"])[:, None] - t02[None, :]) + t02[None, :]
    y = y * _cis(c["hist"].phase_rad(c["t"][0] + tau / c["prf"]) * scale2 / (2 * np.pi), np.complex128)
    n = c["xs"].shape[1]
    return y[:, :n], y[:, n:]


@pytest.mark.parametrize("origins", ["one", "per_column"])
@pytest.mark.parametrize("implementation", ["czt", "dft"])
def test_shared_chirp_tracking_keystone_matches_the_direct_formula(tracking_case, implementation, origins):
    """One time origin (the chain's q = 1: the remodulation phase as one matrix product) and a time
    origin per column (the element-wise Taylor form) against the spline evaluated directly."""
    c = dict(tracking_case)
    if origins == "per_column":
        c["t0"] = c["t0"] + np.linspace(-3.0, 3.0, c["t0"].size)
    ys, yd = keystone_both(c["xs"], c["xd"], alpha=c["alpha"], t0_index=c["t0"], implementation=implementation,
                           ambiguity=0, tracking=(c["hist"], c["t"], c["prf"], c["scale"]))
    rs, rd = reference_tracking(c, implementation)
    # complex64 output against a complex128 reference: float32 rounding only (-100 dB: CZT vs DFT bar)
    assert rel_db(ys, rs) < -100 and rel_db(yd, rd) < -100
    assert ys.dtype == np.complex64


@pytest.mark.parametrize("min_columns", [1, 8])
@pytest.mark.parametrize("threads", ["1", "3"])
@pytest.mark.parametrize("tracking", [False, True])
def test_keystone_column_blocks_change_nothing(tracking_case, tracking, threads, min_columns, monkeypatch):
    """One column per block (or the default floor of a cache line's eight), on one thread or on a pool
    of three (where the cores allow), gives the whole-block keystone bit for bit (to the CZT's three
    transforms' rounding with scipy 1.18's ducc, whose rounding depends on a column's place in its
    batch: tests/fft_backend.py)."""
    monkeypatch.setenv("FWDLOOK_THREADS", threads)
    c = tracking_case
    trk = (c["hist"], c["t"], c["prf"], c["scale"]) if tracking else None
    kw = dict(alpha=c["alpha"], t0_index=c["t0"], implementation="czt", ambiguity=0 if tracking else 3,
              tracking=trk)
    whole = keystone_both(c["xs"], c["xd"], block_bytes=1 << 30, **kw)
    tiny = keystone_both(c["xs"], c["xd"], block_bytes=1, min_columns=min_columns, **kw)   # the narrowest
    n_czt = scipy.fft.next_fast_len(2 * c["p"] - 1)
    for a, b in zip(whole, tiny):
        assert_same_to_fft_rounding(b, a, n_czt, n_czt, n_czt)


@pytest.mark.parametrize("block_bytes", [1, 1 << 16, 1 << 30])
def test_decimated_blocks_by_range_frequency_change_nothing(tracking_case, block_bytes):
    """The decimated layout (three sub-sequences of 24 range frequencies, each its own time origin)
    in blocks of range frequencies across the sub-sequences (``period``) gives the column blocks'
    keystone bit for bit."""
    c = tracking_case
    q, n_f = 3, c["fr"].size
    rng = np.random.default_rng(8)
    xs, xd = ((rng.standard_normal((170, q * n_f)) + 1j * rng.standard_normal((170, q * n_f))).astype(np.complex64)
              for _ in range(2))
    kw = dict(alpha=np.tile(c["alpha"], q), t0_index=np.repeat([40.2, 39.9, 39.5], n_f), implementation="czt",
              ambiguity=2)
    plain = keystone_both(xs, xd, block_bytes=block_bytes, **kw)
    grouped = keystone_both(xs, xd, block_bytes=block_bytes, period=n_f, **kw)
    for a, b in zip(plain, grouped):
        np.testing.assert_array_equal(a, b)


def test_a_plan_told_its_period_is_the_plan_that_finds_the_alphas_itself(tracking_case):
    """``KeystonePlan(period=...)``: the per-alpha filter and chirp broadcast over the groups instead of
    gathered to every column give the same output bit for bit (scalar and per-column ambiguity); a
    period the alphas do not have, or that does not divide the columns, is not taken."""
    c = tracking_case
    q, n_f = 4, c["fr"].size
    rng = np.random.default_rng(9)
    x = (rng.standard_normal((90, q * n_f)) + 1j * rng.standard_normal((90, q * n_f))).astype(np.complex64)
    alpha, t0 = np.tile(c["alpha"], q), np.repeat([45.3, 44.8, 44.1, 43.9], n_f)
    plain = KeystonePlan(90, alpha, t0_index=t0)
    grouped = KeystonePlan(90, alpha, t0_index=t0, period=n_f)
    assert grouped._period == n_f and plain._period is None
    for ambiguity in (0, 3, rng.integers(-2, 3, q * n_f)):
        np.testing.assert_array_equal(grouped(x, ambiguity=ambiguity), plain(x, ambiguity=ambiguity))
    bent = alpha.copy()
    bent[n_f + 1] *= 1 + 1e-12                     # one column off the period: the plan finds the alphas
    assert KeystonePlan(90, bent, t0_index=t0, period=n_f)._period is None
    assert KeystonePlan(90, alpha, t0_index=t0, period=n_f + 1)._period is None
    np.testing.assert_array_equal(KeystonePlan(90, bent, t0_index=t0, period=n_f)(x, ambiguity=3),
                                  KeystonePlan(90, bent, t0_index=t0)(x, ambiguity=3))


def test_a_plan_applied_to_strided_views_writes_what_the_gathered_columns_give(tracking_case):
    """``KeystonePlan.apply`` on a [p, groups, width] strided view of a wider array, into a strided
    view of the output, gives the gathered 2-D columns' keystone bit for bit and leaves every other
    column of the output untouched."""
    c = tracking_case
    q, n_f = 3, c["fr"].size
    rng = np.random.default_rng(10)
    wide = (rng.standard_normal((64, q, n_f)) + 1j * rng.standard_normal((64, q, n_f))).astype(np.complex64)
    k = slice(5, 17)
    view = wide[:, :, k]
    gathered = np.ascontiguousarray(view).reshape(64, -1)
    alpha = np.tile(c["alpha"][k], q)
    t0 = np.repeat([30.2, 29.9, 29.5], k.stop - k.start)
    plan = KeystonePlan(64, alpha, t0_index=t0, period=k.stop - k.start)
    out = np.full(wide.shape, 7 + 7j, np.complex64)
    assert np.shares_memory(plan.apply(view, ambiguity=2, out=out[:, :, k]), out)     # written in place
    np.testing.assert_array_equal(out[:, :, k].reshape(64, -1), plan(gathered, ambiguity=2))
    flat = np.empty_like(gathered)                          # a 2-D output for the grouped plan: the same
    assert plan.apply(gathered, ambiguity=2, out=flat) is flat
    np.testing.assert_array_equal(flat, plan(gathered, ambiguity=2))
    untouched = np.ones(n_f, bool)
    untouched[k] = False
    assert np.all(out[:, :, untouched] == 7 + 7j)
    with pytest.raises(ValueError, match="out has shape"):
        plan.apply(view, ambiguity=2, out=out)


def test_taylor_history_equals_the_spline_at_the_resampled_times(tracking_case):
    from fwdlook_cli.forward.keystone_fast import history_phase_shifted, history_taylor

    c = tracking_case
    derivs = history_taylor(c["hist"], c["t"])
    dt = np.subtract.outer(np.arange(c["p"], dtype=float), c["t0"]) * ((c["alpha"] - 1) / c["prf"])
    exact = c["hist"].phase_rad(c["t"][:, None] + dt)
    # a piecewise quartic's own Taylor series: only rounding of phases up to ~1e3 rad remains
    assert np.max(np.abs(history_phase_shifted(derivs, dt) - exact)) < 1e-8


def test_remodulation_phase_as_one_matrix_product_equals_the_spline(tracking_case):
    """The tracking keystone's remodulation phase (cycles) as one [pulses, 6] x [6, columns] product
    (Taylor terms and the CZT's output chirp as outer products) against the spline itself evaluated at
    the resampled times, plus the plan's own output chirp: within 1e-10 cycles at phases of 3e3 cycles
    (only rounding; the quartic piece is its own Taylor series)."""
    from fwdlook_cli.forward.keystone_fast import history_taylor, remodulation_cycles

    c = tracking_case
    plan = KeystonePlan(c["p"], c["alpha"], t0_index=c["t0"])
    derivs = history_taylor(c["hist"], c["t"])
    got = remodulation_cycles(derivs, c["t0"][0], c["alpha"], c["scale"], c["prf"], *plan.post_cycles_f0_factors())
    dt = np.subtract.outer(np.arange(c["p"], dtype=float), c["t0"]) * ((c["alpha"] - 1) / c["prf"])
    exact = c["hist"].phase_rad(c["t"][:, None] + dt) * c["scale"] / (2 * np.pi) + plan.post_cycles_f0()
    assert np.max(np.abs(exact)) > 100.0
    assert np.max(np.abs(got - exact)) < 1e-10
    rows, cols = plan.post_cycles_f0_factors()
    np.testing.assert_array_equal(np.outer(rows, cols), plan.post_cycles_f0())


@pytest.mark.parametrize("order", ["fft", "shuffled", "off_grid", "short"])
def test_outer_phasors_equal_the_direct_exponential(order):
    """exp(j rate f) from two tables on the frequency grid (fftfreq order: a rotation; shuffled: a
    gather) or, off any grid, directly: within 4e-7 of the complex128 exponential, phases to 60 rad
    (each table phasor within 1.7e-7: its phase rounded to float32 at up to pi, 1.2e-7 rad, and its
    cosine and sine; the complex64 product rounds once more, 6e-8)."""
    rng = np.random.default_rng(11)
    n = {"short": 12}.get(order, 280)
    fr = scipy.fft.fftfreq(n, 1.0 / 20e6)
    if order == "shuffled":
        fr = rng.permutation(fr)
    elif order == "off_grid":
        fr = fr + rng.uniform(-0.3, 0.3, n) * 20e6 / n
    rate = 2.0 * np.pi * rng.uniform(-1e-6, 1e-6, 300)
    h = cis_outer(rate, fr)
    assert h.dtype == np.complex64 and h.shape == (300, n)
    assert np.max(np.abs(h - np.exp(1j * np.multiply.outer(rate, fr)))) < 4e-7


def test_outer_phasor_tables_give_every_column_block_the_same_numbers():
    """The tables built once for the whole axis: any block of columns (a slice or indices) gathers the
    whole's phasors bit for bit, each within 4e-7 of the exponential."""
    rng = np.random.default_rng(12)
    fr = scipy.fft.fftfreq(300, 1.0 / 20e6)
    rate = 2.0 * np.pi * rng.uniform(-1e-6, 1e-6, 200)
    tables = OuterPhasors(rate, fr)
    whole = tables.columns(slice(None))
    assert np.max(np.abs(whole - np.exp(1j * np.multiply.outer(rate, fr)))) < 4e-7
    blocks = np.concatenate([tables.columns(slice(lo, lo + 7)) for lo in range(0, 300, 7)], axis=1)
    np.testing.assert_array_equal(blocks, whole)
    picked = rng.permutation(300)[:40]
    np.testing.assert_array_equal(tables.columns(picked), whole[:, picked])


# ----------------------------------------------------------------------------------------------
# monopulse cells: rows oversampled only where a cell can pass, floor on the native samples
# ----------------------------------------------------------------------------------------------
def reference_cells(sum_z, diff_z, floor, factor, threshold_db, dynamic_range_db, max_ratio):
    # every row oversampled by numpy's FFTs in complex128 (dsp.imaging.oversample_profiles), the
    # selection in float32 as the stage's: an implementation that shares none of the stage's transforms
    s, d = (oversample_profiles(z.reshape(-1, z.shape[-1]), factor).reshape(z.shape[:-1] + (-1,))
            for z in (sum_z, diff_z))
    power = (s.real**2 + s.imag**2).astype(np.float32)
    ratio = (d.real * s.real + d.imag * s.imag) / np.maximum(power, 1e-30)
    peak = power.reshape(power.shape[0], -1).max(axis=1)
    level = np.maximum(floor * 10 ** (threshold_db / 10), peak * 10 ** (-dynamic_range_db / 10))
    keep = (power > level[:, None, None]) & (np.abs(ratio) < max_ratio)
    i_cpi, _, i_r = np.nonzero(keep)
    return i_cpi, i_r, ratio[keep], power[keep], power


@pytest.fixture(scope="module")
def spectra():
    """Noise plus point targets (band-limited in range: a sinc of the native sampling)."""
    rng = np.random.default_rng(5)
    n_cpi, n_dop, n_r = 6, 16, 64
    z = (rng.standard_normal((2, n_cpi, n_dop, n_r)) + 1j * rng.standard_normal((2, n_cpi, n_dop, n_r))) * 0.1
    r = np.arange(n_r)
    for cpi in range(n_cpi):
        for _ in range(3):
            dop, r0, a = rng.integers(n_dop), rng.uniform(10, 54), rng.uniform(3, 30)
            echo = a * np.sinc(r - r0)
            z[0, cpi, dop] += echo
            z[1, cpi, dop] += echo * rng.uniform(-0.5, 0.5)
    return z[0].astype(np.complex64), z[1].astype(np.complex64)


def test_a_float32_power_against_the_rounded_down_level_is_the_float64_test():
    """p > L (float64) and p > float32_floor(L) select the same float32 cells, at and around L."""
    rng = np.random.default_rng(6)
    level = rng.uniform(0.5, 2.0, 500) * 10.0 ** rng.integers(-5, 6, 500)
    f = level.astype(np.float32)
    near = np.concatenate([f, np.nextafter(f, np.float32(np.inf)), np.nextafter(f, np.float32(-np.inf))])
    p = np.concatenate([near, rng.uniform(0, 4, 3000).astype(np.float32) * f.max()]).astype(np.float32)
    floor32 = float32_floor(level)
    assert floor32.dtype == np.float32 and np.all(floor32.astype(np.float64) <= level)
    np.testing.assert_array_equal(p[None, :] > floor32[:, None], p[None, :] > level[:, None])


@pytest.mark.parametrize("block_cells", [1 << 20, 1])
def test_kept_cells_equal_full_oversampling(spectra, block_cells):
    s, d = spectra
    args = dict(range_oversample=4, threshold_db=12.0, dynamic_range_db=60.0, max_ratio=0.4)
    i_cpi, i_r, ratio, power, p0 = kept_cells(s, d, block_cells=block_cells, **args)
    floor = median_floor(power_f32(s), s.shape[1] * s.shape[2])
    r_cpi, r_r, r_ratio, r_power, _ = reference_cells(s, d, floor, 4, 12.0, 60.0, 0.4)
    assert len(i_cpi) > 50
    np.testing.assert_array_equal(i_cpi, r_cpi)
    np.testing.assert_array_equal(i_r, r_r)
    np.testing.assert_allclose(power, r_power, rtol=1e-5)
    np.testing.assert_allclose(ratio, r_ratio, rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(p0, np.abs(s) ** 2, rtol=1e-5)


def test_native_floor_is_the_oversampled_median_within_its_statistical_error():
    # pure noise: the median of |n|^2 is sigma^2 ln 2 for both; 1/(ln 2 sqrt(N)) relative std. error
    rng = np.random.default_rng(11)
    n_cpi, n_dop, n_r = 40, 32, 128
    z = ((rng.standard_normal((n_cpi, n_dop, n_r)) + 1j * rng.standard_normal((n_cpi, n_dop, n_r)))
         / np.sqrt(2)).astype(np.complex64)
    native = median_floor(power_f32(z), n_dop * n_r)
    over = oversample_range(z, 4)
    full = np.median((np.abs(over) ** 2).reshape(n_cpi, -1), axis=1)
    assert np.allclose(native, np.median(np.abs(z.reshape(n_cpi, -1)) ** 2, axis=1), rtol=1e-6)
    err = 1.0 / (np.log(2) * np.sqrt(n_dop * n_r))
    rel = native / full - 1
    assert np.sqrt(np.mean(rel**2)) < 2 * err                  # same quantity, sampling error only
    assert abs(np.mean(rel)) < 3 * err / np.sqrt(n_cpi) + 2e-3


def test_cell_geometry_matches_the_general_form():
    rng = np.random.default_rng(2)
    n = 1000
    pos = np.column_stack([rng.uniform(-5, 5, n), rng.uniform(0, 200, n), np.full(n, 50.0)])
    p_ref = np.array([0.0, 100.0, 50.0])
    rng_m, az = rng.uniform(1500, 1900, n), rng.uniform(-20, 20, n)
    fast = azimuth_at_t_ref_cells(rng_m, az, pos, p_ref)
    slow = azimuth_at_t_ref(rng_m, az, pos, p_ref)
    for a, b in zip(fast, slow):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)
    # the grouped form (one position per CPI, cells indexing it): the same numbers
    groups = pos[:40]
    index = rng.integers(0, 40, n)
    grouped = azimuth_at_t_ref_cells(rng_m, az, groups, p_ref, index=index)
    for a, b in zip(grouped, azimuth_at_t_ref(rng_m, az, groups[index], p_ref)):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)


def test_single_thread_batched_products_equal_matmul():
    rng = np.random.default_rng(4)
    e = (rng.standard_normal((7, 16, 8)) + 1j * rng.standard_normal((7, 16, 8))).astype(np.complex64)
    x = (rng.standard_normal((7, 8, 33)) + 1j * rng.standard_normal((7, 8, 33))).astype(np.complex64)
    np.testing.assert_array_equal(batched_matmul(e, x), np.matmul(e, x))


@pytest.mark.parametrize("threads", ["1", "2"])
def test_side_by_side_products_equal_each_product(monkeypatch, threads):
    """The Doppler zoom's channels on threads: each product the same call, so bit for bit, in order."""
    monkeypatch.setenv("FWDLOOK_THREADS", threads)
    rng = np.random.default_rng(5)
    e = (rng.standard_normal((9, 16, 8)) + 1j * rng.standard_normal((9, 16, 8))).astype(np.complex64)
    xs = [(rng.standard_normal((9, 8, 40)) + 1j * rng.standard_normal((9, 8, 40))).astype(np.complex64)
          for _ in range(3)]
    got = batched_matmul_each(e, xs)
    assert len(got) == 3
    for g, x in zip(got, xs):
        np.testing.assert_array_equal(g, np.matmul(e, x))


# ----------------------------------------------------------------------------------------------
# stage views and --keep-stages
# ----------------------------------------------------------------------------------------------
def _run(argv):
    with pytest.raises(SystemExit) as info:
        main([str(a) for a in argv])
    assert info.value.code == 0


def test_relayout_stages_are_views_of_the_previous_file(tiny_raw, tmp_path):
    run_dir = tmp_path / "run"
    _run(["process", tiny_raw, "-o", run_dir, "-q"])
    st = run_dir / "stages"
    for view, source in (("02_decimate.h5", "01_range_fft.h5"), ("04_regroup.h5", "03_keystone.h5")):
        with h5py.File(st / view) as f, h5py.File(st / source) as g:
            assert f.attrs["view_source"] == source
            assert f.attrs["view_source_sha256"] == g.attrs["config_sha256"]
            for ch in ("sum_f", "diff_f"):
                assert f[ch].is_virtual
                np.testing.assert_array_equal(f[ch][()].reshape(-1), g[ch][()].reshape(-1))
        # a view is a few kB of mappings, not a second copy of the cube
        assert (st / view).stat().st_size < 0.2 * (st / source).stat().st_size


def test_a_view_whose_source_changed_is_not_trusted(tiny_raw, tmp_path, capsys):
    from fwdlook_cli.io.stageview import view_file_key

    run_dir = tmp_path / "run"
    _run(["process", tiny_raw, "-o", run_dir, "-q"])
    st = run_dir / "stages"
    assert view_file_key(st / "02_decimate.h5") is not None
    with h5py.File(st / "01_range_fft.h5", "r+") as f:           # the source now claims another key
        f.attrs["config_sha256"] = "0" * 64
    assert view_file_key(st / "02_decimate.h5") is None
    capsys.readouterr()
    _run(["process", tiny_raw, "-o", run_dir])
    err = capsys.readouterr().err
    assert "[1/7] range_fft" in err and "[2/7] decimate" in err     # recomputed from the start
    assert view_file_key(st / "02_decimate.h5") is not None


@pytest.mark.parametrize("keep, files", [
    ("last", ["06_doppler_spectra.h5", "07_monopulse_image.h5"]),
    ("none", []),
])
def test_keep_stages_writes_less_and_gives_the_same_metrics(tiny_raw, tmp_path, capsys, keep, files):
    full, lean = tmp_path / "all", tmp_path / keep
    _run(["process", tiny_raw, "-o", full, "-q"])
    _run(["process", tiny_raw, "-o", lean, "-q", "--keep-stages", keep])
    assert sorted(p.name for p in (lean / "stages").glob("*.h5")) == files
    a, b = (json.loads((d / "metrics.json").read_text()) for d in (full, lean))
    # with `all` the image stage reads the spectra block by block from 06_doppler_spectra.h5, with
    # `none` from memory: the same targets to the last digit
    assert a["targets"] == b["targets"] and a["stage_sha256"] == b["stage_sha256"]
    # resume: with `last`, the same settings reuse everything; a new threshold reruns the image only
    capsys.readouterr()
    _run(["process", tiny_raw, "-o", lean, "--keep-stages", keep])
    err = capsys.readouterr().err
    if keep == "last":
        assert "up to date" in err
        _run(["process", tiny_raw, "-o", lean, "--keep-stages", keep, "--set", "processing.threshold_db=14"])
        err = capsys.readouterr().err
        assert "[7/7] monopulse_image" in err and "[6/7]" not in err
    else:
        assert "[1/7] range_fft" in err


def test_keep_stages_last_under_dwell_imaging_keeps_what_its_profile_metrics_read(tiny_raw, tmp_path, capsys):
    """Dwell imaging: the profile metrics compute CPI spectra from stage 5's output, so `last` keeps that
    file beside the image's; the same metrics as `all`, and a new threshold reruns the image stage only."""
    dwell = ["--set", "processing.method=tracking", "--set", "processing.imaging=dwell"]
    full, lean = tmp_path / "all", tmp_path / "last"
    _run(["process", tiny_raw, "-o", full, "-q", *dwell])
    _run(["process", tiny_raw, "-o", lean, "-q", "--keep-stages", "last", *dwell])
    assert sorted(p.name for p in (lean / "stages").glob("*.h5")) == ["05_range_curvature.h5", "06_dwell_image.h5"]
    a, b = (json.loads((d / "metrics.json").read_text()) for d in (full, lean))
    assert a["targets"] == b["targets"] and a["summary"]["islr_from"] == "dwell_profile"
    capsys.readouterr()
    _run(["process", tiny_raw, "-o", lean, "--keep-stages", "last", *dwell, "--set", "processing.threshold_db=14"])
    err = capsys.readouterr().err
    assert "[6/6] dwell_image" in err and "[5/6]" not in err
    c = json.loads((lean / "metrics.json").read_text())
    assert [t["islr_db"] for t in c["targets"]] == [t["islr_db"] for t in a["targets"]]


@pytest.mark.parametrize("before", ["all", "last"])
def test_keep_stages_none_over_an_earlier_runs_stage_files(tiny_raw, tmp_path, capsys, before):
    """A folder whose earlier run kept its stage files, rerun with `--keep-stages none` (an independent
    review): the rerun had reused those files, removed them as its policy keeps none, and then read the
    Doppler spectra from the removed file for the CPI profile metrics (a traceback, and the earlier run's
    outputs gone). `none` computes everything: the same metrics as a fresh run, and no stage file left."""
    run_dir, fresh = tmp_path / "run", tmp_path / "fresh"
    _run(["process", tiny_raw, "-o", run_dir, "-q", "--keep-stages", before])
    assert (run_dir / "stages" / "06_doppler_spectra.h5").exists()
    capsys.readouterr()
    _run(["process", tiny_raw, "-o", run_dir, "--keep-stages", "none"])
    assert "[1/7] range_fft" in capsys.readouterr().err
    _run(["process", tiny_raw, "-o", fresh, "-q", "--keep-stages", "none"])
    a, b = (json.loads((d / "metrics.json").read_text()) for d in (run_dir, fresh))
    assert a["targets"] == b["targets"] and a["stage_sha256"] == b["stage_sha256"]
    assert list((run_dir / "stages").glob("*.h5")) == [] and (run_dir / "image.h5").is_file()


# ----------------------------------------------------------------------------------------------
# bench tools
# ----------------------------------------------------------------------------------------------
def test_exponent_fit_and_the_nlogn_bar():
    n = np.array([1250, 2500, 5000, 10000, 20000], float)
    assert fit_exponent(n, 3e-7 * n**1.5) == pytest.approx(1.5, abs=1e-9)
    bar = nlogn_exponent(n)
    assert 1.0 < bar < 1.15                         # N log N looks like N^1.1 over a decade
    assert fit_exponent(n, n * np.log(n)) == pytest.approx(bar)


def test_peak_rss_sees_a_temporary_allocation():
    from fwdlook_cli.report.benchtools import _status_kib

    if reset_peak_rss() is None:
        pytest.skip("no /proc/self/clear_refs here")
    # fresh pages from an anonymous mapping, touched and unmapped: an array from the allocator may be
    # served from freed heap pages still resident (what earlier tests released), which the RSS already
    # counts, and so read back no peak (seen about once in ten suite runs, and three times in a row in
    # one run of a subset, 2026-12-02); the reader is what is under test, not the allocator
    import mmap

    seen = []
    for _ in range(3):
        reset_peak_rss()
        before = _status_kib("VmRSS") * 1024
        block = mmap.mmap(-1, 64 * 2**20)
        np.frombuffer(block, np.uint8)[::4096] = 1   # one byte a page: 64 MiB resident
        block.close()
        seen.append(peak_rss_bytes() - before)
        if seen[-1] >= 60 * 2**20:
            break
    assert max(seen) >= 60 * 2**20, seen


def test_the_scaling_series_fits_the_chains_with_and_without_stage_files_apart(monkeypatch):
    """``fwdlook bench --scaling`` times every point twice, as ``process`` runs it and with
    ``--keep-stages none``, and fits each set of wall times on its own: chains whose stage grows as
    N^1.5 with its files and as N without give those exponents (least squares in log-log is exact
    for a power law), and the user-CPU fit its own N^0.5."""
    from pathlib import Path

    from fwdlook_cli.report import benchtools
    from fwdlook_cli.scenario.loader import load_scenario

    calls = []

    def fake_time_chain(cube, scn, repeats=3, rss=True, keep_stages="all"):
        n = float(cube.sum.shape[0] * cube.sum.shape[1])      # the series' size: pulses or range bins
        calls.append(keep_stages)
        power = 1.5 if keep_stages == "all" else 1.0
        stage = {"doppler_spectra": 1e-9 * n ** power, "range_fft": 1e-8 * n}
        return {"stages_s": stage, "total_s": sum(stage.values()), "stages_user_cpu_s": {
                    "doppler_spectra": 1e-5 * n ** 0.5, "range_fft": 1e-8 * n},
                "user_cpu_s": 1.0, "stages_system_cpu_s": stage, "system_cpu_s": 1e-3}

    monkeypatch.setattr(benchtools, "time_chain", fake_time_chain)
    paper = load_scenario(Path(__file__).resolve().parents[1] / "scenarios" / "paper_fig6_a50.yaml")
    result = benchtools.scaling_series(paper, methods=("tracking",), pulses=(1250, 5000), range_bins=(128, 256))
    assert calls == ["all", "none"] * 4
    for key in ("pulses_tracking", "range_bins_tracking"):
        assert abs(result["exponents"][key]["doppler_spectra"] - 1.5) < 1e-9
        assert abs(result["exponents_keep_none"][key]["doppler_spectra"] - 1.0) < 1e-9
        assert abs(result["exponents_user_cpu"][key]["doppler_spectra"] - 0.5) < 1e-9
        assert abs(result["exponents_keep_none"][key]["range_fft"] - 1.0) < 1e-9
    calls.clear()
    alone = benchtools.scaling_series(paper, methods=("tracking",), pulses=(1250, 5000), range_bins=(128, 256),
                                      keep_none=False)
    assert calls == ["all"] * 4 and alone["exponents_keep_none"] == {}


def test_the_bench_says_whether_fwdlooks_modules_were_compiled(tmp_path):
    """``environment()["fwdlook_bytecode"]``: none of the loaded modules compiled where no bytecode is cached
    and none may be written (``PYTHONDONTWRITEBYTECODE``, as this project's sandboxes set it), all of them once
    ``python -m compileall`` (``make bytecode``) has written it (into a cache prefix of the test's own here)."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1", PYTHONPYCACHEPREFIX=str(tmp_path / "pycache"))
    probe = ("import fwdlook_cli.cli; from fwdlook_cli.report.benchtools import environment; "
             "print(environment()['fwdlook_bytecode'])")

    def reported():
        out = subprocess.run([sys.executable, "-c", probe], env=env, cwd=root, capture_output=True, text=True,
                             check=True).stdout.split()
        return int(out[0]), int(out[2])

    cached, loaded = reported()
    assert cached == 0 and loaded > 5
    subprocess.run([sys.executable, "-m", "compileall", "-q", str(root / "fwdlook_cli")], env=env, check=True,
                   capture_output=True)
    assert reported() == (loaded, loaded)


def test_scaling_scenario_has_the_requested_shape():
    from fwdlook_cli.forward.simulate import simulate_scenario
    from fwdlook_cli.report.benchtools import scaling_scenario
    from fwdlook_cli.scenario.loader import load_scenario
    from pathlib import Path

    paper = load_scenario(Path(__file__).resolve().parents[1] / "scenarios" / "paper_fig6_a50.yaml")
    cube, _ = simulate_scenario(scaling_scenario(paper, 250, 256))
    assert cube.sum.shape == (250, 256)
    assert cube.radar["prf_hz"] == pytest.approx(250.0)        # the same 1 s scan at a tenth of the PRF


def test_chain_timing_reports_every_stage_and_the_peak_rss(tiny_raw):
    from fwdlook_cli.io.raw import read_raw
    from fwdlook_cli.report.benchtools import time_chain
    from fwdlook_cli.testing import tiny_scenario

    cube = read_raw(tiny_raw)
    t = time_chain(cube, tiny_scenario(), repeats=1)
    assert list(t["stages_s"]) == ["range_fft", "decimate", "keystone", "regroup", "range_curvature",
                                   "doppler_spectra", "monopulse_image", "outputs"]
    assert t["total_s"] >= sum(t["stages_s"].values()) * 0.99
    assert "cores_busy" in t                                   # its clock: test_process_cpu_time_counts_busy_threads
    if t["user_cpu_s"] is not None:                            # its split: test_process_cpu_split_tells_...
        assert t["cores_busy"] * t["wall_s"] == pytest.approx(t["user_cpu_s"] + t["system_cpu_s"], rel=1e-9)
        assert t["user_cpu_s"] > 0 and t["system_cpu_s"] >= 0
        # per stage (the scaling series' user-CPU fits): every stage and the outputs, each stage's span
        # inside the chain's, so with one repeat their CPU sums to at most the chain's
        assert list(t["stages_user_cpu_s"]) == list(t["stages_s"]) == list(t["stages_system_cpu_s"])
        assert sum(t["stages_user_cpu_s"].values()) <= t["user_cpu_s"] + 1e-6
        assert sum(t["stages_system_cpu_s"].values()) <= t["system_cpu_s"] + 1e-6
        # the stage-file writer thread's own CPU (Linux) is part of the process's over the same run
        # (Linux splits each task's exact runtime into user and system by its tick samples, so one thread's
        # split may pass the whole process's by a few microseconds, as a clean checkout's CI run once saw:
        # 3.487 against 3.481 ms of system time; their sums are exact runtimes, and the thread's is within)
        if t["stage_files_user_cpu_s"] is not None:
            assert t["stage_files_user_cpu_s"] > 0 and t["stage_files_system_cpu_s"] >= 0
            assert (t["stage_files_user_cpu_s"] + t["stage_files_system_cpu_s"]
                    <= t["user_cpu_s"] + t["system_cpu_s"] + 1e-6)
    if t["peak_rss_x_cube"] is not None:                       # Linux: measured in a fresh interpreter
        # the tiny cube (0.25 MB) is within the RSS noise of two interpreters: only the sign is a fact
        assert t["peak_rss_above_base_bytes"] >= 0
        # the tiny run's own peak is a base at least as high as the RSS after it (VmHWM >= VmRSS)
        assert t["tiny_run_peak_bytes"] >= t["interpreter_base_bytes"]
        assert 0 <= t["peak_rss_over_tiny_peak_x_cube"] <= t["peak_rss_x_cube"] + 1e-12


def test_process_cpu_time_counts_busy_threads():
    """The bench's cores_busy clock: two threads spinning in Python for 0.3 s of wall time use 0.3 s of
    CPU between them (the GIL lets one run at a time), a sleeping process uses almost none, and a
    forked child spinning for 0.3 s adds its 0.3 s once reaped."""
    import threading
    import time

    from fwdlook_cli.report.benchtools import process_cpu_s

    if process_cpu_s() is None:
        pytest.skip("no getrusage here")

    def spin(until):
        while time.perf_counter() < until:
            pass

    c0, w0 = process_cpu_s(), time.perf_counter()
    threads = [threading.Thread(target=spin, args=(w0 + 0.3,)) for _ in range(2)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    cpu, wall = process_cpu_s() - c0, time.perf_counter() - w0
    assert 0.3 * wall <= cpu <= 1.1 * wall + 0.02                # one GIL: at most one core (less on a shared one)
    c0 = process_cpu_s()
    time.sleep(0.2)
    assert process_cpu_s() - c0 < 0.05
    # a forked worker's CPU counts once it is reaped (the joint fit's workers, dsp.forked)
    import os

    c0, w0 = process_cpu_s(), time.perf_counter()
    pid = os.fork()
    if pid == 0:                                    # pragma: no cover (the child: its clock starts at 0)
        while time.process_time() < 0.3:
            pass
        os._exit(0)
    os.waitpid(pid, 0)
    assert 0.29 <= process_cpu_s() - c0 <= 1.1 * (time.perf_counter() - w0) + 0.05


def test_process_cpu_split_tells_the_kernels_work_from_the_process_own():
    """The bench's user / system split: a Python spin is the process's own (user) time; touching fresh
    anonymous pages one byte each (a page fault and a cleared page per 4 KiB, almost no user work) is
    the kernel's (system) time; the two sum to the cores_busy clock."""
    import mmap
    import time

    from fwdlook_cli.report.benchtools import process_cpu_s, process_cpu_split_s

    if process_cpu_split_s() is None:
        pytest.skip("no getrusage here")
    u0, s0 = process_cpu_split_s()
    u1, s1 = u0, s0
    deadline = time.perf_counter() + 10.0
    while u1 - u0 < 0.2 and time.perf_counter() < deadline:   # pure Python between the clock's reads
        for _ in range(100_000):                              # (on a shared core: CPU time, not wall)
            pass
        u1, s1 = process_cpu_split_s()
    assert u1 - u0 >= 0.2 and s1 - s0 < 0.5 * (u1 - u0)
    # fresh pages until the kernel has spent 0.1 s on them (at most 4 GiB, in 32 MiB mappings)
    page = mmap.PAGESIZE
    spent = 0.0
    for _ in range(128):
        with mmap.mmap(-1, 32 << 20) as m:
            np.frombuffer(m, dtype=np.uint8)[::page] = 1
        u2, s2 = process_cpu_split_s()
        spent = s2 - s1
        if spent >= 0.1:
            break
    assert spent >= 0.1 and u2 - u1 < spent
    assert abs(sum(process_cpu_split_s()) - process_cpu_s()) < 0.02


def test_run_stages_splits_each_stage_cpu_into_its_own_and_the_kernels(tmp_path):
    """``run_stages(stage_cpu=...)``: a stage that spins in Python is charged user time, one that touches
    fresh anonymous pages (a fault and a cleared page per 4 KiB) system time, each to its own name."""
    import mmap
    import time

    from fwdlook_cli.io.stagefile import StageData
    from fwdlook_cli.report.benchtools import process_cpu_split_s
    from fwdlook_cli.runner import Stage, run_stages

    if process_cpu_split_s() is None:
        pytest.skip("no getrusage here")

    def spin(data):
        u0 = process_cpu_split_s()[0]
        deadline = time.perf_counter() + 10.0
        while process_cpu_split_s()[0] - u0 < 0.15 and time.perf_counter() < deadline:
            for _ in range(100_000):
                pass
        return data

    def touch(data):
        s0 = process_cpu_split_s()[1]
        for _ in range(128):                   # fresh pages until the kernel has spent 0.1 s on them
            with mmap.mmap(-1, 32 << 20) as m:
                np.frombuffer(m, dtype=np.uint8)[::mmap.PAGESIZE] = 1
            if process_cpu_split_s()[1] - s0 >= 0.1:
                break
        return data

    source = StageData()
    source.add("x", np.arange(4.0), ("n",), "1", "x")
    cpu: dict = {}
    run_stages([Stage("spin", spin, {}), Stage("touch", touch, {})], source, "k" * 64, tmp_path,
               quiet=True, keep="none", stage_cpu=cpu)
    (u_spin, s_spin), (u_touch, s_touch) = cpu["spin"], cpu["touch"]
    assert u_spin >= 0.15 and s_spin < 0.5 * u_spin
    assert s_touch >= 0.1 and u_touch < s_touch


@pytest.mark.parametrize("case", ["noise", "constant", "third_strong", "tiny_groups", "sorted", "sample_misled"])
def test_median_floor_is_exactly_the_median(case):
    """The bracketed median (sampled bracket, sort of the bracket only) is np.median to the bit, also
    where the bracket cannot hold the median (constant data, ties; every sampled cell an outlier, in
    some groups of the call and not in others) or the group is tiny."""
    rng = np.random.default_rng(3)
    shape = (4, 3) if case == "tiny_groups" else (6, 17920)
    p = rng.exponential(size=shape).astype(np.float32)
    if case == "constant":
        p[:] = 2.5
    elif case == "third_strong":
        p[:, : shape[1] // 3] *= 1e3
    elif case == "sorted":
        p.sort(axis=1)
    elif case == "sample_misled":                 # the strided sample sees outliers only: bracket missed
        from fwdlook_cli.dsp.imaging import median_sample_stride

        p[::2, ::median_sample_stride(shape[1])] *= 1e6
    got = median_floor(p, shape[1])
    np.testing.assert_array_equal(got, np.median(p.astype(np.float64), axis=1))


def test_median_sample_stride_walks_every_column():
    """The bracket's stride shares no factor with the row length, so the sample visits every column
    (range cell) of the rows equally: 17 for 280 range cells (16 visits 35 of them), 16 for an odd length."""
    from math import gcd

    from fwdlook_cli.dsp.imaging import median_sample_stride

    assert median_sample_stride(280) == 17 and median_sample_stride(281) == 16
    assert median_sample_stride(16 * 17 * 19) == 21
    for n_r in (1, 2, 64, 255, 256, 272, 280, 4096, 16 * 17 * 19 * 23):
        stride = median_sample_stride(n_r)
        assert stride >= 16 and gcd(stride, n_r) == 1
        cols = np.unique((np.arange(0, 64 * n_r, stride)) % n_r)
        assert len(cols) == min(n_r, len(np.arange(0, 64 * n_r, stride)))


def test_median_bracket_holds_the_median_of_range_structured_cpis():
    """CPIs whose power depends on the range cell (exponential noise, every Doppler row 20x brighter
    in a tenth of the range cells, as a target's cells are): the bracket of a stride that walks every
    range cell holds each CPI's median (a +-4 sigma bracket: about 6e-5 of the CPIs missed, so at most
    one of 600 is allowed), where the stride 16 of 280 range cells, which samples 35 fixed cells, misses
    13-23 of 600 (seeds 0-5).  Either way median_floor is np.median."""
    from fwdlook_cli.dsp.imaging import median_bracket, median_sample_stride

    rng = np.random.default_rng(11)
    n_cpi, n_dop, n_r = 600, 64, 280
    p = rng.exponential(size=(n_cpi, n_dop, n_r)).astype(np.float32)
    bright = rng.random((n_cpi, 1, n_r)) < 0.1
    p *= np.where(bright, np.float32(20.0), np.float32(1.0))
    flat = p.reshape(n_cpi, -1)
    med = np.median(flat.astype(np.float64), axis=1)[:, None]
    lo, hi = median_bracket(flat, median_sample_stride(n_r))
    assert np.count_nonzero((med < lo) | (med > hi)) <= 1
    lo16, hi16 = median_bracket(flat, 16)
    assert np.count_nonzero((med < lo16) | (med > hi16)) >= 5
    np.testing.assert_array_equal(median_floor(p, n_dop * n_r, row_length=n_r), med[:, 0])


def test_chain_floor_items_and_total():
    """bench_floor times every stage's unavoidable work; the total is their sum (small shapes)."""
    from fwdlook_cli.report.bench_floor import chain_floor

    for method, q in (("decimation", 4), ("tracking", 1)):
        floor = chain_floor(64, 32, method=method, q=q, cpi=8, n_doppler=16, range_oversample=4, repeats=1)
        items = {k: v for k, v in floor.items() if k != "total_s"}
        assert set(items) == {"range_fft_s", "keystone_s", "range_curvature_s", "doppler_spectra_s",
                              "monopulse_image_s", "stage_files_s"}
        assert all(v > 0 for v in items.values())
        assert floor["total_s"] == pytest.approx(sum(items.values()))


def test_threaded_image_blocks_equal_one_thread(spectra):
    """The image's CPI blocks on a thread pool (FFTs one thread each) give the same cells, bit for bit
    and in the same order, as one thread."""
    from fwdlook_cli.dsp.imaging import iter_kept_cells

    s, d = spectra
    args = dict(range_oversample=4, threshold_db=12.0, dynamic_range_db=60.0, max_ratio=0.4, block_cells=4096)
    one = list(iter_kept_cells(s, d, threads=1, **args))
    three = list(iter_kept_cells(s, d, threads=3, **args))
    assert len(one) > 1
    assert [b[0] for b in three] == sorted(b[0] for b in three)
    cells = lambda blocks: [np.concatenate([b[k] for b in blocks]) for k in range(1, 6)]   # noqa: E731
    for a, b in zip(cells(one), cells(three)):
        np.testing.assert_array_equal(a, b)


def test_worker_threads_follow_the_environment(monkeypatch):
    """A sweep's workers set OMP_NUM_THREADS=1: the stages' block pools then run one thread."""
    from fwdlook_cli.dsp.blas import worker_threads

    monkeypatch.delenv("FWDLOOK_THREADS", raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    assert worker_threads() == 1
    monkeypatch.setenv("FWDLOOK_THREADS", "2")
    assert worker_threads() <= 2
    monkeypatch.setenv("FWDLOOK_THREADS", "junk")
    assert worker_threads() == 1                   # falls through to OMP_NUM_THREADS


_AFFINITY_SCRIPT = """
import os, sys
from fwdlook_cli.dsp.blas import scipy_fft_helper
helper = scipy_fft_helper()
before, allowed = helper._workers(-1), os.sched_getaffinity(0)
os.sched_setaffinity(0, {min(allowed)})                         # one core of the machine's
from fwdlook_cli.cli import main
try:
    main(["validate", sys.argv[1]])                             # the command line's entry point
except SystemExit as exc:
    assert not exc.code, exc.code
after_command = helper._workers(-1)
helper._cpu_count = 1                                           # a sweep worker's setting ...
os.sched_setaffinity(0, allowed)
from fwdlook_cli.dsp.blas import fft_workers_on_usable_cores
print(before, after_command, fft_workers_on_usable_cores(), helper._workers(-1))   # ... is never raised
"""


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity") or len(os.sched_getaffinity(0)) < 2,
                    reason="needs a CPU affinity of two cores or more to restrict")
def test_the_command_lines_fft_workers_follow_the_cpu_affinity():
    """scipy.fft's workers=-1 counts the machine's cores (os.cpu_count); a command started in a CPU set of
    one core (taskset, Slurm) runs its transforms on one worker, and a smaller count set earlier stays."""
    import subprocess
    import sys
    from pathlib import Path

    tiny = Path(__file__).resolve().parents[1] / "scenarios" / "tiny.yaml"
    res = subprocess.run([sys.executable, "-c", _AFFINITY_SCRIPT, str(tiny)], capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0, res.stderr
    before, after_command, returned, after_sweep = map(int, res.stdout.split()[-4:])
    assert before == os.cpu_count() >= 2                        # scipy's own count, as it comes
    assert (after_command, returned, after_sweep) == (1, 1, 1)


def test_the_fft_worker_count_set_is_the_one_scipy_resolves_workers_from(monkeypatch):
    """dsp.blas reaches scipy.fft's private CPU count (pocketfft's module up to scipy 1.17, ducc's from 1.18):
    with it held at one, scipy's public set_workers(-1) resolves to one worker, and after, to the count as
    it was.  A scipy that moves it fails here; the command line then leaves the count as it comes and
    raises nothing (scipy 1.18 once broke every command, which imported pocketfft's module directly)."""
    import scipy
    import scipy.fft

    from fwdlook_cli.dsp import blas

    assert blas.scipy_fft_helper() is not None
    major_minor = tuple(int(v) for v in scipy.__version__.split(".")[:2])
    assert blas.scipy_fft_backend() == ("ducc" if major_minor >= (1, 18) else "pocketfft")
    before = blas.fft_workers()
    with blas.fft_workers_held_at_most(1) as held:
        assert held == 1
        with scipy.fft.set_workers(-1):
            assert scipy.fft.get_workers() == 1
    assert blas.fft_workers() == before
    with scipy.fft.set_workers(-1):
        assert scipy.fft.get_workers() == before
    monkeypatch.setattr(blas, "_SCIPY_FFT_HELPERS", {"scipy.fft._no_such_backend.helper": "x", "scipy.linalg": "y"})
    assert blas.scipy_fft_helper() is None and blas.scipy_fft_backend() == "unknown"
    assert blas.fft_workers() is None
    assert blas.fft_workers_at_most(1) is None and blas.fft_workers_on_usable_cores() is None
    with blas.fft_workers_held_at_most(1) as held:
        assert held is None


def test_one_allocator_arena_on_glibc():
    """The command line shares glibc's main arena among the stages' threads (dsp.blas): mallopt accepts
    M_ARENA_MAX on glibc Linux; elsewhere the call reports that it did nothing."""
    import platform

    from fwdlook_cli.dsp.blas import share_one_allocator_arena

    applied = share_one_allocator_arena()
    if platform.system() == "Linux" and platform.libc_ver()[0] == "glibc":
        assert applied is True
    else:
        assert applied is False


def test_one_blas_thread_limits_every_blas_and_restores_it():
    """dsp.blas.one_blas_thread: inside, every BLAS library numpy and scipy loaded runs one thread; after,
    each is back at its own count (the controller is made once and reused)."""
    from threadpoolctl import threadpool_info

    from fwdlook_cli.dsp.blas import one_blas_thread

    before = {lib["filepath"]: lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"}
    for _ in range(2):
        with one_blas_thread():
            inside = {lib["filepath"]: lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"}
        assert set(inside) == set(before) and set(inside.values()) == {1}
        after = {lib["filepath"]: lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"}
        assert after == before


def test_the_process_blas_setting_keeps_the_users_own_and_a_plain_environment_drops_only_its_own(monkeypatch):
    """dsp.blas.one_blas_thread_for_the_process sets each BLAS thread variable the environment lacks to 1
    and leaves one the user set; plain_environment (the bench's plain interpreters) is the environment
    without exactly the variables it set."""
    from fwdlook_cli.dsp import blas

    monkeypatch.setattr(blas, "_SET_FOR_THE_PROCESS", [])
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    monkeypatch.setenv("MKL_NUM_THREADS", "3")
    monkeypatch.setenv("FWDLOOK_TEST_OTHER", "kept")
    assert blas.one_blas_thread_for_the_process() == ["OPENBLAS_NUM_THREADS"]
    assert os.environ["OPENBLAS_NUM_THREADS"] == "1" and os.environ["MKL_NUM_THREADS"] == "3"
    assert blas.one_blas_thread_for_the_process() == ["OPENBLAS_NUM_THREADS"]      # again: nothing new
    plain = blas.plain_environment()
    assert "OPENBLAS_NUM_THREADS" not in plain
    assert plain["MKL_NUM_THREADS"] == "3" and plain["FWDLOOK_TEST_OTHER"] == "kept"
    assert set(plain) == set(os.environ) - {"OPENBLAS_NUM_THREADS"}


def test_a_chain_run_from_python_runs_on_one_blas_thread_and_gives_the_thread_count_back(tmp_path, monkeypatch):
    """process_cube and api.run_chain hold the BLAS at one thread while their stages run (dsp/blas.py:
    an idle OpenBLAS thread spins on a core the stages need), and the host program's count after."""
    from threadpoolctl import threadpool_info

    import fwdlook_cli.api as api
    from fwdlook_cli import runner
    from fwdlook_cli.forward.process import process_cube
    from fwdlook_cli.forward.simulate import simulate_scenario
    from fwdlook_cli.testing import tiny_scenario

    def blas():
        return {lib["filepath"]: lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"}

    before = blas()
    seen = []
    run_stages = runner.run_stages

    def spy(stages, source, *a, **kw):
        seen.append(blas())
        return run_stages(stages, source, *a, **kw)

    monkeypatch.setattr(runner, "run_stages", spy)
    scn = tiny_scenario()
    cube, _ = simulate_scenario(scn)
    process_cube(cube, scn, tmp_path / "run", quiet=True, png=False)
    assert len(seen) == 1 and set(seen[0]) == set(before) and set(seen[0].values()) == {1}
    assert blas() == before
    from fwdlook_cli.forward import chain

    build = chain.build_forward_stages

    def spy_build(*a, **kw):
        data, stages, geo = build(*a, **kw)
        first = stages[0]

        def counted(d, **params):
            seen.append(blas())
            return first.fn(d, **params)

        stages[0] = dataclasses.replace(first, fn=counted)
        return data, stages, geo

    monkeypatch.setattr(chain, "build_forward_stages", spy_build)
    api.run_chain(cube, scn["processing"])
    assert len(seen) == 2 and set(seen[1].values()) == {1}
    assert blas() == before


def test_the_bench_states_each_target_against_its_bound_and_prints_them_last(monkeypatch, capsys):
    """report.bench.bench_targets: a ratio of two keys or one key against the issue's bound, met when
    at most it, left out where the run has no figure; the human output ends with them."""
    import fwdlook_cli.report.bench as bench

    result = {"fft2_s": 0.002, "chain_s": 0.07, "chain_tracking_s": 0.09, "chain_dwell_over_tracking": 2.0,
              "chain_decimation_peak_rss_over_tiny_peak_x_cube": 4.2, "chain_tracking_peak_rss_over_tiny_peak_x_cube": None}
    t = bench.bench_targets(result)
    assert t["chain_s / fft2_s"] == {"value": 35.0, "at_most": 35.0, "issue": 11, "met": True}
    assert t["chain_tracking_s / fft2_s"]["value"] == pytest.approx(45.0) and not t["chain_tracking_s / fft2_s"]["met"]
    assert t["chain_dwell_over_tracking"]["met"] and t["chain_dwell_over_tracking"]["issue"] == 9
    assert not t["chain_decimation_peak_rss_over_tiny_peak_x_cube"]["met"]
    assert "chain_tracking_peak_rss_over_tiny_peak_x_cube" not in t                  # no figure, no verdict
    assert bench.bench_targets({"chain_s": 0.07, "fft2_s": 0.0}) == {}                 # no reference, no ratio
    monkeypatch.setattr(bench, "run_bench", lambda chain_repeats=3: dict(result, targets=t))
    bench.print_bench()
    lines = capsys.readouterr().out.splitlines()
    assert lines[-5] == "targets (issue: bound; this run):"
    assert lines[-4].split() == ["chain_s", "/", "fft2_s", "35.00", "at", "most", "35", "(issue", "11):", "met"]
    assert lines[-3].split()[-2:] == ["NOT", "met"]
    # with the one-core timings (report/bench_cores.py), their summary after the targets
    one = {"core": 0, "fft2_s": 0.004, "chain_s": 0.12, "chain_over_fft2": 30.0, "chain_tracking_s": 0.14,
           "chain_tracking_over_fft2": 35.0, "second_core_gain_chain": 0.12 / 0.07,
           "second_core_gain_chain_tracking": 0.14 / 0.09, "second_core_gain_fft2": 2.0}
    monkeypatch.setattr(bench, "run_bench", lambda chain_repeats=3: dict(result, targets=t, one_core=one))
    bench.print_bench()
    lines = capsys.readouterr().out.splitlines()
    assert lines[-6] == "targets (issue: bound; this run):"
    assert lines[-1] == ("on one core (bench_cores.py): chain_s / fft2_s 30.0, chain_tracking_s / fft2_s 35.0; "
                         "the second core's gain (one-core time over two-core time): fft2 2.00 x, the chains "
                         "1.71 x and 1.56 x")
    assert "one_core[chain_s]            120.00 ms" in lines and "one_core[chain_over_fft2]      30.00 x" in lines


def test_the_blas_limit_takes_in_scipys_blas_once_scipy_linalg_is_loaded():
    """dsp.blas.one_blas_thread limits numpy's BLAS without importing scipy.linalg, and once a host
    program has imported it, scipy's BLAS too (the controller is made again), in a fresh interpreter."""
    import subprocess
    import sys
    import textwrap

    script = textwrap.dedent("""
        import sys
        import numpy as np
        from threadpoolctl import threadpool_info
        from fwdlook_cli.dsp.blas import one_blas_thread

        def blas():
            return {lib["filepath"]: lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"}

        with one_blas_thread():
            first = blas()
        print("linalg", "scipy.linalg" in sys.modules, "libraries", len(first), "threads", sorted(set(first.values())))
        import scipy.linalg
        with one_blas_thread():
            second = blas()
        print("libraries", len(second), "threads", sorted(set(second.values())))
    """)
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    first, second = res.stdout.splitlines()
    assert first.startswith("linalg False") and first.endswith("threads [1]"), res.stdout
    n_first, n_second = int(first.split()[3]), int(second.split()[1])
    assert n_first >= 1 and n_second >= n_first and second.endswith("threads [1]"), res.stdout


def test_a_run_imports_neither_scipy_optimize_nor_interpolate(tmp_path):
    """Their imports are a quarter of a second of a command's start (docs/SPEED_HISTORY.md, eighth round): the chain and the
    simulator solve their roots without them (dsp.antenna.bracketed_root), and ``tracking``'s Doppler
    history on the uniform pulse grid is the closed-form spline (dsp.spline).  Nor ``scipy.linalg`` and
    ``scipy.ndimage`` (about 30 ms each, twenty-first round): the BLAS limit does not load scipy's BLAS
    (dsp.blas), and the calibration check's running maximum and groups are dsp.neighbours.  What
    ``import scipy.fft`` loads by itself is scipy's, not the chain's (scipy 1.18's ``scipy.fft`` loads
    ``scipy.linalg`` through ``scipy.special``): it is measured in a plain interpreter and allowed."""
    import subprocess
    import sys
    import textwrap

    heavy_modules = ("scipy.optimize", "scipy.interpolate", "scipy.linalg", "scipy.ndimage")
    probe = subprocess.run([sys.executable, "-c", f"import sys, scipy.fft; print(sorted(m for m in {heavy_modules!r}"
                            " if m in sys.modules))"], capture_output=True, text=True, timeout=120)
    assert probe.returncode == 0, probe.stderr
    by_scipy_fft = probe.stdout.strip()
    script = textwrap.dedent(f"""
        import sys
        from fwdlook_cli.cli import main
        try:
            main(sys.argv[1:])
        except SystemExit as exc:
            heavy = sorted(m for m in {heavy_modules!r} if m in sys.modules)
            print("exit", exc.code, "imported:", heavy)
    """)
    for method in ("decimation", "tracking", "bulk"):
        res = subprocess.run([sys.executable, "-c", script, "run", "scenarios/tiny.yaml", "-o", str(tmp_path / method),
                              "--set", f"processing.method={method}", "-q"],
                             capture_output=True, text=True, timeout=120)
        assert res.returncode == 0, res.stderr
        assert f"exit 0 imported: {by_scipy_fft}" in res.stdout, res.stdout + res.stderr


def test_clean_process_reference_transforms_the_same_cube_without_fwdlook():
    """bench's plain-interpreter reference (benchtools.clean_process_fft2) times the fft2 of the very
    array it is given (sum |fft2| equal to this process's to float32 rounding), in a child that
    imports neither fwdlook nor its allocator setting."""
    from fwdlook_cli.report.benchtools import _CLEAN_FFT2, clean_process_fft2

    rng = np.random.default_rng(9)
    x = (rng.standard_normal((96, 40)) + 1j * rng.standard_normal((96, 40))).astype(np.complex64)
    got = clean_process_fft2(x, repeats=3, processes=2)
    assert len(got["times"]) == 6 and all(t > 0 for t in got["times"]) and len(got["medians"]) == 2
    expect = float(np.abs(scipy.fft.fft2(x)).sum(dtype=np.float64))
    assert got["abs_sum"] == pytest.approx(expect, rel=1e-5)
    assert "fwdlook" not in _CLEAN_FFT2 and "mallopt" not in _CLEAN_FFT2


def test_the_bench_records_what_its_figures_depend_on():
    """``environment()`` (in every bench's JSON): the computing libraries' versions as imported here,
    the cores this process may use and the processor; all strings."""
    import math
    import os

    import ducc0
    import h5py

    from fwdlook_cli import __version__
    from fwdlook_cli.report.benchtools import environment

    env = environment()
    assert all(isinstance(v, str) and v for v in env.values())
    assert env["fwdlook"] == __version__ and env["numpy"] == np.__version__
    assert env["scipy"] == scipy.__version__ and env["ducc0"] == ducc0.__version__
    assert env["h5py"] == h5py.version.version
    affinity, limit = len(os.sched_getaffinity(0)), env["cpu_limit"]       # the cgroup's limit: "none" or CPUs
    assert int(env["cores"]) == (affinity if limit == "none" else max(1, min(affinity, math.ceil(float(limit)))))
    assert int(env["fft_workers"]) >= 1
    assert env["fft_backend"] in ("pocketfft", "ducc")
    assert {"python", "hdf5", "machine", "cpu", "blas", "blas_threads"} <= set(env)


def test_float32_image_sums_are_the_float64_sums_to_their_rounding():
    """The image stage sums each block's cells into the float32 image as the block arrives (np.add.at,
    in CPI order).  Per bin that is a sequential float32 sum of k non-negative terms, within (k - 1)
    roundings of the float64 sum (|error| <= (k - 1) 2^-24 of it, plus its own final rounding): the
    same image as one float64 np.bincount of every cell rounded to float32, to the image's precision.
    Checked on blocks of cells with powers over six decades and bins holding up to ~20 cells."""
    rng = np.random.default_rng(21)
    size = 5000
    bins = [np.sort(rng.integers(0, size, n)) for n in (0, 1, 700, 30000, 12)]
    weights = [(rng.exponential(1.0, len(b)) * 10.0 ** rng.uniform(-3, 3, len(b))).astype(np.float32) for b in bins]
    image = np.zeros(size, np.float32)
    for b, w in zip(bins, weights):
        np.add.at(image, b, w)
    all_bins, all_w = np.concatenate(bins), np.concatenate(weights).astype(np.float64)
    exact = np.bincount(all_bins, all_w, minlength=size)
    count = np.bincount(all_bins, minlength=size)
    assert count.max() >= 15
    bound = (np.maximum(count - 1, 0) + 1) * 2.0 ** -24 * exact
    assert np.all(np.abs(image.astype(np.float64) - exact) <= bound)
    assert np.array_equal(image == 0, count == 0)
    # and it is not the float64 sum rounded once everywhere: the bound is used, not met trivially
    assert np.count_nonzero(image != exact.astype(np.float32)) > 0


def test_the_image_stage_does_not_keep_its_float64_sums_beside_its_output():
    """The monopulse image is summed block by block into its float32 output (no float64 image beside
    it), the real beam's float64 sums rounded at once, so that nothing image-sized is held beside the
    output to the end of the stage (the CPI chains' high-water mark was the image stage's).  On an angle
    grid fine enough that the image dominates, the stage's traced peak exceeds its output by less than
    one float32 image (2.5 with the float64 image, its float32 copy and the real beam's sums all held to
    the end; 1.75 with the float64 image summed block by block, twenty-first round; 0.5 now, the real
    beam's float64 sums).  And the image holds the power of its cells: the sum over the image is the sum
    of the projected cells' power (every cell on the grid here)."""
    import tracemalloc

    from fwdlook_cli.forward.chain import build_forward_stages
    from fwdlook_cli.forward.monopulse import monopulse_image
    from fwdlook_cli.forward.simulate import simulate_scenario
    from fwdlook_cli.testing import tiny_scenario

    scn = tiny_scenario()
    cube, _ = simulate_scenario(scn)
    src, stages, _ = build_forward_stages(cube, dict(scn["processing"], imaging="cpi", method="decimation"))
    data = src
    for st in stages[:-1]:
        data = st.fn(data, **st.params)
    assert stages[-1].name == "monopulse_image"
    params = dict(stages[-1].params, angle_step_deg=0.002, range_oversample=4)   # x 4: the image dominates
    tracemalloc.start()
    try:
        out = monopulse_image(data, **params)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    image32 = out["image"].nbytes
    output = sum(v.data.nbytes for v in out.vars.values())
    assert out["image"].dtype == np.float32 and image32 > 0.6 * output      # the image dominates
    assert len(out["cell"]) > 1000
    assert peak - output < 1.0 * image32
    np.testing.assert_allclose(out["image"].sum(dtype=np.float64), out["cell_power"].sum(dtype=np.float64),
                               rtol=1e-6)
