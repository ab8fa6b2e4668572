"""Threads and memory of the stages: the BLAS held to one thread (for a command, a chain, the small
batched products), the stages' worker threads, one allocator arena.

``np.matmul`` over a stack of small matrices (the Doppler zoom: one 64 x 32 by 32 x n_range product
per CPI) calls the BLAS once per matrix.  A multithreaded OpenBLAS wakes and parks its pool on every
call; with the cores shared, a call can wait for a descheduled thread for milliseconds, and 78 calls
ranged from 55 ms to 1.8 s (issue 11).  One thread per call makes each product a few microseconds of
work that cannot stall; the batch is what is large, not the matrices.  ``threadpoolctl`` controls
the pool of whichever BLAS numpy loaded (OpenBLAS, MKL, BLIS).

A command runs with the BLAS on one thread from its start (:func:`one_blas_thread_for_the_process`,
before numpy is imported) and ``forward.process.process_cube`` holds it there for a chain run from
Python; the joint fit's spawner, forked before that, enters :func:`one_blas_thread` for good, for
the workers it forks (``dsp/spawner.py``).  An OpenBLAS thread that has worked, or has just been started,
spins for about 2^28 cycles (0.1 s here) before it sleeps, on a core the stages' own threads need: measured on this
machine, 52 ms of CPU in the 0.3 s after ``import numpy``, 105 ms after one multithreaded product,
104 ms after a threadpoolctl limit that a fork came under is lifted (the fork shut the pool down,
lifting the limit starts it again).  The chain's products are small and its stages make their own
threads, so one BLAS thread gives the same numbers bit for bit (image.h5 and metrics.json of both
presets on the paper cube) and takes the spinning away (README, Speed).

This module imports no numpy at import time, so that the command line can call it before the
painter is forked (``io/painter.py``).
"""
from __future__ import annotations

import contextlib
import functools
import importlib
import math
import os
import sys

from . import cgroups

try:                                            # a dependency (pyproject.toml); tolerated if absent
    from threadpoolctl import ThreadpoolController
except ImportError:                             # pragma: no cover
    ThreadpoolController = None

_CONTROLLER: list = []      # [(scipy.linalg loaded when it was made, ThreadpoolController)]


def _controller():
    """The process's ThreadpoolController: finding the loaded BLAS libraries costs about 4 ms (a scan
    of the shared objects), so it is done once; limiting through it costs 20 us.  It limits the BLAS
    libraries loaded when it was made: numpy's, which every product of the chain calls, and scipy's
    own where ``scipy.linalg`` has loaded it; made again once ``scipy.linalg`` appears (a host
    program's import), so that its BLAS is limited too.  Not imported here for that: ``scipy.linalg``
    costs about 30 ms to import, and no fwdlook code calls it (it was imported here until issue 11's
    twenty-first round, inside the Doppler stage's time of every command-line run)."""
    linalg = "scipy.linalg" in sys.modules
    if not _CONTROLLER or _CONTROLLER[0][0] != linalg:
        _CONTROLLER[:] = [(linalg, ThreadpoolController())]
    return _CONTROLLER[0][1]


BLAS_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
_SET_FOR_THE_PROCESS: list = []     # the variables one_blas_thread_for_the_process set (not the user's)


def one_blas_thread_for_the_process() -> list:
    """The BLAS on one thread for this process and the children it starts: each of
    :data:`BLAS_THREAD_VARS` the environment does not set is set to 1.  Read by the BLAS when numpy
    loads it, so it takes effect only before numpy is imported (the command line calls it first
    thing); a user's own setting stays.  Returns the variables set here."""
    for var in BLAS_THREAD_VARS:
        if var not in os.environ:
            os.environ[var] = "1"
            _SET_FOR_THE_PROCESS.append(var)
    return list(_SET_FOR_THE_PROCESS)


