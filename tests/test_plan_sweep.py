"""`plan` against closed forms, `processing.method: auto`, and `sweep` (grid, combine, outputs)."""
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from fwdlook_cli.cli import main
from fwdlook_cli.scenario.loader import load_scenario
from fwdlook_cli.dsp.geometry import C_MPS, residual_velocity_mps
from fwdlook_cli.forward.plan import plan_for_scenario

ROOT = Path(__file__).resolve().parent.parent


def paper(name, *sets):
    return load_scenario(ROOT / "scenarios" / name, list(sets))


def test_plan_paper_a0_closed_forms():
    scn = paper("paper_fig5_a0.yaml")
    p = plan_for_scenario(scn)
    assert p["half_range_cell_m"] == pytest.approx(C_MPS / (2 * 60e6) / 2)
    assert p["ambiguity_number_boresight"] == 12
    assert p["ambiguity_number_range"] == [11, 12]           # the paper: 12 at 0 deg, 11 at 10 deg
    # no acceleration: the curvature is the geometry's own, v^2 sin^2(theta) over R (v level along +y;
    # (|v|^2 - (v.u)^2) / R with u the line of sight), largest at the scan's first pulse
    lever = p["t_ref_s"] + p["dwell_s"] / 2
    cos_phi = np.cos(np.radians(p["depression_deg"]))
    geometric = 240.0**2 * (1 - (np.cos(np.radians(15.0)) * cos_phi) ** 2) / p["reference_range_m"]
    assert p["range_curvature_m"] == pytest.approx(0.5 * geometric * lever**2, rel=1e-6)
    assert not p["needs_curvature"]
    assert p["doppler_centroid_drift_hz"] == pytest.approx(0.0, abs=1e-6)
    # one wrong F acting for the longest lever arm (the scan's first pulse, where F is 11):
    # eq. (19) x (|t - t_ref| + dwell / 2)
    lever = p["t_ref_s"] + p["dwell_s"] / 2
    assert p["traditional_residual_walk_m"] == pytest.approx(residual_velocity_mps(2500, 18e9) * lever, rel=1e-6)
    q25 = next(r for r in p["decimation"] if r["q"] == 25)
    assert q25["residual_walk_m"] == pytest.approx(q25["ambiguity_spread"] * residual_velocity_mps(2500, 18e9, 25)
                                                   * lever, rel=1e-6)
    assert p["processing"]["method"] == "tracking"           # no Q keeps the residual under half a cell


def test_plan_curvature_and_drift_at_a50():
    p = plan_for_scenario(paper("paper_fig6_a50.yaml"))
    lever = p["t_ref_s"] + p["dwell_s"] / 2
    cos_phi = np.cos(np.radians(p["depression_deg"]))
    # R'' = v^2 (1 - cos^2(theta) cos^2(phi)) / R - a cos(theta) cos(phi) at the scan's first pulse (the
    # longest lever; v = 240 m/s, theta = -15 deg): eq. 12's a cos(phi) less the geometry's own curvature
    c = np.cos(np.radians(15.0)) * cos_phi
    d2r = 240.0**2 * (1 - c**2) / p["reference_range_m"] - 50.0 * c
    assert p["range_curvature_m"] == pytest.approx(0.5 * abs(d2r) * lever**2, rel=1e-6)
    assert p["accel_mps2"] == pytest.approx([0.0, 50.0, 0.0], abs=1e-6)
    # eq. (25): the beam-centre Doppler drifts by 2 a t cos(theta) cos(phi) / lambda; largest on the last
    # pulse (t = 0.9996 s, theta = 14.99 deg)
    t_last, theta_last = 2499 / 2500, -15.0 + 30.0 * 2499 / 2500
    drift = 2 * 50.0 * t_last * np.cos(np.radians(theta_last)) * cos_phi * 18e9 / C_MPS
    assert abs(p["doppler_centroid_drift_hz"]) == pytest.approx(drift, rel=1e-6)
    assert p["processing"]["range_curvature"] and p["processing"]["doppler_centroid"]


