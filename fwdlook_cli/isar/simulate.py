"""ISAR simulation: exact range (eq. 6-7), stop-and-hop, one channel (sum)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..dsp.geometry import C_MPS
from ..scenario.isar import isar_auto_range_axis, isar_geometry, scatterer_ranges_m

BEAMWIDTH_NOT_USED_DEG = 10.0  # /radar beamwidth_3db_deg of ISAR cubes: a wide beam, not simulated


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
    compressed pulse ``p`` (:class:`~fwdlook_cli.dsp.pulse.CompressedPulse`); the carrier phase is reduced
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
    from ..scenario.loader import dump_scenario, scenario_hash
    from ..io.cube import RawCube
    from ..dsp.pulse import CompressedPulse
    from ..dsp.pulse import noise_sigma_for

    radar = scn["radar"]
    fc, fs = radar["fc_hz"], radar["fs_hz"]
    slow_time_s, pos0, vel, amps = isar_geometry(scn)
    n_p = len(slow_time_s)
    pulse = CompressedPulse(radar["bandwidth_hz"], radar["pulse_width_s"], fs, radar["range_weighting"])
    r_kn = scatterer_ranges_m(pos0, vel, slow_time_s)                  # eq. (7), exact
    dr = C_MPS / (2.0 * fs)
    if radar["range_window_m"] == "auto":
        range_m = isar_auto_range_axis(pos0, vel, r_kn, fs, pulse)[0]
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
        from ..dsp.noise import add_band_limited_noise

        rng = np.random.default_rng(scn["noise"]["seed"])     # band-limited to |f| <= B/2 (noise.py)
        add_band_limited_noise(rng, echo, sigma=sigma, fs_hz=fs, bandwidth_hz=radar["bandwidth_hz"])

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
