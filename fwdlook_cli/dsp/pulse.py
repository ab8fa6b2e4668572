"""Range-compressed LFM pulse (paper eq. 4-5: p(t) is the compressed chirp).

The matched-filter output of a chirp of width T and bandwidth B is confined to |tau| < T; for no
weighting it has the closed form

    p(tau) = (1 - |tau|/T) sinc(B tau (1 - |tau|/T)),   |tau| < T,

a sinc of the stated bandwidth whose tails end at +-T.  With a weighting (Hamming, Hann, Taylor) the
reference chirp is multiplied by the window before correlation (mismatched filter, lower range
sidelobes, wider main lobe).  The kernel is tabulated once by correlating the sampled chirp with its
reference at a fine rate and is then linearly interpolated (table step 1/(64 fs): interpolation error
below -70 dB).  Stop-and-hop: the range-Doppler coupling of the chirp (a shift of f_d T/B, 9 cm for the
paper) is ignored, as in the paper's eq. (5).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from .geometry import C_MPS

TABLE_OVERSAMPLE = 64  # table points per range sample
RANGE_GUARD_SAMPLES = 8  # guard samples of an automatic range axis beyond the kernel's reach


WEIGHTINGS = ("none", "hamming", "hann", "taylor")


def pulse_rule_broken(*, bandwidth_hz: float, fs_hz: float, pulse_width_s: float | None, prf_hz: float,
                      prefix: str = ""):
    """The first rule a radar's pulse breaks, as (key, value, why), else None: complex sampling of the
    compressed pulse (fs >= B), a time-bandwidth product of at least 1 (the compressed pulse no longer
    than the transmitted one), and a duty cycle below 1 (a pulse shorter than the pulse interval).  The
    other keys named in ``why`` carry ``prefix`` (the scenario's ``radar.``).  ``pulse_width_s`` None: a
    cube that does not record it (only the first rule)."""
    if fs_hz < bandwidth_hz:
        return "fs_hz", fs_hz, (f"must be >= {prefix}bandwidth_hz = {bandwidth_hz:g} (complex sampling of the "
                                f"compressed pulse)")
    if pulse_width_s is None:
        return None
    if bandwidth_hz * pulse_width_s < 1.0:
        return "bandwidth_hz", bandwidth_hz, (f"must be >= 1 / {prefix}pulse_width_s = {1.0 / pulse_width_s:g} (a "
                                              f"time-bandwidth product of at least 1: the compressed pulse no "
                                              f"longer than the transmitted one)")
    if pulse_width_s * prf_hz >= 1.0:
        return "pulse_width_s", pulse_width_s, (f"must be shorter than the pulse interval 1 / {prefix}prf_hz = "
                                                f"{1.0 / prf_hz:g} s (a duty cycle below 1)")
    return None


def scenario_pulse_rule_text(radar: dict) -> str | None:
    """The scenario kinds' wording of :func:`pulse_rule_broken` for their ``radar`` section (``radar.KEY
    = value: why``), else None."""
    broken = pulse_rule_broken(bandwidth_hz=radar["bandwidth_hz"], fs_hz=radar["fs_hz"],
                               pulse_width_s=radar["pulse_width_s"], prf_hz=radar["prf_hz"], prefix="radar.")
    return None if broken is None else f"radar.{broken[0]} = {broken[1]:g}: {broken[2]}"


def weighting(name: str, n: int) -> np.ndarray:
    """Symmetric amplitude weighting: none, hamming, hann, or taylor (nbar 4, -35 dB sidelobes)."""
    if name == "none":
        return np.ones(n)
    if name == "hamming":
        return np.hamming(n)
    if name == "hann":
        return np.hanning(n)
    if name == "taylor":
        from scipy.signal.windows import taylor  # heavy import, only when asked for

        return taylor(n, nbar=4, sll=35, sym=True)
    raise ValueError(f"weighting {name!r}; allowed: {', '.join(WEIGHTINGS)}")


@dataclass(frozen=True)
class CompressedPulse:
    """Tabulated range-compressed pulse p(tau), tau in seconds, p(0) = 1 (unweighted)."""

    bandwidth_hz: float
    pulse_width_s: float
    fs_hz: float
    weighting: str = "none"

    def __post_init__(self):
        dt = 1.0 / (TABLE_OVERSAMPLE * self.fs_hz)
        n_chirp = int(np.ceil(self.pulse_width_s / dt)) | 1
        t = (np.arange(n_chirp) - (n_chirp - 1) / 2) * dt
        chirp = np.exp(1j * np.pi * (self.bandwidth_hz / self.pulse_width_s) * t**2)
        reference = chirp * weighting(self.weighting, n_chirp)
        import scipy.fft       # here, not at the top: the scenario and cube readers import WEIGHTINGS

        n_fft = scipy.fft.next_fast_len(2 * n_chirp - 1)
        corr = scipy.fft.ifft(scipy.fft.fft(chirp, n_fft) * np.conj(scipy.fft.fft(reference, n_fft)))
        corr = np.concatenate([corr[-(n_chirp - 1):], corr[:n_chirp]])  # lags -(n-1)..(n-1)
        unweighted_peak = float(n_chirp)
        table = corr / unweighted_peak
        object.__setattr__(self, "_table", table.astype(np.complex64))
        object.__setattr__(self, "_dt", dt)
        object.__setattr__(self, "_half", n_chirp - 1)

    @property
    def support_s(self) -> float:
        """The kernel is zero for |tau| >= support_s (the pulse width)."""
        return self._half * self._dt

    def __call__(self, tau_s):
        """p(tau): linear interpolation of the table; zero outside +-T."""
        pos = np.asarray(tau_s, dtype=np.float64) / self._dt + self._half
        i0 = np.floor(pos)
        frac = (pos - i0).astype(np.float32)
        inside = (i0 >= 0) & (i0 < 2 * self._half)
        i0 = np.where(inside, i0, 0).astype(np.intp)
        out = self._table[i0] * (1.0 - frac) + self._table[i0 + 1] * frac
        return np.where(inside, out, 0).astype(np.complex64)


def lfm_compressed_closed_form(tau_s, bandwidth_hz, pulse_width_s):
    """Closed form of the unweighted compressed chirp, for tests and documentation."""
    tau = np.asarray(tau_s, dtype=np.float64)
    shrink = np.clip(1.0 - np.abs(tau) / pulse_width_s, 0.0, None)
    return shrink * np.sinc(bandwidth_hz * tau * shrink)


def auto_range_axis_m(range_min_m, range_max_m, fs_hz, pulse: CompressedPulse, *, positive: bool = False):
    """Range axis holding every target's whole kernel over the scan, length a fast FFT size.
    ``positive``: it begins one range step out at the nearest, the kernel of a target within the pulse's
    reach of the antenna cut there (no echo is received from a slant range at or below 0 m: a forward scene
    with a point beneath the platform had been simulated on an axis from -150 m, a cube its own reader
    refuses)."""
    dr = C_MPS / (2.0 * fs_hz)
    reach = C_MPS * pulse.support_s / 2.0 + RANGE_GUARD_SAMPLES * dr
    near = np.floor((range_min_m - reach) / dr) * dr
    if positive:
        near = max(near, dr)
    import scipy.fft

    n = scipy.fft.next_fast_len(int(np.ceil((range_max_m + reach - near) / dr)) + 1)
    return near + dr * np.arange(n)


def noise_sigma_for(snr_db, amplitudes) -> float:
    """sigma of the complex noise per sample for the scenario's SNR definition (``forward/simulate.py`` module docstring)."""
    if snr_db is None:
        return 0.0
    return float(np.max(np.abs(amplitudes))) / 10.0 ** (snr_db / 20.0)
