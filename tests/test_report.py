"""``fwdlook report`` and the reproduction's Sec. 4.1 table (fast: two tiny runs, no paper cube).

The report's tables are checked against the metrics.json they come from (parsed back out of
report.md), its figures are opened as PNGs; bad input exits 2 with one line naming the path.
The reproduction's section (a) is checked against the closed forms of paper eq. (16), (17), (19), (20).
"""
from __future__ import annotations

import json
import os
import math
import struct
from pathlib import Path

import numpy as np
import pytest

from fwdlook_cli.cli import main
from fwdlook_cli.dsp.geometry import C_MPS
from fwdlook_cli.report.tables import SIG_DIGITS, parse_md_table, parse_value
from cli_runner import run_cli

REPO = Path(__file__).resolve().parents[1]
TINY = REPO / "scenarios" / "tiny.yaml"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
METHODS = ("tracking", "decimation")


@pytest.fixture(scope="module")
def tiny_runs(tmp_path_factory):
    """The tiny scenario run twice, with two methods, into temporary run directories."""
    base = tmp_path_factory.mktemp("runs")
    dirs = []
    for method in METHODS:
        run_dir = base / method
        with pytest.raises(SystemExit) as exc_info:
            main(["run", str(TINY), "-o", str(run_dir), "--set", f"processing.method={method}", "-q"])
        assert exc_info.value.code == 0
        assert (run_dir / "metrics.json").exists()
        dirs.append(run_dir)
    return dirs


@pytest.fixture(scope="module")
def report_dir(tiny_runs, tmp_path_factory):
    out = tmp_path_factory.mktemp("report")
    with pytest.raises(SystemExit) as exc_info:
        main(["report", *map(str, tiny_runs), "-o", str(out), "-q"])
    assert exc_info.value.code == 0
    return out


def _section(lines, heading):
    """Lines from ``heading`` up to the next heading of the same or higher level."""
    level = heading.split(" ")[0]
    start = lines.index(heading)
    end = len(lines)
    for i in range(start + 1, len(lines)):
        if lines[i].startswith("#") and len(lines[i].split(" ")[0]) <= len(level):
            end = i
            break
    return lines[start + 1:end]


def _subsection(lines, heading):
    start = lines.index(heading)
    end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("#")), len(lines))
    return lines[start + 1:end]


def _close(printed, value):
    """A printed number equals the metrics.json value to the report's SIG_DIGITS digits."""
    if value is None:
        return printed is None
    if isinstance(value, bool):
        return printed is value
    if isinstance(value, int):
        return printed == value
    if isinstance(value, str):
        return printed == value
    return math.isclose(printed, value, rel_tol=10 ** (1 - SIG_DIGITS), abs_tol=1e-12)


def test_report_tables_equal_metrics_json(tiny_runs, report_dir):
    lines = (report_dir / "report.md").read_text(encoding="utf-8").splitlines()
    for run_dir in tiny_runs:
        metrics = json.loads((run_dir / "metrics.json").read_text())
        run_lines = _section(lines, f"## Run `{run_dir.name}`")
        summary = dict(parse_md_table(_subsection(run_lines, "### Summary")))
        assert parse_value(summary["method"]) == metrics["method"]
        assert metrics["method"] == run_dir.name
        assert _close(parse_value(summary["t_ref_s"]), metrics["t_ref_s"])
        for key, value in metrics["params"].items():
            assert _close(parse_value(summary[f"params.{key}"]), value), key
        for key, value in metrics["summary"].items():
            assert _close(parse_value(summary[f"summary.{key}"]), value), key
        heads = [c.strip() for c in _subsection(run_lines, "### Targets")[3].strip("|").split("|")]
        body = parse_md_table(_subsection(run_lines, "### Targets")[3:])
        assert len(body) == len(metrics["targets"]) == 3
        for cells, target in zip(body, metrics["targets"]):
            for head, cell in zip(heads, cells):
                assert _close(parse_value(cell), target.get(head)), (head, cell, target.get(head))
    timing = parse_md_table(_section(lines, "## Timing per stage (s)"))
    by_stage = {row[0]: row[1:] for row in timing}
    for col, run_dir in enumerate(tiny_runs):
        metrics = json.loads((run_dir / "metrics.json").read_text())
        for stage, seconds in metrics["timing_s"].items():
            assert _close(parse_value(by_stage[stage][col]), seconds), stage


