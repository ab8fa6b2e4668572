"""YAML that refuses duplicate keys, with the error naming the dotted key path."""
from __future__ import annotations

from typing import Any

import yaml

from ..errors import BadInput


class _StrictLoader(yaml.SafeLoader):
    """SafeLoader that refuses duplicate mapping keys (PyYAML silently keeps the last one)."""


def _construct_mapping(loader: _StrictLoader, node: yaml.MappingNode, deep: bool = False):
    loader.flatten_mapping(node)
    mapping = {}
    for key_node, value_node in node.value:
        key = loader.construct_object(key_node, deep=deep)
        if key in mapping:
            line = key_node.start_mark.line + 1
            raise yaml.constructor.ConstructorError(
                None, None, f"duplicate key {key!r} (line {line})", key_node.start_mark)
        mapping[key] = loader.construct_object(value_node, deep=deep)
    return mapping


_StrictLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def yaml_load(text: str, source: str) -> Any:
    """Parse YAML text strictly; a syntax error or a duplicate key becomes one BadInput line."""
    try:
        return yaml.load(text, Loader=_StrictLoader)
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
