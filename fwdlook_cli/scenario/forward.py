"""The forward-looking scenario kind: its schema beside its defaults, derived quantities, cross-field checks."""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from ..dsp.antenna import AntennaDesignError, antenna_from_scenario
from ..dsp.geometry import platform_state, range_extent_m
from ..dsp.keystone_common import carrier_floor_text
from ..dsp.pulse import WEIGHTINGS, scenario_pulse_rule_text
from ..errors import BadInput
from ..limits import FC_HZ_RANGE, MAX_DIFF_GAIN_DB, MAX_DIFF_PHASE_DEG, MIN_PRF_HZ
from .fields import folder_name, _show, Field, calibration_setting, amplitude, auto_or, boolean, choice, integer, num, optional, points_list, range_window, text, vector


# ----------------------------------------------------------------------------------------------
# The schema: every key, its default and meaning (the one documented place for defaults)
# ----------------------------------------------------------------------------------------------
MAX_NAVIGATION_DELAY_S = 1.0     # processing.navigation_delay_s's range, seconds either way (echo_navigation's
                                 # suggested settings stay inside it)
MAX_SCAN_ANGLE_OFFSET_DEG = 10.0  # processing.scan_angle_offset_deg's range, degrees either way (likewise)

FORWARD_SCHEMA: dict[str, Any] = {
    "name": Field(folder_name, "scenario", "scenario name, copied into outputs"),
    "kind": Field(choice("forward", "isar"), "forward",
                  "forward: forward-looking scanning monopulse radar; isar: stationary radar, moving object"),
    "radar": {
        "fc_hz": Field(num(*FC_HZ_RANGE), 18.0e9, "carrier frequency"),
        "bandwidth_hz": Field(num(0.0, lo_open=True), 50.0e6, "transmitted LFM bandwidth"),
        "pulse_width_s": Field(num(0.0, 1e-3, lo_open=True), 1.0e-6,
                               "LFM pulse width; the compressed pulse spans +-pulse_width"),
        "prf_hz": Field(num(MIN_PRF_HZ), 2500.0, "pulse repetition frequency"),
        "fs_hz": Field(num(0.0, lo_open=True), 60.0e6,
                       "complex sampling rate of the range-compressed data (range sample c/(2 fs))"),
        "range_window_m": Field(auto_or(range_window), "auto",
                                "[near, far] slant range recorded, or auto: sized from scene and motion"),
        "n_pulses": Field(auto_or(integer(2, 10_000_000)), "auto",
                          "pulses recorded; auto: scan duration x PRF"),
        "range_weighting": Field(choice(*WEIGHTINGS), "none",
                                 "amplitude weighting of the matched filter (range sidelobes)"),
    },
    "antenna": {
        "beamwidth_3db_deg": Field(num(0.1, 90.0), 6.0, "one-way 3 dB width of the SUM beam"),
        "pattern": Field(choice("gaussian2", "sinc2", "table"), "gaussian2",
                         "monopulse pattern family: two squinted Gaussian beams, two squinted uniform-aperture "
                         "(sinc) beams, or a measured table (antenna.pattern_file)"),
        "squint_deg": Field(auto_or(num(0.0, 45.0, lo_open=True)), "auto",
                            "squint of each of the two beams from the boresight; auto: from antenna.crossover_db"),
        "crossover_db": Field(num(-60.0, 0.0, hi_open=True), -3.0,
                              "one-way level at which the two beams cross (used when squint_deg is auto)"),
        "pattern_file": Field(optional(text), None,
                              "antenna.pattern table: CSV (offset_deg, sum, diff voltage gains) or HDF5 "
                              "(datasets offset_deg, sum, diff); relative to the scenario file"),
        "diff_gain_db": Field(num(-MAX_DIFF_GAIN_DB, MAX_DIFF_GAIN_DB), 0.0,
                              "difference/sum channel gain imbalance (the difference channel is x 10^(g/20))"),
        "diff_phase_deg": Field(num(-MAX_DIFF_PHASE_DEG, MAX_DIFF_PHASE_DEG), 0.0,
                                "difference/sum channel phase imbalance (the difference channel is x exp(j phi))"),
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
        "max_cube_bytes": Field(auto_or(num(1.0)), "auto",
                                "size limit checked before allocating: echo cube bytes (both channels, "
                                "complex64) and simulation work; auto: $FWDLOOK_MAX_CUBE_BYTES, else 4 GiB"),
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
        "n_doppler": Field(auto_or(integer(4, 4096)), "auto",
                           "zoomed Doppler cells per CPI over the main-beam band; auto: 4 per CPI resolution cell "
                           "(PRF / cpi) over the scan's widest CPI band (forward/motion.py::auto_doppler_cells)"),
        "doppler_window": Field(choice(*WEIGHTINGS), "none",
                                "slow-time window of each CPI before the Doppler zoom"),
        "range_oversample": Field(auto_or(integer(1, 16)), "auto",
                                  "band-limited range oversampling of the image; auto: the power image's Nyquist "
                                  "rate, ceil(2 bandwidth / fs) (2 for the paper's radar; dsp/imaging.py::"
                                  "auto_range_oversample)"),
        "angle_step_deg": Field(num(1e-4, 1.0), 0.05, "angle bin of the monopulse image"),
        "threshold_db": Field(num(-50.0, 100.0), 12.0,
                              "Doppler cells projected only above this many dB over the CPI noise floor"),
        "imaging": Field(choice("cpi", "dwell"), "cpi",
                         "cpi: the paper's per-CPI monopulse image (processing.cpi pulses); dwell: every image "
                         "direction integrated coherently over its whole two-way beam dwell (forward/dwell.py)"),
        "dwell_fit": Field(choice("joint", "none"), "none",
                           "imaging: dwell near the flight axis (within 1.5 dwell half-widths, 4.8 deg for the paper): "
                           "joint, a sparse fit of the scatterers of each range cluster over the dwell "
                           "(forward/dwell_fit.py; about the chain's own cost again on the paper lattice; two "
                           "Gaussian beams only, extended clusters left to the image); none, the per-direction "
                           "dwell image there too (the tracking preset: joint)"),
        "dwell_range": Field(choice("envelope", "iso_doppler"), "envelope",
                             "imaging: dwell, where a projected cell's range comes from: envelope, the range "
                             "of the cell; iso_doppler, moved along the cell's iso-Doppler line to the "
                             "monopulse azimuth (steep depression: README, dwell imaging)"),
        "subswaths": Field(choice("auto", "none"), "auto",
                           "steep depression: auto corrects the range window in range sub-swaths, one reference "
                           "depression each, where one for the whole window leaves over half a range sample "
                           "(forward/subswath.py); none, one for the window always"),
        "navigation": Field(choice("recorded", "positions", "fused"), "recorded",
                            "the track the chain takes: recorded, /platform/position_m and velocity_mps as stored; "
                            "positions, the velocities from the positions' smoothed time derivative (velocities "
                            "biased, lagging or logged at a lower rate); fused, one track blending the positions' "
                            "low frequencies with the velocities' high ones (io/navigation.py; the reader's "
                            "warnings; README, Raw cube files)"),
        "navigation_delay_s": Field(num(-MAX_NAVIGATION_DELAY_S, MAX_NAVIGATION_DELAY_S), 0.0,
                                    "time by which the navigation lags the radar (its record tagged t holds the "
                                    "platform at t - delay): both records are read at t + delay before "
                                    "processing.navigation (io/navigation.py::delayed_track); metrics.json's "
                                    "echo_navigation.delay_s estimates it from the echoes"),
        "scan_angle_offset_deg": Field(num(-MAX_SCAN_ANGLE_OFFSET_DEG, MAX_SCAN_ANGLE_OFFSET_DEG), 0.0,
                                       "degrees by which the recorded scan angles lie towards +x of where the "
                                       "antenna pointed (a pointing error of the whole antenna): subtracted before "
                                       "processing; metrics.json's echo_navigation.pointing_error_deg estimates it"),
        "doppler_estimator": Field(choice("fft", "iaa"), "fft",
                                   "per-CPI Doppler estimate (imaging: cpi): fft, the zoomed DFT; iaa, the "
                                   "iterative adaptive approach (Yardibi et al. 2010) per range cell"),
        "monopulse_calibration": Field(calibration_setting, "auto",
                                       "where the monopulse ratio curve and channel imbalance come from: cube "
                                       "(/antenna), data (estimated from point returns), auto (cube when it has "
                                       "/antenna, else data), or a slope per degree (tanh curve, no imbalance)"),
        "calibration_model": Field(choice("auto", "tanh", "table"), "auto",
                                   "ratio curve fitted by a calibration from the data: tanh (two Gaussian beams), "
                                   "table (a general monotone curve), auto (tanh unless it misfits grossly)"),
        "backend": Field(choice("cpu", "gpu"), "cpu",
                         "where the keystone (czt), the Doppler zoom (fft) and the image's cell selection run: "
                         "cpu (numpy, scipy), or gpu (CuPy on a CUDA device: pip install -e .[gpu])"),
    },
}

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


