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

Cost.  The window is fitted at the slow-time rate its region needs (``decimation_plan``: each cell
brought to the baseband of the region's directions, low-pass filtered, every Q-th pulse; Q = 10 for
the paper; the dictionary holds what the filter passes, +-7.4 deg, the rest of the window's scatterers
is filtered out instead of fitted),
the phases relative to the axis in float32 (exact difference formula, ``FitModel.paired_phases``), the
Gram matrices updated one atom at a time (``_ActiveSet``), each atom refined on its own cells, the
RELAX sweeps until the angles settle and after the first only near the atoms that moved
(``_relax_until_settled``), the clusters prepared and fitted on forked workers (``dsp.forked``): 0.16 s of CPU on
one thread (about 0.22 s on the workers), 0.13-0.15 s on two cores, for the paper lattice at a = 50 (its three clusters), where the direct form took 45 s.  Clusters wider than
``MAX_CLUSTER_CELLS`` (an extended scene) or needing ``MAX_ATOMS`` are left to the dwell image.

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

import logging

import numpy as np
from scipy.special import gammainccinv

from ..dsp.blas import worker_threads
from ..dsp.fir import filter_same
from ..dsp.forked import start_jobs
from ..dsp.geometry import C_MPS
from ..dsp.keystone_common import _cis as _cis_cycles
from .dwell_fit_plan import decimation_plan, fit_angle_step, noise_sigma, range_clusters

log = logging.getLogger(__name__)

PFA = 1e-3                 # false-alarm probability of one more atom over the whole dictionary
FIT_DYNAMIC_DB = 30.0      # atoms weaker than this under the cluster's strongest are model residue
MAX_ATOMS = 80             # per cluster: a guard against a runaway fit (the paper rows need about 40)
MAX_CLUSTER_CELLS = 48     # a cluster wider than this (150 m at 3 m cells) is an extended scene, not points: the
                           # sparse model does not hold there and the dwell image keeps it (as for a fit that
                           # reaches MAX_ATOMS)
COARSE_RANGE_M = 100.0     # one coarse dictionary per 100 m of range (its phase error there < 0.3 rad)
FILTER_STOP_EDGE = 1.125    # the filter's stop edge, in units of its cut-off (its transition: +-1/8 of it)
REFINE_CELL_DB = 15.0      # an atom's angle is refined on its cells within 15 dB of its strongest one (its main lobe in range)
RESOLVED_MAX_CORR = 0.9    # two atoms the fit parts: |rho| <= 0.9, each amplitude's CRB <= 1/(1 - rho^2) = 5.3 x a lone one's
MAX_RELAX_SWEEPS = 6       # RELAX sweeps until no angle moves by RELAX_TOL_DEG (correlated atoms converge slowly)
RELAX_TOL_DEG = 1e-3        # 1/50 of the image's 0.05 deg angle step, 1/20 of the fit's 0.02 deg RMS on the paper lattice
REFINE_BLOCK_ATOMS = 8     # atoms refined together (their phases [cells, pulses, atoms, 3] bound the temporaries)
BAND_GUARD_DEG = 1.0       # the decimated band holds the region's directions and 1 deg more
RELAX_NEIGHBOUR_DEG = 0.75  # after each new atom, the atoms this close to it or to its mirror are refined again


