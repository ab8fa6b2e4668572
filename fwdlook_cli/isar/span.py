"""ISAR migration span: where to look for the reference scatterer's track, and the span's units.

Gate.  The per-pulse peak search for the migration span (``isar.migration_span_cells``) is restricted to
the range interval the reference scatterer's echo can occupy after the correction.  To first order in
f/f0, resampling the slow time of row f as t = t0 + alpha(f) (t' - t0) with alpha = (f0/(f0+f))^kappa
(``kappa`` = 1 for the first-order keystone, 1/2 for the second-order ones, 0 for none) moves the envelope
of exp(-j 4 pi (f0 + f) R(t) / c) to

    E(t') = R(t') - kappa (t' - t0) dR/dt(t')                 (t0 the keystone centre, t_ref)

(``none``: the raw range history; ``keystone1``: R0 - R2 t'^2 for a quadratic history; ``keystone2_n0``:
R(t_c), constant).  The gate spans the *actual* extent of the predicted tracks over the dwell, from the
exact range history of the truth: min..max of R(t) and of E(t) together, +- a margin of 3 resolution
cells.  The raw extent stays in so that a correction that goes wrong (a wrong Doppler ambiguity number
leaves a residual walk E does not model) is still measured, not cut off.  (A gate centred on the range
at t_ref with half the raw migration either side cuts the far end of a track whose migration is not
centred there: 4 s dwell at theta0 = 3 deg, 7.41 m measured against the true 8.58 m.)

Units.  The span is measured in range samples of the data, c / (2 fs) (0.416 m at fs = 360 MHz).  A
reader expects range resolution cells, c / (2 B) (0.50 m at B = 300 MHz), the cells the forward chain's
"half a range cell" refers to.  :func:`span_units` gives all three, named: ``migration_span_samples``,
``migration_span_resolution_cells`` (which ``summary.migration_span_cells`` carries) and
``migration_span_m``.
"""
from __future__ import annotations

import numpy as np

from ..dsp.geometry import C_MPS

KEYSTONE_ORDER = {"none": 0.0, "keystone1": 1.0, "keystone2": 0.5, "keystone2_n0": 0.5, "keystone2_n0_est": 0.5}


def predicted_envelope_m(range_m, slow_time_s, t0_s: float, correction: str) -> np.ndarray:
    """E(t) = R(t) - kappa (t - t0) dR/dt(t) (module docstring) for an exact range history R(t)."""
    r = np.asarray(range_m, dtype=np.float64)
    t = np.asarray(slow_time_s, dtype=np.float64)
    kappa = KEYSTONE_ORDER[correction]
    if kappa == 0.0 or len(t) < 2:
        return r.copy()
    return r - kappa * (t - t0_s) * np.gradient(r, t)


def track_gate_samples(range_m, slow_time_s, t0_s: float, correction: str, *, range0_m: float,
                       sample_m: float, margin_m: float) -> tuple[float, float]:
    """(lo, hi) in range samples of the axis starting at ``range0_m``: the min..max of the raw range
    history and of the predicted track after the correction, +- ``margin_m`` (module docstring)."""
    e = predicted_envelope_m(range_m, slow_time_s, t0_s, correction)
    lo = min(float(e.min()), float(np.min(range_m))) - margin_m
    hi = max(float(e.max()), float(np.max(range_m))) + margin_m
    return ((lo - range0_m) / sample_m, (hi - range0_m) / sample_m)


def span_units(span_samples: float, *, fs_hz: float, bandwidth_hz: float) -> dict:
    """The span in samples, metres and resolution cells, with the two cell sizes, as named keys."""
    sample_m = C_MPS / (2.0 * fs_hz)
    resolution_m = C_MPS / (2.0 * bandwidth_hz)
    span_m = float(span_samples) * sample_m
    return {"migration_span_samples": float(span_samples), "migration_span_m": span_m,
            "migration_span_resolution_cells": span_m / resolution_m,
            "range_sample_m": sample_m, "range_resolution_m": resolution_m}
