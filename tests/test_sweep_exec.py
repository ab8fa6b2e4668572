"""Sweeps that behave (issue 13, items 5 and 6): a rerun recomputes nothing it finished, one failing
point is recorded and the others complete, pool workers run one FFT/BLAS thread each, and the same
sweep on a loopback dask.distributed LocalCluster gives the local pool's summary."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from fwdlook_cli.report.sweep import SUMMARY_KEYS
from cli_runner import run_cli

ROOT = Path(__file__).resolve().parents[1]
TINY = str(ROOT / "scenarios" / "tiny.yaml")


def sweep_file(tmp_path, methods=("tracking", "beam"), name="t", t_refs=("start", "centre")):
    spec = {"name": name, "scenarios": [TINY], "set": ["noise.snr_db=null"],
            "grid": {"processing.method": list(methods), "processing.t_ref": list(t_refs)}}
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(spec))
    return path


def rows_of(out_dir):
    return json.loads((Path(out_dir) / "summary.json").read_text())["rows"]


@pytest.fixture
def count_processing(monkeypatch):
    """Count (and optionally fail) calls of the forward chain made by an in-process sweep."""
    import fwdlook_cli.forward.process as process

    calls, real = [], process.process_cube

    def counted(cube, scn, run_dir, **kw):
        calls.append(str(run_dir))
        if scn["processing"]["method"] == counted.fail_method and scn["processing"]["t_ref"] == "centre":
            raise RuntimeError("injected fault in stage keystone")
        return real(cube, scn, run_dir, **kw)

    counted.fail_method = None
    monkeypatch.setattr(process, "process_cube", counted)
    return counted, calls


def test_rerun_recomputes_nothing_it_finished(tmp_path, capsys, count_processing):
    counted, calls = count_processing
    path, out = sweep_file(tmp_path, t_refs=("centre",)), tmp_path / "out"
    code, _, err = run_cli(["sweep", path, "-o", out], capsys)
    assert code == 0 and len(calls) == 2
    assert "ETA" in err                                     # progress with an ETA on stderr
    first = rows_of(out)
    mtimes = {p: p.stat().st_mtime_ns for p in out.glob("*/*/metrics.json")}
    assert len(mtimes) == 2
    code, _, err = run_cli(["sweep", path, "-o", out], capsys)
    assert code == 0 and len(calls) == 2                    # nothing recomputed
    assert "2 of 2 points already finished" in err
    assert rows_of(out) == first                            # the same summary, rebuilt from metrics.json
    assert {p: p.stat().st_mtime_ns for p in out.glob("*/*/metrics.json")} == mtimes
    # a point whose recorded scenario hash no longer matches is not finished: only it is recomputed
    victim = sorted(mtimes)[0]
    m = json.loads(victim.read_text())
    m["scenario_sha256"] = "0" * 64
    victim.write_text(json.dumps(m))
    code, _, _ = run_cli(["sweep", path, "-o", out], capsys)
    assert code == 0 and calls[2:] == [str(victim.parent)]
    # a grid extended by one method computes only the new point
    code, _, _ = run_cli(["sweep", sweep_file(tmp_path, ("tracking", "beam", "bulk"), t_refs=("centre",)), "-o", out],
                         capsys)
    assert code == 0 and len(calls) == 4 and "method=bulk" in calls[3]


def test_one_failed_point_is_recorded_and_the_others_complete(tmp_path, capsys, count_processing):
    counted, calls = count_processing
    counted.fail_method = "beam"
    path, out = sweep_file(tmp_path), tmp_path / "out"
    code, stdout, err = run_cli(["sweep", path, "-o", out], capsys)
    assert code == 1 and len(calls) == 4                    # every point was tried
    assert "1 of 4 points failed" in err
    rows = rows_of(out)
    failed = [r for r in rows if r["status"] == "failed"]
    assert len(failed) == 1
    assert failed[0]["processing.method"] == "beam" and failed[0]["processing.t_ref"] == "centre"
    assert failed[0]["error"] == "RuntimeError: injected fault in stage keystone"
    ok = [r for r in rows if r["status"] == "ok"]
    assert len(ok) == 3 and all(r["detected"] == r["n_targets"] == 3 for r in ok)
    assert all(r["max_abs_range_error_m"] < 1.0 for r in ok)   # a third of the tiny scene's 3 m cell
    md = (out / "summary.md").read_text()
    assert "FAILED" in md and "injected fault in stage keystone" in md
    assert (out / "stability.png").stat().st_size > 1000       # drawn from the points that finished
    # fixed, the rerun computes the failed point only
    counted.fail_method = None
    code, _, _ = run_cli(["sweep", path, "-o", out], capsys)
    assert code == 0 and len(calls) == 5 and "method=beam,t_ref=centre" in calls[-1]
    assert all(r["status"] == "ok" for r in rows_of(out))


def test_pool_workers_run_one_fft_and_blas_thread():
    from concurrent.futures import ProcessPoolExecutor

    from fwdlook_cli.report.sweep_exec import limit_threads, thread_report

    with ProcessPoolExecutor(2, initializer=limit_threads) as pool:
        reports = list(pool.map(thread_report_after, range(2)))
    for r in reports:
        assert r["fft_workers"] == 1
        assert all(n == 1 for n in r["blas_threads"])
    import os

    assert thread_report()["pid"] == os.getpid()             # this process is left alone


def test_more_workers_than_usable_cores_are_told(monkeypatch, caplog):
    """A sweep asked for more worker processes than the cores it may use (a CPU limit, a CPU set) says
    so once; as many as the cores, nothing."""
    import logging

    from fwdlook_cli.dsp import blas
    from fwdlook_cli.report import sweep_exec

    monkeypatch.setattr(blas, "available_cores", lambda: 2)
    with caplog.at_level(logging.WARNING, logger=sweep_exec.log.name):
        sweep_exec.executor(2, "local").close()
        assert not [r for r in caplog.records if "--workers" in r.getMessage()]
        sweep_exec.executor(3, "local").close()
    told = [r.getMessage() for r in caplog.records if "--workers" in r.getMessage()]
    assert told == ["--workers 3: this process may use 2 core(s) (its CPU affinity within its cgroup's CPU limit); "
                    "the workers share them"]


def thread_report_after(_):
    from fwdlook_cli.report.sweep_exec import thread_report

    return thread_report()


def _comparable(rows):
    return [{k: r.get(k) for k in ("scenario", "processing.method", "processing.t_ref", "status", *SUMMARY_KEYS)}
            for r in rows]


def test_sweep_on_a_loopback_dask_cluster_equals_the_local_pool(tmp_path, capsys):
    distributed = pytest.importorskip("distributed")
    path = sweep_file(tmp_path, ("decimation",))
    code, _, _ = run_cli(["sweep", path, "-o", tmp_path / "pool", "--workers", "2", "-q"], capsys)
    assert code == 0
    # one worker process (two task threads) on loopback: the sweep limits it to one FFT/BLAS thread, as
    # it does the pool's workers, so both compute in the same order and agree exactly
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=True, protocol="tcp",
                                  host="127.0.0.1", dashboard_address=None) as cluster:
        address = cluster.scheduler_address
        assert address.startswith("tcp://127.0.0.1:")
        code, _, err = run_cli(["sweep", path, "-o", tmp_path / "dask", "--scheduler", address], capsys)
    assert code == 0, err
    assert "dask scheduler" in err
    pool, dask = rows_of(tmp_path / "pool"), rows_of(tmp_path / "dask")
    assert len(pool) == 2 and all(r["status"] == "ok" for r in pool)
    a, b = _comparable(pool), _comparable(dask)
    assert a == b
    assert all(Path(r["run_dir"]).is_absolute() and (Path(r["run_dir"]) / "metrics.json").exists() for r in dask)


def test_scheduler_that_does_not_answer_is_bad_input(tmp_path, capsys):
    pytest.importorskip("distributed")
    code, _, err = run_cli(["sweep", sweep_file(tmp_path), "-o", tmp_path / "x", "--scheduler",
                            "tcp://127.0.0.1:9"], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "--scheduler tcp://127.0.0.1:9" in err


def test_a_scheduler_that_is_not_an_address_is_refused_on_a_finished_sweep_too(tmp_path, capsys):
    """A rerun of a finished sweep needs no executor, and it had taken `--scheduler bogus` with exit 0
    (an independent review): the address's form is checked first thing, as on a fresh folder."""
    path = sweep_file(tmp_path, methods=("beam",), t_refs=("centre",))
    code, _, err = run_cli(["sweep", path, "-o", tmp_path / "s", "-q"], capsys)
    assert code == 0, err
    for out in (tmp_path / "s", tmp_path / "fresh"):
        code, _, err = run_cli(["sweep", path, "-o", out, "--scheduler", "bogus"], capsys)
        assert code == 2 and len(err.strip().splitlines()) == 1 and "--scheduler bogus: not an address" in err


