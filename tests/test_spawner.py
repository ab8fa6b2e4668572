"""dsp.spawner: the joint fit's workers forked by a small process forked before the chain's data
exist, not by the process that runs the chain (its own faults and forks: docs/SPEED_HISTORY.md)."""
import os
import select
import signal
import time

import numpy as np
import pytest

pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="no fork on this platform")

from fwdlook_cli.dsp import forked, spawner  # noqa: E402
from fwdlook_cli.dsp.forked import map_jobs, start_jobs  # noqa: E402


def _svd_job(job):
    """A picklable job (a module function, its data in the job): the singular values, the worker's parent."""
    k, x = job
    return k, np.linalg.svd(x, compute_uv=False), os.getppid()


def _busy(job):
    """About 0.1 s of CPU in the worker."""
    t0 = time.process_time()
    while time.process_time() - t0 < 0.1:
        pass
    return job


def _sleepy(job):
    time.sleep(30.0)
    return job


def _dies(job):
    if job == 1:
        os._exit(3)
    return job


def _fails(job):
    raise ValueError(f"job {job}")


def _jobs():
    rng = np.random.default_rng(7)
    return [(k, rng.standard_normal((30, 20)) + 1j * rng.standard_normal((30, 20))) for k in range(5)]


def _refuse_direct_forks(monkeypatch):
    def refused(*args, **kwargs):
        raise AssertionError("the caller forked a worker itself")

    monkeypatch.setattr(forked, "_fork", refused)


def _state(pid: int) -> str:
    """A process's state letter from /proc (Z: ended, not reaped; '' where there is none)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0]
    except FileNotFoundError:
        return ""


def test_spawned_workers_compute_what_one_process_computes(monkeypatch):
    """With a spawner the caller forks nothing: the workers are the spawner's children, and they return
    what the jobs return in this process, in the jobs' order; an exception of a job, or a worker that
    dies, reaches the caller as with direct forks."""
    sp = spawner.start()
    assert sp is not None and spawner.start() is sp              # one per process
    _refuse_direct_forks(monkeypatch)
    jobs = _jobs()
    serial = [_svd_job(j) for j in jobs]
    spawned = map_jobs(_svd_job, jobs, 3, processes=True)
    assert [k for k, _, _ in spawned] == list(range(5))
    assert all(np.array_equal(a[1], b[1]) for a, b in zip(serial, spawned))
    assert {ppid for _, _, ppid in spawned} <= {sp.pid} and sp.pid != os.getpid()
    with pytest.raises(ValueError, match="job 0"):
        map_jobs(_fails, [0, 1], 2, processes=True)
    with pytest.raises(RuntimeError, match="without a result"):
        map_jobs(_dies, [0, 1, 2], 3, processes=True)
    assert map_jobs(_svd_job, jobs, 2, processes=True)[4][0] == 4      # the spawner still serves


def test_the_spawned_workers_cpu_is_counted_for_the_caller():
    """The spawner's workers are not the caller's children (``RUSAGE_CHILDREN`` misses them): their
    own CPU time, reported with their results, is what ``worker_cpu_split_s`` adds (the bench's chain
    CPU, ``benchtools.process_cpu_split_s``); workers the caller forked itself are not counted twice."""
    import resource

    from fwdlook_cli.report.benchtools import process_cpu_split_s

    def children_cpu():
        ru = resource.getrusage(resource.RUSAGE_CHILDREN)
        return ru.ru_utime + ru.ru_stime

    before, children = spawner.worker_cpu_split_s(), children_cpu()
    assert map_jobs(_busy, [0, 1], 2, processes=True) == [0, 1]               # forked by the caller
    assert spawner.worker_cpu_split_s() == before and children_cpu() - children >= 0.15
    spawner.start()
    children, total0 = children_cpu(), sum(process_cpu_split_s())
    assert map_jobs(_busy, [0, 1], 2, processes=True) == [0, 1]               # forked by the spawner
    after = spawner.worker_cpu_split_s()
    assert 0.2 <= (after[0] + after[1]) - (before[0] + before[1]) < 1.0       # two jobs of 0.1 s each
    assert children_cpu() == children           # (until the spawner itself is reaped: then counted there)
    assert sum(process_cpu_split_s()) - total0 >= 0.2


def test_jobs_that_do_not_pickle_are_forked_by_the_caller():
    """A closure does not pickle: its jobs are forked by the caller as before, with the same results."""
    spawner.start()
    data = _jobs()

    def closure(k):
        return np.linalg.svd(data[k][1], compute_uv=False), os.getppid()

    out = map_jobs(closure, list(range(5)), 2, processes=True)
    assert all(ppid == os.getpid() for _, ppid in out)
    assert all(np.array_equal(s, np.linalg.svd(x, compute_uv=False)) for (s, _), (_, x) in zip(out, data))


def test_a_spawner_gone_leaves_the_jobs_to_direct_forks():
    """A spawner killed meanwhile: the next batch is forked by the caller, same results; none is left."""
    sp = spawner.start()
    os.kill(sp.pid, signal.SIGKILL)
    os.waitpid(sp.pid, 0)
    jobs = _jobs()
    out = map_jobs(_svd_job, jobs, 2, processes=True)
    assert [k for k, _, _ in out] == list(range(5)) and all(ppid == os.getpid() for _, _, ppid in out)
    assert spawner.current() is None


def test_a_spawner_that_does_not_answer_is_killed_and_the_jobs_run_here(monkeypatch):
    """A spawner stuck in a fork (a library's fork handler that loses a wake-up: scipy's pocketfft pool,
    once in the test suite) had hung its caller for good: after ANSWER_TIMEOUT_S the caller kills it,
    computes the jobs itself (same results) and forks the next batch directly."""
    monkeypatch.setattr(spawner, "ANSWER_TIMEOUT_S", 0.5)
    sp = spawner.start()
    os.kill(sp.pid, signal.SIGSTOP)                      # as stuck: it reads nothing and answers nothing
    jobs = _jobs()
    t0 = time.monotonic()
    out = map_jobs(_svd_job, jobs, 2, processes=True)
    assert time.monotonic() - t0 < 10.0
    assert [k for k, _, _ in out] == list(range(5)) and all(ppid == os.getppid() for _, _, ppid in out)  # here
    assert spawner.current() is None and _state(sp.pid) in ("", "Z")
    serial = [_svd_job(j) for j in jobs]
    assert all(np.array_equal(a[1], b[1]) for a, b in zip(serial, out))


def test_cancel_ends_the_spawned_workers():
    """cancel() (the caller failed meanwhile) kills the spawner's workers at once: no job runs on."""
    spawner.start()
    pending = start_jobs(_sleepy, list(range(4)), 2, processes=True)
    pids = [pid for pid, _ in pending._workers()]
    assert len(pids) == 2
    t0 = time.perf_counter()
    pending.cancel()
    pending.cancel()
    while any(_state(pid) not in ("", "Z") for pid in pids) and time.perf_counter() - t0 < 10.0:
        time.sleep(0.01)
    assert all(_state(pid) in ("", "Z") for pid in pids) and time.perf_counter() - t0 < 10.0


