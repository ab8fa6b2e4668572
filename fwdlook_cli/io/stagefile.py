"""Stage files: named arrays with dimensions, units and long names (:class:`StageData`), written to and
read from one HDF5 file per stage with the provenance that made it (settings, input hash, version).
Coordinates are dimension scales, so xarray (engine h5netcdf) reads a stage file with named axes.
"""
from __future__ import annotations

import hashlib
import json
import weakref
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from . import backing, h5native
from .h5 import atomic_h5, set_attrs
from .integrity import (ATTRS_DIGEST_ATTR, DATASETS_ATTR, DIGEST_ATTR, STAGE_FORMAT_VERSION, attrs_digest,
                        declaration, digest, digest_async, read_declaration)


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
                   "software_version", "created_utc", "compute_s", "stage_datasets", "view_source",
                   "view_source_sha256", "format_version", ATTRS_DIGEST_ATTR)


def write_stage(path: Path, data: StageData, *, stage: str, key: str, input_key: str, params: dict,
                extra_attrs: dict | None = None, virtual: dict | None = None, known: dict | None = None) -> dict:
    """``virtual``: {var name: (h5py.VirtualLayout, digest of the bytes it maps)} for arrays stored as
    views of another file (:mod:`io.stageview`); every other array is written in full, uncompressed and
    contiguous (complex stage data compresses to 90-95 % at 30 times the write time: docs/SPEED.md).
    ``known``: {var name: (weak reference to the array, digest)} digests already computed in this run
    (the previous stage's file); an array that is the same object (under any name) keeps its digest.
    Returns that mapping for what the file declares (``known`` for the next stage): weak references, so
    that the digests never keep a stage's arrays alive (on the big cube a write held the range FFT's
    output through the next stages: 0.6 GB of peak RSS).  The digests of large arrays are computed in a
    worker thread while HDF5 writes (io/integrity.py)."""
    virtual = virtual or {}
    known = known or {}
    pending = {}
    by_id = {}                                   # the same object under any name (alive: id not reused)
    for ref, sha in known.values():
        array = ref() if ref is not None else None
        if array is not None:
            by_id[id(array)] = (array, sha)
    for name, var in data.vars.items():
        if name in virtual:
            continue
        prior = by_id.get(id(var.data))
        pending[name] = prior[1] if prior is not None and prior[0] is var.data else digest_async(var.data)
    del by_id
    with atomic_h5(path, own_partial=True) as f:      # stages/ is fwdlook's: a leftover partial replaced
        carried = {}
        for k, v in {**data.attrs, **(extra_attrs or {})}.items():
            if k not in PROVENANCE_KEYS:
                carried[k] = json.dumps(v) if isinstance(v, (dict, list)) else v
        set_attrs(f, carried)
        root = {"format": "fwdlook-stage", "format_version": STAGE_FORMAT_VERSION, "stage": stage,
                "config_sha256": key, "input_sha256": input_key,          # provenance last: never taken
                "settings": json.dumps(_canon(params), sort_keys=True, default=str)}   # from carried attrs
        for k in ("view_source", "view_source_sha256"):          # a view's source (io.stageview)
            if k in (extra_attrs or {}):
                root[k] = extra_attrs[k]
        scales = {}
        for name, var in data.vars.items():  # coordinates first, as dimension scales
            if var.dims == (name,):
                ds = _new_dataset(f.id, name, var.data)
                set_attrs(_Node(ds), {"units": var.units, "long_name": var.long_name})
                _set_scale(ds, name)
                scales[name] = (ds, var.data.shape[0])
        for name, var in data.vars.items():
            if var.dims == (name,):
                continue
            if name in virtual:
                ds = f.create_virtual_dataset(name, virtual[name][0]).id
            else:
                ds = _new_dataset(f.id, name, var.data)
            set_attrs(_Node(ds), {"units": var.units, "long_name": var.long_name, "dims": json.dumps(list(var.dims))})
            for axis, dim in enumerate(var.dims):
                if dim not in scales or scales[dim][1] != var.data.shape[axis]:
                    raise ValueError(f"stage {stage}: {name} axis {axis} is '{dim}', which has no coordinate "
                                     f"of length {var.data.shape[axis]} in the stage output")
                _attach_scale(ds, scales[dim][0], axis)
        declared, out = {}, {}
        for name, var in data.vars.items():
            sha = virtual[name][1] if name in virtual else pending[name]
            sha = sha if isinstance(sha, str) else sha.result()
            declared[name] = declaration(var.data, var.dims, sha)
            out[name] = (_weak(var.data), sha)
        root[DATASETS_ATTR] = json.dumps(declared)   # integrity.py: what the file declares
        root[ATTRS_DIGEST_ATTR] = attrs_digest({**carried, **root})
        set_attrs(f, root)
    return out