@pytest.mark.parametrize("height_m, steep", [(50.0, False), (1000.0, True)])
def test_plan_doppler_across_the_range_extent(height_m, steep):
    """The boresight Doppler 2 v cos(phi(r)) / lambda across the scene's slant ranges (v along +y at
    t_ref, no vertical speed): 7 Hz at 50 m of height, over a CPI Doppler cell (78 Hz) at 1000 m, where
    the chain's CPI band covers the window's depressions."""
    p = plan_for_scenario(paper("paper_fig6_a50.yaml", f"platform.height_m={height_m}"))
    near, far = p["range_extent_m"]
    v = 240.0 + 50.0 * np.rint(p["t_ref_s"] * 2500.0) / 2500.0          # the speed at the pulse nearest t_ref
    expect = 2 * v * 18e9 / C_MPS * abs(np.sqrt(1 - (height_m / far) ** 2) - np.sqrt(1 - (height_m / near) ** 2))
    assert p["doppler_range_spread_hz"] == pytest.approx(expect, rel=1e-6)
    assert p["band_over_depressions"] is steep


def test_plan_command_text_and_json(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["plan", str(ROOT / "scenarios" / "tiny.yaml"), "--json"])
    assert exc.value.code == 0
    out = json.loads(capsys.readouterr().out)
    assert out["processing"]["method"] in ("none", "traditional", "decimation", "tracking")
    with pytest.raises(SystemExit) as exc:
        main(["plan", str(ROOT / "scenarios" / "tiny.yaml")])
    assert exc.value.code == 0 and "=> method" in capsys.readouterr().out


def test_method_auto_runs_the_planned_method(tmp_path, capsys):
    scn_path = ROOT / "scenarios" / "tiny.yaml"
    planned = plan_for_scenario(load_scenario(scn_path))["processing"]["method"]
    with pytest.raises(SystemExit) as exc:
        main(["run", str(scn_path), "-o", str(tmp_path), "--set", "processing.method=auto", "-q"])
    assert exc.value.code == 0
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["method"] == planned


def test_sweep_grid_combine_and_outputs(tmp_path, capsys):
    sweep = {"name": "t", "scenarios": [str(ROOT / "scenarios" / "tiny.yaml")],
             "set": ["noise.snr_db=null"],
             "grid": {"scene.points_m": [[[-150.0, 1000.0]], [[120.0, 990.0]]],
                      "processing.method": ["tracking", "beam"]},
             "combine": ["scene.points_m"]}
    path = tmp_path / "sweep.yaml"
    path.write_text(yaml.safe_dump(sweep))
    with pytest.raises(SystemExit) as exc:
        main(["sweep", str(path), "-o", str(tmp_path / "out"), "-q"])
    assert exc.value.code == 0
    rows = json.loads((tmp_path / "out" / "summary.json").read_text())["rows"]
    # two methods, each the union of the two single-point runs
    assert sorted(r["processing.method"] for r in rows) == ["beam", "tracking"]
    assert all(r["n_targets"] == 2 and r["runs"] == 2 for r in rows)
    for r in rows:
        members = [json.loads(p.read_text()) for p in Path(r["run_dir"]).glob("*/metrics.json")
                   if f"method={r['processing.method']}" in p.parent.name.split(",")]
        assert len(members) == 2
        errors = [abs(t["range_error_m"]) for m in members for t in m["targets"]]
        assert r["max_abs_range_error_m"] == pytest.approx(max(errors))
    assert not list((tmp_path / "out").glob("*/*/stages"))        # stage files pruned
    for name in ("summary.md", "summary.csv", "speed_accuracy.png"):
        assert (tmp_path / "out" / name).stat().st_size > 100
    # the table says how many of the targets each row found; and the report reads the combined summary
    # (an independent review: "rows[0]: the grid key scene.points_m is missing", exit 2)
    table = (tmp_path / "out" / "summary.md").read_text()
    assert all(f"| {r['detected']}/{r['n_targets']} |" in table for r in rows)
    with pytest.raises(SystemExit) as exc:
        main(["report", str(tmp_path / "out"), "-o", str(tmp_path / "report"), "-q"])
    assert exc.value.code == 0
    assert (tmp_path / "report" / "index.html").stat().st_size > 1000


