"""A small process, forked before the chain's data exist, that forks the joint fit's workers.

``dsp.forked`` runs the dwell image's joint fit (``forward.dwell_fit``) on forked children. Forked from
the process that runs the chain, they cost that process where the chain runs: the forks write-protect
every page of its heap (three forks took 16.7-19.7 ms of its main thread, medians of seven and nine chains of the paper
cube, ``-c configs/tracking.yaml``), and then every first write to one of those pages while the
children live is a copy-on-write fault (14 551 minor faults of the process during the dwell stage,
against 842 with the same jobs on threads).

The spawner is forked once, early: the command forks it once the scenario is known and before the cube
is read (``cli``), ``process_cube`` where it is not yet running (and only where the fit forks: more than
one worker thread). It closes every pipe and socket it inherited but its own socket, hands its free
heap back (``malloc_trim``) and waits. A batch of jobs is sent to it pickled,
with the descriptors of its pipes (``SCM_RIGHTS``): the task pipe, read by every worker, and one result
pipe per worker, read by the caller as the directly forked workers' are. It forks the workers from its
own small heap, sends back their process ids and waits for the next batch; the caller's process forks
nothing and shares no heap with the workers. The spawner reaps its workers when the next batch
comes, so a worker's id is never reused while the caller may still end it (``SpawnedPending.cancel``).
It leaves when its socket closes: when the process that forked it ends, however it ends.

A job must pickle (the fit's jobs carry their cells' samples, ``forward.dwell_fit.ClusterFit``); a
batch that does not, a spawner gone, or a platform without ``fork`` falls back to direct forks.
"""
from __future__ import annotations

import atexit
import contextlib
import ctypes
import multiprocessing
import os
import pickle
import resource
import signal
import socket
import struct
import threading
import time

from .blas import one_blas_thread
from .lifetime import die_with_parent, forking_parent

_HEAD = struct.Struct("<iq")          # workers, payload bytes
ANSWER_TIMEOUT_S = 20.0               # a batch's forks take milliseconds; a spawner silent this long is stuck
_SPAWNER = None                       # this process's spawner, if started
_LOCK = threading.Lock()
_WORKER_CPU = [0.0, 0.0]              # user, system seconds of the spawner's workers, as they reported them
FORK_LOCK = threading.Lock()          # held around every fork of workers and the pipes made for them, so that
                                      # a fork from another thread meanwhile inherits none of their ends


class Spawner:
    """The spawner process seen from the process that forked it (module docstring)."""

    def __init__(self, pid: int, sock: socket.socket):
        self.pid, self.sock = pid, sock
        self.lock = threading.Lock()
        self.sent, self.answered, self.answers = 0, 0, {}

    def spawn(self, payload: bytes, fds: list, workers: int):
        """Have ``workers`` workers forked for the pickled (fn, jobs) ``payload``; ``fds``: the task pipe's
        read end, then one result pipe's write end per worker (the caller closes its own copies once
        this returns).  Returns a function that waits for the workers' process ids (fewer where the
        spawner's forks were refused): the caller need not wait for the forks.  Raises OSError where the
        spawner is gone."""
        with self.lock:
            socket.send_fds(self.sock, [_HEAD.pack(int(workers), len(payload))], fds)
            self.sock.sendall(payload)
            ticket = self.sent
            self.sent += 1
        return lambda: self._pids(ticket)

    def _pids(self, ticket: int) -> list:
        """The process ids the spawner answered for batch ``ticket`` (its answers come in order). A
        spawner that has not answered in :data:`ANSWER_TIMEOUT_S` is killed and OSError raised (the
        caller then runs the jobs itself): a fork can hang for good where a library's ``pthread_atfork``
        handler loses a wake-up (scipy's pocketfft pool: it notifies its threads without their lock, and
        a thread it has just restarted after the previous fork may miss it; seen once in the test suite,
        the spawner stuck at its third fork of a batch)."""
        with self.lock:
            self.sock.settimeout(ANSWER_TIMEOUT_S)
            try:
                while self.answered <= ticket:
                    n = struct.unpack("<i", _recv_exact(self.sock, 4))[0]
                    self.answers[self.answered] = (list(struct.unpack(f"<{n}i", _recv_exact(self.sock, 4 * n)))
                                                   if n > 0 else [])
                    self.answered += 1
            except TimeoutError:
                with contextlib.suppress(OSError):
                    os.kill(self.pid, signal.SIGKILL)
                raise ConnectionError(f"the spawner did not answer in {ANSWER_TIMEOUT_S:.0f} s") from None
            finally:
                with contextlib.suppress(OSError):
                    self.sock.settimeout(None)
            return self.answers.pop(ticket)

    def close(self, grace_s: float = 2.0):
        """End the spawner (its socket closed: it leaves at once) and reap it; killed where it has not
        left within ``grace_s`` (an exit never waits on it)."""
        try:
            self.sock.close()
        finally:
            try:
                deadline = time.monotonic() + grace_s
                while not os.waitpid(self.pid, os.WNOHANG)[0]:
                    if time.monotonic() > deadline:
                        os.kill(self.pid, signal.SIGKILL)
                        os.waitpid(self.pid, 0)
                        break
                    time.sleep(0.001)
            except ChildProcessError:
                pass


