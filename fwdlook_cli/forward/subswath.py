"""Range sub-swaths: one reference depression for each part of a steep range window.

Every correction refers its range window to one depression phi_0 (README, "One reference depression
across a steep window"): ``tracking`` follows the boresight Doppler history there and resolves +-PRF / 2
about it, ``traditional`` and ``decimation`` take one ambiguity number, ``bulk`` and ``beam`` shift by
that range's history.  Where the boresight Doppler 2 v cos(phi(r)) / lambda changes across the window
by more than that holds (``motion.depression_reference_error_m`` over half a range sample), the keystone
stage splits the window into sub-swaths: cores that partition the range samples, each the narrowest
equal share of the window whose own middle reference keeps the error within half a range sample, each
padded by the range a target's echo moves while the beam sees it (the plan's walk, plus the compressed
pulse's reach).  Per sub-swath: its padded range samples back to range time, forward again over their
own length, the stage's correction with the core's own reference (depression, reference range, Doppler
and ambiguity number), back to range time, and its core kept.  The cores, whole, go back to range
frequency for the next stage.  A range sample's core is the one its t_ref range lies in: the padding
holds every echo that moves into it, so the cyclic shifts of the padded transform wrap nothing into it.
"""
from __future__ import annotations

import numpy as np
import scipy.fft

from ..dsp.geometry import C_MPS, ambiguity_number
from ..io import backing
from ..io.stagefile import StageData
from .motion import depression_reference_error_m, reference_depression_deg, unit_vector

SUBSWATH_MAX = 16            # sub-swaths at most; beyond, the stage keeps 16 and the warning stays
PULSE_REACH_CELLS = 8.0      # the compressed pulse's reach either side, in range resolution cells (padding)
ERROR_SAMPLES = 65           # slant ranges per core at which the one-depression error is judged


def plan_subswaths(*, height_m: float, range_m, velocity_mps, fc_hz: float, prf_hz: float, q: int, method: str,
                   lever_s: float, walk_m: float, bandwidth_hz: float) -> tuple[list[dict] | None, float]:
    """The sub-swaths of ``range_m`` (module docstring) for ``method``, or None where one reference
    depression holds the whole window within half a range sample.  ``lever_s``: the longest time from
    t_ref a target is seen; ``walk_m``: the farthest an echo moves in it (padding).  Each sub-swath:
    ``lo``, ``hi`` (padded samples), ``core_lo``, ``core_hi``, ``reference_range_m``, ``depression_deg``,
    ``doppler_ref_hz`` (the boresight Doppler there) and ``ambiguity`` (at PRF / Q).  Returned with the
    largest one-depression error they leave (over half a range sample only where SUBSWATH_MAX cores do
    not hold it: ``decimation`` at PRF / Q folds every few metres at steep depression)."""
    if method == "none":
        return None, 0.0
    r = np.asarray(range_m, dtype=np.float64)
    dr = float(r[1] - r[0])
    half_m = dr / 2.0
    rate = None if method in ("bulk", "beam") else prf_hz / q

    def worst(lo_m, hi_m):
        ref = 0.5 * (lo_m + hi_m)
        return float(np.max(depression_reference_error_m(height_m, np.linspace(lo_m, hi_m, ERROR_SAMPLES), ref,
                                                         velocity_mps, fc_hz, lever_s, rate)))

    whole = worst(r[0], r[-1])
    if whole <= half_m:
        return None, whole
    for n in range(2, SUBSWATH_MAX + 1):
        edges = np.linspace(r[0], r[-1], n + 1)
        left = max(worst(edges[i], edges[i + 1]) for i in range(n))
        if left <= half_m:
            break
    cuts = np.unique(np.clip(np.searchsorted(r, edges[1:-1]), 1, len(r) - 1))
    bounds = np.concatenate([[0], cuts, [len(r)]])
    pad = int(np.ceil((walk_m + PULSE_REACH_CELLS * C_MPS / (2.0 * bandwidth_hz)) / dr))
    lam = C_MPS / fc_hz
    out = []
    for a, b in zip(bounds[:-1], bounds[1:]):
        ref = float(0.5 * (r[a] + r[b - 1]))
        dep = reference_depression_deg(height_m, ref)
        f_dc = 2.0 * float(unit_vector(0.0, dep) @ np.asarray(velocity_mps, dtype=np.float64)) / lam
        out.append({"lo": int(max(0, a - pad)), "hi": int(min(len(r), b + pad)), "core_lo": int(a), "core_hi": int(b),
                    "reference_range_m": ref, "depression_deg": float(dep), "doppler_ref_hz": f_dc,
                    "ambiguity": int(ambiguity_number(f_dc, prf_hz / q))})
    return out, left


def keystone_subswaths(data: StageData, subswaths: list[dict], correct, **params) -> StageData:
    """``correct`` (the keystone stage's one-reference correction, ``chain.keystone_stage``) on each
    sub-swath with its own reference, the cores assembled (module docstring).  ``params``: the stage's
    settings; each sub-swath's ``depression_deg``, ``reference_range_m``, ``doppler_ref_hz`` and
    ``ambiguity`` replace theirs."""
    fr_hz = np.asarray(data["fr_hz"])
    n_f = len(fr_hz)
    fs_hz = float(fr_hz[1]) * n_f                       # FFT order: fr[1] = fs / n
    x_time = {ch: scipy.fft.ifft(np.asarray(data[f"{ch}_f"]), axis=-1, workers=-1).astype(np.complex64)
              for ch in ("sum", "diff")}
    y_time = {ch: backing.empty(x.shape, np.complex64) for ch, x in x_time.items()}
    for sw in subswaths:
        lo, hi, c0, c1 = sw["lo"], sw["hi"], sw["core_lo"], sw["core_hi"]
        sub = StageData(dict(data.vars), dict(data.attrs))
        sub.add("fr_hz", scipy.fft.fftfreq(hi - lo, 1.0 / fs_hz), ("fr_hz",), "Hz", "range frequency (FFT order)")
        sub.vars["range_m"] = data.vars["range_m"]
        for ch, x in x_time.items():
            sub.add(f"{ch}_f", scipy.fft.fft(x[..., lo:hi], axis=-1, workers=-1).astype(np.complex64),
                    ("sub_pulse", "subseq", "fr_hz"), "1", f"{ch} channel, sub-swath")
        done = correct(sub, **dict(params, depression_deg=sw["depression_deg"],
                                   reference_range_m=sw["reference_range_m"], doppler_ref_hz=sw["doppler_ref_hz"],
                                   ambiguity=sw["ambiguity"]))
        for ch in ("sum", "diff"):
            y = scipy.fft.ifft(np.asarray(done[f"{ch}_f"]), axis=-1, workers=-1)
            y_time[ch][..., c0:c1] = y[..., c0 - lo:c1 - lo]
        del sub, done
    del x_time
    out = StageData(dict(data.vars), dict(data.attrs))
    for ch, y in y_time.items():
        out.add(f"{ch}_f", scipy.fft.fft(y, axis=-1, workers=-1).astype(np.complex64), ("sub_pulse", "subseq", "fr_hz"),
                "1", f"{ch} channel after the {params['method']} correction, {len(subswaths)} range sub-swaths")
    return out
