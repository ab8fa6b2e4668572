"""Per-target reference implementations of the image metrics, one target at a time as fwdlook computed
them before they were batched over targets (``forward.evaluate``): the oracle of ``test_metrics_batched``.
Nothing here is imported by fwdlook itself."""
from __future__ import annotations

import numpy as np

from fwdlook_cli.dsp.imaging import oversample_profiles
from fwdlook_cli.dsp.peaks import interpolate_peak
from fwdlook_cli.dsp.profile import profile_metrics
from fwdlook_cli.forward.evaluate import (ANGLE_CENTROID_DEG, ANGLE_WINDOW_DEG, DETECT_DB, RANGE_WINDOW_M, _missing,
                                          truth_at_t_ref)

C_MPS = 299_792_458.0


def _centroid(power, index, half_width):
    """Power-weighted centroid of ``power[index-half_width : index+half_width+1]`` (fractional index)."""
    lo, hi = max(0, index - half_width), min(len(power), index + half_width + 1)
    w = power[lo:hi]
    return float(np.sum(w * np.arange(lo, hi)) / np.sum(w)) if np.sum(w) > 0 else float(index)


def _width(profile_power, index, spacing):
    """3 dB width of a power cut around ``index`` by linear interpolation (NaN if not closed)."""
    p = profile_power / profile_power[index]
    left = index
    while left > 0 and p[left] > 0.5:
        left -= 1
    right = index
    while right < len(p) - 1 and p[right] > 0.5:
        right += 1
    if p[left] > 0.5 or p[right] > 0.5:
        return float("nan")
    xl = left + (0.5 - p[left]) / (p[left + 1] - p[left])
    xr = right - (0.5 - p[right]) / (p[right - 1] - p[right])
    return float((xr - xl) * spacing)


def best_ratio_index(meas, ideal) -> int:
    """The sequential rule ``if meas/ideal > best or best_meas == 0: take it``: the first maximum of
    meas/ideal when it is positive, else the last index."""
    ratio = np.asarray(meas, float) / np.asarray(ideal, float)
    if not np.any(ratio > 0):
        return len(ratio) - 1
    return int(np.argmax(ratio))


def _f(x):
    x = float(x)
    return x if np.isfinite(x) else None


def target_metrics_one_by_one(image, range_m, angle_deg, truth_xyz_m, amplitude, position_ref_m, *, bandwidth_hz):
    r_true, az_true = truth_at_t_ref(truth_xyz_m, np.asarray(position_ref_m))
    dr, da = float(range_m[1] - range_m[0]), float(angle_deg[1] - angle_deg[0])
    nonzero = image[image > 0]
    floor = float(np.median(nonzero)) if nonzero.size else 0.0
    res_cells = C_MPS / (2.0 * bandwidth_hz) / dr
    rows = []
    for k in range(len(r_true)):
        row = {"id": k, "x_m": float(truth_xyz_m[k, 0]), "y_m": float(truth_xyz_m[k, 1]),
               "true_range_m": float(r_true[k]), "true_azimuth_deg": float(az_true[k])}
        i0 = np.searchsorted(range_m, r_true[k] - RANGE_WINDOW_M)
        i1 = np.searchsorted(range_m, r_true[k] + RANGE_WINDOW_M)
        j0 = np.searchsorted(angle_deg, az_true[k] - ANGLE_WINDOW_DEG)
        j1 = np.searchsorted(angle_deg, az_true[k] + ANGLE_WINDOW_DEG)
        win = image[i0:i1, j0:j1]
        if win.size == 0 or not np.any(win > 0):
            rows.append({**row, **_missing()})
            continue
        wi, wj = np.unravel_index(np.argmax(win), win.shape)
        i, j = i0 + wi, j0 + wj
        on_edge = wi in (0, win.shape[0] - 1) or wj in (0, win.shape[1] - 1)
        detected = bool(not on_edge and win[wi, wj] > floor * 10 ** (DETECT_DB / 10))
        w_a, w_r = max(1, int(round(0.25 / da))), max(1, int(round(res_cells)))
        range_cut = image[:, max(0, j - w_a):j + w_a + 1].astype(np.float64).sum(axis=1)
        angle_cut = image[max(0, i - w_r):i + w_r + 1, :].astype(np.float64).sum(axis=0)
        i = i0 + int(np.argmax(range_cut[i0:i1]))
        j = j0 + int(np.argmax(angle_cut[j0:j1]))
        fi, _ = interpolate_peak(range_cut, i)
        fj = _centroid(angle_cut, j, int(round(ANGLE_CENTROID_DEG / da)))
        meas_r, meas_a = float(range_m[0] + fi * dr), float(angle_deg[0] + fj * da)
        lo, hi = max(0, i - int(5 * res_cells)), min(len(range_m), i + int(5 * res_cells) + 1)
        try:
            pm = profile_metrics(np.sqrt(range_cut[lo:hi]).astype(np.complex128), spacing=dr, oversample=1)
            islr, pslr = pm.islr_db, pm.pslr_db
        except ValueError:
            islr = pslr = float("nan")
        rows.append({**row, "meas_range_m": meas_r, "meas_azimuth_deg": meas_a,
                     "range_error_m": meas_r - float(r_true[k]), "azimuth_error_deg": meas_a - float(az_true[k]),
                     "islr_db": _f(islr), "pslr_db": _f(pslr), "detected": detected,
                     "range_width_3db_m": _f(_width(range_cut, i, dr)),
                     "angle_width_3db_deg": _f(_width(angle_cut, j, da)),
                     "peak_power": float(image[max(i0, i - w_r):min(i1, i + w_r + 1),
                                                max(j0, j - w_a):min(j1, j + w_a + 1)].max()),
                     "amplitude": float(amplitude[k])})
    return rows


