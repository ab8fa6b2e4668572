"""``--out-of-core`` (io/backing.py, issue 11 item 3): the cube and every stage's arrays in unnamed scratch
files, the stages in blocks read from and written to them.  The results are the in-memory chain's bit
for bit (every stage file's arrays, image.h5, metrics.json's targets) with blocks far smaller than
the arrays; nothing is left in the scratch directory; bad combinations are one-line errors."""
import json
import os

import h5py
import numpy as np
import pytest
import scipy.fft

from fwdlook_cli.errors import BadInput
from fwdlook_cli.forward import keystone_fast
from fwdlook_cli.forward.keystone_fast import keystone_both, keystone_both_blocked
from fwdlook_cli.forward.motion import DopplerPhaseHistory
from fwdlook_cli.forward.process import process_cube
from fwdlook_cli.io import backing
from fwdlook_cli.io.raw import read_raw, write_raw
from fwdlook_cli.testing import tiny_scenario
from cgroup_files import cgroup_files, fake_proc
from fft_backend import assert_same_to_fft_rounding, assert_targets_same_to_rounding


def test_file_backed_arrays_are_unnamed_maps_and_only_inside_the_context(tmp_path):
    with backing.file_backed(tmp_path, min_bytes=1024):
        big = backing.empty((64, 32), np.complex64)               # 16 KiB: file-backed
        small = backing.empty((4, 4), np.complex64)               # under min_bytes: memory
        assert isinstance(big, np.memmap) and not isinstance(small, np.memmap)
        assert not big.any()                                      # a new file reads as zeros
        big[:] = 1 + 2j
        assert os.listdir(tmp_path) == []                         # O_TMPFILE: never a name
        with backing.in_memory():
            assert not isinstance(backing.empty((64, 32), np.complex64), np.memmap)
        assert backing.active()
    assert not backing.active() and not isinstance(backing.empty((64, 32), np.complex64), np.memmap)
    assert np.all(big == 1 + 2j)                                  # the map outlives the context


def test_blocked_reads_and_counts_are_the_whole_ones(tmp_path):
    rng = np.random.default_rng(0)
    x = rng.standard_normal((1000, 37)).astype(np.float32)
    x[[3, 500, 999], [0, 5, 36]] = [np.nan, np.inf, -np.inf]
    with h5py.File(tmp_path / "x.h5", "w") as f:
        f.create_dataset("x", data=x, chunks=(64, 37))
    with h5py.File(tmp_path / "x.h5", "r") as f, backing.file_backed(tmp_path, min_bytes=0):
        backing.BLOCK_BYTES, saved = 1000, backing.BLOCK_BYTES    # 6 rows a block
        try:
            y = backing.read_dataset(f["x"])
            assert isinstance(y, np.memmap) and backing.count_nonfinite(y) == 3
        finally:
            backing.BLOCK_BYTES = saved
    np.testing.assert_array_equal(y, x)