_SAID: set[str] = set()          # warnings already logged by this process (a sweep loads a scenario per point)

SCENE_KEYS_READ = {"lattice": ("center_m", "lattice"), "points": ("points_m",), "image": ("center_m", "image")}


def warn_unused_scene_keys(raw_scene, set_keys, source: str) -> None:
    """The scene keys of another ``scene.kind`` that a ``--set`` gave anything but their defaults
    (``--set scene.lattice.nx=5`` or ``scene.center_m`` under ``kind: points``) are not read: said once
    per process, as an unread pattern file is (they had been recorded in the cube's /scenario and ignored
    without a word: an independent review). ``set_keys``: the scene keys the overrides name (a file may
    keep another kind's keys beside its own, and a written scenario.yaml holds every section)."""
    if not isinstance(raw_scene, dict):
        return
    kind = raw_scene.get("kind", "lattice")
    schema = FORWARD_SCHEMA["scene"]
    for key in ("center_m", "lattice", "points_m", "image"):
        if (kind not in SCENE_KEYS_READ or key in SCENE_KEYS_READ[kind] or key not in raw_scene
                or key not in set_keys):
            continue
        given, default = raw_scene[key], schema[key]
        if isinstance(default, dict):
            changed = isinstance(given, dict) and any(k not in default or v != default[k].default
                                                      for k, v in given.items())
        else:
            changed = given is not None and given != default.default
        said = f"{source}: scene.{key} is not read: scene.kind is {kind}"
        if changed and said not in _SAID:
            _SAID.add(said)
            logging.getLogger(__name__).warning(said)


