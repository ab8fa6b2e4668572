"""The forward-looking processing chain, one pure function per stage (Li & Li 2023, Sec. 3).

Stages (each writes ``RUN_DIR/stages/NN_<name>.h5``):

1. ``range_fft``        range time -> range frequency f_r (eq. 6)
2. ``decimate``         slow time split into Q sub-sequences P_q = pulses q, q+Q, ... (Sec. 3.2, Fig. 3)
3. ``keystone``         the method's range-migration correction (see below), per sub-sequence
4. ``regroup``          sub-sequences interleaved back into one sequence (Fig. 3, inverse)
5. ``range_curvature``  eq. (12) compensation about t_ref, then back to range time
6. ``doppler_spectra``  per CPI, zoomed Doppler spectra of sum and difference (eq. 23-26)
7. ``monopulse_image``  angle per Doppler cell from Re(diff/sum), sum power projected on (range, angle)

Methods (stage 3): ``none`` (identity); ``bulk`` (per-pulse envelope shift by the INS motion along
the flight path); ``beam`` (per-pulse envelope shift by the predicted range history of the beam's
pointing direction); ``traditional`` (keystone over the whole sequence with one ambiguity number, eq. 8,
15-22 with the NOTES.md correction); ``decimation`` (the paper's algorithm: keystone of every sub-sequence
at PRF/Q with its ambiguity number, one global time origin); ``tracking`` (keystone whose Doppler
reference follows the predicted beam-centre Doppler history from INS motion and scan: demodulate,
resample with F = 0, remodulate).  Every corrected output refers to t_ref (NOTES.md).
"""
from __future__ import annotations

import logging
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import scipy.fft

from ..dsp.geometry import C_MPS, ambiguity_number, unit_vector
from .keystone_fast import keystone_both, keystone_both_blocked
from ..dsp.blas import batched_matmul, batched_matmul_each, worker_threads
from ..dsp.imaging import auto_range_oversample, image_angle_grid
from ..dsp.keystone_common import cis_outer, cis_rad as _cis, outer_grid
from .motion import (DopplerPhaseHistory, auto_doppler_cells, beam_range_history_m, boresight_doppler_spread_hz,
                     bulk_range_history_m, cpi_doppler_band_hz, cpi_means, doppler_band_depressions, fit_motion,
                     keystone_residual_envelope_m, position_at, reference_depression_deg, t_ref_seconds,
                     tracked_depression_deg, widest_cpi_band_hz)
from ..runner import Stage
from ..io import backing
from ..io.stagefile import StageData
from ..io.navigation import navigation_of, with_navigation
from ..limits import check_processing_sizes, check_subswath_sizes
from .monopulse import monopulse_image   # noqa: F401 (stage 7, forward/monopulse.py; chain.monopulse_image)

log = logging.getLogger(__name__)


CONTEXT = ("slow_time_s", "scan_angle_deg", "position_m", "velocity_mps", "xyz")
KEYSTONE_METHODS = ("traditional", "decimation", "tracking")
STAGE_NAMES = ("range_fft", "decimate", "keystone", "regroup", "range_curvature", "doppler_spectra",
               "monopulse_image", "dwell_image")     # every forward chain's stages (CPI or dwell imaging)


def _ctx(data: StageData) -> StageData:
    """A new StageData carrying the context vars (axes, INS) and attrs forward."""
    return data.copy_vars(*CONTEXT)



# ----------------------------------------------------------------------------------------------
# 1. range FFT
# ----------------------------------------------------------------------------------------------
def range_fft(data: StageData, *, fs_hz: float) -> StageData:
    """Range time -> range frequency (eq. 6), both channels; f_r in FFT order, values centred."""
    out = _ctx(data)
    n_r = data["sum"].shape[1]
    fr_hz = scipy.fft.fftfreq(n_r, 1.0 / fs_hz)
    out.add("fr_hz", fr_hz, ("fr_hz",), "Hz", "range frequency (FFT order)")
    out.add("range_m", data["range_m"], ("range_m",), "m", "slant range of the input samples")
    for ch in ("sum", "diff"):
        out.add(f"{ch}_f", _fft_rows(data[ch]), ("slow_time_s", "fr_hz"), "1", f"{ch} channel, range frequency")
    return out


