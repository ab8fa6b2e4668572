"""Reading YAML files (scenarios, presets, sweeps): the ONE reader every command uses, and its bounds.

``read_yaml_file`` turns every way a file can be unreadable (missing, a directory, no permission,
non-UTF-8, UTF-16, binary, over 16 MiB) into one BadInput line; ``config.yaml_load`` parses it with
the bounds checked here before anything is constructed: nesting depth on the event stream (no
recursion: 3,000 levels cost nothing), the size after alias expansion counted on the node graph
(a billion-laughs bomb is never expanded), and the length of numbers (401 digits overflow a float,
5,001 exceed Python's int() limit).  ``read_scenario_raw`` refuses an empty or comment-only file.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any


from ..errors import BadInput
from ..limits import shown
from .yamlio import yaml_load

def read_yaml_file(path: str | Path, what: str = "scenario") -> Any:
    """Read and parse a YAML file (scenario, preset, sweep): the ONE reader every command uses.

    Missing files, directories, unreadable files, non-UTF-8 text (UTF-16, binary) and files larger
    than :data:`MAX_YAML_BYTES` are one BadInput line naming the file.
    """
    path = Path(path)
    source = str(path)
    try:
        if path.is_dir():
            raise BadInput(f"{source}: is a directory; expected a {what} YAML file")
        with open(path, "rb") as fh:
            data = fh.read(MAX_YAML_BYTES + 1)
    except FileNotFoundError:
        raise BadInput(f"{source}: {what} file not found") from None
    except OSError as exc:
        raise BadInput(f"{source}: cannot read {what} file ({exc.strerror or exc.__class__.__name__})") from None
    if len(data) > MAX_YAML_BYTES:
        raise BadInput(f"{source}: {what} file larger than {MAX_YAML_BYTES // 2**20} MiB; a {what} is a "
                       f"small YAML text")
    if data.startswith(b"\x89HDF\r\n\x1a\n"):      # HDF5's signature (at offset 0, where h5py writes it)
        raise BadInput(f"{source}: an HDF5 file, not a {what} YAML text; a raw cube is read by its name's "
                       f"suffix: name it .h5, .hdf5 or .hdf, or give it with --raw")
    if data.startswith((b"\xff\xfe", b"\xfe\xff")) or b"\x00" in data:
        raise BadInput(f"{source}: not a UTF-8 text file (UTF-16 or binary content); save the {what} "
                       f"as UTF-8")
    try:
        text_ = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise BadInput(f"{source}: not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start}); "
                       f"save the {what} as UTF-8") from None
    return yaml_load(text_, source)


MAX_YAML_BYTES = 16 * 2**20


def read_scenario_raw(path: str | Path) -> dict:
    """The raw (unresolved) scenario mapping of a file; an empty or comment-only file is refused."""
    raw = read_yaml_file(path, "scenario")
    if raw is None:
        raise BadInput(f"{path}: empty scenario (no keys, only comments or blank lines); a scenario needs "
                       f"at least its sections, e.g. radar, antenna, platform, scene")
    if not isinstance(raw, dict):
        raise BadInput(f"{path}: top level: expected a mapping of scenario sections, got {shown(raw)}")
    return raw


