"""The dwell image's response to a point against its angle, so that a point's peak is one direction's
matched power wherever it lies (``dwell.dwell_image`` divides it out; README, "The dwell image's
radiometry").

Each focused direction's dwell sum is a matched filter over its beam dwell, and a point off that
direction by x is seen as long as the Doppler offset 2 v cos(phi) |sin(theta - axis)| x / lambda stays in
the dwell's Doppler lobe (``dwell_grid.lobe_half_width_hz``).  The image projects every direction's cell
to its monopulse angle, so a point accumulates the power of every direction that sees it.  Far from the
flight axis that is about one direction's worth (the focus directions sample the lobe, ``dwell_grid``);
near it the Doppler is flat in angle and every direction within about 0.7 deg of the axis sees a point
there (18 GHz, the paper's flight): it came out 14 dB brighter than the same point 10 deg off, +6 dB at
1.1 deg, +3 to +4.4 dB at 1.6-4.3 deg, against the joint fit's points, drawn at one direction's power
(``dwell.py``: S' = c L gain), whose range sidelobes outside the fitted cells then stood at -8 dB beside
them (an independent review, fifty-ninth round).

The response is the imaging's own: :func:`dwell.dwell_focus` (the same directions, sub-apertures,
windows, weights and twin null) applied to synthetic noiseless points at a set of angles at the
window's middle range, their sum and difference histories from the two-Gaussian-beam patterns the
focus rotates with, projected by their monopulse angles as the image projects its cells, and their
peak taken against one direction's matched power |L sum_j w_j^2|^2 (the scale of the fit's points).  On
the isolated points' angles it predicts the measured steps within 0.7 dB (0-10.7 deg).  Between the
synthetic angles (:data:`RESPONSE_OFFSETS_DEG` either side of the axis) it is interpolated in dB.

It is divided out within the fit's region of the axis (``dwell.dwell_image``'s ``response_half_width_deg``,
with or without the fit), where it is largest and where the fit draws its points at one direction's
power; beyond it (+1.7 dB at 6.5 deg, -0.8 dB at 10.7 deg) the image stays as it was: dividing it out
there too dimmed the lattice's points 5-10 deg off the axis by 2-3 dB against the image-wide noise
median the detection counts from, 10 more of 63 missed at 0 dB of SNR (README).
"""
from __future__ import annotations

import numpy as np

from ..dsp.geometry import C_MPS, azimuth_at_t_ref
from ..dsp.keystone_common import _cis as cis_cycles
from .dwell_range import ground_points

RESPONSE_OFFSETS_DEG = np.array([0.0, 0.2, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.2, 1.5, 2.0, 3.0, 4.5, 6.0,
                                 8.0, 10.0, 13.0, 16.0, 20.0, 25.0, 32.0, 40.0])
"""The synthetic points' offsets from the flight axis (both sides): finest where the response falls
fastest, 0.5-1.2 deg at 18 GHz (+14 dB to +6 dB); it is smooth beyond (measured on the isolated points:
README, "The dwell image's radiometry")."""


def response_angles(angle_deg, axis_deg: float, half_width_deg: float) -> np.ndarray:
    """The synthetic points' angles: :data:`RESPONSE_OFFSETS_DEG` either side of the flight axis up to
    ``half_width_deg`` and the next beyond it, within the image's span."""
    lo, hi = float(angle_deg[0]), float(angle_deg[-1])
    reach = RESPONSE_OFFSETS_DEG[: int(np.searchsorted(RESPONSE_OFFSETS_DEG, half_width_deg)) + 1]
    test = np.unique(np.round(np.concatenate([axis_deg - reach, axis_deg + reach]), 9))
    return test[(test >= lo) & (test <= hi)]


def point_histories(test_deg, range_m: float, *, position_m, scan_angle_deg, position_ref_m, fc_hz: float,
                    slope_per_deg: float, beta_per_deg2: float):
    """Sum and difference slow-time histories [pulses, len(test_deg)] (complex64) of unit ground points at
    ``test_deg`` from the t_ref antenna and ``range_m`` from it (each column a hair further, 1 mm, so that
    the columns are a range axis), as the chain leaves them (range history straightened, the carrier
    phase -4 pi (R(t) - r) / lambda kept): two-way sum Sigma^2 and sum x difference Sigma Delta, with
    Sigma = exp(-beta d^2) cosh(k d), Delta = exp(-beta d^2) sinh(k d) of the offset d from the beam."""
    lam = C_MPS / fc_hz
    rr = float(range_m) + 1e-3 * np.arange(len(test_deg))
    points = ground_points(rr, np.asarray(test_deg, dtype=np.float64), position_ref_m)        # [n, 3]
    sight = points[None, :, :] - np.asarray(position_m, dtype=np.float64)[:, None, :]     # [pulses, n, 3]
    r_t = np.linalg.norm(sight, axis=-1)
    offset = np.degrees(np.arctan2(sight[..., 0], sight[..., 1])) - np.asarray(scan_angle_deg, float)[:, None]
    offset = offset.astype(np.float32)
    taper = np.exp(np.float32(-beta_per_deg2) * offset**2)
    sigma = taper * np.cosh(np.float32(slope_per_deg) * offset)
    delta = taper * np.sinh(np.float32(slope_per_deg) * offset)
    phase = cis_cycles((r_t - rr[None, :]) * (-2.0 / lam), np.complex64)    # reduced in float64 (keystone_common)
    return sigma * sigma * phase, sigma * delta * phase, rr


