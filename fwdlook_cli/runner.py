"""Stage-by-stage execution with one HDF5 intermediate per stage, hashing and resume.

A stage is a pure function ``fn(data, **params) -> data`` over a :class:`StageData` (named arrays with
their dimension names, units and long names, plus plain attributes).  The runner writes its output to
``RUN_DIR/stages/NN_<name>.h5`` atomically, with the stage's settings and the hash that made it:

    key_n = sha256(name_n, params_n, key_{n-1})        key_0 = hash of the input cube and scenario

A stage whose file exists with the same key is reused, not recomputed (the decision is taken from the
file's own ``config_sha256`` attribute, never from logs); a run interrupted anywhere resumes after the
last finished stage.  ``force`` recomputes every stage; ``from_stage`` recomputes from that stage on.
"""
from __future__ import annotations

import functools
import hashlib
import json
import logging
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable


from .errors import BadInput
from .io import signals
from .io.integrity import STAGE_FORMAT_VERSION
from .io.stagefile import StageData, _canon, declared_digests, load_verified, read_stage, write_stage
from .io.stageview import read_stage_mapped, reshaped_views, view_file_key, virtual_layout

log = logging.getLogger(__name__)

@dataclass
class Stage:
    name: str
    fn: Callable[..., StageData]
    params: dict
    view: bool = False        # a re-layout: its file stores virtual datasets onto the previous file


KEEP_STAGES = ("all", "last", "none")


