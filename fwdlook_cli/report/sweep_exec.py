"""Executing a sweep's points: skip the finished ones, record failures, show progress, pick the executor.

* **Finished** points are skipped: a point is finished when its run directory holds ``scenario.yaml``
  (written last by a run) and a ``metrics.json`` whose ``scenario_sha256`` is the hash of the point's
  resolved scenario and whose ``fwdlook_version`` is this one.  Its summary row is rebuilt from that
  file, so a rerun recomputes nothing it finished, and a changed point (other settings, hence another
  hash) is recomputed.
* **A failed point** (its simulation or its processing raised) is recorded in the summary with
  ``status = "failed"`` and its ``error``; the other points go on.  ``run_sweep`` returns every row.
* **Progress** of each point, with an ETA from the mean rate so far, goes to the log (stderr).
* **Executors**: ``workers = 1`` runs in this process; ``workers > 1`` a process pool whose workers are
  limited to one BLAS/OpenMP thread (threadpoolctl) and one ``scipy.fft`` worker each, so N workers
  use N cores, not N x cores; ``scheduler = "tcp://HOST:PORT"`` (any dask.distributed address) runs
  the points on a Dask cluster (``pip install -e .[dask]``): the workers need fwdlook installed and
  the output folder on a file system they share with the client.
"""
from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import time
import traceback
from pathlib import Path

from ..errors import BadInput

log = logging.getLogger(__name__)


