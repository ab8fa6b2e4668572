"""Joint sparse fit of the scatterers near the flight axis over the whole dwell (``dwell_fit``).

The linear per-direction estimator of ``dwell.py`` (matched filter, twin null) cannot part what one
direction's dwell integrates together: mirror directions +-theta (flight along +y: one range and
Doppler history, exactly) and neighbours closer in Doppler than 1/T_dwell.  What parts them is the
antenna: over the scan each pulse n weights a scatterer at theta by the two-way sum and difference
gains of its offset from that pulse's beam axis beta_n, and the beam reaches -theta before +theta.
So, per range cell b (the range-time cube after stage 5, every envelope at its slant range from the
antenna at t_ref), the pulses n of the window around the flight axis are modelled as

    y_b(n) = [Sigma_b(n), Delta_b(n)] = sum_k c_kb a_b(theta_k; n) + noise,
    a_b(theta; n) = exp(-j 4 pi (|P_b(theta) - p(t_n)| - r_b) / lambda) [G_s(d_n), G_d(d_n)],

P_b(theta) the ground point at slant range r_b and azimuth theta from the t_ref antenna, p(t_n) the
INS positions, d_n = az(P_b from p(t_n)) - beta_n - boresight offset, and the two-way gains of the
chain's monopulse model (two Gaussian beams: G_s = e^{-2 beta d^2} cosh^2(k d), G_d = e^{-2 beta d^2}
cosh(k d) sinh(k d), k the calibrated slope, the channel imbalance divided out before).  It is linear
in c; the angles are found by a group orthogonal matching pursuit over the range cells of a cluster
(one angle set, one amplitude per range cell: a scatterer spans several range cells), each new angle
refined continuously (parabolic steps on the group's projected energy), the amplitudes re-solved by
least squares per cell, and at the end every angle re-refined with the others held (RELAX sweeps).
The channels are whitened by their noise power (the cube's median sample power / ln 2).

Stop: the next atom's group statistic sum_b |a_b^H r_b|^2 / ||a_b||^2 (noise units) under the
value that noise alone exceeds with probability ``PFA`` over the dictionary (Gamma(B) tail, B range
cells), or under ``FIT_DYNAMIC_DB`` below the cluster's first atom (the model's own accuracy: the
Gaussian patterns and the sub-sample range straddle leave residuals about 35 dB under a target).
Never a known target count.

Separability (conditioning).  Two atoms are parted when their normalised correlation rho is well
under 1; the CRB of either amplitude grows as 1 / (1 - rho^2).  Mirror atoms +-theta have the same
phase history, so rho is the pattern's alone: the time envelopes of the two-way sum beam (Gaussian,
e^{-(2 beta - k^2) d^2}) offset by 2 theta correlate as e^{-(2 beta - k^2) theta^2} (0.83 for
theta = 1.1 deg, the paper's x = +-30 m), and the difference channel, odd about each beam axis,
lowers it further; only at theta -> 0 does rho -> 1.  x = 0 against +-30 m: 5 Hz apart over
T_dwell = 0.14 s (0.7 cycle) of phase history besides envelopes 1.1 deg apart.
"""
from __future__ import annotations

import numpy as np
from scipy.special import gammainccinv

from ..dsp.geometry import C_MPS
from ..dsp.keystone_common import _cis as _cis_cycles

PFA = 1e-3                 # false-alarm probability of one more atom over the whole dictionary
FIT_DYNAMIC_DB = 30.0      # atoms weaker than this under the cluster's strongest are model residue
MAX_ATOMS = 80             # per cluster: a guard against a runaway fit (the paper rows need about 40)
CLUSTER_HALF_BINS = 2      # range cells fitted on each side of the strong ones (a scatterer's skirts)
SIDELOBE_DB = 20.0         # range peaks more than 20 dB under the region's strongest: range sidelobes and their
                           # mixing products (or weak scatterers), left to the dwell image
SLOPE_ATOMS = 0           # 1: each atom also gets a slope atom (amplitude drift); it mimics a mirror twin
SLOPE_SCALE_DEG = 3.0      # the slope atom's offset unit (about the dwell half-width): conditioning only
COARSE_RANGE_M = 100.0
RELAX_NEIGHBOUR_DEG = 1.5  # after each new atom, the atoms this close to it or to its mirror are refined again     # one coarse dictionary per 100 m of range (its phase error there < 0.3 rad)


