"""ISAR: a stationary radar imaging a moving object; range-cell migration removed by the
second-order keystone transform about the range-curve minimum (Serafin et al., seed 001).

Geometry (paper eq. 6-9, Fig. 1)
--------------------------------
The radar sits at the origin.  The object moves on a straight line at constant velocity ``v``
(``target.velocity_mps``; paper: [0, 40, 0] m/s).  The observation lasts ``N`` pulses
(``radar.n_pulses``) at ``t_n = n / F_p`` (t = 0 at the first pulse, CONTRACT section 3); its middle is
``t_mid = (N - 1) / (2 F_p)``.  At ``t_mid`` the reference scatterer (``target.points_m[0]``, default the
only one, at offset [0, 0, 0]) is at

    p_mid = R0 (cos theta0, -sin theta0, 0)

``R0`` (``target.range_m``) is the distance to the middle point of the observation and ``theta0``
(``target.theta0_deg``) the middle observation angle, both as in eq. (13).  ``theta0`` is measured in the
ground plane from +x, the normal from the radar to the paper's track (velocity along +y), towards -y:
a target with ``theta0 > 0`` still has to travel ``R0 sin(theta0)`` along +y to its closest approach.
Scatterer ``k`` (offset ``d_k``, rigid) is at ``p_k(t) = p_mid + d_k + v (t - t_mid)`` and its range is
exact (eq. 6-7, stop-and-hop):  ``R_k(t) = |p_k(t)|``.

Shift of the range minimum, eq. (13) corrected.  The range of the reference scatterer is smallest at
``t_c = t_mid - p_mid.v / |v|^2``.  For the paper's ``v = [0, v, 0]`` this is ``t_mid + R0 sin(theta0) / v``,
so in pulses

    n0 = R0 sin(theta0) F_p / v                                             # eq. (13), corrected

Eq. (13) as printed, ``R0 sin(theta0) / (v F_p)``, has the units m / (m/s x 1/s) = s^2: it divides by
F_p where it must multiply (NOTES.md).  The paper's numbers give n0 = 4318 pulses (3 deg) and 7190 pulses
(5 deg); the printed form gives 4.8e-4 and 8.0e-4.  For any velocity the processor uses the general
``n0 = -(p_mid.v) F_p / |v|^2``.  With the paper's numbers and a 2 s dwell the minimum lies outside the
observation (1.44 s and 2.40 s after its middle): the keystone is centred outside the data, which is
allowed.

Range-frequency model and the corrections (eq. 11-12)
-----------------------------------------------------
After a centred range FFT (``f`` in -fs/2..fs/2) the echo of one scatterer is
``P(f) exp(-j 4 pi (f0 + f) R(t) / c)``.  Every correction resamples each range-frequency row in slow
time, ``t = t0 + alpha(f) (t' - t0)``, with the band-limited DFT interpolant of ``keystone.py``
(:class:`~fwdlook_cli.keystone.KeystonePlan`, or :func:`~fwdlook_cli.keystone.keystone_dft`):

* ``none``:          no resampling;
* ``keystone1``:     ``alpha = f0 / (f0 + f)`` about ``t_mid`` (eq. 11): removes the linear range walk and
  leaves the curvature (with its sign reversed);
* ``keystone2``:     ``alpha = (f0 / (f0 + f))^(1/2)`` about ``t_mid``: removes a range curve symmetric
  about ``t_mid`` and leaves half of the linear walk when the minimum is elsewhere;
* ``keystone2_n0``:  the same about ``t_c = t_mid + n0 / F_p`` (eq. 12 with the corrected eq. 13): since
  ``R(t)`` is even about ``t_c`` the range curve up to its quartic term is removed; the target then sits at
  its closest-approach range ``R(t_c)`` at every pulse.  The paper assumes theta0 (and R0, v) known: the
  processor takes them from the cube's ``/truth/targets`` (reference scatterer position and velocity) or
  from ``processing.n0_pulses``; a cube without truth needs one of those or ``keystone2_n0_est``;
* ``keystone2_n0_est``: the same with n0 estimated from the data (:func:`estimate_n0`).

The rows are zero-extended in slow time before the resampling (:func:`_keystone`): a position
``t0 + alpha (m - t0)`` that leaves the observation reads zeros rather than the other end of the dwell.
Such positions exist for ``|1 - alpha| |m - t0| >= 1``, up to ``fs / (4 f0) (|n0| + N/2)`` pulses (220 and
300 pulses of 6000 for the paper's 3 and 5 deg, in the outermost rows only); the lost samples cost about
0.1 dB of integration gain here.  The loss grows with that excursion against ``N``: a short dwell far
from the minimum (e.g. 600 pulses for the 3 deg case) loses about 1 dB.

``t_ref`` (the time the corrected data and image refer to, CONTRACT section 5) is the keystone centre:
``t_mid`` for none/keystone1/keystone2, ``t_c`` for the n0-shifted ones.

Doppler ambiguity.  The slow-time signal of row ``f`` has the Doppler ``(1 + f/f0) f_dc`` with
``f_dc = -2 Rdot(t_mid) f0 / c``.  Where it approaches or exceeds the PRF the periodic interpolant returns
the baseband tone; the keystone multiplies by ``exp(j 2 pi F tau)`` (keystone.py).  ``processing.ambiguity:
auto`` uses per row ``F = <(1 + f/f0) f_dc / F_p>`` (rounded half away from zero) with ``f_dc`` from the
known geometry (truth) or from the estimate (range walk, refined by the image); an integer forces one F
for every row.  A Doppler chirp that crosses a multiple of PRF/2 during the dwell is not handled.

Azimuth compression
-------------------
The keystone leaves the carrier phase of the ``f = 0`` row untouched, so after any correction the
target's slow-time phase is still ``-4 pi f0 R(t) / c``: a Doppler chirp of rate ``2 Rddot / lambda``
(29 Hz/s for the paper's geometry: the image smears over about 60 Doppler bins in 2 s without
compensation).  ``azimuth_compress`` therefore multiplies every range cell by the reference
``exp(+j 4 pi f0 (R_m(t) - R0) / c)`` of the straight-line range model (the paper's eq. 10 phase term)

    R_m(t)^2 = R0^2 + 2 R0 Rdot tau + |v|^2 tau^2,    tau = t - t_mid           (exact for eq. 7)

and takes the slow-time FFT (centred Doppler, unweighted).  The model is the same for every correction
(known geometry from the truth, or the estimate), so the corrections differ only in their range-migration
handling.  The reference scatterer lands at Doppler 0; a scatterer offset ``d`` lands at
``f = -2 omega (d . e_perp) / lambda``, ``omega = sqrt(|v|^2 - Rdot^2) / R0`` the line-of-sight rotation
rate at ``t_mid`` and ``e_perp`` the direction the line of sight turns to: the cross-range axis is
``x = -lambda f / (2 omega)``.

Estimating n0 (``keystone2_n0_est``)
-----------------------------------
The three model parameters fix n0 = -R0 Rdot F_p / |v|^2.  :func:`estimate_n0` (1) tracks the per-pulse
interpolated peak range and fits a quadratic: R0, Rdot (and from it the ambiguity number) and a coarse
``|v|^2 = R0 Rddot + Rdot^2``; (2) applies the n0-shifted second-order keystone at the coarse n0; (3)
searches the model over a grid around the coarse value for the sharpest image (``sum |I|^4 / (sum
|I|^2)^2`` over the target's range cells after the model phase compensation), each candidate being one
value of n0; (4) refines Rdot from the interpolated Doppler of the image peak and repeats on a finer
grid.  The grid is uniform in ``|v|^2`` (equivalently in the Doppler rate) because the sharpness lobe has
a constant width there (a chirp-rate error of ``1/T^2``, quadratic phase pi/4 at the dwell edges); in
n0 the lobe is about ``n0 lambda R0 / (2 T^2 |v|^2)`` pulses wide (37 pulses for theta0 = 3 deg, 2 s).
Settings: ``processing.n0_search.half_span_lobes`` (first grid, +- lobes around the coarse value; a
maximum on the grid's edge moves the grid, up to 8 times), ``points_per_lobe``, ``passes`` (after each pass
the grid narrows to +-2 steps around the maximum and the step is divided by 4).  Sharpness alone cannot give n0: the
range walk it leaves for an n0 error of 2 pulses is about a millimetre, so the information is in the
Doppler rate (``|v|^2``) and the Doppler centroid (``Rdot``), both measured coherently here.  The
estimator assumes one dominant scatterer (the paper's point echo): with several comparable scatterers
the per-pulse peak track of step (1) hops between them.

Metrics
-------
``migration_span_cells``: per pulse, the range profile of the corrected range-time data is oversampled
(band-limited, x4) and its peak (within the reference scatterer's range gate when the truth is known:
the min..max of its raw range history and of its predicted track after the correction, +- 3
resolution cells, ``isar_span.py``) refined by a log-parabola; the positions of the pulses where the
target is present (peak power at least a quarter of the median peak power) are smoothed by a running
mean of ``SPAN_SMOOTH_PULSES`` (32) pulses, which keeps noise jitter out of max-minus-min (keystone2_n0
on the paper scenarios, 3 / 5 deg, 20 dB: 0.09 / 0.12 range samples), and the span is max minus min,
measured in range samples (``c / (2 fs)``) and reported in range resolution cells ``c / (2 B)``
(``summary.migration_span_cells`` = ``migration_span_resolution_cells``), range samples
(``migration_span_samples``) and metres (``migration_span_m``).  With several scatterers in the gate the
track follows the strongest return per pulse.

``integration_gain_db``: 20 log10 of the image maximum within the reference scatterer's migration extent
(the range gate above, +-3 Doppler bins) over the ideal ``N a |p(0)|`` (N pulses of amplitude a, p the
compressed pulse, p(0) = 1 unweighted): perfect range alignment and phase compensation.  The sampled
compressed pulse itself loses 0.09-0.2 dB at fs = 1.2 B (its interpolated per-pulse peak), so a perfectly
compensated target reads about -0.1 dB.  A cube without truth uses N times the median per-pulse peak
amplitude of the raw echo.

Per target (truth known): position, 3 dB widths (range, cross-range), PSLR and ISLR (eq. 27, main lobe
between the first nulls, window +-16 cells, :func:`~fwdlook_cli.metrics.profile_metrics`) come from the
range and Doppler cuts through the image peak within +-3 range resolution cells and +-3 Doppler bins of
the predicted position; the peak value and position from the exact band-limited interpolant of each cut
(a Doppler cut is the DFT of the slow-time record, interpolated as such: :func:`_doppler_line`).
``detected``: that peak is a local maximum inside the gate and 10 dB above the image's median power.

References
----------
.. [1] P. Serafin, C. Lesnik, K. Zielinski, "Range cell migration compensation in inverse synthetic
   aperture radar", seed 001, eq. (6)-(13) and Sec. 4.
.. [2] D. Kirkland, "Imaging moving targets using the second-order keystone transform", IET Radar Sonar
   Navig. 5(8), 902-910 (2011).
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.fft as sfft

from . import __version__
from .config import (REQUIRED, CROSS_CHECKS, Field, amplitude, auto_or, choice, integer, num, optional,
                     range_window, register_schema, text, vector)
from .errors import BadInput
from .geometry import C_MPS, ambiguity_number
from .isar_span import span_units, track_gate_samples
from .pipeline import Stage, StageData

__all__ = [
    "ISAR_SCHEMA", "CORRECTIONS", "LineModel", "isar_geometry", "scatterer_ranges_m", "n0_pulses_eq13",
    "simulate_isar_scenario", "IsarSimulationStats", "range_fft", "estimate_n0", "rcmc", "range_ifft",
    "azimuth_compress",
    "build_isar_stages", "run_isar_stages", "isar_outputs", "peak_track", "migration_span_cells",
    "isar_correction_table", "format_isar_table", "save_isar_figures", "process_isar_cube",
]

CORRECTIONS = ("none", "keystone1", "keystone2", "keystone2_n0", "keystone2_n0_est")
BEAMWIDTH_NOT_USED_DEG = 10.0  # /radar beamwidth_3db_deg of ISAR cubes: a wide beam, not simulated
SPAN_SMOOTH_PULSES = 32        # running mean of the per-pulse peak range before max - min
TRACK_OVERSAMPLE = 4           # band-limited oversampling of each pulse's range profile
ANALYSIS_WINDOW_CELLS = 16.0   # +- cells of the ISLR / PSLR window (range and Doppler)


# ----------------------------------------------------------------------------------------------
# Scenario schema (kind: isar)
# ----------------------------------------------------------------------------------------------
def _offsets(value):
    if not isinstance(value, (list, tuple)) or not value:
        raise ValueError("expected a non-empty list of [dx, dy, dz] offsets")
    return [vector(3)(p) for p in value]


ISAR_SCHEMA: dict = {
    "name": Field(text, "isar", "scenario name, copied into outputs"),
    "kind": Field(choice("isar"), REQUIRED, "isar: stationary radar at the origin, moving object"),
    "radar": {
        "fc_hz": Field(num(1e6, 1e12), 3.0e9, "carrier frequency f0"),
        "bandwidth_hz": Field(num(0.0, lo_open=True), 300.0e6, "transmitted LFM bandwidth"),
        "pulse_width_s": Field(num(0.0, 1e-3, lo_open=True), 0.1e-6,
                               "LFM pulse width; the compressed pulse spans +-pulse_width"),
        "prf_hz": Field(num(0.0, lo_open=True), 3000.0, "pulse repetition frequency F_p"),
        "fs_hz": Field(num(0.0, lo_open=True), 360.0e6,
                       "complex sampling rate of the range-compressed data (range cell c/(2 fs))"),
        "range_window_m": Field(auto_or(range_window), "auto",
                                "[near, far] slant range recorded, or auto: the dwell's ranges, the "
                                "closest-approach range and the compressed pulse's reach"),
        "n_pulses": Field(integer(16, 10_000_000), 6000, "pulses in the observation (the dwell)"),
        "range_weighting": Field(choice("none", "hamming", "hann", "taylor"), "none",
                                 "amplitude weighting of the matched filter (range sidelobes)"),
    },
    "target": {
        "range_m": Field(num(0.0, lo_open=True), 1100.0,
                         "R0: distance to the object at the middle of the observation"),
        "theta0_deg": Field(num(-89.0, 89.0), 3.0,
                            "middle observation angle, from +x (normal to a +y track) towards -y"),
        "velocity_mps": Field(vector(3, num(-1e5, 1e5)), [0.0, 40.0, 0.0], "object velocity [vx, vy, vz]"),
        "points_m": Field(_offsets, [[0.0, 0.0, 0.0]],
                          "offsets [dx, dy, dz] of rigidly moving scatterers; the first is the reference"),
        "amplitude": Field(amplitude, 1.0, "common amplitude, or one per point"),
    },
    "noise": {
        "snr_db": Field(optional(num(-100.0, 300.0)), 20.0,
                        "peak SNR of the strongest scatterer per range-compressed sample; null: no noise"),
        "seed": Field(integer(0), 1, "seed of the noise generator"),
    },
    "processing": {
        "correction": Field(choice(*CORRECTIONS), "keystone2_n0", "range-cell-migration correction"),
        "keystone": Field(choice("czt", "dft"), "czt", "keystone implementation (dft: O(N^2) reference)"),
        "ambiguity": Field(auto_or(integer(-100_000, 100_000)), "auto",
                           "Doppler ambiguity number F; auto: per range-frequency row from the geometry"),
        "n0_pulses": Field(auto_or(num(-1e9, 1e9)), "auto",
                           "shift of the range minimum for keystone2_n0; auto: eq. (13) from the truth"),
        "azimuth_phase": Field(choice("model", "none"), "model",
                               "azimuth compression: model = straight-line range-model phase, then FFT"),
        "n0_search": {
            "half_span_lobes": Field(num(0.5, 1e4), 4.0,
                                     "half-width of the first search grid, in sharpness lobes"),
            "points_per_lobe": Field(integer(2, 1000), 6, "grid points per sharpness lobe"),
            "passes": Field(integer(1, 10), 2, "search passes, each followed by a Doppler refinement"),
        },
    },
}


def _isar_checks(scn: dict, source: str) -> None:
    radar, tg = scn["radar"], scn["target"]
    if radar["fs_hz"] < radar["bandwidth_hz"]:
        raise BadInput(f"{source}: radar.fs_hz = {radar['fs_hz']:g}: must be >= radar.bandwidth_hz "
                       f"= {radar['bandwidth_hz']:g} (complex sampling of the compressed pulse)")
    if not any(tg["velocity_mps"]):
        raise BadInput(f"{source}: target.velocity_mps = [0, 0, 0]: must be non-zero (ISAR images a "
                       f"moving object)")
    n_pts = len(tg["points_m"])
    if isinstance(tg["amplitude"], list) and len(tg["amplitude"]) != n_pts:
        raise BadInput(f"{source}: target.amplitude: list of {len(tg['amplitude'])} values; allowed: one "
                       f"number or one per point ({n_pts})")
    t, pos0, vel, _ = isar_geometry(scn)
    r = scatterer_ranges_m(pos0, vel, t)
    reach = C_MPS * radar["pulse_width_s"] / 2.0
    if r.min() <= reach:
        raise BadInput(f"{source}: target.range_m = {tg['range_m']:g}: the object comes within "
                       f"{r.min():.1f} m of the radar, inside the compressed pulse's reach ({reach:.1f} m)")
    if radar["range_window_m"] != "auto":
        near, far = radar["range_window_m"]
        if r.min() < near or r.max() > far:
            raise BadInput(f"{source}: radar.range_window_m = [{near:g}, {far:g}]: the object spans slant "
                           f"ranges {r.min():.1f} to {r.max():.1f} m over the dwell; widen the window or "
                           f"use auto")


register_schema("isar", ISAR_SCHEMA)
CROSS_CHECKS["isar"] = _isar_checks


# ----------------------------------------------------------------------------------------------
# Geometry
# ----------------------------------------------------------------------------------------------
def isar_geometry(scn: dict):
    """Slow time, initial (t = 0) scatterer positions, velocity and amplitudes of a resolved scenario.

    Returns ``slow_time_s`` [N], ``pos0_m`` [K, 3], ``velocity_mps`` [3], ``amplitudes`` [K].
    """
    radar, tg = scn["radar"], scn["target"]
    n = int(radar["n_pulses"])
    slow_time_s = np.arange(n, dtype=np.float64) / radar["prf_hz"]
    t_mid = (n - 1) / (2.0 * radar["prf_hz"])
    th = math.radians(tg["theta0_deg"])
    p_mid = tg["range_m"] * np.array([math.cos(th), -math.sin(th), 0.0])  # reference scatterer at t_mid
    vel = np.asarray(tg["velocity_mps"], dtype=np.float64)
    offsets = np.asarray(tg["points_m"], dtype=np.float64).reshape(-1, 3)
    pos0 = p_mid[None, :] + offsets - vel[None, :] * t_mid
    amp = tg["amplitude"]
    amps = np.asarray(amp if isinstance(amp, list) else [amp] * len(offsets), dtype=np.float64)
    return slow_time_s, pos0, vel, amps


def scatterer_ranges_m(pos0_m, velocity_mps, slow_time_s):
    """Exact range (eq. 6-7) of every scatterer at every time, radar at the origin: [K, N] float64."""
    p = (np.asarray(pos0_m, dtype=np.float64)[:, None, :]
         + np.asarray(velocity_mps, dtype=np.float64)[None, None, :]
         * np.asarray(slow_time_s, dtype=np.float64)[None, :, None])
    return np.sqrt(np.einsum("kni,kni->kn", p, p))


def n0_pulses_eq13(range_m, theta0_deg, speed_mps, prf_hz):
    """Eq. (13) with its units corrected: ``n0 = R0 sin(theta0) F_p / v`` pulses (NOTES.md)."""
    return range_m * math.sin(math.radians(theta0_deg)) * prf_hz / speed_mps


@dataclass(frozen=True)
class LineModel:
    """Straight-line constant-velocity range history about ``t_mid`` (exact for eq. 7).

    ``R(t)^2 = r0^2 + 2 r0 rdot tau + v2 tau^2``, ``tau = t - t_mid``.
    """

    r0_m: float        # range at t_mid
    rdot_mps: float    # range rate at t_mid
    v2_m2ps2: float    # |v|^2
    t_mid_s: float

    def range_m(self, t_s):
        tau = np.asarray(t_s, dtype=np.float64) - self.t_mid_s
        return np.sqrt(np.maximum(self.r0_m**2 + 2.0 * self.r0_m * self.rdot_mps * tau
                                  + self.v2_m2ps2 * tau**2, 0.0))

    @property
    def tc_minus_tmid_s(self) -> float:
        """Time from the middle of the observation to the range minimum."""
        return -self.r0_m * self.rdot_mps / self.v2_m2ps2

    def n0_pulses(self, prf_hz: float) -> float:
        return self.tc_minus_tmid_s * prf_hz

    def doppler_hz(self, fc_hz: float) -> float:
        """Unambiguous Doppler centroid at t_mid, -2 Rdot f0 / c."""
        return -2.0 * self.rdot_mps * fc_hz / C_MPS

    @property
    def omega_rps(self) -> float:
        """Line-of-sight rotation rate at t_mid."""
        return math.sqrt(max(self.v2_m2ps2 - self.rdot_mps**2, 0.0)) / self.r0_m

    def as_dict(self) -> dict:
        return {"r0_m": float(self.r0_m), "rdot_mps": float(self.rdot_mps),
                "v2_m2ps2": float(self.v2_m2ps2), "t_mid_s": float(self.t_mid_s)}


def _truth_line_model(cube, k=0) -> LineModel | None:
    """The straight-line model of truth scatterer ``k`` (needs x/y/z_m and vx/vy/vz_mps)."""
    tr = cube.truth
    if not tr or any(key not in tr for key in ("vx_mps", "vy_mps", "vz_mps")):
        return None
    t_mid = 0.5 * (cube.slow_time_s[0] + cube.slow_time_s[-1])
    v = np.array([tr["vx_mps"][k], tr["vy_mps"][k], tr["vz_mps"][k]])
    p = np.array([tr["x_m"][k], tr["y_m"][k], tr["z_m"][k]]) + v * t_mid
    r0 = float(np.linalg.norm(p))
    return LineModel(r0, float(p @ v) / r0, float(v @ v), float(t_mid))


def _truth_positions_at(cube, t_s):
    tr = cube.truth
    p0 = np.column_stack([tr["x_m"], tr["y_m"], tr["z_m"]])
    v = np.column_stack([tr["vx_mps"], tr["vy_mps"], tr["vz_mps"]])
    return p0 + v * t_s, v


# ----------------------------------------------------------------------------------------------
# Simulation
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class IsarSimulationStats:
    n_scatterers: int
    n_pulses: int
    kernel_samples: int    # range samples one scatterer-pulse pair writes
    n0_pulses: float       # shift of the reference scatterer's range minimum from the middle


def simulate_isar_scenario(scn: dict):
    """Simulate a resolved ISAR scenario: returns (RawCube, IsarSimulationStats).

    Echo of scatterer k at pulse n (stop-and-hop, eq. 5 and 9):
    ``a_k p(2 (r - R_kn) / c) exp(-j 4 pi f0 R_kn / c)`` with the exact range ``R_kn`` and the tabulated
    compressed pulse ``p`` (:class:`~fwdlook_cli.pulse.CompressedPulse`); the carrier phase is reduced
    modulo one cycle in float64.  Vectorised over (scatterer, pulse) pairs x kernel samples, accumulated
    with ``np.bincount``.  Noise: circular complex Gaussian band-limited to |f| <= B/2,
    ``sigma = max(a) / 10^(snr_db / 20)`` per range-compressed sample (the forward simulator's
    definition, ``noise.py``).

    The single channel is written to ``sum`` (``diff = None``; the file marks it with the root
    attribute ``channels = "sum"``).  ``scan_angle_deg`` holds the reference scatterer's line-of-sight
    azimuth ``atan2(x, y)`` per pulse (there is no scan); the platform is the radar, at rest at the
    origin; ``/radar beamwidth_3db_deg`` is a nominal wide beam (10 deg) that is not simulated.  The
    truth holds every scatterer's position at t = 0 and its velocity (``vx_mps, vy_mps, vz_mps``).
    """
    from .config import dump_scenario, scenario_hash
    from .cube import RawCube
    from .pulse import CompressedPulse
    from .simulate import auto_range_axis_m, noise_sigma_for

    radar = scn["radar"]
    fc, fs = radar["fc_hz"], radar["fs_hz"]
    slow_time_s, pos0, vel, amps = isar_geometry(scn)
    n_p = len(slow_time_s)
    pulse = CompressedPulse(radar["bandwidth_hz"], radar["pulse_width_s"], fs, radar["range_weighting"])
    r_kn = scatterer_ranges_m(pos0, vel, slow_time_s)                  # eq. (7), exact
    dr = C_MPS / (2.0 * fs)
    if radar["range_window_m"] == "auto":
        vhat = vel / np.linalg.norm(vel)
        r_closest = np.linalg.norm(pos0 - (pos0 @ vhat)[:, None] * vhat[None, :], axis=1)
        range_m = auto_range_axis_m(min(r_kn.min(), r_closest.min()), r_kn.max(), fs, pulse)
    else:
        near, far = radar["range_window_m"]
        range_m = near + dr * np.arange(int(np.floor((far - near) / dr)) + 1)
    n_r = len(range_m)

    r = r_kn.ravel()                                                   # pairs (k, n), n fastest
    n_idx = np.tile(np.arange(n_p), len(pos0))
    amp = np.repeat(amps, n_p)
    coef = amp * np.exp(-2j * np.pi * np.mod(2.0 * fc * r / C_MPS, 1.0))  # eq. (9) carrier phase
    half = int(np.ceil(C_MPS * pulse.support_s / 2.0 / dr))
    taps = np.arange(2 * half + 1, dtype=np.int64)
    first = np.floor((r - range_m[0]) / dr).astype(np.int64) - half + 1
    col = first[:, None] + taps[None, :]                               # [pairs, kernel] range sample
    kern = pulse(2.0 * (range_m[0] + col * dr - r[:, None]) / C_MPS)
    inside = (col >= 0) & (col < n_r)
    flat = (n_idx[:, None] * n_r + col)[inside]
    vals = (kern * coef[:, None].astype(np.complex64))[inside]
    size = n_p * n_r
    echo = (np.bincount(flat, weights=vals.real, minlength=size)
            + 1j * np.bincount(flat, weights=vals.imag, minlength=size)).reshape(n_p, n_r)
    echo = echo.astype(np.complex64)
    sigma = noise_sigma_for(scn["noise"]["snr_db"], amps)
    if sigma > 0.0:
        from .noise import band_limited_noise

        rng = np.random.default_rng(scn["noise"]["seed"])     # band-limited to |f| <= B/2 (noise.py)
        echo += band_limited_noise(rng, n_p, n_r, sigma=sigma, fs_hz=fs, bandwidth_hz=radar["bandwidth_hz"])

    p_ref = pos0[0][None, :] + vel[None, :] * slow_time_s[:, None]
    los_az = np.degrees(np.arctan2(p_ref[:, 0], p_ref[:, 1]))
    p_mid = pos0[0] + vel * 0.5 * (slow_time_s[0] + slow_time_s[-1])
    n0 = -float(p_mid @ vel) / float(vel @ vel) * radar["prf_hz"]
    cube = RawCube(
        sum=echo, diff=None, slow_time_s=slow_time_s, range_m=range_m, scan_angle_deg=los_az,
        position_m=np.zeros((n_p, 3)), velocity_mps=np.zeros((n_p, 3)),
        radar={"fc_hz": fc, "bandwidth_hz": radar["bandwidth_hz"], "fs_hz": fs, "prf_hz": radar["prf_hz"],
               "beamwidth_3db_deg": BEAMWIDTH_NOT_USED_DEG, "pulse_width_s": radar["pulse_width_s"],
               "range_weighting": radar["range_weighting"]},
        truth={"x_m": pos0[:, 0].copy(), "y_m": pos0[:, 1].copy(), "z_m": pos0[:, 2].copy(),
               "amplitude": amps.copy(), "vx_mps": np.full(len(pos0), vel[0]),
               "vy_mps": np.full(len(pos0), vel[1]), "vz_mps": np.full(len(pos0), vel[2])},
        scenario_yaml=dump_scenario(scn),
        noise={"snr_db": np.nan if scn["noise"]["snr_db"] is None else scn["noise"]["snr_db"],
               "sigma": sigma, "seed": scn["noise"]["seed"],
               "band_hz": float(radar["bandwidth_hz"]) if sigma > 0.0 else 0.0},   # noise band-limited to |f| <= B/2
        attrs={"scenario_sha256": scenario_hash(scn), "scenario_name": scn["name"], "scenario_kind": "isar"},
    )
    stats = IsarSimulationStats(n_scatterers=len(pos0), n_pulses=n_p, kernel_samples=len(taps), n0_pulses=n0)
    return cube, stats


# ----------------------------------------------------------------------------------------------
# Small DSP helpers
# ----------------------------------------------------------------------------------------------
from .keystone import _cis  # noqa: E402  exp(j 2 pi cycles), reduced modulo one cycle in float64


def _oversample_rows(x, factor):
    """Band-limited oversampling of every row (axis 1), as metrics.oversample_profile row by row."""
    x = np.asarray(x)
    n = x.shape[1]
    m = n * factor
    spec = sfft.fft(x, axis=1, workers=-1)
    padded = np.zeros((x.shape[0], m), dtype=np.complex64 if x.dtype == np.complex64 else np.complex128)
    if n % 2:
        half = (n + 1) // 2
        padded[:, :half] = spec[:, :half]
        padded[:, m - (n - half):] = spec[:, half:]
    else:
        half = n // 2
        padded[:, :half] = spec[:, :half]
        padded[:, m - half + 1:] = spec[:, half + 1:]
        padded[:, half] += 0.5 * spec[:, half]
        padded[:, m - half] += 0.5 * spec[:, half]
    return sfft.ifft(padded, axis=1, workers=-1, overwrite_x=True) * factor


def peak_track(echo_rc, factor=TRACK_OVERSAMPLE, gate=None):
    """Per-pulse interpolated peak of range-time data ``[n_pulses, n_range]``.

    Each pulse's range profile is oversampled ``factor`` times (band-limited), its maximum (within
    ``gate = (lo, hi)`` range samples if given) refined by a three-point parabola on log power.
    Returns (position in range samples [n_pulses], peak power).
    """
    fine = _oversample_rows(echo_rc, factor)
    p = (fine.real.astype(np.float64) ** 2 + fine.imag.astype(np.float64) ** 2)
    del fine
    m = p.shape[1]
    rows = np.arange(p.shape[0])
    if gate is None:
        k = np.argmax(p, axis=1)
    else:
        lo = max(0, int(np.floor(gate[0] * factor)))
        hi = min(m, int(np.ceil(gate[1] * factor)) + 1)
        k = lo + np.argmax(p[:, lo:hi], axis=1)
    tiny = 1e-300
    lm = np.log(np.maximum(p[rows, (k - 1) % m], tiny))
    l0 = np.log(np.maximum(p[rows, k], tiny))
    lp = np.log(np.maximum(p[rows, (k + 1) % m], tiny))
    curv = lm - 2.0 * l0 + lp
    with np.errstate(divide="ignore", invalid="ignore"):
        off = np.where(curv < 0.0, 0.5 * (lm - lp) / curv, 0.0)
    off = np.clip(off, -1.0, 1.0)
    peak = np.exp(l0 + 0.5 * (lp - lm) * off + 0.5 * curv * off**2)
    return (k + off) / factor, peak


def migration_span_cells(echo_rc, *, smooth=SPAN_SMOOTH_PULSES, gate=None):
    """Migration span (module docstring, Metrics): max minus min of the smoothed per-pulse peak range,
    in range samples, over the pulses where the target is present.  ``gate = (lo, hi)`` (range samples)
    restricts the peak search to one scatterer's track.  Returns (span, positions, present).
    """
    pos, peak = peak_track(echo_rc, gate=gate)
    present = peak >= 0.25 * np.median(peak)
    track = pos[present]
    if smooth > 1 and track.size >= smooth:
        track = np.convolve(track, np.ones(smooth) / smooth, mode="valid")
    span = float(track.max() - track.min()) if track.size else math.nan
    return span, pos, present


def _alpha(order, fr_hz, fc_hz):
    if order == 1:
        return fc_hz / (fc_hz + fr_hz)                                 # eq. (11)
    return np.sqrt(fc_hz / (fc_hz + fr_hz))                            # eq. (12), second order


def _ambiguity_rows(ambiguity, doppler_hz, fr_hz, fc_hz, prf_hz):
    """Doppler ambiguity number per range-frequency row (module docstring)."""
    if ambiguity != "auto":
        return np.full(len(fr_hz), int(ambiguity), dtype=np.int64)
    if doppler_hz is None:
        return np.zeros(len(fr_hz), dtype=np.int64)
    return ambiguity_number((1.0 + np.asarray(fr_hz) / fc_hz) * doppler_hz, prf_hz)


def _keystone(echo_f, fr_hz, fc_hz, *, order, t0_index, ambiguity_rows, method):
    """Keystone every row about ``t0_index``, the observation zero-extended in slow time.

    The resampling positions ``t0 + alpha (m - t0)`` leave the observation by up to
    ``|1 - alpha| max|m - t0|`` pulses (about 300 for the paper's 5 deg case, whose centre lies outside
    the dwell); the periodic interpolant would fetch those from the other end of the dwell.  The rows
    are therefore padded with ``P`` zero pulses on each side (P = that excursion + 16) before the
    transform and cropped after it; an integer P leaves the ambiguity factor exp(j 2 pi F tau) unchanged.
    """
    from .keystone import KeystonePlan, keystone_dft

    alpha = _alpha(order, np.asarray(fr_hz, dtype=np.float64), fc_hz)
    n = echo_f.shape[0]
    excursion = float(np.max(np.abs(1.0 - alpha))) * max(abs(t0_index), abs(n - 1 - t0_index))
    pad = int(np.ceil(excursion)) + 16
    padded = np.zeros((n + 2 * pad, echo_f.shape[1]), dtype=np.complex64)
    padded[pad:pad + n] = echo_f
    if method == "dft":
        out = keystone_dft(padded, alpha, t0_index=t0_index + pad, ambiguity=ambiguity_rows)
    else:
        plan = KeystonePlan(n + 2 * pad, alpha, t0_index=t0_index + pad, dtype=np.complex64)
        out = plan(padded, ambiguity=ambiguity_rows)
    return np.ascontiguousarray(out[pad:pad + n], dtype=np.complex64)


def _to_freq(echo):
    return sfft.fftshift(sfft.fft(echo, axis=1, workers=-1), axes=1).astype(np.complex64)


def _to_time(echo_f):
    return sfft.ifft(sfft.ifftshift(echo_f, axes=1), axis=1, workers=-1).astype(np.complex64)


def _doppler_line(line):
    """A centred Doppler line made fit for :func:`~fwdlook_cli.metrics.oversample_profile`.

    The band-limited interpolation of a line assumes its inverse transform has a gap at the middle of
    FFT order; for a Doppler line that inverse transform is the full slow-time record, whose ends are
    at indices 0 and N - 1.  Delaying the record by N // 2 (a factor exp(j 2 pi i (N // 2) / N) on the
    line) moves its ends to the middle, so the interpolant is the DTFT of the record (magnitude exact
    between bins; positions unchanged).
    """
    n = len(line)
    return np.asarray(line) * _cis(np.arange(n) * (n // 2) / n)


def _model_reference(model: LineModel, slow_time_s, fc_hz):
    """exp(+j 4 pi f0 (R_m(t) - R0) / c): the model's carrier phase removed (paper eq. 10 term)."""
    return _cis(2.0 * fc_hz * (model.range_m(slow_time_s) - model.r0_m) / C_MPS)


