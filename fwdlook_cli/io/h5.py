"""HDF5 and text writing at the edges: atomic writes, datasets with units and long names, dimension scales.

Every file is written to ``NAME.partial`` (claimed by ``io.partial.claim_partial``: never through a link,
never over a file fwdlook did not make) and renamed into place with ``os.replace``, so a failed or
interrupted command never leaves a file that looks complete.
"""
from __future__ import annotations

import contextlib
import datetime as _dt
import functools
import json
import os
from pathlib import Path

import h5py
import numpy as np

from .. import __version__
from . import h5native, signals
from .partial import claim_partial_into

_SCALAR = None
_TYPES: dict = {}


def _attr_type(kind: str):
    """(numpy dtype, file type, memory type) of an attribute kind, as ``h5py.AttributeManager.create``."""
    types = _TYPES.get(kind)
    if types is None:
        dt = h5py.string_dtype("utf-8") if kind == "str" else np.dtype("<f8" if kind == "float" else "<i8")
        types = _TYPES[kind] = (dt, h5py.h5t.py_create(dt, logical=True), h5py.h5t.py_create(dt))
    return types


def set_attrs(obj, attrs: dict) -> None:
    """``obj.attrs.update(attrs)`` through HDF5's own calls for str, float and int values (the same
    types h5py writes: variable-length UTF-8 strings, float64, int64), at about a third of the time of
    ``obj.attrs[k] = v`` (26 against 90 us per attribute here); other values, and names already
    present, go through h5py."""
    global _SCALAR
    if _SCALAR is None:
        _SCALAR = h5py.h5s.create(h5py.h5s.SCALAR)
    for name, value in attrs.items():
        kind = ("str" if isinstance(value, str) else "float" if isinstance(value, float)
                else "int" if isinstance(value, int) and not isinstance(value, bool) and -2**63 <= value < 2**63
                else None)
        if kind is None:
            obj.attrs[name] = value
            continue
        dt, ftype, mtype = _attr_type(kind)
        if h5native.enabled():          # the same calls without the GIL (io/h5native.py)
            # a str from a char* in the file's own C string type (h5py's memory type for str is its
            # Python-object type, converted by h5py's own routine)
            if not h5native.write_scalar_attr(obj.id.id, name, kind, value, ftype.id,
                                              (ftype if kind == "str" else mtype).id, _SCALAR.id):
                obj.attrs[name] = value             # already there: h5py replaces it
            continue
        try:
            attr = h5py.h5a.create(obj.id, name.encode(), ftype, _SCALAR)
        except (OSError, KeyError, RuntimeError, ValueError):   # already there: h5py replaces it
            obj.attrs[name] = value
            continue
        attr.write(np.array(value, dtype=dt), mtype=mtype)