class FitModel:
    """The window's geometry and the antenna model: builds the atoms a_b(theta) (module docstring).

    With D_n = p_ref - p(t_n) (horizontal) and u = (sin theta, cos theta), the two-way path of pulse n to
    the ground point at horizontal range rho from p_ref is R = sqrt(rho^2 + 2 rho u.D_n + |D_n|^2 + z_n^2):
    one [N, K] product per call, the [B, N, K] work a square root and a phasor.  The patterns are taken
    at the cluster's mean horizontal range: across a cluster (under 50 m) the azimuth seen from p(t_n)
    moves by D_y sin(theta) d(rho) / rho^2 < 0.01 deg, a gain change under 40 dB below the atom."""

    def __init__(self, *, position_m, scan_angle_deg, fc_hz, slope_per_deg, beta_per_deg2, position_ref_m,
                 boresight_offset_deg=0.0, sigma=(1.0, 1.0), axis_relative_deg=None):
        pos = np.asarray(position_m, dtype=np.float64)
        self.beam = np.asarray(scan_angle_deg, dtype=np.float64)
        self.lam = C_MPS / fc_hz
        self.k = float(slope_per_deg)
        self.beta = float(beta_per_deg2)
        self.p_ref = np.asarray(position_ref_m, dtype=np.float64)
        self.offset = float(boresight_offset_deg)
        self.w = (1.0 / sigma[0], 1.0 / sigma[1])
        self.dx = self.p_ref[0] - pos[:, 0]                                # D_n [N]
        self.dy = self.p_ref[1] - pos[:, 1]
        self.e = self.dx**2 + self.dy**2 + pos[:, 2] ** 2                  # |D_n|^2 + z_n^2
        self.n = len(self.beam)
        # axis_relative_deg: atoms times the conjugate phase history of that direction, the frame of the
        # slow-time decimated data (fit_region; decimation_plan's shift is taken off again after the filter)
        self.axis_relative_deg = axis_relative_deg

    def path(self, theta_deg, range_m):
        """Two-way path halves R_b(theta; n) [B, N, K] (float64)."""
        th = np.radians(np.atleast_1d(np.asarray(theta_deg, dtype=np.float64)))
        rho = self.rho(range_m)[:, None, None]
        ud = self.dx[:, None] * np.sin(th)[None, :] + self.dy[:, None] * np.cos(th)[None, :]     # [N, K]
        return np.sqrt(rho * (rho + 2.0 * ud[None]) + self.e[None, :, None])

    def rho(self, range_m):
        r = np.asarray(range_m, dtype=np.float64)
        return np.sqrt(np.maximum(r**2 - self.p_ref[2] ** 2, 0.0))

    def phases(self, theta_deg, range_m):
        """exp(-j 4 pi (R_b(theta; n) - r_b) / lambda), complex64 [B, N, K] for angles [K] and ranges [B]
        (with ``axis_relative_deg``: relative to that direction's, the frame of the decimated fit)."""
        th = np.atleast_1d(np.asarray(theta_deg, dtype=np.float64))
        r = np.atleast_1d(np.asarray(range_m, dtype=np.float64))
        return self.paired_phases(th[None, :], r[:, None])[:, :, 0, :]

    def paired_phases(self, theta_deg, range_m, axis_path=None):
        """The phases of ``phases`` for angles ``theta_deg`` [J, P] at ranges ``range_m`` [M, J] (or
        [M, 1]: the same for every j): complex64 [M, N, J, P].  With ``axis_relative_deg`` relative to
        the axis direction's R_b(axis; n) (``axis_path`` of the same ranges, when already computed):
        exp(-j 4 pi (R_b(theta; n) - R_b(axis; n)) / lambda).

        Relative to the axis the path difference needs no float64: with s = R_theta^2 - R_axis^2 =
        2 rho (u_theta - u_axis).D_n (the rho^2 and |D_n|^2 + z^2 terms cancel exactly; the unit-vector
        difference and its product with D_n in float64, [N, J, P]), dR = s / (R_axis + sqrt(R_axis^2 +
        s)), a few hundred cycles at most, so float32 keeps the phase to 1e-4 cycle."""
        th = np.radians(np.asarray(theta_deg, dtype=np.float64))
        r = np.asarray(range_m, dtype=np.float64)
        rho = self.rho(r)[:, None, :, None]                                             # [M, 1, J, 1]
        if self.axis_relative_deg is None:
            ud = self.dx[:, None, None] * np.sin(th)[None] + self.dy[:, None, None] * np.cos(th)[None]
            rng = np.sqrt(rho * (rho + 2.0 * ud[None]) + self.e[None, :, None, None])
            return _cis_cycles(-2.0 * (rng - r[:, None, :, None]) / self.lam, np.complex64)
        ax = np.radians(self.axis_relative_deg)
        dud = (self.dx[:, None, None] * (np.sin(th) - np.sin(ax))[None]
               + self.dy[:, None, None] * (np.cos(th) - np.cos(ax))[None]).astype(np.float32)   # [N, J, P]
        r_axis = self.axis_path(range_m) if axis_path is None else axis_path
        s = (2.0 * rho).astype(np.float32) * dud[None]
        cycles = s / (r_axis + np.sqrt(r_axis * r_axis + s))
        cycles *= np.float32(-2.0 / self.lam)
        return _cis_cycles(cycles, np.complex64, reduce_in=np.float32)

    def axis_path(self, range_m):
        """R_b(axis; n) for ranges [M, J]: float32 [M, N, J, 1]."""
        rho = self.rho(np.asarray(range_m, dtype=np.float64))[:, None, :]
        ax = np.radians(self.axis_relative_deg)
        ud_axis = self.dx * np.sin(ax) + self.dy * np.cos(ax)
        return np.sqrt(rho * (rho + 2.0 * ud_axis[None, :, None]) + self.e[None, :, None]).astype(np.float32)[..., None]

    def gains(self, theta_deg, range_m, rho_m=None):
        """Whitened two-way sum and difference gains [N, K] (float32) at the cells' mean horizontal range
        (``rho_m`` [K]: at these horizontal ranges, one per angle; ``range_m`` unused):
        e^{-2 beta d^2} cosh^2(k d) and e^{-2 beta d^2} cosh(k d) sinh(k d), d the offset (deg)."""
        th = np.radians(np.atleast_1d(np.asarray(theta_deg, dtype=np.float64)))
        rho = (float(np.mean(self.rho(np.atleast_1d(range_m)))) if rho_m is None
               else np.asarray(rho_m, dtype=np.float64)[None, :])
        # float32 is enough for the offset: 1e-7 relative of a few hundred metres, a gain error of 1e-6
        d = np.arctan2((self.dx[:, None] + rho * np.sin(th)[None, :]).astype(np.float32),
                       (self.dy[:, None] + rho * np.cos(th)[None, :]).astype(np.float32))
        d *= np.float32(180.0 / np.pi)
        d -= (self.beam + self.offset).astype(np.float32)[:, None]
        env = np.exp(np.float32(-2.0 * self.beta) * d * d)
        e = np.exp(np.float32(self.k) * d)
        ch, sh = np.float32(0.5) * (e + 1 / e), np.float32(0.5) * (e - 1 / e)
        env *= ch
        return env * ch * np.float32(self.w[0]), env * sh * np.float32(self.w[1])

    def atoms(self, theta_deg, range_m):
        """Whitened atoms [B, 2N, K] for angles ``theta_deg`` [K] and slant ranges ``range_m`` [B]."""
        ph = self.phases(theta_deg, range_m)
        g_s, g_d = self.gains(theta_deg, range_m)
        return np.concatenate([ph * g_s[None], ph * g_d[None]], axis=1)