@pytest.mark.parametrize("address", ["http://x", "tcp://", "inproc://x", "tcp://[::1"])
def test_a_malformed_scheduler_address_is_one_line(tmp_path, capsys, address):
    """distributed's own parse errors of an address (unknown scheme, no port, an unclosed bracket) had
    ended in a traceback with exit 1 (an independent review): one line, exit 2, nothing written."""
    pytest.importorskip("distributed")
    code, _, err = run_cli(["sweep", sweep_file(tmp_path), "-o", tmp_path / "x", "--scheduler", address], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and f"--scheduler {address}" in err, err
    assert "Traceback" not in err and not (tmp_path / "x" / "summary.json").exists()


def test_a_corrupt_cube_fails_its_points_through_the_pool_and_spares_the_others(tmp_path, capsys):
    """A real fault through the process pool: one scenario's shared cube holds a NaN on disk before the
    sweep (a damaged recording; a truncated or unreadable one is simulated again since the fifty-second
    round), so its points fail with the reader's one-line error, while the other scenario's points
    complete in the other worker."""
    from fwdlook_cli.report.sweep_plan import load_sweep, plan_runs

    other = tmp_path / "tiny_seed2.yaml"
    other.write_text(Path(TINY).read_text().replace("name: tiny", "name: tiny_seed2"))
    spec = {"name": "c", "scenarios": [TINY, str(other)], "set": ["noise.seed=2"],
            "grid": {"processing.method": ["tracking", "beam"]}}
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(spec))
    out = tmp_path / "out"
    victim = next(r for r in plan_runs(load_sweep(str(path)), out) if r["scenario"] == "tiny_seed2")
    raw = out / "raw" / f"{victim['sim_key'][:16]}.h5"
    raw.parent.mkdir(parents=True)
    import h5py

    from fwdlook_cli.forward.simulate import simulate_scenario
    from fwdlook_cli.io.raw import write_raw

    write_raw(raw, simulate_scenario(victim["resolved"])[0])       # this version's cube, then damaged
    with h5py.File(raw, "a") as f:
        f["echo/sum"][3, 5] = complex(np.nan, 0.0)
    code, _, err = run_cli(["sweep", path, "-o", out, "--workers", "2"], capsys)
    assert code == 1 and "2 of 4 points failed" in err
    rows = rows_of(out)
    assert [r["status"] for r in rows] == ["ok", "ok", "failed", "failed"]
    assert all(r["scenario"] == "tiny_seed2" and r["error"].startswith("BadInput: ") and str(raw) in r["error"]
               for r in rows[2:])
    assert all(r["detected"] == 3 for r in rows[:2])


