"""The quick look drawn by a forked child that imports matplotlib while the chain runs.

``fwdlook process`` and ``fwdlook run`` end with ``image.png``.  Drawn in the command's own process,
it costs the import of matplotlib (about 0.55 s here, more than the whole chain on the paper cube) and
the drawing (about 0.3 s), both after the chain.  A :class:`Painter` forks at the start of the command,
while the process is still small (the fork copies page tables only), and the child imports
matplotlib at once, on the core the command's own imports and scenario loading leave idle; when the
image is ready, :func:`fwdlook_cli.io.quicklook.start_image_png` hands the child the function's name
and its arguments (pickled, on a pipe), the child draws them with the same function and the same
matplotlib, writes the PNG atomically and answers with ``None`` or the exception it raised, which the
command raises as its own (the same one-line errors).  The PNG is the same file, byte for byte
(``tests/test_painter.py``).  This module knows nothing of matplotlib: the child runs functions named
``"module:function"``, a warm-up first (``io.quicklook.painting``).

The child ignores SIGINT (the command handles Ctrl-C) and leaves by ``os._exit`` when its job pipe
closes; it is killed with the command however the command dies (``dsp/lifetime.py``: SIGKILL of the
command too, where the child used to finish its job and rename the PNG into a dead run); the command
ends an idle child at once when it closes the painter.  A child that is gone or has not answered in :data:`RESULT_TIMEOUT_S`
(then it is ended), or a platform without ``fork``, means the PNG is drawn in the command's process
as before.
"""
from __future__ import annotations

import contextlib
import importlib
import os
import pickle
import select
import signal
import struct
import sys
import threading
import time

from ..dsp.lifetime import die_with_parent, forking_parent

_HEADER = struct.Struct("<Q")
RESULT_TIMEOUT_S = 120.0    # a job not answered by then: the child is ended and the PNG drawn in the command
_ACTIVE = None              # the painter of the command in progress (at most one per process)
_EARLY = None               # a painter forked by :func:`fork_early`, not yet taken by :func:`painting`


class PainterGone(RuntimeError):
    """The child is no longer there to draw (the caller draws in its own process)."""


def _read_exactly(fd: int, n: int) -> bytes | None:
    chunks, left = [], n
    while left:
        piece = os.read(fd, min(left, 1 << 20))
        if not piece:
            return None
        chunks.append(piece)
        left -= len(piece)
    return b"".join(chunks)


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


def _send(fd: int, obj) -> None:
    body = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    _write_all(fd, _HEADER.pack(len(body)) + body)


def _receive(fd: int):
    head = _read_exactly(fd, _HEADER.size)
    if head is None:
        return None
    body = _read_exactly(fd, _HEADER.unpack(head)[0])
    if body is None:
        return None
    return (pickle.loads(body),)


def _resolve(name: str):
    """The function ``"package.module:function"``, imported here (in the child: its own, unpatched)."""
    module, _, attr = name.partition(":")
    return getattr(importlib.import_module(module), attr)


def _child_main(job_fd: int, reply_fd: int, warm_up: str | None) -> None:   # pragma: no cover (the child)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)    # (forked after the command's handlers were installed)
    if warm_up:
        with contextlib.suppress(Exception):  # an import failure shows when a job is run
            _resolve(warm_up)()
    while True:
        got = _receive(job_fd)
        if got is None:                       # the command closed the pipe, or is gone
            return
        name, args, kwargs = got[0]
        try:
            _resolve(name)(*args, **kwargs)
            reply = None
        except BaseException as exc:          # noqa: BLE001 (handed to the command, raised there)
            reply = exc
        try:
            pickle.dumps(reply)
        except Exception:                     # noqa: BLE001 (an exception that does not pickle)
            reply = RuntimeError(f"{type(reply).__name__}: {reply}")
        _send(reply_fd, reply)


