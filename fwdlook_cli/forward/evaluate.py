"""Per-target metrics of a forward-looking image against the simulator's truth (CONTRACT.md 5).

For every truth target the truth is its slant range and azimuth from the antenna phase centre at
t_ref.  The measured position is the image peak inside a search window around the truth (+-15 m in
range, +-0.5 deg in angle: half the paper lattice's spacing, so a neighbour is never taken), refined
on the two marginal cuts through it: the range profile summed over +-0.25 deg of angle around the
peak column (parabolic interpolation of log power), and the angle profile summed over +-1 range
resolution cell around the peak row (power centroid within +-0.2 deg: the angle cut is a histogram of
per-CPI monopulse estimates, about 0.1 deg of scatter each at 20 dB SNR, so its single highest bin is
a noisy estimator).  A single-pixel cut is fragile: the projection scatters a target's range skirts
over neighbouring angle bins, and a one-column profile came out 0.7 m off on the tiny scene where the
marginal is within 0.1 m.  A target counts as detected when that peak lies inside the window (not on
its edge) and at least 10 dB over the image's median non-zero pixel.  The angle 3 dB width comes from
the angle cut; the image's own range-cut ISLR/PSLR/width are kept as ``image_*`` (its sidelobes are
cut by the projection threshold).

ISLR (paper eq. 27), PSLR, the range 3 dB width and the peak loss come from the dwell range profile
(:func:`dwell_profile_metrics`): main lobe between the first minima, window +-5 range resolution cells
(+-15 m for the paper: half the lattice spacing; an ideal sinc gives ISLR -10.7 dB there).
"""
from __future__ import annotations

import numpy as np

from ..dsp.geometry import C_MPS
from ..dsp.profile_rows import half_power_width_rows, peak3_rows, power_metrics_rows

RANGE_WINDOW_M = 15.0
ANGLE_WINDOW_DEG = 0.5
DETECT_DB = 10.0
ANGLE_CENTROID_DEG = 0.2


def resolved_flags(range_m, azimuth_deg, *, bandwidth_hz, wavelength_m, speed_mps, prf_hz, cpi,
                   depression_deg, beamwidth_two_way_deg, doppler_resolution_hz=None):
    """Whether each target has no other target inside its image resolution cell.

    Two targets share a cell when they are closer than one range resolution c/(2B) in range, closer
    in Doppler 2 v cos(theta) cos(phi)/lambda than the imaging's Doppler resolution, and closer in angle
    than ``beamwidth_two_way_deg`` (beyond it the beam separates them: the two-way width for a CPI,
    the width of the dwell window for ``dwell``, which integrates everything inside it).  The Doppler resolution is
    the imaging's own: PRF/CPI for ``cpi`` (the default; lambda (PRF/CPI) / (2 v |sin theta| cos phi)
    in angle, NOTES.md), 1/T_dwell for ``dwell`` (``doppler_resolution_hz``).  Mirror directions
    +-theta have the same Doppler (flight along +y) and share a cell when the beam cannot part them.
    """
    r = np.asarray(range_m)
    a = np.asarray(azimuth_deg)
    dr_res = C_MPS / (2.0 * bandwidth_hz)
    f_res = prf_hz / cpi if doppler_resolution_hz is None else doppler_resolution_hz
    f_d = 2.0 * speed_mps * np.cos(np.radians(a)) * np.cos(np.radians(depression_deg)) / wavelength_m
    close_r = np.abs(r[:, None] - r[None, :]) < dr_res
    close_f = np.abs(f_d[:, None] - f_d[None, :]) < f_res
    close_a = np.abs(a[:, None] - a[None, :]) < beamwidth_two_way_deg
    shared = close_r & close_f & close_a
    np.fill_diagonal(shared, False)
    return ~shared.any(axis=1)


def truth_at_t_ref(truth_xyz_m, position_ref_m):
    d = truth_xyz_m - position_ref_m[None, :]
    return np.linalg.norm(d, axis=1), np.degrees(np.arctan2(d[:, 0], d[:, 1]))


