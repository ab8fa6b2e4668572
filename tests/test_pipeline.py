"""The stage runner (issue 3, CONTRACT.md section 4): one HDF5 file per stage, hashed, reused, resumable.

Runs go through ``fwdlook_cli.cli.main`` in-process on the tiny cube (400 pulses x 77 range samples).
"Reused" is checked three independent ways: the file's inode and mtime are unchanged (every write is
a new file renamed into place, so a rewrite always changes the inode), the stage functions are replaced
by ones that raise (a reused stage never calls its function), and the progress lines on stderr.
"""
from __future__ import annotations

import contextlib
import io
import json
import os
import re
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml

import fwdlook_cli
import fwdlook_cli.forward.chain as chain
from fwdlook_cli.cli import main

STAGES = ("range_fft", "decimate", "keystone", "regroup", "range_curvature", "doppler_spectra",
          "monopulse_image")
STAGE_FUNCS = {"range_fft": "range_fft", "decimate": "decimate", "keystone": "keystone_stage",
               "regroup": "regroup", "range_curvature": "range_curvature",
               "doppler_spectra": "doppler_spectra", "monopulse_image": "monopulse_image"}
PROGRESS = re.compile(r"^\[(\d+)/(\d+)\]\s+(\w+)\s+([\d.]+) ms")


# ----------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------
def fwdlook(argv, capsys):
    """``fwdlook ARGV`` in-process: (exit code, stdout, stderr)."""
    with pytest.raises(SystemExit) as info:
        main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return info.value.code, out, err


def process(raw, run_dir, capsys, *extra):
    code, out, err = fwdlook(["process", raw, "-o", run_dir, *extra], capsys)
    assert code == 0, err
    return err


def stage_paths(run_dir):
    return [Path(run_dir) / "stages" / f"{i + 1:02d}_{name}.h5" for i, name in enumerate(STAGES)]


def identity(run_dir):
    """(inode, mtime_ns) of every stage file: changes if and only if the file was rewritten."""
    out = []
    for p in stage_paths(run_dir):
        st = os.stat(p)
        out.append((st.st_ino, st.st_mtime_ns))
    return out


def forbid(monkeypatch, names):
    """Replace the named stages' functions by ones that fail: a reused stage never calls its function."""
    for name in names:
        def boom(*args, _name=name, **kwargs):
            raise AssertionError(f"stage {_name} was recomputed")
        monkeypatch.setattr(chain, STAGE_FUNCS[name], boom)


def progress(err):
    """{stage name: milliseconds} from the '[i/7] name  t ms compute' lines."""
    found = {}
    for line in err.splitlines():
        m = PROGRESS.match(line)
        if m:
            assert int(m.group(2)) == len(STAGES)
            assert STAGES[int(m.group(1)) - 1] == m.group(3)
            found[m.group(3)] = float(m.group(4))
    return found


def stage_key(path):
    with h5py.File(path, "r") as f:
        return f.attrs["config_sha256"]


# ----------------------------------------------------------------------------------------------
# one complete run, copied for every test that changes it
# ----------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def base_run(tiny_raw, tmp_path_factory):
    """A complete ``fwdlook process`` of the tiny cube (default processing settings): (run dir, stderr)."""
    run_dir = tmp_path_factory.mktemp("base") / "run"
    err = io.StringIO()
    with contextlib.redirect_stderr(err), pytest.raises(SystemExit) as info:
        main(["process", str(tiny_raw), "-o", str(run_dir)])
    assert info.value.code == 0, err.getvalue()
    return run_dir, err.getvalue()


@pytest.fixture
def done_run(base_run, tmp_path):
    run_dir = tmp_path / "run"
    shutil.copytree(base_run[0], run_dir)
    return run_dir


def run_params(run_dir):
    return json.loads((Path(run_dir) / "metrics.json").read_text())["params"]


