"""HDF5 at the edges: atomic writes, dimension scales, units, provenance; the raw-cube reader.

Every file is written to ``NAME.partial`` (claimed by ``io.partial.claim_partial``: never through a link,
never over a file fwdlook did not make) and renamed into place with ``os.replace``, so a failed or
interrupted command never leaves a file that looks complete.  Every dataset carries ``units`` and
``long_name``; coordinates are HDF5 dimension scales so that netCDF-aware readers see named axes.
The raw-cube reader accepts any file in the CONTRACT.md section 3 layout, whoever wrote it, and
rejects a missing, mis-shaped, wrongly typed or non-finite dataset with one :class:`BadInput` line.
"""
from __future__ import annotations

import logging
import os
from pathlib import Path

import h5py
import numpy as np

from . import backing
from .cube import RADAR_KEYS, RawCube
from .xr import units_of_name
from ..dsp.geometry import C_MPS
from ..dsp.pulse import WEIGHTINGS, pulse_rule_broken
from ..dsp.keystone_common import carrier_floor_text
from ..errors import BadInput
from .describe import _plain
from .navigation import SMOOTHING_S, check_navigation, kept_float32_step, velocity_integral_m
from .track import least_squares_uniform, restore_float32_track
from .h5 import atomic_h5, put, put_scale
from ..limits import check_declared_dataset, outside_scenario_range, shown

RAW_FORMAT = "fwdlook-raw"
RAW_FORMAT_VERSION = 1
log = logging.getLogger(__name__)


# ----------------------------------------------------------------------------------------------
# Raw cube
# ----------------------------------------------------------------------------------------------
def write_raw(path: str | Path, cube: RawCube) -> None:
    """Write a raw cube in the CONTRACT.md section 3 layout, atomically."""
    with atomic_h5(path) as f:
        f.attrs["format"] = RAW_FORMAT
        f.attrs["format_version"] = RAW_FORMAT_VERSION
        for key, value in cube.attrs.items():
            f.attrs[key] = value
        if cube.scenario_yaml is not None:
            f.attrs["scenario"] = cube.scenario_yaml
        # the dimension scales live at the root, where netCDF readers (xarray + h5netcdf) find them
        # from every group; /axes/* (CONTRACT.md 3) and /echo/* are hard links to the same datasets
        t = put_scale(f, "slow_time_s", cube.slow_time_s.astype(np.float64), "s",
                      "slow time, t = 0 at the first pulse")
        r = put_scale(f, "range_m", cube.range_m.astype(np.float64), "m", "slant range")
        axes = f.create_group("axes")
        axes["slow_time_s"], axes["range_m"] = t, r
        put(axes, "scan_angle_deg", cube.scan_angle_deg.astype(np.float64), "deg",
            "beam pointing azimuth atan2(dx, dy)", dims=(t,))
        echo = f.create_group("echo")
        echo["slow_time_s"], echo["range_m"] = t, r
        if cube.diff is None:  # single channel (ISAR): only /echo/sum, marked by the root attr
            f.attrs["channels"] = "sum"
        for name, data, what in (("sum", cube.sum, "sum"), ("diff", cube.diff, "difference")):
            if data is None:
                continue
            put(echo, name, data.astype(np.complex64, copy=False), "1",
                f"range-compressed baseband echo, {what} channel", dims=(t, r), chunks=True)
        for key, value in cube.noise.items():
            echo.attrs[f"noise_{key}"] = value
        radar = f.create_group("radar")
        for key, value in cube.radar.items():
            radar.attrs[key] = value
        if cube.antenna:
            ant = f.create_group("antenna")
            for key, value in cube.antenna.items():
                if key not in ANTENNA_DATASETS:
                    ant.attrs[key] = value
            # the ratio table: the offsets a dimension scale of the ratio (xarray and netCDF readers see
            # ratio(ratio_offset_deg), not a dimension without a name)
            table = {key: np.asarray(cube.antenna[key], dtype=np.float64) for key in ANTENNA_DATASETS
                     if key in cube.antenna}
            offset = None
            if "ratio_offset_deg" in table:
                offset = put_scale(ant, "ratio_offset_deg", table["ratio_offset_deg"],
                                   *ANTENNA_DATASETS["ratio_offset_deg"])
            if "ratio" in table:
                same = offset is not None and offset.shape == table["ratio"].shape
                put(ant, "ratio", table["ratio"], *ANTENNA_DATASETS["ratio"], dims=(offset,) if same else ())
        plat = f.create_group("platform")
        xyz = put_scale(plat, "xyz", np.arange(3), "1", "axis: 0 = x cross-range, 1 = y forward, 2 = z up")
        put(plat, "position_m", cube.position_m.astype(np.float64), "m",
            "antenna phase centre (x, y, z) per pulse (INS)", dims=(t, xyz))
        put(plat, "velocity_mps", cube.velocity_mps.astype(np.float64), "m/s",
            "antenna phase-centre velocity per pulse (INS)", dims=(t, xyz))
        if cube.truth:
            tg = f.create_group("truth/targets")
            n_t = len(np.atleast_1d(cube.truth["x_m"]))
            tid = put_scale(tg, "target", np.arange(n_t), "1", "target index")
            for key, units in (("x_m", "m"), ("y_m", "m"), ("z_m", "m"), ("amplitude", "1")):
                put(tg, key, np.asarray(cube.truth[key], dtype=np.float64), units, f"target {key}", dims=(tid,))
            for key in sorted(cube.truth.keys() - set(TRUTH_KEYS)):  # extra truth, e.g. vx_mps
                put(tg, key, np.asarray(cube.truth[key], dtype=np.float64), units_of_name(key),
                    f"target {key}", dims=(tid,))


