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

import hashlib
import json
import logging
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable


from .errors import BadInput
from .io.stagefile import StageData, _canon, load_verified, write_stage

log = logging.getLogger(__name__)

@dataclass
class Stage:
    name: str
    fn: Callable[..., StageData]
    params: dict


def stage_key(name: str, params: dict, previous_key: str) -> str:
    """Hash of a stage's name, settings, input key and the software version (new code, new files)."""
    from . import __version__

    blob = json.dumps({"stage": name, "params": _canon(params), "input": previous_key,
                       "version": __version__}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()



def run_stages(stages: list[Stage], source: StageData, source_key: str, run_dir: Path, *,
               force: bool = False, from_stage: str | None = None, quiet: bool = False):
    """Run ``stages`` in order over ``source``; returns (last StageData, timings dict, keys dict)."""
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
    # the first stage that must run: forced, missing, stale or damaged (integrity.py: every reused
    # stage is read and checked against its declared datasets, dtypes, shapes and sha256 digests)
    first = recompute_from
    data = source
    for i in range(first):
        loaded, damage = load_verified(paths[i], keys[i])
        if loaded is None:
            if damage:
                print(f"[{i + 1}/{len(stages)}] {stages[i].name}: stage file {paths[i]} is damaged ({damage}); "
                      f"recomputing it, not reusing it", file=sys.stderr)
            first = i
            break
        data = loaded
    if first == 0:
        data = source
    timings: dict[str, float] = {}
    for i, st in enumerate(stages):
        if i < first:
            timings[st.name] = 0.0
            continue
        t0 = time.perf_counter()
        data = st.fn(data, **st.params)
        t_compute = time.perf_counter() - t0
        write_stage(paths[i], data, stage=st.name, key=keys[i], input_key=keys[i - 1] if i else source_key,
                    params=st.params, extra_attrs={"compute_s": t_compute})
        timings[st.name] = time.perf_counter() - t0
        if not quiet:
            log.info(f"[{i + 1}/{len(stages)}] {st.name:<18s} {t_compute * 1e3:8.1f} ms compute, "
                     f"{(timings[st.name] - t_compute) * 1e3:6.1f} ms write")
        log.debug("stage %s: key %s -> %s", st.name, keys[i][:12], paths[i])
    if first == len(stages) and not quiet:
        log.info(f"all {len(stages)} stages up to date (reused)")
    if first < len(stages) and first > 0 and not quiet:
        log.info(f"reused stages 1-{first} ({', '.join(names[:first])})")
    return data, timings, dict(zip(names, keys))