def test_the_spawner_holds_none_of_its_parents_pipes(tmp_path):
    """The spawner closes every pipe and socket it inherited but its own socket: a pipe of the
    caller's (the painter's, a batch's) ends when the caller closes it, whatever the spawner does.
    Files stay open (a log file its workers may write)."""
    r, w = os.pipe()
    log = open(tmp_path / "log.txt", "w")
    try:
        sp = spawner.start()
        os.close(w)
        w = None
        ready, _, _ = select.select([r], [], [], 10.0)
        assert ready and os.read(r, 1) == b""             # the end of the pipe: no copy of w left open
        def targets():
            return [os.readlink(f"/proc/{sp.pid}/fd/{fd}") for fd in os.listdir(f"/proc/{sp.pid}/fd") if int(fd) > 2]

        t0 = time.perf_counter()                       # (it may still be closing the others)
        while any(t.startswith("pipe:") for t in targets()) and time.perf_counter() - t0 < 10.0:
            time.sleep(0.01)
        targets = targets()
        assert str(tmp_path / "log.txt") in targets
        assert sum(t.startswith("socket:") for t in targets) == 1               # its own
        assert not [t for t in targets if t.startswith("pipe:")]
    finally:
        log.close()
        os.close(r)
        if w is not None:
            os.close(w)


def test_the_spawner_ends_with_the_process_that_forked_it():
    """Its parent killed (no stop, no exit handler): the spawner sees its socket close and leaves."""
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:                                  # a process that starts a spawner and is killed
        try:
            os.close(r)
            sp = spawner.start()
            os.write(w, str(sp.pid).encode())
            time.sleep(60)
        finally:
            os._exit(0)
    os.close(w)
    child_spawner = int(os.read(r, 64))
    os.close(r)
    os.kill(pid, signal.SIGKILL)
    os.waitpid(pid, 0)
    t0 = time.perf_counter()
    while _state(child_spawner) not in ("", "Z") and time.perf_counter() - t0 < 10.0:
        time.sleep(0.01)
    assert _state(child_spawner) in ("", "Z")


