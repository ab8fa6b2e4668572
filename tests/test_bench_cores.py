"""The bench's one-core timings (report/bench_cores.py): every thread of the process really on one core
while they run, the masks given back after, and the medians and gains computed as stated."""
from __future__ import annotations

import os
import threading

import numpy as np
import pytest

from fwdlook_cli.dsp.blas import worker_threads
from fwdlook_cli.report.bench_cores import one_core_timings, pinned_to_one_core, second_core_gains

needs_two_cores = pytest.mark.skipif(
    not hasattr(os, "sched_setaffinity") or not os.path.isdir("/proc/self/task")
    or len(os.sched_getaffinity(0)) < 2, reason="per-thread affinity and two usable cores needed")


def _fft_workers() -> int:
    """What scipy.fft's workers=-1 means now (scipy's private count, as dsp.blas sets it)."""
    from fwdlook_cli.dsp.blas import fft_workers

    return fft_workers()


def _masks() -> dict:
    out = {}
    for tid in os.listdir("/proc/self/task"):
        try:
            out[int(tid)] = os.sched_getaffinity(int(tid))
        except OSError:          # ended meanwhile
            pass
    return out


@needs_two_cores
def test_every_thread_is_on_one_core_inside_and_gets_its_mask_back_after():
    allowed = os.sched_getaffinity(0)
    release = threading.Event()
    older = threading.Thread(target=release.wait)           # a thread that exists before the pinning
    older.start()
    try:
        before, workers, fft_workers = _masks(), worker_threads(), _fft_workers()
        seen = {}

        def report():
            seen["new"] = os.sched_getaffinity(0)

        with pinned_to_one_core() as core:
            assert core == min(allowed)
            assert all(mask == {core} for mask in _masks().values())  # every thread, the older one too
            started = threading.Thread(target=report)                # started inside: inherits the mask
            started.start()
            started.join()
            assert seen["new"] == {core}
            assert worker_threads() == 1                             # the stages' pools shrink to one
            assert _fft_workers() == 1                               # and scipy.fft's workers=-1
        after = _masks()
        for tid, mask in before.items():
            if tid in after:
                assert after[tid] == mask
        assert worker_threads() == workers
        assert _fft_workers() == fft_workers                         # its count given back
    finally:
        release.set()
        older.join()


@needs_two_cores
def test_one_core_timings_take_medians_after_the_untimed_runs_and_the_gains_are_the_quotients():
    allowed = os.sched_getaffinity(0)
    core = min(allowed)
    returned = {"a": iter([9.0, 0.3, 0.1, 0.2]), "b": iter([7.0, 0.5, 0.4, 0.6])}   # first: the untimed run
    masks = []

    def run_chain(name):
        masks.append((os.sched_getaffinity(0), _fft_workers()))
        return next(returned[name])

    x = np.ones((64, 32), np.complex64)
    out = one_core_timings(x, {"chain": "a", "chain_tracking": "b"}, run_chain, fft2_repeats=5, fft2_between=2,
                           rounds=3)
    assert masks == [({core}, 1)] * 8                 # every run on the one core, its FFTs on one worker
    assert out["core"] == core
    assert out["chain_s"] == 0.2 and out["chain_tracking_s"] == 0.5
    assert out["fft2_repeats"] == 2 * 5 + 3 * 2 * 2
    assert out["fft2_s"] > 0
    assert out["chain_over_fft2"] == pytest.approx(0.2 / out["fft2_s"])
    assert out["chain_tracking_over_fft2"] == pytest.approx(0.5 / out["fft2_s"])
    gains = second_core_gains(out, {"fft2_s": out["fft2_s"] / 4, "chain_s": 0.1, "chain_tracking_s": 0.25,
                                    "other_s": 1.0})
    assert gains == pytest.approx({"second_core_gain_fft2": 4.0, "second_core_gain_chain": 2.0,
                                   "second_core_gain_chain_tracking": 2.0})      # only what both hold
    assert os.sched_getaffinity(0) == allowed                       # given back


def test_one_core_timings_say_none_where_there_is_no_second_core(monkeypatch):
    if not hasattr(os, "sched_getaffinity"):
        pytest.skip("no affinity on this OS")
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0})
    calls = []
    assert one_core_timings(np.ones((4, 4), np.complex64), {"chain": None}, calls.append) is None
    assert calls == []


def test_one_core_timings_say_none_under_a_cpu_limit_of_one(monkeypatch):
    """Two cores in the affinity but a cgroup limit of one CPU (a container's --cpus 1): no second core."""
    from fwdlook_cli.dsp import cgroups

    if not hasattr(os, "sched_getaffinity") or len(os.sched_getaffinity(0)) < 2:
        pytest.skip("needs an affinity of two cores")
    monkeypatch.setattr(cgroups, "cached_cpu_limit", lambda: 1.0)
    calls = []
    assert one_core_timings(np.ones((4, 4), np.complex64), {"chain": None}, calls.append) is None
    assert calls == []
