"""A road edge of the procedural scene lands at its true range within half a range cell (tracking)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from fwdlook_cli.scenario.loader import load_scenario
from fwdlook_cli.dsp.geometry import C_MPS
from fwdlook_cli.forward.process import process_cube
from fwdlook_cli.forward.simulate import simulate_scenario

FIG8 = Path(__file__).resolve().parents[1] / "scenarios" / "paper_fig8_a50.yaml"


def test_road_edges_within_half_a_range_cell_with_tracking(tmp_path):
    """The paper radar at a = 50 on a 100 x 80 pixel crop of the procedural scene (both roads; scan
    +-12 deg), the `tracking` method (the best on the point lattice): every edge's median range error
    along its length is under half a range resolution cell c / (4 B), and most of each edge is found."""
    scn = load_scenario(FIG8, ["scene.image.size_px=[100, 80]", "antenna.scan_start_deg=-12",
                               "antenna.scan_stop_deg=12", "processing.method=tracking",
                               "processing.curvature_model=auto"])
    cube, _ = simulate_scenario(scn)
    metrics = process_cube(cube, scn, tmp_path, quiet=True, png=False)
    half_cell = C_MPS / (4.0 * scn["radar"]["bandwidth_hz"])           # 1.5 m
    edges = metrics["scene"]["road_edges"]
    assert set(edges) == {"road_a_near", "road_a_far", "road_b_near", "road_b_far"}
    for name, e in edges.items():
        assert e["n_found"] >= 0.8 * e["n_bins"] and e["n_bins"] >= 10, (name, e["n_found"], e["n_bins"])
        assert abs(e["median_error_m"]) < half_cell, (name, e["median_error_m"])
    assert np.isfinite(metrics["scene"]["ssim"]) and 0 < metrics["scene"]["ssim"] < 1
