"""The GPU backend (``processing.backend: gpu``): stages 3 and 6 of the forward chain written once against
an array module ``xp`` (CuPy on a GPU, numpy under ``FWDLOOK_XP=numpy``), and the dispatch that puts them
and the image stage (:mod:`forward.gpu_imaging`) into the chain.

* ``keystone`` (``traditional``, ``decimation``, ``tracking`` with ``keystone: czt``): the keystone as a
  scaled DFT evaluated by Bluestein's chirp-Z transform (NOTES.md; eq. 8, 15-22 with the corrected
  eq. 21-22), every column at once with FFTs on ``xp``.  Chirp phases are formed in float64 and
  reduced modulo one cycle before the cosines and sines are taken in float32 (complex64 chirps).  The
  tracking keystone demodulates by exp(-j Psi(t) s), resamples with F = 0 and remodulates by
  exp(j Psi(t + dt) s), Psi(t + dt) from the per-pulse Taylor series of the piecewise-quartic Psi.
* ``doppler_spectra`` (``doppler_estimator: fft``): the zoom DFT of eq. (23)-(26) as one batched
  complex64 ``xp.matmul`` per channel (E[i, z, n] = w_n exp(-j 2 pi f_z (t_n - t_c))).

Other keystone implementations (``dft``, ``sinc``), the methods without a keystone and the IAA estimator
have no GPU path: :func:`on_backend` leaves those stages on the CPU and logs one line saying so.  The
host-side geometry (CPI means, the Doppler band, the Taylor coefficients of Psi: O(pulses)) stays on
the CPU; the cube-sized work runs on the device.
"""
from __future__ import annotations

import logging

import numpy as np

from ..dsp.pulse import weighting
from ..dsp.xp import cis, fft_kwargs, fft_module, get_xp, is_numpy, to_device, to_host
from ..io.stagefile import StageData
from .motion import DopplerPhaseHistory, cpi_doppler_band_hz, cpi_means, tracked_depression_deg

log = logging.getLogger(__name__)

CONTEXT = ("slow_time_s", "scan_angle_deg", "position_m", "velocity_mps", "xyz")
KEYSTONE_METHODS = ("traditional", "decimation", "tracking")
BLOCK_BYTES = 1 << 28       # device work buffer per column block of the CZT (L x columns x 8 bytes)


# ----------------------------------------------------------------------------------------------
# The dispatch
# ----------------------------------------------------------------------------------------------
def gpu_path(name: str, params: dict) -> str | None:
    """None when stage ``name`` with ``params`` has a GPU path, else why it stays on the CPU."""
    if name == "keystone":
        if params["method"] not in KEYSTONE_METHODS:
            return f"method {params['method']} has no keystone"
        if params["implementation"] != "czt":
            return f"keystone {params['implementation']} has no GPU path (only czt)"
        if params.get("subswaths"):
            return "range sub-swaths (steep depression) have no GPU path"
    if name == "doppler_spectra" and params.get("estimator", "fft") != "fft":
        return f"doppler_estimator {params['estimator']} has no GPU path (only fft)"
    return None


def on_backend(stages: list, backend: str) -> list:
    """The chain's stages with keystone, doppler_spectra and monopulse_image replaced by their ``xp``
    versions (same params plus ``backend``) where they have a GPU path; :class:`BadInput` at once when
    ``backend`` is ``gpu`` and CuPy or a device is missing."""
    from ..runner import Stage
    from .gpu_imaging import monopulse_image

    get_xp(backend)                             # BadInput before any stage runs
    if backend == "cpu":
        return stages
    fns = {"keystone": keystone_stage, "doppler_spectra": doppler_spectra, "monopulse_image": monopulse_image}
    out = []
    for st in stages:
        why = gpu_path(st.name, st.params) if st.name in fns else "not a GPU stage"
        if st.name in fns and why is None:
            st = Stage(st.name, fns[st.name], dict(st.params, backend=backend), view=st.view)
        elif st.name in fns:
            log.info(f"processing.backend = gpu: stage {st.name} runs on the CPU ({why})")
        out.append(st)
    return out


