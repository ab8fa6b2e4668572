"""Scenario files: schema, defaults, strict loading, cross-field checks, canonical hash.

The schema below is the ONE place where every scenario key, its type, its default and its allowed
values are written down (CONTRACT.md section 2 fixes the names; the README's scenario table is this
file in prose).  ``load_scenario`` reads a YAML file, applies ``--set key.path=value`` overrides,
rejects duplicate keys, unknown keys, wrong types and impossible values with :class:`BadInput`, fills
the defaults, runs the cross-field checks and returns a plain nested dict (the *resolved* scenario).

PyYAML follows YAML 1.1: ``18e9`` (no dot) is read as a string and ``on``/``off`` as booleans, so
every numeric leaf is coerced and checked here explicitly rather than trusted to the parser.
"""
from __future__ import annotations

import copy
import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import yaml

from .errors import BadInput

C_MPS = 299_792_458.0


# ----------------------------------------------------------------------------------------------
# YAML with duplicate-key rejection
# ----------------------------------------------------------------------------------------------
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


# ----------------------------------------------------------------------------------------------
# Leaf validators
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
                raise ValueError("expected an integer") from None
        if not isinstance(value, int):
            raise ValueError("expected an integer")
        if lo is not None and value < lo:
            raise ValueError(f"must be >= {lo}")
        if hi is not None and value > hi:
            raise ValueError(f"must be <= {hi}")
        return value

    return check


def boolean(value: Any) -> bool:
    if not isinstance(value, bool):
        raise ValueError("expected true or false")
    return value


def choice(*allowed: str) -> Callable[[Any], str]:
    def check(value):
        if not isinstance(value, str) or value not in allowed:
            raise ValueError(f"allowed: {', '.join(allowed)}")
        return value

    check.allowed = allowed
    return check


def text(value: Any) -> str:
    if not isinstance(value, str) or not value.strip():
        raise ValueError("expected a non-empty string")
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


def range_window(value: Any):
    out = vector(2, num(0.0))(value)
    if out[1] <= out[0]:
        raise ValueError("expected [near, far] with far > near")
    return out


def points_list(value: Any):
    if not isinstance(value, (list, tuple)) or not value:
        raise ValueError("expected a non-empty list of [x, y] ground points")
    return [vector(2)(p) for p in value]


def amplitude(value: Any):
    if isinstance(value, (list, tuple)):
        if not value:
            raise ValueError("expected a positive number or a non-empty list of them")
        return [num(0.0, lo_open=True)(v) for v in value]
    return num(0.0, lo_open=True)(value)