def _group_stat(model, theta, cell_range_m, resid_conj, gain_rho_m, axis_path=None):
    """sum_m |a_m(theta_jp)^H r_mj|^2 / ||a(theta_jp)||^2 for the angles ``theta`` [J, P], each atom j
    against its own conjugated residuals ``resid_conj`` [M, 2N, J] in its own cells (slant ranges
    ``cell_range_m`` [M, J]; a zero residual row adds nothing): [J, P].  |a^H r| = |sum_n ph (g_s conj
    r_s + g_d conj r_d)|, and ||a||^2 = sum_n g_s^2 + g_d^2 does not depend on the phase (nor on the
    cell: the patterns at the horizontal range ``gain_rho_m`` [J] of the atom's cluster).  With
    ``axis_relative_deg`` the phases are relative to the axis direction's (``fit_region``), and
    ``axis_path`` is the axis history of the cells."""
    n = model.n
    n_j, n_p = theta.shape
    ph = model.paired_phases(theta, cell_range_m, axis_path=axis_path)                   # [M, N, J, P]
    g_s, g_d = (g.reshape(n, n_j, n_p) for g in model.gains(theta.ravel(), None, rho_m=np.repeat(gain_rho_m, n_p)))
    w = resid_conj[:, :n, :, None] * g_s[None] + resid_conj[:, n:, :, None] * g_d[None]    # [M, N, J, P]
    num = np.einsum("mnjp,mnjp->mjp", ph, w)
    norm = np.sum(g_s.astype(np.float64) ** 2 + g_d.astype(np.float64) ** 2, axis=0)
    power = np.sum(num.real.astype(np.float64) ** 2 + num.imag.astype(np.float64) ** 2, axis=0)
    return power / np.maximum(norm, 1e-30)


def _atom_cells(cell_power, floor_db=REFINE_CELL_DB):
    """Each atom's own cells for its refinement: indices [M, J] into the cluster's cells (strongest
    first) and a mask [M, J] of those within ``floor_db`` of the atom's strongest cell (padding False)."""
    order = np.argsort(-cell_power, axis=0, kind="stable")
    ranked = np.take_along_axis(cell_power, order, axis=0)
    mask = ranked >= ranked[:1] * 10 ** (-floor_db / 10)
    n_m = int(mask.sum(axis=0).max())
    return order[:n_m], mask[:n_m]


