"""Scene metrics (scene_metrics.py) on closed forms, and Fig. 8 end to end (slow)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from fwdlook_cli.forward.scene_metrics import edge_true_range_m, entropy_contrast, reference_on_image_grid, road_edge_errors, ssim_to_reference


def test_edge_truth_closed_form():
    """A road across the scene (angle 0) at v0, seen from (0, y_p, h): on boresight the edge is at
    ground distance c_y + v0 - y_p; at azimuth theta that distance over cos(theta)."""
    p_ref = np.array([0.0, 120.0, 50.0])
    ang = np.array([0.0, 5.0, -8.0])
    r = edge_true_range_m(90.0, 0.0, ang, p_ref, [0.0, 1700.0], 0.0, 300.0)
    rho = (1700.0 + 90.0 - 120.0) / np.cos(np.radians(ang))
    assert np.allclose(r, np.hypot(rho, 50.0), rtol=1e-12)
    # the same edge with the map turned by 90 deg is a line along y: a boresight ray never meets it
    r90 = edge_true_range_m(90.0, 0.0, np.array([0.0]), p_ref, [0.0, 1700.0], 90.0, 300.0)
    assert np.isnan(r90[0])


def test_entropy_contrast_ssim_closed_forms():
    ent, con = entropy_contrast(np.ones(100))
    assert ent == pytest.approx(np.log(100)) and con == pytest.approx(0.0, abs=1e-12)
    p = np.zeros(100)
    p[3] = 5.0
    ent, con = entropy_contrast(p)
    assert ent == pytest.approx(0.0, abs=1e-12) and con == pytest.approx(np.sqrt(99), rel=1e-12)
    rng = np.random.default_rng(0)
    ref = rng.uniform(0.1, 1.0, (40, 50))
    assert ssim_to_reference(ref, ref) == pytest.approx(1.0)
    assert ssim_to_reference(rng.permutation(ref.ravel()).reshape(ref.shape), ref) < 0.5


def test_road_edge_found_at_its_range_on_a_synthetic_image():
    """An image that is a ridge exactly on the true edge range (the truth resampled) reads back ~0 m."""
    p_ref = np.array([0.0, 100.0, 50.0])
    range_m = 1500.0 + 0.625 * np.arange(600)
    angle_deg = np.arange(-6.0, 6.0, 0.05)
    truth = edge_true_range_m(-20.0, 5.0, angle_deg, p_ref, [0.0, 1700.0], 0.0, 1000.0)
    img = np.exp(-0.5 * ((range_m[:, None] - truth[None, :]) / 1.2) ** 2)
    out = road_edge_errors(img, range_m, angle_deg, p_ref, [("e", -20.0, 5.0)], center_m=[0.0, 1700.0],
                           orientation_deg=0.0, half_extent_u_m=1000.0)["e"]
    assert out["n_found"] == out["n_bins"] > 20
    assert abs(out["median_error_m"]) < 0.05 and out["max_abs_error_m"] < 0.2   # 0.5 deg bins: curvature


def test_reference_resampling_puts_a_pixel_where_it_is():
    ref = np.zeros((21, 21))
    ref[10, 10] = 1.0                                    # centre pixel at ground (0, 1700)
    p_ref = np.array([0.0, 0.0, 50.0])
    r_true = np.hypot(1700.0, 50.0)
    range_m = r_true + np.arange(-20, 21) * 0.5
    angle_deg = np.arange(-1.0, 1.01, 0.02)
    out = reference_on_image_grid(ref, 3.0, [0.0, 1700.0], 0.0, range_m, angle_deg, p_ref)
    i, j = np.unravel_index(np.nanargmax(out), out.shape)
    assert abs(range_m[i] - r_true) <= 0.5 and abs(angle_deg[j]) <= 0.02


@pytest.mark.slow
def test_fig8_quick(tmp_path):
    """Fig. 8 at quick scale: every figure and the table; fwdlook's methods place the edges better
    than the paper's decimation keystone, and within half a range cell (1.5 m)."""
    from fwdlook_cli.report.fig8 import fig8

    table = fig8(tmp_path, scale="quick")
    for name in ("fig8_scene.png", "fig8_data.png", "fig8_images.png", "fig8.json"):
        assert (tmp_path / name).stat().st_size > 0
    rec = json.loads((tmp_path / "fig8.json").read_text())["methods"]
    assert set(rec) == {"traditional", "decimation_nocurv", "decimation", "beam", "tracking"}
    assert rec["tracking"]["road_edge_median_abs_error_m"] < rec["decimation"]["road_edge_median_abs_error_m"]
    assert rec["tracking"]["road_edge_median_abs_error_m"] < 1.5
    assert "tracking" in table.read_text()
