"""File-backed arrays for ``--out-of-core``: the chain's cube-sized arrays held in unnamed scratch files
instead of anonymous memory.

Inside :func:`file_backed`, :func:`empty` returns an array of at least :data:`MIN_BYTES` as a shared
memory map of an unnamed temporary file in the scratch directory (``tempfile.TemporaryFile``: on Linux
an ``O_TMPFILE`` that never has a name, so nothing is left behind however the process ends; its disk
space is freed when the last view of the array goes).  The kernel then holds as much of the array in
its page cache as memory allows and writes the rest to the file, so a chain whose stages work in blocks
(every stage does: keystone over range-frequency columns, curvature over pulses, Doppler and image
over CPIs) runs with its anonymous memory bounded by those blocks, on cubes larger than the machine's
memory.  Outside it, :func:`empty` is ``np.empty``.  The numbers are the same either way: only where
the bytes live changes.

The state is process-wide (one chain runs at a time in a command; the stages' worker threads see it
too), set and restored by :func:`file_backed`.
"""
from __future__ import annotations

import errno
import os
import tempfile
from contextlib import ExitStack, contextmanager
from pathlib import Path

import numpy as np

from ..dsp.cgroups import own_cgroup_folders
from ..errors import BadInput
from ..limits import gib

IN_MEMORY_X_CUBE = 3.0       # an in-memory run's peak above its base, in cubes (README: Memory, CPI imaging)
SIMULATE_X_CUBE = 1.1        # simulating alone: the cube and blocks of 32 pulses (README: --out-of-core)
MIN_BYTES = 1 << 20          # smaller arrays stay in memory (the page cache would hold them anyway)
BLOCK_BYTES = 8 << 20        # the bytes a file-backed stage reads or writes per block

_scratch_dir: Path | None = None
_min_bytes: int = MIN_BYTES
_map_sources: bool = False


def active() -> bool:
    """Whether cube-sized arrays are file-backed now."""
    return _scratch_dir is not None


@contextmanager
def file_backed(directory, min_bytes: int = MIN_BYTES):
    """Within the block, :func:`empty` puts arrays of ``min_bytes`` or more in scratch files under
    ``directory`` (created if missing)."""
    global _scratch_dir, _min_bytes
    directory = Path(directory)
    try:                                  # refused here, in one line, not at the first big array
        directory.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=directory).close()
    except OSError as exc:
        raise BadInput(f"--out-of-core: scratch directory {directory}: {exc.strerror or exc}; allowed: a "
                       f"writable directory (the run directory's parent)") from None
    before = (_scratch_dir, _min_bytes)
    _scratch_dir, _min_bytes = directory, int(min_bytes)
    try:
        yield directory
    finally:
        _scratch_dir, _min_bytes = before


@contextmanager
def mapped_sources():
    """Within the block, :func:`read_dataset` maps a large dataset stored as one plain run of bytes
    (:func:`map_in_place`) read-only where it lies in its file, instead of reading it: no copy in memory
    nor in a scratch file, and pages the kernel can drop at any time (they are the file's, clean)."""
    global _map_sources
    before, _map_sources = _map_sources, True
    try:
        yield
    finally:
        _map_sources = before


@contextmanager
def read_without_holding(directory=None):
    """For commands that only read a cube (``info``, ``validate``): its large datasets mapped where they
    lie (:func:`mapped_sources`), else copied block by block into unnamed scratch files in
    ``directory`` (the temporary directory by default): no array of the cube held in memory.  Where
    that directory takes no file, the datasets that cannot be mapped are read into memory as before."""
    with ExitStack() as stack:
        try:
            stack.enter_context(file_backed(tempfile.gettempdir() if directory is None else directory))
        except BadInput:
            pass
        stack.enter_context(mapped_sources())
        yield