def test_no_spawner_where_asked_for_none_or_where_the_fit_forks_nothing(monkeypatch):
    """FWDLOOK_SPAWNER=0: none (the workers forked by the caller, as before); nor for a process whose
    fit runs its clusters itself (one worker thread: a sweep's workers), nor for settings without the
    joint fit."""
    import fwdlook_cli.forward.process as process

    start_fit_spawner = process.start_fit_spawner
    fit = {"imaging": "dwell", "dwell_fit": "joint"}
    monkeypatch.setenv("FWDLOOK_SPAWNER", "0")
    assert spawner.start() is None and spawner.current() is None
    monkeypatch.delenv("FWDLOOK_SPAWNER")
    monkeypatch.setattr(process, "worker_threads", lambda: 1)
    start_fit_spawner(fit)
    assert spawner.current() is None
    monkeypatch.setattr(process, "worker_threads", lambda: 2)
    for proc in ({"imaging": "cpi", "dwell_fit": "joint"}, {"imaging": "dwell", "dwell_fit": "none"}):
        start_fit_spawner(proc)
        assert spawner.current() is None
    start_fit_spawner(fit)
    assert spawner.current() is not None


def test_the_dwell_chain_is_the_same_with_its_fit_on_the_spawner(tmp_path, monkeypatch):
    """process_cube with the joint fit (the paper lattice: three clusters) starts the spawner, which
    forks the fit's workers, and its image and metrics are those of the workers forked by the caller
    (``FWDLOOK_SPAWNER=0``), to the bit."""
    import h5py

    from fwdlook_cli.forward.process import process_cube
    from fwdlook_cli.forward.simulate import simulate_scenario
    from fwdlook_cli.scenario.loader import load_scenario
    from pathlib import Path

    import fwdlook_cli.forward.dwell_fit as F
    import fwdlook_cli.forward.process as process

    for module in (F, process):                 # two workers, as on two cores (whatever this machine has)
        monkeypatch.setattr(module, "worker_threads", lambda: 2)
    scn = load_scenario(Path(__file__).resolve().parents[1] / "scenarios" / "paper_fig6_a50.yaml")
    scn["processing"].update(method="tracking", imaging="dwell", dwell_fit="joint", curvature_model="beam")
    cube, _ = simulate_scenario(scn)
    out = {}
    for mode in ("0", "1"):
        monkeypatch.setenv("FWDLOOK_SPAWNER", mode)
        spawner.stop()
        if mode == "1":
            _refuse_direct_forks(monkeypatch)
        out[mode] = process_cube(cube, scn, tmp_path / mode, force=True, quiet=True, png=False,
                                 keep_stages="none")
        assert (spawner.current() is not None) == (mode == "1")
        with h5py.File(tmp_path / mode / "image.h5") as f:
            out[mode + "image"] = f["image"][()]
    assert out["0"]["targets"] == out["1"]["targets"]
    assert np.array_equal(out["0image"], out["1image"]) and out["0image"].any()


def test_stop_does_not_wait_on_a_spawner_that_does_not_leave():
    """A spawner that does not leave when its socket closes (stopped here by SIGSTOP) is killed after
    the grace period: the command's exit never hangs on it."""
    sp = spawner.start()
    os.kill(sp.pid, signal.SIGSTOP)
    t0 = time.perf_counter()
    spawner.stop()
    assert time.perf_counter() - t0 < 10.0 and _state(sp.pid) in ("", "Z")
    with pytest.raises(ChildProcessError):
        os.waitpid(sp.pid, os.WNOHANG)                # reaped


_BLAS_SCRIPT = r"""
import os
import numpy  # noqa: F401 (its BLAS loaded, with the two threads of the environment)
from threadpoolctl import threadpool_info
from fwdlook_cli.dsp import forked, spawner


def blas_threads(job):
    return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]


assert spawner.start() is not None       # forked here, under no BLAS limit (the user's two threads)
spawned = forked.map_jobs(blas_threads, [0, 1], 2, processes=True)
spawner.stop()
os.environ["FWDLOOK_SPAWNER"] = "0"      # and forked by this process itself
direct = forked.map_jobs(blas_threads, [0, 1], 2, processes=True)
print("caller", blas_threads(0), "spawned", spawned, "direct", direct)
"""


def test_the_workers_run_the_blas_on_one_thread_whatever_the_user_set():
    """The fit's workers belong to the chain, which runs the BLAS on one thread (dsp/blas.py): with
    ``OPENBLAS_NUM_THREADS=2`` a spawner forked before the chain's limit gave its workers two BLAS
    threads each, and the paper cube's dwell image took 1.0-3.4 s instead of 0.25-0.37 s (three workers
    on two cores, each idle BLAS thread spinning 0.1 s).  The caller keeps the user's setting."""
    import subprocess
    import sys

    env = dict(os.environ, OPENBLAS_NUM_THREADS="2")
    env.pop("FWDLOOK_SPAWNER", None)
    res = subprocess.run([sys.executable, "-c", _BLAS_SCRIPT], env=env, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "caller [2] spawned [[1], [1]] direct [[1], [1]]", res.stdout
