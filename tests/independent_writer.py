"""An independent raw-cube writer: plain numpy and h5py, sharing no code with fwdlook's simulator.

It writes the CONTRACT.md section 3 layout as another tool would: no ``/antenna`` group, so fwdlook
must calibrate its monopulse from the data.  Physics, written out here on its own:

* exact slant range of paper eq. (1): R_kn = |P_k - p(t_n)|, p(t) = (0, 0, h) + v t + a t^2 / 2;
* the range-compressed LFM pulse in closed form, (1 - |tau|/T) sinc(B tau (1 - |tau|/T)) for |tau| < T,
  carrier phase exp(-j 4 pi f_c R / c);
* two squinted Gaussian beams crossing at their one-way half-power points (squint = half the element
  beamwidth), the element beamwidth found by bisection so that the SUM beam is ``beamwidth_deg`` wide
  at -3 dB one-way; echo gains Sigma^2 (sum channel) and Sigma Delta (difference channel), the
  difference channel times the receiver imbalance 10^(g/20) exp(j phi);
* complex noise band-limited to the signal bandwidth B (white noise filtered to |f| <= B/2 in the
  range-frequency domain), scaled so that its power per sample is exactly |a_max|^2 / 10^(snr/10):
  the stated SNR is the in-band SNR of the peak sample of the strongest target at beam centre.
"""
from __future__ import annotations

import h5py
import numpy as np

C = 299_792_458.0

RADARS = {
    # the paper's radar (Li & Li 2023, Table 1) with its 6 deg sum beam
    "paper": {"fc_hz": 18.0e9, "bandwidth_hz": 50.0e6, "pulse_width_s": 1.0e-6, "prf_hz": 2500.0,
              "fs_hz": 60.0e6, "beamwidth_deg": 6.0},
    # an X-band radar with a 4 deg sum beam
    "xband": {"fc_hz": 10.0e9, "bandwidth_hz": 40.0e6, "pulse_width_s": 1.0e-6, "prf_hz": 2000.0,
              "fs_hz": 48.0e6, "beamwidth_deg": 4.0},
}


def element_beamwidth_deg(sum_beamwidth_deg: float) -> float:
    """Element beamwidth theta_e of two Gaussian beams squinted by +-theta_e/2 whose sum is 3 dB down
    (one-way power) at +-sum_beamwidth/2: bisection on the sum level, which falls as theta_e narrows."""
    h = sum_beamwidth_deg / 2.0

    def sum_level_at_h(theta_e):
        g = lambda u: np.exp(-2.0 * np.log(2.0) * (u / theta_e) ** 2)  # noqa: E731  one-way voltage
        s = theta_e / 2.0
        return (g(h - s) + g(h + s)) / (g(-s) + g(s))

    lo, hi = 0.2 * sum_beamwidth_deg, 2.0 * sum_beamwidth_deg   # level at h: too low ... too high
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if sum_level_at_h(mid) > 1.0 / np.sqrt(2.0):
            hi = mid
        else:
            lo = mid
    return 0.5 * (lo + hi)


def beams(offset_deg, theta_e_deg):
    """(Sigma, Delta) one-way voltages, Sigma(0) = 1; Delta > 0 towards +x of the beam axis."""
    s = theta_e_deg / 2.0
    g = lambda u: np.exp(-2.0 * np.log(2.0) * (u / theta_e_deg) ** 2)  # noqa: E731
    norm = 2.0 * g(s)
    right, left = g(offset_deg - s), g(offset_deg + s)
    return (right + left) / norm, (right - left) / norm


def true_slope_per_deg(sum_beamwidth_deg: float) -> float:
    """d(Delta/Sigma)/d(offset) on the axis, by a central difference of the writer's own beams."""
    te = element_beamwidth_deg(sum_beamwidth_deg)
    eps = 1e-4
    (sp, dp), (sm, dm) = beams(eps, te), beams(-eps, te)
    return float((dp / sp - dm / sm) / (2 * eps))