def plain_environment() -> dict:
    """This process's environment without what :func:`one_blas_thread_for_the_process` set: a plain
    interpreter's, as the user started this one (the bench's reference, ``benchtools.clean_process_fft2``)."""
    return {k: v for k, v in os.environ.items() if k not in _SET_FOR_THE_PROCESS}


def one_blas_thread():
    """A context in which the BLAS runs on one thread (the stage's own threads share the cores)."""
    if ThreadpoolController is None:            # pragma: no cover
        return contextlib.nullcontext()
    return _controller().limit(limits=1, user_api="blas")


def on_one_blas_thread(fn):
    """``fn`` run inside :func:`one_blas_thread` (a whole chain: ``process_cube``, ``api.run_chain``)."""
    @functools.wraps(fn)
    def wrapped(*args, **kwargs):
        with one_blas_thread():
            return fn(*args, **kwargs)
    return wrapped


def batched_matmul(a, b):
    """``np.matmul(a, b)`` over stacks of small matrices, the BLAS limited to one thread."""
    import numpy as np

    with one_blas_thread():
        return np.matmul(a, b)


def batched_matmul_each(a, bs) -> list:
    """``[np.matmul(a, b) for b in bs]`` (one matrix stack ``a`` shared, as the Doppler zoom's by both
    channels), the products on up to :func:`worker_threads` threads, the BLAS on one thread each: the
    same calls as :func:`batched_matmul`, so the same numbers, but both cores busy (numpy's matmul
    loop releases the GIL).  The two channels' zooms of the paper cube: 14.0-15.7 ms one after the other,
    5.7-8.1 ms side by side (random data of those shapes, medians of 41 calls)."""
    import numpy as np

    bs = list(bs)
    threads = min(worker_threads(), len(bs))
    with one_blas_thread():
        if threads <= 1:
            return [np.matmul(a, b) for b in bs]
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(max_workers=threads) as pool:
            later = [pool.submit(np.matmul, a, b) for b in bs[1:]]
            first = np.matmul(a, bs[0])                  # the first on this thread meanwhile
            return [first] + [f.result() for f in later]


def available_cores() -> int:
    """The cores this process may use: its CPU affinity (the machine's count where the OS has none),
    and no more than its control group's CPU limit, rounded up (a container's ``--cpus``, a Kubernetes
    limit: :mod:`dsp.cgroups`)."""
    try:
        n = max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):       # pragma: no cover (not Linux)
        n = os.cpu_count() or 1
    limit = cgroups.cached_cpu_limit()
    return n if limit is None else max(1, min(n, math.ceil(limit)))


def worker_threads() -> int:
    """Threads for independent blocks of a stage (image, dwell, keystone columns): the cores this process
    may use, at most 4 (numpy's element-wise loops and the FFTs release the GIL), or fewer where
    ``FWDLOOK_THREADS`` or ``OMP_NUM_THREADS`` says so (a sweep's workers set the latter to 1)."""
    n = available_cores()
    for var in ("FWDLOOK_THREADS", "OMP_NUM_THREADS"):
        value = os.environ.get(var, "").strip()
        if value.isdigit() and int(value) > 0:
            n = min(n, int(value))
            break
    return max(1, min(4, n))


def fft_workers_on_usable_cores() -> int | None:
    """``scipy.fft``'s ``workers=-1`` on the cores this process may use (:func:`available_cores`: its CPU
    affinity, within its control group's CPU limit), never more than it had; returns that count, or None
    where this scipy's count is out of reach (:func:`fft_workers_at_most`).  scipy counts
    ``os.cpu_count()`` once, at import (scipy issue 17098), and pocketfft's pool (scipy up to 1.17) has a
    thread per online core, so where the process may use fewer cores than the machine has (Slurm,
    ``taskset``, a container's ``--cpuset-cpus`` or ``--cpus``) each such transform was split into a task
    per core of the machine, all on the few allowed.  With the machine's count faked to 64 (16) on this
    2-core VM, one fft2 of the paper cube took 4.9 against 4.3 ms (4.6 against 3.8), with 28 % (33 %) more
    CPU, slower in 28 (30) of 30 alternated batches (docs/SPEED.md, its last section).  The same numbers
    with pocketfft (each 1-D transform is computed whole by one thread); scipy 1.18's ducc rounds a transform by its
    place in the batch, so there the count moves the numbers at float32 rounding (README, "Python and
    library versions").  Called by the command line, never on import (a host program's threads are its
    own)."""
    return fft_workers_at_most(available_cores())