def _model_from(model, attrs) -> LineModel | None:
    if model is None:
        return None
    if model == "estimate":
        return LineModel(attrs["model_r0_m"], attrs["model_rdot_mps"], attrs["model_v2_m2ps2"],
                         attrs["model_t_mid_s"])
    return LineModel(**model)


# ----------------------------------------------------------------------------------------------
# Stages: pure functions StageData -> StageData
# ----------------------------------------------------------------------------------------------
def range_fft(data: StageData) -> StageData:
    """Range-time echo -> centred range frequency (``echo_f`` [slow_time_s, range_freq_hz])."""
    out = data.copy_vars("slow_time_s", "range_m")
    echo = data["echo"]
    fr = sfft.fftshift(sfft.fftfreq(echo.shape[1], 1.0 / data.attrs["fs_hz"]))
    out.add("range_freq_hz", fr, ("range_freq_hz",), "Hz", "range frequency, centred")
    out.add("echo_f", _to_freq(echo), ("slow_time_s", "range_freq_hz"), "1",
            "range-frequency echo before range-migration correction")
    return out


def rcmc(data: StageData, *, correction: str, keystone: str = "czt", ambiguity="auto", n0_pulses="auto",
         model=None) -> StageData:
    """Range-cell-migration correction of ``echo_f`` (module docstring, Corrections).

    ``model``: the straight-line range model (dict of :class:`LineModel` fields, from the cube's truth),
    ``"estimate"`` (from the attributes :func:`estimate_n0` wrote) or None.  ``n0_pulses``: a number
    (pulses from the middle of the observation to the keystone centre) or "auto" (from the model).
    """
    out = data.copy_vars("slow_time_s", "range_m", "range_freq_hz")
    echo_f = data["echo_f"]
    fr = np.asarray(data["range_freq_hz"], dtype=np.float64)
    fc, prf = float(data.attrs["fc_hz"]), float(data.attrs["prf_hz"])
    n = echo_f.shape[0]
    t_mid_index = (n - 1) / 2.0
    m = _model_from(model, data.attrs)
    doppler = None if m is None else m.doppler_hz(fc)
    shift = 0.0
    if correction in ("keystone2_n0", "keystone2_n0_est"):
        if n0_pulses != "auto":
            shift = float(n0_pulses)
        elif m is not None:
            shift = m.n0_pulses(prf)                                   # eq. (13), corrected
        else:
            raise BadInput(f"processing.correction = {correction}: needs the target geometry (cube "
                           f"/truth/targets with velocity) or processing.n0_pulses; allowed without "
                           f"them: keystone2_n0_est")
    t0 = t_mid_index + shift
    if correction == "none":
        corrected = echo_f
        rows = np.zeros(len(fr), dtype=np.int64)
    else:
        rows = _ambiguity_rows(ambiguity, doppler, fr, fc, prf)
        corrected = _keystone(echo_f, fr, fc, order=1 if correction == "keystone1" else 2, t0_index=t0,
                              ambiguity_rows=rows, method=keystone)
    out.add("echo_f", corrected, ("slow_time_s", "range_freq_hz"), "1",
            f"range-frequency echo after correction {correction}")
    out.add("ambiguity_number", rows, ("range_freq_hz",), "1", "Doppler ambiguity number per row")
    out.attrs.update(correction=correction, keystone_centre_index=float(t0), n0_used_pulses=float(shift),
                     t_ref_s=float(t0 / prf))
    return out


