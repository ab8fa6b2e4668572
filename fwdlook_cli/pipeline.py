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
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import h5py
import numpy as np

from .errors import BadInput
from .io import atomic_h5, put

log = logging.getLogger(__name__)


@dataclass
class Var:
    """One array with its dimension names, units and long name."""

    data: np.ndarray
    dims: tuple[str, ...]
    units: str
    long_name: str


@dataclass
class StageData:
    """Named arrays (coordinates are 1-D vars whose single dim is their own name) and attributes."""

    vars: dict[str, Var] = field(default_factory=dict)
    attrs: dict[str, Any] = field(default_factory=dict)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.vars[name].data

    def __contains__(self, name: str) -> bool:
        return name in self.vars

    def add(self, name, data, dims, units, long_name) -> "StageData":
        self.vars[name] = Var(np.asarray(data), tuple(dims), units, long_name)
        return self

    def copy_vars(self, *names) -> "StageData":
        """A new StageData sharing (not copying) the named vars and all attrs."""
        return StageData({n: self.vars[n] for n in names if n in self.vars}, dict(self.attrs))


@dataclass
class Stage:
    name: str
    fn: Callable[..., StageData]
    params: dict


def _canon(value):
    if isinstance(value, dict):
        return {str(k): _canon(v) for k, v in sorted(value.items())}
    if isinstance(value, (list, tuple)):
        return [_canon(v) for v in value]
    if isinstance(value, np.ndarray):
        return hashlib.sha256(np.ascontiguousarray(value).tobytes()).hexdigest()
    if isinstance(value, np.generic):
        return value.item()
    return value


PROVENANCE_KEYS = ("format", "stage", "config_sha256", "input_sha256", "settings", "software",
                   "software_version", "created_utc", "compute_s")


def stage_key(name: str, params: dict, previous_key: str) -> str:
    """Hash of a stage's name, settings, input key and the software version (new code, new files)."""
    from . import __version__

    blob = json.dumps({"stage": name, "params": _canon(params), "input": previous_key,
                       "version": __version__}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()


def write_stage(path: Path, data: StageData, *, stage: str, key: str, input_key: str, params: dict,
                extra_attrs: dict | None = None) -> None:
    with atomic_h5(path) as f:
        for k, v in {**data.attrs, **(extra_attrs or {})}.items():
            if k not in PROVENANCE_KEYS:
                f.attrs[k] = json.dumps(v) if isinstance(v, (dict, list)) else v
        f.attrs["format"] = "fwdlook-stage"      # provenance last: never taken from carried attrs
        f.attrs["stage"] = stage
        f.attrs["config_sha256"] = key
        f.attrs["input_sha256"] = input_key
        f.attrs["settings"] = json.dumps(_canon(params), sort_keys=True, default=str)
        scales = {}
        for name, var in data.vars.items():  # coordinates first, as dimension scales
            if var.dims == (name,):
                ds = put(f, name, var.data, var.units, var.long_name)
                ds.make_scale(name)
                scales[name] = ds
        for name, var in data.vars.items():
            if var.dims == (name,):
                continue
            ds = put(f, name, var.data, var.units, var.long_name)
            ds.attrs["dims"] = json.dumps(list(var.dims))
            for axis, dim in enumerate(var.dims):
                if dim not in scales or scales[dim].shape[0] != var.data.shape[axis]:
                    raise ValueError(f"stage {stage}: {name} axis {axis} is '{dim}', which has no coordinate "
                                     f"of length {var.data.shape[axis]} in the stage output")
                ds.dims[axis].attach_scale(scales[dim])


def read_stage(path: Path) -> StageData:
    out = StageData()
    with h5py.File(path, "r") as f:
        for k, v in f.attrs.items():
            if k in PROVENANCE_KEYS:
                continue
            out.attrs[k] = v.decode() if isinstance(v, bytes) else (v.item() if isinstance(v, np.generic) else v)
        for name, ds in f.items():
            if not isinstance(ds, h5py.Dataset):
                continue
            dims = tuple(json.loads(ds.attrs["dims"])) if "dims" in ds.attrs else (name,)
            out.vars[name] = Var(ds[()], dims, str(ds.attrs.get("units", "")),
                                 str(ds.attrs.get("long_name", "")))
    return out


def stage_file_key(path: Path) -> str | None:
    try:
        with h5py.File(path, "r") as f:
            return f.attrs.get("config_sha256")
    except OSError:
        return None


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
    # the first stage that must run: forced, missing, or stale
    first = recompute_from
    for i, path in enumerate(paths):
        if i >= first:
            break
        if stage_file_key(path) != keys[i]:
            first = i
            break
    timings: dict[str, float] = {}
    data = source if first == 0 else read_stage(paths[first - 1])
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
    if first == len(stages):
        data = read_stage(paths[-1])
    elif first > 0 and not quiet:
        log.info(f"reused stages 1-{first} ({', '.join(names[:first])})")
    return data, timings, dict(zip(names, keys))
