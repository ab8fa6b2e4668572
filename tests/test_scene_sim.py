"""The scene simulator (scene_sim.py) against the exact per-target one (simulate.simulate_echo)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fwdlook_cli.dsp.antenna import MonopulseAntenna
from fwdlook_cli.scenario.loader import load_scenario
from fwdlook_cli.dsp.geometry import azimuth_deg, scan_angle_deg
from fwdlook_cli.scenario.forward import scene_geometry
from fwdlook_cli.dsp.pulse import CompressedPulse
from fwdlook_cli.forward.scene_sim import gate_angle_deg, simulate_scene_echo, visible_intervals
from fwdlook_cli.dsp.geometry import range_extent_m
from fwdlook_cli.dsp.pulse import auto_range_axis_m
from fwdlook_cli.forward.simulate import simulate_echo

PAPER = Path(__file__).resolve().parents[1] / "scenarios" / "paper_fig6_a50.yaml"


def _paper_setup(n_targets=40, seed=3):
    scn = load_scenario(PAPER)
    radar, ant = scn["radar"], scn["antenna"]
    t, pos, _, _, _ = scene_geometry(scn)
    rng = np.random.default_rng(seed)
    tg = np.column_stack([rng.uniform(-300, 300, n_targets), rng.uniform(1500, 1900, n_targets),
                          np.zeros(n_targets)])
    amps = rng.uniform(0.2, 1.0, n_targets) * rng.choice([-1.0, 1.0], n_targets)  # sign: phase pi
    pulse = CompressedPulse(radar["bandwidth_hz"], radar["pulse_width_s"], radar["fs_hz"])
    antenna = MonopulseAntenna(ant["beamwidth_3db_deg"], ant["squint_deg"])
    beam = scan_angle_deg(t, ant["scan_start_deg"], ant["scan_rate_dps"])
    rm = auto_range_axis_m(*range_extent_m(pos, tg), radar["fs_hz"], pulse)
    kw = dict(fc_hz=radar["fc_hz"], pulse=pulse, antenna=antenna, gain_threshold_db=-60.0)
    return t, pos, beam, rm, tg, amps, kw


def _err_db(ref, test):
    return 10 * np.log10(np.sum(np.abs(test - ref) ** 2) / np.sum(np.abs(ref) ** 2))


@pytest.fixture(scope="module")
def paper_exact():
    t, pos, beam, rm, tg, amps, kw = _paper_setup()
    es, ed, st = simulate_echo(t, pos, beam, rm, tg, amps, **kw)
    return (t, pos, beam, rm, tg, amps, kw), (es, ed, st)


@pytest.mark.parametrize("method", ["nufft", "direct"])
def test_scene_sim_matches_exact_simulator(paper_exact, method):
    """Relative error energy below -50 dB in both channels, same gated pair count (paper radar)."""
    (t, pos, beam, rm, tg, amps, kw), (es, ed, st) = paper_exact
    fs, fd, st2 = simulate_scene_echo(t, pos, beam, rm, tg, amps, method=method, block_pulses=16,
                                      max_chunk_pairs=20_000, **kw)   # small chunks: many block edges
    assert st2.n_pairs_kept == st.n_pairs_kept
    assert _err_db(es, fs) < -50.0
    assert _err_db(ed, fd) < -50.0


def test_complex_amplitude_is_a_phase(paper_exact):
    """A target of amplitude |a| exp(j phi) gives exp(j phi) times the echo of |a|."""
    (t, pos, beam, rm, tg, amps, kw), _ = paper_exact
    one, a = tg[:1], np.array([0.7])
    s0, d0, _ = simulate_scene_echo(t, pos, beam, rm, one, a, method="nufft", **kw)
    s1, d1, _ = simulate_scene_echo(t, pos, beam, rm, one, a * np.exp(1j * 1.1), method="nufft", **kw)
    assert _err_db(np.exp(1j * 1.1) * s0, s1) < -60.0
    assert _err_db(np.exp(1j * 1.1) * d0, d1) < -60.0


def test_visible_interval_is_the_gain_gate(paper_exact):
    """Every pulse passing the dense gain gate lies in [n0, n1], and the interval is tight."""
    (t, pos, beam, rm, tg, amps, kw), _ = paper_exact
    ant = kw["antenna"]
    gate = gate_angle_deg(ant, -60.0)
    assert 40.0 * np.log10(ant.sum_voltage(gate)) == pytest.approx(-60.0, abs=1e-9)
    n0, n1, exact = visible_intervals(pos, beam, tg, gate)
    assert exact
    g_sum, _ = ant.two_way_gains(azimuth_deg(pos, tg) - beam[None, :])
    keep = 20 * np.log10(np.maximum(g_sum, 1e-300)) >= -60.0
    n = np.arange(len(beam))[None, :]
    inside = (n >= n0[:, None]) & (n <= n1[:, None])
    assert not np.any(keep & ~inside)
    assert np.all(np.sum(inside & ~keep, axis=1) <= 2)


def test_range_extent_bound_contains_exact():
    t, pos, beam, rm, tg, amps, kw = _paper_setup(n_targets=30)
    lo, hi = range_extent_m(pos, tg)
    blo, bhi = range_extent_m(pos, tg, dense_limit=1)       # the strided bound
    assert blo <= lo and bhi >= hi
    assert lo - blo < 5.0 and bhi - hi < 5.0
