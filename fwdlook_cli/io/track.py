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

Each only where the rounding's phase exceeds ``PHASE_ERROR_RAD`` (float32 positions within about 250 m
of the origin at 18 GHz, and float32 times under a fraction of a second, are kept as they are), and only
where what replaces them agrees with the stored values to their rounding (``AGREEMENT_STEPS`` half
storage steps): positions whose velocities are noisy, logged at a lower rate or not the antenna's, and
times with a real stagger or jitter, depart from it by many steps, and the stored values, whose error
is at most half a step, are kept (a second independent review: velocities logged at 50 Hz had made a
dwell image of positions good to 0.012 rad -4.1 dB off, a 3-pulse stagger thrown away -19 dB).  Each
case said in one warning.  ISAR cubes are left alone: that chain forms no phase from the positions.
"""
from __future__ import annotations

import logging

import numpy as np

from ..dsp.geometry import C_MPS
from .navigation import velocity_integral_m

log = logging.getLogger(__name__)

PHASE_ERROR_RAD = 0.01        # the largest phase the storage's rounding may put into the chain
AGREEMENT_STEPS = 1.5         # the replacement within this many half storage steps of every stored value


def least_squares_uniform(values: np.ndarray) -> tuple[float, float, np.ndarray]:
    """The least-squares uniform sequence through ``values``, in closed form (no Vandermonde matrix):
    (its centre, its step, the sample indices about their mean); it is centre + step * indices."""
    n = np.arange(len(values), dtype=np.float64)
    n -= n.mean()
    centre = float(np.mean(values))
    return centre, float(np.dot(n, values - centre) / np.dot(n, n)), n


def _is_float32(dtype) -> bool:
    dtype = np.dtype(dtype)
    return dtype.kind == "f" and dtype.itemsize < 8


def restore_float32_track(slow_time_s, position_m, velocity_mps, *, time_dtype, position_dtype, fc_hz: float,
                          source: str):
    """(slow_time_s, position_m), each replaced as the module says where it was stored in float32, its
    rounding reaches ``PHASE_ERROR_RAD`` of phase at the carrier ``fc_hz`` and the replacement agrees with
    the stored values to their rounding; float64 arrays as they are."""
    lam = C_MPS / fc_hz
    t = np.asarray(slow_time_s, dtype=np.float64)
    p = np.asarray(position_m, dtype=np.float64)
    v = np.asarray(velocity_mps, dtype=np.float64)
    if _is_float32(time_dtype) and len(t) > 2:
        step_s = float(np.spacing(np.float32(np.max(np.abs(t)))))
        doppler_hz = 2.0 * float(np.max(np.linalg.norm(v, axis=1))) / lam     # the largest Doppler a return has
        if np.pi * doppler_hz * step_s > PHASE_ERROR_RAD:                      # 2 pi f (half a step)
            centre, interval, n = least_squares_uniform(t)
            train = centre + interval * n
            off = float(np.max(np.abs(train - t))) / (0.5 * step_s)
            head = (f"{source}: /axes/slow_time_s is float32, rounded to {step_s:.3g} s "
                    f"({np.pi * doppler_hz * step_s:.2g} rad at a Doppler of {doppler_hz:.0f} Hz)")
            if off <= AGREEMENT_STEPS:
                t = train
                log.warning(f"{head}: taken as its least-squares uniform pulse train (within {off:.2f} half steps)")
            else:
                log.warning(f"{head}; kept as stored: the pulses depart from a uniform train by {off:.3g} half "
                            f"steps (a stagger or jitter the train would lose); store times in float64")
    if _is_float32(position_dtype) and len(p) > 2:
        step_m = float(np.spacing(np.float32(np.max(np.abs(p)))))
        if 2.0 * np.pi * step_m / lam > PHASE_ERROR_RAD:                      # 4 pi (half a step) / lambda
            moved = velocity_integral_m(t, v)
            design = np.column_stack([np.ones_like(t), t - t.mean()])
            coef, *_ = np.linalg.lstsq(design, p - moved, rcond=None)         # offset and drift per axis
            track = moved + design @ coef
            off = float(np.max(np.abs(track - p))) / (0.5 * step_m)
            head = (f"{source}: /platform/position_m is float32, rounded to {step_m:.3g} m "
                    f"({2.0 * np.pi * step_m / lam:.2g} rad of round-trip phase at {fc_hz / 1e9:.4g} GHz)")
            if off <= AGREEMENT_STEPS:
                p = track
                log.warning(f"{head}: the track is the recorded velocities' integral fitted through the positions, "
                            f"within {off:.2f} half steps of each (README, \"Raw cube files\")")
            else:
                log.warning(f"{head}; kept as stored: the recorded velocities' integral departs from them by {off:.3g} "
                            f"half steps (velocities noisy, logged at a lower rate, or not the antenna's); store "
                            f"positions in float64 or relative to a local origin")
    return t, p
