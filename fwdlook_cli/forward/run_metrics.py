"""The per-target rows of metrics.json (CONTRACT.md section 5), shared by ``process`` and
:func:`fwdlook_cli.measure`, so that the Python API gives the numbers the command writes."""
from __future__ import annotations

import numpy as np

from ..dsp.geometry import C_MPS
from ..io import backing

PROFILE_WINDOW_CELLS = 5     # the dwell range profile's ISLR/PSLR window: +-5 range resolution cells
PROFILE_MARGIN_SAMPLES = 2   # range samples beyond each window in profile_spectra (a window's last search index)


def two_way_beamwidth_deg(cube) -> float:
    """Two-way 3 dB width of the cube's antenna (``dsp.antenna.two_way_width_for``)."""
    from ..dsp.antenna import two_way_width_for

    return two_way_width_for(float(cube.radar["beamwidth_3db_deg"]), cube.antenna)


def profile_spectra(compensated, doppler_params: dict, range_ref_m, range_window_m: float):
    """The CPI Doppler spectra of the motion-compensated data (``compensated``: the ``range_curvature``
    stage's output) on the range samples the dwell profiles read: every target's t_ref range
    +-``range_window_m`` and ``PROFILE_MARGIN_SAMPLES`` more each side (``range_m`` then has gaps
    between the targets' windows, never inside one).  ``chain.doppler_spectra`` with the CPI chain's
    own settings (``geo["doppler_params"]``): a range column's spectrum is a product over that column
    alone, so these are the CPI chain's spectra on those columns, and under ``imaging: dwell`` the
    profile metrics are the same eq. (27) measures as under ``imaging: cpi``.  The sum channel's only (the
    profiles read no difference channel)."""
    range_m = np.asarray(compensated["range_m"])
    n_r = len(range_m)
    ref = np.atleast_1d(np.asarray(range_ref_m, dtype=np.float64))
    lo = np.clip(np.searchsorted(range_m, ref - range_window_m) - PROFILE_MARGIN_SAMPLES, 0, n_r)
    hi = np.clip(np.searchsorted(range_m, ref + range_window_m) + PROFILE_MARGIN_SAMPLES + 1, 0, n_r)
    edges = np.zeros(n_r + 1, np.int64)          # the windows' union: +1 at each start, -1 past each end
    np.add.at(edges, lo, 1)
    np.add.at(edges, hi, -1)
    cols = np.flatnonzero(np.cumsum(edges[:-1]) > 0)
    return column_spectra(compensated, doppler_params, cols)


def column_spectra(compensated, doppler_params: dict, cols, channels=("sum",)):
    """``chain.doppler_spectra`` of the motion-compensated data on the range columns ``cols`` only (a
    column's spectrum is a product over that column alone: the CPI chain's spectra there), of
    ``channels``; out of core the columns are gathered block by block of pulses into file-backed arrays."""
    from .chain import doppler_spectra

    range_m = np.asarray(compensated["range_m"])
    sub = compensated.copy_vars("slow_time_s", "xyz", "scan_angle_deg", "position_m", "velocity_mps")
    sub.add("range_m", range_m[cols], ("range_m",), "m", "slant range")
    for ch in channels:
        x = compensated[ch]          # out of core gathered block by block of pulses into a file-backed array
        columns = (backing.map_blocks(lambda s, x=x: x[s][:, cols], x.shape[0], (x.shape[0], len(cols)), x.dtype,
                                      x[0].nbytes) if backing.active() else np.asarray(x)[:, cols])
        sub.add(ch, columns, ("slow_time_s", "range_m"), "1", f"{ch} channel")
    return doppler_spectra(sub, **doppler_params)


def target_rows(cube, final, proc: dict, geo: dict, spectra_of=None, compensated_of=None) -> tuple[list, str | None]:
    """(rows, islr_from) of a forward-looking image against the cube's truth: ``evaluate.target_metrics``,
    the ``resolved`` flags (the joint fit's own inside its region), and ISLR, PSLR, the range width and
    the peak loss from each target's range profile over its dwell (``evaluate.dwell_profile_metrics``),
    the image cut's kept as ``image_*``.  The profiles read the CPI Doppler spectra: ``spectra_of()``
    returns them (imaging ``cpi``), or ``compensated_of()`` the ``range_curvature`` stage's output,
    whose spectra :func:`profile_spectra` computes on the targets' windows (imaging ``dwell``).
    ``islr_from`` says which ISLR the rows hold: ``dwell_profile``, or ``image_cut`` where neither is
    given (None without truth)."""
    from ..dsp.antenna import sum_voltage_for
    from .evaluate import dwell_profile_metrics, resolved_flags, target_metrics, truth_at_t_ref

    truth = cube.truth_xyz_m()
    if truth is None:
        return [], None
    bandwidth_hz = float(cube.radar["bandwidth_hz"])
    rows = target_metrics(final["image"], final["range_m"], final["angle_deg"], truth,
                          cube.truth["amplitude"], geo["p_ref"], bandwidth_hz=bandwidth_hz)
    two_way_deg = two_way_beamwidth_deg(cube)
    true_r = [r["true_range_m"] for r in rows]
    true_a = [r["true_azimuth_deg"] for r in rows]
    flags = resolved_flags(true_r, true_a, bandwidth_hz=bandwidth_hz, wavelength_m=C_MPS / cube.radar["fc_hz"],
                           speed_mps=float(np.linalg.norm(geo["v_ref"])), prf_hz=cube.radar["prf_hz"],
                           cpi=proc["cpi"], depression_deg=geo["depression_deg"],
                           beamwidth_two_way_deg=geo.get("resolution_angle_gate_deg", two_way_deg),
                           doppler_resolution_hz=geo.get("doppler_resolution_hz"))
    if "fit_region" in geo:          # dwell_fit: joint: inside its region, what the fit parts
        from .dwell_range import flight_axis_deg
        from .dwell_resolution import fit_resolved_flags

        inside, fit_flags = fit_resolved_flags(
            true_r, true_a, position_m=cube.position_m, scan_angle_deg=cube.scan_angle_deg,
            axis_deg=flight_axis_deg(geo["v_ref"]), position_ref_m=geo["p_ref"],
            range_resolution_m=C_MPS / (2.0 * bandwidth_hz), **geo["fit_region"])
        flags = np.where(inside, fit_flags, flags)
    for row, flag in zip(rows, flags):
        row["resolved"] = bool(flag)
    window_m = PROFILE_WINDOW_CELLS * C_MPS / (2.0 * bandwidth_hz)
    if spectra_of is not None:
        spectra = spectra_of()
    elif compensated_of is not None:        # imaging: dwell: stage 6 on the profiles' windows only
        spectra = profile_spectra(compensated_of(), geo["doppler_params"],
                                  truth_at_t_ref(truth, np.asarray(geo["p_ref"]))[0], window_m)
    else:                                   # no compensated data at hand: the image cut's measures
        return rows, "image_cut"
    dwell = dwell_profile_metrics(spectra, truth, cube.truth["amplitude"],
                                  sum_voltage_for(float(cube.radar["beamwidth_3db_deg"]), cube.antenna),
                                  geo["p_ref"], range_window_m=window_m, two_way_width_deg=two_way_deg)
    del spectra                               # 2x the cube: not held longer than this
    for row, extra in zip(rows, dwell):
        row["image_islr_db"], row["image_pslr_db"] = row["islr_db"], row["pslr_db"]
        row["image_range_width_3db_m"] = row["range_width_3db_m"]
        row.update(extra)
    return rows, "dwell_profile"
