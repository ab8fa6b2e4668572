"""ISAR migration span: gated on the predicted track's actual extent, reported in named units
(issue 8, item 5).

With a 4 s dwell at theta0 = 3 deg the range minimum (1.44 s after the middle) lies inside the dwell, so
the raw track is not centred on the mid-dwell range: a gate of R(t_mid) +- half the raw migration cuts its
far end (7.41 m measured against the true 8.58 m).  The span must match the exact range history, smoothed
as the metric smooths it (running mean of ``SPAN_SMOOTH_PULSES``), to a tenth of a resolution cell.
"""
from __future__ import annotations

import numpy as np
import pytest

from fwdlook_cli.isar.chain import run_isar_stages
from fwdlook_cli.isar.evaluate import isar_outputs
from fwdlook_cli.isar.simulate import simulate_isar_scenario
from fwdlook_cli.isar.track import SPAN_SMOOTH_PULSES
from fwdlook_cli.report.isar_tables import _scenario_dir
from fwdlook_cli.scenario.isar import scatterer_ranges_m
from fwdlook_cli.scenario.loader import load_scenario
from fwdlook_cli.dsp.geometry import C_MPS
from fwdlook_cli.isar.span import predicted_envelope_m, span_units

ROOT = _scenario_dir()


def exact_range(cube):
    pos = np.stack([cube.truth[k] for k in ("x_m", "y_m", "z_m")], axis=1)
    vel = np.array([cube.truth[k][0] for k in ("vx_mps", "vy_mps", "vz_mps")])
    return scatterer_ranges_m(pos, vel, cube.slow_time_s)[0]


def smoothed_span_m(r_m):
    n = SPAN_SMOOTH_PULSES
    return float(np.ptp(np.convolve(r_m, np.ones(n) / n, mode="valid")))


def run(cube, scn, correction):
    proc = dict(scn["processing"], correction=correction)
    final, _ = run_isar_stages(cube, proc)
    return isar_outputs(final, cube, proc)[1]


@pytest.fixture(scope="module")
def dwell_4s():
    scn = load_scenario(ROOT / "isar_theta3.yaml", ["radar.n_pulses=12000", "noise.snr_db=null"])
    cube, stats = simulate_isar_scenario(scn)
    return scn, cube, stats


def test_span_of_a_4s_dwell_matches_the_exact_range_history(dwell_4s):
    scn, cube, stats = dwell_4s
    assert 0 < stats.n0_pulses < cube.n_pulses / 2            # the minimum lies inside the dwell
    r = exact_range(cube)
    assert np.ptp(r) == pytest.approx(8.58, abs=0.01)
    s = run(cube, scn, "none")["summary"]
    res_m = C_MPS / (2 * scn["radar"]["bandwidth_hz"])
    assert abs(s["migration_span_m"] - smoothed_span_m(r)) <= 0.1 * res_m


def test_gate_follows_the_predicted_track_of_the_correction(dwell_4s):
    # keystone2 about the middle leaves R(t) - (t - t_mid) R'(t) / 2: half the walk, not centred on R(t_mid)
    scn, cube, _ = dwell_4s
    met = run(cube, scn, "keystone2")
    e = predicted_envelope_m(exact_range(cube), cube.slow_time_s, met["t_ref_s"], "keystone2")
    res_m = C_MPS / (2 * scn["radar"]["bandwidth_hz"])
    # first order in f/f0 (B/f0 = 0.1 here): agreement within a fifth of a resolution cell
    assert abs(met["summary"]["migration_span_m"] - smoothed_span_m(e)) <= 0.2 * res_m


def test_span_units_are_named_and_consistent():
    scn = load_scenario(ROOT / "isar_theta3.yaml", ["noise.snr_db=null"])
    cube, _ = simulate_isar_scenario(scn)
    s = run(cube, scn, "none")["summary"]
    sample_m = C_MPS / (2 * scn["radar"]["fs_hz"])              # 0.416 m
    res_m = C_MPS / (2 * scn["radar"]["bandwidth_hz"])          # 0.500 m
    assert s["range_sample_m"] == pytest.approx(sample_m) and s["range_resolution_m"] == pytest.approx(res_m)
    span_m = smoothed_span_m(exact_range(cube))                 # 4.16 m of walk over the 2 s dwell
    assert abs(s["migration_span_m"] - span_m) <= 0.1 * res_m
    # CONTRACT section 5's migration_span_cells carries resolution cells c / (2 B)
    assert s["migration_span_cells"] == pytest.approx(s["migration_span_m"] / res_m, rel=1e-12)
    assert s["migration_span_resolution_cells"] == s["migration_span_cells"]
    assert s["migration_span_samples"] == pytest.approx(s["migration_span_m"] / sample_m, rel=1e-12)
    assert s["migration_span_cells"] == pytest.approx(span_m / res_m, abs=0.1)
    assert span_units(12.0, fs_hz=360e6, bandwidth_hz=300e6)["migration_span_resolution_cells"] == \
        pytest.approx(10.0)
