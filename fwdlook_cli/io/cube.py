"""The raw cube: range-compressed sum/difference echoes with their axes, radar and motion.

One object carries what CONTRACT.md section 3 lays out on disk; ``io.read_raw`` and
``io.write_raw`` move it to and from HDF5.  Processing reads only these fields, never the
informational scenario text.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field

import numpy as np
import xxhash

RADAR_KEYS = ("fc_hz", "bandwidth_hz", "fs_hz", "prf_hz", "beamwidth_3db_deg")


@dataclass
class RawCube:
    sum: np.ndarray              # complex64 [n_pulses, n_range]
    diff: np.ndarray | None      # complex64 [n_pulses, n_range]; None for a single-channel cube
                                 # (ISAR): the file has no /echo/diff and root attr channels = "sum"
    slow_time_s: np.ndarray      # float64 [n_pulses], t = 0 at the first pulse
    range_m: np.ndarray          # float64 [n_range], slant range of each sample
    scan_angle_deg: np.ndarray   # float64 [n_pulses], beam pointing azimuth
    position_m: np.ndarray       # float64 [n_pulses, 3], antenna phase centre (INS)
    velocity_mps: np.ndarray     # float64 [n_pulses, 3]
    radar: dict                  # RADAR_KEYS (+ pulse_width_s where known)
    antenna: dict = field(default_factory=dict)   # /antenna: pattern, squint_deg, slope, ratio table, imbalance
    truth: dict | None = None    # x_m, y_m, z_m, amplitude (1-D float64)
    scenario_yaml: str | None = None
    noise: dict = field(default_factory=dict)     # snr_db, sigma, seed (simulated data)
    attrs: dict = field(default_factory=dict)     # provenance

    @property
    def n_pulses(self) -> int:
        return self.sum.shape[0]

    @property
    def n_range(self) -> int:
        return self.sum.shape[1]

    @property
    def range_spacing_m(self) -> float:
        return float(self.range_m[1] - self.range_m[0]) if self.n_range > 1 else float("nan")

    def truth_xyz_m(self) -> np.ndarray | None:
        if not self.truth:
            return None
        return np.column_stack([self.truth["x_m"], self.truth["y_m"], self.truth["z_m"]])

    def to_xarray(self):
        """The cube as an ``xarray.Dataset``: ``sum`` (and ``diff``) on (slow_time_s, range_m), the scan
        angle and the INS track on slow_time_s, truth on ``target``; radar, antenna and noise as attrs
        (prefixed ``radar_``, ``antenna_``, ``noise_``).  Needs xarray (``pip install -e .[xarray]``)."""
        from .xr import cube_to_xarray

        return cube_to_xarray(self)


def cube_hash(cube) -> str:
    """The key of the first stage (``runner.stage_key``), computed once per run: SHA-256 over the
    XXH3-128 digests of the cube's arrays (``io.integrity``'s digest of their C-ordered bytes, each
    hashed in place: no copy; 16 GB/s against SHA-256's 1.4 here) and its radar and antenna settings."""
    h = hashlib.sha256()
    for arr in (cube.sum, cube.diff, cube.slow_time_s, cube.range_m, cube.scan_angle_deg, cube.position_m,
                cube.velocity_mps):
        if arr is not None:
            a = np.ascontiguousarray(arr)
            h.update(f"|{a.dtype.str}|{list(a.shape)}|".encode())
            h.update(xxhash.xxh3_128_digest(memoryview(a.reshape(-1)).cast("B")))
    for settings in (cube.radar, cube.antenna):
        # arrays (the antenna's ratio table) by their bytes: str() of an array is slow (8 ms here for
        # the paper antenna) and elides the middle of one over 1000 elements
        tables = {k: v for k, v in settings.items() if isinstance(v, np.ndarray)}
        plain = {k: v for k, v in settings.items() if k not in tables}
        h.update(json.dumps(plain, sort_keys=True, default=str).encode())
        for k in sorted(tables):
            a = np.ascontiguousarray(tables[k])
            h.update(f"|{k}|{a.dtype.str}|{list(a.shape)}|".encode())
            h.update(memoryview(a.reshape(-1)).cast("B") if a.dtype.kind in "biufc" else repr(a.tolist()).encode())
    return h.hexdigest()
