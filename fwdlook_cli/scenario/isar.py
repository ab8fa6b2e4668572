"""The ISAR scenario kind: its schema beside its defaults, cross-field checks and derived geometry.

Geometry and conventions: ``fwdlook_cli.isar`` (package docstring, Serafin et al. eq. 6-9).
"""
from __future__ import annotations

import logging
import math

import numpy as np

from ..dsp.geometry import C_MPS
from ..dsp.keystone_common import carrier_floor_text
from ..dsp.pulse import WEIGHTINGS, scenario_pulse_rule_text
from ..errors import BadInput
from ..limits import FC_HZ_RANGE, MIN_PRF_HZ
from .fields import folder_name, REQUIRED, Field, amplitude, auto_or, choice, integer, num, optional, range_window, vector

CORRECTIONS = ("none", "keystone1", "keystone2", "keystone2_n0", "keystone2_n0_est")


# ----------------------------------------------------------------------------------------------
# Scenario schema (kind: isar)
# ----------------------------------------------------------------------------------------------
def _offsets(value):
    if not isinstance(value, (list, tuple)) or not value:
        raise ValueError("expected a non-empty list of [dx, dy, dz] offsets")
    return [vector(3)(p) for p in value]


ISAR_SCHEMA: dict = {
    "name": Field(folder_name, "isar", "scenario name, copied into outputs"),
    "kind": Field(choice("isar"), REQUIRED, "isar: stationary radar at the origin, moving object"),
    "radar": {
        "fc_hz": Field(num(*FC_HZ_RANGE), 3.0e9, "carrier frequency f0"),
        "bandwidth_hz": Field(num(0.0, lo_open=True), 300.0e6, "transmitted LFM bandwidth"),
        "pulse_width_s": Field(num(0.0, 1e-3, lo_open=True), 0.1e-6,
                               "LFM pulse width; the compressed pulse spans +-pulse_width"),
        "prf_hz": Field(num(MIN_PRF_HZ), 3000.0, "pulse repetition frequency F_p"),
        "fs_hz": Field(num(0.0, lo_open=True), 360.0e6,
                       "complex sampling rate of the range-compressed data (range cell c/(2 fs))"),
        "range_window_m": Field(auto_or(range_window), "auto",
                                "[near, far] slant range recorded, or auto: the dwell's ranges, the "
                                "closest-approach range and the compressed pulse's reach"),
        "n_pulses": Field(integer(16, 10_000_000), 6000, "pulses in the observation (the dwell)"),
        "range_weighting": Field(choice(*WEIGHTINGS), "none",
                                 "amplitude weighting of the matched filter (range sidelobes)"),
    },
    "target": {
        "range_m": Field(num(0.0, lo_open=True), 1100.0,
                         "R0: distance to the object at the middle of the observation"),
        "theta0_deg": Field(num(-89.0, 89.0), 3.0,
                            "middle observation angle, from +x (normal to a +y track) towards -y"),
        "velocity_mps": Field(vector(3, num(-1e5, 1e5)), [0.0, 40.0, 0.0], "object velocity [vx, vy, vz]"),
        "points_m": Field(_offsets, [[0.0, 0.0, 0.0]],
                          "offsets [dx, dy, dz] of rigidly moving scatterers; the first is the reference"),
        "amplitude": Field(amplitude, 1.0, "common amplitude, or one per point"),
    },
    "noise": {
        "snr_db": Field(optional(num(-100.0, 300.0)), 20.0,
                        "peak SNR of the strongest scatterer per range-compressed sample; null: no noise"),
        "seed": Field(integer(0), 1, "seed of the noise generator"),
    },
    "processing": {
        "correction": Field(choice(*CORRECTIONS), "keystone2_n0", "range-cell-migration correction"),
        "keystone": Field(choice("czt", "dft"), "czt", "keystone implementation (dft: O(N^2) reference)"),
        "ambiguity": Field(auto_or(integer(-100_000, 100_000)), "auto",
                           "Doppler ambiguity number F; auto: per range-frequency row from the geometry"),
        "n0_pulses": Field(auto_or(num(-1e9, 1e9)), "auto",
                           "shift of the range minimum for keystone2_n0; auto: eq. (13) from the truth"),
        "azimuth_phase": Field(choice("model", "none"), "model",
                               "azimuth compression: model = straight-line range-model phase, then FFT"),
        "n0_search": {
            "half_span_lobes": Field(num(0.5, 1e4), 4.0,
                                     "half-width of the first search grid, in sharpness lobes"),
            "points_per_lobe": Field(integer(2, 1000), 6, "grid points per sharpness lobe"),
            "passes": Field(integer(1, 10), 2, "search passes, each followed by a Doppler refinement"),
        },
    },
}


_SAID: set[str] = set()          # warnings already logged by this process