TRUTH_KEYS = ("x_m", "y_m", "z_m", "amplitude")
ANTENNA_DATASETS = {"ratio_offset_deg": ("deg", "angle offset from the beam axis of the ratio table"),
                    "ratio": ("1", "monopulse ratio Re(diff/sum), monotone over the main lobe")}


def _need(f: h5py.File, path: str, source: str) -> h5py.Dataset:
    obj = f.get(path)
    if not isinstance(obj, h5py.Dataset):
        raise BadInput(f"{source}: /{path}: dataset missing")
    if obj.shape is None:                          # h5py.Empty: a null dataspace, no values at all
        raise BadInput(f"{source}: /{path}: an empty (null) dataspace; expected an array of values")
    return obj


UNIT_SPELLINGS = {"m": ("m", "meter", "metre", "meters", "metres"), "s": ("s", "sec", "second", "seconds"),
                  "deg": ("deg", "degree", "degrees"), "m/s": ("m/s", "m s-1", "m s^-1", "m.s-1", "mps")}


def _check_units(ds, path: str, source: str) -> None:
    """A dataset whose name says its unit (``_m``, ``_s``, ``_deg``, ``_mps``) in that unit: another unit
    (``km``) is refused, not read as metres; none at all is read as the name says (a plain writer's
    cube, as the tests' own minimal one, need not repeat it)."""
    want = units_of_name(path.rsplit("/", 1)[-1])
    units = ds.attrs.get("units") if want != "1" else None
    if units is None:
        return
    text = _plain(units)
    if not isinstance(text, str) or text.strip().lower() not in UNIT_SPELLINGS[want]:
        raise BadInput(f"{source}: /{path}: units = {shown(text)}; allowed: {want} (the unit its name says)")


def _attr_number(value) -> float:
    """A real number from an attribute: a Python or numpy integer or float (a one-element array too); a
    boolean, a complex value or text raise TypeError (``float(True)`` is 1, and numpy's complex drops
    its imaginary part with a warning)."""
    value = _plain(value)
    if isinstance(value, np.ndarray) and value.size == 1:
        value = value.reshape(()).item()
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TypeError(f"not a real number: {type(value).__name__}")
    return float(value)


def _array(f, path, source, *, kind, shape, complex_ok=False):
    """Read one dataset, checking dtype kind, shape and finiteness."""
    ds = _need(f, path, source)
    dt = ds.dtype
    if complex_ok:
        if dt.kind != "c":
            raise BadInput(f"{source}: /{path}: dtype {dt} not allowed; allowed: complex64 "
                           f"(or complex128)")
    elif dt.kind not in "f":
        raise BadInput(f"{source}: /{path}: dtype {dt} not allowed; allowed: float64 (or float32)")
    if ds.shape != shape:
        want = "[" + ", ".join(str(s) for s in shape) + "]"
        raise BadInput(f"{source}: /{path}: shape {list(ds.shape)}, expected {want}")
    _check_units(ds, path, source)
    check_declared_dataset(source, path, ds.shape, dt.itemsize)   # before the read allocates it
    data = backing.read_dataset(ds)      # file-backed, block by block, in an out-of-core run
    bad = backing.count_nonfinite(data)
    if bad:
        raise BadInput(f"{source}: /{path}: {bad} NaN/Inf values; allowed: finite values only")
    if data.dtype != kind and backing.active():       # converted block by block, file-backed too
        return backing.map_blocks(lambda s: data[s].astype(kind), len(data), data.shape, kind, data[0].nbytes)
    return data.astype(kind, copy=False)


