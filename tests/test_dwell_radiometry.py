"""The dwell image's radiometry (forward/dwell_radiometry.py): a point's peak is one direction's matched
power wherever it lies, near the flight axis too.

Near the axis the Doppler is flat in angle, so every direction within about 0.7 deg of it sees a point
there and projects it to the same bin: equal points came out 14 dB brighter at the axis than 10 deg off,
and the joint fit's points (drawn at one direction's power) had the dwell image's brighter range
sidelobes beside them at -8 dB (an independent review, fifty-ninth round).  The scenes are simulated by
the simulator, which shares nothing with the imaging.
"""
from __future__ import annotations

import math
from pathlib import Path

import h5py
import numpy as np
import yaml

from fwdlook_cli.forward.process import process_cube
from fwdlook_cli.forward.simulate import simulate_scenario
from fwdlook_cli.scenario.overlay import resolve_with_config

ROOT = Path(__file__).resolve().parents[1]
# within the response's zone (the fit's region, 4.8 deg of the axis here), and two far from the axis,
# where one direction's power is what the image gives anyway (the response -0.8 to +0.3 dB there; at 6.5
# deg, outside the zone, +1.7 dB is left: README, "Near the flight axis")
ANGLES_DEG = [0.0, 0.5, 1.1, 1.6, 2.2, 3.2, 4.3, 8.6, 10.7]
# the first sidelobe of an unweighted pulse's compressed power, sinc^2 at 1.43 resolution cells
FIRST_SIDELOBE_DB = -13.26


def _points_scenario(points_m, fit: str, **radar):
    raw = yaml.safe_load((ROOT / "scenarios" / "isolated_a50.yaml").read_text())
    raw["scene"]["points_m"] = points_m
    raw["noise"]["snr_db"] = None
    raw["radar"].update(range_window_m=[1150.0, 2050.0], **radar)      # every point well inside the window
    return resolve_with_config(raw, "radiometry", str(ROOT / "configs" / "tracking.yaml"),
                               [f"processing.dwell_fit={fit}"])


def _equal_points_across_the_axis():
    """Equal noiseless points at ANGLES_DEG off the flight axis, each at its own range (40 m steps)."""
    return [[round((1500 + 40 * k) * math.sin(math.radians(a)), 2), round((1500 + 40 * k) * math.cos(math.radians(a)), 2)]
            for k, a in enumerate(ANGLES_DEG)]


def test_equal_points_near_the_flight_axis_are_as_bright_as_far_from_it(tmp_path):
    """Equal points 0-4.3 deg off the axis and two at 8.6 and 10.7 deg: the dwell image alone puts their
    peaks within 1.5 dB of each other (two samplings' straddle, range x 2 and 0.05 deg bins, up to 0.6 dB
    each), where they spread over 14 dB before (+13.7 dB at 0 and 0.5 deg, +6 at 1.1, +3 to +4.4 at
    1.6-4.3); with the joint fit, whose points are one direction's power rendered at their fitted angle
    and range, each within the same 1.5 dB of the image alone (13.9 dB apart at the axis before)."""
    peaks = {}
    for fit in ("none", "joint"):
        scn = _points_scenario(_equal_points_across_the_axis(), fit)
        cube, _ = simulate_scenario(scn)
        rows = process_cube(cube, scn, tmp_path / fit, quiet=True, png=False)["targets"]
        assert all(r["detected"] for r in rows)
        peaks[fit] = 10 * np.log10([r["peak_power"] for r in rows])
    assert np.ptp(peaks["none"]) <= 1.5, peaks["none"]
    assert np.max(np.abs(peaks["joint"] - peaks["none"])) <= 1.5, peaks


def test_a_fitted_point_on_the_axis_has_its_pulses_own_range_sidelobes(tmp_path):
    """One noiseless point on the flight axis at X-band, the tracking preset (joint fit): outside 5 m of
    it, its image column stays under the unweighted pulse's first sidelobe (-13.26 dB).  Before, the
    dwell image's cells beyond the fitted range cells kept their 14 dB brighter scale: -8.0 dB at 11.8 m,
    `image_pslr_db` -8.4 against the image alone's -13.0; now the two within 1 dB."""
    pslr = {}
    for fit in ("joint", "none"):
        scn = _points_scenario([[0.0, 1700.0]], fit, fc_hz=9.6e9)
        cube, _ = simulate_scenario(scn)
        rows = process_cube(cube, scn, tmp_path / fit, quiet=True, png=False)["targets"]
        assert rows[0]["detected"] and abs(rows[0]["azimuth_error_deg"]) <= 0.01
        pslr[fit] = rows[0]["image_pslr_db"]
        if fit == "joint":
            with h5py.File(tmp_path / fit / "image.h5") as f:
                image, range_m = f["image"][()], f["range_m"][()]
            i, j = np.unravel_index(np.argmax(image), image.shape)
            beyond = np.abs(range_m - range_m[i]) > 5.0
            assert 10 * np.log10(image[beyond, j].max() / image[i, j]) <= FIRST_SIDELOBE_DB
    assert abs(pslr["joint"] - pslr["none"]) <= 1.0, pslr        # (4.6 dB worse with the fit before)
