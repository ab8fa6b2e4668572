"""ISAR geometry: eq. (13) corrected, the straight-line range model and the truth at any time."""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from ..dsp.geometry import C_MPS

log = logging.getLogger(__name__)


def n0_pulses_eq13(range_m, theta0_deg, speed_mps, prf_hz):
    """Eq. (13) with its units corrected: ``n0 = R0 sin(theta0) F_p / v`` pulses (NOTES.md)."""
    return range_m * math.sin(math.radians(theta0_deg)) * prf_hz / speed_mps


@dataclass(frozen=True)
class LineModel:
    """Straight-line constant-velocity range history about ``t_mid`` (exact for eq. 7).

    ``R(t)^2 = r0^2 + 2 r0 rdot tau + v2 tau^2``, ``tau = t - t_mid``.
    """

    r0_m: float        # range at t_mid
    rdot_mps: float    # range rate at t_mid
    v2_m2ps2: float    # |v|^2
    t_mid_s: float

    def range_m(self, t_s):
        tau = np.asarray(t_s, dtype=np.float64) - self.t_mid_s
        return np.sqrt(np.maximum(self.r0_m**2 + 2.0 * self.r0_m * self.rdot_mps * tau
                                  + self.v2_m2ps2 * tau**2, 0.0))

    @property
    def tc_minus_tmid_s(self) -> float:
        """Time from the middle of the observation to the range minimum."""
        return -self.r0_m * self.rdot_mps / self.v2_m2ps2

    def n0_pulses(self, prf_hz: float) -> float:
        return self.tc_minus_tmid_s * prf_hz

    def doppler_hz(self, fc_hz: float) -> float:
        """Unambiguous Doppler centroid at t_mid, -2 Rdot f0 / c."""
        return -2.0 * self.rdot_mps * fc_hz / C_MPS

    @property
    def omega_rps(self) -> float:
        """Line-of-sight rotation rate at t_mid."""
        return math.sqrt(max(self.v2_m2ps2 - self.rdot_mps**2, 0.0)) / self.r0_m

    def as_dict(self) -> dict:
        return {"r0_m": float(self.r0_m), "rdot_mps": float(self.rdot_mps),
                "v2_m2ps2": float(self.v2_m2ps2), "t_mid_s": float(self.t_mid_s)}


def _truth_line_model(cube, k=0) -> LineModel | None:
    """The straight-line model of truth scatterer ``k`` (needs x/y/z_m and vx/vy/vz_mps)."""
    tr = cube.truth
    if not tr or any(key not in tr for key in ("vx_mps", "vy_mps", "vz_mps")):
        return None
    t_mid = 0.5 * (cube.slow_time_s[0] + cube.slow_time_s[-1])
    v = np.array([tr["vx_mps"][k], tr["vy_mps"][k], tr["vz_mps"][k]])
    p = np.array([tr["x_m"][k], tr["y_m"][k], tr["z_m"][k]]) + v * t_mid
    r0 = float(np.linalg.norm(p))
    if not (r0 > 0 and float(v @ v) > 0):    # at rest, or at the radar: no range curve to model (eq. 7)
        log.warning(f"/truth/targets: scatterer {k} is {'at rest' if r0 > 0 else 'at the radar'}; its truth "
                    f"gives no range model, which comes from the data instead")
        return None
    return LineModel(r0, float(p @ v) / r0, float(v @ v), float(t_mid))


def _truth_positions_at(cube, t_s):
    tr = cube.truth
    p0 = np.column_stack([tr["x_m"], tr["y_m"], tr["z_m"]])
    v = np.column_stack([tr["vx_mps"], tr["vy_mps"], tr["vz_mps"]])
    return p0 + v * t_s, v
