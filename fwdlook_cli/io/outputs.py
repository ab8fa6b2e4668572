"""Output locations: prepared once, never clobbering a user's file, every OS failure one line.

A command's outputs are checked BEFORE any work is done (:func:`prepare_file`, :func:`prepare_run_dir`,
:func:`prepare_report_dir`):

* a target is writable only if it is absent, or is fwdlook's own product of the same kind (a raw cube
  whose root attribute ``format`` is ``fwdlook-raw``; a run directory holding fwdlook's stage files,
  ``metrics.json`` with ``fwdlook_version``, a fwdlook ``image.h5`` or ``raw.h5``; a report directory
  whose ``report.md`` fwdlook wrote), or ``--overwrite`` is given;
* an output that is one of the command's inputs (same inode, whatever the spelling) is refused always;
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
from ..limits import shown
from . import signals
from .partial import claim_partial_into
from .pending import STAGED_PREFIX

RAW_FORMAT = "fwdlook-raw"
RUN_FILES = ("scenario.yaml", "metrics.json", "image.h5", "image.png")
REPORT_FILES = ("report.md", "index.html", "images.png", "real_beam.png", "range_profiles.png", "errors.png")
SWEEP_FILES = ("summary.json", "summary.csv", "summary.md", "speed_accuracy.png", "stability.png")
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


_MADE_DIRS: dict = {}      # output folder -> the folders this process made for it (deepest first)


def _missing_folders(folder: Path, target: Path) -> list:
    """The folders of ``folder``'s path that do not exist yet (deepest first); BadInput where the first
    that exists is not a folder (a file on the path)."""
    missing = []
    for p in (folder, *folder.parents):
        if p.exists() or p.is_symlink():
            if not p.is_dir():
                raise BadInput(f"cannot write {target}: {p} is not a directory")
            break
        missing.append(p)
    return missing


def _make_dir(folder: Path, target: Path) -> None:
    missing = _missing_folders(folder, target)
    with mapped_os_errors(target):
        folder.mkdir(parents=True, exist_ok=True)
    if missing:
        _MADE_DIRS[str(folder)] = missing


def unmake_dirs(folder) -> None:
    """A command refused after it made ``folder`` (``run --raw`` of a missing cube, a sweep's bad point):
    the folders it made go again where they hold nothing (the lock file and empty ``stages``/``raw``
    aside), so that a refusal leaves nothing behind."""
    made = _MADE_DIRS.pop(str(folder), None)
    if not made:
        return
    for sub in ("stages", "raw"):
        with contextlib.suppress(OSError):
            (Path(folder) / sub).rmdir()
    for p in made:
        with contextlib.suppress(OSError):
            p.rmdir()


def probe_writable(folder: Path, target) -> None:
    """Write and remove a probe file in ``folder``: EROFS, EACCES, ENOSPC show up now, not later."""
    with mapped_os_errors(target):
        fd, name = tempfile.mkstemp(dir=folder, prefix=".fwdlook-probe-")
        os.close(fd)
        os.unlink(name)


def partial_path(path) -> Path:
    """``NAME.partial.SUFFIX``: where :func:`atomic_path` has ``path`` written."""
    path = Path(path)
    return path.with_name(path.stem + ".partial" + path.suffix)


@contextlib.contextmanager
def atomic_path(path, *, rename: bool = True, tmp=None):
    """Yield ``NAME.partial.SUFFIX`` (claimed: ``io.partial``; ``tmp``, one claimed already) for a writer
    that takes a path (matplotlib); rename on success (``rename=False``: left for the caller to rename,
    as the painter's PNG is by its command).  On failure the partial file is removed and an
    ``OSError`` becomes one BadInput line."""
    path = Path(path)
    make_parent(path)
    claimed: list = [] if tmp is None else [Path(tmp)]
    try:
        if tmp is None:     # claimed with signals held: one arriving meanwhile finds the name to remove
            with mapped_os_errors(path):
                signals.call_held(claim_partial_into, claimed, partial_path(path))
        signals.raise_pending()
        yield claimed[0]
        if rename:
            with mapped_os_errors(path):
                os.replace(claimed[0], path)
    except BaseException as exc:
        for name in claimed:
            _unlink_quietly(name)
        if isinstance(exc, OSError):
            raise write_error(path, exc) from None
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
    file, discard the partial file and report the error.  Once closed, the sink drops what HDF5 still
    sends it: only a file that an interrupted command left open (its partial file already removed)
    does, when the interpreter ends.
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
        return 0 if self._f.closed else self._f.readinto(buffer)

    def write(self, buffer):
        n = memoryview(buffer).nbytes
        if self.error is None and not self._f.closed:
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
        return offset if self._f.closed else self._f.seek(offset, whence)

    def tell(self):
        return 0 if self._f.closed else self._f.tell()

    def truncate(self, size=None):
        if self.error is None and not self._f.closed:
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


# HDF5 calls the sink from C: a Ctrl-C or SIGTERM arriving meanwhile is raised after the call (io/signals.py)
signals.protect(*(getattr(FailSafeSink, name) for name in
                  ("readinto", "write", "seek", "tell", "truncate", "flush", "close")))


# ----------------------------------------------------------------------------------------------
# What counts as fwdlook's own product
# ----------------------------------------------------------------------------------------------
def h5_identity(path) -> tuple[str | None, str | None] | None:
    """(root attribute ``format``, root attribute ``software``) of an HDF5 file, either None where it is
    absent; None when the path is not a readable HDF5 file."""
    if not Path(path).is_file():        # absent, a folder, or a FIFO or device (opening one may block)
        return None
    try:
        import h5py

        with h5py.File(path, "r") as f:
            found = [f.attrs.get("format"), f.attrs.get("software")]
    except Exception:  # noqa: BLE001  (anything unreadable is simply not ours)
        return None
    for i, value in enumerate(found):
        if isinstance(value, bytes):
            value = value.decode(errors="replace")
        found[i] = value if isinstance(value, str) else None
    return found[0], found[1]


def h5_format(path) -> str | None:
    """Root attribute ``format`` of an HDF5 file fwdlook wrote (its ``software`` attribute is
    "fwdlook"), or None. Another program's cube in the raw layout also says ``format =
    "fwdlook-raw"`` (CONTRACT.md section 3), so the format alone does not make a file fwdlook's."""
    ident = h5_identity(path)
    return ident[0] if ident is not None and ident[1] == "fwdlook" else None


def is_fwdlook_metrics(path) -> bool:
    if not Path(path).is_file():        # (a FIFO's open would block)
        return False
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
    if not (Path(folder) / "report.md").is_file():
        return False
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
# The kinds of output location
# ----------------------------------------------------------------------------------------------
def output_path(path) -> Path:
    """``path`` as the OS will resolve it once its missing folders are made: ``nodir/../mine.h5`` is
    ``mine.h5`` (the OS cannot resolve ``nodir/..`` before ``nodir`` exists, so a check of the path as
    given would find nothing there and the write would land on ``mine.h5``). A '..' after an existing
    folder is left to the OS (a symlink there goes where the link points)."""
    p = Path(path)
    if ".." not in p.parts:
        return p
    parts = p.parts
    k = len(parts)
    while k > 0 and not (Path(*parts[:k]).exists() or Path(*parts[:k]).is_symlink()):
        k -= 1                                     # parts[:k]: the longest prefix that exists
    if k == len(parts):
        return p
    head = Path(*parts[:k]) if k else Path(".")
    return head / os.path.normpath(os.path.join(*parts[k:]))   # missing folders: made as real ones


def prepare_file(path, *, inputs=(), overwrite: bool = False, kind: str = "raw") -> Path:
    """A raw-cube output file: absent, fwdlook's own raw cube, or ``overwrite``; never an input."""
    if str(path).endswith(("/", os.sep)):
        raise BadInput(f"cannot write {path}: a folder's path (it ends in '/'); expected the path of a raw "
                       f"cube file")
    target = output_path(path)
    _refuse_inputs(target, inputs, "raw cube output")
    if target.is_dir():
        raise BadInput(f"cannot write {target}: is a directory; expected the path of a raw cube file")
    if (target.exists() or target.is_symlink()) and not overwrite:
        ident = h5_identity(target)
        if ident is None or ident != (RAW_FORMAT, "fwdlook"):
            if ident is None:
                what = "permission denied" if target.exists() and not os.access(target, os.R_OK) else \
                    "not a readable HDF5 file"
            elif ident[1] != "fwdlook":
                what = (f"an HDF5 file written by {shown(ident[1]) if ident[1] else 'another program'} "
                        f"(/ attribute software), with / attribute format = {shown(ident[0])}")
            else:
                what = f"a fwdlook file with / attribute format = {shown(ident[0])}"
            raise BadInput(f"{target}: exists and is not a fwdlook raw cube ({what}); refusing to "
                           f"overwrite it; {OVERWRITE_HINT}")
    make_parent(target)
    probe_writable(target.parent, target)
    return target


def prepare_run_dir(path, *, inputs=(), overwrite: bool = False, writes_raw: bool = False) -> Path:
    """A run directory: absent, empty, fwdlook's own run, one holding none of the files a run writes,
    or ``overwrite``; an input inside it that the run would replace is refused always. Made and probed."""
    d = check_run_dir(path, inputs=inputs, overwrite=overwrite, writes_raw=writes_raw)
    _make_dir(d, d)
    if (d / "stages").exists() and not (d / "stages").is_dir():     # (made by the runner, under the lock:
        raise BadInput(f"cannot write {d / 'stages'}: it is not a directory")   # a refused command makes none)
    probe_writable(d, d)
    return d


def check_run_dir(path, *, inputs=(), overwrite: bool = False, writes_raw: bool = False) -> Path:
    """:func:`prepare_run_dir`'s checks alone (nothing made): where a run may write; raises BadInput."""
    d = output_path(path)
    _missing_folders(d.parent, d)   # a file on its path (a sweep's point under a user's file had exit 1)
    if (d.exists() or d.is_symlink()) and not d.is_dir():
        raise BadInput(f"cannot write {d}: exists and is not a directory; expected a run directory")
    names = RUN_FILES + (("raw.h5",) if writes_raw else ())
    if d.is_dir():
        for name in names + tuple(STAGED_PREFIX + n for n in names):      # (io/pending.py: staged first)
            _refuse_inputs(d / name, inputs, f"run directory file {name}")
        stages = d / "stages"
        if stages.is_dir():
            for inp in inputs or ():
                if inp and Path(inp).exists() and any(_same(p, inp) for p in stages.iterdir()):
                    raise BadInput(f"{inp}: is inside {stages}, which this run rewrites; fwdlook never "
                                   f"writes over an input; choose another run directory")
        present = [n for n in names if (d / n).exists() or (d / n).is_symlink()]
        if not overwrite and not is_fwdlook_run_dir(d):
            if (stages.exists() or stages.is_symlink()) and any(
                    not q.name.endswith(".partial") for q in _iter_quiet(stages)):
                present.append("stages/")
            if present:
                raise BadInput(f"{d}: not a fwdlook run directory, and it holds {present[0]}, which a run "
                               f"would replace; refusing to overwrite it; {OVERWRITE_HINT}")
        elif not overwrite:      # fwdlook's run: each file it would replace must be fwdlook's too
            foreign = [n for n in present if not _run_file_is_ours(d, n)]
            staged = [q for q in (_iter_quiet(stages) if stages.is_dir() else []) if not q.name.endswith(".partial")]
            kinds = [h5_format(q) == "fwdlook-stage" for q in staged]
            if not any(kinds) and not is_fwdlook_metrics(d / "metrics.json"):     # stages/ is not the run's:
                foreign += [f"stages/{q.name}" for q in staged]                # (the run's own damaged stage
                #                                                                 files are recomputed)
            if foreign:
                mark = _RUN_FILE_MARK["stages/" if foreign[0].startswith("stages/") else foreign[0]]
                raise BadInput(f"{d / foreign[0]}: a run would replace it, and fwdlook did not write it "
                               f"({mark}); refusing to overwrite it; {OVERWRITE_HINT}")
    return d


_RUN_FILE_MARK = {
    "metrics.json": "not a metrics.json with fwdlook_version",
    "image.h5": "not an HDF5 file with / attributes format = fwdlook-image, software = fwdlook",
    "raw.h5": "not an HDF5 file with / attributes format = fwdlook-raw, software = fwdlook",
    "scenario.yaml": "no fwdlook metrics.json beside it",
    "image.png": "no fwdlook metrics.json beside it",
    "stages/": "no fwdlook stage file or metrics.json beside it",
}


def _run_file_is_ours(d: Path, name: str) -> bool:
    """A file of a run directory that fwdlook wrote: by its own mark (metrics.json, the HDF5 files), or,
    for the files that carry none (scenario.yaml, image.png), by the fwdlook metrics.json that a run
    writes before them (a run removes its outputs first and writes scenario.yaml last)."""
    if name == "metrics.json":
        return is_fwdlook_metrics(d / name)
    if name == "image.h5":
        return h5_format(d / name) == "fwdlook-image"
    if name == "raw.h5":
        return h5_format(d / name) == RAW_FORMAT
    return is_fwdlook_metrics(d / "metrics.json")


def _iter_quiet(folder: Path):
    try:
        return list(folder.iterdir()) if folder.is_dir() else [folder]
    except OSError:
        return [folder]


def _prepare_product_dir(path, files, is_ours, command: str, *, inputs=(), overwrite: bool = False) -> Path:
    """An output folder of ``fwdlook <command>``: absent, its own (``is_ours``), one holding none of
    ``files``, or ``overwrite``; never one of ``inputs``; made and probed before any work."""
    d = output_path(path)
    if (d.exists() or d.is_symlink()) and not d.is_dir():
        raise BadInput(f"cannot write {d}: exists and is not a directory; expected a {command} output folder")
    if d.is_dir():
        for name in files:
            _refuse_inputs(d / name, inputs, f"{command} file {name}")
        if not overwrite and not is_ours(d):
            present = [n for n in files if (d / n).exists() or (d / n).is_symlink()]
            if present:
                raise BadInput(f"{d / present[0]}: exists and was not written by fwdlook {command}; refusing "
                               f"to overwrite it; {OVERWRITE_HINT}")
    _make_dir(d, d)
    probe_writable(d, d)
    return d


def prepare_report_dir(path, *, inputs=(), overwrite: bool = False) -> Path:
    """A report directory: absent, fwdlook's own report, one holding none of the report's files, or
    ``overwrite``."""
    return _prepare_product_dir(path, REPORT_FILES, is_fwdlook_report, "report", inputs=inputs, overwrite=overwrite)


def is_fwdlook_sweep(folder) -> bool:
    """A folder ``fwdlook sweep`` wrote its summary into (summary.json with its sweep, grid and rows)."""
    if not (Path(folder) / "summary.json").is_file():
        return False
    try:
        with open(Path(folder) / "summary.json", "rb") as fh:
            data = json.loads(fh.read(64 * 2**20))
    except Exception:  # noqa: BLE001
        return False
    return isinstance(data, dict) and {"sweep", "grid", "rows"} <= set(data)


def prepare_sweep_dir(path, *, overwrite: bool = False) -> Path:
    """A sweep's output folder: absent, fwdlook's own sweep, one holding none of the summary's files,
    or ``overwrite``."""
    return _prepare_product_dir(path, SWEEP_FILES, is_fwdlook_sweep, "sweep", overwrite=overwrite)


LOCK_NAME = ".fwdlook.lock"
_HELD_LOCK_FDS: set = set()        # this process's lock descriptors (closed in every child it forks)


def _close_inherited_locks() -> None:
    """In a forked child: close the lock descriptors it inherited. An ``flock`` belongs to the open file,
    which the parent's descriptor keeps (the lock is the parent's still); a child that kept its copy
    held the folder after the command died (a sweep's pool workers, left by a SIGKILL, refused every
    rerun as "in use by another fwdlook command")."""
    for fd in list(_HELD_LOCK_FDS):
        with contextlib.suppress(OSError):
            os.close(fd)
    _HELD_LOCK_FDS.clear()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_close_inherited_locks)


@contextlib.contextmanager
def folder_lock(folder, what: str = "run directory"):
    """Hold an exclusive advisory lock (``flock``) on ``folder/.fwdlook.lock`` for the block: a second
    fwdlook command on the same folder is refused in one line instead of interleaving its files with
    this one's (two runs into one folder left a metrics.json of one setting beside the scenario.yaml,
    quick look or stage files of the other). The file stays (holding the last holder's pid): removing
    it while another process has it open would let two processes hold two locks."""
    import fcntl

    path = Path(folder) / LOCK_NAME
    created = not (path.exists() or path.is_symlink())
    try:
        if path.is_symlink():               # replaced, never written through (as every output)
            path.unlink()
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o644)
    except OSError as exc:
        raise write_error(path, exc) from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
            raise BadInput(f"{folder}: {what} in use by another fwdlook command (pid {holder}); wait for it "
                           f"to finish, or choose another output") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        _HELD_LOCK_FDS.add(fd)
        try:
            yield
        except BaseException:               # refused or failed: no lock file or empty folder of its own left
            if created:
                _unlink_quietly(path)
            unmake_dirs(folder)
            raise
        _MADE_DIRS.pop(str(folder), None)
    finally:
        _HELD_LOCK_FDS.discard(fd)
        os.close(fd)
