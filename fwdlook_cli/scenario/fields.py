"""Leaf validators of scenario keys: each returns the coerced value or raises ValueError(reason).

PyYAML follows YAML 1.1: ``18e9`` (no dot) is read as a string and ``on``/``off`` as booleans, so
every numeric leaf is coerced and checked here explicitly rather than trusted to the parser.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
import json
from typing import Any, Callable

from ..limits import MAX_MONOPULSE_SLOPE_PER_DEG


# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Field:
    """One scenario key: a checker that returns the coerced value or raises ValueError(reason)."""

    check: Callable[[Any], Any]
    default: Any
    doc: str


class _Required:
    def __repr__(self):
        return "<required>"


REQUIRED = _Required()


def _as_float(value: Any) -> float:
    if isinstance(value, bool) or value is None:
        raise ValueError("expected a number")
    if isinstance(value, (int, float)):
        out = float(value)
    elif isinstance(value, str):
        try:
            out = float(value.strip())  # YAML 1.1 reads '18e9' as a string
        except ValueError:
            raise ValueError("expected a number") from None
    else:
        raise ValueError("expected a number")
    if not math.isfinite(out):
        raise ValueError("expected a finite number")
    return out


def num(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False,
        hi_open: bool = False) -> Callable[[Any], float]:
    """A finite real number inside [lo, hi] (open ends where asked)."""

    def check(value):
        out = _as_float(value)
        if lo is not None and (out < lo or (lo_open and out == lo)):
            raise ValueError(f"must be {'>' if lo_open else '>='} {lo:g}")
        if hi is not None and (out > hi or (hi_open and out == hi)):
            raise ValueError(f"must be {'<' if hi_open else '<='} {hi:g}")
        return out

    check.kind = "number"
    return check


def integer(lo: int | None = None, hi: int | None = None) -> Callable[[Any], int]:
    def check(value):
        if isinstance(value, bool):
            raise ValueError("expected an integer")
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if isinstance(value, str):
            try:
                value = int(value.strip())
            except ValueError:
                try:                           # YAML 1.1 reads '4e2' as text, as it does '18e9' (_as_float)
                    whole = float(value.strip())
                except ValueError:
                    raise ValueError("expected an integer") from None
                if not (math.isfinite(whole) and whole.is_integer()):
                    raise ValueError("expected an integer") from None
                value = int(whole)
        if not isinstance(value, int):
            raise ValueError("expected an integer")
        if lo is not None and value < lo:
            raise ValueError(f"must be >= {lo}")
        if hi is not None and value > hi:
            raise ValueError(f"must be <= {hi}")
        if hi is None and value >= 2**63:     # stored as HDF5/NumPy int64 attributes
            raise ValueError("must be < 2**63")
        return value

    return check


def boolean(value: Any) -> bool:
    if not isinstance(value, bool):
        raise ValueError("expected true or false")
    return value


def choice(*allowed: str) -> Callable[[Any], str]:
    def check(value):
        if not isinstance(value, str) or value not in allowed:
            # YAML 1.1 reads off/on/no/yes unquoted as booleans: said where that is what arrived
            hint = " (YAML reads off, on, no and yes as true/false: quote a word)" if isinstance(value, bool) else ""
            raise ValueError(f"allowed: {', '.join(allowed)}{hint}")
        return value

    check.allowed = allowed
    return check


def text(value: Any) -> str:
    if not isinstance(value, str) or not value.strip():
        raise ValueError("expected a non-empty string")
    try:            # YAML's "\ud800" is a lone surrogate: no file name, HDF5 attribute or terminal takes it
        value.encode("utf-8")
    except UnicodeEncodeError as exc:
        raise ValueError(f"expected text that UTF-8 can encode (a lone surrogate {value[exc.start]!r} at "
                         f"character {exc.start})") from None
    return value


def folder_name(value: Any) -> str:
    """A scenario's name: also the folder of its default run (``runs/<name>``), so one path component."""
    value = text(value)
    if value.strip() in (".", "..") or any(c in value for c in "/\\\0") or len(value) > 200:
        raise ValueError("expected a name usable as one folder: no '/', '\\' or NUL, not '.' or '..', "
                         "at most 200 characters")
    return value


def vector(n: int, elem: Callable[[Any], float] = num()) -> Callable[[Any], list]:
    def check(value):
        if not isinstance(value, (list, tuple)) or len(value) != n:
            raise ValueError(f"expected a list of {n} numbers")
        return [elem(v) for v in value]

    return check


def auto_or(inner: Callable[[Any], Any]) -> Callable[[Any], Any]:
    def check(value):
        if value == "auto":
            return "auto"
        try:
            return inner(value)
        except ValueError as exc:
            raise ValueError(f"{exc} or 'auto'") from None

    return check


def optional(inner: Callable[[Any], Any]) -> Callable[[Any], Any]:
    def check(value):
        return None if value is None else inner(value)

    return check


def calibration_setting(value: Any):
    if value in ("auto", "cube", "data"):
        return value
    try:
        return num(0.0, MAX_MONOPULSE_SLOPE_PER_DEG, lo_open=True)(value)
    except ValueError:
        raise ValueError("allowed: auto, cube, data, or a slope per degree > 0") from None


def range_window(value: Any):
    # slant ranges > 0: one at 0 m had passed the scenario's check, then stopped the chain (a division by
    # the reference range, exit 1) and made a cube the reader refuses
    out = vector(2, num(0.0, lo_open=True))(value)
    if out[1] <= out[0]:
        raise ValueError("expected [near, far] with far > near")
    return out


def points_list(value: Any):
    if not isinstance(value, (list, tuple)) or not value:
        raise ValueError("expected a non-empty list of [x, y] ground points")
    return [vector(2)(p) for p in value]


MAX_AMPLITUDE = 1.0e4   # amplitudes are relative (noise.snr_db sets the noise against the strongest);
# 1e4 is a 1e8 m^2 RCS against a 1 m^2 one, and keeps the images' powers and fourth moments (a^4 N^4 at
# N = 1e4 integrated pulses: 1e32) inside float32 (at 1e38 the echo itself overflowed to Inf)


def amplitude(value: Any):
    if isinstance(value, (list, tuple)):
        if not value:
            raise ValueError("expected a positive number or a non-empty list of them")
        return [num(0.0, MAX_AMPLITUDE, lo_open=True)(v) for v in value]
    return num(0.0, MAX_AMPLITUDE, lo_open=True)(value)


def _is_number_text(text: str) -> bool:
    try:
        float(text.strip())
    except ValueError:
        return False
    return bool(text.strip())


def _show(value: Any) -> str:
    from ..limits import shown as _bounded

    cut = _bounded(value, 200)        # bounded time: never serialises a huge or alias-expanded value
    if len(cut) > 60 or cut.endswith("..."):
        return _bounded(value, 60)
    if isinstance(value, str) and _is_number_text(value):       # YAML 1.1's '-1e9': a number, shown as one
        return value.strip()
    shown = json.dumps(value, default=str) if not isinstance(value, str) else repr(value)
    return shown if len(shown) <= 60 else shown[:57] + "..."