# ----------------------------------------------------------------------------------------------
# layout of the stage files
# ----------------------------------------------------------------------------------------------
def test_stage_files_attrs_hash_chain_units_and_scales(base_run):
    run_dir, _ = base_run
    files = sorted(p.name for p in (run_dir / "stages").iterdir())
    assert files == [p.name for p in stage_paths(run_dir)]
    metrics = json.loads((run_dir / "metrics.json").read_text())
    previous = None
    for name, path in zip(STAGES, stage_paths(run_dir)):
        with h5py.File(path, "r") as f:
            assert f.attrs["stage"] == name
            key, input_key = f.attrs["config_sha256"], f.attrs["input_sha256"]
            assert re.fullmatch(r"[0-9a-f]{64}", key) and re.fullmatch(r"[0-9a-f]{64}", input_key)
            if previous is not None:
                assert input_key == previous                 # each stage hashes the one before it
            previous = key
            assert metrics["stage_sha256"][name] == key
            assert isinstance(json.loads(f.attrs["settings"]), dict)
            assert f.attrs["software_version"] == fwdlook_cli.__version__
            n_data = 0
            for ds_name, ds in f.items():
                assert isinstance(ds, h5py.Dataset), ds_name
                assert "units" in ds.attrs, f"{path.name}:/{ds_name} has no units"
                if "dims" not in ds.attrs:                  # a coordinate: a dimension scale
                    assert h5py.h5ds.is_scale(ds.id), f"{path.name}:/{ds_name}"
                    continue
                n_data += 1
                dims = json.loads(ds.attrs["dims"])
                assert len(dims) == ds.ndim
                for axis, dim in enumerate(dims):
                    if dim not in f:                        # see test_every_stage_dimension_has_its_scale
                        continue
                    attached = [ds.dims[axis][i].name for i in range(len(ds.dims[axis]))]
                    assert attached == [f"/{dim}"], f"{path.name}:/{ds_name} axis {axis}: {attached}"
                    assert f[dim].shape == (ds.shape[axis],)
            assert n_data > 0
    # the settings of a stage are what made it: stage 2 decimates by the run's q
    q = run_params(run_dir)["q"]
    with h5py.File(stage_paths(run_dir)[1], "r") as f:
        assert json.loads(f.attrs["settings"]) == {"q": q}
        assert f["sum_f"].shape == (400 // q, q, 77)


def test_every_stage_dimension_has_its_scale(base_run):
    run_dir, _ = base_run
    missing = []
    for path in stage_paths(run_dir):
        with h5py.File(path, "r") as f:
            for ds_name, ds in f.items():
                for dim in json.loads(ds.attrs.get("dims", "[]")):
                    if dim not in f:
                        missing.append(f"{path.name}:/{ds_name} -> {dim}")
    assert missing == []


def test_each_stage_reports_its_time(base_run):
    run_dir, err = base_run
    times = progress(err)
    assert list(times) == list(STAGES)                       # in order, one line each
    metrics = json.loads((run_dir / "metrics.json").read_text())
    for name, ms in times.items():
        # the reported compute time is part of the stage's recorded wall time (compute + write)
        assert 0.0 <= ms / 1e3 <= metrics["timing_s"][name] + 1e-4, name


# ----------------------------------------------------------------------------------------------
# reuse and recompute
# ----------------------------------------------------------------------------------------------
def test_identical_rerun_reuses_every_stage(tiny_raw, done_run, capsys, monkeypatch):
    before = identity(done_run)
    metrics_before = json.loads((done_run / "metrics.json").read_text())
    forbid(monkeypatch, STAGES)
    err = process(tiny_raw, done_run, capsys)
    assert identity(done_run) == before
    assert progress(err) == {}
    assert "up to date" in err
    metrics = json.loads((done_run / "metrics.json").read_text())
    assert metrics["targets"] == metrics_before["targets"]


def test_changing_cpi_recomputes_stages_6_and_7_only(tiny_raw, done_run, capsys, monkeypatch):
    before = identity(done_run)
    keys_before = [stage_key(p) for p in stage_paths(done_run)]
    cpi = run_params(done_run)["cpi"] // 2
    forbid(monkeypatch, STAGES[:5])
    err = process(tiny_raw, done_run, capsys, "--set", f"processing.cpi={cpi}")
    after = identity(done_run)
    keys = [stage_key(p) for p in stage_paths(done_run)]
    assert after[:5] == before[:5] and keys[:5] == keys_before[:5]
    assert all(a[0] != b[0] for a, b in zip(after[5:], before[5:]))
    assert all(k != kb for k, kb in zip(keys[5:], keys_before[5:]))
    assert set(progress(err)) == {"doppler_spectra", "monopulse_image"}
    with h5py.File(stage_paths(done_run)[5], "r") as f:
        assert f["cpi_time_s"].shape == (400 // cpi,)


def test_changing_a_keystone_setting_recomputes_from_stage_3(tiny_raw, done_run, capsys, monkeypatch):
    before = identity(done_run)
    t_ref = {"centre": "start", "start": "centre"}[run_params(done_run)["t_ref"]]
    forbid(monkeypatch, STAGES[:2])
    err = process(tiny_raw, done_run, capsys, "--set", f"processing.t_ref={t_ref}")
    after = identity(done_run)
    assert after[:2] == before[:2]
    assert all(a[0] != b[0] for a, b in zip(after[2:], before[2:]))
    assert set(progress(err)) == set(STAGES[2:])


def test_force_recomputes_every_stage_and_quiet_is_silent(tiny_raw, done_run, capsys):
    before = identity(done_run)
    err = process(tiny_raw, done_run, capsys, "--force", "-q")
    assert all(a[0] != b[0] for a, b in zip(identity(done_run), before))
    assert err == ""


def test_from_stage_recomputes_from_that_stage(tiny_raw, done_run, capsys, monkeypatch):
    before = identity(done_run)
    forbid(monkeypatch, STAGES[:4])
    err = process(tiny_raw, done_run, capsys, "--from-stage", "range_curvature")
    after = identity(done_run)
    assert after[:4] == before[:4]
    assert all(a[0] != b[0] for a, b in zip(after[4:], before[4:]))
    assert set(progress(err)) == set(STAGES[4:])


def test_unknown_from_stage_exits_2_listing_the_stages(tiny_raw, tmp_path, capsys):
    run_dir = tmp_path / "run"
    code, out, err = fwdlook(["process", tiny_raw, "-o", run_dir, "--from-stage", "kestone"], capsys)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("fwdlook: error:") and "kestone" in lines[0]
    assert all(name in lines[0] for name in STAGES), lines[0]
    assert not (run_dir / "metrics.json").exists() and not (run_dir / "image.h5").exists()
    assert not list(run_dir.glob("stages/*.h5"))
    # from a scenario, a name no chain of its kind has is refused before the cube is simulated (it had
    # been refused after, the simulator's progress line before the error; an independent review)
    root = Path(__file__).resolve().parents[1]
    for scenario, kind in (("tiny.yaml", "forward"), ("isar_theta3.yaml", "isar")):
        code, out, err = fwdlook(["process", root / "scenarios" / scenario, "-o", tmp_path / kind,
                                  "--from-stage", "kestone"], capsys)
        lines = err.strip().splitlines()
        assert code == 2 and len(lines) == 1 and f"no {kind} chain has this stage" in lines[0], err
        assert not (tmp_path / kind).exists()


def test_the_stage_names_the_command_line_checks_first_are_every_chains():
    """``--from-stage`` is checked against chain.STAGE_NAMES before a cube exists: those lists hold
    every stage of every forward chain (each method, CPI and dwell imaging) and ISAR chain built."""
    from fwdlook_cli.forward.simulate import simulate_scenario
    from fwdlook_cli.isar.chain import STAGE_NAMES as ISAR_NAMES, build_isar_stages
    from fwdlook_cli.isar.simulate import simulate_isar_scenario
    from fwdlook_cli.scenario.loader import load_scenario

    root = Path(__file__).resolve().parents[1]
    tiny = load_scenario(root / "scenarios" / "tiny.yaml")
    cube, _ = simulate_scenario(tiny)
    seen = set()
    for method in ("none", "bulk", "beam", "traditional", "decimation", "tracking"):
        for imaging in ("cpi", "dwell"):
            _, stages, _ = chain.build_forward_stages(cube, dict(tiny["processing"], method=method, imaging=imaging))
            seen |= {st.name for st in stages}
    assert seen == set(chain.STAGE_NAMES)
    isar = load_scenario(root / "scenarios" / "isar_theta3.yaml")
    isar_cube, _ = simulate_isar_scenario(isar)
    seen = set()
    for correction in ("keystone2_n0_est", "keystone1", "none"):
        _, stages = build_isar_stages(isar_cube, dict(isar["processing"], correction=correction))
        seen |= {st.name for st in stages}
    assert seen == set(ISAR_NAMES)


# ----------------------------------------------------------------------------------------------
# interrupted runs
# ----------------------------------------------------------------------------------------------
class Crash(RuntimeError):
    pass


def test_crash_in_stage_5_then_resume(tiny_raw, tmp_path, capsys, monkeypatch):
    run_dir = tmp_path / "run"

    def crash(*args, **kwargs):
        raise Crash("simulated crash in range_curvature")

    with monkeypatch.context() as mp:
        mp.setattr(chain, "range_curvature", crash)
        with pytest.raises(Crash):
            main(["process", str(tiny_raw), "-o", str(run_dir), "-q"])
    paths = stage_paths(run_dir)
    assert all(p.is_file() for p in paths[:4])
    assert not any(p.exists() for p in paths[4:])
    assert not list(run_dir.rglob("*.partial"))
    assert not (run_dir / "metrics.json").exists() and not (run_dir / "image.h5").exists()
    first4 = [(os.stat(p).st_ino, os.stat(p).st_mtime_ns) for p in paths[:4]]
    capsys.readouterr()
    forbid(monkeypatch, STAGES[:4])
    err = process(tiny_raw, run_dir, capsys)
    assert identity(run_dir)[:4] == first4
    assert set(progress(err)) == set(STAGES[4:])
    assert (run_dir / "metrics.json").is_file() and (run_dir / "image.h5").is_file()


def test_crashed_rerun_keeps_the_earlier_runs_outputs_whole(tiny_raw, done_run, monkeypatch):
    """A rerun with other settings that fails in the chain leaves the earlier run's outputs as they were,
    byte for byte, one finished run with its own scenario.yaml (an independent review found them
    removed before the new chain had run: a failed or refused rerun lost them)."""
    outputs = ("metrics.json", "image.h5", "image.png", "scenario.yaml")
    before = {name: (done_run / name).read_bytes() for name in outputs}
    cpi = run_params(done_run)["cpi"] // 2

    def crash(*args, **kwargs):
        raise Crash("simulated crash in doppler_spectra")

    monkeypatch.setattr(chain, "doppler_spectra", crash)
    with pytest.raises(Crash):
        main(["process", str(tiny_raw), "-o", str(done_run), "-q", "--set", f"processing.cpi={cpi}"])
    assert {name: (done_run / name).read_bytes() for name in outputs} == before
    # the folder says what it holds: the metrics' settings are its scenario.yaml's
    held = yaml.safe_load((done_run / "scenario.yaml").read_text())["processing"]["cpi"]
    assert json.loads((done_run / "metrics.json").read_text())["params"]["cpi"] == held != cpi


def test_crash_while_writing_a_stage_leaves_no_partial(tiny_raw, tmp_path, capsys, monkeypatch):
    # stage 5 computes, then its output cannot be written (an object array h5py refuses) mid-file
    run_dir = tmp_path / "run"
    real = chain.range_curvature

    def unwritable(data, **params):
        out = real(data, **params)
        out.add("zz_bad", np.array([object(), object()], dtype=object), ("zz_bad_dim",), "1", "unwritable")
        return out

    with monkeypatch.context() as mp:
        mp.setattr(chain, "range_curvature", unwritable)
        with pytest.raises(TypeError):                      # h5py: no HDF5 equivalent for dtype object
            main(["process", str(tiny_raw), "-o", str(run_dir), "-q"])
    paths = stage_paths(run_dir)
    assert all(p.is_file() for p in paths[:4]) and not any(p.exists() for p in paths[4:])
    assert not list(run_dir.rglob("*.partial"))
    assert not (run_dir / "metrics.json").exists() and not (run_dir / "image.h5").exists()


def test_corrupt_stage_file_is_recomputed_not_trusted(tiny_raw, done_run, capsys, monkeypatch):
    paths = stage_paths(done_run)
    with h5py.File(paths[2], "r") as f:
        good = f["sum_f"][()]
    before = identity(done_run)
    size = paths[2].stat().st_size
    with open(paths[2], "r+b") as fh:                        # truncate stage 3 to half its size
        fh.truncate(size // 2)
    forbid(monkeypatch, STAGES[:2])
    err = process(tiny_raw, done_run, capsys)
    after = identity(done_run)
    assert after[:2] == before[:2]
    assert after[2][0] != before[2][0]
    assert "keystone" in progress(err)
    with h5py.File(paths[2], "r") as f:
        assert np.array_equal(f["sum_f"][()], good)          # deterministic: the same data again


def test_stale_stage_file_is_recomputed(tiny_raw, done_run, capsys, monkeypatch):
    # stage 6 as if made by other settings or another input: its key no longer matches the chain's
    paths = stage_paths(done_run)
    with h5py.File(paths[5], "r+") as f:
        right_key = f.attrs["config_sha256"]
        f.attrs["config_sha256"] = "0" * 64
    before = identity(done_run)
    forbid(monkeypatch, STAGES[:5])
    err = process(tiny_raw, done_run, capsys)
    assert identity(done_run)[:5] == before[:5]
    assert set(progress(err)) == {"doppler_spectra", "monopulse_image"}
    assert right_key != "0" * 64


def assert_provenance(run_dir):
    """Every stage file says which stage it is, and its key is the one metrics.json reports."""
    metrics = json.loads((Path(run_dir) / "metrics.json").read_text())
    for name, path in zip(STAGES, stage_paths(run_dir)):
        with h5py.File(path, "r") as f:
            assert (f.attrs["stage"], f.attrs["config_sha256"]) == (name, metrics["stage_sha256"][name]), path.name


def test_stages_recomputed_after_reused_ones_carry_their_own_provenance(tiny_raw, done_run, capsys, monkeypatch):
    cpi = run_params(done_run)["cpi"] // 2
    process(tiny_raw, done_run, capsys, "-q", "--set", f"processing.cpi={cpi}")
    assert_provenance(done_run)
    before = identity(done_run)
    forbid(monkeypatch, STAGES)                             # the same settings again: nothing to compute
    process(tiny_raw, done_run, capsys, "-q", "--set", f"processing.cpi={cpi}")
    assert identity(done_run) == before


# ----------------------------------------------------------------------------------------------
# fwdlook run: -q
# ----------------------------------------------------------------------------------------------
def test_run_quiet_prints_only_the_metrics_path(tmp_path, capsys):
    tiny_yaml = Path(__file__).resolve().parents[1] / "scenarios" / "tiny.yaml"
    code, out, err = fwdlook(["run", tiny_yaml, "-o", tmp_path / "q", "-q"], capsys)
    assert code == 0 and err == ""
    assert out.strip() == str(tmp_path / "q" / "metrics.json")
    assert (tmp_path / "q" / "metrics.json").is_file()


def test_a_run_folder_reused_for_another_chain_holds_that_chains_stage_files_only(tiny_raw, tmp_path, capsys):
    """`decimation` (CPI image, seven stages) then `tracking` with the dwell image (six) into one folder:
    the CPI chain's Doppler and image files go (they had stayed beside the dwell image's), a user's own
    file in stages/ stays."""
    run_dir = tmp_path / "run"
    process(tiny_raw, run_dir, capsys, "--set", "processing.method=decimation")
    assert (run_dir / "stages" / "07_monopulse_image.h5").exists()
    mine = run_dir / "stages" / "99_mine.h5"
    with h5py.File(mine, "w") as f:
        f["x"] = np.arange(3)
    process(tiny_raw, run_dir, capsys, "--set", "processing.method=tracking", "--set", "processing.imaging=dwell")
    names = sorted(p.name for p in (run_dir / "stages").iterdir())
    assert names == ["01_range_fft.h5", "02_decimate.h5", "03_keystone.h5", "04_regroup.h5",
                     "05_range_curvature.h5", "06_dwell_image.h5", "99_mine.h5"], names
