"""Processing presets (``-c configs/*.yaml``) merged over a scenario's ``processing:`` section."""
from __future__ import annotations

import re

from ..errors import BadInput
from .loader import resolve_scenario


def load_config_overlay(path: str | None) -> dict:
    """A processing preset (configs/*.yaml): a mapping with a ``processing:`` section."""
    if not path:
        return {}
    from .readers import read_yaml_file

    raw = read_yaml_file(path, "config")
    if not isinstance(raw, dict):            # empty or comment-only (None), a list, a scalar: had passed as
        # no preset at all, exit 0 (an independent review), where an empty scenario is refused
        got = "nothing (an empty or comment-only file)" if raw is None else f"a {type(raw).__name__}"
        raise BadInput(f"{path}: a processing preset holds {got}; expected a mapping with a processing: "
                       f"section (configs/*.yaml)")
    if set(raw) - {"processing", "name"}:
        extra = sorted(set(raw) - {"processing", "name"})
        raise BadInput(f"{path}: {extra[0]}: unknown key in a processing preset; allowed: processing")
    if not isinstance(raw.get("processing"), dict):
        raise BadInput(f"{path}: processing = {raw.get('processing')!r}: expected a mapping of processing keys")
    return raw["processing"]


def resolve_with_config(raw_scenario: dict, source: str, config_path: str | None, overrides, *,
                        check_pulses: bool = True) -> dict:
    """Scenario's own processing section, then the -c preset over it, then --set over both."""
    raw = dict(raw_scenario or {})
    overlay = load_config_overlay(config_path)         # (a mapping: load_config_overlay checks it)
    if overlay:
        proc = dict(raw.get("processing") or {})
        proc.update(overlay)
        raw["processing"] = proc
    try:
        return resolve_scenario(raw, source, overrides, check_pulses=check_pulses)
    except BadInput as exc:
        text = str(exc)
        key = re.match(rf"{re.escape(str(source))}: processing\.(\w+): unknown key", text)
        if key and key.group(1) in overlay and key.group(1) not in (raw_scenario or {}).get("processing", {}):
            # the preset's own key: its file named (it had read as the scenario's)
            raise BadInput(f"{config_path}{text[len(str(source)):]}") from None
        if config_path and "processing." in text:
            raise BadInput(f"{text} (with -c {config_path})") from None
        raise