@pytest.mark.parametrize("name", ["images.png", "real_beam.png", "range_profiles.png", "errors.png"])
def test_report_figures_are_png(report_dir, name):
    path = report_dir / name
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC
    width, height = struct.unpack(">II", data[16:24])          # IHDR
    assert width >= 300 and height >= 200
    assert len(data) > 10_000
    assert f"]({name})" in (report_dir / "report.md").read_text()
    assert not list(report_dir.glob("*.partial*"))


def test_report_default_dir_for_one_run(tiny_runs, capsys):
    code, out, err = run_cli(["report", tiny_runs[0], "-q"], capsys)
    assert code == 0, err
    assert Path(out.strip()) == tiny_runs[0] / "report" / "report.md"
    assert (tiny_runs[0] / "report" / "images.png").exists()


def test_report_without_metrics_exits_2(tmp_path, capsys):
    empty = tmp_path / "not_a_run"
    empty.mkdir()
    code, out, err = run_cli(["report", empty, "-o", tmp_path / "rep"], capsys)
    assert code == 2
    lines = err.splitlines()
    assert len(lines) == 1 and "Traceback" not in err
    assert str(empty) in lines[0] and "metrics.json" in lines[0]
    assert out == ""
    assert not (tmp_path / "rep").exists()


def _edit_target(key, value):
    def edit(m):
        if value is KeyError:
            del m["targets"][0][key]
        else:
            m["targets"][0][key] = value
    return edit


@pytest.mark.parametrize("edit, named", [
    (lambda m: m.update(summary=[]), "summary = []"),
    (lambda m: m.update(timing_s="fast"), "timing_s = 'fast'"),
    (lambda m: m["timing_s"].update(keystone="fast"), "timing_s.keystone = 'fast'"),
    (lambda m: m.update(params=7), "params = 7"),
    (lambda m: m.update(targets="all"), "targets = 'all'"),
    (lambda m: m["targets"].__setitem__(0, None), "targets[0] = null"),
    (_edit_target("x_m", KeyError), "targets[0].x_m = null"),
    (_edit_target("true_range_m", "far"), "targets[0].true_range_m = 'far'"),
    (_edit_target("meas_azimuth_deg", [1.0]), "targets[0].meas_azimuth_deg = [1.0]"),
], ids=["summary", "timing", "timing-value", "params", "targets", "target", "x-missing", "true-range",
        "meas-azimuth"])
def test_report_of_a_damaged_metrics_json_is_one_line(tiny_runs, tmp_path, capsys, edit, named):
    """A run directory's metrics.json edited by hand or damaged: the parts the report reads are checked
    against the kinds CONTRACT.md section 5 gives them, and a wrong one is one line naming the file and
    the key (each of these once ended in a traceback inside a figure or a table), nothing written."""
    import shutil

    run = tmp_path / "run"
    shutil.copytree(tiny_runs[0], run)
    metrics = json.loads((run / "metrics.json").read_text())
    edit(metrics)
    (run / "metrics.json").write_text(json.dumps(metrics))
    code, out, err = run_cli(["report", run, "-o", tmp_path / "rep"], capsys)
    lines = err.splitlines()
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert str(run / "metrics.json") in lines[0] and named in lines[0], lines[0]
    assert not (tmp_path / "rep").exists()


def _metrics_a_folder(path):
    path.unlink()
    path.mkdir()


