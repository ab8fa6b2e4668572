"""Scene simulator: the physics of ``simulate.simulate_echo`` doing only the work the scene needs.

Same echo model as ``simulate.py`` (paper eq. 1 and 5, stop-and-hop): for target k and pulse n

    s_sum(r, n)  = a_k Sigma^2(d_kn)      p(2 (r - R_kn)/c) exp(-j 4 pi f_c R_kn / c)
    s_diff(r, n) = a_k Sigma Delta(d_kn)  p(2 (r - R_kn)/c) exp(-j 4 pi f_c R_kn / c)

with the exact slant range R_kn of eq. (1), the gains of ``antenna.MonopulseAntenna.two_way_gains``
and the compressed pulse of ``pulse.CompressedPulse``; a pair whose two-way power gain is below
``gain_threshold_db`` is skipped exactly as there.  What differs is how the work is organised:

* **Visible interval.**  The gain gate is an angle gate |d| <= d_gate (Sigma falls monotonically
  with |d|).  For a monotone scan whose beam moves faster than any target's azimuth (checked: the
  azimuth rate is bounded by speed / ground distance), d_kn falls monotonically along the scan, so
  each target's gated pulses form one interval [n0_k, n1_k], found by a vectorised bisection over
  the pulse index (O(K log N)).  No target x pulse array is ever formed; only the pairs inside the
  intervals are, in chunks.  (Otherwise every pulse is a candidate: still chunked, only slower.)
* **Range synthesis.**  ``method="nufft"``: the pulses of a block of ``block_pulses`` pulses are laid
  end to end on one periodic axis, each in a segment with a guard wider than the kernel, and the sum
  over pairs  sum_j c_j delta(t - t_j)  is taken to range frequency by one type-1 non-uniform FFT
  (``finufft``, both channels as two transforms of one plan), multiplied there by the Fourier
  transform of the kernel, folded to the sample rate and inverse FFT'd.  The kernel transform is
  that of the very function ``CompressedPulse`` evaluates (a 64x-oversampled table with linear
  interpolation: DTFT of the table times sinc^2), kept up to ``oversample`` x fs / 2, so the only
  departures from the per-tap simulator are the kernel's spectrum beyond that band and the NUFFT
  tolerance.  ``method="direct"``: each pair writes the 2 ceil(T/dr)+1 range samples its kernel
  reaches, as ``simulate_echo`` does, but for the gated pairs only.  ``auto``: direct while the
  taps in all (gated pairs x kernel width) stay under ``AUTO_DIRECT_TAPS`` (the paper lattice:
  the exact simulator's output to float32 rounding), nufft beyond (measured faster there: README,
  "Extended scenes"; also its error against the exact simulator).
* **Threads.**  Pulse blocks are shared among ``workers`` threads (default: the CPUs this process
  may use); numpy's ufuncs and finufft (through ctypes) release the GIL.
* **Memory bound.**  Besides the two complex64 outputs (8 n_pulses n_range bytes each) and
  per-target arrays (positions, amplitudes, intervals: about 100 bytes per scatterer), each worker
  holds one chunk of at most ``max_chunk_pairs`` pairs (about 250 bytes per pair in temporaries)
  and its block's modes (2 channels x oversample x block_pulses x segment x 16 bytes: 2 MB for the
  paper radar).  With the defaults (1e6 pairs, 32-pulse blocks, 2 workers) that is under 1 GB
  whatever the number of scatterers, plus about 100 bytes per scatterer; measured peak RSS of the
  whole process: 0.84 GB at 1e5 scatterers, 1.04 GB at 1e6 (README, "Extended scenes").
"""
from __future__ import annotations

from dataclasses import dataclass
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import scipy.fft

from ..dsp.antenna import MonopulseAntenna, bracketed_root
from ..dsp.blas import available_cores
from ..dsp.geometry import C_MPS
from ..dsp.pulse import TABLE_OVERSAMPLE, CompressedPulse
from ..dsp.noise import add_band_limited_noise
from ..io import backing


