"""Children that never outlive the command that forked them.

A command forks helpers: the painter that draws image.png (``io/painter.py``), the joint fit's spawner
and workers (``dsp/spawner.py``, ``dsp/forked.py``), a sweep's pool workers (``report/sweep_exec.py``).
Each asks Linux, as its first act, for SIGKILL when its parent dies (``prctl(PR_SET_PDEATHSIG)``): a
command killed by SIGKILL or the OOM killer runs no handler, and before this its sweep workers lived on
holding the folder's lock (every rerun refused) and its painter renamed image.png into the dead run
after the run's metrics.json had not been written (every rerun refused that PNG as not fwdlook's).
Only ``os``, ``signal``, ``threading`` and ``ctypes``: the painter forks before numpy is imported.
"""
from __future__ import annotations

import ctypes
import os
import signal
import threading

_PR_SET_PDEATHSIG = 1


def _libc():
    try:
        return ctypes.CDLL(None, use_errno=True)
    except OSError:                         # pragma: no cover (no C library to load)
        return None


_LIBC = _libc()                             # loaded once, before any fork (a child need not load it)


def forking_parent() -> int | None:
    """This process's id where a child forked now may die with it: the main thread forks (Linux's
    parent-death signal follows the forking *thread*, and a pool's thread may end before the children
    it forked); else None (such a child is ended by its parent's own code, as before)."""
    return os.getpid() if threading.current_thread() is threading.main_thread() else None


def die_with_parent(parent_pid: int | None) -> None:
    """In a child forked by ``parent_pid`` (:func:`forking_parent`; None: nothing to do): SIGKILL for
    this process when its parent dies, and an immediate exit where the parent is already gone (it died
    before the request, which then never fires). SIGTERM is reset to its default: the command's own
    handler (``cli``) turns SIGTERM into a clean exit of the command only. A no-op without prctl."""
    if parent_pid is None:
        return
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    prctl = getattr(_LIBC, "prctl", None)
    if prctl is None:                       # pragma: no cover (not Linux)
        return
    prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    if os.getppid() != parent_pid:
        os._exit(0)
