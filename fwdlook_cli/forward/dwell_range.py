"""The dwell image's range at steep depression (README, "Found on independent cubes"), and the
geometry it shares with ``dwell.py`` (ground points, the dwell time, the stage's optional parameters).

* :func:`focus_range_oversample`: where the sub-apertures' range phases widen the image's range band
  beyond the native rate, the dwell is focused on the oversampled grid (automatic, by geometry).
* :func:`iso_doppler_range` (``processing.dwell_range: iso_doppler``): the Doppler of a ground point
  changes with its range (10.4 Hz per metre at 1000 m of height, against the dwell's 1/T_dwell = 7 Hz),
  so a dwell cell off a point's direction and off its range focuses it; the cell is moved along its
  iso-Doppler line to the monopulse azimuth, weighed against the envelope.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..dsp.antenna import two_way_width_for
from ..dsp.blas import worker_threads
from ..dsp.geometry import C_MPS
from ..dsp.peaks import oversample_range
from ..io import backing


def flight_axis_deg(velocity_mps):
    """Azimuth (deg, from +y towards +x) of the horizontal velocity: the flight axis, the mirror axis of
    the dwell's twins and the joint fit's region (a float for one velocity, an array for [..., 3])."""
    v = np.asarray(velocity_mps, dtype=np.float64)
    axis = np.degrees(np.arctan2(v[..., 0], v[..., 1]))
    return float(axis) if v.ndim == 1 else axis


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


def focus_range_rate(range_m, position_m, position_ref_m, fc_hz: float, *, resolution_m: float,
                     scan_angle_deg=None, half_width_deg=None) -> float:
    """The dwell image's range bandwidth (cycles per metre of range) near the flight axis, or, given the
    scan (``scan_angle_deg``, per pulse) and the beam's 3 dB half-width, off it: the largest over 17
    directions the scan gives a whole 3 dB dwell, each over the pulses whose beam is within
    ``half_width_deg`` of it.

    The dwell image at (r, theta) is the envelope times the coherence C(r - r_T) of the sub-apertures'
    phases 4 pi (|P(r) - p_j| - r) / lambda; their slopes s_j = d|P - p_j|/dr - 1 are zero at t_ref and
    grow with the depression and the track's length (+-0.011 at 1000 m of height over a 675-pulse scan of
    the paper's radar, 5e-5 at 50 m), so the image's range bandwidth is 1/resolution + 4 max|s_j| / lambda.
    Off the axis they grow too, about as (d sin(theta) / r)^2 / 2 with d the distance flown from t_ref."""
    rr = np.asarray(range_m, dtype=np.float64)
    dr = float(rr[1] - rr[0])
    p_ref = np.asarray(position_ref_m, dtype=np.float64)
    pos_all = np.asarray(position_m, dtype=np.float64)
    r_mid, h = 0.5 * (rr[0] + rr[-1]), 0.5 * dr
    ground = np.sqrt(np.maximum(np.array([r_mid - h, r_mid + h]) ** 2 - p_ref[2] ** 2, 0.0))

    def slope_max(theta_deg, pulses):
        u = np.array([np.sin(np.radians(theta_deg)), np.cos(np.radians(theta_deg))])
        points = np.stack([p_ref[0] + ground * u[0], p_ref[1] + ground * u[1], np.zeros(2)], axis=-1)
        dist = np.linalg.norm(points[None, :, :] - pulses[:, None, :], axis=2)            # [pulses, 2]
        return float(np.max(np.abs((dist[:, 1] - dist[:, 0]) / (2.0 * h) - 1.0)))

    if scan_angle_deg is None:                                           # along the axis, the whole track
        s_max = slope_max(0.0, pos_all[:: max(1, len(pos_all) // 64)])
    else:
        scan = np.asarray(scan_angle_deg, dtype=np.float64)
        every = max(1, len(scan) // 4096)
        s_max = 0.0
        for theta in np.linspace(scan.min() + half_width_deg, scan.max() - half_width_deg, 17):
            lit = pos_all[::every][np.abs(scan[::every] - theta) <= half_width_deg]
            if len(lit):
                s_max = max(s_max, slope_max(theta, lit))
    return 1.0 / resolution_m + 4.0 * s_max / (C_MPS / fc_hz)   # the envelope's band 2B/c plus the slopes' spread


OFF_AXIS_BAND_MARGIN = 1.10   # off the axis the fine grid is taken where the band passes the native rate by 10 %


def focus_range_oversample(range_m, position_m, position_ref_m, fc_hz: float, range_oversample: int, *,
                           resolution_m: float, scan_angle_deg=None, half_width_deg=None) -> int:
    """1, or ``range_oversample`` where the dwell image must be focused on the oversampled range grid:
    where its range bandwidth (:func:`focus_range_rate`) passes the native sampling rate, the image
    sampled on the native grid aliases, and its FFT oversampling is no longer its interpolation (the
    range error at (0, 1200) m from 1000 m of height: -0.14 m on the native samples, -0.71 m
    oversampled x 4).  (``processing.range_oversample: auto`` takes at least x 4 there,
    :func:`auto_focus_range_oversample`.)

    Off the axis (given the scan): where the band over the lit pulses passes the native rate by more
    than ``OFF_AXIS_BAND_MARGIN`` (an independent review, fifty-second round: a +-30 deg scan of the
    paper's radar, 2.5 times the rate, put points 24-28 deg out up to 1.9 m off on the native grid, 0.35 m
    on the fine one; a +-20 deg scan, 1.16 times, 0.99 m against 0.36 m at 19 deg; the paper's +-15 deg
    scan, 1.03 times at a = 50, 0.017 against 0.015 m on its isolated points and 0.43 against 0.52 m on
    its lattice, at a quarter of the stage's time: the margin is that measured bracket, not a bound)."""
    dr = float(range_m[1] - range_m[0])
    axis_rate = focus_range_rate(range_m, position_m, position_ref_m, fc_hz, resolution_m=resolution_m)
    if axis_rate * dr > 1.0:
        return int(range_oversample)
    if scan_angle_deg is not None and half_width_deg is not None:
        lit_rate = focus_range_rate(range_m, position_m, position_ref_m, fc_hz, resolution_m=resolution_m,
                                    scan_angle_deg=scan_angle_deg, half_width_deg=half_width_deg)
        if lit_rate * dr > OFF_AXIS_BAND_MARGIN:
            return int(range_oversample)
    return 1


FOCUS_CHUNK_ROWS = 128       # pulses per one-thread resampling call of the focus grid (oversample_focus_input)


def oversample_focus_input(x, factor: int) -> np.ndarray:
    """``x`` [pulses, ranges] band-limited oversampled in range by ``factor`` (``dsp.peaks.oversample_range``),
    complex64, into :func:`io.backing.empty` (file-backed out of core): in chunks of ``FOCUS_CHUNK_ROWS``
    pulses, each resampled on one thread, the chunks spread over the cores.  ducc0 rounds a row by its
    place in its batch and by its threads' split of the batch, so fixed chunks give every pulse the same
    bits in memory and out of core, on one core or many (an independent review: out of core the dwell
    had been focused on the native grid instead, a different image, a target 2.1 m off)."""
    n_p, n_r = x.shape
    out = backing.empty((n_p, n_r * int(factor)), np.complex64)

    def chunk(a):
        rows = np.asarray(x[a:a + FOCUS_CHUNK_ROWS], dtype=np.complex64)
        oversample_range(rows, factor, workers=1, out=out[a:a + FOCUS_CHUNK_ROWS])

    with ThreadPoolExecutor(max_workers=max(1, worker_threads())) as pool:
        list(pool.map(chunk, range(0, n_p, FOCUS_CHUNK_ROWS)))
    return out


STEEP_FOCUS_OVERSAMPLE = 4    # the fine focus grid of range_oversample: auto (auto_focus_range_oversample)


def auto_focus_range_oversample(cube, position_ref_m, image_factor: int, geo: dict | None = None) -> int:
    """``processing.range_oversample: auto`` for the dwell image: the image's own factor (the power
    image's Nyquist rate, ``dsp.imaging.auto_range_oversample``), or, where the dwell must be focused on
    the fine grid (:func:`focus_range_oversample`), at least ``STEEP_FOCUS_OVERSAMPLE`` (4).

    Not the factor that samples the whole band of :func:`focus_range_rate`: that band is set by the
    largest slope over the whole track, where the beam weights the sub-apertures least.  Measured on a
    675-pulse scan of the paper's radar from 1000 m of height (2.95 per metre on its 2.5 m grid: x 8 or
    9; noiseless points at (80, 1250) and (0, 1200) m, both ``dwell_range`` modes, the x 4 grid against
    the band's): range errors -0.151 / -0.155, 0.038 / 0.012, 0.063 / 0.048 and -0.129 / -0.184 m,
    3 dB widths within 0.2 m, azimuths equal to 1e-4 deg, at twice the dwell stage's time (162-201
    against 312-416 ms)."""
    fine = STEEP_FOCUS_OVERSAMPLE if needs_fine_focus(cube, position_ref_m, geo) else 1
    return max(int(image_factor), fine)          # (fine is 1 where the native grid holds the band)


def needs_fine_focus(cube, position_ref_m, geo: dict | None = None) -> bool:
    """Whether the dwell image must be focused on the oversampled range grid (:func:`focus_range_oversample`
    over the scan's lit directions); kept in ``geo["fine_focus"]`` where ``geo`` is given, as both
    ``range_oversample: auto`` and the stage's parameters ask."""
    if geo is not None and "fine_focus" in geo:
        return geo["fine_focus"]
    fine = focus_range_oversample(cube.range_m, cube.position_m, position_ref_m, cube.radar["fc_hz"], 2,
                                  resolution_m=C_MPS / (2.0 * float(cube.radar["bandwidth_hz"])),
                                  scan_angle_deg=cube.scan_angle_deg,
                                  half_width_deg=0.5 * two_way_width_for(cube.radar["beamwidth_3db_deg"],
                                                                         cube.antenna)) > 1
    if geo is not None:
        geo["fine_focus"] = fine
    return fine


def dwell_duration_s(cube) -> float:
    """T_dwell: the time the scan keeps a direction inside the two-way 3 dB beam (its Doppler
    resolution is 1/T_dwell; 0.142 s, 354 pulses, for the paper's 4.25 deg at 30 deg/s)."""
    rate_dps = float(np.median(np.abs(np.diff(cube.scan_angle_deg)))) * cube.radar["prf_hz"]
    t_scan = cube.n_pulses / cube.radar["prf_hz"]
    two_way_deg = two_way_width_for(cube.radar["beamwidth_3db_deg"], cube.antenna)
    return min(two_way_deg / max(rate_dps, 1e-12), t_scan)


def dwell_stage_params(cube, proc: dict, geo: dict) -> dict:
    """The dwell image's parameters these options add (none by default: the stage's key, and so its
    reuse, are those of before them)."""
    return {**_iso_doppler_params(cube, proc), **_focus_params(cube, proc, geo)}


def _iso_doppler_params(cube, proc: dict) -> dict:
    """The dwell image's parameters for ``processing.dwell_range: iso_doppler`` (none for envelope:
    the stage's key, and so its reuse, are those of before the option)."""
    if proc.get("dwell_range", "envelope") != "iso_doppler":
        return {}
    return {"iso_doppler_resolution_m": C_MPS / (2.0 * float(cube.radar["bandwidth_hz"])),
            "dwell_s": dwell_duration_s(cube)}


def _focus_params(cube, proc: dict, geo: dict) -> dict:
    """``focus_oversample`` where the geometry needs the dwell focused on the fine range grid (none
    where it does not: the stage's key, and so its reuse, as before)."""
    factor = int(geo["range_oversample"]) if needs_fine_focus(cube, geo["p_ref"], geo) else 1
    return {"focus_oversample": factor} if factor > 1 else {}