# ----------------------------------------------------------------------------------------------
# 3. keystone: Bluestein CZT on xp
# ----------------------------------------------------------------------------------------------
def _czt_filters(xp, n: int, nfft: int, alpha):
    """FFT of the Bluestein filter h_d = W^(-d^2/2), W = exp(j 2 pi alpha / n), d = -(n-1)..(n-1)
    wrapped into length ``nfft``: [cols, nfft], computed once per distinct alpha (host array ``alpha``;
    the decimated layout repeats the range-frequency alphas in every sub-sequence)."""
    alpha_u, inverse = np.unique(alpha, return_inverse=True)
    d = np.arange(nfft, dtype=np.float64)
    d[d > nfft // 2] -= nfft
    cycles = -(to_device(alpha_u, xp)[:, None] / (2.0 * n)) * to_device(d * d, xp)[None, :]
    spec = fft_module(xp).fft(cis(xp, cycles), axis=-1, **fft_kwargs(xp))
    return spec[to_device(inverse.reshape(-1), xp)]


def czt_chirps(xp, n: int, alpha, t0_index, *, ambiguity=0, extra_cycles=None):
    """The CZT keystone's chirps for columns with ``alpha``, ``t0_index`` (host float64 [cols]): input
    chirp, filter spectrum and output chirp (with 1/n), each [cols, *] on ``xp``; see :func:`czt_apply`.
    ``ambiguity``: the integer F (scalar); ``extra_cycles`` ([cols, n] float64 on ``xp``, optional) is
    added to the output chirp's phase (the tracking keystone's remodulation)."""
    nfft = fft_module(xp).next_fast_len(2 * n - 1)
    c_min = -(n // 2)
    i = xp.arange(n, dtype=xp.float64)[None, :]
    a, t0 = to_device(alpha, xp, np.float64)[:, None], to_device(t0_index, xp, np.float64)[:, None]
    # input chirp: origin shift exp(j 2 pi c (1 - alpha) t0 / n) and W^(i^2/2), c = c_min + i
    pre = cis(xp, (c_min + i) * ((1.0 - a) * t0 / n) + (a / (2.0 * n)) * (i * i))
    # output chirp W^(c_min m + m^2/2) and the ambiguity correction exp(j 2 pi F tau), eq. (22) corrected
    cycles = (a / n) * (c_min * i + 0.5 * (i * i))
    if float(ambiguity) != 0.0:
        cycles += float(ambiguity) * (a * i + (1.0 - a) * t0)
    if extra_cycles is not None:
        cycles += extra_cycles
    post = cis(xp, cycles)
    post *= np.float32(1.0 / n)
    return pre, _czt_filters(xp, n, nfft, alpha), post


def czt_apply(xp, x, pre, filt, post):
    """Keystone of the rows of ``x`` ([cols, n] complex64 on ``xp``: one range-frequency column per row,
    slow time along the last axis, contiguous for the device FFTs) by the CZT:

        y[k, m] = exp(j 2 pi F tau) (1/n) sum_c X_k(c) exp(j 2 pi c tau / n),  tau = alpha (m - t0) + t0

    (eq. 8, 21, 22 corrected), c the centred Doppler index.  With c = c_min + i and
    tau = alpha m + (1 - alpha) t0 the sum is W^(c_min m + m^2/2) sum_i [Y_i W^(i^2/2)] W^(-(m-i)^2/2),
    Y_i = X(c) exp(j 2 pi c (1 - alpha) t0 / n): a linear convolution by FFTs of length L >= 2n - 1
    with the chirps of :func:`czt_chirps`.
    """
    fx, kw = fft_module(xp), fft_kwargs(xp)
    cols, n = x.shape
    buf = xp.zeros((cols, filt.shape[-1]), dtype=xp.complex64)
    buf[:, :n] = xp.fft.fftshift(fx.fft(x, axis=-1, **kw), axes=-1)      # centred: i holds c = c_min + i
    buf[:, :n] *= pre
    buf = fx.fft(buf, axis=-1, overwrite_x=True, **kw)
    buf *= filt
    buf = fx.ifft(buf, axis=-1, overwrite_x=True, **kw)
    y = buf[:, :n]
    y *= post
    return y


def czt_keystone(xp, x, *, alpha, t0_index, ambiguity=0):
    """:func:`czt_apply` with the chirps of ``alpha``, ``t0_index`` (host [cols]) and ``ambiguity``."""
    return czt_apply(xp, x, *czt_chirps(xp, x.shape[1], alpha, t0_index, ambiguity=ambiguity))


def psi_taylor(hist: DopplerPhaseHistory, slow_time_s):
    """Psi(t_m) and its first four derivatives on the pulse grid (rad, rad/s, ...): Psi' = 2 pi f_b with
    f_b the cubic spline of the beam-centre Doppler (the spline Psi integrates), so the series to
    fourth order is Psi's own piecewise quartic."""
    return [hist.phase_rad(slow_time_s)] + [2.0 * np.pi * hist._anti(slow_time_s, nu) for nu in range(1, 5)]


def tracking_cycles(xp, derivs, t0_index, alpha, scale, prf_hz: float):
    """(demodulation, remodulation) phases in cycles, [cols, n] float64 on ``xp``: -Psi(t_m) s / 2 pi and
    Psi(t_m + dt) s / 2 pi, dt = (alpha - 1)(m - t0) / PRF the keystone's resampling shift (eq. 8),
    Psi(t_m + dt) by Horner from the Taylor coefficients ``derivs`` (host arrays [n])."""
    p0, p1, p2, p3, p4 = (to_device(d, xp)[None, :] for d in derivs)
    n = p0.shape[1]
    s = scale[:, None] / (2.0 * np.pi)
    dt = (xp.arange(n, dtype=xp.float64)[None, :] - t0_index[:, None]) * ((alpha[:, None] - 1.0) / prf_hz)
    acc = ((p4 * (dt / 24.0) + p3 / 6.0) * dt + p2 / 2.0) * dt + p1
    acc = acc * dt + p0
    return -p0 * s, acc * s


def keystone_pair(x_sum, x_diff, *, alpha, t0_index, ambiguity, tracking=None, backend: str = "gpu",
                  block_bytes: int = BLOCK_BYTES):
    """CZT keystone of both channels ([n, cols] host arrays, slow time first) on ``backend``'s array
    module; host complex64 results [n, cols].  ``tracking``: None or (hist, slow_time_s, prf_hz, scale
    per column), the tracking keystone with F = 0.  On the device the channels are transposed once to
    [cols, n] (contiguous FFTs along slow time); columns run in blocks of ``block_bytes`` of buffer."""
    xp = get_xp(backend)
    n, cols = x_sum.shape
    nfft = fft_module(xp).next_fast_len(2 * n - 1)
    alpha_h = np.broadcast_to(np.asarray(alpha, dtype=np.float64), (cols,))
    t0_h = np.broadcast_to(np.asarray(t0_index, dtype=np.float64), (cols,))
    derivs = None
    if tracking is not None:
        hist, t, prf_hz, scale_h = tracking
        derivs = psi_taylor(hist, t)
        scale_h = np.broadcast_to(np.asarray(scale_h, dtype=np.float64), (cols,))
    step = max(1, int(block_bytes) // (8 * nfft))
    # both channels on the device, transposed once to [cols, n]; the chirps of a block serve both
    xts = [xp.ascontiguousarray(to_device(x, xp, np.complex64).T) for x in (x_sum, x_diff)]
    yts = [xp.empty((cols, n), xp.complex64) for _ in xts]
    for lo in range(0, cols, step):
        b = slice(lo, min(cols, lo + step))
        demod = remod = None
        if derivs is not None:
            demod, remod = tracking_cycles(xp, derivs, to_device(t0_h[b], xp), to_device(alpha_h[b], xp),
                                           to_device(scale_h[b], xp), prf_hz)
            demod = cis(xp, demod)
        chirps = czt_chirps(xp, n, alpha_h[b], t0_h[b], ambiguity=0 if derivs is not None else ambiguity,
                            extra_cycles=remod)
        del remod
        for xt, yt in zip(xts, yts):
            yt[b] = czt_apply(xp, xt[b] if demod is None else xt[b] * demod, *chirps)
    del xts
    return tuple(to_host(xp.ascontiguousarray(yt.T)) for yt in yts)


def keystone_stage(data: StageData, *, method: str, implementation: str, fc_hz: float, prf_hz: float,
                   t_ref_s: float, ambiguity: int, doppler_ref_hz: float, depression_deg: float,
                   reference_range_m: float, n_taps: int = 16, backend: str = "gpu") -> StageData:
    """Stage 3 on ``backend`` (``traditional``, ``decimation``, ``tracking``; ``implementation: czt``):
    the vars, dims and attrs of :func:`forward.chain.keystone_stage`.  ``doppler_ref_hz``,
    ``depression_deg`` (tracking: the Doppler history's), ``reference_range_m`` and ``n_taps`` as there."""
    if method not in KEYSTONE_METHODS or implementation != "czt":
        raise ValueError(f"GPU keystone: method {method!r}, keystone {implementation!r}; allowed: "
                         f"{', '.join(KEYSTONE_METHODS)} with czt")
    out = data.copy_vars(*CONTEXT)
    for name in ("fr_hz", "range_m", "subseq", "sub_pulse"):
        out.vars[name] = data.vars[name]
    fr_hz = np.asarray(data["fr_hz"], dtype=np.float64)
    p, q, n_f = data["sum_f"].shape
    t = data["slow_time_s"]
    m0 = (t_ref_s - t[0]) * prf_hz                     # global keystone origin, in pulses
    alpha = np.tile(fc_hz / (fc_hz + fr_hz), q)        # eq. (8); column (q, k) -> q * n_f + k
    t0 = np.repeat((m0 - np.arange(q)) / q, n_f)       # the origin in each sub-sequence's samples
    tracking = None
    if method == "tracking":
        if q != 1:
            raise ValueError("tracking keystone runs on the whole sequence (q = 1)")
        depression = tracked_depression_deg(t, data["position_m"], data["velocity_mps"], data["scan_angle_deg"],
                                            depression_deg, fc_hz, t_ref_s, reference_range_m, prf_hz)
        hist = DopplerPhaseHistory(t, data["velocity_mps"], data["scan_angle_deg"], depression, fc_hz, t_ref_s)
        tracking = (hist, t, prf_hz, 1.0 + fr_hz / fc_hz)       # Doppler at f_r scales by (fc + fr)/fc
    y_sum, y_diff = keystone_pair(np.reshape(data["sum_f"], (p, q * n_f)), np.reshape(data["diff_f"], (p, q * n_f)),
                                  alpha=alpha, t0_index=t0, ambiguity=ambiguity, tracking=tracking,
                                  backend=backend)
    dims = ("sub_pulse", "subseq", "fr_hz")
    out.add("sum_f", y_sum.reshape(p, q, n_f), dims, "1", f"sum channel after the {method} correction")
    out.add("diff_f", y_diff.reshape(p, q, n_f), dims, "1", f"difference channel after the {method} correction")
    out.attrs.update(method=method, keystone=implementation, ambiguity_number=int(ambiguity),
                     t_ref_s=float(t_ref_s))
    return out


# ----------------------------------------------------------------------------------------------
# 6. per-CPI Doppler spectra: the zoom DFT as one batched product on xp
# ----------------------------------------------------------------------------------------------
def doppler_spectra(data: StageData, *, cpi: int, n_doppler: int, window: str, fc_hz: float,
                    beamwidth_deg: float, depression_deg: float, prf_hz: float, follow_speed: bool,
                    band_beamwidths: float = 1.0, estimator: str = "fft", backend: str = "gpu") -> StageData:
    """Stage 6 on ``backend``: per CPI the zoom DFT of both channels on the main-beam band (eq. 23-26),
    the vars and attrs of :func:`forward.chain.doppler_spectra` (``estimator: fft`` only)."""
    if estimator != "fft":
        raise ValueError(f"GPU Doppler stage: estimator {estimator!r}; allowed: fft")
    xp = get_xp(backend)
    t_cpi, t_c, beam_c, vel = cpi_means(data, cpi, follow_speed)       # eq. (25): the CPI's INS means
    n_cpi = t_cpi.shape[0]
    m = n_cpi * cpi
    f_lo, f_hi = cpi_doppler_band_hz(vel, beam_c, depression_deg, fc_hz, beamwidth_deg, prf_hz, cpi, band_beamwidths)
    f_z = f_lo[:, None] + (f_hi - f_lo)[:, None] * ((np.arange(n_doppler) + 0.5) / n_doppler)[None, :]
    w = weighting(window, cpi)
    # E[i, z, n] = w_n exp(-j 2 pi f_z (t_n - t_c)): phase in float64 on the device, complex64 matrix
    cycles = -to_device(f_z, xp)[:, :, None] * to_device(t_cpi - t_c[:, None], xp)[:, None, :]
    e = cis(xp, cycles)
    del cycles
    e *= to_device(w.astype(np.float32), xp)[None, None, :]
    n_r = data["sum"].shape[1]
    if is_numpy(xp):
        from ..dsp.blas import batched_matmul as matmul     # the BLAS on one thread (no pool stalls)
    else:
        matmul = xp.matmul
    z = [to_host(matmul(e, to_device(np.asarray(data[ch])[:m], xp, np.complex64).reshape(n_cpi, cpi, n_r)))
         for ch in ("sum", "diff")]
    out = StageData(attrs=dict(data.attrs))
    out.add("cpi_time_s", t_c, ("cpi_time_s",), "s", "CPI centre time t_c")
    out.add("doppler_cell", np.arange(n_doppler), ("doppler_cell",), "1", "zoomed Doppler cell")
    out.vars["range_m"] = data.vars["range_m"]
    out.vars["xyz"] = data.vars["xyz"]
    out.add("cpi_beam_deg", beam_c, ("cpi_time_s",), "deg", "mean beam pointing angle in the CPI")
    out.add("cpi_speed_mps", np.linalg.norm(vel, axis=1), ("cpi_time_s",), "m/s",
            "CPI speed |v| used for the Doppler band (eq. 25)")
    out.add("cpi_velocity_mps", np.ascontiguousarray(vel), ("cpi_time_s", "xyz"), "m/s",
            "CPI velocity vector used for the Doppler band (eq. 25)")
    out.add("cpi_position_m", data["position_m"][:m].reshape(n_cpi, cpi, 3).mean(axis=1),
            ("cpi_time_s", "xyz"), "m", "mean antenna position in the CPI")
    out.add("doppler_hz", f_z, ("cpi_time_s", "doppler_cell"), "Hz", "true Doppler of each zoomed cell")
    out.add("sum_z", z[0], ("cpi_time_s", "doppler_cell", "range_m"), "1", "sum Doppler spectrum")
    out.add("diff_z", z[1], ("cpi_time_s", "doppler_cell", "range_m"), "1", "difference Doppler spectrum")
    out.attrs.update(cpi=cpi, coherent_gain=float(w.sum()), doppler_window=window)
    return out
