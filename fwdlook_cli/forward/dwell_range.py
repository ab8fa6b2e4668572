"""Where a dwell cell's range belongs once the monopulse has said its azimuth
(``processing.dwell_range: iso_doppler``; README, "Found on independent cubes").

At steep depression the Doppler of a ground point changes with its range (10.4 Hz per metre at 1000 m
of height, against the dwell's 1/T_dwell = 7 Hz): a dwell cell off a point's direction and off its range
has the point's Doppler history and focuses it; :func:`iso_doppler_range` moves the cell along its
iso-Doppler line to the monopulse azimuth, weighed against the envelope.
"""
from __future__ import annotations

import numpy as np


def ground_points(range_m, azimuth_deg, position_ref_m):
    """Ground point (z = 0) at slant range ``range_m`` and azimuth ``azimuth_deg`` from p_ref: [..., 3]."""
    p_ref = np.asarray(position_ref_m, dtype=np.float64)
    rho = np.sqrt(np.maximum(np.asarray(range_m, dtype=np.float64) ** 2 - p_ref[2] ** 2, 0.0))
    az = np.radians(azimuth_deg)
    rho, az = np.broadcast_arrays(rho, az)
    return np.stack([p_ref[0] + rho * np.sin(az), p_ref[1] + rho * np.cos(az), np.zeros_like(rho)], axis=-1)


def _doppler_hz(range_m, azimuth_deg, position_m, position_ref_m, velocity_mps, lam_m):
    """Doppler, seen from ``position_m`` moving at ``velocity_mps``, of the ground point at slant range
    ``range_m`` from the t_ref antenna and azimuth ``azimuth_deg`` from it."""
    P = ground_points(range_m, azimuth_deg, position_ref_m)
    los = P - position_m
    return 2.0 * np.einsum("ij,j->i", los, velocity_mps) / np.linalg.norm(los, axis=1) / lam_m


def iso_doppler_range(range_m, direction_deg, azimuth_deg, position_m, position_ref_m, velocity_mps, *,
                      lam_m, resolution_m, dwell_s):
    """The range a dwell cell's energy comes from, once the monopulse has said its azimuth.

    A cell (r, theta') of the dwell image focuses every point whose Doppler history matches the ground
    point P(r, theta'); the monopulse moves it to the azimuth theta_m it comes from. The point there on
    the cell's iso-Doppler line lies at r + D / g, D = f(r, theta') - f(r, theta_m), g = df/dr at
    theta_m; the envelope says r within the resolution. The two combined (Gaussian approximations of the
    envelope's main lobe, sigma_r, and of the dwell's Doppler response, sigma_f = 0.886 / (2.355 T)):
    x = g D sigma_r^2 / (sigma_f^2 + g^2 sigma_r^2). At low depression g is about 0 (the iso-Doppler lines
    run along range) and the range stays; steep, g sigma_r >> sigma_f and the cell moves along its line."""
    r = np.asarray(range_m, dtype=np.float64)
    f_cell = _doppler_hz(r, direction_deg, position_m, position_ref_m, velocity_mps, lam_m)
    f_m = _doppler_hz(r, azimuth_deg, position_m, position_ref_m, velocity_mps, lam_m)
    h = 0.5 * resolution_m
    g = (_doppler_hz(r + h, azimuth_deg, position_m, position_ref_m, velocity_mps, lam_m)
         - _doppler_hz(r - h, azimuth_deg, position_m, position_ref_m, velocity_mps, lam_m)) / (2.0 * h)
    sigma_r = 0.886 * resolution_m / 2.355
    sigma_f = 0.886 / dwell_s / 2.355
    return r + g * (f_cell - f_m) * sigma_r**2 / (sigma_f**2 + g**2 * sigma_r**2)
