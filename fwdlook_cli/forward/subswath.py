"""Range sub-swaths: one reference depression for each part of a steep range window.

Every correction refers its range window to one depression phi_0 (README, "One reference depression
across a steep window"): ``tracking`` follows the boresight Doppler history there and resolves +-PRF / 2
about it, ``traditional`` and ``decimation`` take one ambiguity number, ``bulk`` and ``beam`` shift by
that range's history.  Where the boresight Doppler 2 v cos(phi(r)) / lambda changes across the window
by more than that holds (``motion.depression_reference_error_m`` over half a range sample), the keystone
stage splits the window into sub-swaths: cores that partition the range samples, each the narrowest
equal share of the window whose own middle reference keeps the error within half a range sample (with a
guard band: a Doppler past ``GUARD`` of the half rate counted as folded, for what the boresight model
leaves out, a target's own range and speed when the beam sees it), each padded on both sides by the range
a target's echo moves while the beam sees it (the plan's walk, plus the compressed pulse's reach; zeros
beyond the window's ends).  Per sub-swath: its padded range samples back to range time, forward again over their
own length, the stage's correction with the core's own reference (depression, reference range, Doppler
and ambiguity number), back to range time, and its core kept.  The cores, whole, go back to range
frequency for the next stage.  A range sample's core is the one its t_ref range lies in: the padding
holds every echo that moves into it, and an echo from beyond the padding that the correction moves out
again wraps into the padding, not the core (at the window's ends too: a second independent review found
ghosts at -0.3 to -2 dB where the first and last sub-swaths had no padding outside the window).
"""
from __future__ import annotations

import numpy as np
import scipy.fft

from ..dsp.geometry import C_MPS, ambiguity_number
from ..io import backing
from ..io.stagefile import StageData
from .motion import boresight_doppler_hz, depression_reference_error_m, reference_depression_deg

SUBSWATH_MAX = 16            # sub-swaths at most; beyond, the stage keeps 16 and the warning stays
GUARD = 0.8                  # a sub-swath's Doppler within GUARD x rate / 2 of its keystone's centre
PULSE_REACH_CELLS = 8.0      # the compressed pulse's reach either side, in range resolution cells (padding)
ERROR_SAMPLES = 65           # slant ranges per core at which the one-depression error is judged


def plan_subswaths(*, height_m: float, range_m, velocity_mps, fc_hz: float, prf_hz: float, q: int, method: str,
                   lever_s: float, walk_m: float, bandwidth_hz: float, implementation: str = "czt",
                   fastest_velocity_mps=None) -> tuple[list[dict] | None, float]:
    """The sub-swaths of ``range_m`` (module docstring) for ``method``, or None where one reference
    depression holds the whole window within half a range sample.  ``lever_s``: the longest time from
    t_ref a target is seen; ``walk_m``: the farthest an echo moves in it (padding); ``velocity_mps`` the
    INS velocity at t_ref (the references' Doppler), ``fastest_velocity_mps`` the fastest pulse's (the
    error's judge, an accelerating platform's Doppler grows).  ``traditional`` and ``decimation`` with czt or
    dft resolve about one whole ambiguity number (``motion.depression_reference_error_m``'s ``rounded``).
    Each sub-swath: ``lo``, ``hi`` (padded samples, beyond the window where they reach past its ends: read
    as zeros), ``core_lo``, ``core_hi``, ``reference_range_m``, ``depression_deg``,
    ``doppler_ref_hz`` (the boresight Doppler there) and ``ambiguity`` (at PRF / Q).  Returned with the
    largest one-depression error they leave (over half a range sample only where SUBSWATH_MAX cores do
    not hold it: ``decimation`` at PRF / Q folds every few metres at steep depression)."""
    if method == "none":
        return None, 0.0
    r = np.asarray(range_m, dtype=np.float64)
    dr = float(r[1] - r[0])
    half_m = dr / 2.0
    rate = None if method in ("bulk", "beam") else prf_hz / q
    rounded = method in ("traditional", "decimation") and implementation != "sinc"
    judge = velocity_mps if fastest_velocity_mps is None else fastest_velocity_mps

    def worst(lo_m, hi_m, guard=GUARD, velocity=judge):
        ref = 0.5 * (lo_m + hi_m)
        return float(np.max(depression_reference_error_m(height_m, np.linspace(lo_m, hi_m, ERROR_SAMPLES), ref,
                                                         velocity, fc_hz, lever_s, rate, rounded=rounded, guard=guard)))

    if worst(r[0], r[-1]) <= half_m:
        return None, worst(r[0], r[-1], 1.0)
    if rounded:
        # one whole ambiguity number per core: the cores are the runs of the window's ranges whose boresight
        # Doppler rounds to the same F (cut where it crosses (F + 1/2) rate); equal shares would leave a core
        # across such a crossing, folded on one side whatever its width
        f_r = boresight_doppler_hz(height_m, r, velocity_mps, fc_hz)
        cuts = np.flatnonzero(np.diff(ambiguity_number(f_r, rate))) + 1
        if len(cuts) >= SUBSWATH_MAX:           # too many: the cap's equal shares, and what they leave said
            cuts = np.searchsorted(r, np.linspace(r[0], r[-1], SUBSWATH_MAX + 1)[1:-1])
    else:
        for n in range(2, SUBSWATH_MAX + 1):
            edges = np.linspace(r[0], r[-1], n + 1)
            if max(worst(edges[i], edges[i + 1]) for i in range(n)) <= half_m:
                break
        cuts = np.searchsorted(r, edges[1:-1])
    cuts = np.unique(np.clip(cuts, 1, len(r) - 1))
    bounds = np.concatenate([[0], cuts, [len(r)]])
    # what they leave, unguarded (a whole F judged at the speed the keystone's F is taken at: t_ref's)
    left = max(worst(r[a], r[b - 1], 1.0, velocity_mps if rounded else judge) for a, b in zip(bounds[:-1], bounds[1:]))
    if len(bounds) == 2:     # one piece (a whole F's guard band about the window's own Doppler): nothing to split
        return None, left
    pad = int(np.ceil((walk_m + PULSE_REACH_CELLS * C_MPS / (2.0 * bandwidth_hz)) / dr))
    out = []
    for a, b in zip(bounds[:-1], bounds[1:]):
        ref = float(0.5 * (r[a] + r[b - 1]))
        f_dc = float(boresight_doppler_hz(height_m, [ref], velocity_mps, fc_hz)[0])
        out.append({"lo": int(a - pad), "hi": int(b + pad), "core_lo": int(a), "core_hi": int(b),
                    "reference_range_m": ref, "depression_deg": reference_depression_deg(height_m, ref),
                    "doppler_ref_hz": f_dc,
                    "ambiguity": int(ambiguity_number(f_dc, prf_hz / q))})
    return out, left