# ----------------------------------------------------------------------------------------------
# One thread per worker
# ----------------------------------------------------------------------------------------------
def limit_threads() -> None:
    """Limit this process to one BLAS/OpenMP thread and one scipy.fft worker (a sweep worker)."""
    import scipy.fft
    from threadpoolctl import threadpool_limits

    from ..dsp.blas import fft_workers_at_most

    global _LIMITS
    _LIMITS = threadpool_limits(limits=1)          # applied on creation, kept for the process's life
    scipy.fft.set_workers(1).__enter__()          # the default for calls without workers=
    fft_workers_at_most(1)                        # and workers=-1 (dsp/blas.py)
    os.environ.update({k: "1" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")})


_LIMITS = None
_BUSY = False               # a pool worker is computing a point or a cube (its signals: _pool_worker)


@contextlib.contextmanager
def _busy():
    global _BUSY
    _BUSY = True
    try:
        yield
    finally:
        _BUSY = False


def _pool_worker(parent_pid) -> None:
    """A pool worker's start: it dies with the sweep (``dsp/lifetime.py``: a sweep killed by SIGKILL
    left its idle workers alive for good), on one thread."""
    from ..dsp.lifetime import die_with_parent
    from ..errors import Terminated
    from ..io import signals

    die_with_parent(parent_pid)
    signals.install(Terminated, idle=lambda: not _BUSY)   # SIGTERM, Ctrl-C: its point ended cleanly (no partial
    #                                                       stage file); between points it leaves at once
    limit_threads()


def thread_report() -> dict:
    """(for tests and logs) the FFT workers that workers=-1 gives here and the BLAS thread counts."""
    from threadpoolctl import threadpool_info

    from ..dsp.blas import fft_workers

    return {"pid": os.getpid(), "fft_workers": fft_workers(),
            "blas_threads": [p["num_threads"] for p in threadpool_info() if p.get("user_api") == "blas"]}


# ----------------------------------------------------------------------------------------------
# Finished points
# ----------------------------------------------------------------------------------------------
def finished_metrics(run: dict) -> dict | None:
    """The point's metrics.json when the point is finished (same scenario hash and version), else None."""
    from .. import __version__
    from ..scenario.loader import scenario_hash

    run_dir = Path(run["run_dir"])
    if not (run_dir / "scenario.yaml").exists():
        return None
    try:
        metrics = json.loads((run_dir / "metrics.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(metrics, dict) or "summary" not in metrics or "timing_s" not in metrics:
        return None
    if metrics.get("scenario_sha256") != scenario_hash(run["resolved"]):
        return None
    if metrics.get("fwdlook_version") != __version__:
        return None
    return metrics


# ----------------------------------------------------------------------------------------------
# Tasks (module-level functions: picklable for a process pool and for Dask)
# ----------------------------------------------------------------------------------------------
def _error_text(exc: BaseException) -> str:
    text = str(exc).splitlines()[0] if str(exc) else ""
    return f"{exc.__class__.__name__}: {text}" if text else exc.__class__.__name__


def simulate_task(args):
    """Simulate one cube; returns (path, None) or (path, error text)."""
    from .sweep_plan import _simulate

    try:
        with _busy():
            return _simulate(args), None
    except Exception as exc:  # noqa: BLE001 - recorded in the summary, the sweep goes on
        log.debug("simulation %s failed:\n%s", args[1], traceback.format_exc())
        return args[1], _error_text(exc)


def process_task(run):
    """Process one point; returns (row, None) or (None, error text)."""
    from .sweep_plan import _process

    try:
        with _busy():
            return _process(run), None
    except Exception as exc:  # noqa: BLE001 - recorded in the summary, the sweep goes on
        log.debug("point %s failed:\n%s", run["run_dir"], traceback.format_exc())
        return None, _error_text(exc)


def failed_row(run: dict, error: str) -> dict:
    return {"scenario": run["scenario"], **run["point"], "status": "failed", "error": error,
            "run_dir": run["run_dir"]}


# ----------------------------------------------------------------------------------------------
# Executors: in process, a process pool, a Dask cluster
# ----------------------------------------------------------------------------------------------
class _Serial:
    def map_unordered(self, fn, items):
        for i, item in enumerate(items):
            yield i, fn(item)

    def close(self, abort: bool = False):
        pass


ABORT_GRACE_S = 5.0


class _Pool:
    def __init__(self, workers: int):
        from concurrent.futures import ProcessPoolExecutor

        from ..dsp.lifetime import forking_parent

        self.pool = ProcessPoolExecutor(workers, initializer=_pool_worker, initargs=(forking_parent(),))

    def map_unordered(self, fn, items):
        from concurrent.futures import as_completed

        futures = {self.pool.submit(fn, item): i for i, item in enumerate(items)}
        for fut in as_completed(futures):
            yield futures[fut], fut.result()

    def close(self, abort: bool = False):
        """Wait for the workers; ``abort`` (Ctrl-C, SIGTERM): not for their points: each worker is sent
        SIGTERM, which ends its point as it ends a command (its partial files removed; a rerun resumes
        the point), and killed if it has not left within :data:`ABORT_GRACE_S` (the pool would wait for
        their points at exit)."""
        workers = list((getattr(self.pool, "_processes", None) or {}).values()) if abort else []
        self.pool.shutdown(wait=not abort, cancel_futures=abort)
        for worker in workers:
            with contextlib.suppress(Exception):
                os.kill(worker.pid, signal.SIGTERM)
        deadline = time.monotonic() + ABORT_GRACE_S
        for worker in workers:
            with contextlib.suppress(Exception):
                worker.join(max(0.0, deadline - time.monotonic()))
                if worker.is_alive():
                    worker.kill()


class _Dask:
    def __init__(self, address: str):
        try:
            from distributed import Client
        except ImportError:
            raise BadInput(f"--scheduler {address}: dask.distributed is not installed; "
                           f"install it with pip install -e '.[dask]', or use --scheduler local") from None
        try:
            self.client = Client(address, timeout="5s")
        except (OSError, TimeoutError) as exc:
            raise BadInput(f"--scheduler {address}: no Dask scheduler answers there ({_error_text(exc)}); "
                           f"allowed: local or the address of a running dask scheduler (tcp://HOST:PORT)") from None
        except (ValueError, TypeError) as exc:   # a malformed address (http://x, tcp://, ucx:// without ucx):
            # distributed's own parse errors, which had ended in a traceback (an independent review)
            raise BadInput(f"--scheduler {address}: not a Dask scheduler address ({_error_text(exc)}); "
                           f"allowed: local or the address of a running dask scheduler (tcp://HOST:PORT)") from None
        pids = set(self.client.run(os.getpid).values())
        if pids and os.getpid() not in pids:
            self.client.run(limit_threads)           # worker processes: one thread per task slot
        else:
            log.debug("dask workers share this process: thread limits not applied")
        n = sum(self.client.nthreads().values())
        log.info("dask scheduler %s: %d worker(s), %d thread(s)", address, len(pids), n)

    def map_unordered(self, fn, items):
        from distributed import as_completed

        futures = [self.client.submit(fn, item, pure=False) for item in items]
        index = {f.key: i for i, f in enumerate(futures)}
        for fut in as_completed(futures):
            yield index[fut.key], fut.result()

    def close(self, abort: bool = False):
        self.client.close()


def executor(workers: int, scheduler: str):
    if scheduler in (None, "", "local"):
        from ..dsp.blas import available_cores

        cores = available_cores()
        if workers > cores:           # each worker runs one thread: more than the cores only share them
            log.warning("--workers %d: this process may use %d core(s) (its CPU affinity within its cgroup's "
                        "CPU limit); the workers share them", workers, cores)
        return _Pool(workers) if workers > 1 else _Serial()
    _check_scheduler_form(scheduler)
    return _Dask(scheduler)


def _check_scheduler_form(scheduler: str) -> None:
    """``--scheduler`` local or an address (checked first thing: a finished sweep's rerun, which needs no
    executor, had taken any text with exit 0)."""
    if scheduler not in (None, "", "local") and "://" not in scheduler and ":" not in scheduler:
        raise BadInput(f"--scheduler {scheduler}: not an address; allowed: local or tcp://HOST:PORT "
                       f"(a dask.distributed scheduler)")


# ----------------------------------------------------------------------------------------------
# The sweep
# ----------------------------------------------------------------------------------------------
def _eta(seconds: float) -> str:
    seconds = max(0.0, seconds)
    return f"{seconds:.0f} s" if seconds < 90 else f"{seconds / 60:.1f} min"


def _reusable_cube(path) -> bool:
    """A sweep's cached cube is reused where it is a readable fwdlook raw cube of this fwdlook version;
    else simulated again (a damaged one had failed its points on every rerun, and one of an older
    version had served after an upgrade)."""
    from .. import __version__
    from ..io.outputs import RAW_FORMAT, h5_identity

    if h5_identity(path) != (RAW_FORMAT, "fwdlook"):
        return False
    try:
        import h5py

        with h5py.File(path, "r") as f:
            version = f.attrs.get("software_version")
    except Exception:  # noqa: BLE001  (unreadable: simulated again)
        return False
    return (version.decode() if isinstance(version, bytes) else version) == __version__


def execute(sweep: dict, out: Path, *, workers: int = 1, quiet: bool = False, scheduler: str = "local") -> list[dict]:
    """Every point of ``sweep`` as a summary row, in plan order (see the module docstring); the points'
    folders were checked by the caller (``sweep.run_sweep``: ``sweep_plan.check_point_folders``)."""
    from .sweep_plan import _fmt, _label, plan_runs, row_of

    say = (lambda *a: None) if quiet else log.info
    _check_scheduler_form(scheduler)
    remote = scheduler not in (None, "", "local")
    out = out.resolve() if remote else out            # Dask workers may have another working directory
    runs = plan_runs(sweep, out, source=sweep.get("source"))
    raw_dir = out / "raw"
    raw_dir.mkdir(parents=True, exist_ok=True)
    rows: list[dict | None] = [None] * len(runs)
    todo = []
    for i, run in enumerate(runs):
        run["raw"] = str(raw_dir / f"{run['sim_key'][:16]}.h5")
        run["keep_stages"] = sweep["keep_stages"]
        metrics = finished_metrics(run)
        if metrics is not None:
            rows[i] = dict(row_of(run, metrics), status="ok")
        else:
            todo.append(i)
    if len(todo) < len(runs):
        say(f"{len(runs) - len(todo)} of {len(runs)} points already finished (same scenario hash): skipped")
    if not todo:
        return rows
    sims = {}
    for i in todo:
        sims.setdefault(runs[i]["raw"], runs[i]["resolved"])
    sim_jobs = [(scn, p) for p, scn in sims.items() if not _reusable_cube(p)]
    ex = executor(workers, scheduler)
    sim_errors = {}
    t0 = time.perf_counter()
    try:
        if sim_jobs:
            say(f"simulating {len(sim_jobs)} cube(s)")
        for _, (path, error) in ex.map_unordered(simulate_task, sim_jobs):
            if error:
                sim_errors[path] = error
                log.warning("simulation of %s failed: %s", path, error)
        ready = []
        for i in todo:
            if runs[i]["raw"] in sim_errors:
                rows[i] = failed_row(runs[i], f"simulation failed: {sim_errors[runs[i]['raw']]}")
            else:
                ready.append(i)
        t_proc = time.perf_counter()
        for done, (k, (row, error)) in enumerate(ex.map_unordered(process_task, [runs[i] for i in ready]), 1):
            i = ready[k]
            run = runs[i]
            left = len(ready) - done
            eta = _eta((time.perf_counter() - t_proc) / done * left)
            if error:
                rows[i] = failed_row(run, error)
                log.warning("[%d/%d] %s %s: FAILED: %s; ETA %s", done, len(ready), run["scenario"],
                            _label(run["point"]), error, eta)
            else:
                rows[i] = dict(row, status="ok")
                say(f"[{done}/{len(ready)}] {run['scenario']} {_label(run['point'])}: max |range error| "
                    f"{_fmt(row.get('max_abs_range_error_m'))} m, {row['total_s']:.2f} s; ETA {eta}")
    except BaseException:
        ex.close(abort=True)
        raise
    ex.close()
    n_failed = sum(1 for r in rows if r.get("status") == "failed")
    say(f"sweep: {len(todo) - n_failed} point(s) computed, {len(runs) - len(todo)} reused, {n_failed} failed, "
        f"{time.perf_counter() - t0:.1f} s")
    return rows