def read_raw(path: str | Path) -> RawCube:
    """Read and validate a raw cube written by anyone in the CONTRACT.md section 3 layout."""
    path = Path(path)
    source = str(path)
    if not path.exists():
        raise BadInput(f"{source}: file not found")
    try:
        f = h5py.File(path, "r")
    except PermissionError:
        raise BadInput(f"{source}: permission denied; the file must be readable") from None
    except OSError:
        if path.is_dir():
            raise BadInput(f"{source}: is a directory, not an HDF5 file") from None
        if not os.access(path, os.R_OK):
            raise BadInput(f"{source}: permission denied; the file must be readable") from None
        raise BadInput(f"{source}: not a readable HDF5 file (truncated or not HDF5)") from None
    try:
        with f:
            return _read_raw_open(f, source)
    except (OSError, KeyError, RuntimeError) as exc:
        raise BadInput(f"{source}: HDF5 read failed ({exc.__class__.__name__}: "
                       f"{str(exc).splitlines()[0][:200] if str(exc) else ''}); the file may be truncated") from None


def _read_raw_open(f: h5py.File, source: str) -> RawCube:
    fmt = f.attrs.get("format")
    if isinstance(fmt, bytes):
        fmt = fmt.decode(errors="replace")
    if not isinstance(fmt, str) or fmt != RAW_FORMAT:
        raise BadInput(f"{source}: / attribute format = {shown(fmt)}; allowed: {RAW_FORMAT!r}")
    try:
        version = int(f.attrs.get("format_version", -1))
    except (TypeError, ValueError, OverflowError):
        version = None
    if version != RAW_FORMAT_VERSION:
        raise BadInput(f"{source}: / attribute format_version = {shown(f.attrs.get('format_version'))}; "
                       f"allowed: {RAW_FORMAT_VERSION}")
    echo_sum_ds = _need(f, "echo/sum", source)
    if echo_sum_ds.ndim != 2 or min(echo_sum_ds.shape) < 2:
        raise BadInput(f"{source}: /echo/sum: shape {list(echo_sum_ds.shape)}, expected "
                       f"[n_pulses, n_range] with both >= 2")
    n_p, n_r = echo_sum_ds.shape
    check_declared_dataset(source, "echo/sum", (n_p, n_r), 8 * (1 if "diff" not in f["echo"] else 2))
    hint = backing.memory_hint(n_p * n_r * 8 * (1 if "diff" not in f["echo"] else 2))
    if hint:                               # said before the read that may not fit
        log.warning(f"{source}: {hint}")
    echo_sum = _array(f, "echo/sum", source, kind=np.complex64, shape=(n_p, n_r), complex_ok=True)
    channels = _plain(f.attrs.get("channels", "sum,diff"))
    if isinstance(channels, str) and channels == "sum" and "diff" not in f["echo"]:
        echo_diff = None  # single-channel cube (ISAR): / attribute channels = "sum"
    else:
        echo_diff = _array(f, "echo/diff", source, kind=np.complex64, shape=(n_p, n_r), complex_ok=True)
    slow_time_s = _array(f, "axes/slow_time_s", source, kind=np.float64, shape=(n_p,))
    range_m = _array(f, "axes/range_m", source, kind=np.float64, shape=(n_r,))
    scan = _array(f, "axes/scan_angle_deg", source, kind=np.float64, shape=(n_p,))
    position = _array(f, "platform/position_m", source, kind=np.float64, shape=(n_p, 3))
    velocity = _array(f, "platform/velocity_mps", source, kind=np.float64, shape=(n_p, 3))
    dt = np.diff(slow_time_s)
    if np.any(dt <= 0):
        raise BadInput(f"{source}: /axes/slow_time_s: not strictly increasing")
    _check_motion(position, velocity, dt, source, stored_dtype=f["platform/position_m"].dtype)
    _check_echo_scale((echo_sum, echo_diff), source)
    range_m = _uniform_range_axis(range_m, f["axes/range_m"].dtype, source)
    if range_m[0] <= 0:
        raise BadInput(f"{source}: /axes/range_m: first slant range {range_m[0]:g} m; allowed: > 0 m")
    worst_scan = float(np.max(np.abs(scan)))
    isar = echo_diff is None or _plain(f.attrs.get("scenario_kind", "")) == "isar"   # its angle: the aspect
    if worst_scan >= MAX_SCAN_DEG and not isar:
        raise BadInput(f"{source}: /axes/scan_angle_deg: |angle| reaches {worst_scan:g} deg; allowed: "
                       f"below {MAX_SCAN_DEG:g} deg off the flight axis (a forward-looking scan)")
    radar_grp = f.get("radar")
    if not isinstance(radar_grp, h5py.Group):
        raise BadInput(f"{source}: /radar: group missing")
    radar = {}
    optional = tuple(key for key in OPTIONAL_RADAR_NUMBERS if key in radar_grp.attrs)   # where recorded
    for key in RADAR_KEYS + optional:
        if key not in radar_grp.attrs:
            raise BadInput(f"{source}: /radar attribute {key}: missing; required: {', '.join(RADAR_KEYS)}")
        value = radar_grp.attrs[key]
        try:
            value = _attr_number(value)
        except (TypeError, ValueError):
            raise BadInput(f"{source}: /radar attribute {key} = {shown(value)}: expected a real number (not "
                           f"text, a boolean or a complex value)") from None
        if not np.isfinite(value) or value <= 0:
            raise BadInput(f"{source}: /radar attribute {key} = {shown(value)}: must be a positive number")
        if why := outside_scenario_range(key, value):       # (limits.CUBE_ATTRIBUTE_RANGES)
            raise BadInput(f"{source}: /radar attribute {key} = {value:.9g}; {why}")
        radar[key] = value
    # (h5py's items() holds its global lock while the loop's body runs: an exception raised in a comprehension's
    # body (its iterator a local of its own frame before Python 3.12), its traceback kept by the caller, left
    # the lock held and a stage writer's thread waiting on it for ever; every loop over an HDF5 object's
    # items here reads them into a list first)
    for key, value in list(radar_grp.attrs.items()):
        if key not in radar:
            radar[key] = _plain(value)
    _check_optional_radar(radar, source)
    _check_pulse_timing(slow_time_s, radar["prf_hz"], source)
    if not isar:     # float32 rounding that reaches the phases (io/track.py; ISAR forms none from the track)
        stored_position, stored_dtype = position, f["platform/position_m"].dtype
        slow_time_s, position = restore_float32_track(
            slow_time_s, position, velocity, time_dtype=f["axes/slow_time_s"].dtype,
            position_dtype=stored_dtype, fc_hz=radar["fc_hz"], source=source)
        check_navigation(slow_time_s, position, velocity, scan_angle_deg=scan, beamwidth_deg=radar["beamwidth_3db_deg"],
                         fc_hz=radar["fc_hz"], range_m=range_m, source=source,
                         rounding_m=kept_float32_step(stored_dtype, stored_position, position))
    _check_radar_values(radar, float(range_m[1] - range_m[0]), n_r, source)
    antenna = _read_antenna(f, source)
    noise = _read_noise(f["echo"].attrs, source)
    truth = None
    tg = f.get("truth/targets")
    if isinstance(tg, h5py.Group):
        n_t = None
        truth = {}
        for key in ("x_m", "y_m", "z_m", "amplitude"):
            ds = _need(f, f"truth/targets/{key}", source)
            n_t = ds.shape[0] if n_t is None else n_t
            truth[key] = _array(f, f"truth/targets/{key}", source, kind=np.float64, shape=(n_t,))
            far = float(np.max(np.abs(truth[key]), initial=0.0))
            if key != "amplitude" and far > MAX_DISTANCE_M:
                raise BadInput(f"{source}: /truth/targets/{key}: reaches {far:.3g} m; allowed: within "
                               f"{MAX_DISTANCE_M:g} m of the origin")
        for key in sorted(set(tg) - set(TRUTH_KEYS)):  # extra per-target truth: 1-D, same length
            ds = tg[key]
            if isinstance(ds, h5py.Dataset) and ds.shape == (n_t,) and ds.dtype.kind == "f":
                truth[key] = _array(f, f"truth/targets/{key}", source, kind=np.float64, shape=(n_t,))
    scenario = f.attrs.get("scenario")
    if scenario is None and isinstance(f.get("scenario"), h5py.Dataset):
        scenario = f["scenario"][()]
    if isinstance(scenario, bytes):
        try:
            scenario = scenario.decode()
        except UnicodeDecodeError:       # informational only: said, then left out
            log.warning(f"{source}: /scenario is not UTF-8 text; ignored (it only records what made the file)")
            scenario = None
    if scenario is not None and not isinstance(scenario, str):
        scenario = None
    attrs = {k: _plain(v) for k, v in list(f.attrs.items()) if k not in ("scenario",)}
    return RawCube(sum=echo_sum, diff=echo_diff, slow_time_s=slow_time_s, range_m=range_m,
                   scan_angle_deg=scan, position_m=position, velocity_mps=velocity, radar=radar,
                   antenna=antenna, truth=truth, scenario_yaml=scenario, noise=noise, attrs=attrs)


