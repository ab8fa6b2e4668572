"""Output locations: prepared once, never clobbering a user's file, every OS failure one line.

A command's outputs are checked BEFORE any work is done (:func:`prepare_file`, :func:`prepare_run_dir`,
:func:`prepare_report_dir`):

* a target is writable only if it is absent, or is fwdlook's own product of the same kind (a raw cube
  whose root attribute ``format`` is ``fwdlook-raw``; a run directory holding fwdlook's stage files,
  ``metrics.json`` with ``fwdlook_version``, a fwdlook ``image.h5`` or ``raw.h5``; a report directory
  whose ``report.md`` fwdlook wrote), or ``--overwrite`` is given;
* an output that is one of the command's inputs (same inode, whatever the spelling) is refused even
  with ``--overwrite``;
* the parent folders are created and a probe file is written and removed, so that a path under a
  regular file, on a read-only file system or in a folder without write permission fails at once;
* every ``OSError`` becomes :class:`BadInput` ``cannot write PATH: <strerror>`` (exit 2).

:class:`FailSafeSink` is the file object HDF5 writes through (``io.atomic_h5``): a write that the OS
refuses (``ENOSPC``, ``EDQUOT``, ``EIO``) is recorded and swallowed, so that HDF5 never sees a failed
write, closes cleanly (HDF5 cannot close a file whose flush failed: h5py then segfaults on the next
id deallocation), and the caller unlinks the partial file and reports the recorded error.
"""
from __future__ import annotations

import contextlib
import errno
import io
import json
import os
import tempfile
from pathlib import Path

from ..errors import BadInput

RAW_FORMAT = "fwdlook-raw"
RUN_FILES = ("scenario.yaml", "metrics.json", "image.h5", "image.png")
REPORT_FILES = ("report.md", "images.png", "real_beam.png", "range_profiles.png", "errors.png")
REPORT_TITLE = "# fwdlook report"
OVERWRITE_HINT = "remove it, choose another output, or pass --overwrite"


# ----------------------------------------------------------------------------------------------
# OSError -> one line
# ----------------------------------------------------------------------------------------------
def reason(exc: BaseException) -> str:
    """The OS's own words for a failed write (``No space left on device``), one line."""
    if isinstance(exc, OSError):
        if exc.strerror:
            return exc.strerror
        if exc.errno:
            return os.strerror(exc.errno)
    text = str(exc).splitlines()[0] if str(exc) else exc.__class__.__name__
    return text[:200]


def write_error(path, exc: BaseException) -> BadInput:
    return BadInput(f"cannot write {path}: {reason(exc)}")


@contextlib.contextmanager
def mapped_os_errors(path):
    """Turn an ``OSError`` raised in the block into ``BadInput("cannot write PATH: ...")``."""
    try:
        yield
    except OSError as exc:
        raise write_error(path, exc) from None


def make_parent(path) -> None:
    """Create the parent folders of ``path``; a regular file in the way is one BadInput line."""
    _make_dir(Path(path).parent, Path(path))


def _make_dir(folder: Path, target: Path) -> None:
    for p in (folder, *folder.parents):
        if p.exists() or p.is_symlink():
            if not p.is_dir():
                raise BadInput(f"cannot write {target}: {p} is not a directory")
            break
    with mapped_os_errors(target):
        folder.mkdir(parents=True, exist_ok=True)


def probe_writable(folder: Path, target) -> None:
    """Write and remove a probe file in ``folder``: EROFS, EACCES, ENOSPC show up now, not later."""
    with mapped_os_errors(target):
        fd, name = tempfile.mkstemp(dir=folder, prefix=".fwdlook-probe-")
        os.close(fd)
        os.unlink(name)


@contextlib.contextmanager
def atomic_path(path):
    """Yield ``NAME.partial.SUFFIX`` for a writer that takes a path (matplotlib); rename on success.

    On failure the partial file is removed and an ``OSError`` becomes one BadInput line.
    """
    path = Path(path)
    make_parent(path)
    tmp = path.with_name(path.stem + ".partial" + path.suffix)
    try:
        yield tmp
        with mapped_os_errors(path):
            os.replace(tmp, path)
    except OSError as exc:
        _unlink_quietly(tmp)
        raise write_error(path, exc) from None
    except BaseException:
        _unlink_quietly(tmp)
        raise


