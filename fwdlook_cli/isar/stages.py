"""ISAR stages (eq. 11-12): range FFT, first/second-order keystone with the range-minimum shift, range IFFT,
azimuth compression.  Plain functions over :class:`StageData`."""
from __future__ import annotations

import logging

import numpy as np
import scipy.fft as sfft

from ..dsp.geometry import C_MPS, ambiguity_number
from ..dsp.keystone_common import _cis  # exp(j 2 pi cycles), reduced modulo one cycle in float64
from ..io.stagefile import StageData
from .geometry import LineModel
from ..errors import BadInput
from ..limits import check_keystone_padding, keystone_padding


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
    from ..dsp.keystone_czt import KeystonePlan
    from ..dsp.keystone import keystone_dft

    alpha = _alpha(order, np.asarray(fr_hz, dtype=np.float64), fc_hz)
    n = echo_f.shape[0]
    excursion, pad = keystone_padding(n, t0_index, float(np.max(np.abs(1.0 - alpha))))
    if excursion > 0.5 * n:
        # most of the band's rows resampled from outside the dwell: zeros (32 pulses at 3 deg: -16 dB, where
        # keystone1 about the middle loses 0.1 dB; an independent review, fifty-second round)
        logging.getLogger(__name__).warning(
            f"the keystone about pulse {t0_index - (n - 1) / 2.0:.0f} from the dwell's centre resamples up to "
            f"{excursion:.0f} pulses outside a dwell of {n}: those rows read zeros and the image loses gain "
            f"(keystone1 about the middle, or a longer dwell)")
    check_keystone_padding(n, pad, echo_f.shape[1], t0_index, float(np.max(np.abs(1.0 - alpha))))
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
    """A centred Doppler line made fit for :func:`~fwdlook_cli.dsp.peaks.oversample_profile`.

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


EDGE_SAMPLES = 4          # the keystone centre's range this many range samples inside the window


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
        if m is not None:
            _warn_if_the_doppler_crosses_a_fold(m, np.asarray(data["slow_time_s"], dtype=np.float64), fc, prf)
        corrected = _keystone(echo_f, fr, fc, order=1 if correction == "keystone1" else 2, t0_index=t0,
                              ambiguity_rows=rows, method=keystone)
    if m is not None and correction in ("keystone2_n0", "keystone2_n0_est"):
        # the envelope comes out at the range of the keystone centre, R(t_c) with the model's n0: outside the
        # window it wraps round the range FFT (an independent review: a window the dwell fits, its target
        # imaged 33 m off at the far edge, "not detected", -19 dB)
        rng = np.asarray(data["range_m"], dtype=np.float64)
        r_centre = float(m.range_m(float(data["slow_time_s"][0]) + t0 / prf))
        margin = EDGE_SAMPLES * float(rng[1] - rng[0])
        if not rng[0] + margin <= r_centre <= rng[-1] - margin:    # (a scenario's window is refused before)
            logging.getLogger(__name__).warning(
                f"processing.correction = {correction}: the keystone centre's range {r_centre:.1f} m lies outside "
                f"the range window {rng[0]:.1f} to {rng[-1]:.1f} m: the focused target wraps round the range axis "
                f"(a window reaching it, or keystone1 / keystone2, images it in place)")
    out.add("echo_f", corrected, ("slow_time_s", "range_freq_hz"), "1",
            f"range-frequency echo after correction {correction}")
    out.add("ambiguity_number", rows, ("range_freq_hz",), "1", "Doppler ambiguity number per row")
    out.attrs.update(correction=correction, keystone_centre_index=float(t0), n0_used_pulses=float(shift),
                     t_ref_s=float(t0 / prf))
    return out


def _warn_if_the_doppler_crosses_a_fold(m, slow_time_s, fc_hz: float, prf_hz: float) -> None:
    """One ambiguity number serves the whole dwell (per range-frequency row, from its middle); where the
    model's Doppler history crosses +-PRF/2 within the dwell the rows past the fold are resampled with
    the wrong one and the image loses gain (README, the ISAR section's second review: 51 pulses at
    93.1 Hz, -2.1 dB): said, not corrected (no Doppler-centroid demodulation here)."""
    t = slow_time_s[[0, -1]]
    tau = t - m.t_mid_s
    rdot = (m.r0_m * m.rdot_mps + m.v2_m2ps2 * tau) / np.maximum(m.range_m(t), 1e-9)
    f_hz = -2.0 * rdot * fc_hz / C_MPS
    folds = ambiguity_number(f_hz, prf_hz)
    if folds[0] != folds[1]:
        logging.getLogger(__name__).warning(
            f"the Doppler centroid moves from {f_hz[0]:.1f} to {f_hz[1]:.1f} Hz over the dwell, across +-PRF/2 "
            f"(ambiguity number {int(folds[0])} to {int(folds[1])} at a {prf_hz:g} Hz PRF): the keystone takes the "
            f"dwell's middle one for every pulse, and the image loses gain (a higher PRF, or a shorter dwell)")


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