def test_pool_workers_die_with_a_killed_sweep_and_leave_its_folder_unlocked(tmp_path):
    """SIGKILL (or the OOM killer) runs no handler in the sweep: its pool workers, idle between points,
    lived on holding the folder's lock (an inherited descriptor of the same open file), and every rerun
    was refused as "in use by another fwdlook command" until they were killed by hand."""
    import os
    import signal
    import subprocess
    import sys
    import textwrap
    import time

    from fwdlook_cli.io.outputs import folder_lock

    script = textwrap.dedent(f"""
        import os, signal, time
        from fwdlook_cli.io.outputs import folder_lock
        from fwdlook_cli.report.sweep_exec import _Pool
        with folder_lock({str(tmp_path)!r}, "sweep folder"):
            pool = _Pool(2)
            pool.pool.submit(time.sleep, 0.2).result()
            print(*pool.pool._processes, flush=True)
            os.kill(os.getpid(), signal.SIGKILL)
    """)
    out = tmp_path / "pids.txt"            # (a pipe would be held open by workers that outlive it)
    with open(out, "w") as fh:
        res = subprocess.run([sys.executable, "-c", script], stdout=fh, stderr=subprocess.PIPE, text=True,
                             timeout=120)
    assert res.returncode == -signal.SIGKILL, res.stderr
    pids = [int(p) for p in out.read_text().split()]
    assert len(pids) == 2

    def gone(pid):
        try:
            with open(f"/proc/{pid}/stat") as f:
                return f.read().rsplit(")", 1)[1].split()[0] in ("Z", "X")
        except FileNotFoundError:
            return True

    deadline = time.monotonic() + 10.0
    while not all(gone(p) for p in pids) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert all(gone(p) for p in pids)
    with folder_lock(tmp_path, "sweep folder"):          # free: no descriptor of it is left open
        assert os.path.exists(tmp_path / ".fwdlook.lock")


def test_a_sweep_stopped_by_sigterm_ends_its_workers_points_cleanly(tmp_path):
    """SIGTERM to a two-worker sweep mid-point: each worker ends its point as a command does (its partial
    stage file removed; it had been killed mid-write, leaving `NN_stage.h5.partial`), the sweep exits 143
    in one line, and no worker is left."""
    import glob
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "sw"
    root = Path(__file__).resolve().parents[1]
    proc = subprocess.Popen([sys.executable, "-c", "from fwdlook_cli.cli import main; main()", "sweep",
                             str(root / "configs" / "sweeps" / "tour.yaml"), "--workers", "2", "-o", str(out), "-q"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True)
    deadline = time.monotonic() + 120.0
    while not glob.glob(str(out / "*" / "*" / "stages" / "*")) and proc.poll() is None \
            and time.monotonic() < deadline:
        time.sleep(0.002)
    assert proc.poll() is None, "finished before a point had begun"
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signal.SIGTERM, err
    # (-q keeps warnings: a `decimation` point says what its plan budget misses before the last line)
    lines = [line for line in err.strip().splitlines() if not line.startswith("processing.method ")]
    assert lines == ["fwdlook: terminated (SIGTERM)"]
    assert not list(out.rglob("*.partial")), list(out.rglob("*.partial"))
    time.sleep(0.5)
    left = subprocess.run(["pgrep", "-s", str(proc.pid)], capture_output=True, text=True).stdout.split()
    assert left == [], left                               # nothing of its session still running
