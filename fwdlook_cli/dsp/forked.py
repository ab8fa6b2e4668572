"""Independent jobs of a stage on worker threads, or on forked worker processes where asked for.

A job that is thousands of small numpy calls holds the GIL for much of its time, so threads running
such jobs take turns rather than share the cores; forked processes inherit the job's data without
copying it (copy on write) and send back only the result.  A fork has its own cost: it write-protects
every page of the parent, and afterwards each first write to one of them costs a page fault (about
8 us on this VM), which the parent's later work pays, in this run and the next ones in the same
process.  Measured on the paper cube, rounds interleaved in one process (medians of 8): the dwell
chain with the joint fit's clusters (``forward.dwell_fit``) on forked processes 1.15 s, on threads
1.28 s; the CPI chain run after it 0.60 s after a forked one, 0.51 s after a threaded one.  The joint
fit asks for processes (``processes=True``); threads are the default.
"""
from __future__ import annotations

import multiprocessing
import threading
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor

from .blas import one_blas_thread

_FORKED: dict = {}     # what the forked workers of start_jobs inherit: the function and its jobs
_FORK_LOCK = threading.Lock()


def _run_forked(i):
    return _FORKED["fn"](_FORKED["jobs"][i])


class Pending:
    """Jobs in flight (``start_jobs``): ``result()`` waits for them, returns their results in the jobs'
    order, and releases the workers and the BLAS limit."""

    def __init__(self, futures=None, pool=None, limit=None, done=None):
        self.futures, self.pool, self.limit, self.done = futures, pool, limit, done

    def cancel(self):
        """Drop the jobs not started, wait for the workers to stop, release them (no result)."""
        if self.done is None:
            self.done = []
            try:
                self.pool.shutdown(wait=True, cancel_futures=True)
            finally:
                self.limit.__exit__(None, None, None)

    def result(self):
        if self.done is None:
            try:
                self.done = [f.result() for f in self.futures]
            finally:
                self.pool.shutdown()
                self.limit.__exit__(None, None, None)
        return self.done


def start_jobs(fn, jobs, workers, processes: bool = False):
    """[fn(job) for job in jobs] started, returned as a ``Pending``: the jobs shared among ``workers``
    threads, or with ``processes`` forked processes where the platform forks (they inherit ``fn`` and
    the data it closes over; only the index goes out and the result, pickled, comes back; threads
    where it does not); the caller is free meanwhile.  The BLAS on one thread throughout (the workers
    share the cores).  Module docstring: why threads by default."""
    limit = one_blas_thread()
    limit.__enter__()
    if workers <= 1:
        try:
            return Pending(done=[fn(job) for job in jobs])
        finally:
            limit.__exit__(None, None, None)
    # (a daemonic process, e.g. a dask worker's, may not have children: threads there)
    if (processes and "fork" in multiprocessing.get_all_start_methods()
            and not multiprocessing.current_process().daemon):
        pool = None
        with _FORK_LOCK:                # every worker is forked at the first submit (the fork context
            _FORKED.update(fn=fn, jobs=jobs)   # forks them all before its manager thread starts)
            try:
                pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("fork"))
                return Pending([pool.submit(_run_forked, i) for i in range(len(jobs))], pool, limit)
            except OSError:             # the system refused a process (memory, a process limit): threads
                if pool is not None:
                    pool.shutdown(wait=False, cancel_futures=True)
            finally:
                _FORKED.clear()
    pool = ThreadPoolExecutor(max_workers=workers)
    return Pending([pool.submit(fn, job) for job in jobs], pool, limit)


def map_jobs(fn, jobs, workers, processes: bool = False):
    """[fn(job) for job in jobs] on ``workers`` (``start_jobs``), waited for."""
    return start_jobs(fn, jobs, workers, processes).result()