# scipy.fft's backend module that holds the CPU count ``workers=-1`` counts from (``_cpu_count``, read once
# at import) and the function that resolves a worker count (``_workers``): pocketfft's up to scipy 1.17,
# ducc's from scipy 1.18 on (which has no ``scipy.fft._pocketfft``).  Both are scipy privates, looked up
# here alone; a scipy with neither leaves the count as it comes.
_SCIPY_FFT_HELPERS = {"scipy.fft._duccfft.helper": "ducc", "scipy.fft._pocketfft.helper": "pocketfft"}


def scipy_fft_helper():
    """The module of ``scipy.fft``'s backend holding ``_cpu_count`` and ``_workers``, or None where this
    scipy has neither known one."""
    for name in _SCIPY_FFT_HELPERS:
        try:
            helper = importlib.import_module(name)
        except ImportError:
            continue
        if hasattr(helper, "_cpu_count") and callable(getattr(helper, "_workers", None)):
            return helper
    return None


def scipy_fft_backend() -> str:
    """Which FFT ``scipy.fft`` computes with: ``pocketfft`` (scipy up to 1.17), ``ducc`` (1.18 on), or
    ``unknown``; they round differently (README, "Python and library versions")."""
    helper = scipy_fft_helper()
    return "unknown" if helper is None else _SCIPY_FFT_HELPERS[helper.__name__]


def fft_workers() -> int | None:
    """How many workers ``scipy.fft``'s ``workers=-1`` means now; None where this scipy's is unknown."""
    helper = scipy_fft_helper()
    return None if helper is None else int(helper._workers(-1))


def fft_workers_at_most(n: int) -> int | None:
    """At most ``n`` for ``scipy.fft``'s ``workers=-1`` from now on (never raised); returns the count, or
    None where this scipy keeps it where this function cannot reach (then it is left as it comes, and
    nothing raises).  It sets scipy's private CPU count (:func:`scipy_fft_helper`)."""
    helper = scipy_fft_helper()
    if helper is None:
        return None
    helper._cpu_count = max(1, min(int(helper._cpu_count or 1), int(n)))
    return helper._cpu_count


@contextlib.contextmanager
def fft_workers_held_at_most(n: int):
    """:func:`fft_workers_at_most` ``n`` inside the block, the count before it given back after (the
    bench's one-core timings: as a command started on one core runs its transforms); yields the count."""
    helper = scipy_fft_helper()
    before = None if helper is None else helper._cpu_count
    try:
        yield fft_workers_at_most(n)
    finally:
        if before is not None:
            helper._cpu_count = before


M_ARENA_MAX = -8            # glibc mallopt parameter


def share_one_allocator_arena() -> bool:
    """Make every thread allocate from glibc's main arena (``mallopt(M_ARENA_MAX, 1)``).

    By default each thread of a stage's block pool gets its own arena, and an arena keeps the
    temporaries its thread freed: the CPI image on 2 threads peaked at 27 MiB above its input against
    10 MiB on one (measured, paper cube), 10.7 MiB with one shared arena.  Called by the command line
    (the process is fwdlook's), never on import (a host program's allocator is its own).  Returns
    whether it was applied (False off glibc)."""
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6")
        return bool(libc.mallopt(M_ARENA_MAX, 1))
    except (OSError, AttributeError):       # pragma: no cover (not glibc)
        return False
