"""Bounds checked before anything large is allocated, and values cut before they are echoed.

The size limit is a setting: the scenario key ``simulation.max_cube_bytes`` (``auto``: the environment
variable ``FWDLOOK_MAX_CUBE_BYTES``, else :data:`DEFAULT_MAX_CUBE_BYTES`).  Reading a cube (``process``,
``validate``, ``info``) has no scenario, so it uses the environment variable or the default.  The limit
bounds the bytes of the echo cube (both channels, complex64) and, before them, the arrays the simulator
needs: pulses, target-pulse pairs and range samples, each derived from the scenario's keys with the
same formulas the simulator uses and checked BEFORE the geometry is computed.
"""
from __future__ import annotations

import math
import os

from .errors import BadInput

DEFAULT_MAX_CUBE_BYTES = 4 * 2**30       # 4 GiB of echo: the simulator's peak is about 4x this
MAX_PULSES = 10_000_000                 # as radar.n_pulses's own schema bound
ENV_VAR = "FWDLOOK_MAX_CUBE_BYTES"
SHOW_CHARS = 60
# The radar's and the channel imbalance's ranges, one rule for a scenario's keys (scenario/forward.py,
# scenario/isar.py) and a cube's attributes (io/raw.py): a recorded cube had taken any positive carrier
# (1e300 Hz went on to a ZeroDivisionError in the chain, exit 1) and any finite imbalance (1e5 dB: an
# OverflowError)
FC_HZ_RANGE = (1e6, 1e12)                # radar.fc_hz: 1 MHz (HF) to 1 THz
MIN_PRF_HZ = 1.0                         # radar.prf_hz: a pulse a second at the least (at 1e-300 Hz two
                                         # pulses spanned 1e300 s, and the scene's extent overflowed to NaN)
MAX_DIFF_GAIN_DB = 40.0                  # antenna.diff_gain_db within +-40 dB
MAX_DIFF_PHASE_DEG = 180.0               # antenna.diff_phase_deg within +-180 deg
MAX_MONOPULSE_SLOPE_PER_DEG = 100.0      # a slope processing.monopulse_calibration takes, a table antenna's, and a
                                         # cube's /antenna monopulse_slope_per_deg (1e6 and 1e300 had run to exit 0,
                                         # numpy's overflow warnings on the terminal)
# a cube's attribute -> (lowest, highest, unit, the scenario key whose range it keeps)
CUBE_ATTRIBUTE_RANGES = {
    "fc_hz": (*FC_HZ_RANGE, "Hz", "radar.fc_hz"),
    "prf_hz": (MIN_PRF_HZ, math.inf, "Hz", "radar.prf_hz"),
    "diff_gain_db": (-MAX_DIFF_GAIN_DB, MAX_DIFF_GAIN_DB, "dB", "antenna.diff_gain_db"),
    # one turn either way: antenna.diff_phase_deg's +-180 deg, or a recorder's 0-360 deg convention
    "diff_phase_deg": (-2 * MAX_DIFF_PHASE_DEG, 2 * MAX_DIFF_PHASE_DEG, "deg", "antenna.diff_phase_deg, or 0 to 360"),
    "monopulse_slope_per_deg": (0.0, MAX_MONOPULSE_SLOPE_PER_DEG, "per degree", "processing.monopulse_calibration"),
}


def outside_scenario_range(key: str, value: float) -> str | None:
    """What a cube's attribute ``key`` may be, where ``value`` lies outside the range the scenario's own key
    takes (:data:`CUBE_ATTRIBUTE_RANGES`), for a one-line message; None where it is inside or unbounded."""
    if key not in CUBE_ATTRIBUTE_RANGES:
        return None
    lo, hi, unit, scenario_key = CUBE_ATTRIBUTE_RANGES[key]
    if lo <= value <= hi:
        return None
    allowed = f"at least {lo:g} {unit}" if hi == math.inf else f"{lo:g} to {hi:g} {unit}"
    return f"allowed: {allowed} (as {scenario_key})"


def gib(n_bytes: float) -> str:
    return f"{n_bytes / 2**30:.3g} GiB" if n_bytes >= 2**30 else f"{n_bytes / 2**20:.3g} MiB"


def max_cube_bytes(setting="auto") -> int:
    """The limit in bytes: the scenario setting, else ``$FWDLOOK_MAX_CUBE_BYTES``, else the default."""
    if setting not in (None, "auto"):
        return int(setting)
    text = os.environ.get(ENV_VAR)
    if text is None or not text.strip():
        return DEFAULT_MAX_CUBE_BYTES
    try:
        value = float(text)
        if not math.isfinite(value) or value < 1:
            raise ValueError
    except ValueError:
        raise BadInput(f"${ENV_VAR} = {shown(text)}: expected a positive number of bytes") from None
    return int(value)


def limit_source(setting="auto") -> str:
    """Where the limit came from; ``setting=None``: a kind with no such scenario key (ISAR)."""
    if setting not in (None, "auto"):
        return "simulation.max_cube_bytes"
    if os.environ.get(ENV_VAR, "").strip():
        return f"${ENV_VAR}"
    return "the default limit" if setting is None else "simulation.max_cube_bytes (default)"