def run_worker(fn, jobs, task_fd: int, out_fd: int, *, parent_pid: int | None = None):
    """A forked worker (the spawner's or ``dsp.forked``'s): the next job index from ``task_fd`` until none
    is left, then (True, [(index, result), ...]) or (False, (the failed job's index, the exception))
    pickled to ``out_fd``; never returns. It dies with ``parent_pid`` (:func:`die_with_parent`)."""
    code = 0
    i = -1
    try:
        die_with_parent(parent_pid)
        try:
            done = []
            while True:
                raw = os.read(task_fd, 4)
                if len(raw) < 4:
                    break
                i = struct.unpack("<i", raw)[0]
                done.append((i, fn(jobs[i])))
            cpu = resource.getrusage(resource.RUSAGE_SELF)          # (a forked child's starts at zero)
            payload = pickle.dumps((True, done, cpu.ru_utime, cpu.ru_stime), protocol=pickle.HIGHEST_PROTOCOL)
        except BaseException as exc:  # noqa: BLE001 (every failure goes to the parent, which raises it)
            try:
                payload = pickle.dumps((False, (i, exc)), protocol=pickle.HIGHEST_PROTOCOL)
            except Exception:  # noqa: BLE001 (an exception that does not pickle: its text)
                payload = pickle.dumps((False, (i, RuntimeError(f"{type(exc).__name__}: {exc}"))))
        view = memoryview(payload)
        while view:
            view = view[os.write(out_fd, view):]
    except BaseException:  # noqa: BLE001 (the parent sees a worker without a result)
        code = 1
    finally:
        os._exit(code)


def _recv_exact(sock, n: int) -> bytes:
    parts, got = [], 0
    while got < n:
        chunk = sock.recv(min(n - got, 1 << 20))
        if not chunk:
            raise ConnectionError("the spawner closed its socket")
        parts.append(chunk)
        got += len(chunk)
    return b"".join(parts)


def _trim_heap():
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):       # pragma: no cover (not glibc)
        pass


def _close_pipes(keep: int):
    """Close every inherited pipe and socket but ``keep``: a pipe end held here would keep its reader
    from ever seeing its end (the painter's, a batch's).  Files stay open (a log file the workers write)."""
    import stat

    try:
        fds = [int(fd) for fd in os.listdir("/proc/self/fd")]
    except OSError:                     # pragma: no cover (no /proc)
        fds = range(3, 1 << 12)
    for fd in fds:
        if fd < 3 or fd == keep:
            continue
        try:
            mode = os.fstat(fd).st_mode
        except OSError:                 # (the listing's own descriptor, closed by now)
            continue
        if stat.S_ISFIFO(mode) or stat.S_ISSOCK(mode):
            os.close(fd)


