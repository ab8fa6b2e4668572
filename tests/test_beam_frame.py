"""The ``beam`` method's beam point per pulse, in the antenna's frame at that pulse (issue 8, item 5).

The scan angle of pulse n is the pointing of the antenna at pulse n (CONTRACT section 3), so the point its
beam looks at lies on the axis from the antenna at pulse n.  Placed from the antenna at t_ref instead, the
point is off the beam by the distance flown since t_ref and each pulse is shifted by the range history of
a point the beam does not see: 0.21-0.26 m at t_ref = centre and 0.56-0.66 m at start on the isolated
scene (noiseless), against 0.03 and 0.15 m once placed right.
"""
from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest
import yaml

from fwdlook_cli.forward.motion import beam_points_m, beam_range_history_m
from fwdlook_cli.forward.process import process_cube
from fwdlook_cli.scenario.overlay import resolve_with_config
from fwdlook_cli.forward.simulate import simulate_scenario

ROOT = Path(__file__).resolve().parents[1]


def test_beam_point_on_the_axis_of_the_antenna_at_each_pulse():
    t = np.arange(0, 1.0, 1 / 500.0)
    v0, a = np.array([3.0, 240.0, 0.0]), np.array([2.0, 50.0, -1.0])
    pos = np.array([0.0, 0.0, 50.0]) + v0 * t[:, None] + 0.5 * a * t[:, None] ** 2
    beam = -15.0 + 30.0 * t
    r_ref = 1700.0
    m_ref = (len(t) - 1) / 2
    pts, p_ref = beam_points_m(pos, m_ref, beam, 0.0, r_ref)
    d = pts - pos
    assert np.all(pts[:, 2] == 0.0)                                            # on the ground
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), r_ref, rtol=1e-12)   # at the reference range
    np.testing.assert_allclose(np.degrees(np.arctan2(d[:, 0], d[:, 1])), beam, atol=1e-9)  # on pulse n's axis
    np.testing.assert_allclose(p_ref, 0.5 * (pos[(len(t) - 1) // 2] + pos[len(t) // 2]))
    # the shift is |P_n - p_n| - |P_n - p_ref|: zero at t_ref
    dr = beam_range_history_m(pos, m_ref, beam, 0.0, r_ref)
    np.testing.assert_allclose(dr, r_ref - np.linalg.norm(pts - p_ref, axis=1), atol=1e-9)


def run_beam(accel, t_ref):
    path = ROOT / "scenarios" / "isolated_a50.yaml"
    scn = resolve_with_config(yaml.safe_load(path.read_text()), str(path), str(ROOT / "configs" / "beam.yaml"),
                              [f"platform.accel_mps2=[0, {accel}, 0]", f"processing.t_ref={t_ref}",
                               "noise.snr_db=null"])
    cube, _ = simulate_scenario(scn)
    with tempfile.TemporaryDirectory() as d:
        return process_cube(cube, scn, d, quiet=True, png=False)


@pytest.mark.parametrize("accel", [0, 10, 30, 50, 80])
def test_beam_places_isolated_targets(accel):
    # eleven isolated points across the sector (x = -300..300 m, each at its own range, 1500-1900 m),
    # noiseless so that the motion compensation's placement is measured, not the noise
    for t_ref, tol_m in (("centre", 0.12), ("start", 0.2)):
        m = run_beam(accel, t_ref)
        rows = m["targets"]
        assert all(r["detected"] for r in rows), t_ref
        err = np.abs([r["range_error_m"] for r in rows])
        assert err.max() <= tol_m, (t_ref, err.max())
