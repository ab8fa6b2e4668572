"""What the joint fit (``dwell_fit``) resolves: the ``resolved`` flag of a target inside the fit's
region is the conditioning of its atom against its neighbours' (``dwell_fit`` module docstring,
"Separability")."""
from __future__ import annotations

import numpy as np

from .dwell_fit import RESOLVED_MAX_CORR, FitModel


def fit_resolved_flags(range_m, azimuth_deg, *, position_m, scan_angle_deg, axis_deg, half_width_deg,
                       dwell_half_width_deg, fc_hz, slope_per_deg, beta_per_deg2, position_ref_m, range_resolution_m,
                       boresight_offset_deg=0.0, max_corr=RESOLVED_MAX_CORR):
    """What the joint fit resolves, per target at slant range ``range_m`` and azimuth ``azimuth_deg``
    (both at t_ref): (inside [T], resolved [T]).  ``inside``: the target is in the fit's region.  There
    it is resolved when its atom and every other target's within one range resolution are parted:
    their normalised correlation |a_i^H a_j| / (||a_i|| ||a_j||) over the fit window (the module's
    model at the target's range, full PRF) is at most ``max_corr``.  Mirror twins +-theta correlate
    through the pattern alone (exp(-(2 beta - k^2) theta^2), module docstring); one target's own
    twin at theta -> 0 does not exist, so the point on the axis is resolved from its neighbours by
    the Doppler their phase histories differ by over the window."""
    r = np.asarray(range_m, dtype=np.float64)
    az = np.asarray(azimuth_deg, dtype=np.float64)
    beam = np.asarray(scan_angle_deg, dtype=np.float64)
    inside = np.abs(az - axis_deg) <= half_width_deg
    resolved = np.ones(len(r), bool)
    win = np.flatnonzero(np.abs(beam - axis_deg) <= half_width_deg + dwell_half_width_deg)
    if not inside.any() or len(win) == 0:
        return inside, resolved
    model = FitModel(position_m=np.asarray(position_m)[win], scan_angle_deg=beam[win], fc_hz=fc_hz,
                     slope_per_deg=slope_per_deg, beta_per_deg2=beta_per_deg2, position_ref_m=position_ref_m,
                     boresight_offset_deg=boresight_offset_deg)
    targets = np.flatnonzero(inside)
    near = [np.flatnonzero(np.abs(r - r[i]) < range_resolution_m) for i in targets]     # itself included
    width = max(len(nb) for nb in near)
    # every target's atom and its neighbours' at its range, one block of targets at a time: the columns
    # [2N, targets, width] (a neighbour list padded with the target itself, its correlation dropped)
    for lo in range(0, len(targets), 32):
        blk = targets[lo:lo + 32]
        cols = np.array([np.concatenate([nb, np.full(width - len(nb), i)]) for i, nb in zip(blk, near[lo:lo + 32])])
        own = cols == blk[:, None]
        ph = model.paired_phases(az[cols], r[blk][None, :])[0]                     # [N, J, W]
        g_s, g_d = (g.reshape(model.n, *cols.shape) for g in
                    model.gains(az[cols].ravel(), None, rho_m=np.repeat(model.rho(r[blk]), width)))
        # a^H a_self = sum_n conj(ph) ph_self (g_s g_s,self + g_d g_d,self); ||a||^2 = sum_n g_s^2 + g_d^2
        jj, self_w = np.arange(len(blk)), np.argmax(own, axis=1)
        q = g_s * g_s[:, jj, self_w][:, :, None]
        q += g_d * g_d[:, jj, self_w][:, :, None]
        q = q * np.conj(ph[:, jj, self_w])[:, :, None]                                  # [N, J, W]
        norm2 = np.sum(g_s.astype(np.float64) ** 2 + g_d.astype(np.float64) ** 2, axis=0)     # [J, W]
        corr = np.abs(np.einsum("njw,njw->jw", ph, q)) / np.sqrt(
            np.maximum(norm2 * norm2[jj, self_w][:, None], 1e-300))
        corr[own] = 0.0
        resolved[blk] = corr.max(axis=1) <= max_corr
    return inside, resolved
