"""Ctrl-C and SIGTERM raised in the command's own code, never inside HDF5's calls back into Python.

h5py writes fwdlook's files through a Python file object (``io.outputs.FailSafeSink``), which HDF5's C
library calls for every write, seek and truncate.  Python runs a signal handler in the main thread at
the next bytecode, which may be inside such a call: an exception raised there unwinds through HDF5,
which cannot recover from it (SIGTERM during a cube's write ended in "Exception ignored in
h5py._objects.ObjectID.__dealloc__" and a segmentation fault, or left the command running).

The command's handlers (:func:`install`) therefore look at the Python frames the signal interrupted:
where one of them is a protected function (:func:`protect`: the sink's methods; :func:`call_held`: the
opening and closing of an HDF5 file), the signal is kept and a timer (``SIGALRM`` every :data:`RETRY_S`)
raises it once the main thread runs other code, or :func:`raise_pending` at once. Where h5py's Cython
code calls back into Python outside the sink (its type conversions' logging), an exception raised there
comes out as another (HDF5's "TypeError: Operation not defined for data type class") with the signal's
as its context: :func:`signal_behind` finds it, and the command reports the signal. A signal kept past
the command's end, or swallowed on the way, is still the command's end (:func:`as_signalled`). An
exception raised where Python cannot propagate it (a weakref callback or a ``__del__``: "Exception
ignored in ...", after which the command had gone on to exit 0 as if never stopped) is caught by
``sys.unraisablehook`` and raised again the same way. Nothing but the exception's moment changes: the
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
_SIGNALLED = None         # the exception type the first signal since install() asked for


def protect(*functions) -> None:
    """No signal's exception is raised while any of ``functions`` runs (nor in what it calls)."""
    _PROTECTED.update(f.__code__ for f in functions)


def call_held(function, *args, **kwargs):
    """``function(*args, **kwargs)`` with no signal's exception raised inside it: one arriving meanwhile is
    raised after it returns.  For calls that create or close what HDF5 holds (``h5py.File``): h5py
    registers a new file's identifier from Python after HDF5 has opened it, so an exception raised there
    left the file open, unreachable, until the interpreter's exit closed it through a sink already
    closed ("Exception ignored in h5py._objects.ObjectID.__dealloc__" after SIGTERM).  And for the wait,
    after a first signal, for a stage file in flight (``runner.run_stages``): a second one had cut it
    short, and the process left with the file's ``.partial``."""
    return function(*args, **kwargs)


def _inside_protected(frame) -> bool:
    while frame is not None:
        if frame.f_code in _PROTECTED:
            return True
        frame = frame.f_back
    return False


protect(call_held)


def raise_pending() -> None:
    """Raise now, in the main thread outside protected code, the signal kept while protected code ran
    (instead of at the retry timer's next tick, when the command may have gone past its cleanup)."""
    if _PENDING is not None and threading.current_thread() is threading.main_thread():
        frame = sys._getframe(1)
        if not _inside_protected(frame):
            _raise_or_keep(_PENDING, frame)


def as_signalled(function, *args, **kwargs):
    """``function(*args, **kwargs)``, where a signal since :func:`install` ends it with the signal's own
    exception: one a library turned into its own (:func:`signal_behind`), and one kept past the call's
    end or swallowed on the way (the command was stopped all the same)."""
    try:
        result = function(*args, **kwargs)
        stopped = _SIGNALLED
    except Exception as exc:
        stopped = signal_behind(exc)
        if stopped is None:
            raise
        raise stopped() from exc
    if stopped is not None:
        _forget_pending()                   # delivered here
        raise stopped()
    return result


def signal_behind(exc: BaseException):
    """The signal's exception type where ``exc`` was raised while handling it (a library turned the
    signal's exception into its own), else None."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if _RAISED is not None and exc is _RAISED:
            return type(exc)
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


def _forget_pending() -> None:
    """A kept signal is being delivered: its retry timer is not needed (nor left to go off as the
    interpreter ends, whose default action for SIGALRM kills it)."""
    global _PENDING
    if _PENDING is not None:
        signal.setitimer(signal.ITIMER_REAL, 0)
        _PENDING = None


def _raise_or_keep(exc_type, frame) -> None:
    global _PENDING, _RAISED
    if _inside_protected(frame):
        _PENDING = _PENDING or exc_type               # the first kept wins
        signal.setitimer(signal.ITIMER_REAL, RETRY_S)
        return
    _forget_pending()
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
            global _SIGNALLED
            if idle is not None and idle():
                os._exit(128 + signum)
            _SIGNALLED = _SIGNALLED or exc_type
            _raise_or_keep(exc_type, frame)
        return handle

    signal.signal(signal.SIGINT, handler(KeyboardInterrupt))
    signal.signal(signal.SIGTERM, handler(terminated_type))
    signal.signal(signal.SIGALRM, _retry)
    sys.unraisablehook = _unraisable(found_hook)

    def restore():
        global _PENDING, _RAISED, _SIGNALLED
        signal.setitimer(signal.ITIMER_REAL, 0)
        for sig, handler in found.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
        sys.unraisablehook = found_hook
        _PENDING = _RAISED = _SIGNALLED = None

    return restore