IMAGE_BYTES_PER_CELL = {"dwell": 32, "cpi": 8}   # peak RSS over the image grid, measured (README, guarantees)


def check_processing_sizes(*, n_range: int, range_oversample: int, n_angle: int, angle_step_deg: float,
                           imaging: str, n_cpi: int, n_doppler: int, spectra_in_memory: bool = True,
                           limit: int | None = None, n_focus: int | None = None) -> None:
    """The chain's own largest arrays, derived from its settings before any is allocated: the image
    grid (``n_angle`` bins of ``angle_step_deg`` x the range samples x ``range_oversample``), at the
    bytes per cell the imaging was measured to peak at, and (CPI imaging) the Doppler spectra, both
    channels in complex64, unless they are file-backed (``--out-of-core``).  Each against the size limit
    the cube has (``FWDLOOK_MAX_CUBE_BYTES`` or the default): a fine angle step once took the dwell
    image past 23 GB and the kernel ended it."""
    limit = max_cube_bytes() if limit is None else limit
    finer = n_focus is not None and n_focus > n_angle        # the dwell focused finer than its bins (dwell_grid)
    cells = (n_focus if finer else n_angle) * n_range * range_oversample
    image_bytes = cells * IMAGE_BYTES_PER_CELL[imaging]
    if image_bytes > limit:
        grid = (f"the dwell focused in {n_focus:,} directions (its angle lobe is finer than the step) x"
                if finer else f"the image grid of {n_angle:,} angles x")
        raise BadInput(f"processing.angle_step_deg = {angle_step_deg:g} with processing.range_oversample = "
                       f"{range_oversample}: {grid} {n_range * range_oversample:,} "
                       f"ranges needs about {gib(image_bytes)} ({imaging} imaging, "
                       f"{IMAGE_BYTES_PER_CELL[imaging]} bytes a cell); over {limit_source(None)} = {gib(limit)}; "
                       f"allowed: a coarser {'range oversampling' if finer else 'angle step or range oversampling'}")
    spectra_bytes = 16 * n_cpi * n_doppler * n_range
    if imaging == "cpi" and spectra_in_memory and spectra_bytes > limit:
        raise BadInput(f"processing.n_doppler = {n_doppler}: the Doppler spectra of {n_cpi:,} CPIs x {n_doppler} "
                       f"cells x {n_range:,} ranges, both channels, need {gib(spectra_bytes)}; over "
                       f"{limit_source(None)} = {gib(limit)}; allowed: fewer cells (auto) or --out-of-core")


SUBSWATH_WORK_FACTOR = 4   # the keystone stage's peak over one sub-swath's padded input (both channels, complex64):
                           # measured 7.8 GiB of peak RSS for 2.07 GiB of padded rows (tiny at PRF 1 Hz, 16 sub-swaths)


def check_subswath_sizes(*, n_subswaths: int, widest_samples: int, n_pulses: int, walk_m: float,
                         limit: int | None = None) -> None:
    """The keystone stage's range sub-swaths (steep depression, ``forward/subswath.py``), each corrected on its
    own, its samples padded each side by the range walk: refused before the chain where one sub-swath's keystone
    would take more than the size limit (in memory; out of core its rows are file-backed).  A scene whose
    walk is longer than its window (tiny at PRF 1 Hz: 1060 km in a 400 s scan) had run for minutes to 7.8 GiB."""
    limit = max_cube_bytes() if limit is None else limit
    need = SUBSWATH_WORK_FACTOR * 2 * 8.0 * n_pulses * widest_samples
    if need > limit:
        raise BadInput(f"processing.subswaths = auto: the range window is corrected in {n_subswaths} sub-swaths "
                       f"(steep depression), each padded by the range walk of {walk_m:.6g} m to up to "
                       f"{widest_samples:,} range samples x {n_pulses:,} pulses; their keystone needs about "
                       f"{gib(need)}, over {limit_source(None)} = {gib(limit)}; allowed: processing.subswaths: none "
                       f"(one reference depression for the window: `fwdlook plan` gives what it leaves), or --out-of-core")


def check_declared_dataset(source: str, name: str, shape, itemsize: int, limit: int | None = None) -> None:
    """A dataset whose declared shape would need more than the limit is refused before it is read."""
    limit = max_cube_bytes() if limit is None else limit
    n = 1
    for s in shape or ():
        n *= int(s)
    if n * itemsize > limit:
        dims = " x ".join(f"{int(s):,}" for s in shape)
        raise BadInput(f"{source}: /{name}: declares shape [{dims}] = {gib(n * itemsize)}; over the limit "
                       f"of {gib(limit)} (set ${ENV_VAR} to raise it)")