MAX_SCAN_DEG = 90.0           # a forward-looking scan points ahead of the platform
MAX_SPEED_MPS = 1e4           # the scenario's own bound on platform.speed_mps (a satellite's 7.8 km/s under it)
MAX_DISTANCE_M = 1e7          # positions and truth within 10 000 km of the origin
MAX_FOCUSED_AMPLITUDE = 1e18  # largest |sample| x pulses: a focused peak's power (1e36) inside float32 (3.4e38)
MAX_BEAMWIDTH_DEG = 90.0      # the scenario's own bound on antenna.beamwidth_3db_deg
TIMING_JITTER_FRACTION = 0.01  # of a pulse interval: 2 pi fd dt <= 0.031 rad at the Doppler band's edge
PRF_TOLERANCE = 1e-4          # relative: prf_hz against the slow-time axis' own mean rate
RANGE_STEP_TOLERANCE = 1e-3   # relative: range step against c / (2 fs) (c rounded to 3e8 is 7e-4 off)
VELOCITY_TOLERANCE = 0.1      # relative, and VELOCITY_TOLERANCE_MPS absolute: the recorded velocities against
VELOCITY_TOLERANCE_MPS = 1.0  # the positions' differences (a flipped axis is 2 x the speed off, an INS's noise cm/s)