def isar_checks(scn: dict, source: str) -> None:
    radar, tg = scn["radar"], scn["target"]
    proc = scn["processing"]
    said = (f"{source}: processing.n0_pulses = {proc['n0_pulses']:g} is not read: processing.correction is "
            f"{proc['correction']} (keystone2_n0 reads it)") if proc["n0_pulses"] != "auto" else ""
    if proc["n0_pulses"] != "auto" and proc["correction"] != "keystone2_n0" and said not in _SAID:
        _SAID.add(said)                    # once per process (a sweep resolves a scenario per point)
        logging.getLogger(__name__).warning(said)
    broken = scenario_pulse_rule_text(radar)
    if broken:
        raise BadInput(f"{source}: {broken}")
    if not any(tg["velocity_mps"]):
        raise BadInput(f"{source}: target.velocity_mps = [0, 0, 0]: must be non-zero (ISAR images a "
                       f"moving object)")
    n_pts = len(tg["points_m"])
    if isinstance(tg["amplitude"], list) and len(tg["amplitude"]) != n_pts:
        raise BadInput(f"{source}: target.amplitude: list of {len(tg['amplitude'])} values; allowed: one "
                       f"number or one per point ({n_pts})")
    t, pos0, vel, _ = isar_geometry(scn)
    r = scatterer_ranges_m(pos0, vel, t)
    reach = C_MPS * radar["pulse_width_s"] / 2.0
    if r.min() <= reach:
        raise BadInput(f"{source}: target.range_m = {tg['range_m']:g}: the object comes within "
                       f"{r.min():.1f} m of the radar, inside the compressed pulse's reach ({reach:.1f} m)")
    if radar["range_window_m"] != "auto":
        near, far = radar["range_window_m"]
        if r.min() < near or r.max() > far:
            raise BadInput(f"{source}: radar.range_window_m = [{near:g}, {far:g}]: the object spans slant "
                           f"ranges {r.min():.1f} to {r.max():.1f} m over the dwell; widen the window or "
                           f"use auto")
        closest = auto_range_extent_m(pos0, vel, r)[0]       # the n0 shift images the object there
        if scn["processing"]["correction"] in ("keystone2_n0", "keystone2_n0_est") and closest < near + reach:
            raise BadInput(f"{source}: radar.range_window_m = [{near:g}, {far:g}]: processing.correction = "
                           f"{scn['processing']['correction']} images the object at its closest-approach range, "
                           f"{closest:.1f} m, outside the window (its focused echo would wrap round); allowed: a "
                           f"window reaching {closest - reach:.1f} m (or auto), or keystone1 / keystone2")
    from ..limits import check_cube_bytes  # before the echo is allocated (issue 12)

    if radar["range_window_m"] != "auto":
        near, far = radar["range_window_m"]
    else:                                         # the simulator's window (its guard samples aside)
        near, far = auto_range_extent_m(pos0, vel, r)
        near, far = near - reach, far + reach
    check_cube_bytes(source, f"radar.range_window_m = {radar['range_window_m']} at radar.fs_hz = "
                     f"{radar['fs_hz']:g}", (far - near) * 2.0 * radar["fs_hz"] / C_MPS + 1, len(t), channels=1,
                     setting=None)
    why = carrier_floor_text(radar["fc_hz"], radar["fs_hz"])    # after the size: a huge fs is first a size
    if why:
        raise BadInput(f"{source}: radar.fc_hz = {radar['fc_hz']:g}: {why.replace('fs_hz', 'radar.fs_hz')}")
    n_cols = None
    if radar["range_window_m"] == "auto":          # the simulator's axis (bounded: the size is checked)
        from ..dsp.pulse import CompressedPulse

        pulse = CompressedPulse(radar["bandwidth_hz"], radar["pulse_width_s"], radar["fs_hz"], radar["range_weighting"])
        axis, holds_closest = isar_auto_range_axis(pos0, vel, r, radar["fs_hz"], pulse)
        if axis[0] <= 0:            # the dwell itself within the pulse's reach and the window's guard
            raise BadInput(f"{source}: target.range_m = {tg['range_m']:g}: the object comes within {r.min():.1f} m "
                           f"of the radar, and the range window holding its echo would begin at {axis[0]:.1f} m; "
                           f"allowed: an object farther than the compressed pulse's reach and the window's guard "
                           f"({-axis[0] + r.min():.1f} m here)")
        if not holds_closest and scn["processing"]["correction"] in ("keystone2_n0", "keystone2_n0_est"):
            closest = auto_range_extent_m(pos0, vel, r)[0]
            raise BadInput(f"{source}: processing.correction = {scn['processing']['correction']}: the object's "
                           f"straight track passes {closest:.1f} m from the radar (its closest approach, where the "
                           f"range-minimum shift images it), within the compressed pulse's reach: no range window "
                           f"holds it; allowed: keystone1 or keystone2, or a track passing farther (a larger "
                           f"target.theta0_deg or target.range_m)")
        n_cols = len(axis)
    _check_n0_padding(scn, source, len(t), vel, n_cols)