@dataclass(frozen=True)
class SimulationStats:
    n_pairs: int          # targets x pulses
    n_pairs_kept: int     # pairs above the gain threshold
    kernel_samples: int   # range samples one pair writes
    samples_written: int  # n_pairs_kept x kernel_samples

NUFFT_EPS = 1e-6
AUTO_DIRECT_TAPS = 2e7   # method auto: direct taps below this many kernel samples in all, else nufft


def gate_angle_deg(antenna: MonopulseAntenna, gain_threshold_db: float) -> float:
    """|d| at which the two-way power gain 20 log10(Sigma^2) equals the threshold (monotone in |d|)."""
    f = lambda d: 40.0 * np.log10(max(float(antenna.sum_voltage(d)), 1e-300)) - gain_threshold_db  # noqa: E731
    hi = antenna.beamwidth_3db_deg
    while f(hi) > 0.0:
        hi *= 2.0
        if hi > 360.0:
            return 360.0
    return bracketed_root(f, 0.0, hi, xtol=1e-12)


def _azimuth(targets_m, position_m):
    """Ground-plane azimuth atan2(dx, dy) of paired target / position rows (degrees)."""
    return np.degrees(np.arctan2(targets_m[..., 0] - position_m[..., 0], targets_m[..., 1] - position_m[..., 1]))


def visible_intervals(position_m, beam_deg, targets_m, gate_deg, velocity_bound_mps=None):
    """First and last pulse (inclusive) at which each target is within ``gate_deg`` of the beam.

    Returns (n0, n1, exact): int64 arrays (n0 > n1 for a target never inside the gate) and whether
    the monotonicity that makes the interval exact was proven; if not, every pulse is returned.
    """
    n_p = len(beam_deg)
    k = len(targets_m)
    full = (np.zeros(k, np.int64), np.full(k, n_p - 1, np.int64), False)
    beam = np.asarray(beam_deg, dtype=np.float64)
    step = np.diff(beam)
    if n_p < 2 or np.any(step <= 0.0):
        return full
    # lower bound on every target's ground distance from the track: distance to the nearest of a
    # few track samples minus half the largest gap between consecutive samples
    sub = np.unique(np.linspace(0, n_p - 1, 17).astype(np.int64))
    track = position_m[sub, :2]
    gap = np.max(np.linalg.norm(np.diff(position_m[:, :2], axis=0), axis=1)) * np.max(np.diff(sub)) if len(sub) > 1 else 0.0
    rho = np.full(k, np.inf)
    for p in track:                                              # K-sized temporaries only
        rho = np.minimum(rho, np.hypot(targets_m[:, 0] - p[0], targets_m[:, 1] - p[1]))
    rho -= 0.5 * gap
    speed = float(np.max(np.linalg.norm(np.diff(position_m[:, :2], axis=0), axis=1)))  # m per pulse
    if np.min(rho) <= 0.0:
        return full
    az_rate = np.degrees(speed / np.min(rho))                                        # deg per pulse, bound
    if az_rate >= 0.5 * np.min(step):
        return full
    tgt = np.asarray(targets_m, dtype=np.float64)

    def offset(idx, n):
        return _azimuth(tgt[idx], position_m[n]) - beam[n]

    def first_at_or_below(level):
        """Smallest n with offset(n) <= level (offset decreases with n); n_p if none."""
        lo = np.zeros(k, np.int64)
        hi = np.full(k, n_p, np.int64)
        while True:
            active = lo < hi
            if not np.any(active):
                return lo
            mid = (lo + hi) // 2
            ok = np.zeros(k, bool)
            idx = np.nonzero(active)[0]
            ok[idx] = offset(idx, mid[idx]) <= level
            hi = np.where(active & ok, mid, hi)
            lo = np.where(active & ~ok, mid + 1, lo)

    margin = 1e-9 + 1e-12 * abs(gate_deg)
    n0 = first_at_or_below(gate_deg + margin)
    n1 = first_at_or_below(-gate_deg - margin) - 1        # last n with offset >= -gate
    return n0, n1, True


