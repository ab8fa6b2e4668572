"""``fwdlook`` run in-process by the tests (one definition for every test file that calls the command)."""
import pytest

from fwdlook_cli.cli import main


def run_cli(argv, capsys):
    """Run ``fwdlook ARGV`` in-process (``capsys``: pytest's capture fixture); return (exit code, stdout,
    stderr)."""
    with pytest.raises(SystemExit) as exc_info:
        main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return exc_info.value.code, out, err
