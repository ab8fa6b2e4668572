"""What the processor knows of the motion: the INS track in the cube, fitted and predicted.

The processor never reads the scenario.  It takes the antenna phase-centre positions and velocities
per pulse (``/platform``) and the beam pointing angles (``/axes/scan_angle_deg``) from the cube and
derives from them what each method needs: the constant acceleration of the paper's model (least
squares over the track), the reference depression angle, and the *predicted beam-centre Doppler
history* (used by ``tracking``) and range histories (``bulk``, ``beam``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..dsp.geometry import C_MPS, unit_vector
from ..dsp.spline import UniformSplineAntiderivative


@dataclass(frozen=True)
class MotionFit:
    """Constant-acceleration fit p(t) = p0 + v0 t + a t^2 / 2 of the INS track."""

    p0_m: np.ndarray
    v0_mps: np.ndarray
    accel_mps2: np.ndarray
    rms_residual_m: float

    def position(self, t_s):
        t = np.asarray(t_s, dtype=np.float64)[..., None]
        return self.p0_m + self.v0_mps * t + 0.5 * self.accel_mps2 * t**2

    def velocity(self, t_s):
        t = np.asarray(t_s, dtype=np.float64)[..., None]
        return self.v0_mps + self.accel_mps2 * t


def fit_motion(slow_time_s, position_m) -> MotionFit:
    t = np.asarray(slow_time_s, dtype=np.float64)
    design = np.column_stack([np.ones_like(t), t, 0.5 * t**2])
    coef, *_ = np.linalg.lstsq(design, position_m, rcond=None)
    resid = position_m - design @ coef
    return MotionFit(coef[0], coef[1], coef[2], float(np.sqrt(np.mean(resid**2))))


def t_ref_seconds(slow_time_s, t_ref: str) -> float:
    """The reference time t_ref (NOTES.md): the first pulse's time (``start``) or the scan's centre."""
    return float(slow_time_s[0]) if t_ref == "start" else float(0.5 * (slow_time_s[0] + slow_time_s[-1]))


def reference_depression_deg(height_m: float, reference_range_m: float) -> float:
    """Depression phi_0 of the scene at the reference slant range (paper: phi ~ phi_0, constant)."""
    return float(np.degrees(np.arcsin(np.clip(height_m / reference_range_m, -1.0, 1.0))))


def position_at(track, index):
    """A per-pulse [n, 3] track (positions, velocities) at a fractional pulse ``index``, linearly
    interpolated (the reference time t_ref's antenna and velocity)."""
    track = np.asarray(track, dtype=np.float64)
    n = np.arange(len(track), dtype=np.float64)
    return np.array([np.interp(index, n, track[:, i]) for i in range(track.shape[1])])


def boresight_doppler_hz(height_m: float, ranges_m, velocity_mps, fc_hz: float):
    """The boresight Doppler 2 v . u(0, phi(r)) / lambda at slant ranges ``ranges_m`` over flat ground,
    phi(r) = asin(h / r) (eq. 16 with the whole velocity vector)."""
    r = np.asarray(ranges_m, dtype=np.float64)
    depression = np.degrees(np.arcsin(np.clip(height_m / r, -1.0, 1.0)))
    return 2.0 * (unit_vector(0.0, depression) @ np.asarray(velocity_mps, dtype=np.float64)) * fc_hz / C_MPS


def boresight_doppler_spread_hz(height_m: float, near_m: float, far_m: float, velocity_mps, fc_hz: float) -> float:
    """How much the boresight Doppler 2 v . u(phi(r)) / lambda changes across slant ranges near..far: the
    paper's one Doppler reference (eq. 16-17) takes phi ~ phi_0 over the window, which steep depression
    breaks (10.4 Hz per metre at 1000 m of height and 1.5 km, 0.05 Hz per metre at 50 m)."""
    f = boresight_doppler_hz(height_m, [near_m, far_m], velocity_mps, fc_hz)
    return abs(float(f[1] - f[0]))


def depression_reference_error_m(height_m: float, ranges_m, reference_range_m: float, velocity_mps, fc_hz: float,
                                 lever_s: float, rate_hz: float | None = None, rounded: bool = False,
                                 guard: float = 1.0):
    """The range error one reference depression phi_0 leaves at slant ranges ``ranges_m`` (flat ground),
    for a point seen ``lever_s`` from t_ref.  There the boresight Doppler 2 v . u(phi(r)) / lambda
    differs from the reference range's, f0.  A shift by the reference's range history (``bulk``,
    ``beam``: ``rate_hz`` None) leaves the walk lambda / 2 |f - f0| lever_s.  A keystone at the rate
    ``rate_hz`` (PRF, or PRF / Q for ``decimation``) resolves the Doppler within +-rate / 2 of its
    centre and leaves the folded part, lambda / 2 |round((f - centre) / rate)| rate lever_s (one
    ambiguity is lambda PRF / 2 metres per second from t_ref): the centre is f0 where the keystone
    follows the reference's Doppler (``tracking``, the sinc implementation), F rate for the whole
    ambiguity number F = round(f0 / rate) of ``traditional`` and ``decimation`` with czt or dft
    (``rounded``: a second review found the sub-swaths judged about f0 there, their targets folded).
    ``guard`` < 1 counts a Doppler past guard x rate / 2 as folded already (the sub-swaths' margin for
    what the boresight model leaves out: the target's own range and speed when the beam sees it)."""
    lam = C_MPS / fc_hz
    f = boresight_doppler_hz(height_m, ranges_m, velocity_mps, fc_hz)
    f0 = float(boresight_doppler_hz(height_m, [reference_range_m], velocity_mps, fc_hz)[0])
    if rate_hz is None:
        return 0.5 * lam * np.abs(f - f0) * lever_s
    centre = float(np.rint(f0 / rate_hz)) * rate_hz if rounded else f0
    folds = np.abs(np.rint((f - centre) / (rate_hz * guard)))
    return 0.5 * lam * folds * rate_hz * lever_s


def beam_points_m(position_m, t_ref_index, beam_deg, depression_deg, reference_range_m):
    """For each pulse n, the ground point on its beam axis: azimuth ``beam_deg[n]`` seen from the
    antenna *at pulse n* (the scan angle is the antenna's pointing at that pulse, CONTRACT section 3),
    at ``reference_range_m`` slant range from it; and the antenna at t_ref.

    (Placing the point at the scan angle seen from the antenna at t_ref instead puts it where the beam
    of pulse n does not look: an error that grows with the distance flown from t_ref, NOTES.md
    "Corrections".)
    """
    p = np.asarray(position_m, dtype=np.float64)
    p_ref = position_at(p, t_ref_index)
    az = np.radians(np.asarray(beam_deg, dtype=np.float64))
    ground = np.sqrt(np.maximum(reference_range_m**2 - p[:, 2] ** 2, 1.0))
    target = np.column_stack([p[:, 0] + ground * np.sin(az), p[:, 1] + ground * np.cos(az), np.zeros(len(p))])
    return target, p_ref


def beam_range_history_m(position_m, t_ref_index, beam_deg, depression_deg, reference_range_m):
    """Predicted slant-range change of the beam-centre point at each pulse, relative to t_ref:
    |P_n - p(t_n)| - |P_n - p_ref| (exact geometry, not the linear projection: the platform moves
    130 m about t_ref)."""
    target, p_ref = beam_points_m(position_m, t_ref_index, beam_deg, depression_deg, reference_range_m)
    return np.linalg.norm(target - position_m, axis=1) - np.linalg.norm(target - p_ref, axis=1)


def keystone_residual_envelope_m(slow_time_s, position_m, velocity_mps, t_ref_s, prf_hz, beam_deg,
                                 depression_deg, reference_range_m):
    """Envelope position left by an exact keystone, relative to R(t_ref), for the beam-centre point.

    Keystone (eq. 8) of exp(-j 4 pi (f_c + f_r) R(t)/c) about t_ref leaves, to first order in f_r/f_c,
    the envelope at R(t') - t' dR/dt(t') (t' from t_ref): R0 for a linear history, R0 - R2 t'^2 for a
    quadratic one (eq. 10, whose f_r t'^2 term eq. 12 compensates with the a_y cos(phi_0) model).  This
    evaluates it exactly for the point each pulse's beam looks at, so the compensation also carries the
    cos(theta) eq. 12 drops and the geometric v^2 (1 - cos^2 theta cos^2 phi)/(2 R) term of eq. (2).
    """
    t = np.asarray(slow_time_s, dtype=np.float64)
    m_ref = (t_ref_s - t[0]) * prf_hz
    target, p_ref = beam_points_m(position_m, m_ref, beam_deg, depression_deg, reference_range_m)
    d = target - position_m
    r = np.linalg.norm(d, axis=1)
    r_dot = -np.einsum("ni,ni->n", d, velocity_mps) / r
    return r - (t - t_ref_s) * r_dot - np.linalg.norm(target - p_ref, axis=1)


def bulk_range_history_m(position_m, t_ref_index, depression_deg):
    """Predicted range change of a boresight (along-track) scatterer: the INS motion along +y."""
    p = np.asarray(position_m, dtype=np.float64)
    n = np.arange(len(p), dtype=np.float64)
    y_ref = np.interp(t_ref_index, n, p[:, 1])
    return -(p[:, 1] - y_ref) * np.cos(np.radians(depression_deg))


def spline_antiderivative(t_s, values):
    """``scipy.interpolate.CubicSpline(t_s, values).antiderivative()``: on a uniform pulse grid the
    closed form of ``dsp.spline`` (the same numbers to rounding, without importing scipy.interpolate:
    a quarter of a second of a command's start), else scipy's."""
    try:
        return UniformSplineAntiderivative(t_s, values)
    except ValueError:                   # not uniform, or too short for the closed form
        pass
    from scipy.interpolate import CubicSpline

    return CubicSpline(t_s, values).antiderivative()


FOLLOW_DEPRESSION_HZ_PER_PRF = 0.01   # the reference's depression followed in time where it moves f_b by more


def tracked_depression_deg(slow_time_s, position_m, velocity_mps, beam_deg, depression_deg: float, fc_hz: float,
                           t_ref_s: float, reference_range_m: float, prf_hz: float):
    """The depression of ``tracking``'s reference point over the scan: the point on the beam axis at
    ``reference_range_m`` from the antenna at t_ref closes in as the platform flies, R(t) = R_ref -
    (p(t) - p(t_ref)) . u(theta(t), phi_0), and its depression asin(h(t) / R(t)) steepens.  At steep
    depression with a long lever that moves its Doppler by a large part of the PRF (a second independent
    review: 35 GHz, 3 km up, t_ref = start, targets folded 5.4 m off); the fixed phi_0 is returned where it
    moves f_b by under ``FOLLOW_DEPRESSION_HZ_PER_PRF`` of the PRF (the paper's: 1.6 Hz), so those chains,
    their stage keys and numbers, are as before."""
    t = np.asarray(slow_time_s, dtype=np.float64)
    p = np.asarray(position_m, dtype=np.float64)
    m_ref = (t_ref_s - t[0]) / max(float(t[1] - t[0]), 1e-300) if len(t) > 1 else 0.0
    p_ref = position_at(p, m_ref)
    r_t = reference_range_m - np.einsum("ni,ni->n", p - p_ref, unit_vector(beam_deg, depression_deg))
    track = np.degrees(np.arcsin(np.clip(p[:, 2] / np.maximum(r_t, 1e-9), -1.0, 1.0)))
    lam = C_MPS / fc_hz
    v = np.asarray(velocity_mps, dtype=np.float64)
    moved = unit_vector(beam_deg, track) - unit_vector(beam_deg, depression_deg)
    moved_hz = 2.0 * np.abs(np.einsum("ni,ni->n", v, moved)) / lam
    return track if float(np.max(moved_hz, initial=0.0)) > FOLLOW_DEPRESSION_HZ_PER_PRF * prf_hz else depression_deg


class DopplerPhaseHistory:
    """Predicted carrier phase of the beam-centre direction, Psi(t) = 2 pi int f_b dt, Psi(t_ref) = 0.

    f_b(t) = 2 v(t) . u(theta_beam(t), phi_0) / lambda is the Doppler of a scatterer on the beam axis
    (eq. 16 and 25 with the INS velocity and the scan).  Psi is the antiderivative of a cubic spline of
    f_b on the pulse grid (not-a-knot, :func:`spline_antiderivative`), so it can be evaluated at the
    keystone's off-grid times.
    """

    def __init__(self, slow_time_s, velocity_mps, beam_deg, depression_deg, fc_hz, t_ref_s):
        los = unit_vector(beam_deg, depression_deg)
        f_b = 2.0 * np.einsum("ni,ni->n", velocity_mps, los) * fc_hz / C_MPS
        self.doppler_hz = f_b
        anti = spline_antiderivative(slow_time_s, f_b)
        self._anti = anti
        self._offset = float(anti(t_ref_s))

    def phase_rad(self, t_s):
        """2 pi int_{t_ref}^{t} f_b dt (float64; large values: reduce before casting)."""
        return 2.0 * np.pi * (self._anti(t_s) - self._offset)


def cpi_doppler_band_hz(velocity_mps, beam_deg, depression_deg, fc_hz, beamwidth_deg, prf_hz, n_cpi_pulses,
                        band_beamwidths=1.0):
    """Doppler band of the main beam per CPI: eq. (25) centroid and eq. (26) width, computed exactly as
    the range of 2 v . u(theta', phi_0) / lambda over theta' = theta +- band_beamwidths * theta_3 / 2,
    with the full velocity vector ``velocity_mps`` ([..., 3]: transverse, forward and vertical motion;
    the paper's 2 v cos(theta') cos(phi_0) / lambda when v is along +y).

    Over theta' the Doppler is A cos(theta' - psi) + C, psi the heading of the horizontal velocity,
    A = 2 |v_h| cos(phi_0) / lambda, C = -2 v_z sin(phi_0) / lambda: its extremes are the band's ends,
    or A + C (C - A) where the heading (its opposite) lies inside the band (eq. 26's second case near
    boresight).  At least 4 Doppler resolution cells wide (and at most the PRF).

    ``depression_deg`` may be a pair [far, near]: the band then covers both depressions, for a range
    window across which the depression, and so the Doppler, changes by more than a Doppler cell
    (steep depression: :func:`doppler_band_depressions`).
    """
    if np.ndim(depression_deg) == 1:
        bands = [cpi_doppler_band_hz(velocity_mps, beam_deg, float(d), fc_hz, beamwidth_deg, prf_hz, n_cpi_pulses,
                                     band_beamwidths) for d in depression_deg]
        f_lo = np.minimum(bands[0][0], bands[1][0])
        f_hi = np.maximum(bands[0][1], bands[1][1])
        centre, width = 0.5 * (f_lo + f_hi), np.minimum(f_hi - f_lo, prf_hz)
        return centre - width / 2, centre + width / 2
    v = np.asarray(velocity_mps, dtype=np.float64)
    lam = C_MPS / fc_hz
    half = band_beamwidths * beamwidth_deg / 2.0
    th = np.asarray(beam_deg, dtype=np.float64)

    def doppler(az_deg):                                  # 2 v . u(theta', phi_0) / lambda, eq. (25)
        return 2.0 * np.sum(v * unit_vector(az_deg, depression_deg), axis=-1) / lam

    f_a, f_b = doppler(th - half), doppler(th + half)
    psi = np.degrees(np.arctan2(v[..., 0], v[..., 1]))
    amp = 2.0 * np.hypot(v[..., 0], v[..., 1]) * np.cos(np.radians(depression_deg)) / lam
    c0 = -2.0 * v[..., 2] * np.sin(np.radians(depression_deg)) / lam

    def within(angle_deg):
        return np.abs((angle_deg - th + 180.0) % 360.0 - 180.0) < half

    f_hi = np.where(within(psi), amp + c0, np.maximum(f_a, f_b))
    f_lo = np.where(within(psi + 180.0), c0 - amp, np.minimum(f_a, f_b))
    min_width = 4.0 * prf_hz / n_cpi_pulses
    centre = 0.5 * (f_lo + f_hi)
    width = np.clip(f_hi - f_lo, min_width, prf_hz)
    return centre - width / 2, centre + width / 2


def doppler_band_depressions(height_m: float, near_m: float, far_m: float, reference_deg: float, velocity_mps,
                             fc_hz: float, prf_hz: float, n_cpi_pulses: int):
    """The depression(s) the CPI Doppler band is computed at: the reference depression phi_0 (eq. 25),
    or [phi(far), phi(near)] where the boresight Doppler changes across the range window by more than
    one Doppler cell PRF / cpi (at 1000 m of height a point 30 m from the window's middle range fell
    outside the band: 22 dB of its peak lost; the paper's scenes: 15 Hz against 78 Hz, unchanged)."""
    spread = boresight_doppler_spread_hz(height_m, near_m, far_m, velocity_mps, fc_hz)
    if spread <= prf_hz / n_cpi_pulses:
        return reference_deg
    return [reference_depression_deg(height_m, far_m), reference_depression_deg(height_m, near_m)]


def cpi_means(data, cpi: int, follow_speed: bool):
    """Per CPI of ``cpi`` pulses (the last partial CPI dropped): (t_cpi [n_cpi, cpi], t_c, mean beam
    angle, velocity) from a stage's ``slow_time_s``, ``scan_angle_deg`` and ``velocity_mps``.  The CPI
    velocity is the INS mean, v_c = v + a t_c (eq. 25, the whole vector), or with ``follow_speed`` off
    the initial velocity for every CPI."""
    t = data["slow_time_s"]
    n_cpi = len(t) // cpi
    m = n_cpi * cpi
    t_cpi = t[:m].reshape(n_cpi, cpi)
    beam_c = data["scan_angle_deg"][:m].reshape(n_cpi, cpi).mean(axis=1)
    vel = data["velocity_mps"][:m].reshape(n_cpi, cpi, 3).mean(axis=1)
    if not follow_speed:
        vel = np.broadcast_to(data["velocity_mps"][0], vel.shape)
    return t_cpi, t_cpi.mean(axis=1), beam_c, vel


AUTO_CELLS_PER_RESOLUTION = 4       # processing.n_doppler: auto, zoomed cells per CPI resolution cell


def widest_cpi_band_hz(data, *, cpi: int, follow_speed: bool, depression_deg, fc_hz: float, beamwidth_deg: float,
                       prf_hz: float, band_beamwidths: float = 1.0) -> float:
    """The widest CPI Doppler band of the scan (Hz): :func:`cpi_doppler_band_hz` of every CPI, as the
    Doppler stage computes it from ``data``'s slow time, scan angle and INS velocity (:func:`cpi_means`)."""
    _, _, beam_c, vel = cpi_means(data, cpi, follow_speed)
    f_lo, f_hi = cpi_doppler_band_hz(vel, beam_c, depression_deg, fc_hz, beamwidth_deg, prf_hz, cpi, band_beamwidths)
    return float(np.max(f_hi - f_lo, initial=0.0))


def auto_doppler_cells(band_hz: float, *, cpi: int, prf_hz: float,
                       per_resolution_cell: float = AUTO_CELLS_PER_RESOLUTION) -> int:
    """``processing.n_doppler: auto``: the zoomed Doppler cells per CPI that sample a band of ``band_hz``
    (the scan's widest, :func:`widest_cpi_band_hz`) at ``per_resolution_cell`` cells per native
    resolution cell PRF / cpi: ``ceil(per_resolution_cell * cpi * band / PRF)``, 4 to 4096.

    A band of B Hz holds B cpi / PRF resolution cells; a point midway between two zoomed cells loses
    sinc^2(1 / (2 per_resolution_cell)) of its peak (rectangular window): 0.22 dB at 4 per cell,
    0.91 dB at 2.  2 per cell is already the Nyquist rate of the CPI's power spectrum (a trigonometric
    polynomial of degree cpi - 1 in f), which holds a point's power whole; 4 per cell is kept because
    the CPI image is a histogram of the cells' monopulse angles, and its fill grows with the count past
    that rate (README, "Doppler cells": at 2 per cell `beam`'s image of the Fig. 8 scene has 15 % empty
    pixels against 4 %, SSIM 0.24 against 0.29).  One count serves every CPI (the spectra are one array), so
    the widest band sets it: 16 cells for a band of the 4-cell minimum, 4 cpi for a band of the whole
    PRF (steep depression)."""
    return int(min(4096, max(4, np.ceil(per_resolution_cell * float(band_hz) * cpi / prf_hz - 1e-9))))
