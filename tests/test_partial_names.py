"""The partial files outputs are written to (``io/partial.py``): never written through a symbolic link,
never over a file fwdlook did not make there (an independent review wrote a cube into a file elsewhere
through ``out.h5.partial -> victim`` and destroyed a user's ``metrics.json.partial``), and fwdlook's own
leftover in ``stages/`` still replaced."""
from __future__ import annotations

import json
import os
from pathlib import Path

import h5py

from fwdlook_cli.io.partial import claim_partial
from cli_runner import run_cli

ROOT = Path(__file__).resolve().parent.parent
TINY = ROOT / "scenarios" / "tiny.yaml"


def _no_partials_of_ours(folder: Path, *keep: Path):
    left = [p for p in folder.rglob("*partial*") if p not in keep]
    assert not left, left


def test_a_link_at_the_partial_name_is_never_written_through(tmp_path, capsys):
    victim = tmp_path / "elsewhere" / "victim.txt"
    victim.parent.mkdir()
    victim.write_text("VICTIM")
    link = tmp_path / "out.h5.partial"
    link.symlink_to(victim)
    code, out, err = run_cli(["simulate", TINY, "-o", tmp_path / "out.h5", "-q"], capsys)
    assert code == 0, err
    assert victim.read_text() == "VICTIM"                       # untouched
    assert link.is_symlink() and os.readlink(link) == str(victim)
    cube = tmp_path / "out.h5"
    assert cube.is_file() and not cube.is_symlink()
    with h5py.File(cube, "r") as f:
        assert f.attrs["format"] == "fwdlook-raw"
    assert "out.h5.partial" in err and "left as it is" in err   # the warning names what it left
    _no_partials_of_ours(tmp_path, link)


def test_a_users_files_at_the_partial_names_stay(tmp_path, capsys):
    run_dir = tmp_path / "R"
    run_dir.mkdir()
    names = ["metrics.json.partial", "image.h5.partial", "scenario.yaml.partial", "image.partial.png",
             "raw.h5.partial"]
    for name in names:
        (run_dir / name).write_text(f"mine: {name}")
    code, out, err = run_cli(["run", TINY, "-o", run_dir], capsys)
    assert code == 0, err
    for name in names:
        assert (run_dir / name).read_text() == f"mine: {name}"
    m = json.loads((run_dir / "metrics.json").read_text())
    assert m["summary"]["detected"] == 3
    with h5py.File(run_dir / "image.h5", "r") as f:
        assert f.attrs["format"] == "fwdlook-image"
    assert (run_dir / "image.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    _no_partials_of_ours(run_dir, *(run_dir / n for n in names))


def test_a_killed_writes_leftover_in_stages_is_replaced_and_a_link_there_left(tmp_path, capsys):
    run_dir = tmp_path / "R"
    code, _, err = run_cli(["run", TINY, "-o", run_dir, "-q"], capsys)
    assert code == 0, err
    stages = run_dir / "stages"
    first = sorted(stages.glob("*.h5"))[0]
    leftover = first.with_name(first.name + ".partial")
    leftover.write_bytes(b"\x89HDF\r\n\x1a\n half a file")    # as a SIGKILL mid-write leaves it
    first.unlink()
    victim = tmp_path / "victim"
    victim.write_text("VICTIM")
    second = sorted(stages.glob("*.h5"))[1]
    link = second.with_name(second.name + ".partial")
    link.symlink_to(victim)
    second.unlink()
    code, _, err = run_cli(["process", run_dir / "raw.h5", "-o", run_dir, "-q"], capsys)
    assert code == 0, err
    assert first.is_file() and second.is_file() and not leftover.exists()
    assert victim.read_text() == "VICTIM" and link.is_symlink()
    _no_partials_of_ours(run_dir, link)


def test_claim_partial_takes_a_fresh_name_beside_whatever_is_there(tmp_path):
    """The free name is created empty with the umask's mode; taken names (a file, a link, a folder)
    get a fresh name before the suffix; ``replace_regular`` replaces only a regular file."""
    free = claim_partial(tmp_path / "a.h5.partial")
    assert free == tmp_path / "a.h5.partial" and free.stat().st_size == 0
    umask = os.umask(0)
    os.umask(umask)
    assert free.stat().st_mode & 0o777 == 0o666 & ~umask
    (tmp_path / "b.partial.png").mkdir()
    other = claim_partial(tmp_path / "b.partial.png")
    assert other.name.startswith("b.partial-") and other.suffix == ".png" and other.is_file()
    (tmp_path / "c.h5.partial").write_text("x")
    assert claim_partial(tmp_path / "c.h5.partial", replace_regular=True) == tmp_path / "c.h5.partial"
    assert (tmp_path / "c.h5.partial").read_text() == ""
    (tmp_path / "d.h5.partial").symlink_to(tmp_path / "nowhere")
    other = claim_partial(tmp_path / "d.h5.partial", replace_regular=True)
    assert other.name.startswith("d.h5.partial-") and (tmp_path / "d.h5.partial").is_symlink()
    assert not (tmp_path / "nowhere").exists()