def _uniform_range_axis(range_m: np.ndarray, stored_dtype, source: str) -> np.ndarray:
    """The range axis, uniformly increasing: equal steps within 1e-6 of the step, or within the rounding
    of the dtype it was stored in (a float32 axis holds 1.5 km to 1.2e-4 m: its steps vary by 1e-4 of a
    2.5 m step, and it had been refused as "not uniformly increasing"); such an axis is replaced by its
    least-squares uniform axis in float64 (within that rounding of the stored values)."""
    dr = np.diff(range_m)                     # (at least two samples: the reader's shape check)
    rounding = 4.0 * float(np.finfo(stored_dtype).eps) * float(np.max(np.abs(range_m)))
    if np.any(dr <= 0) or np.ptp(dr) > 1e-6 * abs(dr[0]) + rounding:
        raise BadInput(f"{source}: /axes/range_m: not uniformly increasing (steps {float(dr.min()):.9g} to "
                       f"{float(dr.max()):.9g} m); allowed: equal positive steps, within 1e-6 of the step or the "
                       f"rounding of its dtype ({np.dtype(stored_dtype)})")
    if np.ptp(dr) <= 1e-6 * abs(dr[0]):
        return range_m                        # float64 axes as they are (the same numbers as before)
    centre, step, n = least_squares_uniform(range_m)
    return centre + step * n