class _KernelFT:
    """P(nu), nu = k / period cycles per range sample, |k| < n_modes/2: the Fourier transform of the
    function ``CompressedPulse`` evaluates.  It linearly interpolates a table of step
    h = 1/TABLE_OVERSAMPLE range samples, so its transform is h DTFT(table)(nu h) sinc^2(nu h).
    """

    def __init__(self, pulse: CompressedPulse, period: int, n_modes: int):
        h = 1.0 / TABLE_OVERSAMPLE
        m_half = int(np.ceil(pulse.support_s * TABLE_OVERSAMPLE * pulse.fs_hz)) + 1
        m = np.arange(-m_half, m_half + 1)
        table = pulse(m / (TABLE_OVERSAMPLE * pulse.fs_hz)).astype(np.complex128)  # the table's nodes
        n_fft = TABLE_OVERSAMPLE * period                    # frequency step 1/(n_fft h) = 1/period
        if n_fft < len(m):
            raise ValueError("segment shorter than the kernel")
        buf = np.zeros(n_fft, np.complex128)
        buf[np.mod(m, n_fft)] = table                         # table index m at time m h
        spec = scipy.fft.fft(buf, workers=-1)
        k = np.fft.fftfreq(n_modes, 1.0 / n_modes).astype(np.int64)   # FFT order (finufft modeord=1)
        nu = k / period
        self.values = h * spec[np.mod(k, n_fft)] * np.sinc(nu * h) ** 2