class Painter:
    """A forked child that runs ``warm_up`` (a ``"module:function"`` name), then the jobs it is handed."""

    def __init__(self, warm_up: str | None = None):
        self.pid = None
        self.warm_up = warm_up
        self.exit_status = None                   # os.waitpid's status, once reaped
        self._sender, self._send_error, self._busy = None, None, False
        job_r, self._job_w = os.pipe()
        self._reply_r, reply_w = os.pipe()
        parent = forking_parent()
        try:
            pid = os.fork()
        except OSError:
            for fd in (job_r, self._job_w, self._reply_r, reply_w):
                os.close(fd)
            raise
        if pid == 0:                                                    # pragma: no cover (the child)
            code = 0
            try:
                die_with_parent(parent)           # never a PNG renamed into a run whose command is dead
                os.close(self._job_w)
                os.close(self._reply_r)
                _child_main(job_r, reply_w, warm_up)
            except BaseException:                 # noqa: BLE001
                code = 1
            finally:
                os._exit(code)
        self.pid = pid
        os.close(job_r)
        os.close(reply_w)

    def submit(self, name: str, *args, **kwargs) -> None:
        """Hand the child a job and return at once (:meth:`result` waits for it; one job at a time)."""
        if self.pid is None:
            raise PainterGone("the painter is closed")
        if self._sender is not None:
            raise RuntimeError("the painter has a job in hand")
        # written by a thread: a pipe holds 64 KiB and an image is megabytes, which the child reads
        # only once its warm-up is done; the command goes on meanwhile
        job = pickle.dumps((name, args, kwargs), protocol=pickle.HIGHEST_PROTOCOL)
        self._busy = True
        self._sender = threading.Thread(target=self._send_job, args=(job,), name="fwdlook-painter", daemon=True)
        self._sender.start()

    def _send_job(self, job: bytes) -> None:
        try:
            _write_all(self._job_w, _HEADER.pack(len(job)) + job)
        except OSError as exc:                    # EPIPE: the child is gone (result() says so)
            self._send_error = exc

    def result(self) -> None:
        """Wait for the job handed over by :meth:`submit`; raise what it raised, or :class:`PainterGone`."""
        if self.pid is None:
            raise PainterGone("the painter is closed")
        deadline = time.monotonic() + RESULT_TIMEOUT_S
        sender, self._sender = self._sender, None
        if sender is not None:
            sender.join(RESULT_TIMEOUT_S)
        if self._send_error is not None:
            self._end(str(self._send_error))
        ready = sender is None or not sender.is_alive()
        if ready:
            ready = bool(select.select([self._reply_r], [], [], max(0.0, deadline - time.monotonic()))[0])
        if not ready:                             # a child that hangs is ended: the PNG is drawn here
            self._sender = sender                 # (joined by close, once the child is gone)
            self._end(f"the painter did not answer in {RESULT_TIMEOUT_S:.0f} s")
        try:
            got = _receive(self._reply_r)
        except OSError as exc:
            got, detail = None, str(exc)
        else:
            detail = "the painter exited"
        if got is None:
            self._end(detail)
        self._busy = False
        if got[0] is not None:
            raise got[0]

    def _end(self, why: str):
        """The child cannot answer (gone, or hung): end it, reap it, raise :class:`PainterGone`."""
        self._busy = False
        self.close()
        raise PainterGone(why)

    def close(self) -> None:
        """End the child and reap it: an idle child at once (SIGKILL: it holds nothing but its imports,
        and a command stopped by Ctrl-C during its chain does not wait for them); a child with a job
        in hand finishes it (no partial PNG), finds its pipes closed and leaves.  The job pipe is
        closed only once the thread writing to it has returned (a closed descriptor's number may be
        reused by the next file the command opens)."""
        if self.pid is None:
            return
        pid, self.pid = self.pid, None
        if not self._busy:
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)
        if self._sender is not None:              # the child reads it all, or is gone (EPIPE)
            self._sender.join()
            self._sender = None
        for fd in (self._job_w, self._reply_r):
            with contextlib.suppress(OSError):
                os.close(fd)
        with contextlib.suppress(ChildProcessError):
            self.exit_status = os.waitpid(pid, 0)[1]


def active() -> Painter | None:
    """The painter of the command in progress, if any."""
    return _ACTIVE


def _can_fork() -> bool:
    return sys.platform.startswith("linux") and hasattr(os, "fork")


def fork_early(warm_up: str | None = None) -> Painter | None:
    """Fork the command's painter now, before the command's own imports: the command line calls this
    first thing for the commands that draw a quick look, so that the child imports matplotlib (and
    numpy) beside the command's imports of numpy and scipy instead of after them (the child's import,
    warm-up and drawing are what a ``fwdlook process`` waits for last).  The next :func:`painting`
    with the same ``warm_up`` takes it; :func:`close_early` ends one that none took."""
    global _EARLY
    if _EARLY is None and _ACTIVE is None and _can_fork():
        with contextlib.suppress(OSError):
            _EARLY = Painter(warm_up)
    return _EARLY


def close_early() -> None:
    """End the painter of :func:`fork_early` if no :func:`painting` took it (the command failed first)."""
    global _EARLY
    painter, _EARLY = _EARLY, None
    if painter is not None:
        painter.close()


@contextlib.contextmanager
def painting(warm_up: str | None = None):
    """Within the block, :func:`active` is a forked :class:`Painter` that ran ``warm_up`` (Linux; None
    elsewhere, or where the fork fails: the callers then work in this process): the one
    :func:`fork_early` made for the same ``warm_up`` where there is one, else one forked now."""
    global _ACTIVE, _EARLY
    painter = None
    if _ACTIVE is None and _EARLY is not None and _EARLY.warm_up == warm_up:
        painter, _EARLY = _EARLY, None
    elif _ACTIVE is None and _can_fork():
        with contextlib.suppress(OSError):
            painter = Painter(warm_up)
    if painter is not None:
        _ACTIVE = painter
    try:
        yield painter
    finally:
        if painter is not None:
            _ACTIVE = None
            painter.close()