@pytest.mark.parametrize("damage, named", [
    (_metrics_a_folder, "cannot read it"),
    (lambda p: p.write_bytes(bytes(range(256)) * 2), "not a UTF-8 text file"),
    (lambda p: p.write_text("{bad"), "not valid JSON"),
], ids=["folder", "binary", "json"])
def test_report_of_an_unreadable_metrics_json_is_one_line(tiny_runs, tmp_path, capsys, damage, named):
    """metrics.json replaced by a folder, binary bytes or broken JSON: one line naming the file (the
    first two once ended in a traceback), nothing written."""
    import shutil

    run = tmp_path / "run"
    shutil.copytree(tiny_runs[0], run)
    damage(run / "metrics.json")
    code, out, err = run_cli(["report", tiny_runs[1], run, "-o", tmp_path / "rep"], capsys)
    lines = err.splitlines()
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert str(run / "metrics.json") in lines[0] and named in lines[0], lines[0]
    assert not (tmp_path / "rep").exists()


@pytest.mark.parametrize("summary, named", [
    ("{bad", "not valid JSON"),
    ("[]", "expected a sweep summary"),
    ('{"grid": {}, "rows": [7]}', "rows[0]"),
    ('{"grid": {"processing.q": [8]}, "rows": [{"scenario": "tiny", "total_s": "slow"}]}', "rows[0].total_s"),
    ('{"grid": {"processing.q": [8]}, "rows": [{"scenario": "tiny", "total_s": 1.0}]}', "processing.q"),
], ids=["json", "list", "row", "time", "grid-key"])
def test_report_of_a_damaged_sweep_summary_is_one_line_and_writes_nothing(tiny_runs, tmp_path, capsys, summary,
                                                                          named):
    """A sweep folder's summary.json is read and checked before any file of the report is written (a
    damaged one ended in a traceback and left a report.md that looked complete)."""
    sweep = tmp_path / "sw"
    sweep.mkdir()
    (sweep / "summary.json").write_text(summary)
    code, out, err = run_cli(["report", tiny_runs[0], sweep, "-o", tmp_path / "rep"], capsys)
    lines = err.splitlines()
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert str(sweep / "summary.json") in lines[0] and named in lines[0], lines[0]
    assert not (tmp_path / "rep").exists()


def test_a_report_that_fails_while_writing_leaves_none_of_its_files(tiny_runs, tmp_path, capsys, monkeypatch):
    """Every file is written aside and moved into place once all are: a failure while writing (here
    index.html's, as on a full disk) leaves the report folder without any of them."""
    from fwdlook_cli.errors import BadInput
    from fwdlook_cli.report import htmlreport

    def full_disk(*args, **kwargs):
        raise BadInput("cannot write index.html: No space left on device")

    monkeypatch.setattr(htmlreport, "render_html", full_disk)
    code, out, err = run_cli(["report", tiny_runs[0], "-o", tmp_path / "rep"], capsys)
    assert code == 2 and "No space left" in err
    assert not (tmp_path / "rep").exists()               # the folder it made, left empty: removed too
    (tmp_path / "mine").mkdir()
    code, out, err = run_cli(["report", tiny_runs[0], "-o", tmp_path / "mine"], capsys)
    assert code == 2 and list((tmp_path / "mine").iterdir()) == []   # a folder it found: kept


def test_a_killed_reports_staging_folder_is_removed_by_the_next_report(tiny_runs, tmp_path, capsys):
    """SIGKILL runs no cleanup: the staging folder of a report whose process is gone is removed by the
    next report into that folder; one of a live process (this one) is not."""
    import subprocess
    import sys

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True).stdout.strip()
    rep = tmp_path / "rep"
    (rep / f".fwdlook-report-{dead}-abc").mkdir(parents=True)
    (rep / f".fwdlook-report-{dead}-abc" / "images.png").write_bytes(b"half")
    (rep / f".fwdlook-report-{os.getpid()}-xyz").mkdir()
    code, out, err = run_cli(["report", tiny_runs[0], "-o", rep], capsys)
    assert code == 0, err
    assert sorted(q.name for q in rep.glob(".fwdlook-report-*")) == [f".fwdlook-report-{os.getpid()}-xyz"]
    assert (rep / "index.html").exists()