def _rows(fn, x, n_out: int) -> np.ndarray:
    """``fn`` over blocks of rows of ``x`` [..., n] (its last axis, range): [..., n_out] complex64; in
    memory one call, out of core (io/backing.py) block by block of rows into a file-backed array, the
    same numbers (each row's transform is its own)."""
    flat = x.reshape(-1, x.shape[-1])
    if not backing.active():
        return np.asarray(fn(flat), dtype=np.complex64).reshape(x.shape[:-1] + (n_out,))
    out = backing.map_blocks(lambda s: fn(flat[s]), flat.shape[0], (flat.shape[0], n_out), np.complex64,
                             8 * max(n_out, flat.shape[1]))
    return out.reshape(x.shape[:-1] + (n_out,))


def _ifft(x):
    return scipy.fft.ifft(x, axis=-1, workers=-1)


def _fft(x):
    return scipy.fft.fft(x, axis=-1, workers=-1, overwrite_x=True)


def keystone_subswaths(data: StageData, subswaths: list[dict], correct, **params) -> StageData:
    """``correct`` (the keystone stage's one-reference correction, ``chain.keystone_stage``) on each
    sub-swath with its own reference, the cores assembled (module docstring).  ``params``: the stage's
    settings; each sub-swath's ``depression_deg``, ``reference_range_m``, ``doppler_ref_hz`` and
    ``ambiguity`` replace theirs.  Out of core every range transform runs in blocks of rows between
    file-backed arrays, as the correction itself does (the window in range time had been held whole in
    memory, both channels)."""
    fr_hz = np.asarray(data["fr_hz"])
    n_f = len(fr_hz)
    fs_hz = float(fr_hz[1]) * n_f                       # FFT order: fr[1] = fs / n
    x_time = {ch: _rows(_ifft, data[f"{ch}_f"], n_f) for ch in ("sum", "diff")}
    y_time = {ch: backing.empty(x.shape, np.complex64) for ch, x in x_time.items()}
    for sw in subswaths:
        lo, hi, c0, c1 = sw["lo"], sw["hi"], sw["core_lo"], sw["core_hi"]
        a, b = max(lo, 0), min(hi, n_f)                 # the window's samples; zeros beyond its ends

        def padded(rows, a=a, b=b, lo=lo, hi=hi):       # the sub-swath's samples, zeros beyond the window
            seg = np.zeros((rows.shape[0], hi - lo), np.complex64)
            seg[:, a - lo:b - lo] = rows[:, a:b]
            return _fft(seg)

        sub = StageData(dict(data.vars), dict(data.attrs))
        sub.add("fr_hz", scipy.fft.fftfreq(hi - lo, 1.0 / fs_hz), ("fr_hz",), "Hz", "range frequency (FFT order)")
        sub.vars["range_m"] = data.vars["range_m"]
        for ch, x in x_time.items():
            sub.add(f"{ch}_f", _rows(padded, x, hi - lo), ("sub_pulse", "subseq", "fr_hz"), "1",
                    f"{ch} channel, sub-swath")
        done = correct(sub, **dict(params, depression_deg=sw["depression_deg"],
                                   reference_range_m=sw["reference_range_m"], doppler_ref_hz=sw["doppler_ref_hz"],
                                   ambiguity=sw["ambiguity"]))
        del sub
        for ch in ("sum", "diff"):                      # the core, back in range time
            y = np.asarray(done[f"{ch}_f"]).reshape(-1, hi - lo)
            core = y_time[ch].reshape(-1, n_f)
            step = backing.rows_per_block(8 * (hi - lo)) if backing.active() else y.shape[0]
            for r in range(0, y.shape[0], step):
                core[r:r + step, c0:c1] = _ifft(y[r:r + step])[:, c0 - lo:c1 - lo]
        del done
    del x_time
    out = StageData(dict(data.vars), dict(data.attrs))
    for ch, y in y_time.items():
        out.add(f"{ch}_f", _rows(_fft, y, n_f), ("sub_pulse", "subseq", "fr_hz"), "1",
                f"{ch} channel after the {params['method']} correction, {len(subswaths)} range sub-swaths")
    return out
