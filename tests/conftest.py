"""Fixtures shared by several test modules."""
import pytest

from fwdlook_cli.io.raw import write_raw
from fwdlook_cli.forward.simulate import simulate_scenario
from fwdlook_cli.testing import tiny_scenario


@pytest.fixture(scope="module")
def tiny_raw(tmp_path_factory):
    """The tiny scene simulated once per module and written as a raw cube."""
    path = tmp_path_factory.mktemp("raw") / "tiny_raw.h5"
    cube, _ = simulate_scenario(tiny_scenario())
    write_raw(path, cube)
    return path


@pytest.fixture(autouse=True)
def _no_spawner_left():
    """A spawner a test started (dsp/spawner.py: the joint fit's) is ended after it: each test's forked
    workers see that test's own code and data, and no child of this process outlives its test."""
    yield
    from fwdlook_cli.dsp import spawner

    spawner.stop()