def map_in_place(ds):
    """A read-only ``np.memmap`` of an open HDF5 dataset's bytes in its own file, where HDF5 stores them
    as one plain run (contiguous layout, no filter, no external storage, allocated, a plain file); else
    None."""
    try:
        dcpl = ds.id.get_create_plist()
        offset = ds.id.get_offset()
        plain = (ds.chunks is None and offset is not None and dcpl.get_nfilters() == 0
                 and dcpl.get_external_count() == 0 and ds.file.driver == "sec2" and ds.shape
                 and not np.dtype(ds.dtype).hasobject)
        if not plain:
            return None
        return np.memmap(ds.file.filename, dtype=ds.dtype, mode="r", offset=offset, shape=tuple(ds.shape))
    except (AttributeError, ValueError, OSError, TypeError):
        return None


@contextmanager
def in_memory():
    """Within the block, :func:`empty` is ``np.empty`` again (a stage's own bounded work buffers)."""
    global _scratch_dir
    before, _scratch_dir = _scratch_dir, None
    try:
        yield
    finally:
        _scratch_dir = before


def empty(shape, dtype, *, fill=np.empty) -> np.ndarray:
    """``np.empty(shape, dtype)``, file-backed inside :func:`file_backed` when it is large enough
    (its contents are then zeros, as a new file's are).  ``fill``: what makes the in-memory array
    (:func:`zeros` passes ``np.zeros``)."""
    shape = tuple(int(n) for n in (shape if np.ndim(shape) else (shape,)))
    dtype = np.dtype(dtype)
    nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    if _scratch_dir is None or nbytes < _min_bytes or nbytes == 0:
        return fill(shape, dtype)
    with tempfile.TemporaryFile(dir=_scratch_dir, prefix=".fwdlook-scratch-") as f:
        # the file's blocks reserved, not a sparse file: a page written into a full file system through a
        # map is a SIGBUS (the command had died by it, no word), where this refuses in one line
        try:
            os.posix_fallocate(f.fileno(), 0, nbytes)
        except OSError as exc:
            if exc.errno not in (errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL):
                raise BadInput(f"cannot write {_scratch_dir}: {exc.strerror or exc} (--out-of-core scratch "
                               f"of {nbytes / 2**20:.0f} MiB for an array {shape})") from None
            f.truncate(nbytes)                # a file system without it: sparse, as before
        # the map holds the file open (its own descriptor): the file lives as long as the array
        return np.memmap(f, dtype=dtype, mode="r+", shape=shape)


def zeros(shape, dtype) -> np.ndarray:
    """``np.zeros(shape, dtype)``, file-backed inside :func:`file_backed` when it is large enough (a new
    file reads as zeros): an array that is filled in parts, some never written."""
    return empty(shape, dtype, fill=np.zeros)