def test_a_run_that_missed_targets_is_marked_on_the_sweeps_figures(tmp_path):
    """The summary's errors are over the targets a run found: `none` at a = 50 finds 1 of 3 and reads
    0.09 m against `tracking`'s 0.20 m over 3 of 3.  The figures say so (an independent review found
    `none` drawn as the most accurate): the stability map writes "2 missed" in its cell, the chart
    draws it hollow and labels it (missed_targets), and the table gives 1/3."""
    from fwdlook_cli.report import plots

    calls = []
    real_error_map = plots.error_map

    def spy_map(ax, grid, *args, missed=None, **kwargs):
        calls.append(("map", grid.copy(), None if missed is None else missed.copy()))
        return real_error_map(ax, grid, *args, missed=missed, **kwargs)

    rows = [{"scenario": "tiny", "processing.method": "none", "processing.t_ref": "centre", "detected": 1,
             "n_targets": 3, "max_abs_range_error_m": 0.089, "total_s": 0.04},
            {"scenario": "tiny", "processing.method": "tracking", "processing.t_ref": "centre", "detected": 3,
             "n_targets": 3, "max_abs_range_error_m": 0.205, "total_s": 0.03}]
    assert [plots.missed_targets(r) for r in rows] == [2, 0]
    import unittest.mock as mock

    with mock.patch.object(plots, "error_map", spy_map):
        plots.stability_map(tmp_path / "s.png", rows, ["processing.method", "processing.t_ref"])
    (_, grid, missed), = calls
    assert grid.tolist() == [[0.089, 0.205]] and missed.tolist() == [[2, 0]]
    from matplotlib.axes import Axes

    labels = []
    real_annotate = Axes.annotate
    with mock.patch.object(Axes, "annotate", lambda self, text, *a, **k: labels.append(text) or
                           real_annotate(self, text, *a, **k)):
        plots.speed_accuracy_chart(tmp_path / "c.png", rows, ["processing.method", "processing.t_ref"])
    assert sorted(labels) == ["none,centre (2 missed)", "tracking,centre"]