class FitModel:
    """The window's geometry and the antenna model: builds the atoms a_b(theta) (module docstring)."""

    def __init__(self, *, position_m, scan_angle_deg, fc_hz, slope_per_deg, beta_per_deg2, position_ref_m,
                 boresight_offset_deg=0.0, sigma=(1.0, 1.0)):
        self.pos = np.asarray(position_m, dtype=np.float64)
        self.beam = np.asarray(scan_angle_deg, dtype=np.float64)
        self.lam = C_MPS / fc_hz
        self.k = float(slope_per_deg)
        self.beta = float(beta_per_deg2)
        self.p_ref = np.asarray(position_ref_m, dtype=np.float64)
        self.offset = float(boresight_offset_deg)
        self.w = (1.0 / sigma[0], 1.0 / sigma[1])

    def atoms(self, theta_deg, range_m, with_slope=False):
        """Whitened atoms [B, 2N, K] for angles ``theta_deg`` [K] and slant ranges ``range_m`` [B]; with
        ``with_slope`` also the slope atoms a d / SLOPE_SCALE_DEG (an amplitude drifting over the dwell)."""
        th = np.radians(np.atleast_1d(np.asarray(theta_deg, dtype=np.float64)))
        r = np.atleast_1d(np.asarray(range_m, dtype=np.float64))
        rho = np.sqrt(np.maximum(r**2 - self.p_ref[2] ** 2, 0.0))[:, None, None]
        dx = self.p_ref[0] + rho * np.sin(th)[None, None, :] - self.pos[None, :, 0, None]   # [B, N, K]
        dy = self.p_ref[1] + rho * np.cos(th)[None, None, :] - self.pos[None, :, 1, None]
        rng = np.sqrt(dx**2 + dy**2 + self.pos[None, :, 2, None] ** 2)
        ph = _cis_cycles(-2.0 * (rng - r[:, None, None]) / self.lam, np.complex64)
        d = np.degrees(np.arctan2(dx, dy)) - self.beam[None, :, None] - self.offset
        env = np.exp(-2.0 * self.beta * d**2)
        ch, sh = np.cosh(self.k * d), np.sinh(self.k * d)
        g_s = (env * ch * ch * self.w[0]).astype(np.float32)
        g_d = (env * ch * sh * self.w[1]).astype(np.float32)
        a = np.concatenate([ph * g_s, ph * g_d], axis=1)
        if not with_slope:
            return a
        tau = np.concatenate([d, d], axis=1).astype(np.float32) / np.float32(SLOPE_SCALE_DEG)
        return a, a * tau


def _group_stat(a, resid, ta=None):
    """sum_b ||projection of r_b on span(a_b[, ta_b])||^2 for atoms a [B, 2N, K] (and their slope atoms
    ta) and residuals [B, 2N]: [K]."""
    def dot(u, v):
        return np.einsum("bnk,bnk->bk", np.conj(u), v)

    num = np.einsum("bnk,bn->bk", np.conj(a), resid)
    g11 = dot(a, a).real
    if ta is None:
        return np.sum((num.real**2 + num.imag**2) / np.maximum(g11, 1e-30), axis=0)
    num2 = np.einsum("bnk,bn->bk", np.conj(ta), resid)
    g22, g12 = dot(ta, ta).real, dot(a, ta)
    det = np.maximum(g11 * g22 - np.abs(g12) ** 2, 1e-30)
    quad = g22 * np.abs(num) ** 2 + g11 * np.abs(num2) ** 2 - 2.0 * np.real(np.conj(num) * g12 * num2)
    return np.sum(quad / det, axis=0)


def _columns(model, theta, range_m, resid):
    """(a, resid, ta) for _group_stat: ta the slope atoms when SLOPE_ATOMS, else None."""
    if SLOPE_ATOMS:
        a, ta = model.atoms(theta, range_m, with_slope=True)
        return a, resid, ta
    return model.atoms(theta, range_m), resid, None


def _refine(model, theta0, step, range_m, resid, n_rounds=4):
    """Continuous angle maximising the group statistic near ``theta0``: parabolic steps on 3 points."""
    theta, h = float(theta0), float(step)
    for _ in range(n_rounds):
        f = _group_stat(*_columns(model, theta + h * np.array([-1.0, 0.0, 1.0]), range_m, resid))
        den = f[0] - 2.0 * f[1] + f[2]
        if den < 0:
            theta += float(np.clip(0.5 * h * (f[0] - f[2]) / den, -2.0 * h, 2.0 * h))
        else:                                  # not concave here: move to the better neighbour
            theta += 2.0 * h * (-1.0 if f[0] > f[2] else 1.0) if max(f[0], f[2]) > f[1] else 0.0
        h *= 0.5
    return theta