def point_response(*, angle_deg, dirs, dir_weight, first_dir, range_m, focus, slow_time_s, scan_angle_deg,
                   position_m, velocity_mps, position_ref_m, fc_hz: float, prf_hz: float, slope_per_deg: float,
                   beta_per_deg2: float, sub_pulses: int, dwell_half_width_deg: float, twin_axis_deg: float,
                   max_ratio: float, half_width_deg: float, focus_kwargs=None) -> np.ndarray:
    """The dwell image's peak response to a unit point at each image angle ``angle_deg``, over one
    direction's matched power (module docstring): a linear factor >= 0 per bin, 1 where no synthetic
    point is seen.  ``focus``: :func:`dwell.dwell_focus`; ``dirs``, ``dir_weight``, ``first_dir``: the
    focused directions, their weights and each bin's own (``dwell_grid.focus_directions``); ``range_m``:
    the window's slant ranges (the points at its middle); ``max_ratio``: the monopulse ratio the image
    projects up to; ``focus_kwargs``: the twin null's settings, as the image's focus has them."""
    angle_deg = np.asarray(angle_deg, dtype=np.float64)
    p_ref = np.asarray(position_ref_m, dtype=np.float64)
    zone = np.abs(angle_deg - twin_axis_deg) <= half_width_deg
    test = response_angles(angle_deg, twin_axis_deg, half_width_deg)
    if not zone.any() or len(test) == 0:
        return np.ones(len(angle_deg))
    r_mid = 0.5 * (float(range_m[0]) + float(range_m[-1]))
    s_syn, d_syn, rr = point_histories(test, r_mid, position_m=position_m, scan_angle_deg=scan_angle_deg,
                                       position_ref_m=p_ref, fc_hz=fc_hz, slope_per_deg=slope_per_deg,
                                       beta_per_deg2=beta_per_deg2)
    s_rot, d_rot, gain, pos_dwell, plain_gain = focus(
        s_syn, d_syn, slow_time_s=slow_time_s, scan_angle_deg=scan_angle_deg, position_m=position_m,
        velocity_mps=velocity_mps, range_m=rr, angle_deg=dirs, fc_hz=fc_hz, prf_hz=prf_hz,
        slope_per_deg=slope_per_deg, beta_per_deg2=beta_per_deg2, position_ref_m=p_ref, sub_pulses=sub_pulses,
        dwell_half_width_deg=dwell_half_width_deg, twin_axis_deg=twin_axis_deg, **(focus_kwargs or {}))
    power = (np.abs(s_rot) ** 2).astype(np.float64)                                    # [dirs, n]
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.real(d_rot * np.conj(s_rot)) / power
    seen = (gain > 0)[:, None] & (np.abs(ratio) < max_ratio) & (power > 0)
    offset = np.where(seen, np.arctanh(np.where(seen, ratio, 0.0)) / slope_per_deg, 0.0)
    step = float(angle_deg[1] - angle_deg[0]) if len(angle_deg) > 1 else 1.0
    n_a, n_t = len(angle_deg), len(test)
    # each direction's cell of each point projected as the image projects (dwell.dwell_image, step 5)
    p_dir = ground_points(rr[None, :], dirs[:, None], p_ref)                              # [dirs, n, 3]
    az_dw = np.degrees(np.arctan2(p_dir[..., 0] - pos_dwell[:, None, 0], p_dir[..., 1] - pos_dwell[:, None, 1]))
    az, _, _ = azimuth_at_t_ref(np.broadcast_to(rr, az_dw.shape), az_dw + offset, pos_dwell[:, None, :], p_ref)
    ok = seen & np.isfinite(az)
    a_idx = np.rint((np.where(ok, az, angle_deg[0]) - angle_deg[0]) / step).astype(np.int64)
    ok &= (a_idx >= 0) & (a_idx < n_a)
    flat = (a_idx + n_a * np.arange(n_t)[None, :])[ok]
    image = np.bincount(flat, weights=(power * dir_weight[:, None])[ok], minlength=n_a * n_t).reshape(n_t, n_a)
    own = first_dir[np.clip(np.rint((test - angle_deg[0]) / step).astype(np.int64), 0, n_a - 1)]
    one = (sub_pulses * plain_gain[own]) ** 2
    peak = image.max(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        peak_db = np.where((one > 0) & (peak > 0), 10.0 * np.log10(peak / one), np.nan)
    known = np.isfinite(peak_db)
    if not known.any():
        return np.ones(n_a)
    return np.where(zone, 10.0 ** (np.interp(angle_deg, test[known], peak_db[known]) / 10.0), 1.0)