def range_ifft(data: StageData) -> StageData:
    """Corrected range-frequency echo -> range time (``echo_rc`` [slow_time_s, range_m])."""
    out = data.copy_vars("slow_time_s", "range_m", "ambiguity_number", "range_freq_hz")
    out.add("echo_rc", _to_time(data["echo_f"]), ("slow_time_s", "range_m"), "1",
            "range-compressed echo after range-migration correction")
    return out


def azimuth_compress(data: StageData, *, phase: str = "model", model=None) -> StageData:
    """Model phase compensation and slow-time FFT per range cell: ``image`` [range_m, doppler_hz].

    ``phase = "model"`` multiplies by ``exp(+j 4 pi f0 (R_m(t) - R0) / c)`` (module docstring, Azimuth
    compression) before the FFT; ``"none"`` takes the plain FFT.  Doppler is centred, unweighted.
    """
    out = data.copy_vars("slow_time_s", "range_m", "echo_rc", "range_freq_hz", "ambiguity_number")
    echo = data["echo_rc"]
    t = np.asarray(data["slow_time_s"], dtype=np.float64)
    prf = float(data.attrs["prf_hz"])
    n = echo.shape[0]
    m = _model_from(model, data.attrs) if phase == "model" else None
    z = echo if m is None else echo * _model_reference(m, t, data.attrs["fc_hz"]).astype(np.complex64)[:, None]
    img = sfft.fftshift(sfft.fft(z, axis=0, workers=-1), axes=0).T.astype(np.complex64)
    doppler = (np.arange(n) - n // 2) * prf / n
    out.add("doppler_hz", doppler, ("doppler_hz",), "Hz", "Doppler relative to the range model, centred")
    out.add("image", img, ("range_m", "doppler_hz"), "1", "ISAR image (complex), range x Doppler")
    if m is not None:
        out.attrs.update({f"azimuth_model_{k}": v for k, v in m.as_dict().items()})
    out.attrs["azimuth_phase"] = phase
    return out


# ----------------------------------------------------------------------------------------------
# n0 estimation
# ----------------------------------------------------------------------------------------------
def _sharpness(cells, t_rel, fc, r0, rdot, v2_grid):
    """Image sharpness sum|I|^4 / (sum|I|^2)^2 for every |v|^2 candidate (model phase, then FFT)."""
    tau = t_rel[:, None]
    rm = np.sqrt(np.maximum(r0**2 + 2.0 * r0 * rdot * tau + v2_grid[None, :] * tau**2, 0.0)) - r0
    ref = _cis(2.0 * fc * rm / C_MPS).astype(np.complex64)             # [N, J]
    z = cells[:, :, None] * ref[:, None, :]                             # [N, C, J]
    spec = sfft.fft(z, axis=0, workers=-1)
    p = spec.real.astype(np.float64) ** 2 + spec.imag.astype(np.float64) ** 2
    return np.sum(p**2, axis=(0, 1)) / np.sum(p, axis=(0, 1)) ** 2


def _doppler_peak_hz(cells, t_rel, fc, r0, rdot, v2, prf):
    """Interpolated Doppler of the peak of the model-compensated image of ``cells``."""
    from .metrics import interpolate_peak, oversample_profile

    ref = _cis(2.0 * fc * (LineModel(r0, rdot, v2, 0.0).range_m(t_rel) - r0) / C_MPS)
    spec = sfft.fftshift(sfft.fft(cells * ref[:, None].astype(np.complex64), axis=0), axes=0)
    c = int(np.argmax(np.sum(np.abs(spec) ** 2, axis=0)))
    line = _doppler_line(spec[:, c])
    factor = 8
    fine = np.abs(oversample_profile(line, factor)) ** 2
    k = int(np.argmax(fine))
    k = min(max(k, 1), fine.size - 2)
    idx, _ = interpolate_peak(fine, k)
    n = len(line)
    return (idx / factor - n // 2) * prf / n


def _refine_max(grid, values):
    """Parabolic refinement of a sampled maximum (on log values); returns (x, index of the max)."""
    j = int(np.argmax(values))
    if 0 < j < len(grid) - 1 and np.all(values[j - 1:j + 2] > 0):
        lm, l0, lp = np.log(values[j - 1:j + 2])
        curv = lm - 2.0 * l0 + lp
        if curv < 0:
            off = float(np.clip(0.5 * (lm - lp) / curv, -1.0, 1.0))
            return grid[j] + off * (grid[j + 1] - grid[j]), j
    return float(grid[j]), j


def estimate_n0(data: StageData, *, half_span_lobes: float = 4.0, points_per_lobe: int = 6, passes: int = 2,
                ambiguity="auto", keystone: str = "czt") -> StageData:
    """Estimate n0 from the data (module docstring, Estimating n0); the echo passes through.

    Adds the attributes ``n0_est_pulses``, ``n0_coarse_pulses``, ``model_r0_m``, ``model_rdot_mps``,
    ``model_v2_m2ps2``, ``model_t_mid_s``, ``doppler_centroid_hz``, ``ambiguity_centre`` and the last
    search grid (``n0_search_pulses`` and ``n0_search_sharpness``).
    """
    out = StageData(dict(data.vars), dict(data.attrs))
    echo = data["echo"]
    t = np.asarray(data["slow_time_s"], dtype=np.float64)
    rng = np.asarray(data["range_m"], dtype=np.float64)
    fc, prf, fs = float(data.attrs["fc_hz"]), float(data.attrs["prf_hz"]), float(data.attrs["fs_hz"])
    lam = C_MPS / fc
    n = echo.shape[0]
    t_mid = 0.5 * (t[0] + t[-1])
    t_rel = t - t_mid
    dwell = t[-1] - t[0] + 1.0 / prf
    dr = rng[1] - rng[0]

    # (1) coarse: quadratic fit of the per-pulse peak range
    pos, peak = peak_track(echo)
    ok = peak >= 0.25 * np.median(peak)
    c2, c1, c0 = np.polyfit(t_rel[ok], rng[0] + pos[ok] * dr, 2)
    r0, rdot, rddot = float(c0), float(c1), 2.0 * float(c2)
    lobe_v2 = lam * r0 / (2.0 * dwell**2)                              # |v|^2 error of one lobe
    v2 = max(r0 * rddot + rdot**2, rdot**2 + lobe_v2)
    n0_coarse = -r0 * rdot * prf / v2

    # (2) n0-shifted second-order keystone at the coarse n0, range cells of the target
    fr = sfft.fftshift(sfft.fftfreq(echo.shape[1], 1.0 / fs))
    rows = _ambiguity_rows(ambiguity, -2.0 * rdot / lam, fr, fc, prf)
    y = _to_time(_keystone(_to_freq(echo), fr, fc, order=2, t0_index=(n - 1) / 2.0 + n0_coarse,
                           ambiguity_rows=rows, method=keystone))
    energy = np.sum(np.abs(y) ** 2, axis=0)
    top = int(np.argmax(energy))
    sel = np.nonzero(energy >= 0.1 * energy[top])[0]
    sel = sel[np.abs(sel - top) <= 4]
    cells = y[:, sel]

    # (3)-(4) sharpness search over the model (one |v|^2 per candidate n0), then Doppler refinement
    half, step = half_span_lobes * lobe_v2, lobe_v2 / points_per_lobe
    grid = sharp = None
    for _ in range(passes):
        for _shift in range(8):                                         # follow a maximum at the edge
            grid = v2 + np.arange(-half, half + 0.5 * step, step)
            grid = grid[grid > rdot**2]
            sharp = _sharpness(cells, t_rel, fc, r0, rdot, grid)
            j = int(np.argmax(sharp))
            if 0 < j < len(grid) - 1:
                break
            v2 = float(grid[j])
        v2, _ = _refine_max(grid, sharp)
        rdot -= lam * _doppler_peak_hz(cells, t_rel, fc, r0, rdot, v2, prf) / 2.0
        half, step = 2.0 * step, step / 4.0
    model = LineModel(r0, rdot, v2, t_mid)
    n0_grid = -r0 * rdot * prf / grid
    out.add("n0_search_pulses", n0_grid, ("n0_candidate",), "1", "n0 of each candidate of the last pass")
    out.add("n0_search_sharpness", sharp, ("n0_candidate",), "1", "image sharpness sum|I|^4/(sum|I|^2)^2")
    out.attrs.update(n0_est_pulses=model.n0_pulses(prf), n0_coarse_pulses=float(n0_coarse),
                     doppler_centroid_hz=model.doppler_hz(fc),
                     ambiguity_centre=int(ambiguity_number(model.doppler_hz(fc), prf)),
                     **{f"model_{k}": v for k, v in model.as_dict().items()})
    return out


# ----------------------------------------------------------------------------------------------
# The chain
# ----------------------------------------------------------------------------------------------
def build_isar_stages(cube, processing: dict):
    """Source data and stage list for ``processing`` (the resolved ``processing:`` section).

    Stages: [``estimate_n0``] ``range_fft``, ``rcmc``, ``range_ifft``, ``azimuth_compress``.
    ``estimate_n0`` runs for ``keystone2_n0_est`` and for a cube without truth (whose range model then
    comes from the data).  Everything the stages need from the cube's truth is passed as explicit
    parameters (the model dict), never read from the scenario.
    """
    correction = processing["correction"]
    if correction not in CORRECTIONS:
        raise BadInput(f"processing.correction = {correction!r}: allowed: {', '.join(CORRECTIONS)}")
    truth_model = _truth_line_model(cube)
    estimate = correction == "keystone2_n0_est" or truth_model is None
    if (correction == "keystone2_n0" and truth_model is None
            and processing.get("n0_pulses", "auto") == "auto"):
        raise BadInput("processing.correction = keystone2_n0: the cube has no /truth/targets geometry "
                       "(position and velocity) to give n0 (eq. 13); set processing.n0_pulses or use "
                       "keystone2_n0_est")
    model = "estimate" if estimate else truth_model.as_dict()
    src = StageData()
    src.add("slow_time_s", cube.slow_time_s, ("slow_time_s",), "s", "slow time, t = 0 at the first pulse")
    src.add("range_m", cube.range_m, ("range_m",), "m", "slant range")
    src.add("echo", cube.sum, ("slow_time_s", "range_m"), "1", "range-compressed echo (single channel)")
    src.attrs.update({k: float(cube.radar[k]) for k in ("fc_hz", "prf_hz", "fs_hz", "bandwidth_hz")})
    stages = []
    if estimate:
        search = processing.get("n0_search", {})
        stages.append(Stage("estimate_n0", estimate_n0, {
            "half_span_lobes": float(search.get("half_span_lobes", 4.0)),
            "points_per_lobe": int(search.get("points_per_lobe", 6)),
            "passes": int(search.get("passes", 2)),
            "ambiguity": processing.get("ambiguity", "auto"), "keystone": processing.get("keystone", "czt")}))
    n0 = processing.get("n0_pulses", "auto")
    if correction == "keystone2_n0_est":
        n0 = "auto"
    stages += [
        Stage("range_fft", range_fft, {}),
        Stage("rcmc", rcmc, {"correction": correction, "keystone": processing.get("keystone", "czt"),
                             "ambiguity": processing.get("ambiguity", "auto"), "n0_pulses": n0,
                             "model": model}),
        Stage("range_ifft", range_ifft, {}),
        Stage("azimuth_compress", azimuth_compress, {"phase": processing.get("azimuth_phase", "model"),
                                                     "model": model}),
    ]
    return src, stages


def run_isar_stages(cube, processing: dict):
    """Run the stage functions in memory (no files); returns (final StageData, timings in s)."""
    data, stages = build_isar_stages(cube, processing)
    timings = {}
    for st in stages:
        t0 = time.perf_counter()
        data = st.fn(data, **st.params)
        timings[st.name] = time.perf_counter() - t0
    return data, timings


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
    from .pulse import CompressedPulse

    r = cube.radar
    if cube.truth:
        p0 = 1.0
        if "pulse_width_s" in r:
            p0 = float(abs(CompressedPulse(r["bandwidth_hz"], float(r["pulse_width_s"]), r["fs_hz"],
                                           str(r.get("range_weighting", "none")))(0.0)))
        return n_pulses * float(cube.truth["amplitude"][0]) * p0, "closed_form N a |p(0)|"
    _, peak = peak_track(cube.sum)
    return n_pulses * float(np.sqrt(np.median(peak))), "N x median per-pulse peak amplitude (no truth)"


@dataclass(frozen=True)
class _Cut:
    peak_index: float   # fractional sample of the local peak (band-limited, log-parabola)
    peak_power: float
    width_3db: float    # shape metrics from profile_metrics (module docstring, Metrics)
    pslr_db: float
    islr_db: float


def _cut_metrics(line, idx, spacing, factor=16):
    """Local peak of a band-limited line near sample ``idx``, with its width, PSLR and ISLR.

    The position and the peak come from the exact band-limited interpolant of the whole line,
    searched within +-1.5 samples of ``idx`` (so a stronger scatterer elsewhere on the line is not
    taken); the shape metrics from :func:`~fwdlook_cli.metrics.profile_metrics` on the whole line when
    this peak is the line's maximum, else on the +-32 samples around it.
    """
    from .metrics import interpolate_peak, oversample_profile, profile_metrics

    line = np.asarray(line)
    n = len(line)
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
                i, j, _ = gated_peak(0.5 * (lo_m + hi_m), 0.5 * (hi_m - lo_m), pred_f, wide_f)
                _, _, peak = _measure_peak(img, i, j, dr, df)
                row["integration_gain_db"] = 10.0 * math.log10(max(peak, 1e-300) / ideal**2)
            rows.append(row)
        ref_row = rows[0]
    else:
        i, j = np.unravel_index(int(np.argmax(power)), power.shape)
        rm, am, peak = _measure_peak(img, int(i), int(j), dr, df)
        ref_row = {"peak_power": peak, "range_width_3db_m": rm.width_3db,
                   "cross_range_width_3db_m": am.width_3db * abs(xscale), "islr_db": rm.islr_db,
                   "pslr_db": rm.pslr_db, "azimuth_islr_db": am.islr_db, "azimuth_pslr_db": am.pslr_db,
                   "integration_gain_db": 10.0 * math.log10(max(peak, 1e-300) / ideal**2)}
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


# ----------------------------------------------------------------------------------------------
# Run directory (called by ``fwdlook run`` / ``fwdlook process`` for kind: isar)
# ----------------------------------------------------------------------------------------------
def process_isar_cube(cube, scn: dict, run_dir, *, force=False, from_stage=None, quiet=False,
                      png=True) -> dict:
    """Run the ISAR chain with its stage files, write image.h5, image.png and metrics.json."""
    from .config import dump_scenario, scenario_hash
    from .io import atomic_h5, atomic_write_text, put, put_scale
    from .pipeline import run_stages
    from .process import cube_hash

    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    proc = scn["processing"]
    t_start = time.perf_counter()
    src, stages = build_isar_stages(cube, proc)
    names = [st.name for st in stages]
    if from_stage is not None and from_stage not in names:
        from .errors import BadInput

        raise BadInput(f"--from-stage {from_stage}: unknown stage; allowed: {', '.join(names)}")
    for name in ("metrics.json", "image.h5", "image.png", "scenario.yaml"):   # no stale outputs
        (run_dir / name).unlink(missing_ok=True)
    final, timings, keys = run_stages(stages, src, cube_hash(cube), run_dir, force=force,
                                      from_stage=from_stage, quiet=quiet)
    t_out = time.perf_counter()
    image, metrics = isar_outputs(final, cube, proc)
    with atomic_h5(run_dir / "image.h5") as f:
        for k, v in image.attrs.items():
            f.attrs[k] = v
        f.attrs["scenario"] = dump_scenario(scn)
        r = put_scale(f, "range_m", image["range_m"], "m", image.vars["range_m"].long_name)
        d = put_scale(f, "doppler_hz", image["doppler_hz"], "Hz", image.vars["doppler_hz"].long_name)
        put(f, "cross_range_m", image["cross_range_m"], "m", image.vars["cross_range_m"].long_name, dims=(d,))
        put(f, "image", image["image"], "1", image.vars["image"].long_name, dims=(r, d))
    if png:
        _save_image_quicklook(run_dir / "image.png", image, title=f"{scn['name']}: ISAR {proc['correction']}")
    timings["outputs"] = time.perf_counter() - t_out
    timing = {k: float(v) for k, v in timings.items()}
    timing["total"] = time.perf_counter() - t_start
    metrics.update(scenario=scn["name"], scenario_sha256=scenario_hash(scn), stage_sha256=keys,
                   timing_s=timing)
    atomic_write_text(run_dir / "metrics.json", json.dumps(metrics, indent=1, allow_nan=False))
    atomic_write_text(run_dir / "scenario.yaml", dump_scenario(scn))   # last: the run is complete
    return metrics


def _save_image_quicklook(path, image: StageData, *, title, half_bins=48):
    from .plots import save_image_png

    p = image["image"]
    i, j = np.unravel_index(int(np.argmax(p)), p.shape)
    lo, hi = max(0, j - half_bins), min(p.shape[1], j + half_bins + 1)
    x = image["cross_range_m"][lo:hi]
    label = "cross-range (m)"
    if not np.all(np.isfinite(x)):
        x, label = image["doppler_hz"][lo:hi], "Doppler (Hz)"
    order = np.argsort(x)
    save_image_png(path, p[:, lo:hi][:, order], x[order], image["range_m"], xlabel=label,
                   ylabel="slant range at t_ref (m)", title=title)


# ----------------------------------------------------------------------------------------------
# The correction table and the paper's figures
# ----------------------------------------------------------------------------------------------
PAPER_SCENARIOS = ("isar_theta3.yaml", "isar_theta5.yaml")


def _scenario_dir() -> Path:
    return Path(__file__).resolve().parents[1] / "scenarios"


def isar_correction_table(scn_paths=None, corrections=CORRECTIONS, overrides=()):
    """For each scenario and correction, run the stages in memory; returns a list of row dicts with
    keys scenario, correction, migration_span_cells (resolution cells c / (2 B)), migration_span_samples
    (range samples c / (2 fs)), migration_span_m, integration_gain_db, n0_true, n0_est (n0_est only
    for keystone2_n0_est; pulses from the middle of the observation)."""
    from .config import load_scenario

    paths = [Path(p) for p in (scn_paths or [_scenario_dir() / name for name in PAPER_SCENARIOS])]
    rows = []
    for path in paths:
        scn = load_scenario(path, overrides)
        cube, _ = simulate_isar_scenario(scn)
        for corr in corrections:
            proc = dict(scn["processing"], correction=corr)
            final, _ = run_isar_stages(cube, proc)
            _, met = isar_outputs(final, cube, proc)
            s = met["summary"]
            rows.append({"scenario": scn["name"], "correction": corr,
                         "migration_span_cells": s["migration_span_cells"],
                         "migration_span_samples": s["migration_span_samples"],
                         "migration_span_m": s["migration_span_m"],
                         "integration_gain_db": s["integration_gain_db"],
                         "n0_true": s["n0_true_pulses"], "n0_est": s["n0_est_pulses"]})
    return rows


def format_isar_table(rows) -> str:
    """Markdown table of :func:`isar_correction_table` rows."""
    lines = ["| scenario | correction | migration span (resolution cells c/2B) | migration span (samples c/2fs) "
             "| migration span (m) | integration gain (dB) | n0 true | n0 est |",
             "|---|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        est = "" if r["n0_est"] is None else f"{r['n0_est']:.1f}"
        true = "" if r["n0_true"] is None else f"{r['n0_true']:.1f}"
        samples = r.get("migration_span_samples")
        span_m = r.get("migration_span_m")
        lines.append(f"| {r['scenario']} | {r['correction']} | {r['migration_span_cells']:.2f} | "
                     f"{'' if samples is None else f'{samples:.2f}'} | {'' if span_m is None else f'{span_m:.3f}'} | "
                     f"{r['integration_gain_db']:.2f} | {true} | {est} |")
    return "\n".join(lines)


def save_isar_figures(out_dir, scn_paths=None, *, correction="keystone2_n0", overrides=(), max_columns=1000):
    """Figures like the paper's Fig. 3-6: raw echo magnitude (range x slow time) before and after the
    range-migration compensation, and the ISAR image, for each scenario (default: theta0 = 3 and 5 deg).

    Writes ``<name>_echo_before.png``, ``<name>_echo_after.png`` and ``<name>_image.png`` per scenario
    into ``out_dir``; returns the paths.
    """
    from .config import load_scenario
    from .plots import save_image_png

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [Path(p) for p in (scn_paths or [_scenario_dir() / name for name in PAPER_SCENARIOS])]
    written = []
    for path in paths:
        scn = load_scenario(path, overrides)
        cube, _ = simulate_isar_scenario(scn)
        proc = dict(scn["processing"], correction=correction)
        final, _ = run_isar_stages(cube, proc)
        image, _ = isar_outputs(final, cube, proc)
        step = max(1, cube.n_pulses // max_columns)
        t = cube.slow_time_s[::step]
        th = scn["target"]["theta0_deg"]
        for tag, echo, what in (("before", cube.sum, "before"),
                                ("after", final["echo_rc"], f"after {correction}")):
            p = np.abs(echo[::step]).T.astype(np.float64) ** 2
            fname = out_dir / f"{scn['name']}_echo_{tag}.png"
            save_image_png(fname, p, t, cube.range_m, xlabel="slow time (s)", ylabel="slant range (m)",
                           title=f"{scn['name']}: raw echo {what} range-migration compensation, "
                                 f"theta0 = {th:g} deg", dynamic_range_db=40)
            written.append(fname)
        fname = out_dir / f"{scn['name']}_image.png"
        _save_image_quicklook(fname, image, title=f"{scn['name']}: ISAR image, {correction}")
        written.append(fname)
    return written