def check_cube_bytes(source: str, key: str, n_range: float, n_pulses: int, *, channels: int,
                     setting="auto") -> None:
    """Refuse an echo of ``n_range`` x ``n_pulses`` complex64 samples per channel over the limit."""
    limit, where = max_cube_bytes(setting), limit_source(setting)
    cube_bytes = channels * 8 * float(n_range) * n_pulses
    if not math.isfinite(cube_bytes) or cube_bytes > limit:
        what = "two complex64 channels" if channels == 2 else "one complex64 channel"
        raise BadInput(f"{source}: {key}: {n_range:,.0f} range samples x {n_pulses:,} pulses = {gib(cube_bytes)} "
                       f"of echo ({what}); over {where} = {gib(limit)}")


def shown(value, limit: int = SHOW_CHARS) -> str:
    """A short display of any value, computed in time bounded by ``limit`` (never the whole value).

    Strings, bytes and numbers are cut before they are repr'd; lists and mappings are walked only
    until ``limit`` characters are produced, so a shared-reference alias bomb or a 100 MiB attribute
    costs nothing.
    """
    out: list[str] = []
    budget = [limit + 4]

    def emit(s: str) -> bool:
        out.append(s[: max(budget[0], 0)])
        budget[0] -= len(s)
        return budget[0] > 0

    def walk(v, depth=0) -> bool:
        if budget[0] <= 0:
            return False
        if depth > 16:
            return emit("...")
        if isinstance(v, str):
            return emit(repr(v[: limit + 2]))
        if isinstance(v, bytes):
            return emit(repr(v[: limit + 2]))
        if isinstance(v, bool) or v is None:
            return emit({True: "true", False: "false", None: "null"}[v])
        if isinstance(v, int):
            digits = len(str(v)) if v.bit_length() < 4000 else None
            return emit(str(v) if digits is not None and digits <= limit else
                        f"<integer of {digits or 'over 1200'} digits>")
        if isinstance(v, float):
            return emit(repr(v))
        if isinstance(v, dict):
            if not emit("{"):
                return False
            for i, (k, item) in enumerate(v.items()):
                if (i and not emit(", ")) or not walk(k, depth + 1) or not emit(": ") or not walk(item, depth + 1):
                    return False
            return emit("}")
        if isinstance(v, (list, tuple)):
            if not emit("["):
                return False
            for i, item in enumerate(v):
                if (i and not emit(", ")) or not walk(item, depth + 1):
                    return False
            return emit("]")
        try:
            import numpy as np

            if isinstance(v, np.ndarray):
                return emit(f"<array {v.dtype} shape {list(v.shape)}>") if v.size > 8 else walk(v.tolist(), depth)
            if isinstance(v, np.generic):
                return walk(v.item(), depth)
        except ImportError:  # pragma: no cover
            pass
        return emit(repr(v)[: limit + 2])

    walk(value)
    text = "".join(out)
    return text if len(text) <= limit else text[: limit - 3] + "..."


# ----------------------------------------------------------------------------------------------
# Derived sizes of a forward-looking scenario, before any array is made
# ----------------------------------------------------------------------------------------------


KEYSTONE_WORK_FACTOR = 8   # the CZT keystone's peak memory over its complex64 input (measured: 4.1 GB of
                           # peak RSS for 0.5 GB of padded rows, isar_theta3 at n0 = 1e7 pulses)


def keystone_padding(n: int, t0_index: float, worst_stretch: float) -> tuple[float, int]:
    """(excursion, pad) of an ISAR keystone about ``t0_index`` over ``n`` pulses: its resampling leaves
    the dwell by up to ``|1 - alpha| max|m - t0|`` pulses, and the rows are padded by that + 16."""
    excursion = float(worst_stretch) * max(abs(t0_index), abs(n - 1 - t0_index))
    return excursion, int(math.ceil(excursion)) + 16


def check_keystone_padding(n, pad, n_cols, t0_index, worst_stretch, n0_auto: bool = False):
    """(ISAR, ``isar/stages.py``) Refuse, before allocating it, a zero-padded keystone input over the cube size limit: a range
    minimum far outside the dwell (``processing.n0_pulses``, given or from eq. 13) moves the resampling
    positions ``|1 - alpha| |m - t0|`` pulses out, and the padding grows with it."""
    limit = max_cube_bytes("auto")
    need = KEYSTONE_WORK_FACTOR * 8.0 * (n + 2 * pad) * n_cols
    if need <= limit:
        return
    room = max((limit / (KEYSTONE_WORK_FACTOR * 8.0 * n_cols) - n) / 2.0 - 16.0, 0.0)   # the widest that fits
    n0_room = max(room / max(worst_stretch, 1e-300) - (n - 1) / 2.0, 0.0)
    said = " = auto (eq. 13, from the geometry)" if n0_auto else ""
    raise BadInput(f"processing.n0_pulses{said}: the range minimum at pulse {t0_index - (n - 1) / 2.0:.6g} from the "
                   f"dwell's centre ({n} pulses) moves the keystone's resampling up to {pad - 16:,} pulses "
                   f"outside it; the keystone over its zero-padded rows would take {gib(need)}, over {limit_source(None)} = "
                   f"{gib(limit)}; allowed: a range minimum within about {n0_room:,.0f} pulses of the centre")
