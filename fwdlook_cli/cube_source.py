"""Where a command's source is a cube file (RAW.h5 as the source, or ``--raw``): which settings a ``--set``
may change, and the note that heads such a run's scenario.yaml (kept apart from cli.py, light to import)."""
from __future__ import annotations

from pathlib import Path

from .errors import BadInput
from .limits import shown


CUBE_SETTABLE = ("processing", "name")     # what a --set can change where the source is a cube
RAW_SETTABLE = ("processing", "name", "kind", "scene")   # with --raw: the scene map of an image scene's metrics


def refuse_unused_sets(cube, overrides, settable=CUBE_SETTABLE) -> None:
    """A cube is processed with its own radar, antenna, motion and truth (CONTRACT.md section 3): a --set
    of another section would be recorded in scenario.yaml and used nowhere (it was, silently)."""
    for item in overrides or ():
        key = str(item).split("=", 1)[0].strip()
        if "=" in str(item) and key.split(".", 1)[0] not in settable:
            raise BadInput(f"--set {shown(str(item))}: {cube} is processed with its own radar, antenna, "
                           f"platform motion and truth (CONTRACT.md section 3), so {key} would change nothing; "
                           f"allowed with a cube: {', '.join(k + '.*' if k in ('processing', 'scene') else k for k in settable)}")


def cube_scenario_note(cube, *, raw_option: bool = False) -> str:
    """The comment that heads scenario.yaml where the chain read a cube: which sections it used (a reader
    must not take the others for the cube's)."""
    unused = ("radar, antenna, platform, noise and simulation sections below are the scenario's" if raw_option
              else "other sections below are the schema's defaults")
    used = "name, kind, scene and processing" if raw_option else "name and processing"
    return (f"# processed from the cube {cube}: the chain took the radar, antenna, platform motion and truth\n"
            f"# from the cube itself (CONTRACT.md section 3); {used} are this run's settings, the\n"
            f"# {unused} and were not used.\n")


def scenario_note(source, raw) -> str:
    if is_cube_path(source):
        return cube_scenario_note(source)
    return cube_scenario_note(raw, raw_option=True) if raw else ""


def reads_cube(source, raw) -> bool:
    """Whether the command processes a cube read from a file (RAW.h5 as the source, or --raw)."""
    return bool(raw) or is_cube_path(source)


def is_cube_path(source) -> bool:
    return Path(source).suffix.lower() in (".h5", ".hdf5", ".hdf")
