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


def unit_vector(azimuth_deg, depression_deg):
    """Unit line-of-sight vector from the antenna towards (azimuth, depression): [..., 3]."""
    az, de = np.radians(azimuth_deg), np.radians(depression_deg)
    return np.stack(np.broadcast_arrays(np.cos(de) * np.sin(az), np.cos(de) * np.cos(az), -np.sin(de)),
                    axis=-1)


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


def azimuth_at_t_ref(range_m, azimuth_deg, position_at_measure_m, position_ref_m):
    """Ground point seen at ``azimuth_deg`` from the antenna at one time, and ``range_m`` from it at
    t_ref: returns its azimuth from the t_ref antenna and its ground (x, y); NaN where no solution.

    The monopulse angle is measured at the CPI time, the corrected range refers to t_ref; the point
    P = g_c + s u(theta) (ground) with |P - p_ref| = R is solved exactly (a quadratic in s).
    """
    u = np.stack([np.sin(np.radians(azimuth_deg)), np.cos(np.radians(azimuth_deg))], axis=-1)
    d = position_at_measure_m[..., :2] - position_ref_m[:2]
    b = np.sum(d * u, axis=-1)
    c = np.sum(d * d, axis=-1) + position_ref_m[2] ** 2 - np.asarray(range_m) ** 2
    disc = b * b - c
    s = -b + np.sqrt(np.where(disc >= 0, disc, np.nan))
    gx = position_at_measure_m[..., 0] + s * u[..., 0]
    gy = position_at_measure_m[..., 1] + s * u[..., 1]
    return np.degrees(np.arctan2(gx - position_ref_m[0], gy - position_ref_m[1])), gx, gy


def range_extent_m(position_m, targets_m, *, dense_limit=20_000_000, stride=8):
    """Smallest and largest slant range (eq. 1) of any target over the track, without a dense array.

    Exact (dense over targets x pulses) up to ``dense_limit`` pairs; beyond, the range is evaluated
    every ``stride`` pulses (and at the last) in target chunks and widened by the largest distance the
    antenna moves in stride/2 pulses, a strict bound on how far the range can go between samples.
    """
    position_m = np.asarray(position_m, dtype=np.float64)
    tgt = np.asarray(targets_m, dtype=np.float64).reshape(-1, 3)
    n_p = len(position_m)
    if len(tgt) * n_p <= dense_limit:
        r = slant_range_m(position_m, tgt)
        return float(r.min()), float(r.max())
    idx = np.unique(np.r_[np.arange(0, n_p, stride), n_p - 1])
    step = np.max(np.linalg.norm(np.diff(position_m, axis=0), axis=1)) if n_p > 1 else 0.0
    margin = step * (stride / 2.0 + 1.0)
    lo, hi = np.inf, -np.inf
    chunk = max(1, dense_limit // len(idx))
    for k in range(0, len(tgt), chunk):
        r = slant_range_m(position_m[idx], tgt[k:k + chunk])
        lo, hi = min(lo, float(r.min())), max(hi, float(r.max()))
    return lo - margin, hi + margin
