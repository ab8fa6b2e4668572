"""A recorded INS track or slow-time axis stored in float32 where its rounding reaches the chain's phases.

The chain forms carrier phases from the positions (4 pi |P - p(t)| / lambda: the dwell image's exact
range history, the joint fit) and Doppler phases from the times (2 pi f t: the Doppler zoom, the
tracking keystone's history).  A float32 number near X is only known to ``np.spacing(float32(X))``:
0.25 m at 4e6 m (map coordinates), 2 us at 30 s.  At 18 GHz a quarter metre is 94 rad of round-trip
phase, and an independent review measured it: the dwell image of float32 UTM positions lost 13.6 dB of
its peak and widened 2.4 times, the image -0.5 dB from the float64 one (the CPI image, which forms no
range history from the positions, -42 dB); float32 times at 30 s put the CPI image -29.5 dB off.  The
rounding's information is gone; what the recording holds besides it is restored here:

* positions: the recorded velocities (about 150 m/s, kept by float32 to 1e-5 m/s) integrated in
  float64 (trapezoids) and fitted through the stored positions by an offset and a drift per axis (least
  squares over every pulse: the rounding averages out, to about step / sqrt(12 N); the drift absorbs a
  velocity bias against the positions);
* times: the least-squares uniform pulse train (the reader has checked every pulse within 1 % of one).

Each only where the rounding's phase exceeds ``PHASE_ERROR_RAD`` (float32 positions within a few tens
of metres of the origin, and float32 times under a fraction of a second, are kept as they are), and
each said in one warning.
"""
from __future__ import annotations

import logging

import numpy as np

from ..dsp.geometry import C_MPS

log = logging.getLogger(__name__)

PHASE_ERROR_RAD = 0.01        # the largest phase the storage's rounding may put into the chain


def _is_float32(dtype) -> bool:
    dtype = np.dtype(dtype)
    return dtype.kind == "f" and dtype.itemsize < 8


def restore_float32_track(slow_time_s, position_m, velocity_mps, *, time_dtype, position_dtype, fc_hz: float,
                          source: str):
    """(slow_time_s, position_m), each replaced as the module says where it was stored in float32 and its
    rounding reaches ``PHASE_ERROR_RAD`` of phase at the carrier ``fc_hz``; float64 arrays as they are."""
    lam = C_MPS / fc_hz
    t = np.asarray(slow_time_s, dtype=np.float64)
    p = np.asarray(position_m, dtype=np.float64)
    v = np.asarray(velocity_mps, dtype=np.float64)
    if _is_float32(time_dtype) and len(t) > 2:
        step_s = float(np.spacing(np.float32(np.max(np.abs(t)))))
        doppler_hz = 2.0 * float(np.max(np.linalg.norm(v, axis=1))) / lam     # the largest Doppler a return has
        if np.pi * doppler_hz * step_s > PHASE_ERROR_RAD:                      # 2 pi f (half a step)
            n = np.arange(len(t), dtype=np.float64) - 0.5 * (len(t) - 1)
            centre = float(np.mean(t))
            t = centre + float(np.dot(n, t - centre) / np.dot(n, n)) * n
            log.warning(f"{source}: /axes/slow_time_s is float32, rounded to {step_s:.3g} s ({np.pi * doppler_hz * step_s:.2g} "
                        f"rad at a Doppler of {doppler_hz:.0f} Hz): taken as its least-squares uniform pulse train")
    if _is_float32(position_dtype) and len(p) > 2:
        step_m = float(np.spacing(np.float32(np.max(np.abs(p)))))
        if 2.0 * np.pi * step_m / lam > PHASE_ERROR_RAD:                      # 4 pi (half a step) / lambda
            dt = np.diff(t)[:, None]
            moved = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (v[1:] + v[:-1]) * dt, axis=0)])
            design = np.column_stack([np.ones_like(t), t - t.mean()])
            coef, *_ = np.linalg.lstsq(design, p - moved, rcond=None)         # offset and drift per axis
            p = moved + design @ coef
            log.warning(f"{source}: /platform/position_m is float32, rounded to {step_m:.3g} m ({2.0 * np.pi * step_m / lam:.2g} "
                        f"rad of round-trip phase at {fc_hz / 1e9:.4g} GHz): the track is the recorded velocities' "
                        f"integral fitted through the positions (README, \"Raw cube files\")")
    return t, p