def _serve(sock: socket.socket, parent_pid: int | None):
    """The spawner's loop (module docstring); never returns."""
    children = set()
    try:
        die_with_parent(parent_pid)
        signal.signal(signal.SIGINT, signal.SIG_IGN)      # the caller ends the workers (it has their ids)
        # the BLAS on one thread for good (the limit applies when made; never left), once here so that every
        # worker inherits it: the spawner is forked before the chain's limit, and with the user's
        # OPENBLAS_NUM_THREADS=2 each of three workers ran two BLAS threads, each spinning 0.1 s after its
        # work (the paper cube's dwell image 1.0-3.4 s instead of 0.25-0.37 s).  Not in each worker: after
        # a fork OpenBLAS restarts its pool in the call that sets the count, so each worker would start a
        # thread that spins (the workers' CPU 430-530 against 280-350 ms a dwell chain)
        one_blas_thread()
        _close_pipes(keep=sock.fileno())
        _trim_heap()
        while True:
            _reap(children, block=False)                  # the workers of earlier batches, ended
            msg, fds, _, _ = socket.recv_fds(sock, _HEAD.size, 64)
            if not msg:
                break
            head = msg + _recv_exact(sock, _HEAD.size - len(msg))
            workers, size = _HEAD.unpack(head)
            fn, jobs = pickle.loads(_recv_exact(sock, size))
            task_fd, outs = fds[0], fds[1:1 + workers]
            pids = []
            me = os.getpid()
            for out_fd in outs:
                try:
                    pid = os.fork()
                except OSError:
                    break
                if pid == 0:
                    sock.close()
                    for fd in fds:
                        if fd not in (task_fd, out_fd):
                            os.close(fd)
                    run_worker(fn, jobs, task_fd, out_fd, parent_pid=me)   # never returns
                pids.append(pid)
                children.add(pid)
            for fd in fds:
                os.close(fd)
            sock.sendall(struct.pack(f"<i{len(pids)}i", len(pids), *pids))
            del fn, jobs
            _trim_heap()                                  # the batch's data freed, and handed back
    except BaseException:  # noqa: BLE001 (the caller sees the socket closed and forks its workers itself)
        pass
    finally:
        try:       # the caller is gone: what its workers still compute has no reader (ended and reaped)
            for pid in children:
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
            _reap(children, block=True)
        finally:
            os._exit(0)


def _reap(children: set, block: bool):
    """Reap the spawner's ended workers (all of them, waiting, with ``block``)."""
    for pid in list(children):
        try:
            done, _ = os.waitpid(pid, 0 if block else os.WNOHANG)
        except ChildProcessError:
            done = pid
        if done:
            children.discard(pid)


def _forget_in_child():
    """In any child of this process: the spawner is not its own (its socket closed, not used), and the
    locks, which the forking thread may hold, are fresh."""
    global _SPAWNER, _LOCK, FORK_LOCK
    sp, _SPAWNER, _LOCK, FORK_LOCK = _SPAWNER, None, threading.Lock(), threading.Lock()
    if sp is not None:
        try:
            sp.sock.close()
        except OSError:
            pass


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_in_child)


def start() -> Spawner | None:
    """This process's spawner, forked now where none is running (None where the platform cannot, in a
    daemonic process, whose jobs run on threads (``dsp.forked.start_jobs``), or where
    ``FWDLOOK_SPAWNER=0``: the workers then forked by this process itself)."""
    global _SPAWNER
    if (not hasattr(os, "fork") or not hasattr(socket, "send_fds") or os.environ.get("FWDLOOK_SPAWNER") == "0"
            or multiprocessing.current_process().daemon):
        return None
    with _LOCK:
        if _SPAWNER is not None:
            return _SPAWNER
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
        me = forking_parent()
        with FORK_LOCK:             # (no pipe end of a batch in flight is inherited)
            try:
                pid = os.fork()
            except OSError:
                ours.close()
                theirs.close()
                return None
            if pid == 0:
                ours.close()
                _serve(theirs, me)
        theirs.close()
        _SPAWNER = Spawner(pid, ours)
    return _SPAWNER


def count_worker_cpu(user_s: float, system_s: float):
    """Add one worker's CPU time (``dsp.forked.SpawnedPending``: the kernel counts it for the spawner)."""
    with _LOCK:
        _WORKER_CPU[0] += user_s
        _WORKER_CPU[1] += system_s


def worker_cpu_split_s() -> tuple[float, float]:
    """(user, system) CPU seconds the spawner's workers have spent for this process so far (those that
    returned their results): the work ``RUSAGE_CHILDREN`` would show were they this process's children."""
    with _LOCK:
        return _WORKER_CPU[0], _WORKER_CPU[1]


def current() -> Spawner | None:
    """The running spawner, if any."""
    return _SPAWNER


def stop():
    """End this process's spawner, if any (at exit; the tests; ``dsp.forked`` when a send to it failed:
    the next batch is then forked directly).  A spawner whose socket closes leaves at once."""
    global _SPAWNER
    with _LOCK:
        sp, _SPAWNER = _SPAWNER, None
    if sp is not None:
        sp.close()


def payload_of(fn, jobs) -> bytes | None:
    """(fn, jobs) pickled for the spawner, or None where they do not pickle (a closure, say)."""
    try:
        return pickle.dumps((fn, jobs), protocol=pickle.HIGHEST_PROTOCOL)
    except (pickle.PicklingError, TypeError, AttributeError):
        return None


atexit.register(stop)       # (once: a process that ends closes its spawner's socket anyway; this reaps it)
