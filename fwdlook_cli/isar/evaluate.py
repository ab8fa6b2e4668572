"""ISAR metrics: migration span, integration gain, peak location, ISLR/PSLR of the range and Doppler cuts."""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from ..dsp.geometry import C_MPS
from ..io.stagefile import StageData
from .geometry import _truth_line_model, _truth_positions_at
from .stages import _doppler_line, _model_from
from .track import migration_span_cells, peak_track
from .geometry import LineModel
from .. import __version__
from ..scenario.isar import scatterer_ranges_m
from .span import span_units, track_gate_samples

ANALYSIS_WINDOW_CELLS = 16.0   # +- cells of the ISLR / PSLR window (range and Doppler)


def _finite(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _jsonable(obj):
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    return _finite(obj)


def _ideal_peak(cube, n_pulses):
    """N a |p(0)| of the reference scatterer (closed form), or N x median raw per-pulse peak."""
    from ..dsp.pulse import WEIGHTINGS, CompressedPulse

    r = cube.radar
    if cube.truth:
        p0, kind = 1.0, "closed_form N a |p(0)|"
        weighting = str(r.get("range_weighting", "none"))
        if "pulse_width_s" in r and weighting in WEIGHTINGS:
            p0 = float(abs(CompressedPulse(r["bandwidth_hz"], float(r["pulse_width_s"]), r["fs_hz"], weighting)(0.0)))
        elif weighting not in WEIGHTINGS:      # another recorder's taper: its loss |p(0)| is not known here
            kind = f"closed_form N a (|p(0)| = 1: range_weighting {weighting!r} unknown)"
        return n_pulses * float(cube.truth["amplitude"][0]) * p0, kind
    _, peak = peak_track(cube.sum)
    return n_pulses * float(np.sqrt(np.median(peak))), "N x median per-pulse peak amplitude (no truth)"


@dataclass(frozen=True)
class _Cut:
    peak_index: float   # fractional sample of the local peak (band-limited, log-parabola)
    peak_power: float
    width_3db: float    # shape metrics from profile_metrics (module docstring, Metrics)
    pslr_db: float
    islr_db: float


RESIDUAL_GAIN_DB = -1.0    # with a span over a cell, the integration gain below which a correction is said not to hold


def _say_residual_migration(correction: str, summary: dict) -> None:
    """One warning where the corrected echo still migrates over more than a range resolution cell and its
    integration gain is more than 1 dB under the ideal: the correction does not hold for this geometry
    (keystone2_n0 beyond about 15 deg of theta0, a wrong n0_pulses, keystone1's curvature), which had
    ended with exit 0 and nothing said (an independent review: -17.1 dB of integration gain at 30 deg,
    the target not detected)."""
    span, gain = summary.get("migration_span_cells"), summary.get("integration_gain_db")
    # both: the span alone reads over a cell from noise (1.7 cells at 10 dB per sample, the gain -0.2 dB)
    if span is None or not span > 1.0 or (gain is not None and gain > RESIDUAL_GAIN_DB):
        return
    n0 = ""
    true, used = summary.get("n0_true_pulses"), summary.get("n0_used_pulses")
    if correction.startswith("keystone2_n0") and true is not None and used is not None and abs(used - true) > 1.0:
        n0 = f"; n0 used {used:.0f} pulses, the truth's {true:.0f}"
    logging.getLogger(__name__).warning(
        f"processing.correction {correction}: the corrected echo still migrates over {span:.2f} range resolution "
        f"cells" + (f" (integration gain {gain:+.1f} dB against the ideal)" if gain is not None else "") + n0
        + ": this correction does not hold here (README, ISAR, 'Limits of the method'); compare the others "
        "(a sweep over processing.correction)")


def _cut_metrics(line, idx, spacing, factor=16):
    """Local peak of a band-limited line near sample ``idx``, with its width, PSLR and ISLR.

    The position and the peak come from the exact band-limited interpolant of the whole line,
    searched within +-1.5 samples of ``idx`` (so a stronger scatterer elsewhere on the line is not
    taken); the shape metrics from :func:`~fwdlook_cli.dsp.profile.profile_metrics` on the whole line when
    this peak is the line's maximum, else on the +-32 samples around it.
    """
    from ..dsp.peaks import interpolate_peak, oversample_profile
    from ..dsp.profile import profile_metrics

    line = np.asarray(line)
    n = len(line)
    if not np.any(line):                   # nothing returned here (an all-zero echo): nothing to measure
        return _Cut(float(idx), 0.0, math.nan, math.nan, math.nan)
    fine = np.abs(oversample_profile(line, factor)[: (n - 1) * factor + 1]) ** 2
    lo = max(1, int((idx - 1.5) * factor))
    hi = min(len(fine) - 1, int((idx + 1.5) * factor) + 1)
    k = lo + int(np.argmax(fine[lo:hi]))
    pos, peak = interpolate_peak(fine, k)
    if abs(int(np.argmax(np.abs(line))) - idx) <= 1:
        pm = profile_metrics(line, spacing=spacing, window_cells=ANALYSIS_WINDOW_CELLS)
    else:
        a = max(0, idx - 2 * int(ANALYSIS_WINDOW_CELLS))
        pm = profile_metrics(line[a:idx + 2 * int(ANALYSIS_WINDOW_CELLS) + 1], spacing=spacing,
                             window_cells=ANALYSIS_WINDOW_CELLS)
    return _Cut(pos / factor, peak, pm.width_3db, pm.pslr_db, pm.islr_db)


def _gain_db(peak_power, ideal_amplitude):
    """The image peak against the ideally integrated one; None where either is missing or zero (nothing
    returned; a truth amplitude of 0: a recorded cube's surveyed point of unknown strength)."""
    if peak_power is None or not peak_power > 0 or not ideal_amplitude > 0:
        return None
    return 10.0 * math.log10(peak_power / ideal_amplitude**2)


def _measure_peak(image, i, j, dr_m, df_hz):
    """Range cut (column j) and Doppler cut (row i) through the local peak at (i, j); the peak power
    assumes a separable peak: P_range P_doppler / P(i, j)."""
    rm = _cut_metrics(image[:, j], i, dr_m)
    am = _cut_metrics(_doppler_line(image[i, :]), j, df_hz)
    centre = float(abs(image[i, j]) ** 2)
    peak = rm.peak_power * am.peak_power / centre if centre > 0 else 0.0
    return rm, am, peak


def isar_outputs(final: StageData, cube, processing: dict):
    """The image StageData (for image.h5) and the metrics dict (CONTRACT section 5, ISAR keys).

    Target keys: ``true_range_m`` / ``meas_range_m`` are slant ranges at ``t_ref_s`` (the keystone
    centre).  A single-channel ISAR image measures no bearing, so ``true_azimuth_deg`` /
    ``meas_azimuth_deg`` hold the angle ``atan(cross_range / range)`` of the scatterer's cross-range
    offset from the reference scatterer's line of sight (0 for the reference itself); the cross-range
    and Doppler measures are in ``*_cross_range_m`` and ``meas_doppler_hz``, and the absolute
    line-of-sight azimuth ``atan2(x, y)`` at t_ref in ``los_azimuth_deg``.
    """
    img = final["image"]
    power = np.abs(img) ** 2
    rng = np.asarray(final["range_m"], dtype=np.float64)
    dop = np.asarray(final["doppler_hz"], dtype=np.float64)
    t = np.asarray(final["slow_time_s"], dtype=np.float64)
    fc, prf = float(cube.radar["fc_hz"]), float(cube.radar["prf_hz"])
    lam = C_MPS / fc
    n = len(t)
    dr, df = float(rng[1] - rng[0]), float(dop[1] - dop[0])
    t_ref = float(final.attrs["t_ref_s"])
    correction = final.attrs["correction"]
    m = None
    if "azimuth_model_r0_m" in final.attrs:
        m = LineModel(*(float(final.attrs[f"azimuth_model_{k}"]) for k in ("r0_m", "rdot_mps", "v2_m2ps2",
                                                                             "t_mid_s")))
    elif "model_r0_m" in final.attrs:
        m = _model_from("estimate", final.attrs)
    omega = m.omega_rps if m is not None else math.nan
    xscale = -lam / (2.0 * omega) if omega > 0 else math.nan          # metres of cross-range per Hz

    ideal, ideal_kind = _ideal_peak(cube, n)
    median_power = float(np.median(power))
    res_r = C_MPS / (2.0 * float(cube.radar["bandwidth_hz"]))          # range resolution
    res_f = prf / n                                                    # Doppler resolution (= bin)

    def gated_peak(r_centre, r_half, f_centre, f_half):
        ri = np.nonzero(np.abs(rng - r_centre) <= r_half)[0]
        fj = np.nonzero(np.abs(dop - f_centre) <= f_half)[0]
        if not (len(ri) and len(fj)):
            return None
        sub = power[np.ix_(ri, fj)]
        a, b = np.unravel_index(int(np.argmax(sub)), sub.shape)
        on_edge = (a in (0, sub.shape[0] - 1) and len(ri) < len(rng)) or \
                  (b in (0, sub.shape[1] - 1) and len(fj) < len(dop))
        return int(ri[a]), int(fj[b]), on_edge

    rows = []
    truth_model = _truth_line_model(cube)
    gate = None
    if cube.truth and truth_model is not None:
        pos_ref, vel = _truth_positions_at(cube, t_ref)
        pos_mid, _ = _truth_positions_at(cube, truth_model.t_mid_s)
        raw_r = scatterer_ranges_m(pos_ref - vel * t_ref, vel[0], t)
        u = pos_mid[0] / np.linalg.norm(pos_mid[0])
        du = (vel[0] - u * (u @ vel[0])) / np.linalg.norm(pos_mid[0])  # d(LOS unit vector)/dt at t_mid
        e_perp = du / np.linalg.norm(du) if np.linalg.norm(du) > 0 else np.zeros(3)
        rdot_all = (pos_mid @ vel[0]) / np.linalg.norm(pos_mid, axis=1)
        chirp_hz = abs(2.0 * (truth_model.v2_m2ps2 - truth_model.rdot_mps**2) / (lam * truth_model.r0_m)) * n / prf
        for k in range(len(cube.truth["x_m"])):
            true_r = float(np.linalg.norm(pos_ref[k]))
            true_x = float((pos_mid[k] - pos_mid[0]) @ e_perp)
            if m is not None:
                pred_f = -2.0 * (rdot_all[k] - m.rdot_mps) / lam
            else:
                pred_f = float(np.mod(-2.0 * rdot_all[k] / lam + prf / 2, prf) - prf / 2)
            wide_f = 3.0 * res_f + (0.0 if m is not None else 0.5 * chirp_hz)
            if k == 0:  # the predicted track's actual extent after this correction (isar_span.py)
                gate = track_gate_samples(raw_r[k], t, t_ref, correction, range0_m=float(rng[0]), sample_m=dr,
                                          margin_m=3.0 * res_r)
            row = {"id": k, "x_m": float(pos_ref[k, 0]), "y_m": float(pos_ref[k, 1]),
                   "z_m": float(pos_ref[k, 2]), "true_range_m": true_r,
                   "true_azimuth_deg": math.degrees(math.atan2(true_x, true_r)),
                   "true_cross_range_m": true_x,
                   "los_azimuth_deg": math.degrees(math.atan2(pos_ref[k, 0], pos_ref[k, 1])),
                   "detected": False}
            # position and shape: the peak within +-3 resolution cells of the prediction
            tight = gated_peak(true_r, 3.0 * res_r, pred_f, wide_f)
            if tight is not None:
                i, j, on_edge = tight
                rm, am, peak = _measure_peak(img, i, j, dr, df)
                meas_r = float(rng[0] + rm.peak_index * dr)
                meas_f = float(dop[0] + am.peak_index * df)
                meas_x = meas_f * xscale
                row.update({
                    "meas_range_m": meas_r,
                    "meas_azimuth_deg": math.degrees(math.atan2(meas_x, meas_r)),
                    "range_error_m": meas_r - true_r,
                    "azimuth_error_deg": math.degrees(math.atan2(meas_x, meas_r))
                    - math.degrees(math.atan2(true_x, true_r)),
                    "meas_doppler_hz": meas_f, "meas_cross_range_m": meas_x,
                    "cross_range_error_m": meas_x - true_x,
                    "islr_db": rm.islr_db, "pslr_db": rm.pslr_db,
                    "range_width_3db_m": rm.width_3db,
                    "cross_range_width_3db_m": am.width_3db * abs(xscale),
                    "doppler_width_3db_hz": am.width_3db,
                    "azimuth_islr_db": am.islr_db, "azimuth_pslr_db": am.pslr_db,
                    "peak_power": peak,
                    "detected": bool(peak >= 10.0 * median_power and not on_edge),
                })
            if k == 0:  # integration gain: the image maximum wherever the migration smeared it
                lo_m, hi_m = (float(rng[0]) + g * dr for g in gate)
                at = gated_peak(0.5 * (lo_m + hi_m), 0.5 * (hi_m - lo_m), pred_f, wide_f)
                peak = _measure_peak(img, at[0], at[1], dr, df)[2] if at is not None else None
                row["integration_gain_db"] = _gain_db(peak, ideal)   # (None: the track off the image)
            # a scatterer whose Doppler relative to the compensated reference lies beyond +-PRF/2 is imaged
            # folded, at another cross-range: it is searched at its own Doppler and counted as not detected
            row["doppler_folded"] = bool(m is not None and abs(pred_f) > prf / 2.0)
            rows.append(row)
        folded = [r["id"] for r in rows if r["doppler_folded"]]
        if folded:
            logging.getLogger(__name__).warning(
                f"truth scatterers {', '.join(map(str, folded))}: Doppler beyond +-PRF/2 = +-{prf / 2:g} Hz from the "
                f"reference's: imaged folded, at another cross-range, and counted as not detected (a higher PRF)")
        ref_row = rows[0]
    else:
        i, j = np.unravel_index(int(np.argmax(power)), power.shape)
        rm, am, peak = _measure_peak(img, int(i), int(j), dr, df)
        ref_row = {"peak_power": peak, "range_width_3db_m": rm.width_3db,
                   "cross_range_width_3db_m": am.width_3db * abs(xscale), "islr_db": rm.islr_db,
                   "pslr_db": rm.pslr_db, "azimuth_islr_db": am.islr_db, "azimuth_pslr_db": am.pslr_db,
                   "integration_gain_db": _gain_db(peak, ideal)}
    span, _, _ = migration_span_cells(final["echo_rc"], gate=gate)      # in range samples c / (2 fs)
    spans = span_units(span, fs_hz=float(cube.radar["fs_hz"]), bandwidth_hz=float(cube.radar["bandwidth_hz"]))

    found = [r for r in rows if "meas_range_m" in r]
    rerr = np.array([r["range_error_m"] for r in found]) if found else np.array([])
    aerr = np.array([r["azimuth_error_deg"] for r in found]) if found else np.array([])
    islr = [r["islr_db"] for r in found if r["islr_db"] is not None and math.isfinite(r["islr_db"])]
    n0_true = truth_model.n0_pulses(prf) if truth_model is not None else None
    summary = {
        "n_targets": len(rows),
        "detected": int(sum(bool(r["detected"]) for r in rows)),
        "max_abs_range_error_m": float(np.max(np.abs(rerr))) if rerr.size else None,
        "rms_range_error_m": float(np.sqrt(np.mean(rerr**2))) if rerr.size else None,
        "max_abs_azimuth_error_deg": float(np.max(np.abs(aerr))) if aerr.size else None,
        "median_islr_db": float(np.median(islr)) if islr else None,
        "migration_span_cells": spans["migration_span_resolution_cells"],   # resolution cells c / (2 B)
        **spans,
        "integration_gain_db": ref_row.get("integration_gain_db"),
        "integration_gain_reference": ideal_kind,
        "range_width_3db_m": ref_row.get("range_width_3db_m"),
        "cross_range_width_3db_m": ref_row.get("cross_range_width_3db_m"),
        "islr_db": ref_row.get("islr_db"), "pslr_db": ref_row.get("pslr_db"),
        "azimuth_islr_db": ref_row.get("azimuth_islr_db"), "azimuth_pslr_db": ref_row.get("azimuth_pslr_db"),
        "n0_true_pulses": n0_true,
        "n0_used_pulses": float(final.attrs.get("n0_used_pulses", 0.0)),
        "n0_est_pulses": float(final.attrs["n0_est_pulses"]) if correction == "keystone2_n0_est" else None,
    }
    _say_residual_migration(correction, summary)
    params = {k: processing.get(k) for k in ("correction", "keystone", "ambiguity", "n0_pulses",
                                             "azimuth_phase", "n0_search")}
    params.update({"ambiguity_numbers": sorted(set(int(a) for a in final["ambiguity_number"]))
                   if "ambiguity_number" in final else [0],
                   "range_model": m.as_dict() if m is not None else None,
                   "range_model_source": "estimate" if "model_r0_m" in final.attrs else "truth"})
    metrics = {
        "fwdlook_version": __version__,
        "scenario": str(cube.attrs.get("scenario_name", "isar")),
        "method": correction,
        "params": params,
        "t_ref_s": t_ref,
        "targets": rows,
        "summary": summary,
    }

    image = StageData()
    image.add("range_m", rng, ("range_m",), "m", f"slant range at t_ref = {t_ref:.4f} s")
    image.add("doppler_hz", dop, ("doppler_hz",), "Hz", "Doppler relative to the range model")
    image.add("cross_range_m", dop * xscale, ("doppler_hz",), "m",
              "cross-range -lambda f / (2 omega) of each Doppler bin")
    image.add("image", power.astype(np.float32), ("range_m", "doppler_hz"), "1", "ISAR image power")
    image.attrs.update(format="fwdlook-image", method=correction, t_ref_s=t_ref, kind="isar")
    return image, _jsonable(metrics)