def test_sweep_rejects_unknown_keys_and_bad_grid(tmp_path, capsys):
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump({"scenarios": [str(ROOT / "scenarios" / "tiny.yaml")],
                                    "grid": {"processing.method": ["warp"]}}))
    with pytest.raises(SystemExit) as exc:
        main(["sweep", str(path), "-o", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2 and len(err) == 1 and "processing.method" in err[0] and "warp" in err[0]
    path.write_text(yaml.safe_dump({"scenarios": ["tiny.yaml"], "grids": {}}))
    with pytest.raises(SystemExit) as exc:
        main(["sweep", str(path)])
    assert exc.value.code == 2 and "grids" in capsys.readouterr().err


@pytest.mark.parametrize("key, value", [
    ("config", 7), ("config", ["a.yaml"]), ("config", {"a": 1}),                # once: TypeError on a path
    ("combine", [{"a": 1}]), ("combine", [["processing.q"]]),                  # once: unhashable
    ("keep_stages", "no"), ("keep_stages", [1]),                               # once: bool() of anything
    ("set", [7]), ("set", ["processing.q"]), ("name", ["a"])])
def test_a_sweep_files_keys_of_the_wrong_kind_are_one_line(tmp_path, capsys, key, value):
    """Each of the sweep file's own keys takes one kind of value; any other is refused with exit 2 and
    one line naming the file, the key and the value, before any point runs (no output folder)."""
    raw = {"scenarios": [str(ROOT / "scenarios" / "tiny.yaml")], "grid": {"processing.q": [4, 8]}, key: value}
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(raw))
    with pytest.raises(SystemExit) as exc:
        main(["sweep", str(path), "-o", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2 and len(err) == 1, err
    assert str(path) in err[0] and f"{key} = " in err[0] and "Traceback" not in err[0]
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("path", sorted((ROOT / "configs" / "sweeps").glob("*.yaml")), ids=lambda p: p.name)
def test_every_shipped_sweep_resolves_every_point(path, tmp_path):
    """The sweep files the README and `make reproduce` name: each point a valid scenario (a typo in a
    grid key or value is bad input before anything runs), each in its own run directory."""
    from fwdlook_cli.report.sweep_plan import load_sweep, plan_runs

    sweep = load_sweep(str(path))
    runs = plan_runs(sweep, tmp_path, source=str(path))
    n_points = 1
    for values in sweep["grid"].values():
        n_points *= len(values)
    assert len(runs) == n_points * len(sweep["scenarios"])
    assert len({r["run_dir"] for r in runs}) == len(runs)
    for run in runs:
        for key, value in run["point"].items():
            section, _, field = key.partition(".")
            got = run["resolved"][section]
            for part in field.split("."):
                got = got[part]
            assert got == value or (isinstance(value, list) and list(got) == value), (key, got, value)


def _auto_run(tmp_path, sets):
    """`run --set processing.method=auto` of the tiny scene with ``sets``: its metrics."""
    with pytest.raises(SystemExit) as exc:
        main(["run", str(ROOT / "scenarios" / "tiny.yaml"), "-o", str(tmp_path), "-q", "--keep-stages", "none",
              "--set", "processing.method=auto"] + [a for s in sets for a in ("--set", s)])   # (a later --set wins)
    assert exc.value.code == 0
    return json.loads((tmp_path / "metrics.json").read_text())


def test_the_plan_models_a_climbing_or_descending_platform(tmp_path):
    """The closing speed is v . u with the vertical speed: a platform accelerating downwards at 80 m/s^2
    (500 m up) drifts in Doppler by 2 a_z t sin(phi) / lambda, and one F is wrong somewhere (an
    independent review: the plan had said no drift and F = 4 throughout, `auto` chose `traditional`,
    5.1 m off).  The method `auto` then takes places every target within half a range cell."""
    sets = ["platform.accel_mps2=[0,0,-80]", "platform.height_m=500", "antenna.scan_rate_dps=40"]
    scn = load_scenario(ROOT / "scenarios" / "tiny.yaml", sets)
    p = plan_for_scenario(scn)
    sin_phi = np.sin(np.radians(p["depression_deg"]))
    n = int(round(20.0 / 40.0 * scn["radar"]["prf_hz"]))               # the scan's pulses, -10 to 10 deg
    drift = 2 * 80.0 * (n - 1) / scn["radar"]["prf_hz"] * sin_phi * scn["radar"]["fc_hz"] / C_MPS
    assert p["doppler_centroid_drift_hz"] == pytest.approx(drift, rel=1e-6)
    assert p["accel_mps2"] == pytest.approx([0.0, 0.0, -80.0], abs=1e-6)
    assert p["ambiguity_number_range"][0] < p["ambiguity_number_range"][1]
    assert p["processing"]["method"] != "traditional" and p["processing"]["doppler_centroid"]
    m = _auto_run(tmp_path, sets)
    assert m["summary"]["detected"] == 3
    assert m["summary"]["max_abs_range_error_m"] < p["half_range_cell_m"]


def test_the_plan_counts_the_scans_own_range_curvature(tmp_path):
    """Without acceleration a +-45 deg scan still curves every range history by v^2 sin^2(theta) / R
    (the review: 14 m, planned as 0, `auto` ran without the curvature stage, 5.7 m off).  The plan's
    curvature is that closed form at the scan's first pulse; `auto` turns the stage on, which takes
    more than half of the worst error away (-10.7 to -3.3 m at 27.6 deg; what stays is over half a
    range sample there: the README says so)."""
    sets = ["antenna.scan_start_deg=-45", "antenna.scan_stop_deg=45", "antenna.scan_rate_dps=30",
            "platform.accel_mps2=[0,0,0]", "scene.points_m=[[-600,900],[0,1030],[300,800]]"]
    p = plan_for_scenario(load_scenario(ROOT / "scenarios" / "tiny.yaml", sets))
    lever = p["t_ref_s"] + p["dwell_s"] / 2
    c = np.cos(np.radians(45.0)) * np.cos(np.radians(p["depression_deg"]))
    assert p["range_curvature_m"] == pytest.approx(0.5 * 150.0**2 * (1 - c**2) / p["reference_range_m"] * lever**2,
                                                   rel=1e-6)
    assert p["processing"]["range_curvature"]
    m = _auto_run(tmp_path / "auto", sets)
    assert m["params"]["range_curvature"] and m["summary"]["detected"] == 3
    off = _auto_run(tmp_path / "off", sets + ["processing.method=tracking", "processing.range_curvature=false"])
    assert m["summary"]["max_abs_range_error_m"] < 0.5 * off["summary"]["max_abs_range_error_m"]


def test_bulk_says_the_walk_its_shift_leaves(tmp_path, capsys):
    """`bulk` shifts every direction by the INS motion along +y at the reference depression
    (motion.bulk_range_history_m), so the scan's cos theta, a heading off +y or a climb leave walk that it
    never corrects (an independent review: 7.7-8.1 m off on a track heading -35 deg, exit 0 and no word,
    where `traditional` and `decimation` said theirs).  The plan's budget for it is the closing speed
    v . u(theta) less bulk's v_y cos(phi) over each direction's lever: for a straight track along +y that is
    v cos(phi) (1 - cos theta) lever, whose largest is at the scan's ends (closed form here); a +-45 deg scan
    leaves more than half a range sample, the run says so in one line and its targets are within the
    budget; the tiny scan (+-10 deg) holds it, without a word."""
    from cli_runner import run_cli

    from fwdlook_cli.forward.plan import plan_geometry

    prf, v, h, r_ref = 2000.0, 150.0, 50.0, 1000.0
    t = np.arange(1200) / prf
    scan = -45.0 + 75.0 * t
    vel = np.tile([0.0, v, 0.0], (len(t), 1))
    pos = np.column_stack([np.zeros_like(t), v * t, np.full_like(t, h)])
    p = plan_geometry(t, pos, vel, scan, fc_hz=10e9, prf_hz=prf, fs_hz=24e6, beamwidth_deg=6.0,
                      reference_range_m=r_ref, t_ref_s=float(t[len(t) // 2]), cpi=16)
    phi = np.arcsin(h / r_ref)
    lever = np.abs(t - t[len(t) // 2]) + p["dwell_s"] / 2
    ends = [0, len(t) - 1]
    assert p["bulk_residual_walk_m"] == pytest.approx(
        max(v * np.cos(phi) * (1 - np.cos(np.radians(scan[i]))) * lever[i] for i in ends), rel=1e-9)
    wide = ["--set", "antenna.scan_start_deg=-45", "--set", "antenna.scan_stop_deg=45", "--set",
            "antenna.scan_rate_dps=30", "--set", "scene.points_m=[[-600,900],[0,1030],[300,800]]"]
    half = C_MPS / (2 * 24e6) / 2
    for name, sets in (("tiny", []), ("wide", wide)):
        code, out, err = run_cli(["run", str(ROOT / "scenarios" / "tiny.yaml"), "-o", str(tmp_path / name),
                                  "--keep-stages", "none", "--set", "processing.method=bulk",
                                  "--set", "processing.imaging=cpi"] + sets, capsys)
        assert code == 0, err
        m = json.loads((tmp_path / name / "metrics.json").read_text())
        said = [line for line in err.splitlines() if "processing.method bulk" in line]
        worst = max(abs(t["range_error_m"]) for t in m["targets"] if t["detected"])
        if name == "tiny":
            assert said == [] and worst < half
        else:
            budget = float(said[0].split("leaves up to ")[1].split(" m")[0])
            assert len(said) == 1 and half < worst <= budget, (worst, budget)


def test_one_depression_error_closed_form():
    """motion.depression_reference_error_m against the boresight Doppler written out: a shift by the
    reference's range history leaves lambda / 2 |df| per second, a keystone at the rate PRF the folded
    part, lambda / 2 round(df / PRF) PRF."""
    from fwdlook_cli.forward.motion import depression_reference_error_m

    lam, v, h, ref, lever = C_MPS / 10e9, 150.0, 3000.0, 4000.0, 0.3
    r = np.array([3300.0, 3600.0, 4000.0, 4500.0, 5000.0])
    df = 2 * v * (np.sqrt(1 - (h / r) ** 2) - np.sqrt(1 - (h / ref) ** 2)) / lam
    shift = depression_reference_error_m(h, r, ref, [0.0, v, 0.0], 10e9, lever)
    folded = depression_reference_error_m(h, r, ref, [0.0, v, 0.0], 10e9, lever, rate_hz=2000.0)
    assert shift == pytest.approx(lam / 2 * np.abs(df) * lever, rel=1e-12)
    assert folded == pytest.approx(lam / 2 * np.abs(np.rint(df / 2000.0)) * 2000.0 * lever, rel=1e-12)
    assert folded[2] == 0.0 and folded[0] > 0.0          # 3300 m folds (df = -1.3 kHz), the reference does not


@pytest.mark.parametrize("method", ["tracking", "beam"])
def test_one_reference_depression_at_steep_depression_is_measured_and_said(tmp_path, capsys, method):
    """3 km up, slant ranges 3.6-4.7 km: the boresight Doppler changes by 3.6 kHz across the window, more
    than the PRF (2 kHz). With one reference depression (`processing.subswaths: none`) `tracking` resolves
    +-PRF / 2 about the reference's Doppler, so the near point (df -1.4 kHz) folds by one ambiguity and
    lands lambda PRF / 2 metres per second of its lever from t_ref off in range (an independent review:
    13.6 m, exit 0, no warning): measured against that closed form, and said in one warning naming the
    span; `beam` shifts by the reference's range history and is off too. With sub-swaths (`auto`, the
    default) every point is within half a range sample, and the run says how many it used."""
    from cli_runner import run_cli

    raw = yaml.safe_load((ROOT / "scenarios" / "tiny.yaml").read_text())
    raw["antenna"]["scan_rate_dps"] = 25.0
    raw["platform"]["height_m"] = 3000.0
    raw["scene"]["points_m"] = [[300.0, 2000.0], [-300.0, 3600.0], [0.0, 2800.0], [200.0, 2300.0]]
    raw["noise"]["snr_db"] = None
    raw["processing"].update(method=method, q=1, cpi=32, imaging="cpi")
    path = tmp_path / "steep.yaml"
    path.write_text(yaml.safe_dump(raw))
    half = C_MPS / (2 * 24e6) / 2
    runs = {}
    for mode in ("none", "auto"):
        code, out, err = run_cli(["run", str(path), "-o", str(tmp_path / mode), "--set", f"processing.subswaths={mode}"],
                                 capsys)
        assert code == 0, err
        runs[mode] = ({round(t["x_m"]): t for t in json.loads((tmp_path / mode / "metrics.json").read_text())["targets"]},
                      err)
    rows, err = runs["none"]
    said = [line for line in err.splitlines() if "one reference depression" in line]
    assert len(said) == 1 and "processing.subswaths: auto corrects the window" in said[0]
    assert abs(rows[300]["range_error_m"]) > half and abs(rows[0]["range_error_m"]) < half
    if method == "tracking":
        lam, prf = C_MPS / 10e9, 2000.0
        t_ref = json.loads((tmp_path / "none" / "metrics.json").read_text())["t_ref_s"]
        t_seen = (rows[300]["true_azimuth_deg"] + 10.0) / 25.0        # the beam on its azimuth (-10 deg, 25 deg/s)
        assert abs(rows[300]["range_error_m"]) == pytest.approx(lam / 2 * prf * abs(t_seen - t_ref), rel=0.1)
    rows, err = runs["auto"]
    assert "sub-swaths, one reference depression each" in err and "one reference depression (" not in err
    assert all(abs(t["range_error_m"]) < half for t in rows.values()), {x: t["range_error_m"] for x, t in rows.items()}
    # the paper's windows (50 m up) hold one depression by far
    p = plan_for_scenario(paper("paper_fig6_a50.yaml"))
    assert p["one_depression"]["keystone"]["error_m"] < 0.1 * p["half_range_cell_m"]


def test_sub_swaths_leave_no_ghost_at_the_windows_ends(tmp_path, capsys):
    """Two points inside a steep window (3 km up, 3350-4900 m of slant range, +-8 deg, t_ref = centre) whose
    echoes walk into the first and last sub-swaths' spans: with no padding beyond the window's ends the
    correction moved them out again and the cyclic transform wrapped them into those cores, ghosts at
    -0.1 and -1.2 dB at the window's ends (a second independent review). Padded with zeros on both sides,
    nothing within 20 dB of the peak lies more than 60 m from a point."""
    import h5py
    from cli_runner import run_cli

    h, prf, rate = 3000.0, 2000.0, 25.0
    t_ref = (int(round(20.0 / rate * prf)) - 1) / prf / 2
    y_ref = 150.0 * t_ref + 5.0 * t_ref**2                   # tiny's platform: 150 m/s, 10 m/s^2 along y

    def ground(r, az):
        g = np.sqrt(r * r - h * h)
        return [float(g * np.sin(np.radians(az))), float(y_ref + g * np.cos(np.radians(az)))]

    raw = yaml.safe_load((ROOT / "scenarios" / "tiny.yaml").read_text())
    raw["antenna"]["scan_rate_dps"] = rate
    raw["platform"]["height_m"] = h
    raw["radar"]["range_window_m"] = [3350.0, 4900.0]
    raw["scene"]["points_m"] = [ground(3870.0, 8.0), ground(4385.0, -8.0)]
    raw["noise"]["snr_db"] = None
    raw["processing"].update(method="tracking", q=1, cpi=32, imaging="cpi")
    path = tmp_path / "edges.yaml"
    path.write_text(yaml.safe_dump(raw))
    code, out, err = run_cli(["run", str(path), "-o", str(tmp_path / "r")], capsys)
    assert code == 0, err
    m = json.loads((tmp_path / "r" / "metrics.json").read_text())
    assert m["params"]["subswaths"] > 1 and all(abs(t["range_error_m"]) < 1.0 for t in m["targets"])
    with h5py.File(tmp_path / "r" / "image.h5") as f:
        image, range_m = f["image"][()], f["range_m"][()]
    far = np.min(np.abs(range_m[:, None] - np.array([t["true_range_m"] for t in m["targets"]])[None, :]), axis=1) > 60.0
    assert image[far].max() < 0.01 * image.max(), 10 * np.log10(image[far].max() / image.max())


def test_steep_window_at_35_ghz_with_t_ref_start_is_held(tmp_path, capsys):
    """35 GHz, 3 km up, t_ref = start: targets are seen up to 0.8 s after t_ref, 100 m nearer, where the
    boresight Doppler changes 3.5 times faster with range than at 10 GHz. With one reference depression
    fixed in time the sub-swaths' cores had still folded targets half a sample inside their edges (a
    second independent review: 5.5-6.6 m); `tracking` now follows its reference point's depression as
    the platform closes in (motion.tracked_depression_deg, where that moves its Doppler by over 1 % of
    the PRF), and the cores keep a guard band: a point every 74 m across the window, all within half a
    range sample (one reference for the window: 8 of the 20 off, by up to 15.3 m)."""
    import numpy as np
    from cli_runner import run_cli

    h = 3000.0

    def ground(r, az):
        g = np.sqrt(r * r - h * h)
        return [float(g * np.sin(np.radians(az))), float(g * np.cos(np.radians(az)))]

    raw = yaml.safe_load((ROOT / "scenarios" / "tiny.yaml").read_text())
    raw["antenna"]["scan_rate_dps"] = 25.0
    raw["platform"]["height_m"] = h
    raw["radar"].update(range_window_m=[3350.0, 4900.0], fc_hz=35e9)
    raw["scene"]["points_m"] = [ground(r, 8.0 if i % 2 else -8.0) for i, r in enumerate(np.arange(3420.0, 4840.0, 74.0))]
    raw["noise"]["snr_db"] = None
    raw["processing"].update(method="tracking", q=1, cpi=32, imaging="cpi", t_ref="start")
    path = tmp_path / "ka.yaml"
    path.write_text(yaml.safe_dump(raw))
    code, out, err = run_cli(["-q", "run", str(path), "-o", str(tmp_path / "r")], capsys)
    assert code == 0, err
    m = json.loads((tmp_path / "r" / "metrics.json").read_text())
    half = C_MPS / (2 * 24e6) / 2
    assert m["summary"]["detected"] == len(m["targets"]) == 20
    assert max(abs(t["range_error_m"]) for t in m["targets"]) < half


def test_a_shallow_window_near_a_half_ambiguity_gets_no_sub_swath():
    """50 m up, a 110 m window, `traditional`: the boresight Doppler changes by a fraction of a hertz across
    it, but sits 0.45 PRF from a whole ambiguity number, inside the guard band. The plan had returned one
    padded sub-swath (a third review: the keystone twice as slow and off the GPU, the same numbers); one
    piece is no split: None, as for a Doppler on a whole number."""
    from fwdlook_cli.forward.subswath import plan_subswaths

    lam, prf, h = C_MPS / 10e9, 2000.0, 50.0
    r = np.arange(990.0, 1100.0, 6.25)
    for ratio in (5.0, 5.45):
        v = ratio * prf * lam / (2.0 * np.sqrt(1.0 - (h / 1045.0) ** 2))     # f0 = ratio x PRF at mid-window
        plan, left = plan_subswaths(height_m=h, range_m=r, velocity_mps=[0.0, v, 0.0], fc_hz=10e9, prf_hz=prf, q=1,
                                    method="traditional", lever_s=0.24, walk_m=40.0, bandwidth_hz=20e6)
        assert plan is None, (ratio, plan)