def _antenna_checks(ant: dict, source: str) -> None:
    """The antenna design must be buildable; a pattern file is made absolute (relative to the scenario).
    A pattern file under another pattern is not read, and the user is told so (once per process)."""
    if ant["pattern"] != "table" and ant["pattern_file"]:
        said = (f"{source}: antenna.pattern_file = {_show(ant['pattern_file'])} is not read: antenna.pattern is "
                f"{ant['pattern']} (set antenna.pattern: table to use the measured pattern)")
        if said not in _SAID:
            _SAID.add(said)
            logging.getLogger(__name__).warning(said)
    if ant["pattern"] == "table":
        if not ant["pattern_file"]:
            raise BadInput(f"{source}: antenna.pattern_file: required when antenna.pattern is table")
        pf = Path(ant["pattern_file"]).expanduser()
        if not pf.is_absolute():
            base = Path(source).parent if Path(source).is_file() else Path.cwd()
            pf = (base / pf).resolve()
        ant["pattern_file"] = str(pf)
    try:
        antenna_from_scenario(ant)
    except AntennaDesignError as exc:
        value = {"antenna.squint_deg": ant["squint_deg"], "antenna.crossover_db": ant["crossover_db"],
                 "antenna.pattern_file": ant["pattern_file"]}.get(exc.key, ant.get(exc.key.split(".")[-1]))
        raise BadInput(f"{source}: {exc.key} = {_show(value)}: {exc}") from None