def rows_per_block(row_bytes: int, block_bytes: int | None = None) -> int:
    """How many rows of ``row_bytes`` a file-backed stage takes per block (of :data:`BLOCK_BYTES`, read
    when called)."""
    return max(1, int(BLOCK_BYTES if block_bytes is None else block_bytes) // max(1, int(row_bytes)))


def map_blocks(fn, n_rows: int, shape, dtype, row_bytes: int) -> np.ndarray:
    """An array of ``shape`` (file-backed when large, inside :func:`file_backed`) whose rows ``s`` are
    ``fn(s)``, for slices ``s`` of :func:`rows_per_block` rows of ``row_bytes`` each: a stage's
    element-wise or per-row work done block by block, the same numbers as on the whole."""
    out = empty(shape, dtype)
    step = rows_per_block(row_bytes)
    for a in range(0, int(n_rows), step):
        s = slice(a, min(a + step, int(n_rows)))
        out[s] = fn(s)
    return out


def read_dataset(ds):
    """All of an open HDF5 dataset (or any array-like with ``shape``, ``dtype`` and slicing): ``ds[()]``,
    unchanged; inside :func:`mapped_sources`, when large and stored plainly, its bytes mapped where they
    lie (:func:`map_in_place`); inside :func:`file_backed`, when large, block by block of rows into a
    file-backed array (an out-of-core run's cube and stage inputs: no copy of the whole in memory)."""
    shape = tuple(ds.shape or ())
    nbytes = int(np.prod(shape, dtype=np.int64)) * np.dtype(ds.dtype).itemsize
    if _map_sources and shape and nbytes >= _min_bytes:
        mapped = map_in_place(ds)
        if mapped is not None:
            return mapped
    if _scratch_dir is None or not shape or nbytes < _min_bytes or np.dtype(ds.dtype).hasobject:
        return ds[()]
    return map_blocks(lambda s: ds[s], shape[0], shape, ds.dtype, nbytes // max(1, shape[0]))


def count_nonfinite(a) -> int:
    """NaN and Inf values in ``a``, counted block by block of rows (no array-sized mask)."""
    a = np.asarray(a)
    if a.ndim == 0:
        return int(not np.isfinite(a))
    step = rows_per_block(a[0].nbytes if a.shape[0] else 1)
    return sum(int(a[s:s + step].size - np.count_nonzero(np.isfinite(a[s:s + step])))
               for s in range(0, a.shape[0], step))


def memory_available_bytes(proc: str = "/proc") -> int | None:
    """The memory available to new work in this process, or None: the kernel's estimate
    (``MemAvailable``), or the room under the memory limit of the process's cgroup or of an ancestor
    (:func:`cgroup_room_bytes`: a container's, a batch job's) where that is smaller."""
    available = None
    try:
        with open(Path(proc, "meminfo"), encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    available = int(line.split()[1]) * 1024
                    break
    except (OSError, ValueError, IndexError):
        pass
    room = cgroup_room_bytes(proc)
    if room is None:
        return available
    return room if available is None else min(available, room)


_NO_LIMIT = 1 << 60          # cgroup v1 writes "no limit" as a number near 2^63


def _read_number(path: Path) -> int | None:
    try:
        text = path.read_text(encoding="ascii").strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None           # v2 writes "max" for no limit


def _stat_field(path: Path, names: tuple) -> int:
    """The first of ``names`` in a cgroup's ``memory.stat`` (0 where absent or unreadable)."""
    try:
        fields = dict(line.split() for line in path.read_text(encoding="ascii").splitlines() if line.count(" ") == 1)
    except (OSError, ValueError):
        return 0
    for name in names:
        if fields.get(name, "").isdigit():
            return int(fields[name])
    return 0


def cgroup_room_bytes(proc: str = "/proc") -> int | None:
    """Room left under the memory limits of this process's memory cgroup and of each ancestor visible
    in a cgroup mount: the smallest of limit - (usage - inactive page cache), the kernel's reclaimable
    file pages counted as free as ``MemAvailable`` counts them.  cgroup v2 (``memory.max``,
    ``memory.current``, ``inactive_file``) and v1 (``memory.limit_in_bytes``, ``memory.usage_in_bytes``,
    ``total_inactive_file``); the folders from :func:`dsp.cgroups.own_cgroup_folders`, so a container
    whose mount root is its own cgroup reads its own limit.  None where no limit is set or nothing can
    be read."""
    rooms = []
    for d, v2 in own_cgroup_folders("memory", proc):   # the own cgroup, then each ancestor
        limit = _read_number(d / ("memory.max" if v2 else "memory.limit_in_bytes"))
        usage = _read_number(d / ("memory.current" if v2 else "memory.usage_in_bytes"))
        if limit is None or usage is None or limit >= _NO_LIMIT:
            continue
        reclaimable = _stat_field(d / "memory.stat", ("inactive_file",) if v2 else
                                  ("total_inactive_file", "inactive_file"))
        rooms.append(max(0, limit - max(0, usage - reclaimable)))
    return min(rooms) if rooms else None


def memory_hint(cube_bytes: int, x_cube: float = IN_MEMORY_X_CUBE, doing: str = "processing") -> str | None:
    """One line for a cube that an in-memory run would likely not fit (None when it fits, when
    :func:`file_backed` is on, or when the available memory is unknown).  ``x_cube``: what the work
    needs in memory, in cubes (:data:`IN_MEMORY_X_CUBE` for the chain, :data:`SIMULATE_X_CUBE` to
    simulate alone); ``doing``: the work, as the line names it."""
    available = None if active() else memory_available_bytes()
    need = x_cube * cube_bytes
    if available is None or need <= available:
        return None
    return (f"{doing} this {gib(cube_bytes)} cube in memory needs about {gib(need)} and {gib(available)} "
            f"is available: --out-of-core holds it in scratch files instead")
