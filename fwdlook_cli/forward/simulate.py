"""Exact-geometry simulation of range-compressed sum and difference echoes (paper eq. 1, 5).

For each target k and pulse n the echo is

    s_sum(r, n)  = a_k Sigma(d_kn)^2          p(2 (r - R_kn)/c) exp(-j 4 pi f_c R_kn / c)
    s_diff(r, n) = a_k Sigma(d_kn) Delta(d_kn) p(2 (r - R_kn)/c) exp(-j 4 pi f_c R_kn / c)

with R_kn the exact slant range of eq. (1) (stop-and-hop), d_kn the ground-plane azimuth of the target
minus the beam pointing angle, p the compressed pulse (``pulse.py``) and Sigma, Delta the monopulse
patterns (``antenna.py``).  Only the work the scene needs is done:

* a target-pulse pair whose two-way power gain Sigma^4 is below ``gain_threshold_db`` is skipped
  (-60 dB by default: a target more than about 9.7 deg off the 6 deg beam);
* each kept pair writes only the range samples its kernel reaches (|tau| < pulse width, where the
  compressed chirp is exactly zero beyond).

Everything is vectorised over pairs x kernel samples; pairs are processed in chunks to bound memory
and accumulated with ``np.bincount`` on flat indices (several targets may hit the same sample).
Noise is circular complex Gaussian, band-limited in range frequency to |f_r| <= B/2 like the echo
(``noise.py``), with variance sigma^2 per range-compressed sample in each channel,
``sigma^2 = a_ref^2 / 10^(snr_db/10)`` with ``a_ref`` the largest target amplitude: the SNR is that of
the peak sample of the strongest target at beam centre, and since all the noise is in band it is also
the in-band SNR.
"""
from __future__ import annotations

import logging

import numpy as np

from ..errors import BadInput
from ..dsp.antenna import MonopulseAntenna, antenna_from_scenario
from ..dsp.geometry import C_MPS, azimuth_deg, scan_angle_deg, slant_range_m
from ..scenario.forward import scene_geometry
from ..dsp.pulse import CompressedPulse
from ..dsp.pulse import auto_range_axis_m, noise_sigma_for
from ..dsp.noise import band_limited_noise
from ..dsp.geometry import range_extent_m
from .scene_sim import SimulationStats, simulate_scene_echo

RANGE_GUARD_SAMPLES = 8