def forward_checks(scn: dict, source: str, *, check_pulses: bool = True) -> None:
    radar, ant, sc, proc = scn["radar"], scn["antenna"], scn["scene"], scn["processing"]
    if sc["kind"] == "image":
        from .scene_image import check_image_scene

        check_image_scene(scn, source)
    if ant["scan_stop_deg"] > ant["scan_start_deg"] and (sc["kind"] != "points" or sc["points_m"]):
        from .sizes import forward_sizes_check

        forward_sizes_check(scn, source)        # before any array: pulses, scatterers, echo bytes
    broken = scenario_pulse_rule_text(radar)
    if broken:
        raise BadInput(f"{source}: {broken}")
    why = carrier_floor_text(radar["fc_hz"], radar["fs_hz"])
    if why:
        raise BadInput(f"{source}: radar.fc_hz = {radar['fc_hz']:g}: {why.replace('fs_hz', 'radar.fs_hz')}")
    if ant["scan_stop_deg"] <= ant["scan_start_deg"]:
        raise BadInput(f"{source}: antenna.scan_stop_deg = {ant['scan_stop_deg']:g}: must be > "
                       f"antenna.scan_start_deg = {ant['scan_start_deg']:g}")
    lat = sc["lattice"]
    if sc["kind"] == "lattice" and (lat["x_offset"] >= lat["x_stride"] or lat["x_offset"] >= lat["nx"]):
        raise BadInput(f"{source}: scene.lattice.x_offset = {lat['x_offset']}: must be below x_stride "
                       f"({lat['x_stride']}) and nx ({lat['nx']})")
    if sc["kind"] == "points" and sc["points_m"] is None:
        raise BadInput(f"{source}: scene.points_m: required when scene.kind is points")
    _antenna_checks(ant, source)
    pts = scene_points(scn)[0] if sc["kind"] != "image" else ()    # (a map's amplitude is one number: checked)
    if isinstance(sc["amplitude"], list) and len(sc["amplitude"]) != len(pts):
        raise BadInput(f"{source}: scene.amplitude: list of {len(sc['amplitude'])} values; "
                       f"allowed: one number or one per point ({len(pts)})")
    m = n_pulses(scn)
    if radar["n_pulses"] != "auto":
        needed = scan_duration_s(scn) * radar["prf_hz"]
        if m > needed + 1.0 + 1e-9:
            raise BadInput(f"{source}: radar.n_pulses = {m}: the scan lasts {scan_duration_s(scn):g} s, "
                           f"at most {int(needed) + 1} pulses fit it at prf_hz = {radar['prf_hz']:g}")
    if check_pulses and proc["method"] == "decimation" and m % proc["q"]:     # (no other method reads Q)
        raise BadInput(f"{source}: processing.q = {proc['q']}: must divide the pulse count {m}")
    if check_pulses and proc["cpi"] > m:
        raise BadInput(f"{source}: processing.cpi = {proc['cpi']}: longer than the {m} pulses")
    if proc["doppler_estimator"] != "fft" and proc["imaging"] != "cpi":
        raise BadInput(f"{source}: processing.doppler_estimator = {proc['doppler_estimator']!r}: the per-CPI "
                       f"estimator needs processing.imaging = cpi (it is {proc['imaging']!r}); allowed with "
                       f"dwell: fft")
    if radar["range_window_m"] != "auto":
        near, far = radar["range_window_m"]
        r_min, r_max = scene_range_extent_m(scn)
        if r_min < near or r_max > far:
            raise BadInput(f"{source}: radar.range_window_m = [{near:g}, {far:g}]: the scene spans "
                           f"slant ranges {r_min:.1f} to {r_max:.1f} m over the scan; widen the window "
                           f"or use auto")


def scene_geometry(scn: dict):
    """Slow time, platform state and target positions of a resolved forward-looking scenario."""
    radar, plat = scn["radar"], scn["platform"]
    m = n_pulses(scn)
    slow_time_s = np.arange(m, dtype=np.float64) / radar["prf_hz"]
    position_m, velocity_mps = platform_state(slow_time_s, plat["speed_mps"], plat["accel_mps2"],
                                              plat["height_m"])
    pts, amps = scene_points(scn)
    targets_m = np.column_stack([np.asarray(pts, dtype=np.float64).reshape(-1, 2), np.zeros(len(pts))])
    amps = np.asarray(amps)                       # complex for a speckled image scene
    return slow_time_s, position_m, velocity_mps, targets_m, amps.astype(
        np.complex128 if np.iscomplexobj(amps) else np.float64)


def scene_range_extent_m(scn: dict):
    """Smallest and largest slant range of any scene point over the whole scan."""
    _, position_m, _, targets_m, _ = scene_geometry(scn)
    return range_extent_m(position_m, targets_m)