# ----------------------------------------------------------------------------------------------
# The schema: every key, its default and meaning (the one documented place for defaults)
# ----------------------------------------------------------------------------------------------
FORWARD_SCHEMA: dict[str, Any] = {
    "name": Field(text, "scenario", "scenario name, copied into outputs"),
    "kind": Field(choice("forward", "isar"), "forward",
                  "forward: forward-looking scanning monopulse radar; isar: stationary radar, moving object"),
    "radar": {
        "fc_hz": Field(num(1e6, 1e12), 18.0e9, "carrier frequency"),
        "bandwidth_hz": Field(num(0.0, lo_open=True), 50.0e6, "transmitted LFM bandwidth"),
        "pulse_width_s": Field(num(0.0, 1e-3, lo_open=True), 1.0e-6,
                               "LFM pulse width; the compressed pulse spans +-pulse_width"),
        "prf_hz": Field(num(0.0, lo_open=True), 2500.0, "pulse repetition frequency"),
        "fs_hz": Field(num(0.0, lo_open=True), 60.0e6,
                       "complex sampling rate of the range-compressed data (range sample c/(2 fs))"),
        "range_window_m": Field(auto_or(range_window), "auto",
                                "[near, far] slant range recorded, or auto: sized from scene and motion"),
        "n_pulses": Field(auto_or(integer(2, 10_000_000)), "auto",
                          "pulses recorded; auto: scan duration x PRF"),
        "range_weighting": Field(choice("none", "hamming", "hann", "taylor"), "none",
                                 "amplitude weighting of the matched filter (range sidelobes)"),
    },
    "antenna": {
        "beamwidth_3db_deg": Field(num(0.1, 90.0), 6.0, "one-way 3 dB width of the SUM beam"),
        "squint_deg": Field(num(0.0, 45.0, lo_open=True), 1.5,
                            "squint of each of the two Gaussian beams from the boresight"),
        "scan_start_deg": Field(num(-89.0, 89.0), -15.0, "beam azimuth at the first pulse"),
        "scan_stop_deg": Field(num(-89.0, 89.0), 15.0, "beam azimuth at the end of the scan"),
        "scan_rate_dps": Field(num(0.0, 1e4, lo_open=True), 30.0, "scan rate (deg/s)"),
    },
    "platform": {
        "speed_mps": Field(num(0.0, 1e4), 240.0, "initial forward speed v (along +y)"),
        "accel_mps2": Field(vector(3, num(-1e3, 1e3)), [0.0, 0.0, 0.0],
                            "[a_x transverse, a_y forward, a_z vertical] (paper Fig. 1)"),
        "height_m": Field(num(0.0, 1e5), 50.0, "antenna height at t = 0 (NOTES.md: 50 m)"),
    },
    "scene": {
        "kind": Field(choice("lattice", "points", "image"), "lattice", "lattice | points | image"),
        "center_m": Field(vector(2), [0.0, 1700.0], "ground (x, y) of the lattice or image centre"),
        "lattice": {
            "nx": Field(integer(1, 10_000), 21, "points across x"),
            "ny": Field(integer(1, 10_000), 3, "points along y"),
            "spacing_m": Field(num(0.0, lo_open=True), 30.0, "lattice spacing"),
            "x_stride": Field(integer(1, 10_000), 1, "keep every x_stride-th column (isolation runs)"),
            "x_offset": Field(integer(0, 10_000), 0, "first column kept (0 <= x_offset < x_stride)"),
        },
        "points_m": Field(optional(points_list), None, "kind: points, ground (x, y) list, z = 0"),
        "image": {  # kind: image (fwdlook_cli/scene_image.py)
            "file": Field(optional(text), None,
                          "reflectivity map: PNG, TIFF, .npy, path.h5:/dataset, or procedural:roads"),
            "pixel_spacing_m": Field(num(0.01, 1000.0), 3.0, "square pixel size on the ground"),
            "orientation_deg": Field(num(-360.0, 360.0), 0.0,
                                     "azimuth of the image's up direction, from +y towards +x"),
            "intensity": Field(choice("amplitude", "power"), "amplitude",
                               "pixel value is the amplitude, or the power (amplitude = sqrt)"),
            "threshold": Field(num(0.0, 1.0, hi_open=True), 0.0,
                               "drop pixels below this normalised amplitude (max pixel = 1)"),
            "speckle": Field(boolean, True, "random phase per pixel from noise.seed"),
            "size_px": Field(vector(2, integer(8, 4096)), [200, 200], "procedural:roads: [nx, ny] pixels"),
            "procedural_seed": Field(integer(0), 0, "procedural:roads: seed of the field texture"),
        },
        "amplitude": Field(amplitude, 1.0, "common amplitude, or one per point"),
    },
    "noise": {
        "snr_db": Field(optional(num(-100.0, 300.0)), 20.0,
                        "peak SNR of a unit target at beam centre, per range-compressed sample; null: no noise"),
        "seed": Field(integer(0), 1, "seed of the noise generator"),
    },
    "simulation": {
        "gain_threshold_db": Field(num(-1000.0, 0.0), -60.0,
                                   "skip a target-pulse pair whose two-way power gain is below this"),
    },
    "processing": {
        "method": Field(choice("none", "bulk", "beam", "traditional", "decimation", "tracking", "auto"),
                        "decimation", "motion-compensation method"),
        "q": Field(integer(1), 25, "decimation factor (must divide the pulse count)"),
        "keystone": Field(choice("czt", "dft", "sinc"), "czt", "keystone implementation"),
        "range_curvature": Field(boolean, True, "eq. (12) range-curvature compensation"),
        "curvature_model": Field(choice("auto", "eq12", "beam"), "auto",
                                 "eq12: the paper's a_y cos(phi_0) t^2 / 2; beam: the exact residual a keystone "
                                 "leaves for each pulse's beam-centre point; auto: eq12 for the paper's methods "
                                 "(traditional, decimation), beam for tracking"),
        "doppler_centroid": Field(boolean, True, "eq. (23)-(26) per-CPI Doppler-centroid compensation"),
        "cpi": Field(integer(2), 32, "pulses per CPI for monopulse imaging"),
        "ambiguity_speed": Field(choice("t_ref", "initial"), "t_ref",
                                 "speed of the boresight Doppler that fixes the ambiguity number F (eq. 16-17): "
                                 "at t_ref, or the initial v of the paper (the same for t_ref = start)"),
        "t_ref": Field(choice("start", "centre"), "centre", "time the corrected image refers to"),
        "n_doppler": Field(integer(4, 4096), 64, "zoomed Doppler cells per CPI over the main-beam band"),
        "doppler_window": Field(choice("none", "hamming", "hann", "taylor"), "none",
                                "slow-time window of each CPI before the Doppler zoom"),
        "range_oversample": Field(integer(1, 16), 4, "band-limited range oversampling of the image"),
        "angle_step_deg": Field(num(1e-4, 1.0), 0.05, "angle bin of the monopulse image"),
        "threshold_db": Field(num(-50.0, 100.0), 12.0,
                              "Doppler cells projected only above this many dB over the CPI noise floor"),
    },
}

