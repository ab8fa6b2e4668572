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

The processes are plain ``os.fork`` children, not a ``ProcessPoolExecutor``: the executor's start
(its manager thread, queues and one ``multiprocessing.Process`` per worker) and its shutdown cost the
stage's main thread about 40 and 30 ms per dwell run on the paper cube (cProfile), where three forks
cost about 3 ms each.  The jobs' indices wait in a pipe, 4 bytes each, written before the forks (at most
``MAX_FORKED_JOBS``, which any pipe's buffer holds; more jobs go to threads); every
child takes the next one (a read of 4 bytes from a pipe is atomic), so a free child takes the next
job as a pool's worker would, and sends back its results, pickled, on a pipe of its own when the
queue is empty; it leaves by ``os._exit`` (no handler or buffer of the parent runs in it).  Where this
process has a spawner (``dsp.spawner``, started for the dwell image's joint fit) and the jobs pickle,
the spawner forks the workers instead, from its own small heap, with the same pipes.
"""
from __future__ import annotations

import multiprocessing
import os
import pickle
import signal
import struct
from concurrent.futures import ThreadPoolExecutor

from . import spawner
from .blas import one_blas_thread

_fork = os.fork if hasattr(os, "fork") else None     # (a hook: the tests refuse it)
MAX_FORKED_JOBS = 1024          # their indices (4 KiB) fit any pipe's buffer (a page at least): written before the forks


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


def _close_workers(children, kill: bool):
    """Close the result pipes of ``children`` [(pid, fd)], the workers killed first where ``kill``."""
    for pid, fd in children:
        if kill:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        try:
            os.close(fd)
        except OSError:
            pass


def _read_all(fd: int) -> bytes:
    parts = []
    while True:
        chunk = os.read(fd, 1 << 20)
        if not chunk:
            return b"".join(parts)
        parts.append(chunk)


class ForkedPending:
    """Jobs on forked children (``start_jobs(processes=True)``): ``result()`` reads every child's
    results, reaps the children and returns the results in the jobs' order (a child's exception is
    raised here, after every child is reaped); ``cancel()`` kills and reaps them."""

    def __init__(self, children, n_jobs: int, limit):
        self.children, self.n_jobs, self.limit, self.done = children, n_jobs, limit, None

    def _reap(self, kill: bool):
        _close_workers(self.children, kill)
        statuses = []
        for pid, _ in self.children:
            try:
                statuses.append(os.waitpid(pid, 0)[1])
            except ChildProcessError:
                statuses.append(0)
        self.children = []
        return statuses

    def _count_cpu(self, user_s: float, system_s: float):
        """A worker's own CPU time, as it reported it: counted by the kernel once the child is reaped
        (``RUSAGE_CHILDREN``), so nothing to do here."""

    def cancel(self):
        """Kill the children (the jobs not finished are dropped), reap them, release the BLAS limit."""
        if self.done is None:
            self.done = []
            try:
                self._reap(kill=True)
            finally:
                self.limit.__exit__(None, None, None)

    def result(self):
        if self.done is None:
            try:
                payloads = [_read_all(fd) for _, fd in self.children]
            except BaseException:          # an interrupt while waiting: the children killed, not waited for
                self.cancel()
                raise
            try:
                statuses = self._reap(kill=False)
            finally:
                self.limit.__exit__(None, None, None)
            out, errors = [None] * self.n_jobs, []
            seen = 0
            for payload, status in zip(payloads, statuses):
                if not payload:
                    errors.append((self.n_jobs, RuntimeError(f"a forked worker ended without a result "
                                                             f"(wait status {status})")))
                    continue
                ok, value, *cpu = pickle.loads(payload)
                if ok and cpu:
                    self._count_cpu(*cpu)
                if not ok:
                    errors.append(value)      # (job index, exception)
                    continue
                for i, res in value:
                    out[i] = res
                    seen += 1
            # the first failed job's exception, whichever worker ran it (as the threads' result() raises)
            error = min(errors, key=lambda e: e[0])[1] if errors else None
            if error is None and seen != self.n_jobs:
                error = RuntimeError(f"forked workers returned {seen} of {self.n_jobs} results")
            self.done = []
            if error is not None:
                raise error
            self.done = out
        return self.done


class SpawnedPending(ForkedPending):
    """Jobs on the spawner's workers (``dsp.spawner``): read as ``ForkedPending``'s once the spawner has
    said which workers it forked (``pids()``; none: the jobs run here, in the caller's thread).  The
    workers are the spawner's children, which it reaps (their wait statuses are not seen here), so
    ``cancel()`` kills them by id (the spawner reaps them only when its next batch comes: the ids
    stay theirs until then)."""

    def __init__(self, pipes, n_jobs: int, limit, pids, fn, jobs):
        super().__init__(None, n_jobs, limit)
        self.pipes, self.pids, self.fn, self.jobs = pipes, pids, fn, jobs

    def _workers(self):
        """The forked workers with their result pipes; the pipes of workers not forked closed."""
        if self.children is None:
            try:
                pids = self.pids()
            except OSError:                    # the spawner is gone (or stuck, and killed): its workers
                spawner.stop()                 # cannot be named; the jobs run here, the next batch forks
                pids = []
            self.children = list(zip(pids, self.pipes))
            for fd in self.pipes[len(pids):]:
                os.close(fd)
        return self.children

    def _count_cpu(self, user_s: float, system_s: float):
        """The spawner's workers are not this process's children: their CPU time, which the kernel does
        not count among this process's children's, is added to ``spawner.worker_cpu_split_s()``."""
        spawner.count_worker_cpu(user_s, system_s)

    def _reap(self, kill: bool):
        _close_workers(self._workers(), kill)
        statuses = [0] * len(self.children)
        self.children = []
        return statuses

    def result(self):
        if self.done is None and not self._workers():      # the spawner forked none: the jobs here
            try:
                self.done = [self.fn(job) for job in self.jobs]
            finally:
                self.limit.__exit__(None, None, None)
        return super().result()


def _start_spawned(fn, jobs, workers: int, limit):
    """The jobs on ``workers`` children of the spawner (``dsp.spawner``), or None where there is no
    spawner, the jobs do not pickle or the spawner is gone (the caller then forks them itself)."""
    sp = spawner.current()
    if sp is None:
        return None
    payload = spawner.payload_of(fn, jobs)
    if payload is None:
        return None
    with spawner.FORK_LOCK:      # (a direct fork meanwhile would inherit the result pipes' write ends)
        task_r, task_w = os.pipe()
        pipes = [os.pipe() for _ in range(workers)]
        pids = None
        try:
            os.write(task_w, struct.pack(f"<{len(jobs)}i", *range(len(jobs))))
            os.close(task_w)
            task_w = None
            try:
                pids = sp.spawn(payload, [task_r] + [w for _, w in pipes], workers)
            except OSError:
                spawner.stop()
        finally:
            for fd in [task_r, task_w] + [w for _, w in pipes]:
                if fd is not None:
                    os.close(fd)
            if pids is None:
                for r, _ in pipes:
                    os.close(r)
    if pids is None:
        return None
    return SpawnedPending([r for r, _ in pipes], len(jobs), limit, pids, fn, jobs)


def _start_forked(fn, jobs, workers: int, limit):
    """The jobs on ``workers`` forked children (module docstring), or None where a fork is refused (the
    children already started killed).  Under one lock, so that the children of a call made meanwhile
    from another thread inherit none of this call's pipe ends (a write end held by another process
    would keep a reader from ever seeing the end of its pipe)."""
    children = []
    with spawner.FORK_LOCK:   # (a fresh one in each child: dsp.spawner's fork hook)
        task_r, task_w = os.pipe()
        try:
            os.write(task_w, struct.pack(f"<{len(jobs)}i", *range(len(jobs))))
            os.close(task_w)
            task_w = None
            me = spawner.forking_parent()
            for _ in range(workers):
                out_r, out_w = os.pipe()
                try:
                    pid = _fork()
                except BaseException:
                    os.close(out_r)
                    os.close(out_w)
                    raise
                if pid == 0:                                   # the child
                    os.close(out_r)
                    spawner.run_worker(fn, jobs, task_r, out_w, parent_pid=me)
                os.close(out_w)
                children.append((pid, out_r))
        except OSError:                      # the system refused a process (memory, a process limit)
            ForkedPending(children, len(jobs), limit)._reap(kill=True)
            return None
        except BaseException:
            ForkedPending(children, len(jobs), limit)._reap(kill=True)
            raise
        finally:
            os.close(task_r)
            if task_w is not None:
                os.close(task_w)
    return ForkedPending(children, len(jobs), limit)


def start_jobs(fn, jobs, workers, processes: bool = False):
    """[fn(job) for job in jobs] started, returned as a ``Pending``: the jobs shared among ``workers``
    threads, or with ``processes`` forked processes where the platform forks (they inherit ``fn`` and
    the data it closes over; only the index goes out and the result, pickled, comes back; threads
    where it does not); the caller is free meanwhile.  The BLAS on one thread throughout (the workers
    share the cores).  Module docstring: why threads by default, and how the processes are run."""
    limit = one_blas_thread()
    limit.__enter__()
    if workers <= 1:
        try:
            return Pending(done=[fn(job) for job in jobs])
        finally:
            limit.__exit__(None, None, None)
    # (a daemonic process, e.g. a dask worker's, may not have children: threads there)
    if (processes and _fork is not None and len(jobs) <= MAX_FORKED_JOBS
            and not multiprocessing.current_process().daemon):
        n = min(int(workers), len(jobs))
        pending = _start_spawned(fn, jobs, n, limit) or _start_forked(fn, jobs, n, limit)
        if pending is not None:
            return pending
    pool = ThreadPoolExecutor(max_workers=workers)
    return Pending([pool.submit(fn, job) for job in jobs], pool, limit)


def map_jobs(fn, jobs, workers, processes: bool = False):
    """[fn(job) for job in jobs] on ``workers`` (``start_jobs``), waited for."""
    return start_jobs(fn, jobs, workers, processes).result()
