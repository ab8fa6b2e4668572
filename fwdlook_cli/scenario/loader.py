"""Scenario files: strict loading, ``--set`` overrides, resolution against the schema, canonical hash.

The schemas (``forward.py``, ``isar.py`` beside this module) are the ONE place where every scenario key, its type, its default and its allowed
values are written down (CONTRACT.md section 2 fixes the names; the README's scenario table is this
file in prose).  ``load_scenario`` reads a YAML file, applies ``--set key.path=value`` overrides,
rejects duplicate keys, unknown keys, wrong types and impossible values with :class:`BadInput`, fills
the defaults, runs the cross-field checks and returns a plain nested dict (the *resolved* scenario).
"""
from __future__ import annotations

import copy
import hashlib
import json
from pathlib import Path
from typing import Any, Callable

import yaml


from ..errors import BadInput
from .forward import FORWARD_SCHEMA, forward_checks, warn_unused_scene_keys
from .isar import ISAR_SCHEMA, isar_checks
from .yamlio import yaml_load
from .fields import REQUIRED, _show

SCHEMAS = {"forward": FORWARD_SCHEMA, "isar": ISAR_SCHEMA}
CROSS_CHECKS: dict[str, Callable[..., None]] = {"forward": forward_checks, "isar": isar_checks}


# ----------------------------------------------------------------------------------------------
# Resolution
# ----------------------------------------------------------------------------------------------
def _resolve(raw: Any, schema: dict, path: str, source: str) -> dict:
    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        raise BadInput(f"{source}: {path or 'top level'}: expected a mapping, got {_show(raw)}")
    unknown = [k for k in raw if k not in schema]
    if unknown:
        key = unknown[0] if len(str(unknown[0])) <= 60 else _show(unknown[0])   # a 1 MB key, cut
        where = f"{path}.{key}" if path else str(key)
        raise BadInput(f"{source}: {where}: unknown key; allowed: {', '.join(schema)}")
    out = {}
    for key, spec in schema.items():
        where = f"{path}.{key}" if path else key
        if isinstance(spec, dict):
            out[key] = _resolve(raw.get(key), spec, where, source)
            continue
        if key not in raw:
            if spec.default is REQUIRED:
                raise BadInput(f"{source}: {where}: required key missing")
            out[key] = copy.deepcopy(spec.default)
            continue
        try:
            out[key] = spec.check(raw[key])
        except ValueError as exc:
            raise BadInput(f"{source}: {where} = {_show(raw[key])}: {exc}") from None
    return out


def apply_overrides(raw: dict, overrides: list[str] | tuple[str, ...], source: str) -> dict:
    """Apply ``--set a.b.c=value`` (value parsed as YAML) to the raw scenario mapping."""
    raw = copy.deepcopy(raw) if raw is not None else {}
    for item in overrides or ():
        if "=" not in item:
            raise BadInput(f"{source}: --set {item!r}: expected KEY.PATH=VALUE")
        key, value_text = item.split("=", 1)
        parts = key.strip().split(".")
        if not key.strip():
            raise BadInput(f"{source}: --set {item!r}: empty key path")
        if not all(parts):                 # 'processing..q', '.q': a typo, not a path
            raise BadInput(f"{source}: --set {item!r}: an empty key in the path; expected KEY.PATH=VALUE, "
                           f"e.g. processing.q=25")
        value = yaml_load(value_text, f"{source}: --set {key}")
        section = _is_section(raw, parts)
        if section and not isinstance(value, dict):
            hint = " (no noise: noise.snr_db=null)" if key.strip() == "noise" else ""
            raise BadInput(f"{source}: --set {key} = {_show(value)}: {key.strip()} is a section; allowed: a mapping "
                           f"of its keys (merged into it) or key paths inside it, e.g. --set {key.strip()}.KEY=VALUE"
                           f"{hint}")
        node = raw
        for i, part in enumerate(parts[:-1]):
            child = node.get(part)
            if child is None:
                child = node[part] = {}
            if not isinstance(child, dict):
                raise BadInput(f"{source}: --set {key}: {'.'.join(parts[:i + 1])} is not a mapping")
            node = child
        if section and isinstance(node.get(parts[-1]), dict):
            node[parts[-1]] = merged_mapping(node[parts[-1]], value)     # the keys it does not name are kept
        else:
            node[parts[-1]] = value
    return raw


