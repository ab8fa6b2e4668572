"""YAML that refuses duplicate keys, with the error naming the dotted key path."""
from __future__ import annotations

import re
from typing import Any

import yaml

from ..errors import BadInput
from ..limits import shown

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


class _StrictLoader(yaml.SafeLoader):
    """SafeLoader that refuses duplicate mapping keys (PyYAML silently keeps the last one)."""


def _construct_mapping(loader: _StrictLoader, node: yaml.MappingNode, deep: bool = False):
    loader.flatten_mapping(node)
    mapping = {}
    for key_node, value_node in node.value:
        key = loader.construct_object(key_node, deep=deep)
        try:
            hash(key)
        except TypeError:
            raise yaml.constructor.ConstructorError(
                None, None, f"a {type(key).__name__} used as a mapping key; keys must be plain names",
                key_node.start_mark) from None
        if key in mapping:
            line = key_node.start_mark.line + 1
            raise yaml.constructor.ConstructorError(
                None, None, f"duplicate key {key!r} (line {line})", key_node.start_mark)
        mapping[key] = loader.construct_object(value_node, deep=deep)
    return mapping


_StrictLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)

_LEADING_ZERO = re.compile(r"^[-+]?0[0-9_]+$")      # YAML 1.1: octal (010 is 8)


def _refuse_yaml11_number(loader: _StrictLoader, node, construct):
    """A number YAML 1.1 reads other than as its digits: a leading 0 (octal: ``seed: 010`` is 8) or
    colons (base 60: ``1:0`` is 60); they had been taken silently (an independent review)."""
    text = str(loader.construct_scalar(node))
    if _LEADING_ZERO.match(text) or ":" in text:
        why = "a leading 0 as octal" if _LEADING_ZERO.match(text) else "a:b as base 60"
        raise yaml.constructor.ConstructorError(
            None, None, f"the number {text} (YAML 1.1 reads {why}: {construct(loader, node)}); allowed: the "
            f"digits without a leading 0 or colons, or the value quoted as text", node.start_mark)
    return construct(loader, node)


_StrictLoader.add_constructor("tag:yaml.org,2002:int", lambda loader, node: _refuse_yaml11_number(
    loader, node, yaml.SafeLoader.construct_yaml_int))
_StrictLoader.add_constructor("tag:yaml.org,2002:float", lambda loader, node: _refuse_yaml11_number(
    loader, node, yaml.SafeLoader.construct_yaml_float))


def yaml_load(text: str, source: str) -> Any:
    """Parse YAML text strictly; a syntax error or a duplicate key becomes one BadInput line."""
    try:
        check_yaml_depth(text, source)           # on the event stream: no recursion, stops early
        loader = _StrictLoader(text)
        try:
            node = loader.get_single_node()
            if node is None:
                return None
            check_yaml_graph(node, source)       # nesting, alias expansion, number length
            return loader.construct_document(node)
        finally:
            loader.dispose()
    except RecursionError:
        raise BadInput(f"{source}: invalid YAML: nesting too deep (more than {MAX_YAML_DEPTH} levels "
                       f"allowed)") from None
    except (ValueError, OverflowError) as exc:      # e.g. int('9' * 5001): Python's digit limit
        raise BadInput(f"{source}: invalid YAML: {str(exc).splitlines()[0][:120]}") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        if mark is not None and str(problem).startswith("duplicate key"):
            key_path = _duplicate_key_path(text, mark.line)
            if key_path:
                raise BadInput(f"{source}:{where}: {key_path}: duplicate key; each key may appear "
                               f"only once in a mapping") from None
        raise BadInput(f"{source}:{where} invalid YAML: {problem}") from None


def _duplicate_key_path(text: str, line: int) -> str | None:
    """Dotted path of the repeated mapping key whose node starts on ``line`` (0-based), if found."""
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError:
        return None

    def walk(node, path):
        if isinstance(node, yaml.MappingNode):
            seen = set()
            for key_node, value_node in node.value:
                name = key_node.value if isinstance(key_node, yaml.ScalarNode) else "?"
                where = f"{path}.{name}" if path else str(name)
                if name in seen and key_node.start_mark.line == line:
                    return where
                seen.add(name)
                found = walk(value_node, where)
                if found:
                    return found
        elif isinstance(node, yaml.SequenceNode):
            for i, item in enumerate(node.value):
                found = walk(item, f"{path}[{i}]")
                if found:
                    return found
        return None

    return walk(root, "")
