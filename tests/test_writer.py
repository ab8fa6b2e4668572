"""The stage runner's writer thread (``runner._StageWriter``): stage files written while the next stage
computes, at most one in flight, in stage order; a failed write stops the run with its own error and
leaves every earlier file complete and nothing half-written.

Runs go through ``fwdlook_cli.cli.main`` in-process on the tiny cube, the stage functions and the
stage-file writer wrapped to record when each starts and ends.
"""
from __future__ import annotations

import threading
import time

import h5py
import numpy as np
import pytest

import fwdlook_cli.forward.chain as chain
import fwdlook_cli.runner as runner
from fwdlook_cli.cli import main
from fwdlook_cli.errors import BadInput

STAGE_FUNCS = ("range_fft", "decimate", "keystone_stage", "regroup", "range_curvature", "doppler_spectra",
               "monopulse_image")


def _run(argv):
    with pytest.raises(SystemExit) as info:
        main([str(a) for a in argv])
    return info.value.code


def test_writes_overlap_the_next_stage_one_at_a_time_in_order(tiny_raw, tmp_path, monkeypatch):
    events, lock = [], threading.Lock()

    def record(*what):
        with lock:
            events.append((time.perf_counter(), *what))

    real_write = runner.write_stage

    def write(path, data, **kw):
        record("write-start", kw["stage"], threading.current_thread().name)
        time.sleep(0.05)                 # a slow disk: the next stage must not wait for it
        out = real_write(path, data, **kw)
        record("write-end", kw["stage"])
        return out

    monkeypatch.setattr(runner, "write_stage", write)
    for name in STAGE_FUNCS:
        real = getattr(chain, name)

        def wrapped(*a, _real=real, _name=name, **k):
            record("compute-start", _name)
            out = _real(*a, **k)
            record("compute-end", _name)
            return out
        monkeypatch.setattr(chain, name, wrapped)
    assert _run(["process", tiny_raw, "-o", tmp_path / "run", "-q"]) == 0
    writes = [e for e in events if e[1] == "write-start"]
    assert [w[2] for w in writes] == ["range_fft", "decimate", "keystone", "regroup", "range_curvature",
                                      "doppler_spectra", "monopulse_image"]
    assert all(w[3].startswith("fwdlook-stage-writer") for w in writes)     # never the main thread
    # never two writes at once, and each file complete before the next one starts
    starts = [e[0] for e in events if e[1] == "write-start"]
    ends = [e[0] for e in events if e[1] == "write-end"]
    assert all(end <= nxt for end, nxt in zip(ends, starts[1:]))
    # the next stages compute while a file is being written (the 50 ms sleep): the keystone during the
    # range FFT's, the range curvature during the keystone's
    t = {(e[1], e[2]): e[0] for e in events}
    assert t[("compute-start", "keystone_stage")] < t[("write-end", "range_fft")]
    assert t[("compute-start", "range_curvature")] < t[("write-end", "keystone")]
    # but a write never outlives the stage that reads its arrays: no stage output is held longer than
    # the chain holds it anyway (a view shares its source's arrays)
    assert t[("write-end", "range_fft")] <= t[("compute-start", "regroup")]
    assert t[("write-end", "keystone")] <= t[("compute-start", "doppler_spectra")]
    assert t[("write-end", "range_curvature")] <= t[("compute-start", "monopulse_image")]

FILES = ["01_range_fft.h5", "02_decimate.h5", "03_keystone.h5", "04_regroup.h5", "05_range_curvature.h5",
         "06_doppler_spectra.h5", "07_monopulse_image.h5"]


@pytest.mark.parametrize("failing", [5, 7])      # a middle stage; the last, written beside the outputs
def test_a_failed_write_stops_the_run_and_leaves_earlier_files_complete(tiny_raw, tmp_path, monkeypatch, capsys,
                                                                        failing):
    real_write = runner.write_stage

    def write(path, data, **kw):
        if path.name == FILES[failing - 1]:
            raise BadInput(f"cannot write {path}: No space left on device")
        return real_write(path, data, **kw)

    monkeypatch.setattr(runner, "write_stage", write)
    run = tmp_path / "run"
    assert _run(["process", tiny_raw, "-o", run]) == 2
    err = capsys.readouterr().err
    assert f"{FILES[failing - 1]}: No space left on device" in err
    stages = run / "stages"
    assert sorted(p.name for p in stages.iterdir()) == FILES[:failing - 1]
    for name in ("metrics.json", "image.h5", "scenario.yaml"):     # no output that looks complete
        assert not (run / name).exists()
    # and the earlier files are sound: a rerun reuses them and finishes with the same image as a fresh run
    monkeypatch.setattr(runner, "write_stage", real_write)
    assert _run(["process", tiny_raw, "-o", run, "-q"]) == 0
    assert _run(["process", tiny_raw, "-o", tmp_path / "fresh", "-q"]) == 0
    with h5py.File(run / "image.h5") as a, h5py.File(tmp_path / "fresh" / "image.h5") as b:
        np.testing.assert_array_equal(a["image"][()], b["image"][()])