def _refine(model, theta0, step, range_m, resid, cell_power, n_rounds, axis_cells=None):
    """Continuous angles maximising the group statistic near ``theta0`` [J], each against its own
    residual ``resid`` [B, 2N, J] in its own cells (``_atom_cells`` of ``cell_power`` [B, J]: the cells
    where the atom is more than REFINE_CELL_DB under its strongest add mostly the others' residue and noise):
    parabolic steps on 3 points, all J at once.  ``axis_cells`` [B, N]: the axis history of the cells
    (``FitModel.axis_path``, axis-relative models), when the caller holds it."""
    theta, h = np.array(theta0, dtype=np.float64), float(step)
    if len(theta) > REFINE_BLOCK_ATOMS:       # independent per atom: in blocks, for bounded temporaries
        return np.concatenate([_refine(model, theta[i:i + REFINE_BLOCK_ATOMS], step, range_m,
                                       resid[:, :, i:i + REFINE_BLOCK_ATOMS], cell_power[:, i:i + REFINE_BLOCK_ATOMS],
                                       n_rounds, axis_cells) for i in range(0, len(theta), REFINE_BLOCK_ATOMS)])
    idx, mask = _atom_cells(cell_power)
    resid_conj = np.conj(np.take_along_axis(resid, idx[:, None, :], axis=0)) * mask[:, None, :]    # [M, 2N, J]
    cell_range = np.asarray(range_m)[idx]
    gain_rho = np.full(len(theta), np.mean(model.rho(np.asarray(range_m))))       # the cluster's patterns
    axis_path = None
    if model.axis_relative_deg is not None:   # the axis history of each atom's cells, once for all rounds
        axis_path = (model.axis_path(cell_range) if axis_cells is None
                     else np.swapaxes(axis_cells[idx], 1, 2)[..., None])              # [M, N, J, 1]
    for _ in range(n_rounds):
        f = _group_stat(model, theta[:, None] + h * np.array([-1.0, 0.0, 1.0]), cell_range, resid_conj, gain_rho,
                        axis_path)
        den = f[:, 0] - 2.0 * f[:, 1] + f[:, 2]
        vertex = np.clip(0.5 * h * (f[:, 0] - f[:, 2]) / np.where(den < 0, den, -1.0), -2.0 * h, 2.0 * h)
        # not concave here: move to the better neighbour (or stay)
        towards = np.where(np.maximum(f[:, 0], f[:, 2]) > f[:, 1], np.where(f[:, 0] > f[:, 2], -2.0 * h, 2.0 * h), 0.0)
        theta = theta + np.where(den < 0, vertex, towards)
        h *= 0.5
    return theta