def _fft_rows(x):
    """FFT of every row: one call in memory; in blocks of pulses into a file-backed output when the
    chain runs out of core (io/backing.py), the same numbers (each row's transform is its own)."""
    if not backing.active():
        return scipy.fft.fft(x, axis=1, workers=-1)
    return backing.map_blocks(lambda s: scipy.fft.fft(x[s], axis=1, workers=-1), x.shape[0], x.shape,
                              np.result_type(x.dtype, np.complex64), 8 * x.shape[1])


# ----------------------------------------------------------------------------------------------
# 2. decimation and 4. regrouping (Sec. 3.2, Fig. 3)
# ----------------------------------------------------------------------------------------------
def decimate(data: StageData, *, q: int) -> StageData:
    """Sub-sequence q holds pulses q, q+Q, q+2Q, ...: layout [P, Q, n_fr] (a view, no copy)."""
    out = _ctx(data)
    for name in ("fr_hz", "range_m"):
        out.vars[name] = data.vars[name]
    m, n_f = data["sum_f"].shape
    if m % q:
        raise ValueError(f"q = {q} does not divide the {m} pulses")
    out.add("subseq", np.arange(q), ("subseq",), "1", "sub-sequence index q")
    out.add("sub_pulse", np.arange(m // q), ("sub_pulse",), "1", "pulse index p within a sub-sequence")
    for ch in ("sum", "diff"):
        out.add(f"{ch}_f", data[f"{ch}_f"].reshape(m // q, q, n_f), ("sub_pulse", "subseq", "fr_hz"), "1",
                f"{ch} channel, decimated sub-sequences")
    out.attrs["q"] = q
    return out


def regroup(data: StageData) -> StageData:
    """Inverse of ``decimate``: interleave the sub-sequences back into one slow-time sequence."""
    out = _ctx(data)
    for name in ("fr_hz", "range_m"):
        out.vars[name] = data.vars[name]
    for ch in ("sum", "diff"):
        x = data[f"{ch}_f"]
        out.add(f"{ch}_f", x.reshape(x.shape[0] * x.shape[1], x.shape[2]), ("slow_time_s", "fr_hz"), "1",
                f"{ch} channel, range-migration corrected, regrouped")
    return out


# ----------------------------------------------------------------------------------------------
# 3. the method's range-migration correction
# ----------------------------------------------------------------------------------------------
def keystone_stage(data: StageData, *, method: str, implementation: str, fc_hz: float, prf_hz: float,
                   t_ref_s: float, ambiguity: int, doppler_ref_hz: float, depression_deg: float,
                   reference_range_m: float, n_taps: int = 16, subswaths: list | None = None) -> StageData:
    """Stage 3: range-migration correction of every sub-sequence (layout [P, Q, n_fr]).

    ``ambiguity`` is the Doppler ambiguity number at the sub-sequence rate PRF/Q (eq. 17 and 20),
    ``doppler_ref_hz`` the unrounded reference Doppler the sinc implementation demodulates.
    ``subswaths`` (steep depression, ``forward/subswath.py``): the window corrected in parts, each with
    its own reference depression, range, Doppler and ambiguity number.
    """
    if subswaths:
        from .subswath import keystone_subswaths

        out = keystone_subswaths(data, subswaths, keystone_stage, method=method, implementation=implementation,
                                 fc_hz=fc_hz, prf_hz=prf_hz, t_ref_s=t_ref_s, n_taps=n_taps)
        out.attrs.update(method=method, keystone=implementation, ambiguity_number=int(ambiguity),
                         t_ref_s=float(t_ref_s), subswaths=len(subswaths))
        return out
    out = _ctx(data)
    for name in ("fr_hz", "range_m", "subseq", "sub_pulse"):
        out.vars[name] = data.vars[name]
    fr_hz = data["fr_hz"]
    x_sum, x_diff = data["sum_f"], data["diff_f"]
    p, q, n_f = x_sum.shape
    t = data["slow_time_s"]
    m0 = (t_ref_s - t[0]) * prf_hz                        # keystone time origin, in pulses (may be fractional)
    dims = ("sub_pulse", "subseq", "fr_hz")

    if method == "none":
        y_sum, y_diff = x_sum, x_diff
    elif method in ("bulk", "beam"):
        pos = data["position_m"]
        if method == "bulk":
            delta_r = bulk_range_history_m(pos, m0, depression_deg)
        else:
            delta_r = beam_range_history_m(pos, m0, data["scan_angle_deg"], depression_deg,
                                           reference_range_m)
        # envelope shift of pulse m by the predicted R(t_m) - R(t_ref); carrier phase kept
        rate = 4.0 * np.pi * delta_r / C_MPS
        if backing.active():     # out of core: blocks of pulses into file-backed outputs, the same numbers
            y_sum, y_diff = _shifted_rows(x_sum, x_diff, rate, fr_hz)
        else:
            shift = cis_outer(rate, fr_hz).reshape(p, q, n_f)
            y_sum, y_diff = x_sum * shift, x_diff * shift
    elif method in ("traditional", "decimation", "tracking"):
        alpha = fc_hz / (fc_hz + fr_hz)                   # eq. (8)
        t0_sub = (m0 - np.arange(q)) / q                  # global origin in each sub-sequence's samples
        alpha_cols = np.tile(alpha, q)                    # column (q, k) -> index q*n_f + k
        t0_cols = np.repeat(t0_sub, n_f)
        tracking = None
        if method == "tracking":
            if q != 1:
                raise ValueError("tracking keystone runs on the whole sequence (q = 1)")
            depression = tracked_depression_deg(t, data["position_m"], data["velocity_mps"], data["scan_angle_deg"],
                                                depression_deg, fc_hz, t_ref_s, reference_range_m, prf_hz)
            hist = DopplerPhaseHistory(t, data["velocity_mps"], data["scan_angle_deg"], depression, fc_hz, t_ref_s)
            tracking = (hist, t, prf_hz, 1.0 + fr_hz / fc_hz)    # Doppler at f_r scales by (fc+fr)/fc
        ref = 0.0 if method == "tracking" else doppler_ref_hz / (prf_hz / q)
        # one geometry, both channels: chirps, demodulation and remodulation computed once
        both = keystone_both_blocked if backing.active() else keystone_both   # out of core: super-blocks
        y_sum, y_diff = both(x_sum.reshape(p, q * n_f), x_diff.reshape(p, q * n_f), alpha=alpha_cols,
                             t0_index=t0_cols, implementation=implementation,
                             ambiguity=0 if method == "tracking" else ambiguity,
                             doppler_ref=ref, n_taps=n_taps, tracking=tracking, period=n_f)
        y_sum, y_diff = y_sum.reshape(p, q, n_f), y_diff.reshape(p, q, n_f)
    else:
        raise ValueError(f"method {method!r}; allowed: none, bulk, beam, traditional, decimation, tracking")
    out.add("sum_f", y_sum, dims, "1", f"sum channel after the {method} correction")
    out.add("diff_f", y_diff, dims, "1", f"difference channel after the {method} correction")
    out.attrs.update(method=method, keystone=implementation, ambiguity_number=int(ambiguity),
                     t_ref_s=float(t_ref_s))
    return out


def _shifted_rows(x_sum, x_diff, rate, fr_hz):
    """``x * exp(j rate[m] f_r)`` of both channels ([p, q, n_f], pulse m = p q + q) in blocks of pulses,
    into file-backed outputs (the phasors of a block only; the grid of the whole axis, so that every
    row is the one :func:`cis_outer` gives for all of them)."""
    shape, n_f = x_sum.shape, x_sum.shape[-1]
    y_sum, y_diff = backing.empty(shape, np.complex64), backing.empty(shape, np.complex64)
    grid = outer_grid(fr_hz, float(np.max(np.abs(rate), initial=0.0)))
    step = backing.rows_per_block(8 * n_f)
    for x, y in ((x_sum, y_sum), (x_diff, y_diff)):
        xf, yf = x.reshape(-1, n_f), y.reshape(-1, n_f)
        for a in range(0, xf.shape[0], step):
            np.multiply(xf[a:a + step], cis_outer(rate[a:a + step], fr_hz, grid), out=yf[a:a + step])
    return y_sum, y_diff


# ----------------------------------------------------------------------------------------------
# 5. range curvature (eq. 12), back to range time
# ----------------------------------------------------------------------------------------------
def range_curvature(data: StageData, *, model: str, radial_accel_mps2: float, t_ref_s: float,
                    prf_hz: float, depression_deg: float, reference_range_m: float) -> StageData:
    """Range-curvature compensation about t_ref, then inverse range FFT back to range time.

    ``model``: ``eq12`` multiplies by exp(j 2 pi f_r a_y cos(phi_0) (t - t_ref)^2 / c) (the paper's eq. 12);
    ``beam`` by exp(j 4 pi f_r E(t) / c) with E the exact residual envelope a keystone leaves for the
    beam-centre point of each pulse (:func:`motion.keystone_residual_envelope_m`); ``off`` does neither.
    """
    out = _ctx(data)
    out.vars["range_m"] = data.vars["range_m"]
    t = data["slow_time_s"] - t_ref_s
    fr_hz = data["fr_hz"]
    if model == "eq12":          # the compensation phase is rate(t) * f_r, rate in rad/Hz
        rate_rad_per_hz = 2.0 * np.pi * radial_accel_mps2 * t ** 2 / C_MPS
    elif model == "beam":
        env_m = keystone_residual_envelope_m(data["slow_time_s"], data["position_m"], data["velocity_mps"],
                                             t_ref_s, prf_hz, data["scan_angle_deg"], depression_deg,
                                             reference_range_m)
        rate_rad_per_hz = 4.0 * np.pi * env_m / C_MPS
    elif model == "off":
        rate_rad_per_hz = None
    else:
        raise ValueError(f"curvature model {model!r}; allowed: off, eq12, beam")
    # h = exp(j rate f_r), x * h, ifft over range: one block of pulses at a time, h shared by both channels
    y_sum, y_diff = _compensate_rows(data["sum_f"], data["diff_f"], rate_rad_per_hz, fr_hz)
    for ch, y in (("sum", y_sum), ("diff", y_diff)):
        out.add(ch, y, ("slow_time_s", "range_m"), "1", f"{ch} channel, motion compensated, range time")
    out.attrs.update(range_curvature=model, radial_accel_mps2=float(radial_accel_mps2))
    return out


def _compensate_rows(x_sum, x_diff, rate_rad_per_hz, fr_hz, block_bytes: int = 1 << 20):
    """ifft over range of ``x * exp(j rate f_r)`` for both channels, in blocks of pulses (h of a block
    only: no cube-sized temporary; :func:`dsp.keystone_common.cis_outer`, f_r on its grid).  The blocks
    run on a thread pool, one FFT thread each (pocketfft's own threads cost more than they gain on
    transforms this small); each block's product is written into the output and transformed there."""
    y_sum, y_diff = backing.empty(x_sum.shape, np.complex64), backing.empty(x_diff.shape, np.complex64)
    step = max(1, block_bytes // max(1, 8 * x_sum.shape[1]))
    grid = None if rate_rad_per_hz is None else outer_grid(fr_hz, float(np.max(np.abs(rate_rad_per_hz), initial=0.0)))
    starts = range(0, x_sum.shape[0], step)
    threads = min(worker_threads(), len(starts))
    fft_workers = 1 if threads > 1 else -1

    def block(lo):
        b = slice(lo, lo + step)
        h = None if rate_rad_per_hz is None else cis_outer(rate_rad_per_hz[b], fr_hz, grid)
        for x, y in ((x_sum, y_sum), (x_diff, y_diff)):
            if h is None:
                y[b] = x[b]
            else:
                np.multiply(x[b], h, out=y[b])
            _ifft_rows_in_place(y[b], fft_workers)

    if threads > 1:
        with ThreadPoolExecutor(max_workers=threads) as pool:
            list(pool.map(block, starts))
    else:
        for lo in starts:
            block(lo)
    return y_sum, y_diff


def _ifft_rows_in_place(block, workers):
    """The inverse FFT over the last axis of a C-contiguous complex64 block, written over it
    (``overwrite_x``: pocketfft transforms in place; copied back should a SciPy return a new array)."""
    out = scipy.fft.ifft(block, axis=1, workers=workers, overwrite_x=True)
    if not np.shares_memory(out, block):
        block[...] = out


# ----------------------------------------------------------------------------------------------
# 6. per-CPI Doppler spectra (eq. 23-26)
# ----------------------------------------------------------------------------------------------
def _window(name: str, n: int) -> np.ndarray:
    from ..dsp.pulse import weighting

    return weighting(name, n)


def doppler_spectra(data: StageData, *, cpi: int, n_doppler: int, window: str, fc_hz: float,
                    beamwidth_deg: float, depression_deg: float, prf_hz: float, follow_speed: bool,
                    band_beamwidths: float = 1.0, estimator: str = "fft", iaa_iterations: int = 10) -> StageData:
    """Per CPI: zoomed DFT (a chirp-Z zoom on the main-beam Doppler band) of both channels (of the sum
    channel alone where ``data`` holds no ``diff``: the dwell-profile metrics, ``run_metrics.profile_spectra``).

    The CPI velocity is the INS mean over the CPI, v_c = v + a t_c (eq. 25, the whole vector) when
    ``follow_speed``; otherwise the initial velocity is used for every CPI (what is lost without eq. 25
    shows in the image).
    """
    out = StageData(attrs=dict(data.attrs))
    t_cpi, t_c, beam_c, vel = cpi_means(data, cpi, follow_speed)       # eq. (25): the CPI's INS means
    n_cpi = t_cpi.shape[0]
    m = n_cpi * cpi
    speed = np.linalg.norm(vel, axis=1)
    f_lo, f_hi = cpi_doppler_band_hz(vel, beam_c, depression_deg, fc_hz, beamwidth_deg, prf_hz, cpi,
                                     band_beamwidths)
    frac = (np.arange(n_doppler) + 0.5) / n_doppler
    f_z = f_lo[:, None] + (f_hi - f_lo)[:, None] * frac[None, :]          # [n_cpi, n_doppler], true Hz
    w = _window(window, cpi)

    def zoom_matrix(c=slice(None)):   # E[i, z, n] = w_n exp(-j 2 pi f_z (t_n - t_c)) of the CPIs c: the DFT
        return (w[None, None, :] * _cis(-2.0 * np.pi * f_z[c, :, None]       # evaluated on the band only
                                        * (t_cpi[c] - t_c[c, None])[:, None, :])).astype(np.complex64)

    n_r = data["sum"].shape[1]
    # one small product per CPI and channel, the BLAS on one thread (dsp.blas: no pool stalls), the
    # two channels side by side
    channels = ("sum", "diff") if "diff" in data else ("sum",)
    z_sum, *z_diff = _zoom(zoom_matrix, *(data[ch][:m].reshape(n_cpi, cpi, n_r) for ch in channels))
    if estimator == "iaa":      # processing.doppler_estimator: iaa (dsp.iaa), same cells and scale
        from ..dsp.iaa import iaa_doppler

        x_sum, x_diff = data["sum"][:m].reshape(n_cpi, cpi, n_r), data["diff"][:m].reshape(n_cpi, cpi, n_r)
        a = _cis(2.0 * np.pi * (t_cpi - t_c[:, None])[:, :, None] * f_z[:, None, :])    # [n_cpi, cpi, K]
        pz = np.abs(z_sum) ** 2
        floor = np.median(pz.reshape(n_cpi, -1), axis=1)
        active = pz.max(axis=1) > floor[:, None] * 10 ** (12.0 / 10)      # range cells holding an echo
        s_s, s_d = iaa_doppler(x_sum, x_diff, a, t_s=t_cpi - t_c[:, None], prf_hz=prf_hz,
                               n_iter=iaa_iterations, active=active,
                               noise_power=float(np.median(np.abs(x_sum) ** 2)))
        z_sum, z_diff = s_s * np.float32(w.sum()), [s_d * np.float32(w.sum())]
    out.add("cpi_time_s", t_c, ("cpi_time_s",), "s", "CPI centre time t_c")
    out.add("doppler_cell", np.arange(n_doppler), ("doppler_cell",), "1", "zoomed Doppler cell")
    out.vars["range_m"] = data.vars["range_m"]
    out.vars["xyz"] = data.vars["xyz"]
    out.add("cpi_beam_deg", beam_c, ("cpi_time_s",), "deg", "mean beam pointing angle in the CPI")
    out.add("cpi_speed_mps", speed, ("cpi_time_s",), "m/s", "CPI speed |v| used for the Doppler band (eq. 25)")
    out.add("cpi_velocity_mps", np.ascontiguousarray(vel), ("cpi_time_s", "xyz"), "m/s",
            "CPI velocity vector used for the Doppler band (eq. 25)")
    out.add("cpi_position_m", data["position_m"][:m].reshape(n_cpi, cpi, 3).mean(axis=1),
            ("cpi_time_s", "xyz"), "m", "mean antenna position in the CPI")
    out.add("doppler_hz", f_z, ("cpi_time_s", "doppler_cell"), "Hz", "true Doppler of each zoomed cell")
    out.add("sum_z", z_sum, ("cpi_time_s", "doppler_cell", "range_m"), "1", "sum Doppler spectrum")
    if z_diff:
        out.add("diff_z", z_diff[0], ("cpi_time_s", "doppler_cell", "range_m"), "1", "difference Doppler spectrum")
    out.attrs.update(cpi=cpi, coherent_gain=float(w.sum()), doppler_window=window)
    return out


def _zoom(zoom_matrix, *xs):
    """``E @ x`` per CPI ([n_cpi, n_doppler, cpi] @ [n_cpi, cpi, n_r]) for each channel ``x``, E of CPIs c
    being ``zoom_matrix(c)``: one batched product each, in memory the channels on threads side by side
    (``dsp.blas.batched_matmul_each``); out of core (io/backing.py) in blocks of CPIs into file-backed
    outputs, E made block by block too (whole, it grows with the pulses: 0.5 of a channel of 129 range
    samples, an independent review), the same products."""
    if not backing.active():
        return batched_matmul_each(zoom_matrix(), xs)
    n_cpi, n_r = xs[0].shape[0], xs[0].shape[2]
    e0 = zoom_matrix(slice(0, 1))
    outs = [backing.empty((n_cpi, e0.shape[1], n_r), np.complex64) for _ in xs]
    # a block's rows: its outputs, and E's float64 and complex128 temporaries (48 bytes per cell of E: with
    # few range columns, the profile metrics' windows, they outweigh the outputs cpi / n_r times over)
    step = backing.rows_per_block(max(8 * e0.shape[1] * n_r, 48 * e0.shape[1] * e0.shape[2]))
    for a in range(0, n_cpi, step):
        c = slice(a, min(n_cpi, a + step))
        e = zoom_matrix(c)
        for x, out in zip(xs, outs):
            out[c] = batched_matmul(e, x[c])
    return outs


# ----------------------------------------------------------------------------------------------
# 7. monopulse image
# ----------------------------------------------------------------------------------------------
# ----------------------------------------------------------------------------------------------
# Building the chain from a cube and the processing settings
# ----------------------------------------------------------------------------------------------
def chain_geometry(cube, proc: dict) -> dict:
    """Everything the stages need that is derived from the cube (never from the scenario)."""
    fit = fit_motion(cube.slow_time_s, cube.position_m)
    t_ref_s = t_ref_seconds(cube.slow_time_s, proc["t_ref"])
    m_ref = (t_ref_s - cube.slow_time_s[0]) * cube.radar["prf_hz"]
    p_ref, v_ref = position_at(cube.position_m, m_ref), position_at(cube.velocity_mps, m_ref)
    reference_range_m = float(0.5 * (cube.range_m[0] + cube.range_m[-1]))
    depression = reference_depression_deg(float(p_ref[2]), reference_range_m)
    fc = cube.radar["fc_hz"]
    # eq. (16)-(17): boresight Doppler with the speed at t_ref (processing.ambiguity_speed: t_ref), or
    # with the initial speed v of the paper's Sec. 4 (initial); the same for t_ref = start
    los0 = unit_vector(0.0, depression)
    v_amb = v_ref if proc.get("ambiguity_speed", "t_ref") == "t_ref" else cube.velocity_mps[0]
    f_dc0 = 2.0 * float(np.dot(v_amb, los0)) * fc / C_MPS
    return {"fit": fit, "t_ref_s": t_ref_s, "p_ref": p_ref, "v_ref": v_ref, "depression_deg": depression,
            "reference_range_m": reference_range_m, "f_dc0_hz": f_dc0,
            "radial_accel_mps2": float(fit.accel_mps2[1] * np.cos(np.radians(depression)))}


def monopulse_slope(cube) -> float:
    """The monopulse slope of ``processing.monopulse_calibration: auto`` (the cube's /antenna, else the
    data's); see :func:`calibration.calibration_for_cube`."""
    from .calibration import calibration_for_cube

    return calibration_for_cube(cube, "auto").slope_per_deg


def build_forward_stages(cube, proc: dict):
    """(source StageData, [Stage]) for a raw cube and resolved ``processing`` settings."""
    from .calibration import calibration_for_cube
    from .plan import method_budget_warnings, method_range_error_m, plan_for_cube
    from .subswath import plan_subswaths

    cube = with_navigation(cube, *navigation_of(proc))
    geo = chain_geometry(cube, proc)
    q_run = proc["q"] if proc["method"] == "decimation" else 1
    plan = plan_for_cube(cube, proc, q_candidates=sorted({1, q_run}))
    # steep depression: one reference depression per range sub-swath where one for the window does not hold
    subswaths, left_m = (None, 0.0) if proc.get("subswaths", "auto") == "none" else plan_subswaths(
        height_m=float(geo["p_ref"][2]), range_m=cube.range_m, velocity_mps=geo["v_ref"], fc_hz=cube.radar["fc_hz"],
        prf_hz=cube.radar["prf_hz"], q=q_run, method=proc["method"], lever_s=plan["lever_max_s"],
        walk_m=plan["range_walk_m"], bandwidth_hz=cube.radar["bandwidth_hz"], implementation=proc["keystone"],
        fastest_velocity_mps=cube.velocity_mps[int(np.argmax(np.linalg.norm(cube.velocity_mps, axis=1)))])
    geo["subswaths"] = len(subswaths) if subswaths else 1
    if subswaths and not backing.active():        # one sub-swath's padded keystone, before the chain (limits.py)
        check_subswath_sizes(n_subswaths=len(subswaths), widest_samples=max(sw["hi"] - sw["lo"] for sw in subswaths),
                             n_pulses=cube.n_pulses, walk_m=float(plan["range_walk_m"]))
    if subswaths:
        log.info(f"steep depression: the keystone stage corrects the range window in {len(subswaths)} sub-swaths, "
                 "one reference depression each (README, steep depression)")
    for line in method_budget_warnings(plan, proc, len(subswaths or ()), left_m):   # where the method cannot hold
        log.warning(line)
    geo["range_error_m"] = method_range_error_m(plan, proc, len(subswaths or ()), left_m)
    m_ref = int(round((geo["t_ref_s"] - cube.slow_time_s[0]) * cube.radar["prf_hz"]))
    geo["calibration"] = calibration_for_cube(cube, proc.get("monopulse_calibration", "auto"),
                                              t_ref_index=min(max(m_ref, 0), cube.n_pulses - 1),
                                              model=proc.get("calibration_model", "auto"))
    method = proc["method"]
    q = proc["q"] if method == "decimation" else 1
    prf = cube.radar["prf_hz"]
    ambiguity = int(ambiguity_number(geo["f_dc0_hz"], prf / q))                # eq. (17), (20)
    geo.update(q=q, ambiguity_number=ambiguity)
    geo["doppler_spread_hz"] = boresight_doppler_spread_hz(float(geo["p_ref"][2]), float(cube.range_m[0]),
                                                           float(cube.range_m[-1]), geo["v_ref"], cube.radar["fc_hz"])
    band_depressions = doppler_band_depressions(float(geo["p_ref"][2]), float(cube.range_m[0]),
                                                float(cube.range_m[-1]), geo["depression_deg"], geo["v_ref"],
                                                cube.radar["fc_hz"], prf, proc["cpi"])
    geo["n_doppler"] = proc["n_doppler"]
    if geo["n_doppler"] == "auto":       # the widest CPI band at 4 cells per resolution cell (motion.py)
        widest_hz = widest_cpi_band_hz(
            {"slow_time_s": cube.slow_time_s, "scan_angle_deg": cube.scan_angle_deg, "velocity_mps": cube.velocity_mps},
            cpi=proc["cpi"], follow_speed=bool(proc["doppler_centroid"]), depression_deg=band_depressions,
            fc_hz=cube.radar["fc_hz"], beamwidth_deg=cube.radar["beamwidth_3db_deg"], prf_hz=prf)
        geo["n_doppler"] = auto_doppler_cells(widest_hz, cpi=proc["cpi"], prf_hz=prf)
    geo["range_oversample"] = proc["range_oversample"]
    if geo["range_oversample"] == "auto":  # the power image's Nyquist rate (dsp/imaging.py)
        geo["range_oversample"] = auto_range_oversample(cube.radar["bandwidth_hz"], cube.radar["fs_hz"])
    n_angle = len(image_angle_grid(cube.scan_angle_deg, cube.radar["beamwidth_3db_deg"], proc["angle_step_deg"]))
    check_processing_sizes(n_range=cube.n_range, range_oversample=int(geo["range_oversample"]), n_angle=n_angle,
                           angle_step_deg=proc["angle_step_deg"], imaging=proc["imaging"],
                           n_cpi=cube.n_pulses // proc["cpi"], n_doppler=geo["n_doppler"],
                           spectra_in_memory=not backing.active())
    src = StageData()
    src.add("slow_time_s", cube.slow_time_s, ("slow_time_s",), "s", "slow time")
    src.add("range_m", cube.range_m, ("range_m",), "m", "slant range")
    src.add("xyz", np.arange(3), ("xyz",), "1", "x, y, z")
    src.add("scan_angle_deg", cube.scan_angle_deg, ("slow_time_s",), "deg", "beam pointing azimuth")
    src.add("position_m", cube.position_m, ("slow_time_s", "xyz"), "m", "antenna phase centre (INS)")
    src.add("velocity_mps", cube.velocity_mps, ("slow_time_s", "xyz"), "m/s", "antenna velocity (INS)")
    src.add("sum", cube.sum, ("slow_time_s", "range_m"), "1", "sum channel echo")
    src.add("diff", cube.diff, ("slow_time_s", "range_m"), "1", "difference channel echo")
    src.attrs.update(t_ref_s=geo["t_ref_s"], method=method)
    fc = cube.radar["fc_hz"]
    curvature = proc["curvature_model"]
    if curvature == "auto":
        curvature = "beam" if method == "tracking" else "eq12"
    if not proc["range_curvature"] or method not in KEYSTONE_METHODS:
        curvature = "off"       # bulk and beam already shift by the whole predicted range history
    geo["curvature_model"] = curvature                  # what stage 5 runs (metrics.json's params)
    # stage 6's settings; under imaging: dwell the dwell-profile metrics run it on their range windows
    # (run_metrics.profile_spectra), so that ISLR is eq. (27)'s whichever image the chain forms
    geo["doppler_params"] = {
        "cpi": proc["cpi"], "n_doppler": geo["n_doppler"], "window": proc["doppler_window"], "fc_hz": fc,
        "beamwidth_deg": cube.radar["beamwidth_3db_deg"], "depression_deg": band_depressions,
        "prf_hz": prf, "follow_speed": bool(proc["doppler_centroid"])}
    stages = [
        Stage("range_fft", range_fft, {"fs_hz": cube.radar["fs_hz"]}),
        Stage("decimate", decimate, {"q": q}, view=True),
        Stage("keystone", keystone_stage, {
            "method": method, "implementation": proc["keystone"], "fc_hz": fc, "prf_hz": prf,
            "t_ref_s": geo["t_ref_s"], "ambiguity": ambiguity, "doppler_ref_hz": geo["f_dc0_hz"],
            "depression_deg": geo["depression_deg"], "reference_range_m": geo["reference_range_m"],
            **({"subswaths": subswaths} if subswaths else {})}),
        Stage("regroup", regroup, {}, view=True),
        Stage("range_curvature", range_curvature, {
            "model": curvature, "radial_accel_mps2": geo["radial_accel_mps2"], "t_ref_s": geo["t_ref_s"],
            "prf_hz": prf, "depression_deg": geo["depression_deg"],
            "reference_range_m": geo["reference_range_m"]}),
        Stage("doppler_spectra", doppler_spectra, {
            **geo["doppler_params"],
            **({"estimator": "iaa"} if proc.get("doppler_estimator", "fft") == "iaa" else {})}),
        Stage("monopulse_image", monopulse_image, {
            "beamwidth_deg": cube.radar["beamwidth_3db_deg"],
            "angle_step_deg": proc["angle_step_deg"], "range_oversample": geo["range_oversample"],
            "threshold_db": proc["threshold_db"], "dynamic_range_db": 60.0,
            "position_ref_m": [float(v) for v in geo["p_ref"]], **geo["calibration"].stage_params()}),
    ]
    if proc.get("imaging", "cpi") == "dwell":      # whole-dwell imaging replaces stages 6-7 (dwell.py)
        from .dwell import dwell_stages

        stages = stages[:5] + dwell_stages(cube, proc, geo)
    if proc.get("backend", "cpu") == "gpu":        # processing.backend: stages 3, 6, 7 on xp (gpu_stages.py)
        from .gpu_stages import on_backend

        stages = on_backend(stages, "gpu")
    return src, stages, geo