SCHEMAS = {"forward": FORWARD_SCHEMA}


def register_schema(kind: str, schema: dict) -> None:
    """Another scenario kind (e.g. ISAR) plugs its own schema in."""
    SCHEMAS[kind] = schema


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
        key = unknown[0]
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


def _show(value: Any) -> str:
    shown = json.dumps(value, default=str) if not isinstance(value, str) else repr(value)
    return shown if len(shown) <= 60 else shown[:57] + "..."


def apply_overrides(raw: dict, overrides: list[str] | tuple[str, ...], source: str) -> dict:
    """Apply ``--set a.b.c=value`` (value parsed as YAML) to the raw scenario mapping."""
    raw = copy.deepcopy(raw) if raw is not None else {}
    for item in overrides or ():
        if "=" not in item:
            raise BadInput(f"{source}: --set {item!r}: expected KEY.PATH=VALUE")
        key, value_text = item.split("=", 1)
        parts = [p for p in key.strip().split(".") if p]
        if not parts:
            raise BadInput(f"{source}: --set {item!r}: empty key path")
        value = yaml_load(value_text, f"{source}: --set {key}")
        node = raw
        for i, part in enumerate(parts[:-1]):
            child = node.get(part)
            if child is None:
                child = node[part] = {}
            if not isinstance(child, dict):
                raise BadInput(f"{source}: --set {key}: {'.'.join(parts[:i + 1])} is not a mapping")
            node = child
        node[parts[-1]] = value
    return raw


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
    if kind == "isar" and "isar" not in SCHEMAS:
        from . import isar  # noqa: F401  (registers the ISAR schema and its checks)
    if kind not in SCHEMAS:
        raise BadInput(f"{source}: kind = {_show(kind)}: allowed: {', '.join(SCHEMAS)}")
    resolved = _resolve(raw, SCHEMAS[kind], "", source)
    if kind == "forward":
        CROSS_CHECKS[kind](resolved, source, check_pulses=check_pulses)
    else:
        CROSS_CHECKS[kind](resolved, source)
    return resolved