def _check_n0_padding(scn: dict, source: str, n: int, vel, n_cols) -> None:
    """``keystone2_n0``'s zero-padded keystone input against the size limit, before the simulation (the
    stage's own check, ``limits.check_keystone_padding``, with the same numbers: n0 as given or from the
    geometry, the range axis the simulator will make, the widest second-order stretch of the band)."""
    radar, tg, proc = scn["radar"], scn["target"], scn["processing"]
    if proc["correction"] != "keystone2_n0":       # (the estimator's n0 comes from the data)
        return
    from ..limits import check_keystone_padding, keystone_padding

    fc, fs = radar["fc_hz"], radar["fs_hz"]
    if proc["n0_pulses"] != "auto":
        n0 = float(proc["n0_pulses"])
    else:                        # eq. (13): the reference point's closest approach, from the dwell's centre
        th = math.radians(tg["theta0_deg"])
        p_mid = tg["range_m"] * np.array([math.cos(th), -math.sin(th), 0.0])
        n0 = -float(p_mid @ vel) / float(vel @ vel) * radar["prf_hz"]
    if n_cols is None:                             # a given window: its samples
        near, far = radar["range_window_m"]
        n_cols = int(np.floor((far - near) * 2.0 * fs / C_MPS)) + 1
    t0 = (n - 1) / 2.0 + n0
    worst = math.sqrt(fc / (fc - fs / 2.0)) - 1.0                 # |1 - alpha| at the band's lower edge, eq. (12)
    pad = keystone_padding(n, t0, worst)[1]
    try:
        check_keystone_padding(n, pad, n_cols, t0, worst, n0_auto=proc["n0_pulses"] == "auto")
    except BadInput as exc:
        raise BadInput(f"{source}: {exc}") from None


# ----------------------------------------------------------------------------------------------
# Geometry
# ----------------------------------------------------------------------------------------------
def isar_geometry(scn: dict):
    """Slow time, initial (t = 0) scatterer positions, velocity and amplitudes of a resolved scenario.

    Returns ``slow_time_s`` [N], ``pos0_m`` [K, 3], ``velocity_mps`` [3], ``amplitudes`` [K].
    """
    radar, tg = scn["radar"], scn["target"]
    n = int(radar["n_pulses"])
    slow_time_s = np.arange(n, dtype=np.float64) / radar["prf_hz"]
    t_mid = (n - 1) / (2.0 * radar["prf_hz"])
    th = math.radians(tg["theta0_deg"])
    p_mid = tg["range_m"] * np.array([math.cos(th), -math.sin(th), 0.0])  # reference scatterer at t_mid
    vel = np.asarray(tg["velocity_mps"], dtype=np.float64)
    offsets = np.asarray(tg["points_m"], dtype=np.float64).reshape(-1, 3)
    pos0 = p_mid[None, :] + offsets - vel[None, :] * t_mid
    amp = tg["amplitude"]
    amps = np.asarray(amp if isinstance(amp, list) else [amp] * len(offsets), dtype=np.float64)
    return slow_time_s, pos0, vel, amps


def auto_range_extent_m(pos0_m, velocity_mps, ranges_m):
    """(nearest, farthest) slant range the auto range window must hold: every scatterer's range over the
    dwell (``ranges_m``, [K, N]) and its range minimum on its straight track (its closest approach, which
    the range-minimum shift n0 refers to, inside the dwell or not).  The simulator's window and the
    size check before it both come from here."""
    vel = np.asarray(velocity_mps, dtype=np.float64)
    pos0 = np.asarray(pos0_m, dtype=np.float64)
    vhat = vel / np.linalg.norm(vel)
    closest_m = np.linalg.norm(pos0 - (pos0 @ vhat)[:, None] * vhat[None, :], axis=1)
    return float(min(ranges_m.min(), closest_m.min())), float(ranges_m.max())


def isar_auto_range_axis(pos0_m, velocity_mps, ranges_m, fs_hz, pulse):
    """(the auto range axis, whether it holds the closest approach): every scatterer's range over the dwell
    and its closest approach (:func:`auto_range_extent_m`), or, where a window holding that approach
    would begin at or below 0 m (a track passing within the pulse's reach of the radar), the dwell's
    ranges alone: only the range-minimum shift images the object there, and it is refused for such a
    track (a cube with a negative first range had been written, and refused by its own reader)."""
    from ..dsp.pulse import auto_range_axis_m

    axis = auto_range_axis_m(*auto_range_extent_m(pos0_m, velocity_mps, ranges_m), fs_hz, pulse)
    if axis[0] > 0:
        return axis, True
    return auto_range_axis_m(float(np.min(ranges_m)), float(np.max(ranges_m)), fs_hz, pulse), False


def scatterer_ranges_m(pos0_m, velocity_mps, slow_time_s):
    """Exact range (eq. 6-7) of every scatterer at every time, radar at the origin: [K, N] float64."""
    p = (np.asarray(pos0_m, dtype=np.float64)[:, None, :]
         + np.asarray(velocity_mps, dtype=np.float64)[None, None, :]
         * np.asarray(slow_time_s, dtype=np.float64)[None, :, None])
    return np.sqrt(np.einsum("kni,kni->kn", p, p))