def _unlink_quietly(path) -> None:
    with contextlib.suppress(OSError):
        Path(path).unlink()


WRITE_PIECE_BYTES = 256 << 10
"""Large writes go to the OS in pieces of this size: measured here (ext4, a 22 MB stage array, 15
shuffled repeats), 7.6 ms median in 256 KiB pieces against 37 ms in one write(2) (1 MiB: 33 ms,
64 KiB: 9.0 ms); the copy into the page cache stays within the CPU caches."""


class FailSafeSink(io.RawIOBase):
    """A read/write file for h5py's file-object driver that never reports a failed write to HDF5.

    The first ``OSError`` of a write or truncate is kept in :attr:`error`; that write and every later
    one are dropped (reported as done).  The caller must check :attr:`error` after closing the HDF5
    file, discard the partial file and report the error.
    """

    def __init__(self, path):
        super().__init__()
        self.path = Path(path)
        self._f = open(self.path, "w+b", buffering=0)  # noqa: SIM115 (closed in close())
        self.error: OSError | None = None

    def readable(self):
        return True

    def writable(self):
        return True

    def seekable(self):
        return True

    def readinto(self, buffer):
        return self._f.readinto(buffer)

    def write(self, buffer):
        n = memoryview(buffer).nbytes
        if self.error is None:
            try:
                view = memoryview(buffer).cast("B")
                done = 0
                while done < n:               # a raw write may be short: finish it or fail
                    k = self._f.write(view[done:done + WRITE_PIECE_BYTES])
                    if not k:
                        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
                    done += k
            except OSError as exc:
                self.error = exc
        return n

    def seek(self, offset, whence=os.SEEK_SET):
        return self._f.seek(offset, whence)

    def tell(self):
        return self._f.tell()

    def truncate(self, size=None):
        if self.error is None:
            try:
                return self._f.truncate(size)
            except OSError as exc:
                self.error = exc
        return self.tell() if size is None else size

    def flush(self):
        pass

    def close(self):
        if not self.closed:
            try:
                self._f.close()
            except OSError as exc:          # a late write-back failure (NFS, quota)
                self.error = self.error or exc
            super().close()


# ----------------------------------------------------------------------------------------------
# What counts as fwdlook's own product
# ----------------------------------------------------------------------------------------------
def h5_format(path) -> str | None:
    """Root attribute ``format`` of an HDF5 file, or None when it is not a readable HDF5 file."""
    try:
        import h5py

        with h5py.File(path, "r") as f:
            fmt = f.attrs.get("format")
    except Exception:  # noqa: BLE001  (anything unreadable is simply not ours)
        return None
    if isinstance(fmt, bytes):
        fmt = fmt.decode(errors="replace")
    return fmt if isinstance(fmt, str) else None


def is_fwdlook_metrics(path) -> bool:
    try:
        with open(path, "rb") as fh:
            data = json.loads(fh.read(64 * 2**20))
    except Exception:  # noqa: BLE001
        return False
    return isinstance(data, dict) and "fwdlook_version" in data


def is_fwdlook_run_dir(folder) -> bool:
    """A folder fwdlook ran in: its metrics, image, raw cube or any stage file carries fwdlook's mark."""
    d = Path(folder)
    if is_fwdlook_metrics(d / "metrics.json"):
        return True
    if h5_format(d / "image.h5") == "fwdlook-image" or h5_format(d / "raw.h5") == RAW_FORMAT:
        return True
    stages = d / "stages"
    if stages.is_dir():
        return any(h5_format(p) == "fwdlook-stage" for p in sorted(stages.glob("*.h5"))[:64])
    return False


def is_fwdlook_report(folder) -> bool:
    try:
        with open(Path(folder) / "report.md", "rb") as fh:
            head = fh.read(len(REPORT_TITLE) + 1).decode("utf-8", errors="replace")
    except OSError:
        return False
    return head.rstrip("\n") == REPORT_TITLE


