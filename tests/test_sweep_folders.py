"""A sweep's point folders: checked as ``fwdlook run -o`` checks its folder, always inside the sweep's
folder, never shared by two points; and a point's stage files pruned without touching anything else."""
import hashlib
import json
import shutil
from pathlib import Path

import pytest
import yaml

from fwdlook_cli.cli import main
from fwdlook_cli.io.extra_outputs import remove_stage_files

ROOT = Path(__file__).resolve().parent.parent
TINY = ROOT / "scenarios" / "tiny.yaml"


def _sweep(tmp_path, grid, scenarios=(str(TINY),)):
    path = tmp_path / "sw.yaml"
    path.write_text(yaml.safe_dump({"name": "s", "scenarios": list(scenarios), "grid": grid,
                                    "set": ["noise.snr_db=null"]}))
    return path


def _run(capsys, *args):
    with pytest.raises(SystemExit) as exc:
        main(["sweep", *map(str, args), "-q"])
    return exc.value.code, capsys.readouterr().err.strip().splitlines()


def _hashes(folder: Path) -> dict:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def test_a_point_folder_holding_the_users_files_is_refused_before_anything_runs(tmp_path, capsys):
    point = tmp_path / "out" / "tiny" / "method=decimation"
    (point / "stages").mkdir(parents=True)
    (point / "metrics.json").write_text('{"mine": 1}')
    (point / "stages" / "mine.txt").write_text("my notes")
    (point / "image.png").write_text("my picture")
    before = _hashes(tmp_path / "out")
    code, err = _run(capsys, _sweep(tmp_path, {"processing.method": ["decimation"]}), "-o", tmp_path / "out")
    assert code == 2 and len(err) == 1, err
    assert "metrics.json" in err[0] and "--overwrite" in err[0]
    assert _hashes(tmp_path / "out") == before
    assert not (tmp_path / "out" / "raw").exists()            # refused before any cube was simulated
    # --overwrite replaces what a run writes; the user's other file in stages/ stays
    code, err = _run(capsys, _sweep(tmp_path, {"processing.method": ["decimation"]}), "-o", tmp_path / "out",
                     "--overwrite")
    assert code == 0, err
    assert "fwdlook_version" in json.loads((point / "metrics.json").read_text())
    assert (point / "stages" / "mine.txt").read_text() == "my notes"
    assert [q.name for q in (point / "stages").iterdir()] == ["mine.txt"]   # the run's own stage files gone


def test_a_grid_value_cannot_put_a_point_outside_the_sweeps_folder(tmp_path, capsys):
    victim = tmp_path / "victim"
    (victim / "stages").mkdir(parents=True)
    (victim / "stages" / "mine.txt").write_text("mine")
    sweep = _sweep(tmp_path, {"antenna.pattern_file": ["../../../victim"], "processing.q": [8]})
    code, err = _run(capsys, sweep, "-o", tmp_path / "out")
    assert code == 0, err
    assert [q.name for q in victim.rglob("*")] == ["stages", "mine.txt"]
    rows = json.loads((tmp_path / "out" / "summary.json").read_text())["rows"]
    (run_dir,) = [Path(r["run_dir"]) for r in rows]
    assert run_dir.resolve().parent == (tmp_path / "out" / "tiny").resolve()
    assert "/" not in run_dir.name and (run_dir / "metrics.json").exists()


def test_two_grid_values_that_resolve_to_one_scenario_are_refused(tmp_path, capsys):
    """4 and 4.0 of an integer key: two folders, one scenario, the same run twice and two identical rows
    (an independent review); refused in one line before anything runs."""
    code, err = _run(capsys, _sweep(tmp_path, {"processing.q": [4, 4.0]}), "-o", tmp_path / "o")
    assert code == 2 and len(err) == 1, err
    assert "processing.q=4" in err[0] and "processing.q=4.0" in err[0] and "resolve to one scenario" in err[0]
    assert not (tmp_path / "o").exists()


def test_two_points_that_would_share_a_folder_are_refused(tmp_path, capsys):
    code, err = _run(capsys, _sweep(tmp_path, {"processing.q": [8, "8"]}), "-o", tmp_path / "o")
    assert code == 2 and len(err) == 1, err
    assert "processing.q=8" in err[0] and 'processing.q="8"' in err[0] and "share the folder" in err[0]
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        shutil.copy(TINY, tmp_path / name / "tiny.yaml")
    code, err = _run(capsys, _sweep(tmp_path, {"processing.q": [8]},
                                    scenarios=[str(tmp_path / "a" / "tiny.yaml"), str(tmp_path / "b" / "tiny.yaml")]),
                     "-o", tmp_path / "o")
    assert code == 2 and len(err) == 1, err
    assert "are both named 'tiny'" in err[0], err[0]
    assert not (tmp_path / "o" / "raw").exists()


def test_removing_a_runs_stage_files_removes_fwdlooks_only(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["run", str(TINY), "-o", str(tmp_path / "r"), "-q"])
    assert exc.value.code == 0
    stages = tmp_path / "r" / "stages"
    ours = sorted(q.name for q in stages.iterdir())
    assert len(ours) >= 5
    (stages / "notes.txt").write_text("mine")
    (stages / "01_mine.h5.partial").write_text("a fwdlook partial file's name")
    remove_stage_files(tmp_path / "r")
    assert sorted(q.name for q in stages.iterdir()) == ["notes.txt"]
    (stages / "notes.txt").unlink()
    remove_stage_files(tmp_path / "r")
    assert not stages.exists()                                   # empty: removed


def test_a_users_file_on_a_points_path_is_refused_in_one_line(tmp_path, capsys):
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "tiny").write_text("mine")           # where the scenario's folder would go
    code, err = _run(capsys, _sweep(tmp_path, {"processing.q": [8]}), "-o", tmp_path / "out")
    assert code == 2 and len(err) == 1, err
    assert "is not a directory" in err[0] and str(tmp_path / "out" / "tiny") in err[0]
    assert sorted(q.name for q in (tmp_path / "out").iterdir()) == ["tiny"]
    assert (tmp_path / "out" / "tiny").read_text() == "mine"