def simulate_scene_echo(slow_time_s, position_m, beam_deg, range_m, targets_m, amplitudes, *, fc_hz,
                        pulse: CompressedPulse, antenna: MonopulseAntenna, gain_threshold_db=-60.0,
                        noise_sigma=0.0, seed=None, method="auto", max_chunk_pairs=1_000_000,
                        block_pulses=32, oversample=4, nufft_eps=NUFFT_EPS, workers=None, diff_gain_db=0.0,
                        diff_phase_deg=0.0):
    """Sum and difference echoes, complex64 [n_pulses, n_range] each, and work statistics.

    Same arguments and results as ``simulate.simulate_echo`` (plus the work layout); see the module
    docstring for the method and the memory bound.
    """
    if method not in ("auto", "nufft", "direct"):
        raise ValueError(f"method {method!r}; allowed: auto, nufft, direct")
    n_p, n_r = len(slow_time_s), len(range_m)
    range_m = np.asarray(range_m, dtype=np.float64)
    position_m = np.asarray(position_m, dtype=np.float64)
    beam = np.asarray(beam_deg, dtype=np.float64)
    tgt = np.asarray(targets_m, dtype=np.float64).reshape(-1, 3)
    amps = np.asarray(amplitudes).reshape(-1)
    dr = float(range_m[1] - range_m[0])
    fs_hz = C_MPS / (2.0 * dr)
    half = int(np.ceil(C_MPS * pulse.support_s / 2.0 / dr))
    width = 2 * half + 1

    gate = gate_angle_deg(antenna, gain_threshold_db)
    n0, n1, _exact = visible_intervals(position_m, beam, tgt, gate)
    live = (n1 >= n0) & (amps != 0.0)
    t_idx = np.nonzero(live)[0]
    n0, n1 = n0[t_idx], n1[t_idx]
    amp_abs = np.abs(amps).astype(np.float64)
    # a complex amplitude |a| exp(j phi) turns the carrier phase -2 pi cyc into -2 pi (cyc - phi / 2 pi)
    amp_cyc = np.angle(amps) / (2.0 * np.pi) if np.iscomplexobj(amps) or np.any(amps < 0) else None
    if method == "auto":
        est_taps = float(np.sum(n1 - n0 + 1)) * width
        method = "direct" if est_taps < AUTO_DIRECT_TAPS else "nufft"
        if method == "nufft":
            import importlib.util

            if importlib.util.find_spec("finufft") is None:
                method = "direct"
    if method == "nufft" and not np.isclose(fs_hz, pulse.fs_hz, rtol=1e-9):
        method = "direct"                  # the kernel table's step is tied to the pulse's own fs

    # zeros (a block no target reaches is not written), file-backed inside io.backing.file_backed
    # (--out-of-core: a cube larger than memory, its pulse blocks written into the scratch file's pages)
    echo_sum, echo_diff = backing.zeros((n_p, n_r), np.complex64), backing.zeros((n_p, n_r), np.complex64)
    guard = 2 * half + 4
    seg = scipy.fft.next_fast_len(n_r + 2 * guard)
    blk = max(1, min(int(block_pulses), n_p))
    period = blk * seg
    n_modes = int(oversample) * period
    kernel_ft = _KernelFT(pulse, period, n_modes) if method == "nufft" else None
    taps = np.arange(width, dtype=np.int64)
    tx, ty, tz = (np.ascontiguousarray(tgt[:, i]) for i in range(3))
    px, py, pz = (np.ascontiguousarray(position_m[:, i]) for i in range(3))
    local = threading.local()

    def do_block(b0):
        """Synthesise pulses [b0, b0 + blk) of both channels; returns the pairs kept by the gate."""
        b1 = min(n_p, b0 + blk)
        nb = b1 - b0
        sel = np.nonzero((n0 < b1) & (n1 >= b0))[0]
        if len(sel) == 0:
            return 0
        kept = 0
        if method == "nufft":
            if getattr(local, "plan", None) is None:
                import finufft

                local.plan = finufft.Plan(1, (n_modes,), n_trans=2, eps=nufft_eps, isign=-1,
                                          dtype="complex128", nthreads=1, modeord=1)
            plan = local.plan
            modes = np.zeros((2, n_modes), np.complex128)
        else:
            acc = np.zeros((4, nb * n_r))
        bpx, bpy, bpz = px[b0:b1, None], py[b0:b1, None], pz[b0:b1, None]
        bbeam = beam[b0:b1, None]
        pulse_of = np.broadcast_to(np.arange(nb)[:, None], (nb, 1))
        step = max(1, max_chunk_pairs // nb)
        for lo in range(0, len(sel), step):
            # a [pulse, target] grid of this block's pulses and a chunk of the targets whose visible
            # interval meets the block: pulse-major, so the NUFFT points come nearly sorted
            tk = t_idx[sel[lo:lo + step]]
            dx = tx[tk][None, :] - bpx
            dy = ty[tk][None, :] - bpy
            dz = tz[tk][None, :] - bpz
            r = np.sqrt(dx * dx + dy * dy + dz * dz)                       # eq. (1), exact
            off = np.degrees(np.arctan2(dx, dy))
            off -= bbeam
            del dx, dy, dz
            # the gain gate 20 log10(Sigma^2) >= threshold is |d| <= gate (Sigma monotone in |d|)
            keep = np.abs(off) <= gate
            kept += int(np.count_nonzero(keep))
            delay = r - range_m[0]
            delay /= dr                                                  # fractional sample index
            keep &= (delay > -half - 1) & (delay < n_r + half)           # kernel touches the window
            n_idx = np.broadcast_to(pulse_of, keep.shape)[keep]          # pulse within the block
            amp = np.broadcast_to(amp_abs[tk][None, :], keep.shape)[keep]
            if amp_cyc is not None:
                a_cyc = np.broadcast_to(amp_cyc[tk][None, :], keep.shape)[keep]
            r, off, delay = r[keep], off[keep], delay[keep]
            if len(r) == 0:
                continue
            g_sum, g_diff = antenna.two_way_gains(off)
            # eq. (5): carrier phase -4 pi fc R / c, reduced in float64 before float32 trigonometry
            cyc = (2.0 * fc_hz / C_MPS) * r
            if amp_cyc is not None:
                cyc -= a_cyc
            cyc -= np.floor(cyc)
            cyc32 = (2.0 * np.pi) * cyc.astype(np.float32)
            g_sum *= amp
            g_diff *= amp
            if method == "nufft":
                cos_, sin_ = np.cos(cyc32), np.sin(cyc32)
                strengths = np.empty((2, len(r)), np.complex128)
                strengths[0].real, strengths[0].imag = g_sum * cos_, -(g_sum * sin_)
                strengths[1].real, strengths[1].imag = g_diff * cos_, -(g_diff * sin_)
                x = n_idx * float(seg) + (guard + delay)
                x *= 2.0 * np.pi / period
                plan.setpts(x)
                modes += plan.execute(strengths)
            else:
                phasor = np.exp(-1j * cyc32.astype(np.float64))
                c_sum = (g_sum * phasor).astype(np.complex64)
                c_diff = (g_diff * phasor).astype(np.complex64)
                fi = np.floor(delay).astype(np.int64) - half + 1
                ch = max(1, 4_000_000 // width)
                size = nb * n_r
                for lo2 in range(0, len(r), ch):
                    s_ = slice(lo2, lo2 + ch)
                    col = fi[s_, None] + taps[None, :]
                    kern = pulse(2.0 * (range_m[0] + col * dr - r[s_, None]) / C_MPS)
                    inside = (col >= 0) & (col < n_r)
                    flat = (n_idx[s_, None] * n_r + np.clip(col, 0, n_r - 1))[inside]
                    v_sum = (kern * c_sum[s_, None])[inside]
                    v_diff = (kern * c_diff[s_, None])[inside]
                    for j, part in enumerate((v_sum.real, v_sum.imag, v_diff.real, v_diff.imag)):
                        acc[j] += np.bincount(flat, weights=part, minlength=size)
        if method == "nufft":
            # S_k = P(k / period) / period * sum_j c_j exp(-i 2 pi k t_j / period) (FFT order); fold
            # to the sample rate (k mod period) and inverse FFT: s(i) = sum_k S_k exp(i 2 pi k i / period)
            modes *= kernel_ft.values[None, :]
            folded = modes.reshape(2, int(oversample), period).sum(axis=1)
            sig = scipy.fft.ifft(folded, axis=1, workers=1)             # (1/period) sum_k ... * period
            sig = sig.reshape(2, blk, seg)[:, :nb, guard:guard + n_r]
            echo_sum[b0:b1] = sig[0]
            echo_diff[b0:b1] = sig[1]
        else:
            acc = acc.reshape(4, nb, n_r)
            echo_sum[b0:b1] = acc[0] + 1j * acc[1]
            echo_diff[b0:b1] = acc[2] + 1j * acc[3]
        return kept

    n_workers = max(1, int(workers if workers is not None else available_cores()))
    blocks = range(0, n_p, blk)
    if n_workers == 1:
        kept_total = sum(do_block(b0) for b0 in blocks)
    else:
        with ThreadPoolExecutor(max_workers=n_workers) as pool:  # numpy and finufft release the GIL
            kept_total = sum(pool.map(do_block, blocks))

    if diff_gain_db or diff_phase_deg:          # receiver imbalance on the difference echo (before noise)
        echo_diff *= np.complex64(10.0 ** (diff_gain_db / 20.0) * np.exp(1j * np.radians(diff_phase_deg)))
    if noise_sigma > 0.0:                       # the same draws, in the same order, as simulate_echo
        rng = np.random.default_rng(seed)
        for echo in (echo_sum, echo_diff):      # band-limited to |f_r| <= B/2 like the echo (dsp/noise.py),
            add_band_limited_noise(rng, echo, sigma=noise_sigma, fs_hz=pulse.fs_hz,     # in pulse blocks
                                   bandwidth_hz=pulse.bandwidth_hz)
    stats = SimulationStats(n_pairs=int(len(tgt)) * n_p, n_pairs_kept=int(kept_total), kernel_samples=width,
                            samples_written=int(kept_total) * width)
    return echo_sum, echo_diff, stats