def stage_key(name: str, params: dict, previous_key: str) -> str:
    """Hash of a stage's name, settings, input key, the software version and the stage-file format
    (new code or a new format, new files: a file of another format is stale, never trusted)."""
    from . import __version__

    blob = json.dumps({"stage": name, "params": _canon(params), "input": previous_key,
                       "version": __version__, "format": STAGE_FORMAT_VERSION}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()



def run_stages(stages: list[Stage], source: StageData, source_key: str, run_dir: Path, *,
               force: bool = False, from_stage: str | None = None, quiet: bool = False,
               keep: str = "all", captured: dict | None = None, pending_writes: list | None = None,
               stage_cpu: dict | None = None, file_cpu: dict | None = None):
    """Run ``stages`` in order over ``source``; returns (last StageData, timings dict, keys dict).

    ``keep``: ``all`` writes every stage file (a killed run resumes after the last finished stage);
    ``last`` writes only the final stage and the stages named in ``captured``; ``none`` writes none.
    With ``all`` the first missing or stale file decides where the chain starts; otherwise the latest
    valid file does (the earlier ones were never kept).  ``captured``: {stage name: None}, filled with
    a function returning each named stage's output: the output itself when this run computed it (no
    reopening of its file: 14 ms of HDF5 metadata for the Doppler spectra, issue 11's third round; the
    chain held it anyway, as the next stage's input), else memory maps of its file.  Every stage
    takes its input from memory, also while that input's file is being written (the image stage read
    the Doppler spectra back from their file, block by block, until issue 11's second round: it waited
    for the write, and the peak RSS is the Doppler stage's either way).  Stage files are written on a
    writer thread while the next stages compute (:class:`_StageWriter`); ``pending_writes``: a list to
    which the function waiting for the last writes is appended instead of waiting here (it returns the
    seconds it waited; the caller must call it, error or not, before it treats the files as written).
    ``stage_cpu``: a dict filled with {stage name: (user s, system s)}, the process's CPU time while each
    computed stage ran (every thread: its blocks' pool and the writer's work on the file before it), so
    that the kernel's share (page faults on memory touched first) can be told from the stage's own.
    """
    if keep not in KEEP_STAGES:
        raise BadInput(f"--keep-stages {keep}: allowed: {', '.join(KEEP_STAGES)}")
    captured = {} if captured is None else captured
    names = [s.name for s in stages]
    if from_stage is not None and from_stage not in names:
        raise BadInput(f"--from-stage {from_stage}: unknown stage; allowed: {', '.join(names)}")
    stage_dir = Path(run_dir) / "stages"
    stage_dir.mkdir(parents=True, exist_ok=True)
    recompute_from = names.index(from_stage) if from_stage else (0 if force else len(names))
    keys, paths = [], []
    key = source_key
    for i, st in enumerate(stages):
        key = stage_key(st.name, st.params, key)
        keys.append(key)
        paths.append(stage_dir / f"{i + 1:02d}_{st.name}.h5")
    _remove_other_chains_files(stage_dir, paths)
    # the first stage that must run: forced, missing, stale or damaged (every reused stage is read and
    # checked against its declared datasets, dtypes, shapes and digests: io/integrity.py)
    first = _first_to_run(paths, keys, recompute_from, keep, [names.index(n) for n in captured],
                          labels=[f"[{i + 1}/{len(stages)}] {s.name}" for i, s in enumerate(stages)])
    kept = set(range(len(stages))) if keep == "all" else (
        {len(stages) - 1} | {names.index(n) for n in captured} if keep == "last" else set())
    timings: dict[str, float] = {}
    data = source if first == 0 else read_stage(paths[first - 1])
    del source                          # the input cube is freed once stage 1 has consumed it
    writer = _StageWriter(stages, quiet=quiet, file_cpu=file_cpu)
    try:
        for i, st in enumerate(stages):
            if i < first:
                timings[st.name] = 0.0
                if st.name in captured:
                    captured[st.name] = functools.partial(read_stage_mapped, paths[i])
                continue
            cpu0 = cpu_split_s() if stage_cpu is not None else None
            t0 = time.perf_counter()
            out = st.fn(data, **st.params)
            t_compute = time.perf_counter() - t0
            timings[st.name] = t_compute
            if cpu0 is not None:
                cpu1 = cpu_split_s()
                stage_cpu[st.name] = (cpu1[0] - cpu0[0], cpu1[1] - cpu0[1])
            if i in kept:                   # written on the writer thread while the next stage computes
                # a re-layout is a view of the previous file when that file exists (this run's, or an
                # earlier run's when the chain starts here)
                view_of = paths[i - 1] if st.view and i > 0 and (i - 1 in kept or i == first) else None
                writer.submit(i, st, out, data if view_of is not None else None, view_of, paths[i], keys[i],
                              keys[i - 1] if i else source_key, t_compute, timings)
            else:
                writer.forget(i, st, t_compute, timings)
            if st.name in captured:         # the output itself, in memory (also while its file is written)
                captured[st.name] = lambda out=out: out
            data = out
            del out
            log.debug("stage %s: key %s -> %s", st.name, keys[i][:12], paths[i])
        if pending_writes is None:
            writer.wait()
        else:                               # the caller waits (its own work overlaps the last write)
            pending_writes.append(writer.finish)
    finally:
        if pending_writes is None or writer.finish not in pending_writes:
            # the write in flight ends (renamed, or its partial file removed) before an exception goes on,
            # a second signal held meanwhile: Ctrl-C reaches a sweep's workers with their group, and the
            # SIGTERM the sweep then passes on had cut this wait short, leaving the stage's .partial
            signals.call_held(writer.close)
            signals.raise_pending()
    for i, path in enumerate(paths):     # what this run's policy does not keep goes
        if i not in kept:
            path.unlink(missing_ok=True)
    if first == len(stages) and not quiet:
        log.info(f"all {len(stages)} stages up to date (reused)")
    if first < len(stages) and first > 0 and not quiet:
        log.info(f"reused stages 1-{first} ({', '.join(names[:first])})")
    return data, timings, dict(zip(names, keys))


def _remove_other_chains_files(stage_dir: Path, paths: list[Path]) -> None:
    """Stage files of another chain in this run's ``stages/`` (a run directory reused for another method,
    imaging or radar system: ISAR's ``02_rcmc.h5`` had stayed beside the forward stages, the dwell
    image's beside the CPI image's) go: fwdlook's own stage files only (``io.outputs.h5_format``)."""
    from .io.outputs import h5_format

    mine = {p.name for p in paths}
    for q in sorted(stage_dir.glob("[0-9][0-9]_*.h5")):
        if q.name not in mine and q.is_file() and not q.is_symlink() and h5_format(q) == "fwdlook-stage":
            q.unlink(missing_ok=True)


def _rusage_split_s(who: str) -> tuple[float, float] | None:
    """(user, system) CPU seconds of ``getrusage(resource.<who>)``; None where the platform has no such
    measure."""
    try:
        import resource

        usage = resource.getrusage(getattr(resource, who))
    except (ImportError, AttributeError, OSError):     # pragma: no cover (not POSIX; RUSAGE_THREAD: Linux)
        return None
    return usage.ru_utime, usage.ru_stime


def cpu_split_s() -> tuple[float, float]:
    """(user, system) CPU seconds of this process, every thread (``getrusage``; (0, 0) off POSIX)."""
    return _rusage_split_s("RUSAGE_SELF") or (0.0, 0.0)


def thread_cpu_split_s() -> tuple[float, float] | None:
    """(user, system) CPU seconds of the calling thread (``getrusage(RUSAGE_THREAD)``, Linux); None
    elsewhere."""
    return _rusage_split_s("RUSAGE_THREAD")


class _StageWriter:
    """Stage files written on one worker thread while the next stages compute, in stage order: a file
    is renamed into place only when complete (``io.h5.atomic_h5``), so a run killed at any moment
    resumes after the last file that exists.  A write waits in the queue only while the arrays it holds
    are the input of the stage computing now (the previous stage's output, and the output before a
    re-layout view, which shares its arrays): no more stage outputs are held than the chain holds
    anyway.  A failed write is raised by the next :meth:`submit` or :meth:`wait`.  The digests of the
    previous file's arrays (``known``) and whether it is a view are the writer's own state: only the
    writer thread touches them."""

    def __init__(self, stages, quiet: bool, file_cpu: dict | None = None):
        from concurrent.futures import ThreadPoolExecutor

        self.pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="fwdlook-stage-writer")
        self.pending: list = []               # (stage index, name, compute s, timings, future), in order
        self.known: dict = {}
        self.prev_is_view = None
        self.views = [st.view for st in stages]
        self.quiet, self.n = quiet, len(stages)
        self.file_cpu = file_cpu            # {stage: (user s, system s)} of the writer thread, per file

    def _make_room(self, i):
        """Before stage i's write is queued, wait for the queued writes that do not hold stage i's output
        (the next stage's input): all but stage i's own and, where stage i is a view, its source's."""
        keep = i
        while keep > 0 and self.views[keep]:     # a view's arrays are its own input's
            keep -= 1
        while self.pending and self.pending[0][0] < keep:
            self._finish(self.pending.pop(0))

    def submit(self, i, st, out, previous, previous_path, path, key, input_key, t_compute, timings):
        self._make_room(i)
        self.pending.append((i, st.name, t_compute, timings, self.pool.submit(
            self._write, st, out, previous, previous_path, path, key, input_key, t_compute)))

    def forget(self, i, st, t_compute, timings):
        """A stage not kept: the file after it cannot be a view of it, and there are no digests to carry."""
        self._make_room(i)
        self.pending.append((i, st.name, t_compute, timings, self.pool.submit(self._reset)))

    def _reset(self):
        self.known, self.prev_is_view = {}, False
        return None

    def _write(self, st, out, previous, previous_path, path, key, input_key, t_compute):
        t0 = time.perf_counter()
        cpu0 = thread_cpu_split_s() if self.file_cpu is not None else None
        extra, virtual, is_view = {"compute_s": t_compute}, None, False
        if previous_path is not None and not (self.prev_is_view if self.prev_is_view is not None
                                              else _is_view(previous_path)):
            virtual = _virtual_layouts(out, previous, previous_path, self.known)
            if virtual:
                extra.update(view_source=previous_path.name, view_source_sha256=input_key)
                is_view = True
        self.known = write_stage(path, out, stage=st.name, key=key, input_key=input_key, params=st.params,
                                 extra_attrs=extra, virtual=virtual, known=self.known)
        self.prev_is_view = is_view
        if cpu0 is not None:
            cpu1 = thread_cpu_split_s()
            self.file_cpu[st.name] = (cpu1[0] - cpu0[0], cpu1[1] - cpu0[1])
        return ("view" if is_view else "write", time.perf_counter() - t0)

    def _finish(self, job):
        i, name, t_compute, timings, fut = job
        t0 = time.perf_counter()
        done = fut.result()
        timings[name] += time.perf_counter() - t0        # the wait the chain saw (the write overlapped)
        if not self.quiet:
            what, t_write = done if done else ("not kept", 0.0)
            log.info(f"[{i + 1}/{self.n}] {name:<18s} {t_compute * 1e3:8.1f} ms compute, "
                     f"{t_write * 1e3:6.1f} ms {what}")

    def wait(self):
        """Every queued write done (its error raised, if any)."""
        while self.pending:
            self._finish(self.pending.pop(0))

    def close(self):
        self.pool.shutdown(wait=True)

    def finish(self) -> float:
        """Wait for every queued write and release the thread; returns the seconds waited."""
        t0 = time.perf_counter()
        try:
            self.wait()
        finally:
            self.close()
        return time.perf_counter() - t0

