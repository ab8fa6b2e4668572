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
        # the child's drawing stays partial: only its command renames it (after the run's metrics.json)
        assert not (tmp_path / "image.png").exists() and (tmp_path / "image.partial.png").exists()
    assert os.WIFEXITED(child.exit_status)
    assert list(tmp_path.iterdir()) == []                 # never claimed: removed as the painting ended
    pending.finish()                                       # the child is gone: drawn here instead
    assert [q.name for q in tmp_path.iterdir()] == ["image.png"]


def test_the_painters_png_appears_only_when_its_command_renames_it(tmp_path):
    power, x, y, kw = _picture()
    with painting_checked():
        pending = start_image_png(tmp_path / "image.png", power, x, y, **kw)
        deadline = time.monotonic() + 60.0
        while not (tmp_path / "image.partial.png").exists() and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.3)                                    # drawn by now (about 0.1 s warm)
        assert not (tmp_path / "image.png").exists()
        pending.finish()
    assert [q.name for q in tmp_path.iterdir()] == ["image.png"]


def test_a_drawing_its_command_never_claimed_is_removed_with_the_painter(tmp_path):
    """Stopped between metrics.json and the rename (SIGTERM, Ctrl-C): the child finishes its job as the
    painter closes, and its staged drawing is removed then (it had stayed as image.partial.png)."""
    power, x, y, kw = _picture()
    with pytest.raises(KeyboardInterrupt):
        with quicklook.painting() as child:
            assert child is not None
            start_image_png(tmp_path / "image.png", power, x, y, **kw)
            raise KeyboardInterrupt                   # before finish()
    assert list(tmp_path.iterdir()) == []


def test_a_painter_with_a_job_in_hand_dies_with_its_killed_command(tmp_path):
    """SIGKILL runs no handler in the command: the child, busy with a job, must not live on (it used to
    finish and rename its PNG into the dead run, where the run's metrics.json had not been written,
    and every rerun refused that PNG as not fwdlook's)."""
    script = textwrap.dedent("""
        import os, signal, sys, time
        from fwdlook_cli.io.quicklook import painting
        from fwdlook_cli.io import painter
        with painting() as child:
            child.submit("time:sleep", 60.0)             # a job that would keep it for a minute
            print(child.pid, flush=True)
            time.sleep(0.5)
            os.kill(os.getpid(), signal.SIGKILL)
    """)
    out = tmp_path / "pid.txt"             # (a pipe would be held open by a child that outlives it)
    with open(out, "w") as fh:
        res = subprocess.run([sys.executable, "-c", script], stdout=fh, timeout=60)
    assert res.returncode == -signal.SIGKILL
    pid = int(out.read_text().split()[0])
    deadline = time.monotonic() + 10.0
    while not _gone(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert _gone(pid)


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


def test_process_forks_its_painter_before_numpy_and_the_painter_draws_its_png(tmp_path):
    """``fwdlook process`` forks the painter first thing (cli.main), before numpy is imported, and the
    run's image.png is that child's: the command's own draw_image_png, replaced right after the fork,
    refuses.  Before the fork the command has put the BLAS on one thread (``OPENBLAS_NUM_THREADS``,
    read when numpy loads it: the painter's and the command's)."""
    script = textwrap.dedent("""
        import os
        import sys
        from fwdlook_cli.io import painter
        forks = []
        fork_early = painter.fork_early
        def refuse(*args, **kwargs):
            raise AssertionError("drawn in the command's process")
        def spy(*args):
            forks.append("numpy" in sys.modules)
            forks.append(os.environ.get("OPENBLAS_NUM_THREADS"))
            child = fork_early(*args)
            import fwdlook_cli.io.quicklook as q          # the parent's module only: the child has forked
            q.draw_image_png = refuse
            return child
        painter.fork_early = spy
        from fwdlook_cli.cli import main
        try:
            main(sys.argv[1:])
        except SystemExit as exc:
            from threadpoolctl import threadpool_info
            blas = sorted({p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"})
            print("exit", exc.code, "numpy imported before the fork, OPENBLAS_NUM_THREADS:", forks, "blas", blas)
    """)
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}      # (none of the user's)
    res = subprocess.run([sys.executable, "-c", script, "process", "scenarios/tiny.yaml", "-o", str(tmp_path / "run"),
                          "-q"], capture_output=True, text=True, timeout=120, env=env)
    assert res.returncode == 0, res.stderr
    # the BLAS on one thread from before numpy's import, the painter's included (dsp/blas.py)
    assert "exit 0 numpy imported before the fork, OPENBLAS_NUM_THREADS: [False, '1'] blas [1]" in res.stdout, \
        res.stdout + res.stderr
    assert (tmp_path / "run" / "image.png").stat().st_size > 10_000


@pytest.mark.parametrize("argv, forks", [(["process", "x.yaml"], True), (["-q", "run", "x.yaml"], True),
                                         (["-v", "process", "--help"], False), (["--help", "process"], False),
                                         (["simulate", "x.yaml"], False), (["--version"], False), ([], False)])
def test_only_the_commands_that_draw_a_quick_look_fork_early(monkeypatch, argv, forks):
    from fwdlook_cli import cli

    assert cli.QUICKLOOK_WARM_UP == quicklook.WARM_UP
    made, closed = [], []
    monkeypatch.setattr(painter, "fork_early", lambda warm_up: made.append(warm_up))
    monkeypatch.setattr(painter, "close_early", lambda: closed.append(True))
    monkeypatch.setattr(cli, "_run", lambda argv: None)     # (the set-up runs inside the signal handlers)
    with pytest.raises(SystemExit):
        cli.main(argv)
    assert made == ([quicklook.WARM_UP] if forks else []) and closed == [True]


def test_a_command_that_fails_before_its_chain_ends_the_early_painter(tmp_path, capsys, monkeypatch):
    """Bad input (exit 2) before ``painting`` took the early painter: main ends and reaps it."""
    from fwdlook_cli import cli

    made = []
    fork_early = painter.fork_early

    def spy(warm_up):
        made.append(fork_early(warm_up))
        return made[-1]

    monkeypatch.setattr(painter, "fork_early", spy)
    with pytest.raises(SystemExit) as exc:
        cli.main(["process", str(tmp_path / "missing.yaml"), "-o", str(tmp_path / "run")])
    assert exc.value.code == 2 and "missing.yaml" in capsys.readouterr().err
    child = made[0]
    assert child is not None and child.pid is None and child.exit_status is not None   # closed, reaped
    assert painter._EARLY is None and painter.active() is None
