"""The quick look drawn by the forked painter (io/painter.py) is the quick look drawn in the process:
the same bytes, the same errors, and no child left behind however the command ends."""
import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from fwdlook_cli.errors import BadInput
from fwdlook_cli.io import painter, quicklook
from fwdlook_cli.io.quicklook import draw_image_png, save_image_png, start_image_png

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the painter forks on Linux only")


def _picture():
    rng = np.random.default_rng(7)
    power = rng.exponential(size=(120, 90)) * 1e-4
    power[60, 45] = 1.0                                    # one bright cell: the colour scale's top
    x, y = -2.0 + 0.05 * np.arange(90), 1000.0 + 0.6 * np.arange(120)
    return power, x, y, dict(xlabel="azimuth (deg)", ylabel="range (m)", title="painter",
                             markers=(np.array([0.25]), np.array([1036.0])))


def _gone(pid: int) -> bool:
    """No such process, or a zombie (exited; an orphan's reaper may be slow or absent in a container)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] in ("Z", "X")
    except FileNotFoundError:
        return True


def _not_here(*args, **kwargs):
    raise AssertionError("drawn in the command's process, not by the painter")


def test_the_painters_png_is_the_in_process_png(tmp_path, monkeypatch):
    power, x, y, kw = _picture()
    draw_image_png(tmp_path / "here.png", power, x, y, **kw)
    with painting_checked() as child:
        monkeypatch.setattr(quicklook, "draw_image_png", _not_here)     # the parent's only (after the fork)
        save_image_png(tmp_path / "child.png", power, x, y, **kw)
        pid = child.pid
        assert not (tmp_path / "child.partial.png").exists()
    assert (tmp_path / "child.png").read_bytes() == (tmp_path / "here.png").read_bytes()
    assert _gone(pid)                                      # closed and reaped with the block


def test_the_painters_error_is_the_in_process_error(tmp_path, monkeypatch):
    power, x, y, kw = _picture()
    (tmp_path / "plain").write_text("a file, not a folder")
    target = tmp_path / "plain" / "image.png"
    with pytest.raises(BadInput) as here:
        draw_image_png(target, power, x, y, **kw)
    with painting_checked():
        monkeypatch.setattr(quicklook, "draw_image_png", _not_here)
        with pytest.raises(BadInput) as there:
            save_image_png(target, power, x, y, **kw)
        save_image_png(tmp_path / "after.png", power, x, y, **kw)     # the child still draws
    assert str(there.value) == str(here.value)
    assert (tmp_path / "after.png").exists()


def test_a_dead_painter_means_the_png_is_drawn_here(tmp_path):
    power, x, y, kw = _picture()
    draw_image_png(tmp_path / "here.png", power, x, y, **kw)
    with painting_checked() as child:
        os.kill(child.pid, signal.SIGKILL)
        save_image_png(tmp_path / "fallback.png", power, x, y, **kw)
        assert painter.active().pid is None                # reaped once found gone
    assert (tmp_path / "fallback.png").read_bytes() == (tmp_path / "here.png").read_bytes()


def test_a_discarded_png_is_not_left_behind(tmp_path):
    power, x, y, kw = _picture()
    with painting_checked():
        pending = start_image_png(tmp_path / "image.png", power, x, y, **kw)
        pending.discard()                                  # the command failed after it was begun
    assert list(tmp_path.iterdir()) == []


def test_closing_an_idle_painter_ends_it_at_once():
    """A command that stops before its image (an error, Ctrl-C) does not wait for the child's imports."""
    with painting_checked() as child:
        pid = child.pid
    assert _gone(pid)
    assert os.WIFSIGNALED(child.exit_status) and os.WTERMSIG(child.exit_status) == signal.SIGKILL


def test_a_painter_that_drew_leaves_by_its_closed_pipe_after_the_job(tmp_path):
    power, x, y, kw = _picture()
    with painting_checked() as child:
        pending = start_image_png(tmp_path / "image.png", power, x, y, **kw)
        child.close()                                      # with the job in hand: finished, then gone
    assert os.WIFEXITED(child.exit_status)
    assert (tmp_path / "image.png").exists() and not (tmp_path / "image.partial.png").exists()
    pending.finish()                                       # the child is gone: drawn here instead


def test_the_painter_leaves_when_its_command_is_killed(tmp_path):
    script = textwrap.dedent("""
        import os, signal, sys
        from fwdlook_cli.io.quicklook import painting
        with painting() as child:
            print(child.pid, flush=True)
            os.kill(os.getpid(), signal.SIGKILL)
    """)
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert res.returncode == -signal.SIGKILL
    pid = int(res.stdout.split()[0])
    deadline = time.monotonic() + 30.0                     # its imports first, then the closed pipe
    while not _gone(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert _gone(pid)


def painting_checked():
    """:func:`quicklook.painting`, which must have started a child here (Linux)."""
    ctx = quicklook.painting()

    class Checked:
        def __enter__(self):
            child = ctx.__enter__()
            assert child is not None and child.pid and painter.active() is child
            return child

        def __exit__(self, *exc):
            out = ctx.__exit__(*exc)
            assert painter.active() is None
            return out

    return Checked()


def test_a_painter_that_does_not_answer_is_ended(monkeypatch):
    """A child that hangs costs the command the timeout, then the PNG is drawn in the process."""
    monkeypatch.setattr(painter, "RESULT_TIMEOUT_S", 0.5)
    child = painter.Painter()
    try:
        child.submit("time:sleep", 60)
        t0 = time.monotonic()
        with pytest.raises(painter.PainterGone):
            child.result()
        assert time.monotonic() - t0 < 10
    finally:
        child.close()
    assert os.WIFSIGNALED(child.exit_status) and os.WTERMSIG(child.exit_status) == signal.SIGKILL
