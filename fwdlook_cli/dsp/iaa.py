"""The iterative adaptive approach (IAA) Doppler estimator per range cell
(``processing.doppler_estimator: iaa``; Zhang et al. 2016, which the paper cites; Yardibi et al. 2010)."""
from __future__ import annotations

import numpy as np


def iaa_doppler(y_sum, y_diff, steering, *, t_s=None, prf_hz=None, n_iter=10, noise_power=None,
                grid_oversample=4, active=None):
    """Iterative adaptive approach (IAA; Yardibi et al. 2010, single snapshot) per range cell.

    ``y_sum``, ``y_diff``: [n_cpi, L, n_r] slow-time samples of each CPI; ``steering``: [n_cpi, L, K]
    the output cells' steering vectors a_z(n) = exp(j 2 pi f_z (t_n - t_c)).  IAA runs on a uniform grid
    of ``grid_oversample`` x L cells over the whole PRF (``t_s`` [n_cpi, L] times from the CPI centre),
    so every echo in the CPI is modelled: from the periodogram p_g = |a_g^H y|^2 / L^2, each iteration
    forms R = A diag(p) A^H + sigma^2 I per range cell and sets s_g = a_g^H R^-1 y / (a_g^H R^-1 a_g),
    p_g = |s_g|^2.  The output cells get the same adaptive filters from the final R; the difference
    channel too (the sum channel's R), so a single scatterer keeps Re(s_diff / s_sum) = Delta/Sigma.
    Without ``t_s`` the output cells are the grid.  ``active`` [n_cpi, n_r] (bool) limits IAA to the
    range cells that hold an echo; the others get the periodogram.  Vectorised over CPIs and range
    cells (batched L x L solves).  Cost per iteration ~ n_active L^2 (K_grid + L).

    Returns (s_sum, s_diff): [n_cpi, K, n_r] complex64 amplitude estimates (per-sample amplitude; the
    FFT zoom's value divided by its coherent gain).
    """
    n_cpi, L, n_r = y_sum.shape
    a_out = steering.astype(np.complex64)                                    # [n_cpi, L, K]
    if t_s is None:
        a_grid = a_out
    else:
        f_g = np.arange(grid_oversample * L) * (prf_hz / (grid_oversample * L))
        a_grid = np.exp(2j * np.pi * np.asarray(t_s)[:, :, None] * f_g[None, None, :]).astype(np.complex64)
    ys = np.moveaxis(y_sum, 2, 1).astype(np.complex64)                       # [n_cpi, n_r, L]
    yd = np.moveaxis(y_diff, 2, 1).astype(np.complex64)
    if noise_power is None:
        noise_power = float(np.median(ys.real**2 + ys.imag**2))
    out_s = np.einsum("clk,crl->crk", np.conj(a_out), ys) / L                # periodogram (FFT zoom / L)
    out_d = np.einsum("clk,crl->crk", np.conj(a_out), yd) / L
    if active is None:
        active = np.ones((n_cpi, n_r), bool)
    # the neighbours of an active cell are active too: the powers are smoothed over +-1 range cell
    # (adjacent range cells as extra snapshots), so the adaptive filters vary smoothly with range and
    # the range profile of each Doppler cell stays a band-limited, interpolable pulse
    active = active | np.roll(active, 1, axis=1) | np.roll(active, -1, axis=1)
    ic, ir = np.nonzero(active)
    if len(ic):
        ag, ao = a_grid[ic], a_out[ic]                                       # [n_act, L, K]
        y1, y2 = ys[ic, ir], yd[ic, ir]                                      # [n_act, L]
        s_all = np.einsum("clk,crl->crk", np.conj(a_grid), ys) / L           # periodogram, every cell
        eye = np.eye(L, dtype=np.complex64) * np.complex64(noise_power)
        for it in range(n_iter + 1):
            p_all = s_all.real**2 + s_all.imag**2
            p_all = (p_all + np.roll(p_all, 1, axis=1) + np.roll(p_all, -1, axis=1)) / 3.0
            p = p_all[ic, ir].astype(np.complex64)
            r_mat = np.matmul(ag * p[:, None, :], np.conj(np.swapaxes(ag, 1, 2))) + eye   # A diag(p) A^H
            a_use = ag if it < n_iter else ao                                # last pass: output cells
            rhs = np.concatenate([a_use, y1[:, :, None], y2[:, :, None]], axis=2)
            sol = np.linalg.solve(r_mat, rhs)
            den = np.einsum("alk,alk->ak", np.conj(a_use), sol[:, :, :-2]).real
            s = np.einsum("alk,al->ak", np.conj(a_use), sol[:, :, -2]) / den
            if it < n_iter:
                s_all[ic, ir] = s
        out_s[ic, ir] = s
        out_d[ic, ir] = np.einsum("alk,al->ak", np.conj(ao), sol[:, :, -1]) / den
    return np.moveaxis(out_s, 1, 2).astype(np.complex64), np.moveaxis(out_d, 1, 2).astype(np.complex64)
