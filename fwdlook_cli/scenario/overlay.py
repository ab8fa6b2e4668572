"""Processing presets (``-c configs/*.yaml``) merged over a scenario's ``processing:`` section."""
from __future__ import annotations


from ..errors import BadInput
from .loader import resolve_scenario


def load_config_overlay(path: str | None) -> dict:
    """A processing preset (configs/*.yaml): a mapping with a ``processing:`` section."""
    if not path:
        return {}
    from .readers import read_yaml_file

    raw = read_yaml_file(path, "config") or {}
    if not isinstance(raw, dict) or set(raw) - {"processing", "name"}:
        extra = sorted(set(raw) - {"processing", "name"}) if isinstance(raw, dict) else ["<not a mapping>"]
        raise BadInput(f"{path}: {extra[0]}: unknown key in a processing preset; allowed: processing")
    return raw.get("processing") or {}


def resolve_with_config(raw_scenario: dict, source: str, config_path: str | None, overrides, *,
                        check_pulses: bool = True) -> dict:
    """Scenario's own processing section, then the -c preset over it, then --set over both."""
    raw = dict(raw_scenario or {})
    overlay = load_config_overlay(config_path)
    if overlay:
        if not isinstance(overlay, dict):
            raise BadInput(f"{config_path}: processing: expected a mapping")
        proc = dict(raw.get("processing") or {})
        proc.update(overlay)
        raw["processing"] = proc
    try:
        return resolve_scenario(raw, source, overrides, check_pulses=check_pulses)
    except BadInput as exc:
        if config_path and "processing." in str(exc):
            raise BadInput(f"{exc} (with -c {config_path})") from None
        raise
