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
from .io.integrity import STAGE_FORMAT_VERSION
from .io.stagefile import StageData, _canon, declared_digests, load_verified, read_stage, write_stage
from .io.stageview import (mapped_stage, read_stage_lazy, read_stage_mapped, reshaped_views, view_file_key,
                             virtual_layout)

log = logging.getLogger(__name__)

@dataclass
class Stage:
    name: str
    fn: Callable[..., StageData]
    params: dict
    view: bool = False        # a re-layout: its file stores virtual datasets onto the previous file
    lazy_input: bool = False  # reads its input block by block: given the previous file's datasets


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
               keep: str = "all", captured: dict | None = None):
    """Run ``stages`` in order over ``source``; returns (last StageData, timings dict, keys dict).

    ``keep``: ``all`` writes every stage file (a killed run resumes after the last finished stage);
    ``last`` writes only the final stage and the stages named in ``captured``; ``none`` writes none.
    With ``all`` the first missing or stale file decides where the chain starts; otherwise the latest
    valid file does (the earlier ones were never kept).  ``captured``: {stage name: None}, filled with
    a function returning each named stage's output (from its file when kept, its large arrays memory
    maps of it, so that the output is neither held in memory meanwhile nor copied whole).  A
    ``lazy_input`` stage after a written stage gets that file's large arrays as open datasets instead
    of the arrays in memory (bounded memory; the same numbers).
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
    # the first stage that must run: forced, missing, stale or damaged (every reused stage is read and
    # checked against its declared datasets, dtypes, shapes and sha256 digests: io/integrity.py)
    first = _first_to_run(paths, keys, recompute_from, keep, [names.index(n) for n in captured],
                          labels=[f"[{i + 1}/{len(stages)}] {s.name}" for i, s in enumerate(stages)])
    kept = set(range(len(stages))) if keep == "all" else (
        {len(stages) - 1} | {names.index(n) for n in captured} if keep == "last" else set())
    timings: dict[str, float] = {}
    open_files = []
    if first == 0:
        data = source
    elif first < len(stages) and stages[first].lazy_input:
        data, fh = read_stage_lazy(paths[first - 1])
        open_files.append(fh)
    else:
        data = read_stage(paths[first - 1])
    del source                          # the input cube is freed once stage 1 has consumed it
    written_prev = first > 0            # the input of stage `first` is on disk
    known: dict = {}                    # {name: (array, sha256)} of the last file written (no rehash)
    prev_is_view = None                 # whether the last file written is a view (None: not known)
    for i, st in enumerate(stages):
        if i < first:
            timings[st.name] = 0.0
            if st.name in captured:
                captured[st.name] = functools.partial(read_stage_mapped, paths[i])
            continue
        t0 = time.perf_counter()
        out = st.fn(data, **st.params)
        t_compute = time.perf_counter() - t0
        is_view = False
        if i in kept:
            extra, virtual = {"compute_s": t_compute}, None
            if st.view and written_prev and not (prev_is_view if prev_is_view is not None
                                                 else _is_view(paths[i - 1])):
                virtual = _virtual_layouts(out, data, paths[i - 1], known)
                if virtual:
                    extra.update(view_source=paths[i - 1].name, view_source_sha256=keys[i - 1])
                    is_view = True
            known = write_stage(paths[i], out, stage=st.name, key=keys[i],
                                input_key=keys[i - 1] if i else source_key, params=st.params,
                                extra_attrs=extra, virtual=virtual, known=known)
        else:
            known = {}
        prev_is_view = is_view
        written_prev = i in kept
        for fh in open_files:           # a lazy input is consumed
            fh.close()
        open_files = []
        if st.name in captured:
            captured[st.name] = functools.partial(read_stage_mapped, paths[i]) if i in kept else (lambda out=out: out)
        if i in kept and i + 1 < len(stages) and stages[i + 1].lazy_input:
            del out
            data, fh = read_stage_lazy(paths[i])
            open_files.append(fh)
            if st.name in captured:     # the same file, once: its large arrays as memory maps
                captured[st.name] = (lambda mapped=mapped_stage(data, paths[i]): mapped)
        else:
            data = out
        timings[st.name] = time.perf_counter() - t0
        if not quiet:
            what = ("view" if st.view and i in kept else "write") if i in kept else "not kept"
            log.info(f"[{i + 1}/{len(stages)}] {st.name:<18s} {t_compute * 1e3:8.1f} ms compute, "
                     f"{(timings[st.name] - t_compute) * 1e3:6.1f} ms {what}")
        log.debug("stage %s: key %s -> %s", st.name, keys[i][:12], paths[i])
    for i, path in enumerate(paths):     # what this run's policy does not keep goes
        if i not in kept:
            path.unlink(missing_ok=True)
    if first == len(stages) and not quiet:
        log.info(f"all {len(stages)} stages up to date (reused)")
    if first < len(stages) and first > 0 and not quiet:
        log.info(f"reused stages 1-{first} ({', '.join(names[:first])})")
    return data, timings, dict(zip(names, keys))


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
    """{name: (virtual layout, sha256)} for the arrays of ``out`` that reshape arrays of the previous
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
