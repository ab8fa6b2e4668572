"""``fwdlook plan``: the migration budget of a scene, and the corrections it therefore needs.

Each effect is computed from the motion (INS track), the scan and the radar, at the scene's
reference range, and compared with what it must stay within (CONTRACT.md section 6):

* range walk: the closing speed v . u x (the longest time a target is seen from t_ref), against half a
  range cell: above it, a range-walk correction is needed; u = (sin theta cos phi, cos theta cos phi,
  -sin phi) the line of sight to the ground point at depression phi, v the INS velocity with its
  vertical part (eq. 16's v cos(theta) cos(phi) where the platform flies level along +y);
* range curvature: |R''| T^2 / 2 over the same time, R'' = (|v|^2 - (v . u)^2) / R - a . u (the
  geometry's own curvature and the acceleration along the line of sight; eq. 10-12's a_y cos(phi) for a
  level flight on boresight), against half a range cell;
* Doppler-ambiguity-number spread: F = <f_dc / PRF> (eq. 17) of every beam direction over the whole
  scan, with the speed at that time; a spread above 0 means one fixed F is wrong somewhere and the
  traditional keystone leaves a residual walk of (F error) c PRF / (2 f_c) (eq. 19);
* decimation: the same spread at PRF/Q and the residual walk it leaves (eq. 20) for each Q that
  divides the pulse count; the smallest Q whose residual stays under half a range cell;
* Doppler-centroid drift: 2 (v(t) - v(0)) . u / lambda across the scan (eq. 25's 2 a t cos(theta) cos(phi)
  / lambda for a level flight), against one Doppler cell of a CPI (PRF / CPI): above it the CPI band must
  follow v_c.

An independent review (forty-ninth round) found the plan modelling the forward motion only: a climbing
or descending platform (a_z = -80 m/s^2, 500 m up) was planned as `traditional` with no drift, and
measured 5.1 m off (`tracking` 0.06 m); a +-45 deg scan's geometric curvature (14 m) was planned as 0.

The recommendation (what ``processing.method: auto`` uses) is the cheapest method whose residual is
under half a range cell: none, then traditional, then decimation with that Q, then tracking.
"""
from __future__ import annotations

import json

import numpy as np

from ..dsp.geometry import C_MPS, ambiguity_number
from ..dsp.imaging import auto_range_oversample
from ..io.navigation import navigation_of, with_navigation
from .motion import (auto_doppler_cells, boresight_doppler_spread_hz, depression_reference_error_m,
                     doppler_band_depressions, t_ref_seconds, widest_cpi_band_hz)

DEPRESSION_SAMPLES = 257      # slant ranges across the window at which one reference depression is judged


def one_depression_budget(height_m: float, near_m: float, far_m: float, reference_range_m: float, velocity_mps,
                          fc_hz: float, lever_s: float, rate_hz: float | None, half_cell_m: float,
                          rounded: bool = False) -> dict:
    """What one reference depression (at ``reference_range_m``) leaves across the range window near..far
    (``motion.depression_reference_error_m``; ``rate_hz`` None for a shift by the reference's range
    history, else the keystone's rate): the largest range error, and the span of slant ranges about the
    reference range where it stays within ``half_cell_m``."""
    r = np.linspace(float(near_m), float(far_m), DEPRESSION_SAMPLES)
    err = depression_reference_error_m(height_m, r, reference_range_m, velocity_mps, fc_hz, lever_s, rate_hz,
                                       rounded=rounded)
    i = int(np.argmin(np.abs(r - reference_range_m)))
    bad = err > half_cell_m
    below, above = np.flatnonzero(bad[:i]), np.flatnonzero(bad[i:])
    lo = float(r[below[-1] + 1]) if len(below) else float(r[0])
    hi = float(r[i + above[0] - 1]) if len(above) else float(r[-1])
    return {"error_m": float(err.max()), "span_m": [lo, hi]}