class _Node:
    """The ``.id`` that :func:`io.h5.set_attrs` writes through, for a low-level dataset identifier."""

    __slots__ = ("id",)

    def __init__(self, dsid):
        self.id = dsid


_H5_TYPES: dict = {}
_DCPL: list = []


def _new_dataset(group_id, name: str, data):
    """A contiguous dataset holding ``data``, through HDF5's own calls: the dataset h5py's
    ``create_dataset(name, data=data)`` makes (its file type, no timestamps), at a fraction of the
    Python around it (stage files hold about ten datasets each; docs/SPEED.md)."""
    a = np.ascontiguousarray(data)
    types = _H5_TYPES.get(a.dtype.str)
    if types is None:      # (file type, memory type), as h5py's create_dataset and DatasetID.write
        types = _H5_TYPES[a.dtype.str] = (h5py.h5t.py_create(a.dtype, logical=True), h5py.h5t.py_create(a.dtype))
    tid = types[0]
    if not _DCPL:
        dcpl = h5py.h5p.create(h5py.h5p.DATASET_CREATE)
        dcpl.set_obj_track_times(False)         # as h5py's default
        _DCPL.append(dcpl)
    if h5native.enabled() and a.dtype.kind in "biufc":   # the same calls without the GIL (io/h5native.py)
        return h5py.h5d.DatasetID(h5native.new_dataset(group_id.id, name, a, tid.id, types[1].id, _DCPL[0].id))
    space = h5py.h5s.create_simple(a.shape) if a.ndim else h5py.h5s.create(h5py.h5s.SCALAR)
    dsid = h5py.h5d.create(group_id, name.encode(), tid, space, dcpl=_DCPL[0])
    if a.size:
        dsid.write(h5py.h5s.ALL, h5py.h5s.ALL, a)
    return dsid


def _set_scale(ds, name: str) -> None:
    if h5native.enabled():
        h5native.set_scale(ds.id, name)
    else:
        h5py.h5ds.set_scale(ds, name.encode())


def _attach_scale(ds, scale, axis: int) -> None:
    if h5native.enabled():
        h5native.attach_scale(ds.id, scale.id, axis)
    else:
        h5py.h5ds.attach_scale(ds, scale, axis)


def _weak(array):
    """A weak reference to ``array`` (None for an object that has none)."""
    try:
        return weakref.ref(array)
    except TypeError:
        return None

def declared_dims(f) -> dict:
    """{dataset: dims} from a stage file's declaration ({} for a file without one, e.g. image.h5)."""
    try:
        return {k: tuple(v["dims"]) for k, v in read_declaration(_text(f.attrs[DATASETS_ATTR])).items()}
    except Exception:  # noqa: BLE001  (none, or not of this version: dims from the datasets' attributes)
        return {}


def dims_of(ds, name: str, declared: dict) -> tuple:
    if name in declared:
        return declared[name]
    return tuple(json.loads(_text(ds.attrs["dims"]))) if "dims" in ds.attrs else (name,)


def read_stage(path: Path) -> StageData:
    out = StageData()
    with h5py.File(path, "r") as f:
        for k, v in list(f.attrs.items()):
            if k in PROVENANCE_KEYS:
                continue
            out.attrs[k] = v.decode() if isinstance(v, bytes) else (v.item() if isinstance(v, np.generic) else v)
        declared = declared_dims(f)
        for name, ds in list(f.items()):
            if not isinstance(ds, h5py.Dataset):
                continue
            out.vars[name] = Var(backing.read_dataset(ds), dims_of(ds, name, declared),   # file-backed
                                 str(_text(ds.attrs.get("units", ""))),                   # out of core
                                 str(_text(ds.attrs.get("long_name", ""))))
    return out