def _check_pulse_timing(slow_time_s: np.ndarray, prf_hz: float, source: str) -> None:
    """The chain's slow-time FFTs need uniform pulses: every pulse within 1 % of an interval of a
    uniform train (a dropped pulse or a gap is a whole interval), and ``prf_hz`` equal to the
    least-squares train's rate within 1e-4 (float32 times stay well inside both)."""
    _, interval_s, n = least_squares_uniform(slow_time_s)
    # the best uniform train in the max norm, approximately: for the least-squares interval and for
    # 1/prf_hz, the offset at the residuals' midrange (half their spread: the least-squares offset can
    # put a train whose pulses all lie within 1 % of a uniform one at 1.02 %)
    worst, interval_best = min((float(np.ptp(slow_time_s - step * n)) / 2.0, step)
                               for step in (interval_s, 1.0 / prf_hz))
    if worst > TIMING_JITTER_FRACTION * interval_s:
        res = slow_time_s - interval_best * n
        k = int(np.argmax(np.abs(res - 0.5 * (res.max() + res.min()))))
        raise BadInput(f"{source}: /axes/slow_time_s: pulse {k} lies {worst / interval_s:.3g} pulse intervals "
                       f"off a uniform pulse train ({1.0 / interval_best:.9g} Hz); allowed: at most "
                       f"{TIMING_JITTER_FRACTION:g} (uniform pulses, no gaps or dropped pulses)")
    prf_axis_hz = 1.0 / interval_s
    if abs(prf_axis_hz - prf_hz) > PRF_TOLERANCE * prf_hz:
        raise BadInput(f"{source}: /radar attribute prf_hz = {prf_hz:.9g}: /axes/slow_time_s is sampled at "
                       f"{prf_axis_hz:.9g} Hz; allowed: within {PRF_TOLERANCE:g} (relative) of that rate")


OPTIONAL_RADAR_NUMBERS = ("pulse_width_s",)   # positive numbers where a cube records them (the ISAR closed form)


def _check_motion(position, velocity, dt, source: str, stored_dtype=np.float64) -> None:
    """The INS track is a platform's: speeds (recorded, and implied by consecutive positions) within
    ``MAX_SPEED_MPS`` and positions within ``MAX_DISTANCE_M`` (1e12 m/s, a platform 1e7 km away or a
    500 m jump between pulses had been processed into an empty image with exit 0).  The recorded
    velocities against the positions: over spans of pulses long enough that the positions' storage step
    (float32 map coordinates: 0.03-0.25 m at 5e5-4e6 m, more than a pulse's travel) moves a span's mean
    velocity by under 0.1 m/s, each span's displacement against its velocities' trapezoidal integral
    (exact for a constant acceleration, whatever the span; per pulse, float32 UTM positions had been
    refused as a velocity of the wrong sign or unit)."""
    far = float(np.max(np.abs(position)))
    if far > MAX_DISTANCE_M:
        raise BadInput(f"{source}: /platform/position_m: reaches {far:.3g} m; allowed: within "
                       f"{MAX_DISTANCE_M:g} m of the origin")
    speed = float(np.max(np.linalg.norm(velocity, axis=1)))
    if speed > MAX_SPEED_MPS:
        raise BadInput(f"{source}: /platform/velocity_mps: speed {speed:.3g} m/s; allowed: up to {MAX_SPEED_MPS:g} m/s")
    implied = np.linalg.norm(np.diff(position, axis=0), axis=1) / dt
    if len(implied) and float(implied.max()) > MAX_SPEED_MPS:
        i = int(np.argmax(implied))
        raise BadInput(f"{source}: /platform/position_m: moves {float(implied[i] * dt[i]):.3g} m between pulses {i} "
                       f"and {i + 1} ({float(implied[i]):.3g} m/s); allowed: a track within {MAX_SPEED_MPS:g} m/s")
    if len(dt):     # the velocities the positions' differences imply, against the recorded (span means)
        floating = np.issubdtype(stored_dtype, np.floating)     # (far is within 1e7 m: checked above)
        step_m = float(np.spacing(np.asarray(far, dtype=stored_dtype))) if floating else 1.0
        # (and at least the navigation check's smoothing: positions with centimetres of white noise had been
        # refused as a velocity of the wrong sign or unit, pulse to pulse; their noise is that check's)
        span = int(min(len(dt), max(1, np.ceil(10.0 * step_m / float(np.median(dt))),
                                    np.ceil(SMOOTHING_S / float(np.median(dt))))))
        t = np.concatenate([[0.0], np.cumsum(dt)])
        moved = velocity_integral_m(t, velocity)
        gap = np.linalg.norm(((position[span:] - position[:-span]) - (moved[span:] - moved[:-span]))
                             / (t[span:] - t[:-span])[:, None], axis=1)
        speed = float(np.median(np.linalg.norm(velocity, axis=1)))
        worst = float(np.median(gap))          # the median: an INS's noise and a jump of a few pulses pass
        if worst > VELOCITY_TOLERANCE * speed + VELOCITY_TOLERANCE_MPS:
            raise BadInput(f"{source}: /platform/velocity_mps: contradicts /platform/position_m (the median "
                           f"pulse's velocity {worst:.3g} m/s from the positions' own, at a speed of {speed:.3g} "
                           f"m/s: a sign, an axis order or a unit); allowed: within {VELOCITY_TOLERANCE:g} of the "
                           f"speed + {VELOCITY_TOLERANCE_MPS:g} m/s")


