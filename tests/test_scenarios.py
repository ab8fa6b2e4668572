"""Every scenario shipped in scenarios/ validates, and the paper ones say what the paper says."""
from pathlib import Path

import pytest

from fwdlook_cli.scenario.loader import load_scenario, scenario_hash
from fwdlook_cli.scenario.forward import n_pulses, scene_points

SCEN = sorted((Path(__file__).resolve().parent.parent / "scenarios").glob("*.yaml"))


@pytest.mark.parametrize("path", SCEN, ids=[p.stem for p in SCEN])
def test_scenario_validates(path):
    scn = load_scenario(path)
    assert len(scenario_hash(scn)) == 64


@pytest.mark.parametrize("name, accel", [("paper_fig5_a0", 0.0), ("paper_fig6_a10", 10.0),
                                         ("paper_fig6_a50", 50.0)])
def test_paper_scenarios_follow_table_1(name, accel):
    scn = load_scenario(Path(__file__).resolve().parent.parent / "scenarios" / f"{name}.yaml")
    assert scn["radar"]["fc_hz"] == 18e9 and scn["radar"]["bandwidth_hz"] == 50e6
    assert scn["radar"]["prf_hz"] == 2500 and n_pulses(scn) == 2500
    assert scn["antenna"]["beamwidth_3db_deg"] == 6.0 and scn["antenna"]["scan_rate_dps"] == 30.0
    assert scn["platform"]["accel_mps2"] == [0.0, accel, 0.0] and scn["platform"]["height_m"] == 50.0
    pts, _ = scene_points(scn)
    assert len(pts) == 63
    assert min(p[0] for p in pts) == -300.0 and max(p[1] for p in pts) == 1730.0


def test_hash_is_canonical_and_sensitive():
    a = load_scenario(SCEN[0])
    b = load_scenario(SCEN[0], ["noise.seed=2"])
    assert scenario_hash(a) == scenario_hash(load_scenario(SCEN[0]))
    assert scenario_hash(a) != scenario_hash(b)