def declared_digests(path: Path) -> dict:
    """{dataset: digest} a stage file declares ({} when it has no readable declaration)."""
    try:
        with h5py.File(path, "r") as f:
            return {k: v[DIGEST_ATTR] for k, v in read_declaration(_text(f.attrs[DATASETS_ATTR])).items()}
    except Exception:  # noqa: BLE001
        return {}


def stage_file_key(path: Path) -> str | None:
    try:
        with h5py.File(path, "r") as f:
            return f.attrs.get("config_sha256")
    except OSError:
        return None


def _text(value):
    if isinstance(value, bytes):
        return value.decode(errors="replace")
    if isinstance(value, np.generic):
        return value.item()
    return value


def load_verified(path, key: str):
    """(StageData, None) for a sound stage file made by ``key``; (None, None) when the file is missing
    or was made by other settings (normal: recompute); (None, reason) when it is damaged."""
    try:
        f = h5py.File(path, "r")
    except FileNotFoundError:
        return None, None
    except Exception:  # noqa: BLE001  (truncated, not HDF5, unreadable)
        return None, "not a readable HDF5 file"
    try:
        with f:
            if _text(f.attrs.get("config_sha256")) != key:
                return None, None
            if _text(f.attrs.get("format")) != "fwdlook-stage":
                return None, "root attribute format is not fwdlook-stage"
            if _text(f.attrs.get("format_version")) != STAGE_FORMAT_VERSION:
                return None, f"root attribute format_version is not {STAGE_FORMAT_VERSION}"
            try:
                declared = read_declaration(_text(f.attrs[DATASETS_ATTR]))
            except Exception:  # noqa: BLE001
                return None, f"root attribute {DATASETS_ATTR} missing or malformed (no declaration)"
            out = StageData()
            found = dict(f.attrs.items())
            if attrs_digest(found) != _text(found.get(ATTRS_DIGEST_ATTR)):
                return None, (f"root attributes do not match their {ATTRS_DIGEST_ATTR} digest (an attribute "
                              f"edited, added or removed)")
            for k, v in found.items():
                if k not in PROVENANCE_KEYS:
                    out.attrs[k] = _text(v)
            for name, want in declared.items():
                ds = f.get(str(name))
                if not isinstance(ds, h5py.Dataset):
                    return None, f"/{name}: declared dataset missing"
                want_dtype, want_shape = want.get("dtype"), want.get("shape")
                want_digest, dims = want.get(DIGEST_ATTR), want.get("dims")
                if want_dtype is None or want_shape is None or want_digest is None or dims is None:
                    return None, f"/{name}: no dtype, shape, dims or {DIGEST_ATTR} declaration"
                if list(want_shape) != list(ds.shape):
                    return None, f"/{name}: shape {list(ds.shape)}, declared {want_shape}"
                if np.dtype(want_dtype) != ds.dtype:
                    return None, f"/{name}: dtype {ds.dtype}, declared {np.dtype(want_dtype)}"
                data = backing.read_dataset(ds)          # file-backed when out of core (io/backing.py)
                if digest(data) != want_digest:
                    return None, f"/{name}: data does not match its {DIGEST_ATTR} digest (bit rot or edited)"
                if len(dims) != np.ndim(data):
                    return None, f"/{name}: {len(dims)} dimension names for {np.ndim(data)} axes"
                out.vars[str(name)] = Var(data, tuple(dims), str(_text(ds.attrs.get("units", ""))),
                                          str(_text(ds.attrs.get("long_name", ""))))
            extra = [n for n, o in list(f.items()) if isinstance(o, h5py.Dataset) and n not in declared]
            if extra:
                return None, f"/{extra[0]}: dataset not declared"
            return out, None
    except Exception as exc:  # noqa: BLE001  (any read failure inside the file is damage)
        text = str(exc).splitlines()[0][:120] if str(exc) else ""
        return None, f"read failed ({exc.__class__.__name__}: {text})"