def load_scenario(path: str | Path, overrides=()) -> dict:
    """Read, validate and resolve a scenario file."""
    path = Path(path)
    source = str(path)
    try:
        text_ = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise BadInput(f"{source}: scenario file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise BadInput(f"{source}: cannot read scenario file ({exc.__class__.__name__})") from None
    return resolve_scenario(yaml_load(text_, source), source, overrides)


def scenario_hash(resolved: dict) -> str:
    """SHA-256 of the canonical JSON form of a resolved scenario (sorted keys, floats repr'd)."""
    blob = json.dumps(resolved, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(blob.encode()).hexdigest()


def dump_scenario(resolved: dict) -> str:
    """Re-loadable YAML of a resolved scenario (not a dict repr)."""
    return yaml.safe_dump(resolved, sort_keys=False, default_flow_style=None, width=100)


# ----------------------------------------------------------------------------------------------
# Derived quantities and cross-field checks (forward-looking)
# ----------------------------------------------------------------------------------------------
def scan_duration_s(scn: dict) -> float:
    ant = scn["antenna"]
    return abs(ant["scan_stop_deg"] - ant["scan_start_deg"]) / ant["scan_rate_dps"]


def n_pulses(scn: dict) -> int:
    """Pulse count: explicit, or the scan duration times the PRF (paper: 1 s x 2500 Hz = 2500)."""
    value = scn["radar"]["n_pulses"]
    if value != "auto":
        return int(value)
    return max(2, int(round(scan_duration_s(scn) * scn["radar"]["prf_hz"])))


def scene_points(scn: dict):
    """Ground (x, y) of every scene point and its amplitude, as two lists."""
    sc = scn["scene"]
    if sc["kind"] == "lattice":
        lat = sc["lattice"]
        cx, cy = sc["center_m"]
        xs = [cx + (i - (lat["nx"] - 1) / 2) * lat["spacing_m"] for i in range(lat["nx"])
              if i % lat["x_stride"] == lat["x_offset"]]
        ys = [cy + (j - (lat["ny"] - 1) / 2) * lat["spacing_m"] for j in range(lat["ny"])]
        pts = [[x, y] for y in ys for x in xs]
    elif sc["kind"] == "image":
        from .scene_image import image_scene_points

        return image_scene_points(scn)         # arrays: [n, 2] ground points, complex amplitudes
    else:
        pts = sc["points_m"]
    amp = sc["amplitude"]
    amps = list(amp) if isinstance(amp, list) else [amp] * len(pts)
    return pts, amps


def _forward_checks(scn: dict, source: str, *, check_pulses: bool = True) -> None:
    radar, ant, sc, proc = scn["radar"], scn["antenna"], scn["scene"], scn["processing"]
    if radar["fs_hz"] < radar["bandwidth_hz"]:
        raise BadInput(f"{source}: radar.fs_hz = {radar['fs_hz']:g}: must be >= radar.bandwidth_hz "
                       f"= {radar['bandwidth_hz']:g} (complex sampling of the compressed pulse)")
    if ant["scan_stop_deg"] <= ant["scan_start_deg"]:
        raise BadInput(f"{source}: antenna.scan_stop_deg = {ant['scan_stop_deg']:g}: must be > "
                       f"antenna.scan_start_deg = {ant['scan_start_deg']:g}")
    lat = sc["lattice"]
    if sc["kind"] == "lattice" and (lat["x_offset"] >= lat["x_stride"] or lat["x_offset"] >= lat["nx"]):
        raise BadInput(f"{source}: scene.lattice.x_offset = {lat['x_offset']}: must be below x_stride "
                       f"({lat['x_stride']}) and nx ({lat['nx']})")
    if sc["kind"] == "points" and sc["points_m"] is None:
        raise BadInput(f"{source}: scene.points_m: required when scene.kind is points")
    if sc["kind"] == "image":
        from .scene_image import check_image_scene

        check_image_scene(scn, source)
    try:
        from .antenna import MonopulseAntenna

        MonopulseAntenna(ant["beamwidth_3db_deg"], ant["squint_deg"])
    except ValueError as exc:
        raise BadInput(f"{source}: antenna.squint_deg = {ant['squint_deg']:g}: {exc}") from None
    pts, amps = scene_points(scn)
    if isinstance(sc["amplitude"], list) and len(sc["amplitude"]) != len(pts):
        raise BadInput(f"{source}: scene.amplitude: list of {len(sc['amplitude'])} values; "
                       f"allowed: one number or one per point ({len(pts)})")
    m = n_pulses(scn)
    if radar["n_pulses"] != "auto":
        needed = scan_duration_s(scn) * radar["prf_hz"]
        if m > needed + 1.0 + 1e-9:
            raise BadInput(f"{source}: radar.n_pulses = {m}: the scan lasts {scan_duration_s(scn):g} s, "
                           f"at most {int(needed) + 1} pulses fit it at prf_hz = {radar['prf_hz']:g}")
    if check_pulses and m % proc["q"]:
        raise BadInput(f"{source}: processing.q = {proc['q']}: must divide the pulse count {m}")
    if check_pulses and proc["cpi"] > m:
        raise BadInput(f"{source}: processing.cpi = {proc['cpi']}: longer than the {m} pulses")
    if radar["range_window_m"] != "auto":
        from .geometry import scene_range_extent_m  # local: geometry imports nothing from here

        near, far = radar["range_window_m"]
        r_min, r_max = scene_range_extent_m(scn)
        if r_min < near or r_max > far:
            raise BadInput(f"{source}: radar.range_window_m = [{near:g}, {far:g}]: the scene spans "
                           f"slant ranges {r_min:.1f} to {r_max:.1f} m over the scan; widen the window "
                           f"or use auto")


CROSS_CHECKS: dict[str, Callable[[dict, str], None]] = {"forward": _forward_checks}
