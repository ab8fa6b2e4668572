"""Factories for small point-target scenes (Py-ART's ``sample_objects`` style), used by tests."""
from __future__ import annotations

import copy

from .scenario.loader import merged_mapping, resolve_scenario

TINY = {
    "name": "tiny",
    "radar": {"fc_hz": 10.0e9, "bandwidth_hz": 20.0e6, "pulse_width_s": 1.0e-6, "prf_hz": 2000.0,
              "fs_hz": 24.0e6},
    "antenna": {"beamwidth_3db_deg": 6.0, "squint_deg": 1.5, "scan_start_deg": -10.0,
                "scan_stop_deg": 10.0, "scan_rate_dps": 100.0},
    "platform": {"speed_mps": 150.0, "accel_mps2": [0.0, 10.0, 0.0], "height_m": 50.0},
    "scene": {"kind": "points", "points_m": [[-150.0, 1000.0], [0.0, 1030.0], [120.0, 990.0]]},
    "noise": {"snr_db": 30.0, "seed": 7},
    "processing": {"q": 8, "cpi": 16},
}


def _merge(base: dict, extra: dict) -> dict:
    """``extra`` merged into ``base`` as ``--set SECTION={...}`` merges (copies of both: nothing shared)."""
    return merged_mapping(copy.deepcopy(base), copy.deepcopy(extra))


def tiny_scenario(**sections) -> dict:
    """The tiny scene, resolved, with any section keys replaced: ``tiny_scenario(noise={...})``."""
    return resolve_scenario(_merge(TINY, sections), "<tiny>")


def lone_target_scenario(x_m=0.0, y_m=1000.0, **sections) -> dict:
    """One unit point target in the tiny radar, noiseless unless asked."""
    base = {"scene": {"kind": "points", "points_m": [[x_m, y_m]]}, "noise": {"snr_db": None}}
    return resolve_scenario(_merge(_merge(TINY, base), sections), "<lone>")


W_BAND = {
    "radar": {"fc_hz": 94.0e9, "bandwidth_hz": 50.0e6, "pulse_width_s": 1.0e-6, "prf_hz": 2500.0, "fs_hz": 60.0e6},
    "antenna": {"beamwidth_3db_deg": 6.0, "scan_start_deg": -15.0, "scan_stop_deg": 15.0, "scan_rate_dps": 30.0},
    "platform": {"speed_mps": 240.0, "accel_mps2": [0.0, 20.0, 0.0], "height_m": 50.0},
}


def w_band_raw(name: str, points_m, *, snr_db: float, seed: int, processing: dict | None = None) -> dict:
    """An unresolved scenario: the paper's beam, scan and flight at 94 GHz and a = 20, equal points at
    ``points_m`` (the independent review's W-band scenes; resolve it with a ``-c`` preset)."""
    return _merge(W_BAND, {"name": name, "scene": {"kind": "points", "amplitude": 1.0, "points_m": points_m},
                           "noise": {"snr_db": snr_db, "seed": seed},
                           "processing": {"t_ref": "centre", "q": 1, **(processing or {})}})