def _window_peaks(image, i0, i1, j0, j1):
    """For every target the first maximum of ``image[i0:i1, j0:j1]`` in row-major order (as
    ``np.argmax`` of the window), all windows at once: (row, column) within the window, the value, and
    whether the window is empty or holds no positive pixel."""
    n_t = len(i0)
    h, w = max(1, int((i1 - i0).max(initial=0))), max(1, int((j1 - j0).max(initial=0)))
    rows = i0[:, None] + np.arange(h)[None, :]                  # [T, h]
    cols = j0[:, None] + np.arange(w)[None, :]                  # [T, w]
    valid = (rows < i1[:, None])[:, :, None] & (cols < j1[:, None])[:, None, :]
    win = image[np.minimum(rows, image.shape[0] - 1)[:, :, None], np.minimum(cols, image.shape[1] - 1)[:, None, :]]
    win = np.where(valid, win.astype(np.float64), -np.inf)      # padding below every pixel: the same argmax
    flat = win.reshape(n_t, -1).argmax(axis=1)
    wi, wj = np.divmod(flat, w)
    peak = win.reshape(n_t, -1)[np.arange(n_t), flat]
    missing = ((i1 - i0) <= 0) | ((j1 - j0) <= 0) | ~(peak > 0)
    return wi, wj, peak, missing