def merged_mapping(base: dict, over: dict) -> dict:
    """``over`` merged into a (shallow) copy of ``base``, mapping by mapping (the values shared)."""
    out = dict(base)
    for k, v in over.items():
        out[k] = merged_mapping(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def _is_section(raw: dict, parts: list[str]) -> bool:
    """Whether the key path names a section of the schema (a mapping of keys). ``--set SECTION=VALUE``
    had replaced the whole section, every key the value did not name back to its default (``noise=null``
    meant tiny's noise at 20 dB and seed 1, ``processing={q: 4}`` its CPI at 32: an independent review):
    a mapping is now merged into the section, anything else refused."""
    kind = raw.get("kind", "forward")
    node = SCHEMAS.get(kind, FORWARD_SCHEMA) if isinstance(kind, str) else FORWARD_SCHEMA
    for part in parts:
        node = node.get(part) if isinstance(node, dict) else None
    return isinstance(node, dict)


def resolve_scenario(raw: Any, source: str = "<scenario>", overrides=(), *, check_pulses: bool = True) -> dict:
    """Validate a raw scenario mapping (plus overrides) and return the resolved scenario.

    ``check_pulses=False`` leaves out the checks against the scenario's own pulse count (Q divides it,
    the CPI fits it): for settings that will process a recorded cube, which is checked instead.
    """
    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        raise BadInput(f"{source}: top level: expected a mapping of scenario sections")
    raw = apply_overrides(raw, overrides, source)
    kind = raw.get("kind", "forward")
    if not isinstance(kind, str) or kind not in SCHEMAS:        # (a list or mapping is unhashable)
        raise BadInput(f"{source}: kind = {_show(kind)}: allowed: {', '.join(SCHEMAS)}")
    try:
        resolved = _resolve(raw, SCHEMAS[kind], "", source)
        if kind == "forward":
            CROSS_CHECKS[kind](resolved, source, check_pulses=check_pulses)
        else:
            CROSS_CHECKS[kind](resolved, source)
        _check_text_encodes(resolved, "", source)
    except BadInput as exc:
        raise _with_the_setting(exc, source, overrides) from None
    if kind == "forward":
        set_keys = set()                 # the scene keys the overrides name (scene.KEY..., or scene={KEY: ...})
        for item in overrides or ():
            path, value = (part.strip() for part in item.split("=", 1))
            if path.startswith("scene."):
                set_keys.add(path.split(".")[1])
            elif path == "scene" and isinstance(scene_value := yaml_load(value, source), dict):
                set_keys |= set(scene_value)
        warn_unused_scene_keys(raw.get("scene"), set_keys, source)      # a valid scenario only (one line else)
    return resolved


def _check_text_encodes(node, path: str, source: str) -> None:
    """Every string of a resolved scenario is written into the outputs (scenario.yaml, image.h5, metrics.json):
    a path made absolute from a folder whose name holds bytes that are not UTF-8 (Python keeps each as a lone
    surrogate) is refused here, in one line; it had passed ``validate`` and then ended ``simulate`` in a
    UnicodeEncodeError, exit 1 (the scenario's own strings are checked by ``fields.text``)."""
    if isinstance(node, dict):
        for key, value in node.items():
            _check_text_encodes(value, f"{path}.{key}" if path else str(key), source)
    elif isinstance(node, (list, tuple)):
        for value in node:
            _check_text_encodes(value, path, source)
    elif isinstance(node, str):
        try:
            node.encode("utf-8")
        except UnicodeEncodeError:
            raise BadInput(f"{source}: {path} = {_show(node)}: not UTF-8 text (a folder's name the file system "
                           f"holds as bytes), and every output records it; allowed: a path whose names are "
                           f"UTF-8") from None


def _with_the_setting(exc: BadInput, source: str, overrides) -> BadInput:
    """A refusal of a key that a ``--set`` gave names that setting too: it had read as the scenario
    file's own value (``tiny.yaml: processing.q = 7: ...`` for ``--set processing.q=7``; an independent
    review)."""
    text = str(exc)
    for item in reversed(list(overrides or ())):
        key = item.split("=", 1)[0].strip()
        if key and text.startswith(f"{source}: {key}") and text[len(source) + 2 + len(key):][:1] in (" ", ":", ""):
            return BadInput(f"{text} (set by --set {item.strip()})")
    return exc


def load_scenario(path: str | Path, overrides=()) -> dict:
    """Read, validate and resolve a scenario file (read by the one reader, ``readers.py``)."""
    from .readers import read_scenario_raw

    return resolve_scenario(read_scenario_raw(path), str(path), overrides)


def scenario_hash(resolved: dict) -> str:
    """SHA-256 of the canonical JSON form of a resolved scenario (sorted keys, floats repr'd)."""
    blob = json.dumps(resolved, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(blob.encode()).hexdigest()


def dump_scenario(resolved: dict) -> str:
    """Re-loadable YAML of a resolved scenario (not a dict repr); libyaml's emitter where PyYAML has it
    (``yaml.CSafeDumper``: the same text, about 10 times faster than the pure-Python one)."""
    dumper = getattr(yaml, "CSafeDumper", yaml.SafeDumper)
    return yaml.dump(resolved, Dumper=dumper, sort_keys=False, default_flow_style=None, width=100)