def test_the_image_stage_takes_the_spectra_from_memory_and_leaves_them_as_written(tiny_raw, tmp_path, monkeypatch):
    """The image stage gets the Doppler stage's own arrays (no wait for their file, no read back), and
    leaves them unchanged while the writer thread writes them: the file holds the very spectra the
    image was made from, and its declared digests (taken while the image stage ran) verify."""
    from fwdlook_cli.io.stagefile import load_verified, read_stage

    seen = {}
    real = chain.monopulse_image

    def spy(data, **kw):
        seen.update(kind=type(data["sum_z"]), sum_z=data["sum_z"].copy(), diff_z=data["diff_z"].copy())
        return real(data, **kw)

    monkeypatch.setattr(chain, "monopulse_image", spy)
    assert _run(["process", tiny_raw, "-o", tmp_path / "run", "-q"]) == 0
    assert seen["kind"] is np.ndarray
    path = tmp_path / "run" / "stages" / "06_doppler_spectra.h5"
    written = read_stage(path)
    for name in ("sum_z", "diff_z"):
        np.testing.assert_array_equal(written[name], seen[name])
    with h5py.File(path) as f:
        key = f.attrs["config_sha256"]
    loaded, damage = load_verified(path, key)
    assert damage is None and loaded is not None


def test_the_dwell_metrics_take_the_spectra_from_memory_and_a_reused_run_from_the_file(tiny_raw, tmp_path,
                                                                                       monkeypatch):
    """A run that computed the Doppler spectra gives them to the dwell metrics as they are (the file is
    not reopened); a rerun that reuses every stage reads them from the file; the metrics are the same
    numbers either way (the file holds those very arrays)."""
    import json

    calls = []
    real = runner.read_stage_mapped

    def spy(path, *a, **kw):
        calls.append(str(path))
        return real(path, *a, **kw)

    monkeypatch.setattr(runner, "read_stage_mapped", spy)
    run = tmp_path / "run"
    assert _run(["process", tiny_raw, "-o", run, "-q"]) == 0
    assert calls == []
    fresh = json.loads((run / "metrics.json").read_text())
    assert all("peak_loss_db" in row for row in fresh["targets"])       # the dwell metrics ran
    assert _run(["process", tiny_raw, "-o", run, "-q", "--overwrite"]) == 0
    assert len(calls) == 1 and calls[0].endswith("06_doppler_spectra.h5")
    again = json.loads((run / "metrics.json").read_text())
    assert again["targets"] == fresh["targets"]


@pytest.mark.parametrize("truth", [True, False])
def test_the_spectra_are_not_held_while_the_png_is_drawn(tiny_raw, tmp_path, monkeypatch, truth):
    """The Doppler spectra (2 x the cube) that the dwell metrics take from memory are released before
    the quick-look PNG is drawn in the process (no painter: io/painter.py draws it in a child of its
    own memory), also for a cube without truth, whose metrics never read them."""
    import contextlib
    import gc
    import shutil
    import weakref

    import fwdlook_cli.io.quicklook as quicklook

    raw = tmp_path / "raw.h5"
    shutil.copy(tiny_raw, raw)
    if not truth:
        with h5py.File(raw, "a") as f:
            del f["truth"]
    refs, alive = [], []
    real_doppler, real_png = chain.doppler_spectra, quicklook.draw_image_png

    def doppler_spy(data, **kw):
        out = real_doppler(data, **kw)
        refs.append(weakref.ref(out["sum_z"]))
        return out

    def png_spy(*a, **kw):
        gc.collect()
        alive.append(refs[-1]() is not None)
        return real_png(*a, **kw)

    monkeypatch.setattr(chain, "doppler_spectra", doppler_spy)
    monkeypatch.setattr(quicklook, "draw_image_png", png_spy)
    monkeypatch.setattr(quicklook, "painting", contextlib.nullcontext)     # drawn here, in the process
    assert _run(["process", raw, "-o", tmp_path / "run", "-q"]) == 0
    assert alive == [False]


