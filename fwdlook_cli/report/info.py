"""``fwdlook info``: a plain description of a raw cube, a stage file or an image."""
from __future__ import annotations

import os
from pathlib import Path

import h5py
import numpy as np

from ..errors import BadInput


def describe(path: str) -> str:
    p = Path(path)
    if not p.exists():
        raise BadInput(f"{path}: file not found")
    try:
        with h5py.File(p, "r") as f:
            fmt = f.attrs.get("format")
    except OSError:
        if Path(path).is_dir():
            inside = [n for n in ("image.h5", "raw.h5") if (Path(path) / n).is_file()]
            hint = f"; allowed: a file, e.g. {Path(path) / inside[0]} (a run folder's)" if inside else ""
            raise BadInput(f"{path}: is a directory, not an HDF5 file{hint}") from None
        if not os.access(path, os.R_OK):
            raise BadInput(f"{path}: permission denied; the file must be readable") from None
        raise BadInput(f"{path}: not a readable HDF5 file (truncated or not HDF5)") from None
    if isinstance(fmt, bytes):
        fmt = fmt.decode(errors="replace")
    if isinstance(fmt, str) and fmt == "fwdlook-raw":      # (an array there is some other file's: listed)
        return describe_raw(path)
    from ..io.describe import describe_h5

    return f"{path}\n" + describe_h5(p)


def describe_raw(path: str) -> str:
    """The cube's description and a calibration from its data, with bounded memory whatever its size:
    its echoes mapped read-only where they lie in the file (or, stored chunked or compressed, copied
    block by block into an unnamed scratch file in the temporary directory: ``io/backing.py``), and
    the calibration's detection reading them in blocks of pulses (``forward/point_returns.py``)."""
    from ..io import backing
    from ..io.raw import read_raw

    with backing.read_without_holding():
        return _describe_cube(path, read_raw(path))


def _describe_cube(path: str, cube) -> str:
    r, t = cube.radar, cube.slow_time_s
    lines = [
        f"{path}: fwdlook raw cube (format_version 1)",
        f"  echo            {'sum + diff' if cube.diff is not None else 'sum only (single channel)'}, "
        f"{cube.n_pulses} pulses x {cube.n_range} range samples, complex64",
        f"  radar           fc {r['fc_hz'] / 1e9:g} GHz, bandwidth {r['bandwidth_hz'] / 1e6:g} MHz, "
        f"fs {r['fs_hz'] / 1e6:g} MHz, PRF {r['prf_hz']:g} Hz, sum beam {r['beamwidth_3db_deg']:g} deg",
        f"  range window    {cube.range_m[0]:.1f} .. {cube.range_m[-1]:.1f} m, "
        f"spacing {cube.range_spacing_m:.3f} m",
        f"  slow time       0 .. {t[-1]:.4f} s",
        f"  scan            {cube.scan_angle_deg[0]:+.2f} .. {cube.scan_angle_deg[-1]:+.2f} deg",
    ]
    speed = np.linalg.norm(cube.velocity_mps, axis=1)
    lines.append(f"  platform        speed {speed[0]:.1f} -> {speed[-1]:.1f} m/s, height "
                 f"{cube.position_m[0, 2]:.1f} m, travel {np.linalg.norm(cube.position_m[-1] - cube.position_m[0]):.1f} m")
    if cube.antenna:
        a = cube.antenna
        lines.append(f"  antenna         {a.get('pattern', 'gaussian2')}, squint {float(a.get('squint_deg', float('nan'))):g} "
                     f"deg, slope {float(a.get('monopulse_slope_per_deg', float('nan'))):.4f} /deg, imbalance "
                     f"{float(a.get('diff_gain_db', 0.0)):+g} dB {float(a.get('diff_phase_deg', 0.0)):+g} deg"
                     + (f", ratio table of {len(a['ratio'])} points" if "ratio" in a else ""))
    else:
        lines.append("  antenna         no /antenna group: the monopulse calibration comes from the data")
    if cube.diff is not None:
        from ..forward.calibration import antenna_contradiction, calibration_for_cube

        try:
            cal = calibration_for_cube(cube, "data")
            lines.append(f"  calibration     {cal.describe()}")
            contradiction = antenna_contradiction(cube, cal)             # the data against /antenna
            if contradiction:
                lines.append(f"  check           {contradiction}; `fwdlook process` refuses "
                             f"processing.monopulse_calibration = auto for this cube: give data (calibrate "
                             f"from the data) or cube (/antenna as it is)")
        except BadInput as exc:
            lines.append(f"  calibration     data: not possible ({str(exc).split(';')[0]})")
    snr = cube.noise.get("snr_db")
    lines.append(f"  SNR             {'noiseless' if snr is None or not np.isfinite(snr) else f'{snr:g} dB'}"
                 " (peak sample, unit target at beam centre)" if snr is not None else
                 "  SNR             unknown (not a simulated cube)")
    n_truth = 0 if not cube.truth else len(cube.truth["x_m"])
    lines.append(f"  truth           {n_truth} targets" if n_truth else "  truth           none")
    if "scenario_name" in cube.attrs:
        lines.append(f"  scenario        {cube.attrs['scenario_name']} "
                     f"(sha256 {str(cube.attrs.get('scenario_sha256', ''))[:16]})")
    lines.append(f"  software        {cube.attrs.get('software', '?')} {cube.attrs.get('software_version', '')}")
    return "\n".join(lines)