@pytest.mark.parametrize("name, change, named", [
    ("range_m", lambda a: a[::-1], "/range_m"),
    ("angle_deg", lambda a: a[:, None], "/angle_deg"),
    ("real_beam", lambda a: a[..., None], "/real_beam: shape"),
    ("real_beam", lambda a: np.array(b"abc"), "/real_beam: dtype"),
    ("ground_x_m", lambda a: a[:0], "/ground_x_m"),
    ("ground_image", lambda a: a.astype(np.complex64), "/ground_image: dtype"),
])
def test_report_of_a_damaged_image_h5_is_one_line(tiny_runs, tmp_path, capsys, name, change, named):
    """image.h5's axes and images are checked before a figure is drawn: an axis not 1-D, not finite or
    not increasing, an image of another shape or of no real numbers is one line naming the dataset
    (each of these once ended in a traceback from matplotlib or scipy)."""
    import shutil

    import h5py

    run = tmp_path / "run"
    shutil.copytree(tiny_runs[0], run)
    with h5py.File(run / "image.h5", "r+") as f:
        data = change(f[name][()])
        del f[name]
        f[name] = data
    code, out, err = run_cli(["report", run, "-o", tmp_path / "rep"], capsys)
    lines = err.splitlines()
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert str(run / "image.h5") in lines[0] and named in lines[0], lines[0]


def test_reproduce_sec41_equals_closed_forms():
    from fwdlook_cli.report.experiments import PAPER_CLAIMS
    from fwdlook_cli.report.reproduce import sec41_table

    rows = {r["key"]: r for r in sec41_table(REPO / "scenarios" / "paper_fig5_a0.yaml")}
    assert rows["F_0deg"]["ours"] == 12 == PAPER_CLAIMS["sec4.1"]["F_0deg"]["value"]
    assert rows["F_10deg"]["ours"] == 11 == PAPER_CLAIMS["sec4.1"]["F_10deg"]["value"]
    assert rows["ambiguity_change_q_10deg"]["ours"] == 4
    # eq. (19)-(20): c F_R / (2 f_c cos phi_0), h = 50 m at 1700 m ground range
    cos_phi0 = math.cos(math.atan2(50.0, 1700.0))
    assert rows["residual_velocity_mps"]["ours"] == pytest.approx(C_MPS * 2500 / (2 * 18e9 * cos_phi0), rel=1e-12)
    assert rows["residual_velocity_mps"]["ours"] == pytest.approx(20.8, abs=0.05)
    assert rows["residual_velocity_q_mps"]["ours"] == pytest.approx(0.83, abs=0.005)
    assert rows["depression_deg"]["ours"] == pytest.approx(math.degrees(math.atan2(50.0, 1700.0)), rel=1e-12)
    assert rows["f_dc0_hz"]["ours"] == pytest.approx(2 * 240 * 18e9 * cos_phi0 / C_MPS, rel=1e-12)


def test_text_with_a_bar_reads_back_as_metrics_json_has_it():
    """A metrics text holding '|' (ISAR's integration_gain_reference, "closed_form N a |p(0)|") is written
    with markdown's escaped bar and read back unchanged, also from a table row (it had been printed
    "/p(0)/", an independent review found)."""
    from fwdlook_cli.report.tables import fmt_value, md_table

    text = "closed_form N a |p(0)|"
    table = md_table(["key", "value"], [["summary.integration_gain_reference", fmt_value(text)], ["n", "3"]])
    rows = parse_md_table(table.splitlines())
    assert rows == [["summary.integration_gain_reference", "closed_form N a \\|p(0)\\|"], ["n", "3"]]
    assert parse_value(rows[0][1]) == text and parse_value(rows[1][1]) == 3
