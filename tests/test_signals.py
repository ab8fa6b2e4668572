"""Ctrl-C and SIGTERM are raised in the command's own code, never inside HDF5's calls into Python
(io/signals.py): a SIGTERM during a cube's write had ended in a segmentation fault, and one raised in a
weakref callback had been printed as "Exception ignored" while the command went on to exit 0."""
import os
import signal
import time

import pytest

from fwdlook_cli.errors import Terminated
from fwdlook_cli.io import signals


@pytest.fixture
def installed():
    restore = signals.install(Terminated)
    yield
    restore()


def _spin(seconds):
    end = time.monotonic() + seconds
    while time.monotonic() < end:             # bytecodes, at which Python runs a pending handler
        pass


def test_a_signal_inside_a_protected_call_is_raised_after_it(installed):
    events = []

    def protected():                          # as HDF5's calls of the sink's write
        os.kill(os.getpid(), signal.SIGTERM)
        _spin(0.05)
        events.append("returned")

    signals.protect(protected)
    with pytest.raises(Terminated):
        protected()
        events.append("after")
        _spin(1.0)                            # the retry timer raises it here
    assert events == ["returned", "after"]


def test_a_signal_raised_where_python_cannot_propagate_it_is_raised_again(installed, capsys):
    class Dropped:
        def __del__(self):
            os.kill(os.getpid(), signal.SIGTERM)
            _spin(0.05)                       # raised here: "Exception ignored in __del__"

    with pytest.raises(Terminated):
        Dropped()
        _spin(1.0)
    assert "Exception ignored" not in capsys.readouterr().err


def test_ctrl_c_outside_protected_code_is_a_keyboard_interrupt_at_once(installed):
    with pytest.raises(KeyboardInterrupt):
        os.kill(os.getpid(), signal.SIGINT)
        _spin(1.0)
