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

import yaml

from .errors import BadInput
from .limits import shown

MAX_YAML_DEPTH = 64            # levels of nested mappings and lists
MAX_YAML_NODES = 1_000_000     # nodes after alias expansion (a billion-laughs bomb has ~1e9)
MAX_NUMBER_CHARS = 100         # a float64 needs 25; 401 digits overflow it, 4301 overflow int()
_NUMBER_TAGS = ("tag:yaml.org,2002:int", "tag:yaml.org,2002:float")


def check_yaml_graph(root, source: str) -> None:
    """Bound a composed YAML node graph before it is constructed: depth, size after alias expansion
    (shared nodes counted once per use, computed on the graph, never expanded), number length."""
    size: dict[int, int] = {}
    depth: dict[int, int] = {}
    stack = [(root, False)]
    on_path: set[int] = set()
    while stack:
        node, done = stack.pop()
        nid = id(node)
        if done:
            on_path.discard(nid)
            kids = _children(node)
            size[nid] = 1 + sum(size[id(k)] for k in kids)
            depth[nid] = 1 + max((depth[id(k)] for k in kids), default=0)
            line = node.start_mark.line + 1
            if depth[nid] > MAX_YAML_DEPTH:
                raise BadInput(f"{source}: line {line}: nesting deeper than {MAX_YAML_DEPTH} levels; "
                               f"a scenario is a few levels deep")
            if size[nid] > MAX_YAML_NODES:
                raise BadInput(f"{source}: line {line}: the YAML expands (through aliases) to more than "
                               f"{MAX_YAML_NODES:,} values; refused (alias bomb?)")
            continue
        if nid in size:
            continue
        if nid in on_path:
            raise BadInput(f"{source}: line {node.start_mark.line + 1}: recursive alias (a value that "
                           f"contains itself)")
        if isinstance(node, yaml.ScalarNode):
            if node.tag in _NUMBER_TAGS and len(node.value) > MAX_NUMBER_CHARS:
                raise BadInput(f"{source}: line {node.start_mark.line + 1}: a number of {len(node.value):,} "
                               f"characters ({shown(node.value)}); numbers are limited to "
                               f"{MAX_NUMBER_CHARS} characters")
            size[nid], depth[nid] = 1, 1
            continue
        on_path.add(nid)
        stack.append((node, True))
        stack.extend((k, False) for k in _children(node) if id(k) not in size)
        if len(on_path) > MAX_YAML_DEPTH + 1:
            raise BadInput(f"{source}: line {node.start_mark.line + 1}: nesting deeper than "
                           f"{MAX_YAML_DEPTH} levels; a scenario is a few levels deep")


def check_yaml_depth(text: str, source: str) -> None:
    depth = 0
    for event in yaml.parse(text, Loader=yaml.SafeLoader):
        if isinstance(event, (yaml.SequenceStartEvent, yaml.MappingStartEvent)):
            depth += 1
            if depth > MAX_YAML_DEPTH:
                raise BadInput(f"{source}: line {event.start_mark.line + 1}: nesting deeper than "
                               f"{MAX_YAML_DEPTH} levels; a scenario is a few levels deep")
        elif isinstance(event, (yaml.SequenceEndEvent, yaml.MappingEndEvent)):
            depth -= 1


def _children(node):
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    return []



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
    if data.startswith((b"\xff\xfe", b"\xfe\xff")) or b"\x00" in data:
        raise BadInput(f"{source}: not a UTF-8 text file (UTF-16 or binary content); save the {what} "
                       f"as UTF-8")
    try:
        text_ = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise BadInput(f"{source}: not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start}); "
                       f"save the {what} as UTF-8") from None
    from .config import yaml_load

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


