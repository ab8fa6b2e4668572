"""The echoes against the navigation: the Doppler the echoes show at their monopulse angles against the
Doppler the recorded track predicts there (README, "The echoes against the navigation").

Every check in ``io/navigation.py`` compares the navigation with itself; a time-tag offset common to the
positions and the velocities (the navigation lagging the radar by d) passes them all, and moves every
target by about |v| d.  The echoes can see it where the platform accelerates: the recorded velocity at
radar time t is then v(t - d) = v(t) - a d, so a point's Doppler 2 v . u / lambda (eq. 2's rate of the
range history) sits 2 (a . u) d / lambda above what the record predicts.  The monopulse gives each
Doppler peak its own direction u (the chain's angle, ``forward/monopulse.py``), independently of its
Doppler; the residual f - 2 v . u / lambda over the peaks measures the velocity error along the lines
of sight, and with the acceleration along them the offset d.

Only point-like peaks count (:func:`_peaks`: no sidelobe of a stronger echo, a single scatterer's
Doppler width), and only where the Doppler resolves their direction.  Near the flight axis (the
horizontal velocity's azimuth) the beam's Doppler is flat in angle, and two scatterers in one Doppler
resolution cell (prf / cpi, an angle (prf / cpi) / |df/dpsi| wide) read at their mean angle and mean
Doppler, which the curvature of f = F cos(psi) (psi from the flight axis, F = 2 |v| cos(phi) / lambda)
puts up to (prf / cpi)^2 / (8 F sin^2 psi) low: a cell counts where that bound is at most
``MAX_BLEND_HZ``.  Where the method's budget leaves range errors, cells whose predicted Doppler they
would move by more do not count either.  On each side of the flight axis the median over its CPIs of
each CPI's median residual (cells within a CPI share targets and are not independent; CPIs are), with
its sigma 1.25 x the CPIs' MAD-sigma / sqrt(CPIs) (the median's efficiency for Gaussian spread); the
two sides are solved for the offset common to both and a pointing error, which changes sign across
the axis (:func:`echo_navigation_check`).

What it cannot tell apart: a velocity bias and a time-tag offset read alike along the lines of sight
(a d against a velocity error); the navigation's own checks tell the first from the second (a bias
makes the velocities disagree with the positions, a common offset does not).  With the counted echoes
on one side of the flight axis only, a pointing error reads as an offset too (the warning says both).
Without acceleration along the lines of sight an offset is a fixed shift of the track, which no echo
shows (``delay_s`` is then None).  The estimates are what is left after ``processing.navigation_delay_s``
and ``scan_angle_offset_deg``: the warnings name those settings plus the estimates.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..dsp.geometry import C_MPS, azimuth_at_t_ref
from ..dsp.imaging import median_sample_stride
from ..dsp.neighbours import running_max
from ..dsp.profile_rows import parabola_vertex_rows
from ..dsp.pulse import weighting
from ..io.backing import BLOCK_BYTES
from ..scenario.forward import MAX_NAVIGATION_DELAY_S, MAX_SCAN_ANGLE_OFFSET_DEG
from .dwell_range import flight_axis_deg

MAX_BLEND_HZ = 2.0              # a cell counts where the blind zone's blend bound is at most this (Hz)
THRESHOLD_DB = 20.0             # a peak's sum power over its CPI's median: its Doppler and angle need SNR
MAIN_BEAM_DB = 12.0             # and within this of the strongest peak at its range over the scan: main-beam echoes
NUMERIC_FLOOR_DB = 100.0        # and within this of the strongest peak of all: over float32 processing's residue
SHIFT_WARN_SAMPLES = 0.1        # a delay warned where it moves the targets over this many range samples
MAX_DWELL_COLUMNS = 128         # range columns a dwell-imaging chain computes CPI spectra on for the check
MIN_SIDE_CPIS = 5               # CPIs with counted cells a side of the flight axis needs to count


class Cells(NamedTuple):
    """The counted cells of :func:`cell_residuals_hz`."""
    cpi: np.ndarray             # CPI index
    residual_hz: np.ndarray     # measured Doppler less 2 v . u / lambda
    los: np.ndarray             # [n, 3] line-of-sight unit vectors
    sin_psi: np.ndarray         # sine of the azimuth from the flight axis
    f_span_hz: np.ndarray       # F = 2 |v_h| cos(depression) / lambda: the Doppler per unit cos(psi)
    prf_hz: float = 0.0         # the residuals are known modulo it (0: taken as they are)


def _peaks(z, threshold_db: float, *, range_cells: int, doppler_cells: int, min_curvature: float, eligible,
           envelopes=None):
    """The point-like Doppler peaks of a block of CPI spectra ``z`` [cpi, doppler, range]: over
    ``threshold_db`` of each CPI's noise floor, the largest power within +-``range_cells`` in range (same
    Doppler cell) and +-``doppler_cells`` in Doppler (same range cell), so that no sidelobe of a stronger
    echo counts (at 800 m height the predicted Doppler moves 4-5 Hz per metre of range: sidelobe cells
    4-10 m off a target had read +20 Hz, a review), and with the Doppler curvature of a single
    scatterer, (2 p0 - p_lo - p_hi) / p0 at least ``min_curvature`` (a blend of scatterers is wider), in
    range cells ``eligible`` (their +-``range_cells`` neighbours contiguous samples), and, with
    ``envelopes`` (:func:`sidelobe_envelopes`), over the sidelobes of every stronger peak of its CPI by
    :data:`SIDELOBE_MARGIN_DB` (:func:`_clear_of_far_sidelobes`).  Returns (CPI in
    the block, Doppler cell, range cell, the powers of the Doppler cells below, at and above, and the sum
    samples within +-:func:`interp_cells` in range, [n, 2 interp_cells + 1], the peak's own in the middle)."""
    power = np.abs(z) ** 2
    n_c, n_z, n_r = power.shape
    # the CPI's noise floor: the median of a strided sample (the image's stride, sharing no factor with
    # the range cells, dsp/imaging.py; the threshold needs no exact median)
    floor = np.median(power.reshape(n_c, -1)[:, ::median_sample_stride(n_r)], axis=1)
    flat = np.flatnonzero(power > floor[:, None, None] * np.float32(10.0 ** (threshold_db / 10.0)))
    iz, ir = np.divmod(flat % (n_z * n_r), n_r)
    inner = (iz > 0) & (iz < n_z - 1) & eligible[ir]
    flat, iz = flat[inner], iz[inner]
    # the neighbours by flat index (a Doppler cell n_r samples on, a range cell 1: one take each, not
    # a 3-index gather); an eligible cell's +-range_cells lie in its own row, so no clamp in range
    pf = power.reshape(-1)
    p_0 = pf.take(flat)
    # local maxima first (cheap: one neighbour each way), then the wider dominance on those few
    first = ((p_0 > pf.take(flat - n_r)) & (p_0 >= pf.take(flat + n_r)) & (p_0 >= pf.take(flat - 1))
             & (p_0 >= pf.take(flat + 1)))
    flat, iz, p_0 = flat[first], iz[first], p_0[first]
    keep = np.ones(len(flat), bool)
    for k in range(2, range_cells + 1):
        keep &= (p_0 >= pf.take(flat - k)) & (p_0 >= pf.take(flat + k))
    for k in range(2, doppler_cells + 1):     # clamped to the CPI's first and last Doppler cells
        keep &= ((p_0 >= pf.take(flat + (np.maximum(iz - k, 0) - iz) * n_r))
                 & (p_0 >= pf.take(flat + (np.minimum(iz + k, n_z - 1) - iz) * n_r)))
    flat, p_0 = flat[keep], p_0[keep]
    p_lo, p_hi = pf.take(flat - n_r), pf.take(flat + n_r)
    single = (2.0 * p_0 - p_lo - p_hi) >= min_curvature * p_0
    flat, p_0, p_lo, p_hi = flat[single], p_0[single], p_lo[single], p_hi[single]
    jc, rest = np.divmod(flat, n_z * n_r)
    iz, ir = np.divmod(rest, n_r)
    if envelopes is not None and len(flat):
        clear = _clear_of_far_sidelobes(jc, iz, ir, p_0, *envelopes, doppler_cells, range_cells)
        flat, p_0, p_lo, p_hi, jc, iz, ir = (a[clear] for a in (flat, p_0, p_lo, p_hi, jc, iz, ir))
    k_interp = interp_cells(range_cells)
    around = z.reshape(-1).take(flat[:, None] + np.arange(-k_interp, k_interp + 1))   # its range row
    return jc, iz, ir, p_lo, p_0, p_hi, around


SIDELOBE_MARGIN_DB = 6.0         # a peak counts where it stands this far over a stronger peak's far sidelobes


def main_beam_peaks(ir, p_0, n_range: int, range_cells: int):
    """Which peaks (range cell ``ir``, power ``p_0``, over every CPI) lie within :data:`MAIN_BEAM_DB` of the
    strongest peak within +-``range_cells`` of their range over the scan.  A target seen through the
    beam's far sidelobes lies at its own range tens of dB under its main-beam peak there, and its
    monopulse ratio gives an angle within the beam all the same: a noiseless cube's such echoes, and its
    residues in CPIs aimed away from every target, had read +47 to +79 Hz, a lone point's -59.5 Hz and a
    0.37 deg pointing error (fifty-ninth round).  A counted echo is within half a beamwidth of the beam's
    axis, 6 dB of two-way pattern; 12 dB leaves noise and the Doppler cells' straddle room.  (A floor
    gate at each CPI's median floor had dropped real peaks of the dwell chain's strong columns and the
    extended scene, whose CPIs' floors differ by 17-19 dB: a review.)"""
    ir = np.asarray(ir, dtype=np.int64)
    strongest = np.zeros(max(int(n_range), 1))
    np.maximum.at(strongest, ir, p_0)
    near = running_max(strongest, 2 * int(range_cells) + 1)
    return p_0 >= near[ir] * 10.0 ** (-MAIN_BEAM_DB / 10.0)


def _clear_of_far_sidelobes(jc, iz, ir, p_0, doppler_envelope, range_envelope, doppler_cells: int,
                            range_cells: int):
    """Which peaks (CPI ``jc``, Doppler cell ``iz``, range cell ``ir``, power ``p_0``) stand
    :data:`SIDELOBE_MARGIN_DB` over the sidelobes every stronger peak of their CPI puts there: its power
    times the Doppler response's envelope at their Doppler cells apart times the compressed pulse's at
    their range cells apart (a point's CPI spectrum is the product of the two; ``doppler_envelope``,
    ``range_envelope`` by whole cells apart, :func:`sidelobe_envelopes`).  Pairs within the dominance
    tests' reach (``doppler_cells``, ``range_cells``) are left to them."""
    margin = 10.0 ** (SIDELOBE_MARGIN_DB / 10.0)
    order = np.argsort(jc, kind="stable")
    bounds = np.flatnonzero(np.r_[True, jc[order][1:] != jc[order][:-1], True])
    clear = np.ones(len(jc), bool)
    for a, b in zip(bounds[:-1], bounds[1:]):            # one CPI's peaks: tens, pairwise
        k = order[a:b]
        dz = np.abs(iz[k][:, None] - iz[k][None, :])
        dr = np.abs(ir[k][:, None] - ir[k][None, :])
        lobes = p_0[k][None, :] * doppler_envelope[np.minimum(dz, len(doppler_envelope) - 1)] \
            * range_envelope[np.minimum(dr, len(range_envelope) - 1)]
        lobes[(dz <= doppler_cells) & (dr <= range_cells)] = 0.0          # (itself, and the dominance's reach)
        lobes[p_0[k][None, :] <= p_0[k][:, None]] = 0.0                   # only stronger peaks' sidelobes
        clear[k] = p_0[k] >= margin * lobes.max(axis=1)
    return clear


def sidelobe_envelopes(window, step_hz: float, prf_hz: float, n_doppler: int, n_range: int, spacing_m: float,
                       range_resolution_m: float):
    """The sidelobes :func:`_clear_of_far_sidelobes` compares with: the power response of one scatterer
    in the CPI's zoom (slow-time weights ``window`` at ``prf_hz``, cells ``step_hz`` apart) and, in range,
    of an unweighted compressed pulse (sinc^2 of the offset over the resolution: the highest sidelobes
    any range weighting has), each as its running maximum outwards (an envelope, 1 at 0) at whole cells
    apart, taken half a cell nearer (a peak between two cells).  Strong echoes' far sidelobes are
    point-like peaks over the threshold too wherever the CPI's floor lies far under them (a noiseless
    cube, a target 40 dB and more over the noise): ``test_a_strong_points_sidelobes_are_not_read_as_echoes``
    (fifty-ninth round)."""
    w = np.asarray(window, dtype=np.float64)
    n = np.arange(len(w))
    fine = np.linspace(0.0, float(n_doppler + 1), 16 * (n_doppler + 1) + 1)
    resp = np.abs(np.exp(2j * np.pi * fine[:, None] * step_hz * n[None, :] / prf_hz) @ w) ** 2 / np.sum(w) ** 2
    tail = np.maximum.accumulate(resp[::-1])[::-1]                          # the largest response at or beyond
    doppler = np.interp(np.arange(n_doppler + 1) - 0.5, fine, tail, left=1.0)
    apart = (np.arange(n_range + 1) - 0.5) * spacing_m / max(float(range_resolution_m), 1e-12)
    pulse = np.minimum(1.0, 1.0 / np.maximum(np.pi * apart, 1e-12) ** 2)    # sinc^2's envelope
    return doppler, pulse


RANGE_FINE_STEP = 1.0 / 32.0     # the fine grid of :func:`range_peak_offsets`, in range samples
MIN_INTERP_CELLS = 4             # the range samples either side the peak is interpolated from, at least


def interp_cells(range_cells: int) -> int:
    """The samples either side of a peak :func:`range_peak_offsets` reads: the dominance test's reach, and
    at least :data:`MIN_INTERP_CELLS` (worst errors of an unweighted pulse, in samples, from +-3 / +-4:
    0.018 / 0.005 at fs / B = 1.2, 0.056 / 0.038 at 1.05, 0.075 / 0.057 at 1.0, a review)."""
    return max(int(range_cells), MIN_INTERP_CELLS)


def range_peak_offsets(around):
    """The peak of each row of ``around`` [n, 2K + 1] (a cell's complex samples at -K..K range samples
    about its largest one) in samples from the middle one: the band-limited profile interpolated by a
    Lanczos kernel (a = K + 1, the samples' own span) on a grid of :data:`RANGE_FINE_STEP` over -1..1,
    then a parabola through the largest power and its two neighbours there.

    A parabola through the three native powers is biased by the point's shape: up to 0.21 samples for
    an unweighted pulse sampled at 1.2 samples per resolution cell (the paper's fs / B), 0.10 with a
    Hamming taper; at steep depression the predicted Doppler moves with range (14 Hz per metre at 3000 m
    of height, 1.7 km out), so that bias had read as a 7 Hz offset and a false 3 ms lag on a clean cube
    (a review).  Interpolated from +-3 samples, 0.018 samples (unweighted) and 0.005 (Hamming) at worst
    (``tests/test_echo_navigation.py``); the check reads +-:func:`interp_cells`, 4 at least: 0.005 samples
    unweighted at fs / B = 1.2."""
    k_max = (around.shape[1] - 1) // 2
    taps = np.arange(-k_max, k_max + 1)
    fine = np.arange(-1.0, 1.0 + 0.5 * RANGE_FINE_STEP, RANGE_FINE_STEP)
    lobe = k_max + 1.0
    x = fine[:, None] - taps[None, :]
    kernel = np.where(np.abs(x) < lobe, np.sinc(x) * np.sinc(x / lobe), 0.0)
    power = np.abs(np.asarray(around, np.complex128) @ kernel.T) ** 2          # [n, fine]
    j = np.clip(np.argmax(power, axis=1), 1, len(fine) - 2)
    rows = np.arange(len(j))
    vertex = parabola_vertex_rows(power[rows, j - 1], power[rows, j], power[rows, j + 1])[0]
    return fine[j] + vertex * RANGE_FINE_STEP


def single_scatterer_curvature(window, step_hz: float, prf_hz: float) -> float:
    """The least Doppler curvature 2 - (W(d - 1) + W(d + 1)) / W(d) of one scatterer in the zoom of
    ``window`` (the CPI's slow-time weights at ``prf_hz``) sampled every ``step_hz``: half a cell off
    (0.93 of the centred one for a rectangular window at 4 cells per resolution cell)."""
    w = np.asarray(window, dtype=np.float64)
    n = np.arange(len(w))

    def response(offset_cells):            # the zoom's power response to one scatterer, offset in cells
        return abs(np.sum(w * np.exp(2j * np.pi * offset_cells * step_hz * n / prf_hz))) ** 2

    return float(2.0 - (response(-0.5) + response(1.5)) / response(0.5))


def _range_cells(range_m, range_resolution_m: float | None) -> tuple[float, int]:
    """(the range samples' spacing, the samples either side a peak must dominate): a point's first
    sidelobes lie within 1.5 resolution cells, so 2 resolution cells either way."""
    spacing_m = float(np.min(np.diff(np.asarray(range_m, float)))) if len(range_m) > 1 else 1.0
    return spacing_m, int(np.ceil(2.0 * (range_resolution_m or spacing_m) / spacing_m))


def _eligible_ranges(range_m, range_cells: int, spacing_m: float) -> np.ndarray:
    """Range cells whose +-``range_cells`` neighbours are contiguous samples (a dwell chain's strong
    columns have gaps between their windows; ``spacing_m``: the samples' spacing, :func:`_range_cells`)."""
    gaps = np.diff(np.asarray(range_m, dtype=np.float64))
    run = np.concatenate([[0], np.cumsum(gaps > 1.5 * spacing_m)])
    idx = np.arange(len(range_m))
    lo, hi = np.clip(idx - range_cells, 0, len(idx) - 1), np.clip(idx + range_cells, 0, len(idx) - 1)
    return (idx - range_cells >= 0) & (idx + range_cells < len(idx)) & (run[lo] == run) & (run[hi] == run)


def cell_residuals_hz(sum_z, diff_z, doppler_hz, beam_deg, velocity_mps, position_m, range_m, *, fc_hz: float,
                      beamwidth_deg: float, prf_hz: float, cpi: int, offset_of_ratio, diff_gain_db: float = 0.0,
                      position_ref_m, diff_phase_deg: float = 0.0, threshold_db: float = THRESHOLD_DB,
                      range_resolution_m: float | None = None, window=None, range_error_m: float = 0.0) -> Cells:
    """The counted cells (module docstring).  ``sum_z``, ``diff_z``: [cpi, doppler, range] spectra of the
    Doppler stage with ``doppler_hz`` [cpi, doppler] their true Doppler; ``beam_deg``,
    ``velocity_mps``, ``position_m``: the CPIs' mean beam angle, velocity and antenna position;
    ``range_m``: the spectra's slant ranges at t_ref (``position_ref_m``, the antenna there);
    ``offset_of_ratio``: the calibration's inverse ratio curve (degrees from the beam axis), offsets
    beyond half a beamwidth not counted (as the image projects them); ``window``: the CPI's slow-time
    weights (rectangular where None); ``range_error_m``: the range error the method's budget leaves
    (``plan.method_range_error_m``)."""
    wavelength_m = C_MPS / fc_hz
    beam_deg, velocity_mps = np.asarray(beam_deg, float), np.asarray(velocity_mps, float)
    flight_deg = flight_axis_deg(velocity_mps)
    # only CPIs whose beam reaches angles that can count (the bound below at the beam's outer edge from
    # the flight axis, half a beamwidth out, and the CPI's largest F = 2 |v_h| / lambda)
    edge = np.minimum(np.abs(beam_deg - flight_deg) + 0.5 * beamwidth_deg, 90.0)
    f_top_hz = 2.0 * np.hypot(velocity_mps[:, 0], velocity_mps[:, 1]) / wavelength_m
    usable = np.flatnonzero(np.sin(np.radians(edge)) ** 2 * 8.0 * f_top_hz * MAX_BLEND_HZ >= (prf_hz / cpi) ** 2)
    if len(usable) == 0 or sum_z.shape[-1] == 0:     # (a dwell chain with no strong range column: none to read)
        empty = np.zeros(0)
        return Cells(empty.astype(np.int64), empty, np.zeros((0, 3)), empty, empty)
    step_hz = float(np.median(np.diff(np.asarray(doppler_hz)[:, :2], axis=1)))
    spacing_m, range_cells = _range_cells(range_m, range_resolution_m)
    doppler_cells = int(np.ceil(2.0 * (prf_hz / cpi) / step_hz))
    min_curvature = 0.8 * single_scatterer_curvature(np.ones(cpi) if window is None else window, step_hz, prf_hz)
    eligible = _eligible_ranges(range_m, interp_cells(range_cells), spacing_m)
    # blocks of whole CPIs (a file-backed stage's spectra are read a block at a time: README, out of core)
    per_block = max(1, BLOCK_BYTES // max(1, sum_z[0].nbytes))
    starts = range(0, len(usable), per_block)
    consecutive = usable[-1] - usable[0] == len(usable) - 1     # (the paper's scan: every CPI)

    def block(i):           # CPIs usable[i:i + per_block]: a view of the spectra where they are consecutive
        picked = usable[i:i + per_block]
        return sum_z[picked[0]:picked[-1] + 1] if consecutive else sum_z[picked]

    envelopes = sidelobe_envelopes(np.ones(cpi) if window is None else window, step_hz, prf_hz, sum_z.shape[1],
                                   len(range_m), spacing_m, range_resolution_m or spacing_m)
    parts = [_peaks(block(i), threshold_db, range_cells=range_cells, doppler_cells=doppler_cells,
                    min_curvature=min_curvature, eligible=eligible, envelopes=envelopes) for i in starts]
    jc = np.concatenate([part[0] + i for part, i in zip(parts, starts)])
    iz, ir, p_lo, p_0, p_hi, around = (np.concatenate([part[k] for part in parts]) for k in range(1, 7))
    # through the main beam only: within MAIN_BEAM_DB of the strongest peak at its range over the scan
    # (a target's far-sidelobe echoes carry no monopulse angle; a noiseless cube's had read +47 to +79 Hz),
    # and over the float32 processing's own floor, NUMERIC_FLOOR_DB under the strongest peak of all
    main = main_beam_peaks(ir, p_0, len(range_m), range_cells)
    main &= p_0 >= float(p_0.max(initial=0.0)) * 10.0 ** (-NUMERIC_FLOOR_DB / 10.0)
    jc, iz, ir, p_lo, p_0, p_hi, around = (a[main] for a in (jc, iz, ir, p_lo, p_0, p_hi, around))
    ic = usable[jc]
    ratio = diff_z[ic, iz, ir] / around[:, around.shape[1] // 2]         # over the peak's own sum sample
    if diff_gain_db or diff_phase_deg:     # the calibration's channel imbalance divided out (as the image)
        ratio = ratio / (10.0 ** (diff_gain_db / 20.0) * np.exp(1j * np.radians(diff_phase_deg)))
    offset_deg = offset_of_ratio(np.real(ratio))
    angle_deg = beam_deg[ic] + offset_deg
    # the Doppler peak interpolated (a parabola through the powers: the zoom's 4 cells per resolution
    # cell), the range peak from the band-limited profile (the predicted Doppler moves with range at
    # steep depression: :func:`range_peak_offsets`)
    f_hz = doppler_hz[ic, iz] + parabola_vertex_rows(p_lo, p_0, p_hi)[0] * (doppler_hz[ic, 1] - doppler_hz[ic, 0])
    r_m = range_m[ir] + range_peak_offsets(around) * spacing_m
    # the ground point at that angle from the CPI's antenna and at the cell's t_ref range (as the image)
    _, gx, gy = azimuth_at_t_ref(r_m, angle_deg, position_m[ic], np.asarray(position_ref_m, float))
    los = np.stack([gx - position_m[ic, 0], gy - position_m[ic, 1], -position_m[ic, 2]], axis=1)
    los /= np.linalg.norm(los, axis=1, keepdims=True)
    v = velocity_mps[ic]
    predicted_hz = 2.0 * np.einsum("ij,ij->i", v, los) / wavelength_m
    # the blind zone (module docstring): the blend bound (prf / cpi)^2 / (8 F sin^2 psi) at most MAX_BLEND_HZ
    psi = np.radians(angle_deg - flight_deg[ic])
    cos_dep = np.hypot(los[:, 0], los[:, 1])
    f_span_hz = 2.0 * np.hypot(v[:, 0], v[:, 1]) * cos_dep / wavelength_m
    blend_hz = (prf_hz / cpi) ** 2 / (8.0 * f_span_hz * np.maximum(np.sin(psi) ** 2, 1e-12))
    # a range error moves the predicted Doppler through the depression: df/dR = F |cos(psi)| tan^2(phi) / R
    # (= 2 |v| |cos psi| sin^2 phi / (cos phi lambda R): 4.3-5.1 Hz per metre at 800 m height, 1.7 km and
    # 240-290 m/s; 0.015 at 50 m); where the method's budget leaves ``range_error_m``, cells it would move
    # by over MAX_BLEND_HZ do not count (decimation at 800 m: +16 Hz from its range errors, a review)
    dfdr = f_span_hz * np.abs(np.cos(psi)) * (los[:, 2] / np.maximum(cos_dep, 1e-12)) ** 2 / r_m
    keep = (np.isfinite(predicted_hz) & (np.abs(offset_deg) <= 0.5 * beamwidth_deg) & (blend_hz <= MAX_BLEND_HZ)
            & (dfdr * range_error_m <= MAX_BLEND_HZ))
    residual_hz = wrapped_hz(f_hz - predicted_hz, prf_hz)
    return Cells(ic[keep], residual_hz[keep], los[keep], np.sin(psi)[keep], f_span_hz[keep], float(prf_hz))


def wrapped_hz(residual_hz, prf_hz: float):
    """A Doppler residual taken to [-prf/2, prf/2): the pulses sample the echoes' Doppler modulo the PRF
    (eq. 23-26), so a CPI's band (at most one PRF wide, centred on the window's middle) holds an echo
    whose Doppler lies outside it at that Doppler less a whole number of PRFs.  At steep depression the
    window's Doppler spreads over more than one PRF (about 5.4 kHz across 1000 m of height, 1.5-1.9 km, at
    18 GHz and PRF 2500 Hz), and the echoes at its ends had read whole PRFs from the prediction: -1226 Hz
    and a 15.8 deg pointing error on a clean cube (a review).  An offset of the navigation is read
    unambiguously within +-prf/2, as the band itself places the echoes only so far."""
    return (np.asarray(residual_hz, dtype=np.float64) + 0.5 * prf_hz) % prf_hz - 0.5 * prf_hz


def _group_medians(groups, values):
    """The median of ``values`` in each distinct value of ``groups`` (sorted by group): one sort."""
    order = np.lexsort((values, groups))
    g, v = groups[order], values[order]
    first = np.flatnonzero(np.r_[True, g[1:] != g[:-1]])
    count = np.diff(np.r_[first, len(g)])
    return 0.5 * (v[first + (count - 1) // 2] + v[first + count // 2])


def unwrapped_about_centre(residual_hz, prf_hz: float):
    """Residuals known modulo ``prf_hz``, each taken within half a PRF of their circular mean (the
    direction of sum exp(j 2 pi r / prf)), so that medians and spreads see one cluster where it lies
    across +-prf/2 (an offset of 1230 Hz at 2500 Hz had read -76.5 Hz and a -11 deg pointing error; a
    review); as they are where ``prf_hz`` is 0."""
    r = np.asarray(residual_hz, dtype=np.float64)
    if not prf_hz or r.size == 0:
        return r
    centre = prf_hz / (2.0 * np.pi) * float(np.angle(np.sum(np.exp(2j * np.pi * r / prf_hz))))
    return centre + wrapped_hz(r - centre, prf_hz)


def _side(cells: Cells, mask):
    """(median over the side's CPIs of each CPI's median residual, its sigma, the CPIs' median of
    F sin(psi)), or None where the side has fewer than ``MIN_SIDE_CPIS`` CPIs (one CPI's MAD is 0)."""
    if len(np.unique(cells.cpi[mask])) < MIN_SIDE_CPIS:
        return None
    per_cpi = _group_medians(cells.cpi[mask], unwrapped_about_centre(cells.residual_hz[mask], cells.prf_hz))
    lever_cpi = _group_medians(cells.cpi[mask], (cells.f_span_hz * cells.sin_psi)[mask])
    med = float(np.median(per_cpi))
    # 1.4826 MAD: the CPIs' sigma; 1.25 / sqrt(n): the median's sigma for Gaussian spread
    sigma = float(1.25 * 1.4826 * np.median(np.abs(per_cpi - med)) / np.sqrt(len(per_cpi)))
    return med, sigma, float(np.median(lever_cpi))


def echo_navigation_check(cells: Cells, *, fc_hz: float, accel_mps2, speed_mps: float,
                          range_spacing_m: float) -> dict:
    """The estimate of the module docstring from :func:`cell_residuals_hz`'s cells.  Each side of the
    flight axis with at least ``MIN_SIDE_CPIS`` CPIs gives the median over its CPIs of each CPI's median
    residual, m_L and m_R, at g_L < 0 < g_R, the CPIs' median of F sin(psi).  Scan angles recorded b (rad)
    towards +x of where the antenna pointed add g b to a side; the navigation's offset c0 adds the same to
    both: m = c0 + g b on each side, solved for c0 and b.  With one side, c0 is its median and b cannot be
    told from it: ``pointing_alternative_deg`` = c0 / g is the b that would read the same.  Returns
    ``doppler_offset_hz`` c0 and ``sigma_hz``; the line-of-sight velocity error ``velocity_error_mps`` =
    lambda c0 / 2 (positive: the echoes faster than the record) and its sigma; the acceleration along the
    lines of sight ``accel_los_mps2``; where it pins the offset to a range sample's worth of shift
    (``speed_mps`` x its sigma at most ``range_spacing_m``), ``delay_s`` (the navigation lagging the radar
    by it), ``sigma_delay_s`` and ``shift_m`` = ``speed_mps`` x delay (how far a lag moves the targets);
    with both sides ``pointing_error_deg`` b and its sigma; ``cells``, ``cpis``, ``sides`` and
    ``blend_bound_hz`` (c0 may read that much low).  ``doppler_offset_hz`` None where neither side
    counts."""
    wavelength_m = C_MPS / fc_hz
    out = {"cells": int(len(cells.residual_hz)), "cpis": int(len(np.unique(cells.cpi))), "sides": 0,
           "doppler_offset_hz": None, "sigma_hz": None, "velocity_error_mps": None, "sigma_velocity_mps": None,
           "accel_los_mps2": None, "delay_s": None, "sigma_delay_s": None, "shift_m": None,
           "pointing_error_deg": None, "sigma_pointing_deg": None, "pointing_alternative_deg": None,
           "blend_bound_hz": MAX_BLEND_HZ}
    sides = [side for side in (_side(cells, cells.sin_psi < 0), _side(cells, cells.sin_psi > 0)) if side is not None]
    if not sides:
        return out
    if len(sides) == 2:           # m = c0 + (F sin(psi)) x pointing error, one equation per side
        (m_l, sg_l, g_l), (m_r, sg_r, g_r) = sides
        if cells.prf_hz:          # the right side's median within half a PRF of the left's (one cluster)
            m_r = m_l + float(wrapped_hz(m_r - m_l, cells.prf_hz))
        offset_hz = (m_l * g_r - m_r * g_l) / (g_r - g_l)
        sigma_hz = float(np.hypot(g_r * sg_l, g_l * sg_r) / (g_r - g_l))
        out["pointing_error_deg"] = float(np.degrees((m_r - m_l) / (g_r - g_l)))
        out["sigma_pointing_deg"] = float(np.degrees(np.hypot(sg_l, sg_r) / (g_r - g_l)))
    else:
        offset_hz, sigma_hz, lever = sides[0]
    if cells.prf_hz:                  # the offset within half a PRF, as the residuals are
        offset_hz = float(wrapped_hz(offset_hz, cells.prf_hz))
    if len(sides) == 1:
        out["pointing_alternative_deg"] = float(np.degrees(offset_hz / lever))
    accel_los = float(np.median(cells.los @ np.asarray(accel_mps2, float)))
    out.update(sides=len(sides), doppler_offset_hz=float(offset_hz), sigma_hz=sigma_hz,
               velocity_error_mps=wavelength_m * offset_hz / 2.0, sigma_velocity_mps=wavelength_m * sigma_hz / 2.0,
               accel_los_mps2=accel_los)
    if accel_los != 0.0 and speed_mps * out["sigma_velocity_mps"] / abs(accel_los) <= range_spacing_m:
        delay = out["velocity_error_mps"] / accel_los
        out.update(delay_s=delay, sigma_delay_s=out["sigma_velocity_mps"] / abs(accel_los),
                   shift_m=abs(speed_mps * delay))
    return out


def echo_navigation_of(spectra, calibration, *, fc_hz: float, beamwidth_deg: float, prf_hz: float, cpi: int,
                       position_ref_m, speed_mps: float, range_spacing_m: float,
                       range_resolution_m: float | None = None, range_error_m: float = 0.0) -> dict:
    """:func:`echo_navigation_check` of the Doppler stage's output ``spectra`` (both channels) with the
    chain's monopulse ``calibration`` (``forward/calibration.py``).  The CPIs' velocities are the spectra's
    own, the mean of the chain's track over each CPI (eq. 25; under ``processing.doppler_centroid: false``
    the initial velocity for every CPI, which ``process`` does not read); the acceleration is their
    least-squares slope over the CPI times."""
    t_c = np.asarray(spectra["cpi_time_s"], float)
    vel = np.asarray(spectra["cpi_velocity_mps"], float)
    accel = np.polyfit(t_c - t_c.mean(), vel, 1)[0] if len(t_c) >= 2 else np.zeros(3)
    cells = cell_residuals_hz(spectra["sum_z"], spectra["diff_z"], np.asarray(spectra["doppler_hz"]),
                              np.asarray(spectra["cpi_beam_deg"]), vel, np.asarray(spectra["cpi_position_m"]),
                              np.asarray(spectra["range_m"]), fc_hz=fc_hz, beamwidth_deg=beamwidth_deg,
                              prf_hz=prf_hz, cpi=cpi, offset_of_ratio=calibration.offset_deg,
                              diff_gain_db=calibration.diff_gain_db, diff_phase_deg=calibration.diff_phase_deg,
                              position_ref_m=position_ref_m, range_resolution_m=range_resolution_m,
                              window=weighting(spectra.attrs.get("doppler_window", "none"), cpi),
                              range_error_m=range_error_m)
    return echo_navigation_check(cells, fc_hz=fc_hz, accel_mps2=accel, speed_mps=speed_mps,
                                 range_spacing_m=range_spacing_m)


def echo_navigation_warnings(check: dict, *, range_spacing_m: float, angle_step_deg: float,
                             delay_set_s: float = 0.0, scan_offset_set_deg: float = 0.0) -> list[str]:
    """The warnings of :func:`echo_navigation_check`'s result: an offset that would move the targets over
    ``SHIFT_WARN_SAMPLES`` of a range sample as a lag, and a pointing error over the image's angle step,
    each only where it stands out of the estimate's noise (3 sigma) and, for the offset, of the blind
    zone's bound.  The estimates are what the settings in force (``delay_set_s``, ``scan_offset_set_deg``)
    left: each warning names the setting plus the estimate (a delay only within the setting's range)."""
    out = []
    if check.get("doppler_offset_hz") is None:
        return out
    off, sig = check["doppler_offset_hz"], check["sigma_hz"]
    if (check["delay_s"] is not None and check["shift_m"] > SHIFT_WARN_SAMPLES * range_spacing_m
            and abs(off) > 3.0 * sig + check["blend_bound_hz"]):
        delay = delay_set_s + check["delay_s"]
        line = (f"the echoes' Doppler sits {off:+.1f} +- {sig:.1f} Hz from the navigation's at their monopulse angles "
                f"({check['cells']} cells in {check['cpis']} CPIs): the track's velocity is "
                f"{check['velocity_error_mps']:+.3f} m/s off along the lines of sight; a navigation lagging the radar "
                f"by {check['delay_s'] * 1e3:.2f} +- {check['sigma_delay_s'] * 1e3:.2f} ms more reads so (acceleration "
                f"{check['accel_los_mps2']:.1f} m/s^2 along them) and would move the targets about "
                f"{check['shift_m']:.2f} m (a velocity bias moves none: the navigation's own checks tell)")
        if check["sides"] == 1:
            line += (f"; so would scan angles {check['pointing_alternative_deg']:+.3f} deg off, as the counted echoes "
                     f"lie on one side of the flight axis only")
        if abs(delay) <= MAX_NAVIGATION_DELAY_S:     # (a setting the schema takes)
            line += (f": where the navigation agrees with itself{' and the pointing is known' if check['sides'] == 1 else ''}, "
                     f"set processing.navigation_delay_s: {delay:.5f}")
        alternative = scan_offset_set_deg + (check["pointing_alternative_deg"] if check["sides"] == 1 else 0.0)
        if check["sides"] == 1 and abs(alternative) <= MAX_SCAN_ANGLE_OFFSET_DEG:     # (a setting the schema takes)
            line += f"; where the timing is known, processing.scan_angle_offset_deg: {alternative:.4f}"
        out.append(line + " (README, The echoes against the navigation)")
    point = check.get("pointing_error_deg")
    if point is not None and abs(point) > max(3.0 * check["sigma_pointing_deg"], angle_step_deg):
        offset = scan_offset_set_deg + point
        setting = (f"set processing.scan_angle_offset_deg: {offset:.4f}" if abs(offset) <= MAX_SCAN_ANGLE_OFFSET_DEG
                   else f"{offset:.4f} deg in all, beyond what processing.scan_angle_offset_deg takes "
                        f"(+-{MAX_SCAN_ANGLE_OFFSET_DEG:g} deg): check the recorded scan angles")
        out.append(
            f"the echoes' Doppler agrees with their monopulse angles only with the scan angles moved by "
            f"{-point:+.3f} +- {check['sigma_pointing_deg']:.3f} deg more: a pointing error of the antenna (or scan "
            f"angles recorded that far off) puts the targets that far off in azimuth: {setting} (README, The "
            f"echoes against the navigation)")
    return out


def echo_margin_cells(range_m, range_resolution_m: float) -> int:
    """The range samples either side a counted cell's tests and its range peak read (:func:`_peaks`), plus one."""
    return interp_cells(_range_cells(range_m, range_resolution_m)[1]) + 1


def strong_columns(compensated, max_columns: int = MAX_DWELL_COLUMNS, over_db: float = 10.0,
                   margin: int = 0) -> np.ndarray:
    """The range columns of the motion-compensated data (``range_curvature``'s output) whose sum-channel
    energy is ``over_db`` over the median column's, the strongest ``max_columns`` of them, each with
    ``margin`` columns either side (the peak tests' neighbours), in range order: where a dwell-imaging
    chain, which forms no CPI spectra, has its echoes' spectra computed for this check
    (``run_metrics.column_spectra``).  Read in blocks of pulses."""
    x = compensated["sum"]
    rows = max(1, BLOCK_BYTES // max(1, x[0].nbytes))
    energy = np.zeros(x.shape[1])
    for i in range(0, x.shape[0], rows):
        block = np.asarray(x[i:i + rows])
        energy += np.einsum("ij,ij->j", block.real, block.real) + np.einsum("ij,ij->j", block.imag, block.imag)
    strong = np.flatnonzero(energy >= np.median(energy) * 10.0 ** (over_db / 10.0))
    strong = strong[np.argsort(energy[strong])[::-1][:max_columns]]
    wide = (strong[:, None] + np.arange(-margin, margin + 1)[None, :]).ravel()
    return np.unique(wide[(wide >= 0) & (wide < x.shape[1])])