def write_cube(path, radar: str, targets_xy_m, *, amplitude=1.0, speed_mps=240.0, accel_mps2=(0.0, 10.0, 0.0),
               height_m=50.0, scan_start_deg=-8.0, scan_stop_deg=8.0, scan_rate_dps=60.0, n_pulses=None,
               snr_db=20.0, seed=1, diff_gain_db=0.0, diff_phase_deg=0.0):
    """Write one cube; returns a dict of what was written (truth, true slope, imbalance)."""
    rd = RADARS[radar]
    prf, fs, bw_hz, T, fc = rd["prf_hz"], rd["fs_hz"], rd["bandwidth_hz"], rd["pulse_width_s"], rd["fc_hz"]
    if n_pulses is None:
        n_pulses = int(round((scan_stop_deg - scan_start_deg) / scan_rate_dps * prf))
    t = np.arange(n_pulses) / prf
    a = np.asarray(accel_mps2, dtype=np.float64)
    v0 = np.array([0.0, speed_mps, 0.0])
    pos = np.array([0.0, 0.0, height_m])[None, :] + v0[None, :] * t[:, None] + 0.5 * a[None, :] * t[:, None] ** 2
    vel = v0[None, :] + a[None, :] * t[:, None]
    scan = scan_start_deg + scan_rate_dps * t
    tg = np.asarray(targets_xy_m, dtype=np.float64)
    tgt = np.column_stack([tg, np.zeros(len(tg))])
    amp = np.broadcast_to(np.asarray(amplitude, dtype=np.float64), (len(tg),)).copy()

    rng_kn = np.linalg.norm(tgt[:, None, :] - pos[None, :, :], axis=2)          # eq. (1), exact
    dr = C / (2.0 * fs)
    near = np.floor((rng_kn.min() - 200.0) / dr) * dr
    n_r = int(np.ceil((rng_kn.max() + 200.0 - near) / dr))
    range_m = near + dr * np.arange(n_r)
    theta_e = element_beamwidth_deg(rd["beamwidth_deg"])
    gamma = 10.0 ** (diff_gain_db / 20.0) * np.exp(1j * np.radians(diff_phase_deg))
    echo_s = np.zeros((n_pulses, n_r), np.complex128)
    echo_d = np.zeros((n_pulses, n_r), np.complex128)
    for k in range(len(tgt)):                         # few targets: vectorised over pulses x samples
        d = tgt[k] - pos
        az = np.degrees(np.arctan2(d[:, 0], d[:, 1]))
        sig, dlt = beams(az - scan, theta_e)
        tau = 2.0 * (range_m[None, :] - rng_kn[k][:, None]) / C
        shrink = np.clip(1.0 - np.abs(tau) / T, 0.0, None)
        p = shrink * np.sinc(bw_hz * tau * shrink)
        ph = np.exp(-4j * np.pi * fc * rng_kn[k] / C)[:, None]
        echo_s += amp[k] * (sig * sig)[:, None] * p * ph
        echo_d += amp[k] * gamma * (sig * dlt)[:, None] * p * ph
    sigma2 = float(amp.max() ** 2 / 10.0 ** (snr_db / 10.0)) if snr_db is not None else 0.0
    if sigma2 > 0:
        r = np.random.default_rng(seed)
        f = np.fft.fftfreq(n_r, 1.0 / fs)
        band = np.abs(f) <= bw_hz / 2.0
        for echo in (echo_s, echo_d):
            w = r.standard_normal((n_pulses, n_r)) + 1j * r.standard_normal((n_pulses, n_r))
            w = np.fft.ifft(np.fft.fft(w, axis=1) * band[None, :], axis=1)
            w *= np.sqrt(sigma2 / np.mean(np.abs(w) ** 2))
            echo += w
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "fwdlook-raw"
        f.attrs["format_version"] = 1
        f.attrs["software"] = "independent_writer (tests)"
        f.attrs["scenario"] = f"independent writer: {radar}, {len(tgt)} targets"

        def ds(name, data, units):
            obj = f.create_dataset(name, data=data)
            obj.attrs["units"] = units
            return obj

        ds("echo/sum", echo_s.astype(np.complex64), "1")
        ds("echo/diff", echo_d.astype(np.complex64), "1")
        ds("axes/slow_time_s", t, "s")
        ds("axes/range_m", range_m, "m")
        ds("axes/scan_angle_deg", scan, "deg")
        ds("platform/position_m", pos, "m")
        ds("platform/velocity_mps", vel, "m/s")
        for key, col in (("x_m", tgt[:, 0]), ("y_m", tgt[:, 1]), ("z_m", tgt[:, 2]), ("amplitude", amp)):
            ds(f"truth/targets/{key}", col, "1" if key == "amplitude" else "m")
        g = f.create_group("radar")
        for key in ("fc_hz", "bandwidth_hz", "fs_hz", "prf_hz"):
            g.attrs[key] = rd[key]
        g.attrs["beamwidth_3db_deg"] = rd["beamwidth_deg"]
    return {"n_pulses": n_pulses, "slope_per_deg": true_slope_per_deg(rd["beamwidth_deg"]),
            "diff_gain_db": diff_gain_db, "diff_phase_deg": diff_phase_deg, "targets_m": tgt,
            "element_beamwidth_deg": theta_e}