@contextlib.contextmanager
def atomic_h5(path: str | Path, *, own_partial: bool = False):
    """Open ``path.partial`` for writing; rename to ``path`` only if the block succeeds.  The partial name
    is claimed by ``io.partial.claim_partial`` (never through a link, never over a file fwdlook did not
    make: ``own_partial``, a stage file's, replaces a regular file there, a killed write's leftover).

    HDF5 writes through :class:`outputs.FailSafeSink`, so a full disk or any refused write never
    reaches HDF5 (which cannot close a file whose flush failed); the partial file is removed and the
    OS's error becomes one line, ``cannot write PATH: No space left on device`` (exit 2).
    """
    from .outputs import FailSafeSink, make_parent, write_error

    path = Path(path)
    make_parent(path)
    claimed: list = []
    try:           # claimed with signals held, so that one arriving meanwhile finds the name to remove
        tmp = signals.call_held(claim_partial_into, claimed, path.with_name(path.name + ".partial"),
                                replace_regular=own_partial)
        signals.raise_pending()
        sink = FailSafeSink(tmp)
    except BaseException as exc:       # (a signal included) the claimed name removed again
        _discard(path, claimed[0] if claimed else None, exc)
    done = False
    f = None
    try:
        try:
            # opened and closed with Ctrl-C and SIGTERM held (io/signals.py): an exception inside h5py's
            # open would leave HDF5 holding the file with nothing to close it before the sink
            f = signals.call_held(h5py.File, sink, "w")
            signals.raise_pending()
            set_attrs(f, {"software": "fwdlook", "software_version": __version__,
                          "created_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")})
            yield f
            if h5native.enabled():          # the metadata written out without the GIL; h5py's
                h5native.flush(f.id.id)     # close then finds nothing left to write
        finally:
            if f is not None:
                signals.call_held(f.close)
            sink.close()
            signals.raise_pending()         # a signal kept while closing: before the rename, not after
        if sink.error is not None:
            raise write_error(path, sink.error)
        try:
            os.replace(tmp, path)
        except OSError as exc:
            raise write_error(path, exc) from None
        done = True
    except BaseException:
        if sink.error is not None and not done:      # a refused write explains whatever followed
            with contextlib.suppress(FileNotFoundError, OSError):
                tmp.unlink()
            raise write_error(path, sink.error) from None
        raise
    finally:
        if not done:
            with contextlib.suppress(OSError):
                tmp.unlink()


def atomic_write_text(path: str | Path, text: str) -> None:
    from .outputs import make_parent

    path = Path(path)
    make_parent(path)
    claimed: list = []
    try:
        tmp = signals.call_held(claim_partial_into, claimed, path.with_name(path.name + ".partial"))
        signals.raise_pending()
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, path)
    except BaseException as exc:       # (a signal included) no partial file left
        _discard(path, claimed[0] if claimed else None, exc)


def _discard(path, tmp, exc: BaseException):
    """A failed write's partial file ``tmp`` (if claimed) removed; an OSError raised as one line naming
    ``path``, anything else (a signal) as it is."""
    from .outputs import write_error

    if tmp is not None:
        with contextlib.suppress(OSError):
            tmp.unlink()
    if isinstance(exc, OSError):
        raise write_error(path, exc) from None
    raise exc


def json_text(obj: dict, allow_nan: bool = False) -> str:
    """JSON of a dict laid out for reading: one top-level key per line, a dict value's keys one per
    line and a list of records one record per line (``metrics.json``: a target per line).  Every piece
    goes through ``json.dumps`` without ``indent``, i.e. the C encoder: ``indent=1`` takes the pure-Python
    encoder, 3.4 against about 1.3 ms for the paper run's metrics.  ``json.loads`` gives the same object."""
    enc = functools.partial(json.dumps, allow_nan=allow_nan)

    def value(v, pad):
        if isinstance(v, dict) and v:
            return "{\n" + ",\n".join(f"{pad}  {enc(str(k))}: {enc(x)}" for k, x in v.items()) + f"\n{pad}}}"
        if isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            return "[\n" + ",\n".join(f"{pad}  {enc(x)}" for x in v) + f"\n{pad}]"
        return enc(v)

    return "{\n" + ",\n".join(f" {enc(str(k))}: {value(v, ' ')}" for k, v in obj.items()) + "\n}\n"


def put(group: h5py.Group, name: str, data, units: str, long_name: str, *, dims=(), **kw):
    """Create a dataset with its ``units`` and ``long_name`` and attach dimension scales ``dims``."""
    ds = group.create_dataset(name, data=data, **kw)
    set_attrs(ds, {"units": units, "long_name": long_name})
    for axis, scale in enumerate(dims):
        if scale is not None:
            ds.dims[axis].attach_scale(scale)
    return ds


def put_scale(group: h5py.Group, name: str, data, units: str, long_name: str):
    ds = put(group, name, data, units, long_name)
    ds.make_scale(name)
    return ds


_POOL = (None, None)