def target_metrics(image, range_m, angle_deg, truth_xyz_m, amplitude, position_ref_m, *,
                   bandwidth_hz, range_window_m=RANGE_WINDOW_M, angle_window_deg=ANGLE_WINDOW_DEG):
    """One dict per target with the CONTRACT.md section 5 keys and the extra measures.

    The search windows' peaks and the marginal cuts through them are taken for every target at once
    (gathers of the image; the cuts summed in float64, so the same as one target at a time to rounding:
    ``tests/test_metrics_batched.py``), and so are the peak refinement and the profile measures
    (``dsp.profile_rows``: the scalar walks as searches over each target's row)."""
    r_true, az_true = truth_at_t_ref(truth_xyz_m, np.asarray(position_ref_m))
    dr = float(range_m[1] - range_m[0])
    da = float(angle_deg[1] - angle_deg[0])
    nonzero = image[image > 0]
    floor = float(np.median(nonzero)) if nonzero.size else 0.0
    res_cells = C_MPS / (2.0 * bandwidth_hz) / dr               # range resolution in image samples
    n_r, n_a = image.shape
    i0 = np.searchsorted(range_m, r_true - range_window_m)
    i1 = np.searchsorted(range_m, r_true + range_window_m)
    j0 = np.searchsorted(angle_deg, az_true - angle_window_deg)
    j1 = np.searchsorted(angle_deg, az_true + angle_window_deg)
    rows = []
    if len(r_true) == 0:
        return rows
    wi, wj, win_peak, missing = _window_peaks(image, i0, i1, j0, j1)
    ip, jp = i0 + wi, j0 + wj
    w_a = max(1, int(round(0.25 / da)))
    w_r = max(1, int(round(res_cells)))
    # marginal cuts of the targets whose strips lie inside the image, gathered together: the range cut
    # sums 2 w_a + 1 adjacent columns (contiguous, as one column strip does), the angle cut 2 w_r + 1 rows
    inner_a = ~missing & (jp - w_a >= 0) & (jp + w_a + 1 <= n_a)
    inner_r = ~missing & (ip - w_r >= 0) & (ip + w_r + 1 <= n_r)
    # (in float64: the sums of float32 pixels to its precision, whichever order they are added in; the
    # range cuts one column offset at a time, a third faster than one gather of every strip)
    strip_cols = jp[inner_a]
    range_cuts = image[:, strip_cols - w_a].astype(np.float64)
    for offset in range(1 - w_a, w_a + 1):
        range_cuts += image[:, strip_cols + offset]
    angle_cuts = image[(ip[inner_r][:, None] + np.arange(-w_r, w_r + 1)[None, :]), :].sum(axis=1, dtype=np.float64)
    rows = [{"id": k, "x_m": float(truth_xyz_m[k, 0]), "y_m": float(truth_xyz_m[k, 1]),
             "true_range_m": float(r_true[k]), "true_azimuth_deg": float(az_true[k])} for k in range(len(r_true))]
    tg = np.flatnonzero(~missing)                               # the targets with a peak in their window
    if len(tg) == 0:                                            # none: every target missed (no gathers)
        for row in rows:
            row.update(_missing())
        return rows
    # every measured target's two cuts as rows ([T', n_r] and [T', n_a]); a strip the image's edge clips
    # summed on its own
    range_rows = np.empty((len(tg), n_r))
    angle_rows = np.empty((len(tg), n_a))
    range_rows[inner_a[tg]] = range_cuts.T
    angle_rows[inner_r[tg]] = angle_cuts
    for t in np.flatnonzero(~inner_a[tg]).tolist():
        j = int(jp[tg[t]])
        range_rows[t] = image[:, max(0, j - w_a):j + w_a + 1].sum(axis=1, dtype=np.float64)
    for t in np.flatnonzero(~inner_r[tg]).tolist():
        i = int(ip[tg[t]])
        angle_rows[t] = image[max(0, i - w_r):i + w_r + 1, :].sum(axis=0, dtype=np.float64)
    on_edge = ((wi == 0) | (wi == i1 - i0 - 1) | (wj == 0) | (wj == j1 - j0 - 1))[tg]
    detected = ~on_edge & (win_peak[tg] > floor * 10 ** (DETECT_DB / 10))
    # the cuts' peaks inside the windows (the first maximum, as np.argmax), refined: the range peak by
    # the log-parabola fit, the angle peak by the power centroid within +-ANGLE_CENTROID_DEG
    i = _window_argmax(range_rows, i0[tg], i1[tg])
    j = _window_argmax(angle_rows, j0[tg], j1[tg])
    fi, _ = peak3_rows(range_rows, i, np.full(len(tg), n_r))
    fj = _centroid_rows(angle_rows, j, int(round(ANGLE_CENTROID_DEG / da)))
    meas_r = range_m[0] + fi * dr
    meas_a = angle_deg[0] + fj * da
    # the range profile's ISLR and PSLR over +-5 resolution cells around the peak (clipped to the image)
    half = int(5 * res_cells)
    lo = np.maximum(0, i - half)
    n_prof = np.minimum(n_r, i + half + 1) - lo
    # the measures take the amplitude |p| and square it, as profile_metrics(sqrt(cut)) did: sqrt then
    # square is not the identity in the last bit, and the same numbers are wanted
    amp = np.sqrt(np.take_along_axis(range_rows, np.minimum(lo[:, None] + np.arange(2 * half + 1), n_r - 1), axis=1))
    pslr, islr, _ = power_metrics_rows(amp * amp, n_prof, dr)
    range_width = half_power_width_rows(range_rows, i, np.full(len(tg), n_r), dr)
    angle_width = half_power_width_rows(angle_rows, j, np.full(len(tg), n_a), da)
    # the strongest pixel of the point's cell around the measured peak (the cuts' strips, inside the search
    # window): the cuts' peaks need not meet on one pixel of a projected image, whose cells are sparse (a
    # dwell image's point split over two adjacent rows and bins put image[i, j] 34 dB under it)
    peak_power = _cell_max(image, i, j, w_r, w_a, i0[tg], i1[tg], j0[tg], j1[tg])
    for t, k in enumerate(tg.tolist()):
        rows[k].update({"meas_range_m": float(meas_r[t]), "meas_azimuth_deg": float(meas_a[t]),
                        "range_error_m": float(meas_r[t]) - float(r_true[k]),
                        "azimuth_error_deg": float(meas_a[t]) - float(az_true[k]),
                        "islr_db": _f(islr[t]), "pslr_db": _f(pslr[t]), "detected": bool(detected[t]),
                        "range_width_3db_m": _f(range_width[t]), "angle_width_3db_deg": _f(angle_width[t]),
                        "peak_power": float(peak_power[t]), "amplitude": float(amplitude[k])})
    for k in np.flatnonzero(missing).tolist():
        rows[k].update(_missing())
    return rows


