"""Reliability corpus (issue 12): no user file lost, no traceback, no silent reuse of damaged data.

Every case asserts: exit 2 (never 1) for the user's mistake or the machine's refusal, exactly one
``fwdlook: error:`` line naming the file and the key or dataset, no traceback, no output that looks
complete (no target file, no ``*.partial``), and the user's files byte-identical afterwards.
Classes: clobbering, full disk (mocked write failure and a real 1 MiB tmpfs), unwritable outputs,
unreadable scenarios, declared and derived sizes, YAML parser edge cases, damaged stage files, huge
attribute values.  Mounts need root; a case that cannot mount is skipped, never passed.
"""
from __future__ import annotations

import errno
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from fwdlook_cli.errors import BadInput
from fwdlook_cli.io import extra_outputs, outputs
from fwdlook_cli.cli import main
from cli_runner import run_cli

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "scenarios" / "tiny.yaml"


# ----------------------------------------------------------------------------------------------
# Helpers
# ----------------------------------------------------------------------------------------------


def assert_refused(code, out, err, *fragments):
    """Exit 2, exactly one 'fwdlook: error:' line on stderr holding every fragment, no traceback."""
    assert code == 2, f"exit {code}, stderr: {err[-2000:]!r}"
    assert "Traceback" not in err and "Traceback" not in out
    lines = err.splitlines()
    assert len(lines) == 1, f"expected one stderr line, got {lines[:5]!r}"
    assert lines[0].startswith("fwdlook: error:"), lines[0]
    for fragment in fragments:
        assert str(fragment) in lines[0], f"{fragment!r} not in: {lines[0]}"
    assert out == ""
    return lines[0]


def snapshot(*roots):
    """{path: bytes} of every regular file under (or at) ``roots``."""
    files = {}
    for root in roots:
        root = Path(root)
        for p in ([root] if root.is_file() else sorted(root.rglob("*"))):
            if p.is_file() and not p.is_symlink():
                files[p] = p.read_bytes()
    return files


def no_partials(*roots):
    return [p for r in roots for p in Path(r).rglob("*.partial*")]


def _sh(*cmd):
    return subprocess.run(cmd, capture_output=True, text=True)


