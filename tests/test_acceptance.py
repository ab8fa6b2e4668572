"""Issue 3's accuracy claims on the paper scenarios (Table 1, h = 50 m, SNR 20 dB), measured.

Tolerances are the issue's, not tuned: azimuth of isolated targets RMS <= 0.05 deg, max <= 0.15 deg,
3 dB width <= 0.5 deg; lattice RMS <= 0.3 deg, <= 0.1 deg for |x| >= 210 m; range within 0.3 m.
The full-lattice range criterion is asserted on the targets the image resolves (no other target in
the same range cell and Doppler cell, ``evaluate.resolved_flags``): near boresight neighbours 1 deg
apart share a Doppler cell of a 32-pulse CPI and the monopulse ratio mixes them (NOTES.md); these
tests pin ``imaging: cpi`` (the whole-dwell imaging resolves them away from boresight: test_dwell.py).  The placement of every one of the 63 targets, free of that mixing, is the
slow test at the end (each lattice column processed on its own).
"""
import json
from pathlib import Path

import numpy as np
import pytest

import yaml

from fwdlook_cli.forward.process import process_cube
from fwdlook_cli.scenario.overlay import resolve_with_config
from fwdlook_cli.forward.simulate import simulate_scenario

ROOT = Path(__file__).resolve().parent.parent


def run_tracking(scenario, tmp_path, *overrides):
    """The scenario with the tracking preset (-c configs/tracking.yaml) and --set overrides over it."""
    path = ROOT / "scenarios" / scenario
    scn = resolve_with_config(yaml.safe_load(path.read_text()), str(path), str(ROOT / "configs" / "tracking.yaml"),
                              ["processing.imaging=cpi", *overrides])   # issue 3's claims: the CPI image
    cube, _ = simulate_scenario(scn)
    return process_cube(cube, scn, tmp_path, quiet=True, png=False)


def test_isolated_targets_azimuth(tmp_path):
    m = run_tracking("isolated_a50.yaml", tmp_path)
    rows = m["targets"]
    assert all(r["detected"] for r in rows)
    az = np.array([r["azimuth_error_deg"] for r in rows])
    assert np.sqrt(np.mean(az**2)) <= 0.05
    assert np.max(np.abs(az)) <= 0.15
    widths = np.array([r["angle_width_3db_deg"] for r in rows])
    assert np.all(widths <= 0.5)
    # against the real-beam image: its two-way width is ~4.2 deg, ten times wider at least
    assert np.max(widths) < 4.24 / 8
    assert np.max(np.abs([r["range_error_m"] for r in rows])) <= 0.3


@pytest.mark.parametrize("scenario", ["paper_fig5_a0.yaml", "paper_fig6_a10.yaml", "paper_fig6_a50.yaml"])
def test_lattice_azimuth_and_resolved_range(scenario, tmp_path):
    m = run_tracking(scenario, tmp_path)
    rows = m["targets"]
    det = [r for r in rows if r["detected"]]
    # only targets that share an image cell with a neighbour may be missed
    assert all(r["detected"] for r in rows if r["resolved"])
    az = np.array([r["azimuth_error_deg"] for r in det])
    assert np.sqrt(np.mean(az**2)) <= 0.3
    outer = np.array([r["azimuth_error_deg"] for r in det if abs(r["x_m"]) >= 210.0])
    assert len(outer) == 24 and np.sqrt(np.mean(outer**2)) <= 0.1
    resolved = [r for r in rows if r["resolved"]]
    assert len(resolved) >= 24 and all(r["detected"] for r in resolved)
    assert max(abs(r["range_error_m"]) for r in resolved) <= 0.3


def test_doppler_band_must_follow_vc_at_a50(tmp_path):
    """Eq. (25): with a = 50 m/s^2 the Doppler centroid drifts 5.8 kHz over the scan (2.3 PRF); a CPI
    band placed with the initial speed misses every target whose drift, modulo the PRF, is near half a
    PRF, and its image is lost; with v_c = v + a t_c all are imaged."""
    with_vc = run_tracking("isolated_a50.yaml", tmp_path / "vc")
    without = run_tracking("isolated_a50.yaml", tmp_path / "v0", "processing.doppler_centroid=false")
    assert all(r["detected"] for r in with_vc["targets"])
    loss_db = np.array([10 * np.log10(max(b["peak_power"], 1e-30) / a["peak_power"])
                        for a, b in zip(with_vc["targets"], without["targets"])])
    assert np.sum(loss_db < -20.0) >= 3
    assert sum(not r["detected"] for r in without["targets"]) >= 3


@pytest.mark.slow
@pytest.mark.parametrize("scenario", ["paper_fig5_a0.yaml", "paper_fig6_a10.yaml", "paper_fig6_a50.yaml"])
def test_every_lattice_target_placed_within_0p3_m(scenario, tmp_path):
    errors = []
    for column in range(21):
        m = run_tracking(scenario, tmp_path / str(column), "scene.lattice.x_stride=21",
                         f"scene.lattice.x_offset={column}")
        errors += [r["range_error_m"] for r in m["targets"] if r["detected"]]
    assert len(errors) == 63
    assert np.max(np.abs(errors)) <= 0.3, json.dumps(sorted(errors))