def worker_pool():
    """One worker thread for work that releases the GIL (SHA-256 digests, zlib) beside the main thread;
    a new one in a forked child (the parent's thread does not exist there: its pool would never run)."""
    global _POOL
    pool, pid = _POOL
    if pool is None or pid != os.getpid():
        from concurrent.futures import ThreadPoolExecutor

        pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="fwdlook-io")
        _POOL = (pool, os.getpid())
    return pool


def deflate_rle(buffer, level: int) -> bytes:
    """``zlib.compress(buffer, level)`` with zlib's run-length strategy (``Z_RLE``): a zlib stream that
    HDF5's deflate filter (any zlib decoder) reads as it reads the default strategy's.  The images'
    chunks are runs of zeros around float32 values whose low bytes do not repeat; the default
    strategy's search for matches in those values finds little.  Measured on the paper run's image.h5
    grids (image, real beam, ground image; medians of seven): 7.3 ms and 561 kB with ``Z_RLE`` against
    13.1 ms and 581 kB with the default strategy at level 1."""
    import zlib

    packer = zlib.compressobj(level, zlib.DEFLATED, zlib.MAX_WBITS, 8, zlib.Z_RLE)
    return packer.compress(buffer) + packer.flush()


class GzipChunks:
    """The chunks of ``rows_per_chunk`` full rows of a 2-D array that hold a non-zero byte, deflated
    (zlib ``level``, run-length strategy: :func:`deflate_rle`; HDF5's deflate filter reads them) in the
    worker thread from construction on, so that the compression runs beside whatever the caller does
    next; :func:`put_sparse_gzip` writes them."""

    def __init__(self, data, rows_per_chunk: int = 16, level: int = 1):
        a = np.ascontiguousarray(data)
        if a.ndim != 2 or a.size == 0:
            raise ValueError(f"GzipChunks: a non-empty 2-D array, got shape {a.shape}")
        self.shape, self.dtype, self.level = a.shape, a.dtype, level
        self.rows = max(1, min(int(rows_per_chunk), a.shape[0]))
        flat = a.view(np.uint8).reshape(a.shape[0], -1)
        pool, self.jobs = worker_pool(), []
        for i0 in range(0, a.shape[0], self.rows):
            block = flat[i0:i0 + self.rows]
            if not block.any():
                continue                                  # an all-zero chunk is not written
            if block.shape[0] < self.rows:                # an edge chunk is stored at full size
                block = np.concatenate([block, np.zeros((self.rows - block.shape[0], block.shape[1]), np.uint8)])
            self.jobs.append((i0, pool.submit(deflate_rle, memoryview(block).cast("B"), level)))


def put_sparse_gzip(group: h5py.Group, name: str, data, units: str, long_name: str, *, dims=(),
                    rows_per_chunk: int = 16, level: int = 1):
    """A 2-D dataset stored gzip-compressed (HDF5's deflate filter, ``level``) in chunks of
    ``rows_per_chunk`` full rows, of which only the chunks holding a non-zero byte are written: an
    unwritten chunk reads as the fill value 0, so every reader sees the same array, bit for bit.
    ``data``: the array, or its :class:`GzipChunks` (compressed beforehand, beside other work).
    The chunks are compressed by ``zlib`` and handed to HDF5 as they are (``write_direct_chunk``)."""
    if not isinstance(data, GzipChunks):
        a = np.asarray(data)
        if a.ndim != 2 or a.size == 0:
            return put(group, name, a, units, long_name, dims=dims, compression="gzip", compression_opts=level)
        data = GzipChunks(a, rows_per_chunk, level)
    ds = group.create_dataset(name, shape=data.shape, dtype=data.dtype, chunks=(data.rows, data.shape[1]),
                              compression="gzip", compression_opts=data.level, fillvalue=np.zeros((), data.dtype))
    for i0, job in data.jobs:
        ds.id.write_direct_chunk((i0, 0), job.result())
    set_attrs(ds, {"units": units, "long_name": long_name})
    for axis, scale in enumerate(dims):
        if scale is not None:
            ds.dims[axis].attach_scale(scale)
    return ds