@pytest.fixture
def mount_tmpfs(tmp_path):
    """mount_tmpfs(name, size='1m', ro=False) -> mounted folder; unmounted after the test."""
    mounted = []

    def mount(name, size="1m", ro=False):
        d = tmp_path / name
        d.mkdir()
        opts = f"size={size}" + (",ro" if ro else "")
        r = _sh("mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(d))
        if r.returncode != 0:
            pytest.skip(f"cannot mount a tmpfs here ({r.stderr.strip()[:80]})")
        mounted.append(d)
        return d

    yield mount
    for d in mounted:
        _sh("umount", "-l", str(d))


@pytest.fixture
def scn(tmp_path):
    path = tmp_path / "S.yaml"
    shutil.copyfile(TINY, path)
    return path


@pytest.fixture(scope="module")
def base_run(tiny_raw, tmp_path_factory):
    """A complete run of the tiny cube (process --raw): the reference for the damaged-stage cases."""
    run_dir = tmp_path_factory.mktemp("base") / "run"
    with pytest.raises(SystemExit) as e:
        main(["process", str(tiny_raw), "-o", str(run_dir), "-q"])
    assert e.value.code == 0
    return run_dir


def _targets(run_dir):
    m = json.loads((Path(run_dir) / "metrics.json").read_text())
    return m["targets"], m["summary"]


# ----------------------------------------------------------------------------------------------
# 1. Clobbering
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("overwrite", [False, True])
def test_simulate_never_writes_over_its_scenario(scn, capsys, overwrite):
    before = snapshot(scn)
    code, out, err = run_cli(["simulate", scn, "-o", scn] + (["--overwrite"] if overwrite else []), capsys)
    assert_refused(code, out, err, scn, "input")
    assert snapshot(scn) == before


def test_simulate_never_writes_over_a_symlinked_input(scn, tmp_path, capsys):
    link = tmp_path / "link.h5"
    link.symlink_to(scn)
    before = snapshot(scn)
    code, out, err = run_cli(["simulate", scn, "-o", link, "--overwrite"], capsys)
    assert_refused(code, out, err, link, "input")
    assert snapshot(scn) == before


@pytest.mark.parametrize("content", ["text", "foreign-hdf5"])
def test_simulate_refuses_a_users_file(scn, tmp_path, capsys, content):
    target = tmp_path / "out.h5"
    if content == "text":
        target.write_text("my notes\n")
    else:
        with h5py.File(target, "w") as f:
            f.attrs["format"] = "my-lab-format"
            f["x"] = np.arange(5)
    before = snapshot(target)
    code, out, err = run_cli(["simulate", scn, "-o", target, "-q"], capsys)
    assert_refused(code, out, err, target, "not a fwdlook raw cube", "--overwrite")
    assert snapshot(target) == before and no_partials(tmp_path) == []
    code, out, err = run_cli(["simulate", scn, "-o", target, "-q", "--overwrite"], capsys)
    assert code == 0, err
    assert outputs.h5_format(target) == "fwdlook-raw"


def test_simulate_replaces_its_own_raw_cube(scn, tmp_path, capsys):
    target = tmp_path / "raw.h5"
    for _ in range(2):
        code, _, err = run_cli(["simulate", scn, "-o", target, "-q"], capsys)
        assert code == 0, err
    assert outputs.h5_format(target) == "fwdlook-raw"


def _foreign_raw_cube(path, software):
    """A cube another program wrote in the raw layout: it says format = "fwdlook-raw" too."""
    with h5py.File(path, "w") as f:
        f.attrs["format"], f.attrs["format_version"] = "fwdlook-raw", 1
        if software is not None:
            f.attrs["software"] = software
        f["echo/sum"] = np.ones((4, 3), np.complex64)


@pytest.mark.parametrize("software", ["acme-recorder", None])
def test_simulate_refuses_another_writers_raw_cube(scn, tmp_path, capsys, software):
    target = tmp_path / "recorded.h5"
    _foreign_raw_cube(target, software)
    before = snapshot(target)
    code, out, err = run_cli(["simulate", scn, "-o", target, "-q"], capsys)
    assert_refused(code, out, err, target, "not a fwdlook raw cube",
                   repr(software) if software else "another program", "--overwrite")
    assert snapshot(target) == before and no_partials(tmp_path) == []


def test_run_refuses_a_folder_holding_another_writers_raw_cube(scn, tmp_path, capsys):
    d = tmp_path / "flight7"
    d.mkdir()
    _foreign_raw_cube(d / "raw.h5", "acme-recorder")
    before = snapshot(d)
    code, out, err = run_cli(["run", scn, "-o", d, "-q"], capsys)
    assert_refused(code, out, err, d, "not a fwdlook run directory", "raw.h5")
    assert snapshot(d) == before


@pytest.mark.parametrize("command", ["simulate", "run", "report"])
def test_a_dotdot_through_a_missing_folder_does_not_pass_the_guard(scn, base_run, tmp_path, capsys, monkeypatch,
                                                                   command):
    """`nodir/../mine` is `mine` once `nodir` is made: the guard checks that path, not the one that
    the OS cannot resolve yet (the user's file was replaced before)."""
    monkeypatch.chdir(tmp_path)
    if command == "simulate":
        Path("mine.h5").write_text("my notes\n")
        mine, argv = Path("mine.h5"), ["simulate", scn, "-o", "nodir/../mine.h5", "-q"]
    elif command == "run":
        Path("mine").mkdir()
        (Path("mine") / "metrics.json").write_text('{"my": "numbers"}')
        mine, argv = Path("mine"), ["run", scn, "-o", "nodir/../mine", "-q"]
    else:
        Path("mine").mkdir()
        (Path("mine") / "report.md").write_text("# my report\n")
        mine, argv = Path("mine"), ["report", base_run, "-o", "nodir/../mine", "-q"]
    before = snapshot(mine)
    code, out, err = run_cli(argv, capsys)
    assert_refused(code, out, err, "mine", "refusing to overwrite it")
    assert snapshot(mine) == before and not Path("nodir").exists()


@pytest.mark.parametrize("with_metrics", [False, True])
def test_a_run_folder_holding_a_users_file_beside_a_cube_is_refused(scn, tiny_raw, tmp_path, capsys, with_metrics):
    """A fwdlook raw.h5 makes a folder fwdlook's, but not the user's notes beside it: each file a run
    would replace is checked (scenario.yaml and image.png, which carry no mark of their own, are
    fwdlook's only beside a fwdlook metrics.json)."""
    d = tmp_path / "flight7"
    d.mkdir()
    shutil.copyfile(tiny_raw, d / "raw.h5")
    (d / "scenario.yaml").write_text("my: notes\n")
    if with_metrics:
        (d / "metrics.json").write_text('{"my": "numbers"}')
    before = snapshot(d)
    code, out, err = run_cli(["process", d / "raw.h5", "-o", d, "-q"], capsys)
    assert_refused(code, out, err, d / "scenario.yaml", "fwdlook did not write it", "--overwrite")
    code, out, err = run_cli(["run", scn, "-o", d, "-q"], capsys)
    assert_refused(code, out, err, "fwdlook did not write it")
    assert snapshot(d) == before


def test_a_dotdot_output_lands_where_it_says_and_makes_no_folder(scn, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, _, err = run_cli(["simulate", scn, "-o", "nodir/../new.h5", "-q"], capsys)
    assert code == 0, err
    assert Path("new.h5").is_file() and not Path("nodir").exists()


def test_a_users_stage_file_beside_a_cube_is_refused(scn, tiny_raw, tmp_path, capsys):
    d = tmp_path / "m"
    (d / "stages").mkdir(parents=True)
    shutil.copyfile(tiny_raw, d / "raw.h5")
    (d / "stages" / "01_range_fft.h5").write_text("mine\n")
    before = snapshot(d)
    code, out, err = run_cli(["run", scn, "-o", d, "-q"], capsys)
    assert_refused(code, out, err, "stages/01_range_fft.h5", "fwdlook did not write it")
    assert snapshot(d) == before


def test_the_lock_is_never_written_through_a_symlink(base_run, tiny_raw, tmp_path, capsys):
    d = tmp_path / "run"
    shutil.copytree(base_run, d)
    user = tmp_path / "userfile"
    user.write_text("precious\n")
    lock = d / outputs.LOCK_NAME
    lock.unlink(missing_ok=True)
    lock.symlink_to(user)
    code, _, err = run_cli(["process", tiny_raw, "-o", d, "-q"], capsys)
    assert code == 0, err
    assert user.read_text() == "precious\n" and not lock.is_symlink()


def test_a_finished_run_is_rerun_in_place(scn, tmp_path, capsys):
    d = tmp_path / "r"
    for _ in range(2):
        code, _, err = run_cli(["run", scn, "-o", d, "-q"], capsys)
        assert code == 0, err


def _tiny_sweep(tmp_path, scn):
    path = tmp_path / "sw.yaml"
    path.write_text(f"name: sw\nscenarios: [{scn}]\ngrid: {{processing.q: [25]}}\n")
    return path


@pytest.mark.parametrize("holding", ["summary.md", "summary.csv", "a regular file"])
def test_sweep_refuses_a_users_folder(scn, tmp_path, capsys, holding):
    sweep = _tiny_sweep(tmp_path, scn)
    if holding == "a regular file":
        out_dir = tmp_path / "plain"
        out_dir.write_text("x\n")
        fragments = ("not a directory",)
    else:
        out_dir = tmp_path / "mine"
        out_dir.mkdir()
        (out_dir / holding).write_text("mine\n")
        fragments = (out_dir / holding, "not written by fwdlook sweep", "--overwrite")
    before = snapshot(out_dir)
    code, out, err = run_cli(["sweep", sweep, "-o", out_dir, "-q"], capsys)
    assert_refused(code, out, err, *fragments)
    assert snapshot(out_dir) == before


def test_sweep_grid_error_names_the_sweep_file_and_the_scenario(scn, tmp_path, capsys):
    sweep = tmp_path / "sw.yaml"
    sweep.write_text(f"name: sw\nscenarios: [{scn}]\ngrid: {{processing.qq: [25]}}\n")
    code, out, err = run_cli(["sweep", sweep, "-o", tmp_path / "sw", "-q"], capsys)
    assert_refused(code, out, err, sweep, "qq=25", scn, "processing.qq", "unknown key")


def test_sweep_reruns_into_its_own_folder(scn, tmp_path, capsys):
    sweep = _tiny_sweep(tmp_path, scn)
    for _ in range(2):
        code, _, err = run_cli(["sweep", sweep, "-o", tmp_path / "sw", "-q"], capsys)
        assert code == 0, err
    assert json.loads((tmp_path / "sw" / "summary.json").read_text())["sweep"] == "sw"


def test_simulate_refuses_a_folders_path(scn, tmp_path, capsys):
    code, out, err = run_cli(["simulate", scn, "-o", f"{tmp_path / 'newdir'}/", "-q"], capsys)
    assert_refused(code, out, err, "newdir/", "ends in '/'")
    assert not (tmp_path / "newdir").exists()


@pytest.mark.parametrize("value", ["nan", "inf", "1e308"])
def test_report_target_must_be_finite_metres(base_run, tmp_path, capsys, value):
    code, out, err = run_cli(["report", base_run, "-o", tmp_path / "rt", "--target", "0", value, "-q"], capsys)
    assert_refused(code, out, err, "--target", value, "finite number of metres")
    assert not (tmp_path / "rt").exists()


@pytest.mark.parametrize("command", ["process", "run", "sweep"])
def test_a_folder_in_use_by_another_command_is_refused(scn, tiny_raw, base_run, tmp_path, capsys, command):
    """Two commands on one folder interleaved their files (a metrics.json of one setting beside the
    scenario.yaml, quick look or stage files of the other); the second is now refused while the first
    holds the folder's lock, and the folder is untouched."""
    d = tmp_path / "busy"
    if command == "sweep":
        d.mkdir()
        argv = ["sweep", _tiny_sweep(tmp_path, scn), "-o", d, "-q"]
        what = "sweep folder in use"
    else:
        shutil.copytree(base_run, d)
        argv = ([command, tiny_raw, "-o", d, "-q", "--force"] if command == "process"
                else ["run", scn, "-o", d, "-q"])
        what = "run directory in use"
    with outputs.folder_lock(d):                  # another command holding it (a second open: flock conflicts)
        before = snapshot(d)
        code, out, err = run_cli(argv, capsys)
        assert_refused(code, out, err, d, what, f"pid {os.getpid()}")
        assert snapshot(d) == before
    code, _, err = run_cli(argv, capsys)          # released: the command runs
    assert code == 0, err


def test_a_refused_command_leaves_no_stages_folder(scn, tmp_path, capsys):
    d = tmp_path / "fresh"
    d.mkdir()
    with outputs.folder_lock(d):
        code, out, err = run_cli(["run", scn, "-o", d, "-q"], capsys)
        assert_refused(code, out, err, "run directory in use")
    assert sorted(p.name for p in d.iterdir()) == [outputs.LOCK_NAME]


@pytest.mark.parametrize("exists", [False, True])
@pytest.mark.parametrize("command", ["run", "process"])
def test_a_command_refused_after_it_took_its_folder_leaves_nothing(scn, tmp_path, capsys, command, exists):
    """A refusal that comes once the folder is made and locked (the cube of --raw is read after that)
    leaves the folder as it was: not made, or without the lock file it would have made."""
    d = tmp_path / "a" / "b"
    if exists:
        d.mkdir(parents=True)
    code, out, err = run_cli([command, scn, "--raw", tmp_path / "nothere.h5", "-o", d, "-q"], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "nothere.h5" in err, err
    if exists:
        assert list(d.iterdir()) == []
    else:
        assert not (tmp_path / "a").exists()


def test_bench_write_cube_is_guarded_and_bounded(tmp_path, capsys, monkeypatch):
    notes = tmp_path / "notes.txt"
    notes.write_text("precious\n")
    before = snapshot(notes)
    code, out, err = run_cli(["bench", "--write-cube", notes, "--shape", "32", "32"], capsys)
    assert_refused(code, out, err, notes, "not a fwdlook raw cube", "--overwrite")
    assert snapshot(notes) == before
    code, out, err = run_cli(["bench", "--write-cube", tmp_path / "big.h5", "--shape", "1048576", "4096"], capsys)
    assert_refused(code, out, err, "big.h5", "--shape 1048576 4096", "64 GiB", "4 GiB")
    monkeypatch.setenv("FWDLOOK_MAX_CUBE_BYTES", "20000000")
    code, out, err = run_cli(["bench", "--write-cube", tmp_path / "mid.h5", "--shape", "16384", "4096"], capsys)
    assert_refused(code, out, err, "--shape 16384 4096", "$FWDLOOK_MAX_CUBE_BYTES")
    assert list(tmp_path.glob("*.h5")) == []


def test_bench_scaling_plot_is_guarded_before_the_series(tmp_path, capsys, monkeypatch):
    """The series runs for minutes: its plot's path is checked first (a user's PNG had been overwritten
    after the series, a regular file on the path had ended in a traceback)."""
    from fwdlook_cli.report import bench

    monkeypatch.setattr(bench, "print_bench", lambda *a, **k: pytest.fail("the series started"))
    mine = tmp_path / "p.png"
    mine.write_bytes(b"\x89PNG\r\n\x1a\n my own picture")
    before = snapshot(mine)
    code, out, err = run_cli(["bench", "--scaling", "--plot", mine], capsys)
    assert_refused(code, out, err, str(mine), "not a plot of fwdlook bench --scaling", "--overwrite")
    assert snapshot(mine) == before
    (tmp_path / "f").write_text("a file")
    code, out, err = run_cli(["bench", "--scaling", "--plot", tmp_path / "f" / "x.png"], capsys)
    assert_refused(code, out, err, "is not a directory")
    for argv, flag in ((["--shape", "64", "64"], "--shape"), (["--plot", tmp_path / "q.png"], "--plot")):
        code, out, err = run_cli(["bench", *argv], capsys)
        assert_refused(code, out, err, flag, "applies only with")


def test_bench_refuses_options_its_mode_would_ignore(tmp_path, capsys, monkeypatch):
    """`--scaling --backend gpu` had run the CPU series for a minute, and `--write-cube` had dropped
    `--scaling`, `--scene`, `--backend gpu` and `--json` without a word (an independent review): each
    such option is refused in one line before anything is measured or written (`--backend gpu` without
    a GPU: tests/test_gpu_backend.py)."""
    from fwdlook_cli.report import bench

    monkeypatch.setattr(bench, "print_bench", lambda *a, **k: pytest.fail("the bench started"))
    cube = tmp_path / "c.h5"
    for argv, flag, mode in ((["--scaling", "--backend", "gpu"], "--backend", "--scaling"),
                             (["--scaling", "--scene"], "--scene", "--scaling"),
                             (["--write-cube", cube, "--scaling"], "--scaling", "--write-cube"),
                             (["--write-cube", cube, "--shape", "64", "64", "--json"], "--json", "--write-cube"),
                             (["--write-cube", cube, "--repeats", "5"], "--repeats", "--write-cube")):
        code, out, err = run_cli(["bench", *argv], capsys)
        assert_refused(code, out, err, f"{flag}: does not apply with {mode}")
        assert not cube.exists()
    code, out, err = run_cli(["bench", "--overwrite"], capsys)          # alone: nothing it could overwrite
    assert_refused(code, out, err, "--overwrite: applies only with --write-cube or --scaling")


def test_a_bench_plot_is_recognised_by_its_pngs_software_text(tmp_path):
    """matplotlib writes the mark, the guard's own PNG reader finds it (and nothing in another PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    fig = Figure(figsize=(1, 1))
    fig.subplots().plot([0, 1])
    fig.savefig(tmp_path / "ours.png", metadata={"Software": extra_outputs.BENCH_PNG_SOFTWARE})
    fig.savefig(tmp_path / "theirs.png")
    assert extra_outputs.png_software(tmp_path / "ours.png") == extra_outputs.BENCH_PNG_SOFTWARE
    assert extra_outputs.png_software(tmp_path / "theirs.png").startswith("Matplotlib")
    assert extra_outputs.bench_png_path(tmp_path / "ours.png") == tmp_path / "ours.png"
    with pytest.raises(BadInput):
        extra_outputs.bench_png_path(tmp_path / "theirs.png")


def test_force_and_from_stage_together_are_refused(tiny_raw, tmp_path, capsys):
    code, out, err = run_cli(["process", tiny_raw, "-o", tmp_path / "r", "--force", "--from-stage", "regroup"], capsys)
    assert_refused(code, out, err, "--force", "--from-stage", "one of them")


def test_report_on_a_file_says_it_is_a_file(tiny_raw, tmp_path, capsys):
    code, out, err = run_cli(["report", tiny_raw, "-o", tmp_path / "rr", "-q"], capsys)
    assert_refused(code, out, err, tiny_raw, "a file, not a folder")


def _foreign_folder(tmp_path):
    d = tmp_path / "mine"
    d.mkdir()
    (d / "image.png").write_bytes(b"\x89PNG my holiday photo")
    (d / "metrics.json").write_text('{"my": "numbers"}')
    (d / "scenario.yaml").write_text("my: notes\n")
    return d


def test_process_refuses_a_foreign_folder(tiny_raw, tmp_path, capsys):
    d = _foreign_folder(tmp_path)
    before = snapshot(d)
    code, out, err = run_cli(["process", tiny_raw, "-o", d, "-q"], capsys)
    assert_refused(code, out, err, d, "not a fwdlook run directory", "--overwrite")
    assert snapshot(d) == before and not (d / "stages").exists()
    code, _, err = run_cli(["process", tiny_raw, "-o", d, "-q", "--overwrite"], capsys)
    assert code == 0, err
    assert "fwdlook_version" in json.loads((d / "metrics.json").read_text())


def test_run_refuses_a_foreign_folder(scn, tmp_path, capsys):
    d = _foreign_folder(tmp_path)
    before = snapshot(d)
    code, out, err = run_cli(["run", scn, "-o", d, "-q"], capsys)
    assert_refused(code, out, err, d, "not a fwdlook run directory")
    assert snapshot(d) == before


def test_process_keeps_unrelated_files(tiny_raw, tmp_path, capsys):
    d = tmp_path / "results"
    d.mkdir()
    (d / "notes.txt").write_text("keep me")
    code, _, err = run_cli(["process", tiny_raw, "-o", d, "-q"], capsys)
    assert code == 0, err
    assert (d / "notes.txt").read_text() == "keep me" and (d / "metrics.json").exists()


@pytest.mark.parametrize("overwrite", [False, True])
def test_process_never_writes_over_an_input_in_the_run_dir(tiny_raw, tmp_path, capsys, overwrite):
    """A scenario given as RUN_DIR/scenario.yaml would be replaced by the run: refused even with --overwrite."""
    d = tmp_path / "run"
    code, _, err = run_cli(["process", tiny_raw, "-o", d, "-q"], capsys)
    assert code == 0, err
    before = snapshot(d / "scenario.yaml")
    code, out, err = run_cli(["process", d / "scenario.yaml", "--raw", tiny_raw, "-o", d, "-q"]
                             + (["--overwrite"] if overwrite else []), capsys)
    assert_refused(code, out, err, "scenario.yaml", "input")
    assert snapshot(d / "scenario.yaml") == before


@pytest.mark.parametrize("name, text", [("report.md", "# My thesis chapter\n"), ("index.html", "<p>mine</p>")])
def test_report_refuses_a_users_report(base_run, tmp_path, capsys, name, text):
    d = tmp_path / "rep"
    d.mkdir()
    (d / name).write_text(text)
    before = snapshot(d)
    code, out, err = run_cli(["report", base_run, "-o", d, "-q"], capsys)
    assert_refused(code, out, err, d / name, "not written by fwdlook", "--overwrite")
    assert snapshot(d) == before
    code, _, err = run_cli(["report", base_run, "-o", d, "-q", "--overwrite"], capsys)
    assert code == 0, err
    code, _, err = run_cli(["report", base_run, "-o", d, "-q"], capsys)   # its own report: rewritten
    assert code == 0, err
    assert (d / "report.md").read_text().startswith("# fwdlook report")


def test_report_refuses_a_users_file_named_as_one_of_its_run_figures(base_run, tmp_path, capsys):
    """The figures named after a run (ground_<run>.png) or a sweep (sweep_<name>_*.png) are not in the
    fixed list the folder check knows: a user's file of such a name had been replaced with exit 0 (an
    independent review). It is refused as report.md is, with nothing written, and --overwrite replaces it."""
    d = tmp_path / "rep"
    code, _, err = run_cli(["report", base_run, "-o", tmp_path / "probe", "-q"], capsys)
    assert code == 0, err
    (ground,) = [p.name for p in (tmp_path / "probe").glob("ground_*.png")]
    d.mkdir()
    (d / ground).write_text("my own figure")
    before = snapshot(d)
    code, out, err = run_cli(["report", base_run, "-o", d, "-q"], capsys)
    assert_refused(code, out, err, d / ground, "not written by fwdlook report", "--overwrite")
    assert snapshot(d) == before and sorted(p.name for p in d.iterdir()) == [ground]
    code, _, err = run_cli(["report", base_run, "-o", d, "-q", "--overwrite"], capsys)
    assert code == 0, err
    assert (d / ground).read_bytes().startswith(b"\x89PNG")


# ----------------------------------------------------------------------------------------------
# 2. Full disk: a mocked write failure and a real 1 MiB tmpfs
# ----------------------------------------------------------------------------------------------
class _FillingFile:
    """A raw file that accepts ``budget`` bytes in all, then fails with ENOSPC (a filling disk)."""

    budget = 64 * 1024

    def __init__(self, path, mode, buffering=-1):
        self._f = open(path, mode, buffering=buffering)  # noqa: SIM115

    def write(self, b):
        n = memoryview(b).nbytes
        if _FillingFile.budget < n:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        _FillingFile.budget -= n
        return self._f.write(b)

    def __getattr__(self, name):
        return getattr(self._f, name)


@pytest.fixture
def filling_disk(monkeypatch):
    _FillingFile.budget = 64 * 1024
    monkeypatch.setattr(outputs, "open", _FillingFile, raising=False)

    def fail_text(self, *a, **k):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(Path, "write_text", fail_text)


def test_simulate_mocked_full_disk(scn, tmp_path, capsys, filling_disk):
    target = tmp_path / "out" / "raw.h5"
    code, out, err = run_cli(["simulate", scn, "-o", target, "-q"], capsys)
    assert_refused(code, out, err, f"cannot write {target}: No space left on device")
    assert not target.exists() and no_partials(tmp_path) == []


@pytest.mark.parametrize("command", ["process", "run"])
def test_process_and_run_mocked_full_disk(scn, tiny_raw, tmp_path, capsys, filling_disk, command):
    d = tmp_path / "run"
    argv = ["process", tiny_raw] if command == "process" else ["run", scn]
    code, out, err = run_cli(argv + ["-o", d, "-q"], capsys)
    assert_refused(code, out, err, "cannot write", str(d), "No space left on device")
    for name in ("metrics.json", "scenario.yaml", "image.h5", "image.png"):
        assert not (d / name).exists(), name
    assert no_partials(tmp_path) == []


def test_text_output_mocked_full_disk(base_run, tmp_path, capsys, monkeypatch):
    """report.md written when the disk is full: one line, no report.md, no partial."""
    def fail_text(self, *a, **k):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(Path, "write_text", fail_text)
    d = tmp_path / "rep"
    code, out, err = run_cli(["report", base_run, "-o", d, "-q"], capsys)
    assert_refused(code, out, err, f"cannot write {d / 'report.md'}: No space left on device")
    assert not (d / "report.md").exists() and no_partials(tmp_path) == []


def _fwdlook(*args, env=None, timeout=120):
    return subprocess.run([sys.executable, "-c", "from fwdlook_cli.cli import main; main()", *map(str, args)],
                          capture_output=True, text=True, timeout=timeout, cwd=ROOT, env=env)


@pytest.mark.parametrize("command", ["simulate", "process", "run"])
def test_real_full_tmpfs(mount_tmpfs, tiny_raw, command):
    """A real 1 MiB tmpfs (the issue's segfault): exit 2, one line, nothing left that looks complete.

    In a subprocess: a regression would segfault (rc -11), which must not take pytest down."""
    mnt = mount_tmpfs("full")
    bigger = ["--set", "antenna.scan_rate_dps=20"]          # 2000 pulses: a 3 MB cube, 1 MiB disk
    if command == "simulate":
        r = _fwdlook("simulate", TINY, *bigger, "-o", mnt / "raw.h5", "-q")
    elif command == "process":
        big = mnt.parent / "big.h5"
        assert _fwdlook("simulate", TINY, *bigger, "-o", big, "-q").returncode == 0
        r = _fwdlook("process", big, "-o", mnt / "run", "-q")
    else:
        r = _fwdlook("run", TINY, *bigger, "-o", mnt / "run", "-q")
    assert r.returncode == 2, (r.returncode, r.stderr[-1500:])
    assert "Traceback" not in r.stderr
    # (-q: warnings stay; at 20 deg/s the tiny scene's decimation misses its plan budget and says so first)
    lines = [line for line in r.stderr.splitlines() if not line.startswith("processing.method ")]
    assert len(lines) == 1 and "No space left on device" in lines[0] and str(mnt) in lines[0], lines
    assert list(mnt.rglob("*.partial*")) == []
    names = ["raw.h5"] if command == "simulate" else ["run/metrics.json", "run/scenario.yaml", "run/image.h5"]
    assert not any((mnt / name).exists() for name in names)


def test_report_on_a_nearly_full_tmpfs(mount_tmpfs, base_run, capsys):
    """PNGs (matplotlib) and report.md on a disk with 40 KiB free: one line, no partial, the user's
    file on that disk untouched."""
    mnt = mount_tmpfs("nearly_full")
    filler = mnt / "users_data.bin"
    with open(filler, "wb", buffering=0) as fh:      # fill the disk, 4 KiB at a time
        try:
            while fh.write(b"u" * 4096):
                pass
        except OSError:
            pass
    size = filler.stat().st_size
    filler.write_bytes(b"u" * (size - 40 * 1024))
    before = snapshot(filler)
    code, out, err = run_cli(["report", base_run, "-o", mnt / "rep", "-q"], capsys)
    assert_refused(code, out, err, "cannot write", mnt / "rep", "No space left on device")
    assert not (mnt / "rep" / "report.md").exists() and list(mnt.rglob("*.partial*")) == []
    assert snapshot(filler) == before


# ----------------------------------------------------------------------------------------------
# 3. Output paths that cannot be written
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("command", ["simulate", "process", "run", "report"])
def test_output_under_a_regular_file(scn, tiny_raw, base_run, tmp_path, capsys, command):
    blocker = tmp_path / "afile"
    blocker.write_text("I am a file")
    target = blocker / "sub" / ("raw.h5" if command == "simulate" else "out")
    argv = {"simulate": ["simulate", scn], "process": ["process", tiny_raw], "run": ["run", scn],
            "report": ["report", base_run]}[command]
    code, out, err = run_cli(argv + ["-o", target, "-q"], capsys)
    assert_refused(code, out, err, "cannot write", target, "not a directory")
    assert blocker.read_text() == "I am a file"


@pytest.mark.parametrize("command", ["process", "run", "report"])
def test_existing_file_where_a_directory_is_expected(scn, tiny_raw, base_run, tmp_path, capsys, command):
    target = tmp_path / "afile"
    target.write_text("I am a file")
    argv = {"process": ["process", tiny_raw], "run": ["run", scn], "report": ["report", base_run]}[command]
    code, out, err = run_cli(argv + ["-o", target, "-q"], capsys)
    assert_refused(code, out, err, target, "not a directory")
    assert target.read_text() == "I am a file"


def test_simulate_output_is_a_directory(scn, tmp_path, capsys):
    code, out, err = run_cli(["simulate", scn, "-o", tmp_path, "-q"], capsys)
    assert_refused(code, out, err, tmp_path, "is a directory")


@pytest.mark.parametrize("command", ["simulate", "process", "run", "report"])
def test_read_only_file_system(scn, tiny_raw, base_run, mount_tmpfs, capsys, command):
    ro = mount_tmpfs("ro", ro=True)
    target = ro / ("raw.h5" if command == "simulate" else "out")
    argv = {"simulate": ["simulate", scn], "process": ["process", tiny_raw], "run": ["run", scn],
            "report": ["report", base_run]}[command]
    code, out, err = run_cli(argv + ["-o", target, "-q"], capsys)
    assert_refused(code, out, err, "cannot write", target, "Read-only file system")


def test_permission_denied_mocked(scn, tmp_path, capsys, monkeypatch):
    """Root ignores chmod, so a folder without write permission is mocked at the probe."""
    def denied(*a, **k):
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES))

    monkeypatch.setattr(outputs.tempfile, "mkstemp", denied)
    target = tmp_path / "locked" / "raw.h5"
    code, out, err = run_cli(["simulate", scn, "-o", target, "-q"], capsys)
    assert_refused(code, out, err, f"cannot write {target}: Permission denied")


# ----------------------------------------------------------------------------------------------
# 4. Unreadable scenarios: one reader for every command
# ----------------------------------------------------------------------------------------------
def _unreadable(kind, tmp_path):
    p = tmp_path / f"{kind}.yaml"
    if kind == "latin1":
        p.write_bytes(TINY.read_bytes().replace(b"name: tiny", b"name: caf\xe9"))
    elif kind == "utf16":
        p.write_bytes(TINY.read_text().encode("utf-16"))
    elif kind == "binary":
        p.write_bytes(bytes(range(256)) * 4)
    elif kind == "directory":
        p.mkdir()
    elif kind == "empty":
        p.write_bytes(b"")
    elif kind == "comments":
        p.write_text("# nothing here yet\n\n   # really nothing\n")
    return p


UNREADABLE = {"latin1": "UTF-8", "utf16": "UTF-8", "binary": "UTF-8", "directory": "directory",
              "empty": "empty scenario", "comments": "empty scenario"}


@pytest.mark.parametrize("command", ["validate", "simulate", "process", "run", "plan"])
@pytest.mark.parametrize("kind", sorted(UNREADABLE))
def test_unreadable_scenario(tmp_path, capsys, kind, command):
    path = _unreadable(kind, tmp_path)
    before = snapshot(path) if path.is_file() else {}
    extra = {"simulate": ["-o", tmp_path / "raw.h5"], "process": ["-o", tmp_path / "run", "-q"],
             "run": ["-o", tmp_path / "run", "-q"]}.get(command, [])
    code, out, err = run_cli([command, path] + extra, capsys)
    assert_refused(code, out, err, path, UNREADABLE[kind])
    assert not (tmp_path / "raw.h5").exists() and not (tmp_path / "run").exists()
    assert (snapshot(path) if path.is_file() else {}) == before


def test_unreadable_config_preset(scn, tiny_raw, tmp_path, capsys):
    cfg = tmp_path / "preset.yaml"
    cfg.write_bytes(b"processing:\n  q: 8\n  keystone: \xff\xfe\n")
    code, out, err = run_cli(["process", tiny_raw, "-c", cfg, "-o", tmp_path / "run", "-q"], capsys)
    assert_refused(code, out, err, cfg, "UTF-8")


# ----------------------------------------------------------------------------------------------
# 5. Sizes bounded before allocation
# ----------------------------------------------------------------------------------------------
SIZE_CASES = {
    "prf-1e8-auto-pulses": (["radar.prf_hz=1.0e8"], ["radar.n_pulses", "2e+07 pulses", "10,000,000"]),
    "prf-1e12": (["radar.prf_hz=1.0e12"], ["radar.n_pulses", "2e+11 pulses"]),
    "scan-rate-1e-9": (["antenna.scan_rate_dps=1.0e-9"], ["antenna.scan_rate_dps = 1e-09", "pulses"]),
    "point-at-1e9-m": (["scene.points_m=[[0.0, 1000.0], [0.0, 1.0e9]]"],
                       ["radar.range_window_m = auto", "1e+09 m", "GiB of echo", "max_cube_bytes"]),
    "lone-point-at-1e9-m": (["scene.points_m=[[0.0, 1.0e9]]"], ["scene.points_m", "unambiguous range"]),
    "window-1e9-m": (["radar.range_window_m=[1.0, 1.0e9]"], ["radar.range_window_m = [1, 1e+09]", "GiB"]),
    "fs-1e15": (["radar.fs_hz=1.0e15"], ["radar.fs_hz = 1e+15", "range samples"]),
    "huge-lattice": (["scene.kind=lattice", "scene.lattice.nx=10000", "scene.lattice.ny=10000",
                      "scene.lattice.spacing_m=0.01"],
                     ["scene:", "scatterers need"]),
    "setting-small-limit": (["simulation.max_cube_bytes=1.0e5"], ["over simulation.max_cube_bytes = 0.0954 MiB"]),
}


@pytest.mark.parametrize("command", ["validate", "simulate"])
@pytest.mark.parametrize("case", sorted(SIZE_CASES))
def test_derived_size_refused_before_allocation(tmp_path, capsys, case, command):
    sets, fragments = SIZE_CASES[case]
    extra = ["-o", tmp_path / "raw.h5"] if command == "simulate" else []
    argv = [command, TINY] + [a for s in sets for a in ("--set", s)] + extra
    t0 = time.perf_counter()
    code, out, err = run_cli(argv, capsys)
    assert time.perf_counter() - t0 < 10.0, "the check must come before the allocation"
    assert_refused(code, out, err, TINY, *fragments)
    assert not (tmp_path / "raw.h5").exists()


@pytest.mark.parametrize("sets", [["radar.fs_hz=1.0e13"], ["radar.range_window_m=[100.0, 1.0e8]"]])
def test_isar_derived_size_refused(capsys, sets):
    path = ROOT / "scenarios" / "isar_theta3.yaml"
    t0 = time.perf_counter()
    code, out, err = run_cli(["validate", path] + [a for s in sets for a in ("--set", s)], capsys)
    assert time.perf_counter() - t0 < 10.0
    assert_refused(code, out, err, path, "radar.range_window_m", "one complex64 channel", "the default limit")


def test_size_limit_from_environment(capsys, monkeypatch):
    monkeypatch.setenv("FWDLOOK_MAX_CUBE_BYTES", "100000")
    code, out, err = run_cli(["validate", TINY], capsys)
    assert_refused(code, out, err, TINY, "$FWDLOOK_MAX_CUBE_BYTES", "range samples x 400 pulses")
    monkeypatch.setenv("FWDLOOK_MAX_CUBE_BYTES", "lots")
    code, out, err = run_cli(["validate", TINY], capsys)
    assert_refused(code, out, err, "FWDLOOK_MAX_CUBE_BYTES", "'lots'")


def test_paper_scenarios_fit_the_default_limit(capsys):
    for path in sorted((ROOT / "scenarios").glob("*.yaml")):
        code, out, err = run_cli(["validate", path], capsys)
        assert code == 0, err


@pytest.fixture(scope="module")
def huge_declared_cube(tiny_raw, tmp_path_factory):
    """A small file declaring a 1e6 x 1e6 complex64 echo (7.3 TiB; chunked, nothing written)."""
    path = tmp_path_factory.mktemp("huge") / "huge.h5"
    shutil.copyfile(tiny_raw, path)
    with h5py.File(path, "r+") as f:
        for name in ("sum", "diff"):
            del f["echo"][name]
            f["echo"].create_dataset(name, shape=(10**6, 10**6), dtype=np.complex64, chunks=(64, 64))
    assert path.stat().st_size < 10**6
    return path


@pytest.mark.parametrize("command", ["validate", "info", "process"])
def test_declared_size_refused_before_reading(huge_declared_cube, tmp_path, capsys, command):
    extra = ["-o", tmp_path / "run", "-q"] if command == "process" else []
    t0 = time.perf_counter()
    code, out, err = run_cli([command, huge_declared_cube] + extra, capsys)
    assert time.perf_counter() - t0 < 10.0
    assert_refused(code, out, err, huge_declared_cube, "/echo/sum", "1,000,000 x 1,000,000", "GiB")
    assert not (tmp_path / "run" / "metrics.json").exists()


# ----------------------------------------------------------------------------------------------
# 6. YAML parser edge cases
# ----------------------------------------------------------------------------------------------
BOMB = "\n".join(
    ["a: &a [" + ", ".join(['"lol"'] * 9) + "]"]
    + [f"{c}: &{c} [" + ", ".join([f"*{p}"] * 9) + "]" for p, c in zip("abcdefgh", "bcdefghi")]
    + ["name: *i"]) + "\n"

PARSER_CASES = {
    "nesting-3000": ("name: " + "[" * 3000 + "]" * 3000 + "\n", ["line 1", "nesting deeper than 64"]),
    "nesting-3000-block": ("".join("  " * i + f"k{i}:\n" for i in range(3000)) + "  " * 3000 + "v: 1\n",
                           ["line 65", "nesting deeper than 64"]),
    "nesting-100": ("name: " + "[" * 100 + "]" * 100 + "\n", ["nesting deeper than 64"]),
    "list-as-key": ("? [a, b]\n: 1\n", ["line 1", "list used as a mapping key"]),
    "dict-as-key": ("radar:\n  ? {a: 1}\n  : 2\n", ["line 2", "dict used as a mapping key"]),
    "401-digits": ("radar:\n  prf_hz: " + "9" * 401 + "\n", ["line 2", "number of 401 characters"]),
    "5001-digits": ("radar:\n  prf_hz: " + "9" * 5001 + "\n", ["line 2", "number of 5,001 characters"]),
    "billion-laughs": (BOMB, ["expands (through aliases)", "1,000,000"]),
    "bomb-in-points": (BOMB.replace("name: *i", "scene:\n  kind: points\n  points_m: *i"),
                       ["expands (through aliases)"]),
    "recursive-alias": ("name: &x [*x]\n", ["recursive alias"]),
    "empty": ("", ["empty scenario"]),
    "comment-only": ("# a scenario, one day\n", ["empty scenario"]),
    "null-document": ("~\n", ["empty scenario"]),
}


@pytest.mark.parametrize("case", sorted(PARSER_CASES))
def test_yaml_parser_edge_cases(tmp_path, capsys, case):
    text, fragments = PARSER_CASES[case]
    path = tmp_path / "S.yaml"
    path.write_text(text)
    t0 = time.perf_counter()
    code, out, err = run_cli(["validate", path], capsys)
    assert time.perf_counter() - t0 < 5.0, "bounded: no expansion, no hang"
    line = assert_refused(code, out, err, path, *fragments)
    assert len(line) < 400


@pytest.mark.parametrize("command", ["process", "run"])
def test_yaml_edge_cases_same_path_for_process_and_run(tmp_path, capsys, command):
    path = tmp_path / "S.yaml"
    path.write_text(BOMB)
    code, out, err = run_cli([command, path, "-o", tmp_path / "run", "-q"], capsys)
    assert_refused(code, out, err, path, "expands (through aliases)")
    assert not (tmp_path / "run").exists()


def test_set_value_is_bounded_too(capsys):
    code, out, err = run_cli(["validate", TINY, "--set", "name=" + "[" * 200 + "]" * 200], capsys)
    assert_refused(code, out, err, "--set name", "nesting")


def test_huge_integer_value_is_refused_not_stored(tmp_path, capsys):
    """A 30-digit seed would overflow the HDF5 attribute later (exit 1): refused at validation."""
    code, out, err = run_cli(["validate", TINY, "--set", "noise.seed=" + "9" * 30], capsys)
    assert_refused(code, out, err, "noise.seed", "2**63")


# ----------------------------------------------------------------------------------------------
# 7. Damaged stage files: checked before reuse, recomputed, never reused, resume never crashes
# ----------------------------------------------------------------------------------------------
def _largest(f):
    names = [k for k in f if isinstance(f[k], h5py.Dataset)]
    return max(names, key=lambda k: f[k].size)


def _rewrite(f, name, data):
    old = f[name]
    attrs = dict(old.attrs)
    dims = old.attrs.get("dims")
    del f[name]
    ds = f.create_dataset(name, data=data)
    for k, v in attrs.items():
        if k not in ("DIMENSION_LIST", "REFERENCE_LIST", "CLASS", "NAME"):
            ds.attrs[k] = v
    if dims is not None:
        ds.attrs["dims"] = dims


def _bitflip(f):
    ds = f[_largest(f)]
    a = ds[()]
    a.view(np.uint8).reshape(-1)[a.nbytes // 2] ^= 0x10
    ds[...] = a


def _truncate_dataset(f):
    name = _largest(f)
    _rewrite(f, name, f[name][()][:-1])


def _retype(f):
    name = _largest(f)
    other = {"c": {8: np.complex128, 16: np.complex64}, "f": {4: np.float64, 8: np.float32},
             "i": {4: np.int64, 8: np.int32}}[f[name].dtype.kind][f[name].dtype.itemsize]
    _rewrite(f, name, f[name][()].astype(other))
    assert f[name].dtype == other


def _drop(f):
    del f[_largest(f)]


def _strip_digest(f):
    """The largest dataset's digest removed from the root declaration (io/integrity.py)."""
    from fwdlook_cli.io.integrity import DIGEST_ATTR

    decl = json.loads(f.attrs["stage_datasets"])
    del decl[_largest(f)][DIGEST_ATTR]
    f.attrs["stage_datasets"] = json.dumps(decl)


DAMAGE = {"bit-flip": _bitflip, "truncated-dataset": _truncate_dataset, "retyped": _retype,
          "dataset-deleted": _drop, "digest-removed": _strip_digest}


def _copy_run(base_run, tmp_path):
    d = tmp_path / "run"
    shutil.copytree(base_run, d)
    return d


@pytest.mark.parametrize("damage", sorted(DAMAGE))
@pytest.mark.parametrize("stage", ["03_keystone", "07_monopulse_image"])
def test_damaged_stage_is_recomputed(base_run, tiny_raw, tmp_path, capsys, damage, stage):
    d = _copy_run(base_run, tmp_path)
    with h5py.File(d / "stages" / f"{stage}.h5", "r+") as f:
        DAMAGE[damage](f)
    code, out, err = run_cli(["process", tiny_raw, "-o", d], capsys)
    assert code == 0, err
    assert "Traceback" not in err
    assert f"{stage}.h5 is damaged" in err and "recomputing" in err
    assert _targets(d) == _targets(base_run)          # bit-identical recompute, not the damaged data
    code, _, err = run_cli(["process", tiny_raw, "-o", d], capsys)   # and now it is sound again
    assert code == 0 and "all 7 stages up to date (reused)" in err


def _edit_gain(f):
    f.attrs["coherent_gain"] = 1.0 if float(f.attrs["coherent_gain"]) != 1.0 else 2.0


def _edit_settings(f):
    f.attrs["settings"] = f.attrs["settings"].replace('"', "'", 2)


def _add_attr(f):
    f.attrs["note"] = "added by hand"


ATTR_EDITS = {"result-edited": _edit_gain, "settings-edited": _edit_settings, "attribute-added": _add_attr}


@pytest.mark.parametrize("edit", sorted(ATTR_EDITS))
def test_edited_stage_attributes_are_recomputed(base_run, tiny_raw, tmp_path, capsys, edit):
    """A stage's scalar results (the Doppler stage's coherent gain scales every peak loss) and its
    settings are covered by the attributes' digest: edited, the stage is recomputed, not reused."""
    d = _copy_run(base_run, tmp_path)
    with h5py.File(d / "stages" / "06_doppler_spectra.h5", "r+") as f:
        assert "coherent_gain" in f.attrs
        ATTR_EDITS[edit](f)
    code, out, err = run_cli(["process", tiny_raw, "-o", d], capsys)
    assert code == 0, err
    assert "06_doppler_spectra.h5 is damaged" in err and "attrs_xxh3_128" in err
    assert _targets(d) == _targets(base_run)


@pytest.mark.parametrize("how", ["truncated-file", "garbage", "empty-file"])
def test_unreadable_stage_file_is_recomputed(base_run, tiny_raw, tmp_path, capsys, how):
    d = _copy_run(base_run, tmp_path)
    p = d / "stages" / "04_regroup.h5"
    data = p.read_bytes()
    p.write_bytes({"truncated-file": data[: len(data) // 2], "garbage": os.urandom(4096),
                   "empty-file": b""}[how])
    code, out, err = run_cli(["process", tiny_raw, "-o", d], capsys)
    assert code == 0, err
    assert "04_regroup.h5 is damaged" in err
    assert _targets(d) == _targets(base_run)


def test_resume_over_a_damaged_stage_does_not_crash(base_run, tiny_raw, tmp_path, capsys):
    """--from-stage reads the stage before it: damaged, it is recomputed from the last sound one."""
    d = _copy_run(base_run, tmp_path)
    with h5py.File(d / "stages" / "04_regroup.h5", "r+") as f:
        _drop(f)
    code, out, err = run_cli(["process", tiny_raw, "-o", d, "--from-stage", "range_curvature"], capsys)
    assert code == 0, err
    assert "04_regroup.h5 is damaged" in err and "reused stages 1-3" in err
    assert _targets(d) == _targets(base_run)


def test_stage_reuse_still_reuses_sound_stages(base_run, tiny_raw, tmp_path, capsys):
    d = _copy_run(base_run, tmp_path)
    before = snapshot(d / "stages")
    code, _, err = run_cli(["process", tiny_raw, "-o", d], capsys)
    assert code == 0 and "all 7 stages up to date (reused)" in err and "damaged" not in err
    assert snapshot(d / "stages") == before


# ----------------------------------------------------------------------------------------------
# 8. Huge values are cut before they are echoed
# ----------------------------------------------------------------------------------------------
def _dense(path):
    return h5py.File(path, "r+", libver="latest")


@pytest.mark.parametrize("where", ["format", "format_version", "radar/fc_hz"])
def test_huge_attribute_is_cut_in_the_message(tiny_raw, tmp_path, capsys, where):
    path = tmp_path / "cube.h5"
    shutil.copyfile(tiny_raw, path)
    huge = "x" * (8 * 2**20)
    with _dense(path) as f:
        group, _, name = where.rpartition("/")
        obj = f[group] if group else f
        del obj.attrs[name]
        obj.attrs[name] = huge
    code, out, err = run_cli(["validate", path], capsys)
    line = assert_refused(code, out, err, path, name)
    assert len(line) < 500


def test_huge_yaml_value_is_cut_in_the_message(tmp_path, capsys):
    path = tmp_path / "S.yaml"
    path.write_text(TINY.read_text().replace("prf_hz: 2000", "prf_hz: '" + "x" * 2_000_000 + "'"))
    code, out, err = run_cli(["validate", path], capsys)
    line = assert_refused(code, out, err, path, "radar.prf_hz", "expected a number")
    assert len(line) < 300


def test_huge_unknown_key_is_cut_in_the_message(tmp_path, capsys):
    path = tmp_path / "S.yaml"
    path.write_text(TINY.read_text() + "? " + "k" * 1_000_000 + "\n: 1\n")   # explicit key: no 1024 limit
    code, out, err = run_cli(["validate", path], capsys)
    line = assert_refused(code, out, err, path, "unknown key", "allowed: name, kind, radar")
    assert len(line) < 400


def test_shown_is_bounded_on_shared_structures():
    from fwdlook_cli.limits import shown

    x = ["lol"] * 9
    for _ in range(9):
        x = [x] * 9                   # 9**10 leaves through shared references
    t0 = time.perf_counter()
    text = shown(x)
    assert time.perf_counter() - t0 < 0.1 and len(text) <= 60 and text.endswith("...")
    assert shown(10**5000).startswith("<integer of")


def test_every_scaling_shape_is_a_cube_the_reader_accepts(tmp_path):
    """The scaling series' and `bench --write-cube`'s scenarios keep every slant range positive and the
    points inside the window at its middle (a window centred on the paper's points began at -3415 m at
    4096 bins, and `process` refused the 16384 x 4096 memory cube); a 4096-bin cube writes and reads back."""
    from fwdlook_cli.io.raw import read_raw
    from fwdlook_cli.report.benchtools import PULSES, RANGE_BINS, scaling_scenario, write_scaling_cube
    from fwdlook_cli.scenario.loader import load_scenario

    paper = load_scenario(Path(__file__).resolve().parents[1] / "scenarios" / "paper_fig6_a50.yaml")
    for n_range in RANGE_BINS:
        for n_pulses in (PULSES[0], 16384):
            scn = scaling_scenario(paper, n_pulses, n_range)
            near, far = scn["radar"]["range_window_m"]
            ranges = [np.hypot(np.hypot(x, y), paper["platform"]["height_m"]) for x, y in scn["scene"]["points_m"]]
            assert near > paper["platform"]["height_m"] and far > near
            assert abs(0.5 * (near + far) - np.mean(ranges)) < 30.0, (n_range, near, far, ranges)
    write_scaling_cube(tmp_path / "wide.h5", 128, 4096, paper)
    cube = read_raw(tmp_path / "wide.h5")
    assert cube.range_m[0] > 0 and cube.n_range == 4096


_CLAIM_WINDOW = """
import os, signal, sys
from pathlib import Path
import fwdlook_cli.io.partial as partial
from fwdlook_cli.io import signals
from fwdlook_cli.io.h5 import atomic_h5, atomic_write_text
from fwdlook_cli.io.outputs import atomic_path

class Terminated(Exception):
    pass

signals.install(Terminated)
created = partial._create

def create_then_signalled(path):            # SIGTERM the moment the partial file exists
    made = created(path)
    os.kill(os.getpid(), signal.SIGTERM)
    return made

partial._create = create_then_signalled
out = Path(sys.argv[1])
writers = {"h5": lambda: atomic_h5(out / "a.h5").__enter__(), "text": lambda: atomic_write_text(out / "b.txt", "x"),
           "path": lambda: atomic_path(out / "c.png").__enter__()}
try:
    writers[sys.argv[2]]()
except Terminated:
    print(sorted(p.name for p in out.iterdir()))
"""


@pytest.mark.parametrize("writer", ["h5", "text", "path"])
def test_a_signal_the_moment_a_partial_file_is_claimed_leaves_none(tmp_path, writer):
    """A SIGTERM arriving just after ``NAME.partial`` was created, before the writer held its name, left
    it behind the stopped command (seen under load in the SIGTERM test below: ``cube.h5.partial``).  The
    name is now claimed with signals held (``io.partial.claim_partial_into``), and the signal raised once
    the writer can remove it: each atomic writer stopped there leaves the folder empty."""
    out = tmp_path / "out"
    out.mkdir()
    res = subprocess.run([sys.executable, "-c", _CLAIM_WINDOW, str(out), writer], capture_output=True, text=True,
                         timeout=120)
    assert res.stdout.strip() == "[]", (res.stdout, res.stderr)


def test_sigterm_ends_a_command_cleanly_without_a_partial_file(tmp_path):
    """SIGTERM (a scheduler's or a container's stop) is handled as Ctrl-C is: the command's atomic
    writers remove their partial files, exit 143 with one line (it had left raw.h5.partial behind)."""
    import signal

    out = tmp_path / "cube.h5"
    proc = subprocess.Popen([sys.executable, "-c", "from fwdlook_cli.cli import main; main()", "simulate",
                             str(ROOT / "scenarios" / "paper_fig6_a50.yaml"), "-o", str(out), "-q"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120.0
    while not out.with_name(out.name + ".partial").exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.002)
    assert proc.poll() is None, "finished before its partial file was seen"
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert err.strip().splitlines() == ["fwdlook: terminated (SIGTERM)"]
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("setting", ["radar.prf_hz=5", "platform.accel_mps2=[0,30,0]", "scene.kind=points",
                                     "noise.snr_db=3", "kind=isar"])
def test_a_set_that_a_cube_source_would_ignore_is_refused(tiny_raw, tmp_path, capsys, setting):
    """A cube as the source is processed with its own radar, antenna, motion and truth (CONTRACT.md
    section 3): a --set of another section changed nothing and was recorded in scenario.yaml as if it
    had (radar.prf_hz=5 beside the cube's 2000 Hz)."""
    code, out, err = run_cli(["process", tiny_raw, "-o", tmp_path / "r", "--set", setting], capsys)
    assert_refused(code, out, err, setting, str(tiny_raw), "allowed with a cube: processing.*, name")
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("command", ["run", "process"])
def test_a_set_that_the_raw_option_would_ignore_is_refused(tiny_raw, tmp_path, capsys, command):
    """With --raw the scenario's radar, antenna, platform, noise and simulation are not used either."""
    code, out, err = run_cli([command, TINY, "--raw", tiny_raw, "-o", tmp_path / "r", "--set",
                              "radar.prf_hz=5"], capsys)
    assert_refused(code, out, err, "radar.prf_hz", str(tiny_raw), "scene.*")
    code, out, err = run_cli([command, TINY, "--raw", tiny_raw, "-o", tmp_path / "r", "--set",
                              "processing.q=8", "-q"], capsys)
    assert code == 0, err
    head = (tmp_path / "r" / "scenario.yaml").read_text().splitlines()[:3]
    assert head[0].startswith(f"# processed from the cube {tiny_raw}:") and "the scenario's" in head[2]


def test_a_cube_sources_scenario_yaml_says_what_the_chain_used(tiny_raw, tmp_path, capsys):
    import yaml

    code, out, err = run_cli(["process", tiny_raw, "-o", tmp_path / "r", "--set", "processing.q=8",
                              "--set", "name=mine", "-q"], capsys)
    assert code == 0, err
    text = (tmp_path / "r" / "scenario.yaml").read_text()
    assert text.startswith(f"# processed from the cube {tiny_raw}:") and "were not used" in text
    scn = yaml.safe_load(text)
    assert scn["processing"]["q"] == 8 and scn["name"] == "mine"
    # image.h5 carries the same text, the note with it (its default radar had read as the cube's own:
    # an independent review, fifty-third round)
    import h5py

    with h5py.File(tmp_path / "r" / "image.h5") as f:
        assert f.attrs["scenario"] == text


def test_a_fifo_where_an_output_goes_is_refused_not_waited_on(tmp_path, capsys):
    """Checking whether a file at an output's path is fwdlook's opened it: a FIFO there blocked the
    command for good. Not a regular file: refused as any other file fwdlook did not write."""
    os.mkfifo(tmp_path / "out.h5")
    code, out, err = run_cli(["simulate", TINY, "-o", tmp_path / "out.h5"], capsys)
    assert_refused(code, out, err, "out.h5", "not a fwdlook raw cube")
    (tmp_path / "r").mkdir()
    os.mkfifo(tmp_path / "r" / "metrics.json")
    code, out, err = run_cli(["run", TINY, "-o", tmp_path / "r", "-q"], capsys)
    assert_refused(code, out, err, "metrics.json", "--overwrite")


def test_a_cube_with_another_suffix_is_named_as_hdf5(tiny_raw, tmp_path, capsys):
    cube = tmp_path / "cube.dat"
    shutil.copy(tiny_raw, cube)
    code, out, err = run_cli(["process", cube, "-o", tmp_path / "r"], capsys)
    assert_refused(code, out, err, str(cube), "an HDF5 file", ".h5")
