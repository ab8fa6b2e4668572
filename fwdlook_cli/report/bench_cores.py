"""What the second core buys: the reference fft2 and the CPI chains timed again with every thread of
the process on one core (``fwdlook bench``'s ``one_core``).

The bench's ratios divide a chain by one 2-D FFT, and on this 2-core machine the two gain unequally
from the second core: the FFT is compute-bound and pocketfft splits it over both cores, while most of
the chain is numpy's element-wise passes over arrays larger than the caches, one thread each (the
stages' block pools add a second where the work divides, but memory-bound passes gain little from it,
and calls of a few microseconds on two threads queue for the GIL).  Timing both on one core, in the
same process and the same interleaved way, separates the chain's work from how it spreads over cores:
``chain_over_fft2`` on one core against ``chain_s / fft2_s`` on all of them, and each one's
``second_core_gain`` (one-core time over all-core time, :func:`second_core_gains`).

On one core ``worker_threads()`` is 1 (it reads the process's affinity), so the stages run their blocks
one after the other, and ``scipy.fft``'s ``workers=-1`` is held at one worker while the process is
pinned, in the reference and in the chain alike, as in a command started on one core (the command line
sets that count from the usable cores, ``dsp.blas.fft_workers_on_usable_cores``; before the forty-sixth
round the pinned process kept two pocketfft tasks on its one core: one fft2 of the paper cube 4.58
against 4.49 ms, medians of 30 alternated batches).  A process held to under two CPUs by its cgroup's
limit (``dsp.cgroups``) has no second core to compare either.
"""
from __future__ import annotations

import contextlib
import os
import statistics

from .benchtools import wall_times as _times


def _thread_ids() -> list[int]:
    return [int(t) for t in os.listdir("/proc/self/task")]


@contextlib.contextmanager
def pinned_to_one_core():
    """Every thread of this process on one core, the lowest this process may use, and every thread
    started meanwhile (a new thread inherits its creator's mask); yields that core, or None where the OS
    has no per-thread affinity or the process may use one core only (nothing to compare).  On exit
    each thread that existed before gets its own mask back, and any other the process's mask.  Meanwhile
    ``scipy.fft``'s ``workers=-1`` means one worker (:func:`dsp.blas.fft_workers_held_at_most`), as in a
    command started on one core; its count before is given back on exit."""
    if not hasattr(os, "sched_setaffinity") or not os.path.isdir("/proc/self/task"):
        yield None                                       # pragma: no cover (not Linux)
        return
    from ..dsp.blas import available_cores, fft_workers_held_at_most

    allowed = os.sched_getaffinity(0)
    if available_cores() < 2:            # one core in the affinity, or a CPU limit under two
        yield None
        return
    before = {}
    for tid in _thread_ids():
        with contextlib.suppress(OSError):             # a thread that ended meanwhile
            before[tid] = os.sched_getaffinity(tid)
    core = min(allowed)
    try:
        for tid in _thread_ids():
            with contextlib.suppress(OSError):
                os.sched_setaffinity(tid, {core})
        with fft_workers_held_at_most(1):
            yield core
    finally:
        for tid in _thread_ids():
            with contextlib.suppress(OSError):
                os.sched_setaffinity(tid, before.get(tid, allowed))


def one_core_timings(x, chains: dict, run_chain, *, fft2_repeats: int = 21, fft2_between: int = 3,
                     rounds: int = 3) -> dict | None:
    """The reference (``scipy.fft.fft2(x, workers=-1)``) and each chain of ``chains`` ({name:
    scenario}, run by ``run_chain(scenario)``, which returns its seconds) on one core: the reference
    ``fft2_repeats`` times before and after the chains and ``fft2_between`` times before each chain run
    (after one untimed), the chains in ``rounds`` interleaved rounds after one untimed run each;
    medians, and each chain over that fft2.  None where the process cannot be put on one core (:func:`pinned_to_one_core`)."""
    import scipy.fft

    def fft2():
        scipy.fft.fft2(x, workers=-1)

    with pinned_to_one_core() as core:
        if core is None:
            return None
        fft2()
        reference = _times(fft2, fft2_repeats)
        for scn in chains.values():                     # untimed: the pool threads and pages on this core
            run_chain(scn)
        runs: dict[str, list[float]] = {name: [] for name in chains}
        for _ in range(max(1, int(rounds))):
            for name, scn in chains.items():
                fft2()
                reference += _times(fft2, fft2_between)
                runs[name].append(run_chain(scn))
        reference += _times(fft2, fft2_repeats)
    fft2_s = statistics.median(reference)
    out = {"core": core, "fft2_s": fft2_s, "fft2_repeats": len(reference)}
    for name, seconds in runs.items():
        chain_s = statistics.median(seconds)
        out[f"{name}_s"] = chain_s
        out[f"{name}_over_fft2"] = chain_s / fft2_s
    return out


def second_core_gains(one_core: dict, all_cores: dict) -> dict:
    """``second_core_gain_<name>``: one-core seconds over all-core seconds, for each ``<name>_s`` of
    ``one_core`` that ``all_cores`` ({"<name>_s": seconds}, the bench's own keys) holds too."""
    return {f"second_core_gain_{k[:-2]}": v / all_cores[k] for k, v in one_core.items()
            if k.endswith("_s") and all_cores.get(k)}