class _ActiveSet:
    """The fitted atoms of one cluster with their Gram matrices and right-hand sides per range cell,
    updated one column at a time (an atom added or moved), so that each least-squares solve costs
    O(K^3) per cell instead of the O(N K^2) of forming A^H A again.  Atoms are stored [B, K, 2N]."""

    def __init__(self, y, max_atoms):
        self.y = y
        self.max_atoms = int(max_atoms)
        self.k = 0
        self.c = np.zeros((y.shape[0], 0), np.complex128)
        self.axis_cells = None            # the cells' axis history [B, N] (fit_cluster, axis-relative models)
        self._allocate(min(16, self.max_atoms))

    def _allocate(self, capacity):
        """Storage for ``capacity`` atoms, the ones held copied over (grown by doubling)."""
        n_b, n_2 = self.y.shape
        a = np.zeros((n_b, capacity, n_2), np.complex64)
        gram = np.zeros((n_b, capacity, capacity), np.complex128)
        rhs = np.zeros((n_b, capacity), np.complex128)
        if self.k:
            a[:, :self.k], gram[:, :self.k, :self.k], rhs[:, :self.k] = (
                self.a[:, :self.k], self.gram[:, :self.k, :self.k], self.rhs[:, :self.k])
        self.a, self.gram, self.rhs = a, gram, rhs

    def set(self, idx, atoms):
        """Atoms ``idx`` [J] (an index == k appends) := ``atoms`` [B, 2N, J]; their Gram rows and columns
        and right-hand sides updated."""
        idx = np.asarray(idx)
        if int(idx.max()) >= self.a.shape[1]:
            self._allocate(min(self.max_atoms, max(int(idx.max()) + 1, 2 * self.a.shape[1])))
        self.k = max(self.k, int(idx.max()) + 1)
        self.a[:, idx, :] = np.swapaxes(atoms, 1, 2)
        atoms_conj = np.conj(atoms)
        v = (self.a[:, :self.k, :] @ atoms_conj).astype(np.complex128)          # [B, k, J]: conj(a_k^H a_j)
        self.gram[:, :self.k, idx] = np.conj(v)
        self.gram[:, idx, :self.k] = np.swapaxes(v, 1, 2)
        self.rhs[:, idx] = np.einsum("bnj,bn->bj", atoms_conj, self.y)

    def solve(self):
        """Least-squares amplitudes per range cell (a 1e-9 relative ridge): c [B, K]."""
        k = self.k
        gram = self.gram[:, :k, :k]
        ridge = 1e-9 * np.trace(gram, axis1=1, axis2=2).real[:, None, None] * np.eye(k)
        self.c = np.linalg.solve(gram + ridge, self.rhs[:, :k, None])[..., 0]
        return self.c

    def model(self):
        """sum_j c_j a_j [B, 2N]."""
        return (self.c.astype(np.complex64)[:, None, :] @ self.a[:, :self.k, :])[:, 0, :]

    def relax(self, model, thetas, idx, range_m, step):
        """RELAX (Li & Stoica 1996), one Jacobi sweep: the angles ``idx`` refined at once, each with the
        others' fitted contributions removed, then every amplitude re-solved (``thetas`` in place).
        Returns each angle's move [J] (deg)."""
        idx = np.asarray(idx)
        resid = self.y - self.model()
        old = np.asarray(thetas)[idx]
        new = np.empty(len(idx))
        for lo in range(0, len(idx), REFINE_BLOCK_ATOMS):      # blocks of atoms: bounded temporaries
            blk = idx[lo:lo + REFINE_BLOCK_ATOMS]
            c = self.c[:, blk]
            others = resid[:, :, None] + np.swapaxes(self.a[:, blk, :], 1, 2) * c[:, None, :].astype(np.complex64)
            new[lo:lo + len(blk)] = _refine(model, old[lo:lo + len(blk)], 0.25 * step, range_m, others,
                                            c.real**2 + c.imag**2, n_rounds=1, axis_cells=self.axis_cells)
        moved = np.abs(new - old)
        for i, t in zip(idx, new):
            thetas[i] = float(t)
        for lo in range(0, len(idx), REFINE_BLOCK_ATOMS):
            self.set(idx[lo:lo + REFINE_BLOCK_ATOMS], model.atoms(new[lo:lo + REFINE_BLOCK_ATOMS], range_m))
        self.solve()
        return moved


def _near(thetas, idx, centres, axis_deg):
    """The atoms of ``idx`` within RELAX_NEIGHBOUR_DEG of any angle in ``centres`` or of its mirror."""
    t = np.asarray(thetas)[idx][:, None]
    c = np.asarray(centres)[None, :]
    close = np.minimum(np.abs(t - c), np.abs(t + c - 2.0 * axis_deg)) <= RELAX_NEIGHBOUR_DEG
    return idx[close.any(axis=1)]


def _relax_until_settled(act, model, thetas, idx, range_m, step, axis_deg, min_sweeps):
    """RELAX sweeps over the atoms ``idx`` until none moves by RELAX_TOL_DEG (at most MAX_RELAX_SWEEPS,
    at least ``min_sweeps`` while any moves): after the first, each sweep refines only the atoms near
    one that moved in the last (or near its mirror), the ones whose residual changed; an atom that has
    settled with its neighbours settled is where another sweep would leave it."""
    idx = np.asarray(idx)
    todo = idx
    for sweep in range(MAX_RELAX_SWEEPS):
        moved = act.relax(model, thetas, todo, range_m, step)
        movers = todo[moved >= RELAX_TOL_DEG]
        if len(movers) == 0 and sweep + 1 >= min_sweeps:
            break
        todo = _near(thetas, idx, [thetas[i] for i in movers], axis_deg) if len(movers) else todo


