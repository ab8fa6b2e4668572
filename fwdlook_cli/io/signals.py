"""Ctrl-C and SIGTERM raised in the command's own code, never inside HDF5's calls back into Python.

h5py writes fwdlook's files through a Python file object (``io.outputs.FailSafeSink``), which HDF5's C
library calls for every write, seek and truncate.  Python runs a signal handler in the main thread at
the next bytecode, which may be inside such a call: an exception raised there unwinds through HDF5,
which cannot recover from it (SIGTERM during a cube's write ended in "Exception ignored in
h5py._objects.ObjectID.__dealloc__" and a segmentation fault, or left the command running).

The command's handlers (:func:`install`) therefore look at the Python frames the signal interrupted:
where one of them is a protected function (:func:`protect`: the sink's methods), the signal is kept and
a timer (``SIGALRM`` every :data:`RETRY_S`) raises it once the main thread runs other code.  An
exception raised where Python cannot propagate it (a weakref callback or a ``__del__``: "Exception
ignored in ...", after which the command had gone on to exit 0 as if never stopped) is caught by
``sys.unraisablehook`` and raised again the same way.  Nothing but the exception's moment changes: the
atomic writers then remove their partial files as for any other error.
"""
from __future__ import annotations

import os
import signal
import sys
import threading

RETRY_S = 0.002
_PROTECTED: set = set()   # code objects in which no signal's exception is raised
_PENDING = None           # the exception type a signal asked for, kept until it may be raised
_RAISED = None            # the last exception raised for a signal (to tell it among unraisable ones)


def protect(*functions) -> None:
    """No signal's exception is raised while any of ``functions`` runs (nor in what it calls)."""
    _PROTECTED.update(f.__code__ for f in functions)


def _inside_protected(frame) -> bool:
    while frame is not None:
        if frame.f_code in _PROTECTED:
            return True
        frame = frame.f_back
    return False


def _raise_or_keep(exc_type, frame) -> None:
    global _PENDING, _RAISED
    if _inside_protected(frame):
        _PENDING = _PENDING or exc_type               # the first kept wins
        signal.setitimer(signal.ITIMER_REAL, RETRY_S)
        return
    _PENDING = None
    _RAISED = exc_type()
    raise _RAISED


def _retry(signum, frame):
    if _PENDING is not None:
        _raise_or_keep(_PENDING, frame)


def _unraisable(found_hook):
    def hook(unraisable):
        global _PENDING
        if _RAISED is not None and unraisable.exc_value is _RAISED:
            _PENDING = _PENDING or type(_RAISED)
            signal.setitimer(signal.ITIMER_REAL, RETRY_S)
            return
        found_hook(unraisable)

    return hook


def install(terminated_type, *, idle=None):
    """The command's handlers: Ctrl-C raises KeyboardInterrupt (as Python's own), SIGTERM
    ``terminated_type``, each where it may be raised (module docstring); where ``idle()`` says the
    process has nothing to clean up (a sweep's pool worker between points), it leaves at once with exit
    128 + the signal instead. Returns a function that restores the handlers found (main thread only;
    elsewhere nothing is installed)."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    found = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGALRM)}
    found_hook = sys.unraisablehook

    def handler(exc_type):
        def handle(signum, frame):
            if idle is not None and idle():
                os._exit(128 + signum)
            _raise_or_keep(exc_type, frame)
        return handle

    signal.signal(signal.SIGINT, handler(KeyboardInterrupt))
    signal.signal(signal.SIGTERM, handler(terminated_type))
    signal.signal(signal.SIGALRM, _retry)
    sys.unraisablehook = _unraisable(found_hook)

    def restore():
        global _PENDING, _RAISED
        signal.setitimer(signal.ITIMER_REAL, 0)
        for sig, handler in found.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
        sys.unraisablehook = found_hook
        _PENDING = _RAISED = None

    return restore