def _max_abs(a) -> float:
    """max |a| block by block of rows (no array-sized temporary; file-backed arrays read once)."""
    step = backing.rows_per_block(a[0].nbytes if a.shape[0] else 1)
    return max((float(np.max(np.abs(a[i:i + step]), initial=0.0)) for i in range(0, a.shape[0], step)), default=0.0)


def _check_echo_scale(channels, source: str) -> None:
    """Finite samples whose focused peak would overflow the chain's float32 powers are refused: a focused
    peak is at most |sample| x pulses, its power must stay under float32's 3.4e38 (a cube scaled by
    1e18, or one sample of 3e38, came out as NaN images and a metrics.json that could not be written)."""
    for name, x in zip(("sum", "diff"), channels):
        if x is None:
            continue
        peak = _max_abs(x)
        if peak == 0.0 and x.size:          # a dead receiver: nothing to image, nor a ratio to take (the
            # calibration divided by the data's zero slope, the noise level by a zero sigma: tracebacks)
            raise BadInput(f"{source}: /echo/{name}: every sample is zero; allowed: an echo with signal "
                           f"(a {'sum' if name == 'sum' else 'difference'} channel that recorded nothing cannot be "
                           f"imaged)")
        if peak * x.shape[0] > MAX_FOCUSED_AMPLITUDE:
            raise BadInput(f"{source}: /echo/{name}: largest |sample| {peak:.3g} x {x.shape[0]} pulses = "
                           f"{peak * x.shape[0]:.3g}; allowed: up to {MAX_FOCUSED_AMPLITUDE:g} (a focused peak's "
                           f"power in float32; the chain is linear: scale the cube down)")


def _check_optional_radar(radar: dict, source: str) -> None:
    """``range_weighting``, which a cube may leave out (where known, the ISAR metrics' closed form uses
    it): where given, a name."""
    weighting = radar.get("range_weighting", "none")
    if not isinstance(weighting, str) or not weighting.strip():
        raise BadInput(f"{source}: /radar attribute range_weighting = {shown(weighting)}: expected a name "
                       f"(fwdlook's own: {', '.join(WEIGHTINGS)}; another recorder's is kept as it is)")


def _check_radar_values(radar: dict, range_step_m: float, n_range: int, source: str) -> None:
    """What the chain's physics needs of the /radar attributes besides being positive numbers: the
    scenario's own rules on the pulse (fs >= B, B T >= 1: scenario/forward.py), and a range window at
    least one resolution cell c / (2 B) long (a narrower band has no range to image, and every profile
    measured in resolution cells would span millions of samples)."""
    why = carrier_floor_text(radar["fc_hz"], radar["fs_hz"])
    if why:
        raise BadInput(f"{source}: /radar attribute fc_hz = {radar['fc_hz']:g}: {why}")
    beam = radar["beamwidth_3db_deg"]
    if beam > MAX_BEAMWIDTH_DEG:
        raise BadInput(f"{source}: /radar attribute beamwidth_3db_deg = {beam:g}; allowed: up to "
                       f"{MAX_BEAMWIDTH_DEG:g} deg (the sum beam's 3 dB width, as antenna.beamwidth_3db_deg)")
    step_m = C_MPS / (2.0 * radar["fs_hz"])
    if abs(range_step_m - step_m) > RANGE_STEP_TOLERANCE * step_m:
        raise BadInput(f"{source}: /radar attribute fs_hz = {radar['fs_hz']:.9g}: /axes/range_m steps "
                       f"{range_step_m:.6g} m, c / (2 fs_hz) = {step_m:.6g} m; allowed: within "
                       f"{RANGE_STEP_TOLERANCE:g} (relative): fs_hz is the rate of the range samples")
    band_hz, fs_hz = radar["bandwidth_hz"], radar["fs_hz"]
    broken = pulse_rule_broken(bandwidth_hz=band_hz, fs_hz=fs_hz, pulse_width_s=radar.get("pulse_width_s"),
                               prf_hz=radar["prf_hz"])
    if broken:
        key, value, why = broken
        raise BadInput(f"{source}: /radar attribute {key} = {value:.9g}: {why}")
    if n_range * band_hz / fs_hz < 1.0:
        raise BadInput(f"{source}: /radar attribute bandwidth_hz = {band_hz:.9g}: its resolution cell "
                       f"c / (2 B) = {C_MPS / (2.0 * band_hz):.6g} m is longer than the range window "
                       f"({n_range} samples of {range_step_m:.6g} m); allowed: B >= fs_hz / {n_range} = "
                       f"{fs_hz / n_range:.6g} Hz")