def _cell_max(image, i, j, w_r, w_a, i0, i1, j0, j1):
    """Per target the largest pixel of ``image`` within +-w_r rows of i and +-w_a columns of j, clipped to
    its window [i0, i1) x [j0, j1) (which holds i and j)."""
    rows = i[:, None] + np.arange(-w_r, w_r + 1)[None, :]
    cols = j[:, None] + np.arange(-w_a, w_a + 1)[None, :]
    ok = (((rows >= i0[:, None]) & (rows < i1[:, None]))[:, :, None]
          & ((cols >= j0[:, None]) & (cols < j1[:, None]))[:, None, :])
    vals = image[np.clip(rows, 0, image.shape[0] - 1)[:, :, None], np.clip(cols, 0, image.shape[1] - 1)[:, None, :]]
    return np.where(ok, vals.astype(np.float64), -np.inf).reshape(len(i), -1).max(axis=1)


def _window_argmax(cuts, lo, hi):
    """Per row of ``cuts`` the index of the first maximum of ``cuts[t, lo[t]:hi[t]]`` (non-empty windows)."""
    idx = lo[:, None] + np.arange(max(1, int((hi - lo).max(initial=0))))[None, :]
    win = np.take_along_axis(cuts, np.minimum(idx, cuts.shape[1] - 1), axis=1)
    return lo + np.where(idx < hi[:, None], win, -np.inf).argmax(axis=1)


