"""The per-target metrics batched over targets (``forward.evaluate``) against the same metrics taken one
target at a time (``tests/reference_metrics.py``), and the ground image against a float64 bincount.

Scenes: the paper lattice (63 targets, a = 50: the README's numbers) through the tracking chain with
CPI imaging, and the tiny scene, whose image edges cut some targets' strips and windows (the batched
path's per-target fallback)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fwdlook_cli.dsp.antenna import sum_voltage_for
from fwdlook_cli.forward.evaluate import dwell_profile_metrics, target_metrics
from fwdlook_cli.forward.process import ground_image, process_cube
from fwdlook_cli.forward.simulate import simulate_scenario
from fwdlook_cli.io.stagefile import read_stage
from fwdlook_cli.scenario.loader import load_scenario
from reference_metrics import dwell_profile_metrics_one_by_one, target_metrics_one_by_one

from fwdlook_cli.testing import tiny_scenario

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module", params=["paper", "tiny"])
def finished(request, tmp_path_factory):
    scn = load_scenario(REPO / "scenarios" / "paper_fig6_a50.yaml") if request.param == "paper" else tiny_scenario()
    scn = dict(scn, processing=dict(scn["processing"], method="tracking", imaging="cpi", dwell_fit="none"))
    cube, _ = simulate_scenario(scn)
    run = tmp_path_factory.mktemp(request.param)
    metrics = process_cube(cube, scn, run, quiet=True, png=False)
    final = read_stage(run / "stages" / "07_monopulse_image.h5")
    spectra = read_stage(run / "stages" / "06_doppler_spectra.h5")
    return cube, final, spectra, metrics


def _close(a, b, rtol):
    assert a.keys() == b.keys()
    for key in a:
        x, y = a[key], b[key]
        if isinstance(x, float) and isinstance(y, float):
            assert x == pytest.approx(y, rel=rtol, abs=1e-12), (a.get("id"), key, x, y)
        else:
            assert x == y, (a.get("id"), key, x, y)


@pytest.mark.parametrize("crop", [None, 0.3])
def test_target_metrics_batched_equal_one_by_one(finished, crop):
    """``crop``: the image cut to its middle rows and columns, so that the edges run through targets
    (windows and cuts clipped, some targets outside: the per-target fallback and the missing rows)."""
    cube, final, _, _ = finished
    p_ref = np.asarray(json.loads(final.attrs["position_ref_m"]))
    image, range_m, angle_deg = final["image"], final["range_m"], final["angle_deg"]
    if crop:
        r0, r1 = int(crop * len(range_m)), int((1 - crop) * len(range_m))
        a0, a1 = int(crop * len(angle_deg)), int((1 - crop) * len(angle_deg))
        image, range_m, angle_deg = image[r0:r1, a0:a1], range_m[r0:r1], angle_deg[a0:a1]
    args = (image, range_m, angle_deg, cube.truth_xyz_m(), cube.truth["amplitude"], p_ref)
    batched = target_metrics(*args, bandwidth_hz=cube.radar["bandwidth_hz"])
    one = target_metrics_one_by_one(*args, bandwidth_hz=cube.radar["bandwidth_hz"])
    assert len(batched) == len(one) == len(cube.truth["x_m"])
    assert sum(r["detected"] for r in batched) > 0
    for a, b in zip(batched, one):
        _close(a, b, 1e-9)       # float64 sums of the same pixels, perhaps added in another order


def test_dwell_profile_metrics_batched_equal_one_by_one(finished):
    cube, final, spectra, _ = finished
    p_ref = np.asarray(json.loads(final.attrs["position_ref_m"]))
    slope, beta = float(cube.antenna["monopulse_slope_per_deg"]), float(cube.antenna["beta_per_deg2"])
    window_m = 5 * 299_792_458.0 / (2 * cube.radar["bandwidth_hz"])       # +-5 range resolution cells
    one = dwell_profile_metrics_one_by_one(spectra, cube.truth_xyz_m(), cube.truth["amplitude"], slope, beta, p_ref,
                                           range_window_m=window_m)
    # the cube's /antenna as the sum pattern (dsp.antenna.sum_voltage_for: the Gaussian pair's closed form)
    batched = dwell_profile_metrics(spectra, cube.truth_xyz_m(), cube.truth["amplitude"],
                                    sum_voltage_for(cube.radar["beamwidth_3db_deg"], cube.antenna), p_ref,
                                    range_window_m=window_m)
    assert any(r["islr_db"] is not None for r in batched)
    for a, b in zip(batched, one):
        _close(a, b, 1e-12)


def test_ground_image_is_the_float64_bincount_to_float32_rounding(finished):
    _, final, _, _ = finished
    x, y, w = final["cell_x_m"], final["cell_y_m"], final["cell_power"]
    img, gx, gy = ground_image(x, y, w, step_m=0.5)
    ix, iy = np.rint((x - gx[0]) / 0.5).astype(int), np.rint((y - gy[0]) / 0.5).astype(int)
    ok = (ix >= 0) & (ix < len(gx)) & (iy >= 0) & (iy < len(gy))
    ref = np.bincount(iy[ok] * len(gx) + ix[ok], weights=w[ok], minlength=img.size).reshape(img.shape)
    assert ok.mean() > 0.99                  # the 0.1-99.9 percentile box plus margins holds nearly all cells
    np.testing.assert_allclose(img, ref, rtol=2e-6, atol=0)
    assert img.sum(dtype=np.float64) == pytest.approx(float(w[ok].sum(dtype=np.float64)), rel=1e-6)


def test_ground_image_in_blocks_of_cells_is_the_one_block_image(finished, monkeypatch):
    """The ground image bins its cells in blocks (bounded temporaries while the outputs still hold the
    Doppler spectra): the same sums in the same order as one block, so the same image bit for bit."""
    import fwdlook_cli.forward.process as process

    _, final, _, _ = finished
    x, y, w = final["cell_x_m"], final["cell_y_m"], final["cell_power"]
    monkeypatch.setattr(process, "GROUND_BLOCK_CELLS", len(x) + 1)
    one, gx1, gy1 = ground_image(x, y, w, step_m=0.5)
    monkeypatch.setattr(process, "GROUND_BLOCK_CELLS", max(1, len(x) // 7))
    blocks, gx, gy = ground_image(x, y, w, step_m=0.5)
    assert len(x) > 7 and np.count_nonzero(one) > 10
    np.testing.assert_array_equal(blocks, one)
    np.testing.assert_array_equal(gx, gx1)
    np.testing.assert_array_equal(gy, gy1)


@pytest.mark.parametrize("shape", ["wide", "thin"])
def test_a_ground_image_wider_than_its_bin_budget_takes_a_coarser_whole_step(finished, monkeypatch, shape):
    """Cells spread over more ground than ``GROUND_MAX_BINS`` bins of the step (a scene 800 km across had
    asked for 23e9 bins: an 85.7 GiB allocation, a traceback): the step grows by the smallest whole factor
    that fits (one less does not), whether the cells cover an area or a line (``thin``: one x, whose axis is
    all margin and does not shrink), the axes say it, and every cell's power is binned as the float64
    bincount on that step gives it; within the budget the step is the one asked for."""
    import fwdlook_cli.forward.process as process

    _, final, _, _ = finished
    x, y, w = final["cell_x_m"], final["cell_y_m"], final["cell_power"]
    if shape == "thin":
        x = np.full_like(x, float(np.median(x)))
    fine, gx, _ = ground_image(x, y, w, step_m=0.5)
    assert gx[1] - gx[0] == pytest.approx(0.5)
    budget = fine.size // 10
    monkeypatch.setattr(process, "GROUND_MAX_BINS", budget)
    img, gx, gy = ground_image(x, y, w, step_m=0.5)
    step = float(gy[1] - gy[0])
    factor = int(round(step / 0.5))
    assert step == pytest.approx(0.5 * factor) and img.size <= budget
    assert factor >= (4 if shape == "wide" else 10)              # a line shrinks along one axis only
    monkeypatch.setattr(process, "GROUND_MAX_BINS", 1 << 40)
    assert ground_image(x, y, w, step_m=0.5 * (factor - 1))[0].size > budget     # the smallest that fits
    ix, iy = np.rint((x - gx[0]) / step).astype(int), np.rint((y - gy[0]) / step).astype(int)
    ok = (ix >= 0) & (ix < len(gx)) & (iy >= 0) & (iy < len(gy))
    ref = np.bincount(iy[ok] * len(gx) + ix[ok], weights=w[ok], minlength=img.size).reshape(img.shape)
    # float32 sums in order: at most one rounding (2^-24) of the running sum per cell added to a bin
    per_bin = np.bincount(iy[ok] * len(gx) + ix[ok], minlength=img.size).reshape(img.shape)
    assert np.all(np.abs(img - ref) <= 2.0**-24 * per_bin * ref + 1e-30)
    total = float(w[ok].sum(dtype=np.float64))                  # every cell in the box binned, none lost
    bound = float(np.sum(2.0**-24 * per_bin * ref))
    assert ok.mean() > 0.99 and abs(img.sum(dtype=np.float64) - total) <= bound
    assert img.sum(dtype=np.float64) >= fine.sum(dtype=np.float64) - 2 * bound - 1e-6 * total   # holds the fine box


def test_best_ratio_rows_is_the_sequential_rule_per_segment():
    """The peak loss's CPI choice for every dwell at once against the one-dwell rule, on segments of
    ratios with ties, with no positive ratio (the rule then takes the last CPI) and of one element."""
    from fwdlook_cli.forward.evaluate import _best_ratio_rows
    from reference_metrics import best_ratio_index

    rng = np.random.default_rng(7)
    lengths = rng.integers(1, 9, 300)
    segments = []
    for n in lengths:
        kind = rng.integers(0, 3)
        meas = (np.round(3 * rng.random(n)) if kind == 0 else np.zeros(n) if kind == 1 else rng.random(n))
        segments.append(meas)
    meas = np.concatenate(segments)
    ideal = rng.uniform(0.5, 2.0, meas.size).round(1)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    got = _best_ratio_rows(meas / ideal, starts)
    want = [s + best_ratio_index(meas[s:s + n], ideal[s:s + n]) for s, n in zip(starts, lengths)]
    assert got.tolist() == want
    assert any(not np.any(meas[s:s + n] > 0) for s, n in zip(starts, lengths))      # the no-positive case ran