def plan_geometry(slow_time_s, position_m, velocity_mps, scan_deg, *, fc_hz, prf_hz, fs_hz,
                  beamwidth_deg, reference_range_m, t_ref_s, cpi, q_candidates=None, range_extent_m=None,
                  bandwidth_hz=None) -> dict:
    t = np.asarray(slow_time_s, dtype=np.float64)
    half_cell_m = C_MPS / (2.0 * fs_hz) / 2.0
    height = float(position_m[0, 2])
    phi = np.arcsin(np.clip(height / reference_range_m, -1, 1))
    # each beam direction theta(t) is seen around time t: its walk acts for |t - t_ref| + half a dwell
    dwell_s = beamwidth_deg / max(abs(float(np.median(np.diff(scan_deg)))) * prf_hz, 1e-12)
    lever_s = np.abs(t - t_ref_s) + dwell_s / 2
    th = np.radians(scan_deg)
    vel = np.asarray(velocity_mps, dtype=np.float64)
    los = np.stack([np.sin(th) * np.cos(phi), np.cos(th) * np.cos(phi), np.full_like(th, -np.sin(phi))], axis=1)
    radial_speed = np.sum(vel * los, axis=1)                               # v . u, the closing speed
    walk_m = float(np.max(np.abs(radial_speed) * lever_s))
    # bulk's shift follows the INS motion along +y at the reference depression (motion.bulk_range_history_m):
    # what it leaves of each direction's walk (the scan's cos theta, a heading off +y, a climb)
    bulk_walk_m = float(np.max(np.abs(radial_speed - vel[:, 1] * np.cos(phi)) * lever_s))
    accel = np.polyfit(t, vel, 1)[0] if len(t) > 2 else np.zeros(3)      # [3]: the INS track's mean acceleration
    d2r = (np.sum(vel**2, axis=1) - radial_speed**2) / reference_range_m - los @ accel      # R'' (module doc)
    curvature_m = float(np.max(0.5 * np.abs(d2r) * lever_s**2))
    f_dc = 2.0 * radial_speed * fc_hz / C_MPS                              # eq. (16), (25)
    m_ref = int(np.clip(np.rint((t_ref_s - t[0]) * prf_hz), 0, len(t) - 1))
    boresight = np.array([0.0, np.cos(phi), -np.sin(phi)])
    f_dc0 = 2.0 * float(vel[m_ref] @ boresight) * fc_hz / C_MPS            # boresight at t_ref
    n = len(t)
    # (Q = 1 always: a cube of under 8 pulses had no candidate and the plan stopped with an IndexError)
    q_candidates = q_candidates or ([1] + [q for q in range(2, n + 1) if n % q == 0 and n // q >= 8])[:40]
    near, far = range_extent_m if range_extent_m is not None else (reference_range_m, reference_range_m)
    # one reference depression across the window (steep depression: motion.depression_reference_error_m)
    lever_max = float(np.max(lever_s))

    def one_depression(rate_hz, rounded=False):
        return one_depression_budget(height, near, far, reference_range_m, vel[m_ref], fc_hz, lever_max, rate_hz,
                                     half_cell_m, rounded)

    rows = []
    for q in q_candidates:
        prf_q = prf_hz / q
        err = np.abs(ambiguity_number(f_dc, prf_q) - ambiguity_number(f_dc0, prf_q))
        resid = float(np.max(err * C_MPS * prf_q / (2.0 * fc_hz) * lever_s))       # eq. (19)-(20)
        rows.append({"q": q, "ambiguity_spread": int(err.max()), "residual_walk_m": resid,
                     "one_depression": one_depression(prf_q, rounded=True)})    # one whole F (czt, dft)
    drift_hz = float(np.ptp(f_dc - 2.0 * (los @ vel[0]) * fc_hz / C_MPS))     # what the speed change adds
    doppler_cell_hz = prf_hz / cpi
    range_spread_hz = boresight_doppler_spread_hz(height, float(near), float(far), velocity_mps[m_ref], fc_hz)
    # the widest CPI Doppler band of the scan, as the Doppler stage computes it (eq. 25-26; over the
    # window's depressions where they differ by more than a cell), and processing.n_doppler: auto for it
    band_depressions = doppler_band_depressions(height, float(near), float(far), float(np.degrees(phi)),
                                                velocity_mps[m_ref], fc_hz, prf_hz, cpi)
    widest_hz = widest_cpi_band_hz({"slow_time_s": t, "scan_angle_deg": np.asarray(scan_deg, dtype=np.float64),
                                    "velocity_mps": np.asarray(velocity_mps, dtype=np.float64)},
                                   cpi=cpi, follow_speed=True, depression_deg=band_depressions, fc_hz=fc_hz,
                                   beamwidth_deg=beamwidth_deg, prf_hz=prf_hz)
    traditional = rows[0]
    deci_ok = [r for r in rows[1:] if r["residual_walk_m"] < half_cell_m
               and r["one_depression"]["error_m"] < half_cell_m]
    if walk_m < half_cell_m:
        method, q_best = "none", 1
    elif traditional["residual_walk_m"] < half_cell_m and traditional["one_depression"]["error_m"] < half_cell_m:
        method, q_best = "traditional", 1
    elif deci_ok:
        method, q_best = "decimation", deci_ok[0]["q"]
    else:
        method, q_best = "tracking", 1
    return {
        "half_range_cell_m": half_cell_m, "reference_range_m": float(reference_range_m),
        "depression_deg": float(np.degrees(phi)), "dwell_s": float(dwell_s), "t_ref_s": float(t_ref_s),
        "range_walk_m": walk_m, "needs_walk_correction": walk_m >= half_cell_m, "lever_max_s": lever_max,
        "bulk_residual_walk_m": bulk_walk_m,
        "range_curvature_m": curvature_m, "needs_curvature": curvature_m >= half_cell_m,
        "forward_accel_mps2": float(accel[1]), "accel_mps2": [float(a) for a in accel],
        "ambiguity_number_boresight": int(ambiguity_number(f_dc0, prf_hz)),
        "ambiguity_number_range": [int(ambiguity_number(f_dc, prf_hz).min()),
                                   int(ambiguity_number(f_dc, prf_hz).max())],
        "ambiguity_spread": traditional["ambiguity_spread"],
        "traditional_residual_walk_m": traditional["residual_walk_m"],
        "decimation": rows,
        "doppler_centroid_drift_hz": drift_hz, "doppler_cell_hz": doppler_cell_hz,
        "needs_doppler_centroid": abs(drift_hz) >= doppler_cell_hz / 2,
        "doppler_range_spread_hz": range_spread_hz, "range_extent_m": [float(near), float(far)],
        "band_over_depressions": range_spread_hz > doppler_cell_hz,
        # what one reference depression leaves: tracking's keystone (about the reference's Doppler),
        # traditional's (one whole ambiguity number at the PRF), a shift by the reference's range history
        # (bulk, beam); decimation's at PRF / Q in its rows
        "one_depression": {"keystone": one_depression(prf_hz), "traditional": traditional["one_depression"],
                           "shift": one_depression(None)},
        "doppler_band_widest_hz": widest_hz, "n_doppler_auto": auto_doppler_cells(widest_hz, cpi=cpi, prf_hz=prf_hz),
        # processing.range_oversample: auto, the power image's Nyquist rate (dsp/imaging.py)
        "range_oversample_auto": (None if bandwidth_hz is None
                                  else auto_range_oversample(float(bandwidth_hz), float(fs_hz))),
        "processing": {"method": method, "q": q_best if method == "decimation" else 1,
                       "range_curvature": curvature_m >= half_cell_m,
                       "doppler_centroid": abs(drift_hz) >= doppler_cell_hz / 2},
    }


def plan_for_cube(cube, proc: dict, q_candidates=None) -> dict:
    cube = with_navigation(cube, *navigation_of(proc))
    t_ref_s = t_ref_seconds(cube.slow_time_s, proc["t_ref"])
    out = plan_geometry(cube.slow_time_s, cube.position_m, cube.velocity_mps, cube.scan_angle_deg,
                        fc_hz=cube.radar["fc_hz"], prf_hz=cube.radar["prf_hz"], fs_hz=cube.radar["fs_hz"],
                        bandwidth_hz=cube.radar["bandwidth_hz"],
                        beamwidth_deg=cube.radar["beamwidth_3db_deg"],
                        reference_range_m=float(0.5 * (cube.range_m[0] + cube.range_m[-1])), t_ref_s=t_ref_s,
                        cpi=proc["cpi"], range_extent_m=(float(cube.range_m[0]), float(cube.range_m[-1])),
                        q_candidates=q_candidates)
    return out


def _method_budget(plan: dict, proc: dict) -> tuple:
    """(Q, the residual walk the method's budget leaves or None, its one-depression entry or None) of the
    method that runs (:func:`method_budget_warnings`, :func:`method_range_error_m`)."""
    method = proc["method"]
    q = int(proc.get("q", 1)) if method == "decimation" else 1
    row = next(r for r in plan["decimation"] if r["q"] == q)
    residual = {"none": plan["range_walk_m"], "bulk": plan["bulk_residual_walk_m"], "traditional": row["residual_walk_m"],
                "decimation": row["residual_walk_m"]}.get(method)
    dep = None if method == "none" else {"bulk": plan["one_depression"]["shift"], "beam": plan["one_depression"]["shift"],
                                         "tracking": plan["one_depression"]["keystone"]}.get(method, row["one_depression"])
    return q, residual, dep


def method_range_error_m(plan: dict, proc: dict, subswaths: int = 0, subswath_error_m: float = 0.0) -> float:
    """The largest range error the plan's budget leaves the method that runs where it misses half a range
    sample (the lines of :func:`method_budget_warnings`), else 0: what a cell's range may be off by in
    the stages after the keystone (the echoes' check, ``forward/echo_navigation.py``, reads it)."""
    _, residual, dep = _method_budget(plan, proc)
    dep_error = 0.0 if dep is None else subswath_error_m if subswaths else dep["error_m"]
    return float(max((e for e in (residual or 0.0, dep_error) if e > plan["half_range_cell_m"]), default=0.0))


def method_budget_warnings(plan: dict, proc: dict, subswaths: int = 0, subswath_error_m: float = 0.0) -> list[str]:
    """What the plan's budget (:func:`plan_for_cube` with the run's Q among its candidates) says of the
    method that runs, where it misses half a range sample: the residual walk of ``none``, ``bulk``,
    ``traditional`` and ``decimation`` at its Q (eq. 19-20), and what one reference depression leaves
    across the range window (steep depression, any method but ``none``), or where the keystone stage
    splits the window (``subswaths`` of them, ``forward/subswath.py``) what they still leave.  One line
    each, for the log; an empty list where the method holds."""
    method = proc["method"]
    half = plan["half_range_cell_m"]
    q, residual, dep = _method_budget(plan, proc)
    out = []
    if residual is not None and residual > half:
        what = {"none": "range walk", "bulk": "residual range walk (its shift follows the motion along +y at one "
                "depression, not each direction's)"}.get(method, "residual range walk (eq. 19-20: one ambiguity number)")
        out.append(f"processing.method {method}" + (f" (Q = {q})" if method == "decimation" else "")
                   + f": the plan's budget leaves up to {residual:.2f} m of {what} against half a range sample "
                   f"{half:.2f} m (`fwdlook plan` gives each method's)")
    if dep is not None and subswaths:
        if subswath_error_m > half:
            out.append(f"processing.method {method}: even in {subswaths} range sub-swaths, one reference depression "
                       f"each, the window's Doppler across range leaves up to {subswath_error_m:.2f} m of range error "
                       f"against half a range sample {half:.2f} m (README, steep depression)")
    elif dep is not None and dep["error_m"] > half:
        out.append(f"processing.method {method}: the boresight Doppler changes by "
                   f"{plan['doppler_range_spread_hz']:.0f} Hz across the range window, and one reference "
                   f"depression ({plan['depression_deg']:.1f} deg at {plan['reference_range_m']:.0f} m) leaves "
                   f"targets outside {dep['span_m'][0]:.0f}-{dep['span_m'][1]:.0f} m (slant) up to "
                   f"{dep['error_m']:.2f} m off in range against half a range sample {half:.2f} m; "
                   "processing.subswaths: auto corrects the window in range sub-swaths (README, steep depression)")
    return out


def plan_for_scenario(scn: dict) -> dict:
    """The plan from the scenario's geometry alone (nothing is simulated)."""
    from ..dsp.geometry import scan_angle_deg, slant_range_m
    from ..scenario.forward import scene_geometry

    t, pos, vel, targets, _ = scene_geometry(scn)
    ant, radar = scn["antenna"], scn["radar"]
    stride = max(1, int(np.ceil(len(targets) * len(t) / 2e7)))  # an extended scene: a sample of its points
    r = slant_range_m(pos, targets[::stride])
    return plan_geometry(t, pos, vel, scan_angle_deg(t, ant["scan_start_deg"], ant["scan_rate_dps"]),
                         fc_hz=radar["fc_hz"], prf_hz=radar["prf_hz"], fs_hz=radar["fs_hz"],
                         bandwidth_hz=radar["bandwidth_hz"],
                         beamwidth_deg=ant["beamwidth_3db_deg"], reference_range_m=float(np.median(r)),
                         t_ref_s=t_ref_seconds(t, scn["processing"]["t_ref"]), cpi=scn["processing"]["cpi"],
                         range_extent_m=(float(np.min(r)), float(np.max(r))))


def format_plan(plan: dict, name: str) -> str:
    h = plan["half_range_cell_m"]

    def verdict(flag):
        return "NEEDS correction" if flag else "ok"

    lines = [
        f"migration budget of {name} (t_ref = {plan['t_ref_s']:.3f} s, reference range "
        f"{plan['reference_range_m']:.0f} m, depression {plan['depression_deg']:.2f} deg)",
        f"  range walk           {plan['range_walk_m']:9.2f} m   vs half a range cell {h:.2f} m   "
        f"{verdict(plan['needs_walk_correction'])}",
        f"  range curvature      {plan['range_curvature_m']:9.2f} m   vs {h:.2f} m   "
        f"{verdict(plan['needs_curvature'])}  (a = [{', '.join(f'{a:.1f}' for a in plan['accel_mps2'])}] m/s^2 "
        f"and the scan's geometry, eq. 12 generalised)",
        f"  ambiguity number     F = {plan['ambiguity_number_boresight']} on boresight, "
        f"{plan['ambiguity_number_range'][0]}..{plan['ambiguity_number_range'][1]} across the scan: "
        f"traditional keystone residual walk {plan['traditional_residual_walk_m']:.2f} m (eq. 19)",
        f"  bulk shift residual  {plan['bulk_residual_walk_m']:9.2f} m   vs {h:.2f} m   "
        f"{'ok' if plan['bulk_residual_walk_m'] < h else 'NOT HELD'} (the motion along +y at one depression)",
        f"  Doppler drift        {plan['doppler_centroid_drift_hz']:9.1f} Hz  vs half a CPI Doppler cell "
        f"{plan['doppler_cell_hz'] / 2:.1f} Hz   {verdict(plan['needs_doppler_centroid'])} (eq. 25)",
        f"  Doppler across range {plan['doppler_range_spread_hz']:9.1f} Hz  vs a CPI Doppler cell "
        f"{plan['doppler_cell_hz']:.1f} Hz   "
        + ("the CPI band covers the window's depressions (steep: motion.doppler_band_depressions)"
           if plan["band_over_depressions"] else "ok (one depression, eq. 25)"),
        f"  Doppler band         {plan['doppler_band_widest_hz']:9.1f} Hz  widest CPI band, "
        f"{plan['doppler_band_widest_hz'] / plan['doppler_cell_hz']:.1f} CPI Doppler cells: processing.n_doppler "
        f"auto gives {plan['n_doppler_auto']} (4 per cell)",
    ]
    dep = plan.get("one_depression")
    if dep is not None:
        named = (("tracking", "keystone"), ("traditional", "traditional"), ("beam/bulk", "shift"))
        worst = max(dep[key]["error_m"] for _, key in named)
        lines.append(
            f"  one depression       {worst:9.2f} m   vs {h:.2f} m   " + (
                "ok" if worst <= h else
                "NOT HELD: " + ", ".join(f"{label} up to {dep[key]['error_m']:.2f} m outside "
                                         f"{dep[key]['span_m'][0]:.0f}-{dep[key]['span_m'][1]:.0f} m"
                                         for label, key in named)
                + ": processing.subswaths auto corrects it in range sub-swaths (at most 16)")
            + " (the window's Doppler across range at one depression)")
    if plan.get("range_oversample_auto") is not None:
        lines.append(f"  range oversampling   x {plan['range_oversample_auto']} (processing.range_oversample auto: "
                     f"the power image's Nyquist rate, ceil(2 bandwidth / fs))")
    lines += [
        "  decimation (eq. 20): " + ", ".join(
            f"Q={r['q']}: spread {r['ambiguity_spread']}, residual {r['residual_walk_m']:.2f} m"
            for r in plan["decimation"] if r["q"] in (1, 5, 10, 20, 25, 50, 100)),
    ]
    p = plan["processing"]
    lines.append(f"=> method {p['method']}" + (f" with Q = {p['q']}" if p["method"] == "decimation" else "")
                 + f", range_curvature {'on' if p['range_curvature'] else 'off'}, doppler_centroid "
                 f"{'on' if p['doppler_centroid'] else 'off'}")
    return "\n".join(lines)


def plan_json(plan: dict) -> str:
    return json.dumps(plan, indent=1)