# ----------------------------------------------------------------------------------------------
# Inputs are never outputs
# ----------------------------------------------------------------------------------------------
def _same(a: Path, b) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _refuse_inputs(target: Path, inputs, what: str) -> None:
    if not (target.exists() or target.is_symlink()):
        return
    for inp in inputs or ():
        if inp and _same(target, inp):
            raise BadInput(f"{target}: is this command's input {inp}; fwdlook never writes over an input "
                           f"({what}); choose another output")


# ----------------------------------------------------------------------------------------------
# The three kinds of output location
# ----------------------------------------------------------------------------------------------
def prepare_file(path, *, inputs=(), overwrite: bool = False, kind: str = "raw") -> Path:
    """A raw-cube output file: absent, fwdlook's own raw cube, or ``overwrite``; never an input."""
    target = Path(path)
    _refuse_inputs(target, inputs, "raw cube output")
    if target.is_dir():
        raise BadInput(f"cannot write {target}: is a directory; expected the path of a raw cube file")
    if (target.exists() or target.is_symlink()) and not overwrite:
        fmt = h5_format(target)
        if fmt != RAW_FORMAT:
            what = "not an HDF5 file" if fmt is None else f"an HDF5 file with / attribute format = {fmt[:40]!r}"
            raise BadInput(f"{target}: exists and is not a fwdlook raw cube ({what}); refusing to "
                           f"overwrite it; {OVERWRITE_HINT}")
    make_parent(target)
    probe_writable(target.parent, target)
    return target


def prepare_run_dir(path, *, inputs=(), overwrite: bool = False, writes_raw: bool = False) -> Path:
    """A run directory: absent, empty, fwdlook's own run, one holding none of the files a run writes,
    or ``overwrite``; an input inside it that the run would replace is refused always."""
    d = Path(path)
    if (d.exists() or d.is_symlink()) and not d.is_dir():
        raise BadInput(f"cannot write {d}: exists and is not a directory; expected a run directory")
    names = RUN_FILES + (("raw.h5",) if writes_raw else ())
    if d.is_dir():
        for name in names:
            _refuse_inputs(d / name, inputs, f"run directory file {name}")
        stages = d / "stages"
        if stages.is_dir():
            for inp in inputs or ():
                if inp and Path(inp).exists() and any(_same(p, inp) for p in stages.iterdir()):
                    raise BadInput(f"{inp}: is inside {stages}, which this run rewrites; fwdlook never "
                                   f"writes over an input; choose another run directory")
        if not overwrite and not is_fwdlook_run_dir(d):
            present = [n for n in names if (d / n).exists() or (d / n).is_symlink()]
            if (stages.exists() or stages.is_symlink()) and any(
                    not q.name.endswith(".partial") for q in _iter_quiet(stages)):
                present.append("stages/")
            if present:
                raise BadInput(f"{d}: not a fwdlook run directory, and it holds {present[0]}, which a run "
                               f"would replace; refusing to overwrite it; {OVERWRITE_HINT}")
    _make_dir(d, d)
    _make_dir(d / "stages", d / "stages")
    probe_writable(d, d)
    return d


def _iter_quiet(folder: Path):
    try:
        return list(folder.iterdir()) if folder.is_dir() else [folder]
    except OSError:
        return [folder]


def prepare_report_dir(path, *, inputs=(), overwrite: bool = False) -> Path:
    """A report directory: absent, fwdlook's own report, one holding none of the report's files, or
    ``overwrite``."""
    d = Path(path)
    if (d.exists() or d.is_symlink()) and not d.is_dir():
        raise BadInput(f"cannot write {d}: exists and is not a directory; expected a report directory")
    if d.is_dir():
        for name in REPORT_FILES:
            _refuse_inputs(d / name, inputs, f"report file {name}")
        if not overwrite and not is_fwdlook_report(d):
            present = [n for n in REPORT_FILES if (d / n).exists() or (d / n).is_symlink()]
            if present:
                raise BadInput(f"{d / present[0]}: exists and was not written by fwdlook report; refusing "
                               f"to overwrite it; {OVERWRITE_HINT}")
    _make_dir(d, d)
    probe_writable(d, d)
    return d