def dwell_profile_metrics_one_by_one(spectra, truth_xyz_m, amplitude, slope_per_deg, beta_per_deg2, position_ref_m,
                                     oversample=8, range_window_m=RANGE_WINDOW_M):
    r_ref, _ = truth_at_t_ref(truth_xyz_m, np.asarray(position_ref_m))
    s, range_m = spectra["sum_z"], spectra["range_m"]
    dr = float(range_m[1] - range_m[0])
    cg = float(spectra.attrs.get("coherent_gain", s.shape[1]))
    pos, beam = spectra["cpi_position_m"], spectra["cpi_beam_deg"]
    out = []
    for k in range(truth_xyz_m.shape[0]):
        d = truth_xyz_m[k][None, :] - pos
        off = np.degrees(np.arctan2(d[:, 0], d[:, 1])) - beam
        sigma = np.exp(-beta_per_deg2 * off**2) * np.cosh(slope_per_deg * off)
        dwell = np.nonzero(sigma**4 >= 0.5)[0]
        i0 = int(np.searchsorted(range_m, r_ref[k] - range_window_m))
        i1 = int(np.searchsorted(range_m, r_ref[k] + range_window_m))
        ic = int(np.argmin(np.abs(range_m - r_ref[k])))
        if len(dwell) == 0 or i1 - i0 < 4:
            out.append({"peak_loss_db": None, "islr_db": None, "pslr_db": None, "range_width_3db_m": None})
            continue
        z = np.argmax(np.abs(s[dwell, :, ic]), axis=1)
        acc = np.sum(np.abs(oversample_profiles(s[dwell, z, i0:i1], oversample)) ** 2, axis=0)
        meas = np.abs(s[dwell, z, max(0, ic - 1):ic + 2]).max(axis=1).astype(np.float64)
        ideal = amplitude[k] * sigma[dwell] ** 2 * cg
        j = best_ratio_index(meas, ideal)
        try:
            pm = profile_metrics(np.sqrt(acc).astype(np.complex128), spacing=dr / oversample, oversample=1)
            islr, pslr, width = pm.islr_db, pm.pslr_db, pm.width_3db
        except ValueError:
            islr = pslr = width = float("nan")
        out.append({"peak_loss_db": float(20 * np.log10(max(float(meas[j]), 1e-30) / float(ideal[j]))),
                    "islr_db": _f(islr), "pslr_db": _f(pslr), "range_width_3db_m": _f(width)})
    return out