def _solve(a, y):
    """Least-squares amplitudes per range cell: a [B, 2N, K], y [B, 2N] -> c [B, K]."""
    ah = np.conj(np.swapaxes(a, 1, 2))
    gram = ah @ a
    rhs = (ah @ y[:, :, None])[..., 0]
    ridge = 1e-9 * np.trace(gram, axis1=1, axis2=2).real[:, None, None] * np.eye(a.shape[2])
    return np.linalg.solve(gram + ridge, rhs[..., None])[..., 0]


def fit_cluster(model, y, range_m, theta_grid_deg, *, pfa=PFA, dynamic_db=FIT_DYNAMIC_DB, max_atoms=MAX_ATOMS,
                relax_sweeps=2, coarse=None, axis_deg=0.0):
    """Group OMP with continuous angles over one cluster of range cells.

    ``y`` [B, 2N] whitened data (sum then difference over the window's pulses), ``range_m`` [B] the
    cells' slant ranges, ``theta_grid_deg`` the coarse dictionary's angles.  Returns (theta [K],
    c [B, K], stats [K]).
    """
    n_b = len(range_m)
    step = float(theta_grid_deg[1] - theta_grid_deg[0])
    if coarse is None:                                                       # [2N, M], centre cell
        coarse = model.atoms(theta_grid_deg, [range_m[n_b // 2]])[0]
    coarse_norm = np.sum(coarse.real**2 + coarse.imag**2, axis=0)
    keep = coarse_norm > 1e-6 * coarse_norm.max()
    coarse, coarse_norm, grid = coarse[:, keep], coarse_norm[keep], np.asarray(theta_grid_deg)[keep]
    noise_stop = float(gammainccinv(n_b, pfa / max(len(grid), 1)))            # Gamma(B) tail, noise units
    thetas, stats = [], []
    c = np.zeros((n_b, 0), np.complex64)
    a_act = np.zeros((n_b, y.shape[1], 0), np.complex64)
    resid = y
    n_col = 1 + SLOPE_ATOMS
    while len(thetas) < max_atoms:
        corr = resid @ np.conj(coarse)                                       # [B, M]
        stat = np.sum(corr.real**2 + corr.imag**2, axis=0) / coarse_norm
        stat[np.abs(grid[:, None] - np.asarray(thetas)[None, :]).min(axis=1) < 0.5 * step if thetas else
             np.zeros(len(grid), bool)] = 0.0
        m = int(np.argmax(stat))
        if stat[m] < noise_stop or (stats and stat[m] < stats[0] * 10 ** (-dynamic_db / 10)):
            break
        theta = _refine(model, grid[m], step, range_m, resid)
        thetas.append(theta)
        stats.append(float(stat[m]))
        a_act = np.concatenate([a_act, *_columns(model, [theta], range_m, resid)[::2][:n_col]], axis=2)
        c = _solve(a_act, y)
        # RELAX (Li & Stoica 1996) on the atoms the new one correlates with: its neighbours and its
        # mirror twin's (the greedy pick of one of two correlated atoms is biased by the other)
        near = [i for i, t in enumerate(thetas)
                if min(abs(t - theta), abs(t + theta - 2.0 * axis_deg)) <= RELAX_NEIGHBOUR_DEG]
        for _ in range(relax_sweeps):
            for i in near:
                a_act, c = _relax_one(model, a_act, c, thetas, i, y, range_m, step, n_col)
        resid = y - (a_act @ c[:, :, None])[..., 0]
    for _ in range(relax_sweeps if thetas else 0):                             # RELAX: each angle again
        for i in range(len(thetas)):
            a_act, c = _relax_one(model, a_act, c, thetas, i, y, range_m, step, n_col)
    return np.asarray(thetas), c[:, 0::n_col], np.asarray(stats)


def _relax_one(model, a_act, c, thetas, i, y, range_m, step, n_col):
    """Refine atom i's angle with the others held, then re-solve every amplitude (``thetas`` in place)."""
    pair = slice(n_col * i, n_col * (i + 1))
    others = y - (a_act @ c[:, :, None])[..., 0] + (a_act[:, :, pair] @ c[:, pair, None])[..., 0]
    thetas[i] = _refine(model, thetas[i], step, range_m, others)
    a_act[:, :, pair] = np.concatenate(_columns(model, [thetas[i]], range_m, y)[::2][:n_col], axis=2)
    return a_act, _solve(a_act, y)


def range_clusters(profile, level, half_bins=CLUSTER_HALF_BINS, sidelobe_db=SIDELOBE_DB):
    """Clusters of range cells to fit: the runs of cells where ``profile`` [n_r] (the region's strongest
    power per range cell) is above ``level`` and within ``sidelobe_db`` of its maximum, widened by
    +-``half_bins`` (a scatterer's skirts stay inside its cluster), overlapping runs merged."""
    p = np.asarray(profile, dtype=np.float64)
    n = len(p)
    floor = max(float(level), float(p.max(initial=0.0)) * 10 ** (-sidelobe_db / 10))
    hot = np.flatnonzero(p > floor)
    act = np.zeros(n, bool)
    for q in hot:
        act[max(0, q - half_bins):min(n, q + half_bins + 1)] = True
    edges = np.flatnonzero(np.diff(np.concatenate([[0], act.astype(np.int8), [0]])))
    return [np.arange(a, b) for a, b in zip(edges[::2], edges[1::2])]


def noise_sigma(x):
    """Noise standard deviation of a mostly-empty channel: median sample power / ln 2, square-rooted."""
    p = np.asarray(x[:: max(1, x.shape[0] // 256)])
    return float(np.sqrt(np.median(p.real**2 + p.imag**2) / np.log(2.0)))


def fit_region(sum_rt, diff_rt, *, scan_angle_deg, position_m, range_m, profile, level, axis_deg, half_width_deg,
               dwell_half_width_deg, angle_step_deg, fc_hz, slope_per_deg, beta_per_deg2, position_ref_m,
               boresight_offset_deg=0.0, pfa=PFA, dynamic_db=FIT_DYNAMIC_DB):
    """Fit every cluster of ``active`` range cells [n_r] for the scatterers within ``half_width_deg`` of
    the flight axis ``axis_deg`` (azimuth at t_ref).

    The window holds the pulses whose beam is within half_width + dwell_half_width of the axis (every
    pulse that sees the region); the dictionary spans every direction those pulses illuminate
    (half_width + 2 dwell_half_width), so the scatterers beyond the region that leak into the window
    are fitted too, and dropped.  Returns (theta [K], profile [K, n_r] complex amplitude per range cell,
    zero outside the atom's cluster) for the atoms inside the region, and the range cells fitted [n_r].
    """
    beam = np.asarray(scan_angle_deg, dtype=np.float64)
    win = np.flatnonzero(np.abs(beam - axis_deg) <= half_width_deg + dwell_half_width_deg)
    sig = (noise_sigma(sum_rt), noise_sigma(diff_rt))
    model = FitModel(position_m=np.asarray(position_m)[win], scan_angle_deg=beam[win], fc_hz=fc_hz,
                     slope_per_deg=slope_per_deg, beta_per_deg2=beta_per_deg2, position_ref_m=position_ref_m,
                     boresight_offset_deg=boresight_offset_deg, sigma=sig)
    span = half_width_deg + 2.0 * dwell_half_width_deg
    grid = axis_deg + angle_step_deg * np.arange(-np.ceil(span / angle_step_deg), np.ceil(span / angle_step_deg) + 1)
    xs = np.asarray(sum_rt)[win] / np.float32(sig[0])
    xd = np.asarray(diff_rt)[win] / np.float32(sig[1])
    thetas, profiles = [], []
    n_r = len(range_m)
    dictionaries = {}
    covered = np.zeros(n_r, bool)
    for cells in range_clusters(profile, level):
        covered[cells] = True
        y = np.concatenate([xs[:, cells].T, xd[:, cells].T], axis=1)               # [B, 2N]
        r_c = float(np.asarray(range_m)[cells].mean())
        key = int(round(r_c / COARSE_RANGE_M))
        if key not in dictionaries:
            dictionaries[key] = model.atoms(grid, [key * COARSE_RANGE_M])[0]
        theta, c, _ = fit_cluster(model, y, np.asarray(range_m)[cells], grid, pfa=pfa, dynamic_db=dynamic_db,
                                  coarse=dictionaries[key], axis_deg=axis_deg)
        inside = np.abs(theta - axis_deg) <= half_width_deg
        prof = np.zeros((int(inside.sum()), n_r), np.complex64)
        prof[:, cells] = c[:, inside].T
        thetas.append(theta[inside])
        profiles.append(prof)
    if not thetas:
        return np.zeros(0), np.zeros((0, n_r), np.complex64), covered
    return np.concatenate(thetas), np.concatenate(profiles, axis=0), covered
