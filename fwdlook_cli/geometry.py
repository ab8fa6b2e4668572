"""Forward-looking geometry of Li & Li (2023), Fig. 1 and eq. (1)-(3), (15)-(20).

Ground frame: x cross-range (right), y forward along the flight path, z up.  The antenna phase centre
starts at (0, 0, h) with speed v along +y and constant acceleration (a_x, a_y, a_z).  Azimuth is the
ground-plane angle atan2(dx, dy) from +y towards +x; depression is the angle below the horizontal.
The simulator uses the exact range (eq. 1); the Taylor forms are for the processor and ``plan``.
"""
from __future__ import annotations

import numpy as np

C_MPS = 299_792_458.0


def platform_state(slow_time_s, speed_mps, accel_mps2, height_m):
    """Antenna phase-centre position and velocity at each slow time (paper Fig. 1, point B).

    Returns ``position_m`` and ``velocity_mps``, both float64 [n, 3].
    """
    t = np.asarray(slow_time_s, dtype=np.float64)[:, None]
    a = np.asarray(accel_mps2, dtype=np.float64)[None, :]
    v0 = np.array([0.0, speed_mps, 0.0])[None, :]
    p0 = np.array([0.0, 0.0, height_m])[None, :]
    return p0 + v0 * t + 0.5 * a * t**2, v0 + a * t


def slant_range_m(position_m, targets_m):
    """Exact slant range (eq. 1) of every target from every antenna position: float64 [n_targets, n]."""
    d = np.asarray(targets_m, dtype=np.float64)[:, None, :] - np.asarray(position_m)[None, :, :]
    return np.sqrt(np.einsum("kni,kni->kn", d, d))


def azimuth_deg(position_m, targets_m):
    """Ground-plane azimuth atan2(dx, dy) of every target seen from every position: [n_targets, n]."""
    t = np.asarray(targets_m, dtype=np.float64)
    p = np.asarray(position_m, dtype=np.float64)
    return np.degrees(np.arctan2(t[:, None, 0] - p[None, :, 0], t[:, None, 1] - p[None, :, 1]))


def depression_deg(position_m, targets_m):
    """Depression angle of every target below the antenna's horizontal: [n_targets, n]."""
    t = np.asarray(targets_m, dtype=np.float64)
    p = np.asarray(position_m, dtype=np.float64)
    ground = np.hypot(t[:, None, 0] - p[None, :, 0], t[:, None, 1] - p[None, :, 1])
    return np.degrees(np.arctan2(p[None, :, 2] - t[:, None, 2], ground))


def scan_angle_deg(slow_time_s, scan_start_deg, scan_rate_dps):
    """Beam pointing azimuth of a uniform scan."""
    return scan_start_deg + scan_rate_dps * np.asarray(slow_time_s, dtype=np.float64)


def doppler_centroid_hz(speed_mps, fc_hz, azimuth_deg_, depression_deg_):
    """Eq. (16): f_dc = 2 v f_c cos(theta) cos(phi) / c."""
    return (2.0 * speed_mps * fc_hz / C_MPS * np.cos(np.radians(azimuth_deg_))
            * np.cos(np.radians(depression_deg_)))


def ambiguity_number(doppler_hz, prf_hz):
    """Eq. (17): F = <f_dc / F_R>, rounding half away from zero as the paper's <.> operator."""
    ratio = np.asarray(doppler_hz, dtype=np.float64) / prf_hz
    return (np.sign(ratio) * np.floor(np.abs(ratio) + 0.5)).astype(np.int64)


def residual_velocity_mps(prf_hz, fc_hz, q=1):
    """Eq. (19)-(20): radial-velocity error of one wrong ambiguity number, c (F_R/Q) / (2 f_c)."""
    return C_MPS * (prf_hz / q) / (2.0 * fc_hz)


def scene_geometry(scn: dict):
    """Slow time, platform state and target positions of a resolved forward-looking scenario."""
    from .config import n_pulses, scene_points

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
    from .scene_sim import range_extent_m

    _, position_m, _, targets_m, _ = scene_geometry(scn)
    return range_extent_m(position_m, targets_m)