def _first_to_run(paths, keys, recompute_from: int, keep: str, needed: list[int], labels=None) -> int:
    """Index of the first stage to compute (see :func:`run_stages`): a stage file is valid when its key
    (and a view's source key) match and its data passes :func:`io.stagefile.load_verified`."""
    checked = {}

    def valid(i):
        if i not in checked:
            loaded, damage = load_verified(paths[i], keys[i])
            if damage:
                label = labels[i] if labels else paths[i].name
                print(f"{label}: stage file {paths[i]} is damaged ({damage}); recomputing it, not "
                      f"reusing it", file=sys.stderr)
            checked[i] = loaded is not None and view_file_key(paths[i]) == keys[i]
        return checked[i]

    if keep == "none":            # every run computes everything: the files of an earlier run are neither
        return 0                  # read nor reused (its captured stages would be read after they go, below)
    if keep == "all":
        first = recompute_from
        for i in range(recompute_from):
            if not valid(i):
                return i
        return first
    first = 0
    for i in reversed(range(recompute_from)):
        if valid(i):
            first = i + 1
            break
    for i in sorted(needed, reverse=True):       # a stage the caller needs must be valid or recomputed
        if i < first and not valid(i):
            first = next((j + 1 for j in reversed(range(i)) if valid(j)), 0)
    return first


def _is_view(path: Path) -> bool:
    import h5py

    with h5py.File(path, "r") as f:
        return "view_source" in f.attrs


def _virtual_layouts(out: StageData, previous: StageData, previous_path: Path, known: dict) -> dict:
    """{name: (virtual layout, digest)} for the arrays of ``out`` that reshape arrays of the previous
    (written) stage: the same bytes, so the digest that file declares (``known`` when it was written
    in this run, else read from its declaration, which the reuse check verified)."""
    layouts, digests = {}, None
    for name in reshaped_views(out, previous):
        src = previous.vars[name].data
        if name in known:
            sha = known[name][1]
        else:
            digests = declared_digests(previous_path) if digests is None else digests
            if name not in digests:
                continue
            sha = digests[name]
        layouts[name] = (virtual_layout(previous_path, name, out.vars[name].data.shape, src.dtype, src.shape), sha)
    return layouts
