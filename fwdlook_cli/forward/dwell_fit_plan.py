"""The joint fit's plan (``forward.dwell_fit``): whether it runs at all (the cube's antenna its model's, each
cell's own history close enough to a point's), the clusters of range cells it fits, the channels' noise
level, and the slow-time decimation its directions allow."""
from __future__ import annotations

import logging

import numpy as np

from ..dsp.fir import kaiser_lowpass
from ..dsp.geometry import C_MPS
from .dwell_range import flight_axis_deg, ground_points

log = logging.getLogger(__name__)

CLUSTER_HALF_BINS = 2      # range cells fitted on each side of the strong ones (a scatterer's skirts)
SIDELOBE_DB = 20.0         # range peaks more than 20 dB under the region's strongest: range sidelobes and their
                           # mixing products (or weak scatterers), left to the dwell image
DECIMATION_PASSBAND = 0.87  # the atoms' baseband within 87 % of the decimated Nyquist band (the filter: flat to 1e-4 up to 87.5 %)


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
    """Noise standard deviation of a mostly-empty channel: median sample power / ln 2, square-rooted.  A
    noiseless channel (median zero: a simulation with ``noise.snr_db: null``) gets 1e-6 of its largest
    sampled magnitude (-120 dB: the fit then stops by its dynamic range, not by a noise level), 1 where
    every sample is zero (no 1/0 in the fit's channel weights)."""
    p = np.asarray(x[:: max(1, x.shape[0] // 256)])
    power = p.real**2 + p.imag**2
    sigma = float(np.sqrt(np.median(power) / np.log(2.0)))
    if sigma > 0:
        return sigma
    peak = float(np.sqrt(power.max(initial=0.0)))
    return 1e-6 * peak if peak > 0 else 1.0


def decimation_plan(model, grid_deg, range_m, axis_deg, prf_hz):
    """Slow-time decimation the directions ``grid_deg`` allow: (Q, shift_hz, taps).

    Relative to the axis direction's phase history, the atom at theta has the Doppler
    f(theta; n) = -(2 / lambda) d/dt [R(theta; n) - R(axis; n)] (2 v (cos theta - 1) / lambda for a
    straight flight: 0 to -200 Hz over the paper's region and 1 deg more); measured here over the
    window's pulses and the grid, shifted to baseband by -shift_hz and widened by the antenna envelope's own
    bandwidth (a Gaussian two-way pattern exp(-2 beta d^2) swept at w deg/s: -60 dB at
    sqrt(27.6 beta) w / pi Hz), it fits in ``DECIMATION_PASSBAND`` of the band of a rate prf / Q.  The
    anti-alias filter is a Kaiser (beta 8) windowed sinc of 40 Q + 1 taps cut at prf / (2 Q): flat to
    1e-4 in the passband (-80 dB), its transition (a quarter of the cut-off frequency wide, centred on
    it) beyond where any atom lives.  Q = 1: no decimation."""
    grid = np.asarray(grid_deg, dtype=np.float64)
    grid = np.unique(np.concatenate([grid[::8], grid[-1:], [axis_deg]]))    # f is smooth in theta: every 8th
    rng = model.path(grid, [range_m])[0] - model.path([axis_deg], [range_m])[0]     # [N, M]
    f_hz = -2.0 / model.lam * np.diff(rng, axis=0) * prf_hz
    scan_dps = float(np.median(np.abs(np.diff(model.beam)))) * prf_hz
    envelope_hz = np.sqrt(27.6 * model.beta) * scan_dps / np.pi
    lo, hi = float(f_hz.min()), float(f_hz.max())
    half = 0.5 * (hi - lo) + envelope_hz
    q = int(np.floor(DECIMATION_PASSBAND * prf_hz / (2.0 * half)))
    if q < 2:
        return 1, 0.0, None
    taps = kaiser_lowpass(40 * q + 1, prf_hz / (2.0 * q), prf_hz)
    return q, 0.5 * (lo + hi), taps



GRID_MIN_CORR2 = 0.5       # a point half a grid step from an atom keeps at least half its power (3 dB straddle loss)
GRID_MAX_HALVINGS = 6      # the grid step at most 2^6 times finer than the image's angle step


def fit_angle_step(model, axis_deg, half_width_deg, range_m, angle_step_deg):
    """The fit's dictionary step: the image's ``angle_step_deg`` halved until, at both edges of the region
    (the finest angle resolution there: an atom's Doppler changes with angle as 2 v sin(theta) / lambda),
    an atom and the one half a step away correlate at least ``GRID_MIN_CORR2`` (|a^H b|^2 / |a|^2 |b|^2,
    the window's atoms at ``range_m``): a scatterer between two grid angles then loses at most 3 dB to
    the nearest one in the greedy pick (an FFT grid's worst straddle loss is 3.9 dB), and the parabolic
    refinement (``dwell_fit._refine``, 3 points a step apart) starts inside its main lobe.  On the paper's
    radar (18 GHz, a = 0, 10, 50) the 0.05 deg step keeps 0.81-0.88 half a step away at the region's
    edges, so it stays; at 94 GHz (a lobe five times narrower) 0.001-0.008, where the fit built 20 atoms
    on one point, 40-65 dB too strong, and lost others under the image's dynamic range; 0.0125 deg
    keeps 0.69-0.76 there."""
    step = float(angle_step_deg)
    edges = np.array([axis_deg - half_width_deg, axis_deg + half_width_deg])
    a0 = model.atoms(edges, [range_m])[0]                                                 # [2N, 2]
    for _ in range(GRID_MAX_HALVINGS):
        a1 = model.atoms(edges + 0.5 * step, [range_m])[0]
        corr2 = (np.abs(np.sum(np.conj(a0) * a1, axis=0)) ** 2
                 / (np.sum(np.abs(a0) ** 2, axis=0) * np.sum(np.abs(a1) ** 2, axis=0)))
        if float(corr2.min()) >= GRID_MIN_CORR2:
            break
        step *= 0.5
    return step


FIT_MAX_CELL_CYCLES = 0.25   # the history's change across one range cell over the fit window, in cycles, up to
                             # which each cell's atom may carry its own range's history (README, "The joint
                             # fit's cell model"): 0.02 on the paper's flights, 0.12 at 94 GHz (0.2 m bias), 0.2
                             # at 150 m of height (0.37 m), 2.1 at 500 m (0.85 m, where the dwell image: 0.05 m)


def cell_history_cycles(position_m, scan_angle_deg, range_m, *, axis_deg: float, window_deg: float,
                        position_ref_m, fc_hz: float) -> float:
    """How much the two-way phase history of the flight-axis direction changes from one range cell to
    the next over the pulses whose beam is within ``window_deg`` of the axis (the joint fit's window), in
    cycles: 2 / lambda ptp_n[(R(r + dr/2; n) - R(r - dr/2; n)) - dr] at the window's middle range.  Each
    of the fit's atoms carries its own cell's history, so a point between two cells is fitted with a
    history this far from its own (a range bias growing with it: steep depression, short wavelengths)."""
    beam = np.asarray(scan_angle_deg, dtype=np.float64)
    win = np.flatnonzero(np.abs(beam - axis_deg) <= window_deg)
    rng = np.asarray(range_m, dtype=np.float64)
    if len(win) < 2 or len(rng) < 2:
        return 0.0
    pos = np.asarray(position_m, dtype=np.float64)[win]
    r_mid, dr = float(np.median(rng)), float(rng[1] - rng[0])
    ground = ground_points(np.array([r_mid - 0.5 * dr, r_mid + 0.5 * dr]), axis_deg, position_ref_m)   # [2, 3]
    hist = np.linalg.norm(ground[:, None, :] - pos[None], axis=2)                                     # [2, N]
    return 2.0 * float(np.ptp(hist[1] - hist[0] - dr)) * fc_hz / C_MPS


def fit_models_antenna(cube) -> bool:
    """Whether the joint fit's pattern model (two Gaussian beams, dwell_fit.py) is the cube's antenna: a
    cube whose ``/antenna`` declares ``gaussian2``.  Another pattern (sinc2, a table) or a cube without
    ``/antenna`` would be fitted with the wrong weights (on the paper lattice with sinc2 beams: 10 m
    and 0.35 deg off), so there the dwell image stays alone, and the log says so."""
    pattern = (cube.antenna or {}).get("pattern", "gaussian2" if cube.antenna else None)
    if pattern == "gaussian2":
        return True
    log.warning(f"processing.dwell_fit: joint models two Gaussian beams; this cube's antenna is "
                f"{pattern or 'not declared (no /antenna)'}: the dwell image is used without the fit")
    return False


def fit_cell_model_holds(cube, geo: dict, window_deg: float) -> bool:
    """Whether each fitted cell may carry its own range's history (``dwell_fit_plan.cell_history_cycles``
    at most FIT_MAX_CELL_CYCLES over the fit's window); where not (steep depression: 0.85 m of range bias
    at 500 m of height, a lone point missed at 2000 m; an independent review), the dwell image stays
    alone near the axis too, and the log says so."""
    cycles = cell_history_cycles(cube.position_m, cube.scan_angle_deg, cube.range_m,
                                 axis_deg=flight_axis_deg(geo["v_ref"]),
                                 window_deg=window_deg, position_ref_m=geo["p_ref"], fc_hz=cube.radar["fc_hz"])
    if cycles <= FIT_MAX_CELL_CYCLES:
        return True
    log.warning(f"processing.dwell_fit: joint is not used: a point's phase history changes by {cycles:.2f} cycle "
                f"from one range cell to the next over the fit's window (steep depression or a short wavelength; "
                f"the fit's cells hold up to {FIT_MAX_CELL_CYCLES:g}: README, \"The joint fit's cell model\"), so "
                f"the dwell image is used without it")
    return False