def fit_cluster(model, y, range_m, theta_grid_deg, *, pfa=PFA, dynamic_db=FIT_DYNAMIC_DB, max_atoms=MAX_ATOMS,
                relax_sweeps=1, coarse=None, axis_deg=0.0, separation_deg=None):
    """Group OMP with continuous angles over one cluster of range cells.

    ``y`` [B, 2N] whitened data (sum then difference over the window's pulses), ``range_m`` [B] the
    cells' slant ranges, ``theta_grid_deg`` the coarse dictionary's angles.  A new atom is picked at
    least ``separation_deg`` (default half a grid step) from the atoms held: half the image's angle
    step where the grid is finer (``fit_angle_step``), since the image cannot show two points closer
    and the model's residue beside a strong atom would otherwise be picked there.  Returns (theta [K],
    c [B, K], stats [K]).
    """
    n_b = len(range_m)
    step = float(theta_grid_deg[1] - theta_grid_deg[0])
    separation_deg = 0.5 * step if separation_deg is None else float(separation_deg)
    if coarse is None:                                                       # [2N, M], centre cell
        coarse = model.atoms(theta_grid_deg, [range_m[n_b // 2]])[0]
    coarse_norm = np.sum(coarse.real**2 + coarse.imag**2, axis=0)
    keep = coarse_norm > 1e-6 * coarse_norm.max()
    coarse_conj, coarse_norm, grid = np.conj(coarse[:, keep]), coarse_norm[keep], np.asarray(theta_grid_deg)[keep]
    noise_stop = float(gammainccinv(n_b, pfa / max(len(grid), 1)))            # Gamma(B) tail, noise units
    thetas, stats = [], []
    act = _ActiveSet(y, max_atoms)
    if model.axis_relative_deg is not None:    # the axis history of the cluster's cells, once: [B, N]
        act.axis_cells = model.axis_path(np.asarray(range_m, dtype=np.float64)[:, None])[:, :, 0, 0]
    resid = y
    while len(thetas) < max_atoms:
        corr = resid @ coarse_conj                                           # [B, M]
        stat = np.sum(corr.real**2 + corr.imag**2, axis=0) / coarse_norm
        stat[np.abs(grid[:, None] - np.asarray(thetas)[None, :]).min(axis=1) < separation_deg if thetas else
             np.zeros(len(grid), bool)] = 0.0
        m = int(np.argmax(stat))
        if stat[m] < noise_stop or (stats and stat[m] < stats[0] * 10 ** (-dynamic_db / 10)):
            break
        power_m = corr[:, m:m + 1].real ** 2 + corr[:, m:m + 1].imag ** 2
        theta = float(_refine(model, [grid[m]], step, range_m, resid[:, :, None], power_m, n_rounds=2,
                              axis_cells=act.axis_cells)[0])
        thetas.append(theta)
        stats.append(float(stat[m]))
        act.set([len(thetas) - 1], model.atoms([theta], range_m))
        act.solve()
        # RELAX on the atoms the new one correlates with: its neighbours and its mirror twin's (the
        # greedy pick of one of two correlated atoms is biased by the other)
        near = _near(thetas, np.arange(len(thetas)), [theta], axis_deg)
        if len(near) > 1:                                                    # alone, it was just refined
            _relax_until_settled(act, model, thetas, near, range_m, step, axis_deg, relax_sweeps)
        resid = y - act.model()
    if thetas:                                                                    # RELAX: every angle again
        _relax_until_settled(act, model, thetas, np.arange(len(thetas)), range_m, step, axis_deg, relax_sweeps)
    return np.asarray(thetas), act.c.astype(np.complex64), np.asarray(stats)


class ClusterFit:
    """One cluster's fit (``start_fit_region``), run on a worker: called with job = (cells, the sum
    channel's samples, the difference channel's) at the pulses the fit reads (the window, or with
    Q > 1 the window and the filter's half length each side).  Holds no more than the fit needs, so
    that it pickles (``dsp.spawner``); each worker keeps its own coarse dictionaries."""

    def __init__(self, *, model, range_m, grid, axis_deg, half_width_deg, pfa, dynamic_db, sig, q, lam, taps=None,
                 shift_hz=0.0, gain=1.0, ext=None, kept=None, ext_model=None, prf_hz=None, separation_deg=None):
        self.model, self.range_m, self.grid, self.axis_deg = model, range_m, grid, axis_deg
        self.separation_deg = separation_deg
        self.half_width_deg, self.pfa, self.dynamic_db, self.sig, self.q, self.lam = (
            half_width_deg, pfa, dynamic_db, sig, q, lam)
        self.taps, self.shift_hz, self.gain, self.ext, self.kept, self.ext_model, self.prf_hz = (
            taps, shift_hz, gain, ext, kept, ext_model, prf_hz)
        self.dictionaries = {}

    def cluster_data(self, cells, x_sum, x_diff):
        """y [B, 2N/Q] whitened and the coarse dictionary of the cluster's range."""
        range_m, sig = self.range_m, self.sig
        if self.q > 1:     # baseband of the axis history, filtered, every Q-th pulse of the window (whitened)
            ext, kept, prf_hz = self.ext, self.kept, self.prf_hz
            to_base = _cis_cycles(2.0 * (self.ext_model.path([self.axis_deg], range_m[cells])[:, :, 0]
                                         - range_m[cells, None]) / self.lam - self.shift_hz * ext[None, :] / prf_hz,
                                  np.complex64)                                           # [B, N_ext]
            pick = kept - ext[0]
            # filtered at baseband, then the shift put back on the kept pulses: the fit's frame is the
            # axis-relative one, unshifted (its atoms need no shift; the amplitudes are the same)
            unshift = _cis_cycles(self.shift_hz * kept / prf_hz, np.complex64) / np.float32(self.gain)
            chans = [filter_same(x.T * to_base, self.taps)[:, pick] * (unshift / np.float32(s_ch))
                     for x, s_ch in ((x_sum, sig[0]), (x_diff, sig[1]))]
            y = np.concatenate(chans, axis=1).astype(np.complex64)                       # [B, 2N/Q]
        else:
            y = np.concatenate([x.T / np.float32(s_ch) for x, s_ch in ((x_sum, sig[0]), (x_diff, sig[1]))],
                               axis=1)                                                    # [B, 2N]
        key = int(round(float(range_m[cells].mean()) / COARSE_RANGE_M))
        if key not in self.dictionaries:
            self.dictionaries[key] = self.model.atoms(self.grid, [key * COARSE_RANGE_M])[0]
        return y, self.dictionaries[key]

    def __call__(self, job):
        """(theta [K], profile [K, n_r], cells) of the atoms inside the region; cells None where the cluster
        is not sparse (left to the dwell image)."""
        cells, x_sum, x_diff = job
        range_m, n_r = self.range_m, len(self.range_m)
        y, coarse = self.cluster_data(cells, x_sum, x_diff)
        theta, c, _ = fit_cluster(self.model, y, range_m[cells], self.grid, pfa=self.pfa, dynamic_db=self.dynamic_db,
                                  coarse=coarse, axis_deg=self.axis_deg, separation_deg=self.separation_deg)
        if len(theta) >= MAX_ATOMS:              # not sparse: the dwell image keeps these cells
            log.info(f"dwell_fit: the cluster at {range_m[cells[0]]:.0f} m needs over {MAX_ATOMS} points: left "
                     "to the dwell image")
            return np.zeros(0), np.zeros((0, n_r), np.complex64), None
        inside = np.abs(theta - self.axis_deg) <= self.half_width_deg
        prof = np.zeros((int(inside.sum()), n_r), np.complex64)
        prof[:, cells] = c[:, inside].T
        return theta[inside], prof, cells


def fit_region(*args, **kw):
    """:func:`start_fit_region`, waited for: (theta [K], profile [K, n_r], covered [n_r])."""
    return start_fit_region(*args, **kw)()


def start_fit_region(sum_rt, diff_rt, *, scan_angle_deg, position_m, range_m, profile, level, axis_deg,
                     half_width_deg, dwell_half_width_deg, angle_step_deg, fc_hz, prf_hz, slope_per_deg, beta_per_deg2,
                     position_ref_m, boresight_offset_deg=0.0, pfa=PFA, dynamic_db=FIT_DYNAMIC_DB, decimate=True):
    """Start fitting every cluster of ``active`` range cells [n_r] for the scatterers within ``half_width_deg`` of
    the flight axis ``axis_deg`` (azimuth at t_ref).

    The window holds the pulses whose beam is within half_width + dwell_half_width of the axis (every
    pulse that sees the region).  It is fitted at the slow-time rate the region's directions (and
    ``BAND_GUARD_DEG`` more) need (``decimation_plan``): each cell's pulses multiplied by the conjugate
    of the axis direction's history, low-pass filtered and kept every Q-th, the atoms built at those
    pulses in the same baseband (the amplitudes are unchanged).  The scatterers beyond the region that
    the window sees are then outside the band; the dictionary holds every direction whose baseband
    offsets reach inside the filter's stop edge, so what leaks through is fitted too, and dropped.
    ``decimate=False``: at the PRF, the dictionary spanning every direction the window illuminates
    (half_width + 2 dwell_half_width).  Returns a function that waits for the fits (the caller may work
    meanwhile: they run on other processes, ``dsp.forked.start_jobs``) and returns (theta [K], profile [K, n_r]
    complex amplitude per range cell, zero outside the atom's cluster) for the atoms inside the region,
    and the range cells fitted [n_r].
    """
    beam = np.asarray(scan_angle_deg, dtype=np.float64)
    pos = np.asarray(position_m, dtype=np.float64)
    range_m = np.asarray(range_m, dtype=np.float64)
    win = np.flatnonzero(np.abs(beam - axis_deg) <= half_width_deg + dwell_half_width_deg)
    sig = (noise_sigma(sum_rt), noise_sigma(diff_rt))
    kw = dict(fc_hz=fc_hz, slope_per_deg=slope_per_deg, beta_per_deg2=beta_per_deg2, position_ref_m=position_ref_m,
              boresight_offset_deg=boresight_offset_deg)
    span = half_width_deg + 2.0 * dwell_half_width_deg
    full = FitModel(position_m=pos[win], scan_angle_deg=beam[win], sigma=sig, **kw)
    r_mid = float(np.median(range_m))
    step = fit_angle_step(full, axis_deg, half_width_deg, r_mid, angle_step_deg)     # the statistic's lobe sampled
    grid = axis_deg + step * np.arange(-np.ceil(span / step), np.ceil(span / step) + 1)
    q, shift_hz, taps = 1, 0.0, None
    if decimate and len(win) > 1 and np.all(np.diff(win) == 1):
        band_grid = grid[np.abs(grid - axis_deg) <= half_width_deg + BAND_GUARD_DEG]
        q, shift_hz, taps = decimation_plan(full, band_grid, r_mid, axis_deg, prf_hz)
        if q > 1:     # the dictionary: every direction the filter lets through (offsets inside its stop edge)
            # (the offsets every 8th pulse: they change by under 1 Hz per pulse)
            every8 = FitModel(position_m=pos[win[::8]], scan_angle_deg=beam[win[::8]], **kw)
            path = every8.path(grid, [r_mid])[0] - every8.path([axis_deg], [r_mid])[0]
            f_hz = -2.0 / full.lam * np.diff(path, axis=0) * prf_hz / 8
            stop_hz = FILTER_STOP_EDGE * prf_hz / (2.0 * q)
            grid = grid[np.any(np.abs(f_hz - shift_hz) <= stop_hz, axis=0)]
    if q > 1:
        half_taps = len(taps) // 2
        ext = np.arange(max(0, win[0] - half_taps), min(len(beam), win[-1] + half_taps + 1))
        kept = np.arange(win[0], win[-1] + 1, q)
        gain = float(np.sqrt(np.sum(taps**2)))                         # noise sigma after the filter
        model = FitModel(position_m=pos[kept], scan_angle_deg=beam[kept], sigma=(sig[0] * gain, sig[1] * gain),
                         axis_relative_deg=axis_deg, **kw)
        ext_model = FitModel(position_m=pos[ext], scan_angle_deg=beam[ext], **kw)
    else:
        model = full
    n_r, covered = len(range_m), np.zeros(len(range_m), bool)
    clusters = range_clusters(profile, level)
    for cells in (c for c in clusters if len(c) > MAX_CLUSTER_CELLS):
        log.info(f"dwell_fit: {len(cells)} contiguous range cells at {range_m[cells[0]]:.0f} m are an extended "
                 f"scene, not points (over {MAX_CLUSTER_CELLS}): left to the dwell image")
    # each job carries its cells' samples (the pulses the fit reads), so that it pickles (dsp/spawner.py)
    jobs = [(cells, *(np.asarray(x[ext[0]:ext[-1] + 1, cells] if q > 1 else x[np.ix_(win, cells)])
                      for x in (sum_rt, diff_rt)))
            for cells in clusters if len(cells) <= MAX_CLUSTER_CELLS]
    fit_one = ClusterFit(model=model, range_m=range_m, grid=grid, axis_deg=axis_deg, half_width_deg=half_width_deg,
                         pfa=pfa, dynamic_db=dynamic_db, sig=sig, q=q, lam=full.lam,
                         separation_deg=0.5 * angle_step_deg,
                         **(dict(taps=taps, shift_hz=shift_hz, gain=gain, ext=ext, kept=kept, ext_model=ext_model,
                                 prf_hz=prf_hz) if q > 1 else {}))

    # a forked worker per cluster, at most two per core (threads take turns on the GIL; a fork costs page
    # tables and copy-on-write faults, dsp.forked): the paper's 3 clusters end together (README, Speed)
    pending = start_jobs(fit_one, jobs, min(2 * worker_threads(), len(jobs)) if worker_threads() > 1 else 1,
                         processes=True)

    def finish():
        done = pending.result()
        thetas, profiles = [t for t, _, _ in done], [p for _, p, _ in done]
        for _, _, cells in done:
            if cells is not None:
                covered[cells] = True
        if not thetas:
            return np.zeros(0), np.zeros((0, n_r), np.complex64), covered
        return np.concatenate(thetas), np.concatenate(profiles, axis=0), covered

    finish.cancel = pending.cancel            # the caller failed meanwhile: the workers released, no result
    return finish