def _spin_cpu(seconds):
    t0 = time.thread_time()
    while time.thread_time() - t0 < seconds:
        pass


def test_the_writer_threads_cpu_is_counted_per_file_and_only_its_own(tiny_raw, tmp_path, monkeypatch):
    """``file_cpu`` (the bench's ``chain_<method>_stage_files_*_cpu_ms``) holds, per stage file, the CPU
    time of the thread that wrote it: 80 ms of CPU spent inside the keystone's write appears in the
    keystone's file and nowhere else, and 80 ms spent by the main thread computing the range curvature
    (while the keystone's file is being written) appears in no file's."""
    from fwdlook_cli.forward.process import process_cube
    from fwdlook_cli.io.raw import read_raw
    from fwdlook_cli.testing import tiny_scenario

    if runner.thread_cpu_split_s() is None:
        pytest.skip("per-thread CPU time (getrusage RUSAGE_THREAD) is Linux's")
    burn = 0.08
    real_write = runner.write_stage

    def write(path, data, **kw):
        if kw["stage"] == "keystone":
            _spin_cpu(burn)
        return real_write(path, data, **kw)

    real_curvature = chain.range_curvature

    def curvature(*a, **k):
        _spin_cpu(burn)
        return real_curvature(*a, **k)

    monkeypatch.setattr(runner, "write_stage", write)
    monkeypatch.setattr(chain, "range_curvature", curvature)
    cube = read_raw(tiny_raw)
    file_cpu = {}
    process_cube(cube, tiny_scenario(), tmp_path / "run", force=True, quiet=True, png=False, file_cpu=file_cpu)
    assert list(file_cpu) == ["range_fft", "decimate", "keystone", "regroup", "range_curvature",
                              "doppler_spectra", "monopulse_image"]
    cpu = {name: u + s for name, (u, s) in file_cpu.items()}
    assert all(u >= 0 and s >= 0 for u, s in file_cpu.values())
    assert cpu["keystone"] >= burn
    others = {name: c for name, c in cpu.items() if name != "keystone"}
    assert max(others.values()) < burn / 2, others       # the curvature's 80 ms went to no file
    assert cpu["keystone"] - burn < burn / 2             # nor to the keystone's beyond its own
    empty = {}
    process_cube(cube, tiny_scenario(), tmp_path / "none", force=True, quiet=True, png=False,
                 keep_stages="none", file_cpu=empty)
    assert empty == {}


def test_a_second_signal_does_not_cut_short_the_wait_for_the_write_in_flight(tmp_path, monkeypatch):
    """Ctrl-C reaches a sweep's workers with their process group, and the sweep then passes SIGTERM on:
    the second signal had cut short a worker's wait for its stage file in flight, whose process then
    left, leaving ``NN_stage.h5.partial``.  The wait ends with the write (renamed or removed), and the
    chain's exception comes after it."""
    import os
    import signal

    from fwdlook_cli.errors import Terminated
    from fwdlook_cli.io import signals
    from fwdlook_cli.io.stagefile import StageData

    real_write = runner.write_stage
    written = []

    def slow_write(path, *args, **kwargs):     # the write in flight when the signals arrive
        time.sleep(0.5)
        result = real_write(path, *args, **kwargs)
        written.append(path.name)
        return result

    def stopped(data):                         # Ctrl-C in the next stage, SIGTERM during the wait after it
        threading.Timer(0.15, os.kill, (os.getpid(), signal.SIGTERM)).start()
        os.kill(os.getpid(), signal.SIGINT)
        end = time.monotonic() + 5.0
        while time.monotonic() < end:
            pass
        return data

    monkeypatch.setattr(runner, "write_stage", slow_write)
    source = StageData()
    source.add("n", np.arange(4.0), ("n",), "1", "sample").add("x", np.ones(4), ("n",), "1", "x")
    restore = signals.install(Terminated)
    try:
        with pytest.raises((KeyboardInterrupt, Terminated)):
            runner.run_stages([runner.Stage("first", lambda d: d, {}), runner.Stage("second", stopped, {})],
                              source, "k" * 64, tmp_path, quiet=True)
        assert written == ["01_first.h5"]      # finished before the exception left run_stages
    finally:
        restore()
    assert sorted(p.name for p in (tmp_path / "stages").iterdir()) == ["01_first.h5"]