def test_keystone_super_blocks_give_the_whole_keystone(tmp_path):
    """The out-of-core keystone reads super-blocks of range frequencies (of every sub-sequence) and
    transforms each in memory: the decimated layout and the tracking keystone (whose demodulation grid
    is the whole axis's) bit for bit the in-memory keystone of all columns (to the CZT's rounding with
    scipy 1.18's ducc, whose rounding depends on a column's place in its batch: tests/fft_backend.py)."""
    rng = np.random.default_rng(5)
    p, q, n_f, prf, fc = 256, 3, 40, 2500.0, 18e9
    fr = scipy.fft.fftfreq(n_f, 1 / 60e6)
    xs, xd = ((rng.standard_normal((p, q * n_f)) + 1j * rng.standard_normal((p, q * n_f))).astype(np.complex64)
              for _ in range(2))
    grouped = dict(alpha=np.tile(fc / (fc + fr), q), t0_index=np.repeat([40.2, 39.9, 39.5], n_f),
                   implementation="czt", ambiguity=2, period=n_f)
    t = np.arange(p) / prf
    vel = np.column_stack([np.zeros(p), 240.0 + 50.0 * t, np.zeros(p)])
    hist = DopplerPhaseHistory(t, vel, -15.0 + 30.0 * t / t[-1], 1.7, fc, t[p // 2])
    tracking = dict(alpha=fc / (fc + fr), t0_index=np.full(n_f, p / 2.0), implementation="czt", ambiguity=0,
                    tracking=(hist, t, prf, 1.0 + fr / fc), period=n_f)
    for kw, (a, b) in ((grouped, (xs, xd)), (tracking, (xs[:, :n_f], xd[:, :n_f]))):
        whole = keystone_both(a, b, **kw)
        with backing.file_backed(tmp_path, min_bytes=0):
            for width in (1, 7):                                   # columns of each group per super-block
                blocked = keystone_both_blocked(a, b, superblock_bytes=8 * p * (q if kw is grouped else 1) * width,
                                                **kw)
                n_czt = scipy.fft.next_fast_len(2 * p - 1)
                for u, v in zip(whole, blocked):
                    assert_same_to_fft_rounding(v, u, n_czt, n_czt, n_czt)


def _stage_arrays(run_dir):
    out = {}
    for path in sorted((run_dir / "stages").glob("*.h5")) + [run_dir / "image.h5"]:
        with h5py.File(path, "r") as f:
            f.visititems(lambda n, o: out.__setitem__(f"{path.name}:{n}", o[()]) if isinstance(o, h5py.Dataset)
                         else None)
    return out


@pytest.mark.parametrize("method, imaging", [("decimation", "cpi"), ("tracking", "cpi"), ("tracking", "dwell"),
                                             ("beam", "cpi")])
def test_the_out_of_core_chain_is_the_in_memory_chain(tiny_raw, tmp_path, monkeypatch, method, imaging):
    """Every stage file's arrays, image.h5 and the targets of metrics.json, with every array of the run
    file-backed (min_bytes 0) and blocks of a few rows: bit for bit (to float32 rounding where scipy's FFT
    rounds a transform by its place in the batch, scipy 1.18's ducc: tests/fft_backend.py); a rerun
    reuses the stage files (read back file-backed) with the same outputs; no scratch file is left."""
    monkeypatch.setattr(backing, "BLOCK_BYTES", 4096)
    monkeypatch.setattr(keystone_fast, "SUPERBLOCK_BYTES", 16384)
    scn = tiny_scenario(processing={"method": method, "imaging": imaging, "q": 4})
    cube = read_raw(tiny_raw)
    assert backing.rows_per_block(cube.sum[0].nbytes) < cube.n_pulses // 8      # many blocks per stage
    n_p, n_r = cube.sum.shape
    memory = process_cube(read_raw(tiny_raw), scn, tmp_path / "memory", png=False, quiet=True)
    scratch = tmp_path / "scratch"
    with backing.file_backed(scratch, min_bytes=0):
        cube = read_raw(tiny_raw)
        assert isinstance(cube.sum, np.memmap)
        on_file = process_cube(cube, scn, tmp_path / "file", png=False, quiet=True, release_cube=True)
        again = process_cube(read_raw(tiny_raw), scn, tmp_path / "file", png=False, quiet=True)
    assert os.listdir(scratch) == []
    assert on_file["targets"] == again["targets"]
    assert_targets_same_to_rounding(on_file["targets"], memory["targets"])
    assert set(again["timing_s"]) == set(on_file["timing_s"])
    a, b = _stage_arrays(tmp_path / "memory"), _stage_arrays(tmp_path / "file")
    assert a.keys() == b.keys()
    # the transforms a sample goes through: the range FFT, the keystone's CZT (three), the curvature's
    # inverse range FFT and the Doppler zoom (the dwell focus's are of the same lengths)
    n_czt = scipy.fft.next_fast_len(2 * n_p - 1)
    lengths = (n_r, n_czt, n_czt, n_czt, n_r, n_p)
    for name in a:
        assert_same_to_fft_rounding(b[name], a[name], *lengths, err_msg=name)


def test_plain_datasets_are_mapped_where_they_lie_and_others_are_not(tmp_path):
    """`map_in_place`: a contiguous, unfiltered dataset is a read-only map of its bytes in the file (the
    same values as reading it); chunked, compressed or not yet allocated ones are not mapped, and
    `read_dataset` reads those as before."""
    x = (np.arange(3000, dtype=np.float32).reshape(100, 30) + 1j).astype(np.complex64)     # 24 KB
    with h5py.File(tmp_path / "x.h5", "w") as f:
        f.create_dataset("plain", data=x)
        f.create_dataset("chunked", data=x, chunks=(10, 30))
        f.create_dataset("gzip", data=x, compression="gzip")
        f.create_dataset("empty", shape=x.shape, dtype=x.dtype)         # never written: no storage
    with h5py.File(tmp_path / "x.h5", "r") as f:
        m = backing.map_in_place(f["plain"])
        assert isinstance(m, np.memmap) and not m.flags.writeable
        np.testing.assert_array_equal(m, x)
        assert all(backing.map_in_place(f[k]) is None for k in ("chunked", "gzip", "empty"))
        with backing.file_backed(tmp_path, min_bytes=0), backing.mapped_sources():
            assert backing.read_dataset(f["plain"]).filename == str((tmp_path / "x.h5").resolve())
            y = backing.read_dataset(f["chunked"])                # copied into a scratch file
            assert y.filename is None and y.flags.writeable
            np.testing.assert_array_equal(y, x)
        assert not isinstance(backing.read_dataset(f["plain"]), np.memmap)    # only inside the context


def _isolated_cube_file(path):
    """fwdlook's isolated-point cube written to ``path`` (8 MB a channel: over backing.MIN_BYTES)."""
    from fwdlook_cli.forward.simulate import simulate_scenario
    from fwdlook_cli.scenario.loader import load_scenario

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    cube, _ = simulate_scenario(load_scenario(os.path.join(root, "scenarios", "isolated_a50.yaml")))
    write_raw(path, cube)
    return path


def _keep_arguments_of(monkeypatch, module, name):
    """Replace ``module.name`` by itself recording its calls' (arguments, result) in the list returned."""
    calls, real = [], getattr(module, name)
    monkeypatch.setattr(module, name, lambda *args: calls.append((args, real(*args))) or calls[-1][1])
    return calls


def test_info_holds_no_copy_of_a_cube_and_says_the_same(tmp_path, monkeypatch):
    """`fwdlook info` reads a cube's echoes as maps: of the file itself where they are stored plainly
    (the independent writer's contiguous datasets), else of an unnamed scratch copy (fwdlook's chunked
    ones), and the calibration's detection reads them in blocks; its text is the in-memory
    description's, to the character."""
    import sys

    from fwdlook_cli.report import info

    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import independent_writer

    _isolated_cube_file(tmp_path / "chunked.h5")
    az = np.radians([-3.5, -2.1, -0.7, 0.7, 2.1, 3.5])
    r = 1650.0 + 70.0 * np.arange(len(az))
    independent_writer.write_cube(tmp_path / "plain.h5", "paper", np.column_stack([r * np.sin(az), r * np.cos(az)]),
                                  n_pulses=650)
    in_memory = {name: info._describe_cube(str(tmp_path / name), read_raw(tmp_path / name))
                 for name in ("chunked.h5", "plain.h5")}
    calls = _keep_arguments_of(monkeypatch, info, "_describe_cube")
    for name, mapped in (("chunked.h5", False), ("plain.h5", True)):
        assert "calibration     data (" in in_memory[name]            # a calibration from the data
        assert info.describe_raw(str(tmp_path / name)) == in_memory[name]
        echo = calls[-1][0][1].sum
        assert isinstance(echo, np.memmap) and echo.nbytes >= backing.MIN_BYTES
        assert (echo.filename == str((tmp_path / name).resolve()) and not echo.flags.writeable) == mapped, name


def test_validate_checks_a_cube_without_holding_it(tmp_path, monkeypatch, capsys):
    """`fwdlook validate RAW.h5` reads a cube as `info` does: the echoes it checks are maps (here of a
    scratch copy, fwdlook's cubes being chunked), the verdict the same as in memory.  Where the
    temporary directory takes no file, they are read into memory as before, with the same verdict and
    no word of --out-of-core."""
    from fwdlook_cli.cli import main
    import fwdlook_cli.io.raw as raw

    path = _isolated_cube_file(tmp_path / "iso.h5")
    calls = _keep_arguments_of(monkeypatch, raw, "read_raw")
    (tmp_path / "not_a_dir").write_text("")
    for tmpdir, held in ((tmp_path / "scratch", False), (tmp_path / "not_a_dir" / "sub", True)):
        monkeypatch.setattr(backing.tempfile, "gettempdir", lambda d=str(tmpdir): d)
        with pytest.raises(SystemExit) as exc:
            main(["validate", str(path)])
        out, err = capsys.readouterr()
        assert exc.value.code in (0, None) and err == "", err
        assert out.strip() == f"{path}: valid raw cube, 2500 pulses x 400 range samples"
        assert isinstance(calls[-1][1].sum, np.memmap) != held, tmpdir


def read_raw_tiny(tmp_path):
    from fwdlook_cli.forward.simulate import simulate_scenario

    cube, _ = simulate_scenario(tiny_scenario())
    return cube


def test_out_of_core_still_rejects_a_cube_with_nan(tmp_path):
    cube = read_raw_tiny(tmp_path)
    cube.diff[7, 3] = np.nan
    write_raw(tmp_path / "nan.h5", cube)
    with backing.file_backed(tmp_path / "scratch", min_bytes=0), pytest.raises(BadInput) as err:
        read_raw(tmp_path / "nan.h5")
    assert str(err.value).endswith("/echo/diff: 1 NaN/Inf values; allowed: finite values only")


def test_the_command_line_flag(tiny_raw, tmp_path, capsys):
    """``process --out-of-core`` runs and leaves nothing beside the run directory; a setting it cannot
    honour (IAA, whole CPIs of every range cell) is one line on stderr and exit 2."""
    from fwdlook_cli.cli import main

    def run(*argv):
        with pytest.raises(SystemExit) as exc:
            main([str(a) for a in argv])
        return exc.value.code, capsys.readouterr().err

    code, err = run("process", tiny_raw, "-o", tmp_path / "run", "--out-of-core", "-q")
    assert code == 0, err
    assert sorted(os.listdir(tmp_path)) == ["run"]
    assert json.loads((tmp_path / "run" / "metrics.json").read_text())["summary"]["detected"] >= 1
    code, err = run("process", tiny_raw, "-o", tmp_path / "iaa", "--out-of-core", "-q",
                    "--set", "processing.doppler_estimator=iaa", "--set", "processing.imaging=cpi")
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert str(tiny_raw) in err and "allowed with --out-of-core: fft" in err
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    code, err = run("run", os.path.join(root, "scenarios", "isar_theta3.yaml"), "-o", tmp_path / "isar",
                    "--out-of-core", "-q")                      # refused before the cube is simulated
    assert code == 2 and "ISAR chain runs in memory" in err and not (tmp_path / "isar").exists()
    # `run` refuses the settings --out-of-core cannot honour before it simulates: a refused rerun had
    # simulated and written raw.h5 first, over the earlier run's cube (an independent review)
    code, err = run("run", os.path.join(root, "scenarios", "tiny.yaml"), "-o", tmp_path / "iaa_run", "--out-of-core",
                    "-q", "--set", "processing.doppler_estimator=iaa", "--set", "processing.imaging=cpi")
    assert code == 2 and "allowed with --out-of-core: fft" in err and not (tmp_path / "iaa_run").exists()
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    code, err = run("process", tiny_raw, "-o", blocker / "run", "--out-of-core", "-q")
    assert code == 2 and len(err.strip().splitlines()) == 1 and "scratch directory" in err


def test_a_cube_too_big_for_memory_is_told_about_out_of_core(tiny_raw, tmp_path, monkeypatch, caplog):
    """Reading a cube whose in-memory run would need more than the memory available warns once, before
    the read, naming the file and --out-of-core; not when it fits, nor inside the out-of-core context."""
    import logging

    cube_bytes = 2 * 8 * int(np.prod(h5py.File(tiny_raw, "r")["echo/sum"].shape))
    caplog.set_level(logging.WARNING)
    for available, expected in ((10 * cube_bytes, 0), (2 * cube_bytes, 1)):
        monkeypatch.setattr(backing, "memory_available_bytes", lambda a=available: a)
        caplog.clear()
        read_raw(tiny_raw)
        hints = [r.getMessage() for r in caplog.records if "--out-of-core" in r.getMessage()]
        assert len(hints) == expected and all(str(tiny_raw) in h for h in hints)
    caplog.clear()
    with backing.file_backed(tmp_path):
        read_raw(tiny_raw)
    assert not [r for r in caplog.records if "--out-of-core" in r.getMessage()]


def test_a_scene_too_big_to_simulate_in_memory_is_told_about_out_of_core(tmp_path, monkeypatch, capsys):
    """``simulate`` of a scene whose cube (with its blocks, 1.1 cubes) would not fit the memory available
    warns once before simulating, naming the scenario file and --out-of-core; ``run`` warns where its
    whole in-memory chain (3 cubes) would not fit; neither warns when it fits or out of core."""
    from fwdlook_cli.cli import main
    from fwdlook_cli.scenario.loader import load_scenario
    from fwdlook_cli.forward.simulate import simulate_scenario

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    tiny_yaml = os.path.join(root, "scenarios", "tiny.yaml")
    cube, _ = simulate_scenario(load_scenario(tiny_yaml))
    cube_bytes = cube.sum.nbytes + cube.diff.nbytes

    def warnings_of(*argv, available):
        monkeypatch.setattr(backing, "memory_available_bytes", lambda: available)
        with pytest.raises(SystemExit) as exc:
            main([str(a) for a in argv])
        err = capsys.readouterr().err
        assert exc.value.code in (0, None), err
        return [line for line in err.splitlines() if "--out-of-core holds it" in line]

    for i, (available, command, expected) in enumerate((
            (int(1.5 * cube_bytes), "simulate", 0), (int(1.05 * cube_bytes), "simulate", 1),
            (int(4.0 * cube_bytes), "run", 0), (int(2.0 * cube_bytes), "run", 1))):
        argv = (("simulate", tiny_yaml, "-o", tmp_path / f"c{i}.h5") if command == "simulate"
                else ("run", tiny_yaml, "-o", tmp_path / f"r{i}", "--keep-stages", "none"))
        hints = warnings_of(*argv, available=available)
        assert len(hints) == expected, (command, available, hints)
        assert all(tiny_yaml in h and ("simulating and processing" in h) == (command == "run") for h in hints)
    assert warnings_of("simulate", tiny_yaml, "-o", tmp_path / "ooc.h5", "--out-of-core",
                       available=int(0.5 * cube_bytes)) == []


# ----------------------------------------------------------------------------------------------
# the memory available under a cgroup limit (a container's, a batch job's)
# ----------------------------------------------------------------------------------------------
GIB = 1 << 30


def test_cgroup_v2_room_is_the_smallest_over_the_own_cgroup_and_its_ancestors(tmp_path):
    """limit - (usage - inactive file pages), the smallest over the job's cgroup and its parents; a parent
    without a limit ("max") does not count."""
    mnt = tmp_path / "cg"
    cgroup_files(mnt / "user.slice" / "job_42", memory_max=8 * GIB, memory_current=3 * GIB,
                memory_stat=f"anon {2 * GIB}\ninactive_file {GIB}")
    cgroup_files(mnt / "user.slice", memory_max="max", memory_current=5 * GIB)
    proc = fake_proc(tmp_path, ["0::/user.slice/job_42"],
                      [f"30 23 0:27 / {mnt} rw,nosuid - cgroup2 cgroup2 rw,nsdelegate"])
    assert backing.cgroup_room_bytes(proc) == 8 * GIB - (3 * GIB - GIB)
    cgroup_files(mnt / "user.slice", memory_max=5 * GIB, memory_current=4 * GIB + GIB // 2,
                memory_stat="inactive_file 0")
    assert backing.cgroup_room_bytes(proc) == GIB // 2
    cgroup_files(mnt / "user.slice", memory_max="max")
    cgroup_files(mnt / "user.slice" / "job_42", memory_max="max")
    assert backing.cgroup_room_bytes(proc) is None


def test_cgroup_v1_in_a_container_reads_its_own_limit(tmp_path):
    """A v1 memory hierarchy mounted with the container's cgroup as its root (docker's layout): the
    mount point itself holds the limit; v1's "unlimited" (about 2^63) is no limit; another v1
    controller's mount is not read."""
    mem, cpu = tmp_path / "memory", tmp_path / "cpu"
    cgroup_files(mem, memory_limit_in_bytes=2 * GIB, memory_usage_in_bytes=GIB + GIB // 2,
                memory_stat=f"cache {GIB}\ntotal_inactive_file {GIB // 4}")
    cgroup_files(cpu, memory_limit_in_bytes=GIB // 8, memory_usage_in_bytes=0)
    proc = fake_proc(tmp_path, ["5:cpu,cpuacct:/docker/abc", "4:memory:/docker/abc", "0::/"],
                      [f"40 31 0:30 /docker/abc {cpu} rw - cgroup cgroup rw,cpu,cpuacct",
                       f"41 31 0:31 /docker/abc {mem} rw - cgroup cgroup rw,memory"],
                      meminfo_kib=100 * GIB // 1024)
    assert backing.cgroup_room_bytes(proc) == 2 * GIB - (GIB + GIB // 2 - GIB // 4)
    # the available memory is the smaller of MemAvailable and the room under the limit
    assert backing.memory_available_bytes(proc) == 3 * GIB // 4
    cgroup_files(mem, memory_limit_in_bytes=9223372036854771712)
    assert backing.cgroup_room_bytes(proc) is None
    assert backing.memory_available_bytes(proc) == 100 * GIB


def test_no_cgroup_information_leaves_the_kernel_estimate(tmp_path):
    proc = tmp_path / "proc"
    proc.mkdir()
    (proc / "meminfo").write_text("MemAvailable: 2048 kB\n")
    assert backing.cgroup_room_bytes(str(proc)) is None
    assert backing.memory_available_bytes(str(proc)) == 2048 * 1024
    assert backing.memory_available_bytes(str(tmp_path / "nothing")) is None


def test_simulation_out_of_core_writes_the_in_memory_cube(tmp_path, capsys):
    """``simulate --out-of-core`` (and ``run --out-of-core``, which simulates inside the same context)
    synthesises both channels into scratch maps, pulse block by pulse block, the noise too: the raw
    file's echoes are the in-memory simulation's bit for bit, nothing is left beside the output, and an
    ISAR scenario (simulated in memory) is refused in one line before any work."""
    from fwdlook_cli.cli import main
    from fwdlook_cli.forward.simulate import simulate_scenario

    scn = tiny_scenario(noise={"snr_db": 20.0, "seed": 3})
    with backing.file_backed(tmp_path, min_bytes=1024):
        cube, _ = simulate_scenario(scn)
        assert isinstance(cube.sum, np.memmap) and isinstance(cube.diff, np.memmap)
    in_memory, _ = simulate_scenario(scn)
    assert not isinstance(in_memory.sum, np.memmap)
    np.testing.assert_array_equal(cube.sum, in_memory.sum)
    np.testing.assert_array_equal(cube.diff, in_memory.diff)

    def run(*argv):
        with pytest.raises(SystemExit) as exc:
            main([str(a) for a in argv])
        return exc.value.code, capsys.readouterr().err

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    tiny_yaml = os.path.join(root, "scenarios", "tiny.yaml")
    for flag in ((), ("--out-of-core",)):
        out = tmp_path / f"cube{len(flag)}" / "raw.h5"
        out.parent.mkdir()
        code, err = run("simulate", tiny_yaml, "-o", out, "-q", *flag)
        assert code in (0, None), err
        assert sorted(os.listdir(out.parent)) == ["raw.h5"]
    with h5py.File(tmp_path / "cube0" / "raw.h5") as a, h5py.File(tmp_path / "cube1" / "raw.h5") as b:
        for name in ("echo/sum", "echo/diff"):
            np.testing.assert_array_equal(a[name][()], b[name][()])
    code, err = run("simulate", os.path.join(root, "scenarios", "isar_theta3.yaml"), "-o", tmp_path / "isar.h5",
                    "--out-of-core", "-q")
    assert code == 2 and len(err.strip().splitlines()) == 1 and "ISAR chain runs in memory" in err
    assert not (tmp_path / "isar.h5").exists()


def test_simulated_pulses_no_target_reaches_are_zeros_out_of_core_too(tmp_path, monkeypatch):
    """The simulator writes only the pulse blocks a target reaches, into arrays that must start at zero:
    inside ``--out-of-core`` a channel under ``MIN_BYTES`` stays in memory, and there it must be zeros,
    not whatever ``np.empty`` returns (poisoned here: NaN), as it is file-backed (a new file) or not."""
    from fwdlook_cli.forward.simulate import simulate_scenario

    scn = tiny_scenario(noise={"snr_db": None})
    scn["scene"]["points_m"] = [scn["scene"]["points_m"][0]]
    scn["antenna"].update(scan_start_deg=-30.0, scan_stop_deg=30.0)       # the point seen part of the scan
    expected, _ = simulate_scenario(scn)
    quiet = ~np.any(expected.sum != 0, axis=1)
    assert quiet.any() and not quiet.all()                                # blocks no target reaches
    monkeypatch.setattr(backing.empty, "__kwdefaults__", {"fill": lambda shape, dtype: np.full(shape, np.nan, dtype)})
    for min_bytes in (1 << 40, 1024):                                     # in memory, then file-backed
        with backing.file_backed(tmp_path, min_bytes=min_bytes):
            cube, _ = simulate_scenario(scn)
        np.testing.assert_array_equal(cube.sum, expected.sum)
        np.testing.assert_array_equal(cube.diff, expected.diff)


@pytest.mark.parametrize("method", ["tracking", "decimation"])
def test_steep_sub_swaths_out_of_core_hold_blocks_not_the_window(tmp_path, monkeypatch, method):
    """Steep depression (3 km up, a 1.5 km window): the keystone stage corrects the window in range
    sub-swaths (forward/subswath.py), each a pair of range transforms around the correction.  Out of
    core they run in blocks of rows between file-backed arrays: the stage's traced memory (numpy's own
    allocations; the maps are the kernel's) is the one-reference correction's own working set (within
    10 % and four blocks of it, under half a channel), where the first version held the window in range
    time whole, both channels (3.4 channels traced, 7 times the one-reference stage); the stage's output
    is the in-memory stage's to the FFTs' rounding."""
    import tracemalloc

    from fwdlook_cli.forward.chain import build_forward_stages
    from fwdlook_cli.forward.simulate import simulate_scenario

    h = 3000.0

    def ground(r, az):
        g = np.sqrt(r * r - h * h)
        return [float(g * np.sin(np.radians(az))), float(g * np.cos(np.radians(az)))]

    scn = tiny_scenario(antenna=dict(tiny_scenario()["antenna"], scan_rate_dps=25.0),
                        platform=dict(tiny_scenario()["platform"], height_m=h),
                        radar=dict(tiny_scenario()["radar"], range_window_m=[3300.0, 4900.0]),
                        scene={"kind": "points", "points_m": [ground(3600.0, 4.0), ground(4500.0, -4.0)],
                               "amplitude": 1.0})
    cube, _ = simulate_scenario(scn)
    proc = dict(scn["processing"], method=method, q=1 if method == "tracking" else 4, imaging="cpi")
    monkeypatch.setattr(backing, "BLOCK_BYTES", 16384)
    monkeypatch.setattr(keystone_fast, "SUPERBLOCK_BYTES", 65536)

    def keystone_in_and_out(subswaths="auto"):
        src, stages, _ = build_forward_stages(cube, dict(proc, subswaths=subswaths))
        names = [st.name for st in stages]
        data = src
        for st in stages[:names.index("keystone")]:
            data = st.fn(data, **st.params)
        st = stages[names.index("keystone")]
        assert len(st.params.get("subswaths") or ()) >= (3 if subswaths == "auto" else 0)
        tracemalloc.start()
        try:
            out = st.fn(data, **st.params)
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        return data["sum_f"].nbytes, peak, {ch: np.array(out[f"{ch}_f"]) for ch in ("sum", "diff")}

    _, _, whole = keystone_in_and_out()
    with backing.file_backed(tmp_path / "scratch", min_bytes=0):
        channel_bytes, peak, blocked = keystone_in_and_out()
        _, peak_one_reference, _ = keystone_in_and_out("none")
    assert peak < min(1.1 * peak_one_reference + 4 * backing.BLOCK_BYTES, 0.5 * channel_bytes), \
        (peak, peak_one_reference, channel_bytes)
    n_p, n_f = cube.sum.shape[0], whole["sum"].shape[-1]
    n_czt = scipy.fft.next_fast_len(2 * n_p - 1)
    for ch in ("sum", "diff"):
        assert_same_to_fft_rounding(blocked[ch], whole[ch], n_f, n_f, n_czt, n_czt, n_czt, err_msg=ch)


def test_the_tracking_remodulation_of_one_column_is_that_column_of_many():
    """keystone_fast.remodulation_cycles: its phase is a [pulses, 6] x [6, columns] product; numpy sends
    a one-column product to gemv, which sums in another order than gemm, and the out-of-core keystone's
    one-column super-blocks differed from the whole keystone in float32's last bit (a steep window's
    sub-swath).  Each column alone is now the many-column product's, bit for bit."""
    from fwdlook_cli.forward.keystone_fast import remodulation_cycles

    rng = np.random.default_rng(3)
    p, n_cols, prf, fc = 1600, 81, 2000.0, 10e9
    derivs = [rng.standard_normal(p) * s for s in (3e3, 2e2, 3e1, 5.0, 1.0)]
    alpha = fc / (fc + scipy.fft.fftfreq(n_cols, 1 / 24e6))
    chirp_rows, chirp_cols = rng.standard_normal(p) * 1e2, rng.standard_normal(n_cols)
    whole = remodulation_cycles(derivs, 800.0, alpha, 1.0 / alpha, prf, chirp_rows, chirp_cols)
    for k in range(n_cols):
        one = remodulation_cycles(derivs, 800.0, alpha[k:k + 1], 1.0 / alpha[k:k + 1], prf, chirp_rows,
                                  chirp_cols[k:k + 1])
        np.testing.assert_array_equal(one[:, 0], whole[:, k], err_msg=str(k))


def _tiny_low_window(prf_hz=2000.0):
    """The tiny radar over a 600-1400 m window, 4000 pulses: the dwell focus needs the oversampled range
    grid there (dwell_range.focus_range_oversample), and blocks of 4 KB are many."""
    from fwdlook_cli.forward.simulate import simulate_scenario

    b = tiny_scenario()
    scn = tiny_scenario(antenna=dict(b["antenna"], scan_rate_dps=10.0),
                        radar=dict(b["radar"], prf_hz=prf_hz, range_window_m=[600.0, 1400.0]))
    return scn, simulate_scenario(scn)[0]


def _file_backed_cube(cube):
    for ch in ("sum", "diff"):
        m = backing.empty(getattr(cube, ch).shape, np.complex64)
        m[:] = getattr(cube, ch)
        setattr(cube, ch, m)
    return cube


def test_the_dwell_focused_on_the_fine_range_grid_out_of_core_is_the_in_memory_one(tmp_path, monkeypatch):
    """Where the dwell image must be focused on the oversampled range grid, out of core had focused it on
    the native grid instead, with a log line (an independent review: 8648 image cells differed, a target
    -0.17 m off in memory and -2.10 m out of core).  The fine grid is now made in chunks of pulses into a
    file-backed array (dwell_range.oversample_focus_input), each chunk resampled on one thread: the dwell
    stage's image, cells and gain are the in-memory stage's bit for bit (ducc0 rounds a row by its place
    in its batch: the chunks are the same either way)."""
    from fwdlook_cli.forward.chain import build_forward_stages

    monkeypatch.setattr(backing, "BLOCK_BYTES", 4096)
    monkeypatch.setattr(keystone_fast, "SUPERBLOCK_BYTES", 16384)
    scn, cube = _tiny_low_window()
    proc = dict(scn["processing"], method="tracking", q=1, imaging="dwell")

    def chain(c):
        src, stages, geo = build_forward_stages(c, proc)
        d = src
        for st in stages:
            d = st.fn(d, **st.params)
        return d, stages[-1].params

    memory, params = chain(cube)
    assert params["focus_oversample"] > 1
    with backing.file_backed(tmp_path, min_bytes=0):
        on_file, _ = chain(_file_backed_cube(cube))
    for name in sorted(memory.vars):
        np.testing.assert_array_equal(np.asarray(on_file[name]), np.asarray(memory[name]), err_msg=name)


def test_the_doppler_zoom_and_the_profile_spectra_out_of_core_hold_blocks(tmp_path, monkeypatch):
    """Out of core with blocks of 4 KB the Doppler stage had built its zoom matrix for every CPI at once
    (pulses x n_doppler, complex128 then complex64: half a channel of 129 range samples) and the dwell
    profile metrics had copied every pulse of the targets' range windows into memory (0.68 of a channel;
    an independent review, both growing with the pulses).  Now each is made block by block of CPIs or
    pulses: their traced peaks stay under a tenth of a channel, and the spectra are the in-memory ones bit
    for bit."""
    import tracemalloc

    from fwdlook_cli.dsp.geometry import C_MPS
    from fwdlook_cli.forward.chain import build_forward_stages
    from fwdlook_cli.forward.evaluate import truth_at_t_ref
    from fwdlook_cli.forward.run_metrics import PROFILE_WINDOW_CELLS, profile_spectra

    monkeypatch.setattr(backing, "BLOCK_BYTES", 4096)
    monkeypatch.setattr(keystone_fast, "SUPERBLOCK_BYTES", 16384)
    scn, cube = _tiny_low_window()
    proc = dict(scn["processing"], method="tracking", q=1, imaging="cpi")

    def spectra(c, trace):
        src, stages, geo = build_forward_stages(c, proc)
        d = src
        for st in stages:
            if st.name == "doppler_spectra":
                break
            d = st.fn(d, **st.params)
        r_true = truth_at_t_ref(c.truth_xyz_m(), np.asarray(geo["p_ref"]))[0]
        window_m = PROFILE_WINDOW_CELLS * C_MPS / (2.0 * c.radar["bandwidth_hz"])
        out = []
        for fn, args in ((st.fn, (d,)), (profile_spectra, (d, geo["doppler_params"], r_true, window_m))):
            if trace:
                tracemalloc.start()
            try:
                z = fn(*args, **(st.params if fn is st.fn else {}))
                peak = tracemalloc.get_traced_memory()[1] if trace else 0
            finally:
                tracemalloc.stop()
            out.append((np.array(z["sum_z"]), peak))
        return out

    memory = spectra(cube, False)
    with backing.file_backed(tmp_path, min_bytes=0):
        channel = cube.sum.nbytes
        on_file = spectra(_file_backed_cube(cube), True)
    for (z_file, peak), (z_memory, _) in zip(on_file, memory):
        assert peak < 0.1 * channel, (peak, channel)
        np.testing.assert_array_equal(z_file, z_memory)


def test_the_doppler_zoom_of_few_range_columns_out_of_core_holds_blocks(tmp_path, monkeypatch):
    """With few range columns (the dwell profile metrics' windows) a block of CPIs sized by its output
    alone had made E's float64 and complex128 temporaries cpi / n_r times that size: 86 MiB traced for
    8 MiB blocks on 65536 pulses x 12 columns (a review of the round's change).  Sized by both: within
    three blocks here, whatever the pulses."""
    import tracemalloc

    from fwdlook_cli.forward.chain import doppler_spectra
    from fwdlook_cli.io.stagefile import StageData

    monkeypatch.setattr(backing, "BLOCK_BYTES", 1 << 20)
    n_p, n_r, prf = 16384, 12, 2500.0
    d = StageData()
    d.add("slow_time_s", np.arange(n_p) / prf, ("slow_time_s",), "s", "t")
    d.add("xyz", np.arange(3), ("xyz",), "1", "x")
    d.add("scan_angle_deg", np.linspace(-15, 15, n_p), ("slow_time_s",), "deg", "beam")
    d.add("position_m", np.zeros((n_p, 3)), ("slow_time_s", "xyz"), "m", "p")
    d.add("velocity_mps", np.tile([0.0, 240.0, 0.0], (n_p, 1)), ("slow_time_s", "xyz"), "m/s", "v")
    d.add("range_m", 1700 + np.arange(n_r) * 2.5, ("range_m",), "m", "r")
    with backing.file_backed(tmp_path, min_bytes=0):
        x = backing.empty((n_p, n_r), np.complex64)
        x[:] = 1
        d.add("sum", x, ("slow_time_s", "range_m"), "1", "sum")
        tracemalloc.start()
        try:
            doppler_spectra(d, cpi=128, n_doppler=128, window="hamming", fc_hz=18e9, beamwidth_deg=6.0,
                            depression_deg=1.7, prf_hz=prf, follow_speed=True)
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
    assert peak < 3 * backing.BLOCK_BYTES, peak