def simulate_echo(slow_time_s, position_m, beam_deg, range_m, targets_m, amplitudes, *, fc_hz,
                  pulse: CompressedPulse, antenna: MonopulseAntenna, gain_threshold_db=-60.0,
                  noise_sigma=0.0, seed=None, max_chunk_samples=4_000_000, diff_gain_db=0.0,
                  diff_phase_deg=0.0):
    """Sum and difference channel echoes, complex64 [n_pulses, n_range] each, and work statistics.

    Parameters
    ----------
    slow_time_s : (n_pulses,) pulse times (only the count is used; motion is in ``position_m``).
    position_m : (n_pulses, 3) antenna phase centre.
    beam_deg : (n_pulses,) beam pointing azimuth.
    range_m : (n_range,) uniformly spaced slant-range axis.
    targets_m : (n_targets, 3) target positions; amplitudes : (n_targets,).
    antenna : any antenna model of ``antenna.py`` (``two_way_gains``).
    diff_gain_db, diff_phase_deg : receiver imbalance; the difference channel's echo is multiplied by
        10^(g/20) exp(j phi) (noise is added after, at the same level in both channels).
    """
    n_p, n_r = len(slow_time_s), len(range_m)
    dr = float(range_m[1] - range_m[0])
    r_kn = slant_range_m(position_m, targets_m)                      # eq. (1), exact
    offset_deg = azimuth_deg(position_m, targets_m) - np.asarray(beam_deg)[None, :]
    g_sum, g_diff = antenna.two_way_gains(offset_deg)
    keep = 20.0 * np.log10(np.maximum(g_sum, 1e-300)) >= gain_threshold_db  # two-way power gain
    k_idx, n_idx = np.nonzero(keep)
    amp = np.asarray(amplitudes, dtype=np.float64)[k_idx]
    r = r_kn[k_idx, n_idx]
    # eq. (5): carrier phase -4 pi fc R / c, reduced in float64 before it is used in float32
    phasor = np.exp(-2j * np.pi * np.mod(2.0 * r * fc_hz / C_MPS, 1.0))
    c_sum = (amp * g_sum[k_idx, n_idx] * phasor).astype(np.complex64)
    imbalance = 10.0 ** (diff_gain_db / 20.0) * np.exp(1j * np.radians(diff_phase_deg))
    c_diff = (amp * g_diff[k_idx, n_idx] * phasor * imbalance).astype(np.complex64)

    half = int(np.ceil(C_MPS * pulse.support_s / 2.0 / dr))
    width = 2 * half + 1
    delay = (r - range_m[0]) / dr                                   # fractional sample index
    first = np.floor(delay).astype(np.int64) - half + 1
    taps = np.arange(width, dtype=np.int64)

    acc = np.zeros(4 * n_p * n_r, dtype=np.float64)                 # sum re, sum im, diff re, diff im
    chunk = max(1, max_chunk_samples // width)
    for lo in range(0, len(r), chunk):
        sl = slice(lo, lo + chunk)
        col = first[sl, None] + taps[None, :]                        # [pairs, width] range sample
        tau = 2.0 * (range_m[0] + col * dr - r[sl, None]) / C_MPS
        kern = pulse(tau)
        inside = (col >= 0) & (col < n_r)
        flat = (n_idx[sl, None] * n_r + np.clip(col, 0, n_r - 1))[inside]
        v_sum = (kern * c_sum[sl, None])[inside]
        v_diff = (kern * c_diff[sl, None])[inside]
        size = n_p * n_r
        for j, part in enumerate((v_sum.real, v_sum.imag, v_diff.real, v_diff.imag)):
            acc[j * size:(j + 1) * size] += np.bincount(flat, weights=part, minlength=size)
    acc = acc.reshape(4, n_p, n_r)
    echo_sum = (acc[0] + 1j * acc[1]).astype(np.complex64)
    echo_diff = (acc[2] + 1j * acc[3]).astype(np.complex64)
    if noise_sigma > 0.0:
        rng = np.random.default_rng(seed)
        for echo in (echo_sum, echo_diff):      # band-limited to |f_r| <= B/2 like the echo (noise.py)
            echo += band_limited_noise(rng, n_p, n_r, sigma=noise_sigma, fs_hz=pulse.fs_hz,
                                       bandwidth_hz=pulse.bandwidth_hz)
    stats = SimulationStats(n_pairs=int(keep.size), n_pairs_kept=int(len(r)), kernel_samples=width,
                            samples_written=int(len(r)) * width)
    return echo_sum, echo_diff, stats


MAX_TARGETS_CHECKED = 10_000      # (the check is n_targets x n_pulses / 8 angles; larger scenes are images)


def warn_unseen_targets(position_m, beam_deg, targets_m, antenna, gain_threshold_db, source) -> None:
    """One warning naming the targets the beam never reaches (the two-way gain under the simulator's
    threshold on every pulse: behind the platform, outside the scanned sector): they leave no echo and
    cannot be imaged, and the metrics count them as missed (an independent review ran a point behind the
    platform to "detected 0/1" with nothing said).  Every 8th pulse (the beam moves under 0.1 deg)."""
    if len(targets_m) == 0 or len(targets_m) > MAX_TARGETS_CHECKED:
        return
    offset = azimuth_deg(position_m[::8], targets_m) - np.asarray(beam_deg)[None, ::8]
    g_sum, _ = antenna.two_way_gains(offset)
    seen = np.any(20.0 * np.log10(np.maximum(g_sum, 1e-300)) >= gain_threshold_db, axis=1)
    unseen = np.flatnonzero(~seen)
    if len(unseen):
        az = azimuth_deg(position_m[len(position_m) // 2:len(position_m) // 2 + 1], targets_m[unseen])[:, 0]
        listed = ", ".join(f"{i} at ({targets_m[i, 0]:g}, {targets_m[i, 1]:g}) m, azimuth {a:.1f} deg"
                           for i, a in zip(unseen[:3], az[:3]))
        logging.getLogger(__name__).warning(
            f"{source}: {len(unseen)} of {len(targets_m)} targets never in the beam (the scan covers "
            f"{float(np.min(beam_deg)):g} to {float(np.max(beam_deg)):g} deg; two-way gain under "
            f"{gain_threshold_db:g} dB on every pulse): {listed}{', ...' if len(unseen) > 3 else ''}; they "
            f"leave no echo and count as missed")


def antenna_group(antenna, diff_gain_db=0.0, diff_phase_deg=0.0) -> dict:
    """The cube's /antenna group (CONTRACT.md section 3): the model's attributes, its monotone ratio
    table over the main lobe (datasets ``ratio_offset_deg``, ``ratio``) and the channel imbalance."""
    out = antenna.to_attrs()
    offset, ratio = antenna.ratio_table
    step = max(1, len(offset) // 400)
    out["ratio_offset_deg"] = np.asarray(offset[::step], dtype=np.float64)
    out["ratio"] = np.asarray(ratio[::step], dtype=np.float64)
    out["diff_gain_db"] = float(diff_gain_db)
    out["diff_phase_deg"] = float(diff_phase_deg)
    return out


def simulate_scenario(scn: dict, *, in_memory_x_cube: float | None = None, doing: str = "simulating",
                      source: str | None = None):
    """Simulate a resolved forward-looking scenario: returns (RawCube, SimulationStats).

    ``in_memory_x_cube``: where given, the memory the caller's in-memory work (``doing``, as the line
    names it) needs in cubes (``io.backing.memory_hint``); a cube that would not fit logs one warning
    naming ``source`` and ``--out-of-core`` before it is simulated."""
    from ..scenario.loader import dump_scenario, scenario_hash
    from ..io.cube import RawCube
    from ..io import backing

    radar, ant = scn["radar"], scn["antenna"]
    slow_time_s, position_m, velocity_mps, targets_m, amps = scene_geometry(scn)
    pulse = CompressedPulse(radar["bandwidth_hz"], radar["pulse_width_s"], radar["fs_hz"],
                            radar["range_weighting"])
    antenna = antenna_from_scenario(ant)
    beam_deg = scan_angle_deg(slow_time_s, ant["scan_start_deg"], ant["scan_rate_dps"])
    if radar["range_window_m"] == "auto":
        range_m = auto_range_axis_m(*range_extent_m(position_m, targets_m), radar["fs_hz"], pulse, positive=True)
    else:
        near, far = radar["range_window_m"]
        dr = C_MPS / (2.0 * radar["fs_hz"])
        range_m = near + dr * np.arange(int(np.floor((far - near) / dr)) + 1)
    if in_memory_x_cube is not None:
        hint = backing.memory_hint(2 * 8 * len(slow_time_s) * len(range_m), in_memory_x_cube, doing)
        if hint:                                       # said before the work that may not fit
            logging.getLogger(__name__).warning(f"{source or scn['name']}: {hint}")
    if scn["scene"]["kind"] != "image":
        warn_unseen_targets(position_m, beam_deg, targets_m, antenna, scn["simulation"]["gain_threshold_db"],
                            source or scn["name"])
    sigma = noise_sigma_for(scn["noise"]["snr_db"], amps)
    echo_sum, echo_diff, stats = simulate_scene_echo(   # scene_sim.py: gated pairs only, any scene size
        slow_time_s, position_m, beam_deg, range_m, targets_m, amps, fc_hz=radar["fc_hz"],
        pulse=pulse, antenna=antenna, gain_threshold_db=scn["simulation"]["gain_threshold_db"],
        noise_sigma=sigma, seed=scn["noise"]["seed"], diff_gain_db=ant["diff_gain_db"],
        diff_phase_deg=ant["diff_phase_deg"])
    if scn["scene"]["kind"] == "image" and stats.n_pairs_kept == 0 and stats.n_pairs > 0:
        # (the points' check above, per target, is not made for a map; a map wholly outside ran to "detected 0/0")
        logging.getLogger(__name__).warning(
            f"{source or scn['name']}: no pixel of the image scene is ever in the beam (the scan covers "
            f"{float(np.min(beam_deg)):g} to {float(np.max(beam_deg)):g} deg; two-way gain under "
            f"{scn['simulation']['gain_threshold_db']:g} dB on every pulse): the cube holds "
            f"{'noise only' if scn['noise']['snr_db'] is not None else 'zeros (no noise), which process refuses'}")
    cube = RawCube(
        sum=echo_sum, diff=echo_diff, slow_time_s=slow_time_s, range_m=range_m,
        scan_angle_deg=beam_deg, position_m=position_m, velocity_mps=velocity_mps,
        radar={"fc_hz": radar["fc_hz"], "bandwidth_hz": radar["bandwidth_hz"], "fs_hz": radar["fs_hz"],
               "prf_hz": radar["prf_hz"], "beamwidth_3db_deg": ant["beamwidth_3db_deg"],
               "pulse_width_s": radar["pulse_width_s"], "range_weighting": radar["range_weighting"]},
        antenna=antenna_group(antenna, ant["diff_gain_db"], ant["diff_phase_deg"]),
        truth=None if scn["scene"]["kind"] == "image" else   # an image's truth is its map (scene_metrics)
        {"x_m": targets_m[:, 0].copy(), "y_m": targets_m[:, 1].copy(),
         "z_m": targets_m[:, 2].copy(), "amplitude": amps.astype(np.float64)},
        scenario_yaml=dump_scenario(scn),
        noise={"snr_db": np.nan if scn["noise"]["snr_db"] is None else scn["noise"]["snr_db"],
               "sigma": sigma, "seed": scn["noise"]["seed"],
               "band_hz": float(radar["bandwidth_hz"]) if sigma > 0.0 else 0.0},   # noise band-limited to |f| <= B/2
        attrs={"scenario_sha256": scenario_hash(scn), "scenario_name": scn["name"]},
    )
    return cube, stats


def refuse_an_all_zero_cube(scn: dict, stats, source: str) -> None:
    """``run`` / ``process SCENARIO``: a noiseless scene no target or pixel of which is ever in the beam
    gives a cube of zeros, which ``process RAW.h5`` refuses (``io.raw``); refused here the same way (the
    chain had run on it to "detected 0/0", and the joint fit to a division by a zero noise level)."""
    if stats.n_pairs_kept == 0 and scn["noise"]["snr_db"] is None:
        raise BadInput(f"{source}: scene: no target or pixel is ever in the beam and noise.snr_db is null, so "
                       f"every sample of the cube is zero: nothing to image; allowed: a scene inside the scan, "
                       f"or noise")
