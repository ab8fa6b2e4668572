"""The per-target rows of metrics.json (CONTRACT.md section 5), shared by ``process`` and
:func:`fwdlook_cli.measure`, so that the Python API gives the numbers the command writes."""
from __future__ import annotations

import numpy as np

from ..dsp.geometry import C_MPS

PROFILE_WINDOW_CELLS = 5     # the dwell range profile's ISLR/PSLR window: +-5 range resolution cells


def two_way_beamwidth_deg(cube) -> float:
    """Two-way 3 dB width of the cube's antenna (``dsp.antenna.two_way_width_for``)."""
    from ..dsp.antenna import two_way_width_for

    return two_way_width_for(float(cube.radar["beamwidth_3db_deg"]), cube.antenna)


def target_rows(cube, final, proc: dict, geo: dict, spectra_of=None) -> tuple[list, str | None]:
    """(rows, islr_from) of a forward-looking image against the cube's truth: ``evaluate.target_metrics``,
    the ``resolved`` flags (the joint fit's own inside its region), and where the CPI Doppler spectra
    are at hand (``spectra_of()`` returns them: imaging ``cpi``) ISLR, PSLR, the range width and the
    peak loss from each target's range profile over its dwell (``evaluate.dwell_profile_metrics``),
    the image cut's kept as ``image_*``.  ``islr_from`` says which ISLR the rows hold:
    ``dwell_profile`` or ``image_cut`` (None without truth)."""
    from ..dsp.antenna import sum_voltage_for
    from .evaluate import dwell_profile_metrics, resolved_flags, target_metrics

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
    if spectra_of is None:                  # imaging: dwell (no CPI spectra): the image cut's measures
        return rows, "image_cut"
    spectra = spectra_of()
    dwell = dwell_profile_metrics(spectra, truth, cube.truth["amplitude"],
                                  sum_voltage_for(float(cube.radar["beamwidth_3db_deg"]), cube.antenna),
                                  geo["p_ref"], range_window_m=PROFILE_WINDOW_CELLS * C_MPS / (2.0 * bandwidth_hz),
                                  two_way_width_deg=two_way_deg)
    del spectra                               # 2x the cube: not held longer than this
    for row, extra in zip(rows, dwell):
        row["image_islr_db"], row["image_pslr_db"] = row["islr_db"], row["pslr_db"]
        row["image_range_width_3db_m"] = row["range_width_3db_m"]
        row.update(extra)
    return rows, "dwell_profile"
