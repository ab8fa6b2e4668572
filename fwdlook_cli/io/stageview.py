"""Stage files that are views: re-layout stages (``decimate``, ``regroup``) only reshape arrays the
previous stage file already holds, so their file stores those arrays as HDF5 *virtual datasets* mapped
onto the previous file (row-major order is the same; one mapping per array) instead of a second copy.
The file keeps its coordinates, settings and hashes like any stage file, and records which file it views
and that file's key (``view_source``, ``view_source_sha256``): a view whose source is missing or was
rewritten with another key is not reused (:func:`view_file_key`), since HDF5 would read fill values.
"""
from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

from . import backing
from .stagefile import stage_file_key


VIEW_MIN_BYTES = 128 << 10     # smaller arrays are copied: a mapping costs more than their bytes


def reshaped_views(out, previous, min_bytes: int = VIEW_MIN_BYTES) -> dict:
    """{name: source name} of ``out``'s non-coordinate arrays of ``min_bytes`` or more that are reshapes
    (same bytes, same dtype, C order) of an array of the same name in ``previous``.  The smaller ones
    (the INS context: positions, velocities, scan angles) are written again: a virtual dataset costs
    HDF5 about 0.26 ms to create (its layout 0.14 ms, the dataset 0.12 ms; thirty-second round), a
    60 kB copy 0.1 ms, so copies pay up to about 128 KiB."""
    found = {}
    for name, var in out.vars.items():
        if var.dims == (name,) or name not in previous.vars or var.data.nbytes < min_bytes:
            continue
        src = previous.vars[name].data
        a = var.data
        if (a.dtype == src.dtype and a.size == src.size and a.flags.c_contiguous and src.flags.c_contiguous
                and np.shares_memory(a, src) and a.__array_interface__["data"][0] == src.__array_interface__["data"][0]):
            found[name] = name
    return found


def virtual_layout(source_file: Path, source_name: str, shape, dtype, source_shape):
    """A virtual layout of ``shape`` whose row-major elements are those of ``source_file:/source_name``."""
    layout = h5py.VirtualLayout(shape=tuple(shape), dtype=dtype)
    layout[...] = h5py.VirtualSource(Path(source_file).name, source_name, shape=tuple(source_shape))[...]
    return layout


def view_file_key(path: Path) -> str | None:
    """The stage file's key when it can be trusted: as ``stage_file_key``, and for a view, only while
    its source file exists with the key recorded when the view was written."""
    key = stage_file_key(path)
    if key is None:
        return None
    try:
        with h5py.File(path, "r") as f:
            source = f.attrs.get("view_source")
            source_key = f.attrs.get("view_source_sha256")
    except OSError:
        return None
    if source is None:
        return key
    return key if stage_file_key(Path(path).parent / str(source)) == source_key else None


def _mapped(ds, path):
    """A read-only memory map of an open, uncompressed, contiguous dataset (None for another layout)."""
    if ds.chunks is not None or ds.is_virtual:
        return None
    offset = ds.id.get_offset()
    return None if offset is None else np.memmap(path, dtype=ds.dtype, mode="r", offset=offset, shape=ds.shape)


def read_stage_mapped(path: Path, min_bytes: int = 1 << 20):
    """A stage file as :class:`StageData` whose large contiguous arrays are read-only memory maps of the
    file (``np.memmap`` at the dataset's offset: HDF5 stores an uncompressed contiguous dataset as its
    raw bytes), so a reader that looks at a few slices (the dwell metrics) pages in only those, with no
    copy of the rest; other arrays are read.  The maps stay valid after the file is closed or removed."""
    from .stagefile import StageData, Var, _text, declared_dims, dims_of

    with h5py.File(path, "r") as f:
        out = StageData(attrs=_carried_attrs(f))
        declared = declared_dims(f)
        for name, ds in list(f.items()):
            if not isinstance(ds, h5py.Dataset):
                continue
            data = _mapped(ds, path) if ds.size * ds.dtype.itemsize >= min_bytes else None
            data = backing.read_dataset(ds) if data is None else data     # file-backed out of core
            out.vars[name] = Var(data, dims_of(ds, name, declared), str(_text(ds.attrs.get("units", ""))),
                                 str(_text(ds.attrs.get("long_name", ""))))
    return out


def _carried_attrs(f) -> dict:
    """A stage file's root attributes other than its provenance, as Python values."""
    from .stagefile import PROVENANCE_KEYS

    return {k: v.decode() if isinstance(v, bytes) else (v.item() if isinstance(v, np.generic) else v)
            for k, v in list(f.attrs.items()) if k not in PROVENANCE_KEYS}