def _read_antenna(f: h5py.File, source: str) -> dict:
    """The optional /antenna group: attrs as they are, the ratio table checked (finite, same length,
    offsets increasing, ratio strictly increasing)."""
    grp = f.get("antenna")
    if not isinstance(grp, h5py.Group):
        return {}
    antenna = {k: _plain(v) for k, v in list(grp.attrs.items())}
    present = [k for k in ANTENNA_DATASETS if k in grp]
    if present and len(present) != len(ANTENNA_DATASETS):
        raise BadInput(f"{source}: /antenna: {present[0]} without "
                       f"{[k for k in ANTENNA_DATASETS if k not in present][0]}; allowed: both or neither")
    if present:
        n = _need(f, "antenna/ratio", source).shape
        if len(n) != 1 or n[0] < 2:
            raise BadInput(f"{source}: /antenna/ratio: shape {list(n)}, expected [n] with n >= 2")
        offset = _array(f, "antenna/ratio_offset_deg", source, kind=np.float64, shape=n)
        ratio = _array(f, "antenna/ratio", source, kind=np.float64, shape=n)
        if np.any(np.diff(offset) <= 0) or np.any(np.diff(ratio) <= 0):
            raise BadInput(f"{source}: /antenna/ratio: not strictly increasing with ratio_offset_deg; allowed: "
                           f"a ratio curve monotone over the main lobe")
        antenna["ratio_offset_deg"], antenna["ratio"] = offset, ratio
    if "pattern" in antenna and not isinstance(antenna["pattern"], str):
        raise BadInput(f"{source}: /antenna attribute pattern = {shown(antenna['pattern'])}: expected a name "
                       f"(e.g. gaussian2, sinc2, table)")
    for key in ANTENNA_NUMBERS:
        if key in antenna:
            try:
                value = _attr_number(antenna[key])
            except (TypeError, ValueError):
                raise BadInput(f"{source}: /antenna attribute {key} = {shown(antenna[key])}: "
                               f"expected a real number (not text, a boolean or a complex value)") from None
            if key in ANTENNA_POSITIVE and not (np.isfinite(value) and value > 0):
                raise BadInput(f"{source}: /antenna attribute {key} = {value!r}: must be a positive number")
            if not np.isfinite(value) and not (np.isnan(value) and key in ANTENNA_MAY_BE_NAN):
                raise BadInput(f"{source}: /antenna attribute {key} = {value!r}: must be a finite number"
                               + (" (or NaN: not given)" if key in ANTENNA_MAY_BE_NAN else ""))
            if why := outside_scenario_range(key, value):   # (a ranged key is finite here: refused above)
                raise BadInput(f"{source}: /antenna attribute {key} = {value!r}; {why}")
            antenna[key] = value
    return antenna


ANTENNA_NUMBERS = ("monopulse_slope_per_deg", "squint_deg", "diff_gain_db", "diff_phase_deg", "beta_per_deg2",
                   "crossover_db", "main_lobe_deg")
ANTENNA_POSITIVE = ("monopulse_slope_per_deg", "beta_per_deg2", "main_lobe_deg")
ANTENNA_MAY_BE_NAN = ("squint_deg", "crossover_db")      # a measured table has neither (dsp/antenna.py)


def _read_noise(attrs, source: str) -> dict:
    """/echo's ``noise_*`` attributes (what the simulator drew: informational, never used by the chain):
    the real scalars as they are (NaN or Inf included: a noiseless cube's SNR is Inf); anything else is
    said and left out."""
    noise = {}
    for key, value in list(attrs.items()):
        if not key.startswith("noise_"):
            continue
        value = _plain(value)
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            noise[key[len("noise_"):]] = value
        else:
            log.warning(f"{source}: /echo attribute {key} = {shown(value)} is not a number; ignored "
                        f"(it only records the simulated noise)")
    return noise