def _centroid_rows(power, index, half_width):
    """Per row the power-weighted centroid of ``power[t, index-half_width : index+half_width+1]`` (clipped
    to the row; fractional index), ``index`` itself where that power sums to zero.  Not clipped to the
    search window: where a neighbour's energy pulls the centroid beyond it, the error says so."""
    cols = index[:, None] + np.arange(-half_width, half_width + 1)[None, :]
    inside = (cols >= 0) & (cols < power.shape[1])
    w = np.where(inside, np.take_along_axis(power, np.clip(cols, 0, power.shape[1] - 1), axis=1), 0.0)
    total = w.sum(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(total > 0, (w * cols).sum(axis=1) / total, index.astype(np.float64))


def _f(x):
    x = float(x)
    return x if np.isfinite(x) else None


def _missing():
    return {"meas_range_m": None, "meas_azimuth_deg": None, "range_error_m": None, "azimuth_error_deg": None,
            "islr_db": None, "pslr_db": None, "detected": False, "range_width_3db_m": None,
            "angle_width_3db_deg": None, "peak_power": 0.0}


def dwell_profile_metrics(spectra, truth_xyz_m, amplitude, sum_voltage, position_ref_m, *, range_window_m,
                          two_way_width_deg=None, oversample=8):
    """Range-profile quality of each target over its dwell, from the zoomed Doppler spectra.

    For every CPI in which the target lies inside the two-way 3 dB beam, the complex range profile of
    the Doppler cell holding the target (the strongest cell at its t_ref range) is taken over
    +-``range_window_m`` (the caller's +-5 range resolution cells, +-15 m for the paper), band-limited
    oversampled x8, and its power accumulated over the dwell.  The accumulated profile shows what the
    residual range migration did across the dwell, with its real sidelobes (the monopulse image only
    holds cells above the projection threshold, so its sidelobes are cut and an image-based ISLR reads
    better than an ideal sinc).  ISLR (eq. 27, main lobe between the first minima, ideal sinc -10.7 dB
    over +-5 cells), PSLR and the 3 dB width come from it; peak loss compares the strongest single-CPI
    sample with an ideally focused target (amplitude x two-way sum gain at that CPI's beam offset x the
    window's coherent gain).

    ``sum_voltage``: the antenna's one-way sum voltage against the beam offset (deg)
    (``dsp.antenna.sum_voltage_for``); where the cube does not fix it (None), the dwell is the CPIs
    within half of ``two_way_width_deg`` of the target and the peak loss is None (no gain to compare with).
    """
    from ..dsp.imaging import oversample_profiles

    r_ref, _ = truth_at_t_ref(truth_xyz_m, np.asarray(position_ref_m))
    s = spectra["sum_z"]
    range_m = spectra["range_m"]
    dr = float(range_m[1] - range_m[0])
    cg = float(spectra.attrs.get("coherent_gain", s.shape[1]))
    pos = np.asarray(spectra["cpi_position_m"])
    beam = np.asarray(spectra["cpi_beam_deg"])
    n_t = truth_xyz_m.shape[0]
    # every target's dwell at once: its beam offset in each CPI, the two-way gain, the CPIs inside the
    # two-way 3 dB beam ([target, cpi]); its search window and centre range bin
    d = truth_xyz_m[:, None, :] - pos[None, :, :]
    off = np.degrees(np.arctan2(d[..., 0], d[..., 1])) - beam[None, :]
    if sum_voltage is not None:
        sigma = np.asarray(sum_voltage(off), dtype=np.float64)
        in_dwell = sigma**4 >= 0.5
    else:                                       # the two-way 3 dB beam of the cube's width, no gain known
        sigma = np.full(off.shape, np.nan)
        in_dwell = np.abs(off) <= 0.5 * float(two_way_width_deg)
    i0 = np.searchsorted(range_m, r_ref - range_window_m)
    i1 = np.searchsorted(range_m, r_ref + range_window_m)
    ic = np.argmin(np.abs(range_m[None, :] - r_ref[:, None]), axis=1)
    usable = in_dwell.any(axis=1) & (i1 - i0 >= 4)
    # the (target, CPI) rows of the usable dwells, in target order: the strongest Doppler cell at the
    # target's range, its profile over the window, the peak sample near the centre
    t_row, c_row = np.nonzero(in_dwell & usable[:, None])
    z_row = np.argmax(np.abs(s[c_row, :, ic[t_row]]), axis=1) if len(t_row) else np.zeros(0, np.intp)
    near = ic[t_row][:, None] + np.arange(-1, 2)[None, :]
    near_ok = near >= 0
    meas_row = np.where(near_ok, np.abs(s[c_row[:, None], z_row[:, None], np.maximum(near, 0)]), -np.inf).max(axis=1)
    starts = np.searchsorted(t_row, np.arange(n_t))
    pslr, islr, width = np.full(n_t, np.nan), np.full(n_t, np.nan), np.full(n_t, np.nan)
    for n_win in np.unique((i1 - i0)[usable]):      # one batched oversampling per window length
        sel = np.flatnonzero(usable & (i1 - i0 == n_win))
        rows = np.flatnonzero(np.isin(t_row, sel))
        profiles = s[c_row[rows][:, None], z_row[rows][:, None], i0[t_row[rows]][:, None] + np.arange(n_win)[None, :]]
        power = np.abs(oversample_profiles(profiles, oversample)) ** 2
        acc = np.add.reduceat(power, np.searchsorted(t_row[rows], sel), axis=0)    # the dwell's sum, per target
        amp = np.sqrt(acc)                      # (|p| squared back, as above)
        pslr[sel], islr[sel], width[sel] = power_metrics_rows(amp * amp, np.full(len(sel), acc.shape[1]),
                                                              dr / oversample)
    # the peak loss: the CPI of the best measured-to-ideal ratio (the first maximum when one is positive,
    # else the dwell's last CPI), for every usable target at once
    meas = meas_row.astype(np.float64)
    ideal = amplitude[t_row] * sigma[t_row, c_row] ** 2 * cg
    loss_db = np.full(n_t, np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):     # a target of amplitude 0 has no loss: None
        best = _best_ratio_rows(meas / ideal, starts[usable])    # (the usable dwells tile the rows)
        loss_db[usable] = 20 * np.log10(np.maximum(meas[best], 1e-30) / ideal[best])
    out = []
    for k in range(n_t):
        if not usable[k]:
            out.append({"peak_loss_db": None, "islr_db": None, "pslr_db": None, "range_width_3db_m": None})
            continue
        out.append({"peak_loss_db": _f(loss_db[k]), "islr_db": _f(islr[k]), "pslr_db": _f(pslr[k]),
                    "range_width_3db_m": _f(width[k])})
    return out


def _best_ratio_rows(ratio, starts):
    """For the segments ``ratio[starts[s]:starts[s + 1]]`` (the last to the end), which tile ``ratio`` and
    are not empty, the index (into ``ratio``) of the CPI the peak loss is read at: the segment's first
    maximum when a ratio in it is positive, else its last element (the rule of the per-dwell code this
    replaced: ``tests/reference_metrics.py::best_ratio_index``)."""
    if len(starts) == 0:
        return np.zeros(0, np.intp)
    stops = np.append(starts[1:], len(ratio))
    seg = np.repeat(np.arange(len(starts)), stops - starts)
    top = np.maximum.reduceat(ratio, starts)
    hit = np.flatnonzero(ratio == top[seg])            # ascending: each segment's hits in order
    first = np.full(len(starts), -1)
    with_hit, at = np.unique(seg[hit], return_index=True)
    first[with_hit] = hit[at]                          # each segment's first hit
    return np.where(top > 0, first, stops - 1)


def summarize(rows) -> dict:
    out = _summary_of(rows)
    resolved = [r for r in rows if r.get("resolved")]
    if resolved:       # (every target resolved too: then the same as the whole's, but there, so that a sweep's
        sub = _summary_of(resolved)     # chart of the resolved errors had not dropped such points)
        out.update({"n_resolved": len(resolved), "detected_resolved": sub["detected"],
                    "max_abs_range_error_resolved_m": sub["max_abs_range_error_m"],
                    "median_abs_range_error_resolved_m": sub["median_abs_range_error_m"],
                    "rms_azimuth_error_resolved_deg": sub["rms_azimuth_error_deg"],
                    "max_abs_azimuth_error_resolved_deg": sub["max_abs_azimuth_error_deg"]})
    return out


def _stat(fn, values):
    """fn over the non-None values, None when there are none (no NaN-of-empty warnings)."""
    vals = np.array([v for v in values if v is not None], dtype=np.float64)
    return _f(fn(vals)) if vals.size else None


def _summary_of(rows) -> dict:
    det = [r for r in rows if r["detected"]]
    rng = [abs(r["range_error_m"]) for r in det]
    az = [abs(r["azimuth_error_deg"]) for r in det]
    rms = lambda v: np.sqrt(np.mean(v**2))  # noqa: E731
    return {
        "n_targets": len(rows), "detected": len(det),
        "max_abs_range_error_m": _stat(np.max, rng), "rms_range_error_m": _stat(rms, rng),
        "median_abs_range_error_m": _stat(np.median, rng),
        "max_abs_azimuth_error_deg": _stat(np.max, az), "rms_azimuth_error_deg": _stat(rms, az),
        "median_islr_db": _stat(np.median, [r["islr_db"] for r in det]),
        "median_pslr_db": _stat(np.median, [r["pslr_db"] for r in det]),
        "median_angle_width_3db_deg": _stat(np.median, [r["angle_width_3db_deg"] for r in det]),
        "median_peak_loss_db": _stat(np.median, [r.get("peak_loss_db") for r in rows]),
    }
