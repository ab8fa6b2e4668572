"""ISAR: a stationary radar imaging a moving object; range-cell migration removed by the
second-order keystone transform about the range-curve minimum (Serafin et al., seed 001).

Geometry (paper eq. 6-9, Fig. 1)
--------------------------------
The radar sits at the origin.  The object moves on a straight line at constant velocity ``v``
(``target.velocity_mps``; paper: [0, 40, 0] m/s).  The observation lasts ``N`` pulses
(``radar.n_pulses``) at ``t_n = n / F_p`` (t = 0 at the first pulse, CONTRACT section 3); its middle is
``t_mid = (N - 1) / (2 F_p)``.  At ``t_mid`` the reference scatterer (``target.points_m[0]``, default the
only one, at offset [0, 0, 0]) is at

    p_mid = R0 (cos theta0, -sin theta0, 0)

``R0`` (``target.range_m``) is the distance to the middle point of the observation and ``theta0``
(``target.theta0_deg``) the middle observation angle, both as in eq. (13).  ``theta0`` is measured in the
ground plane from +x, the normal from the radar to the paper's track (velocity along +y), towards -y:
a target with ``theta0 > 0`` still has to travel ``R0 sin(theta0)`` along +y to its closest approach.
Scatterer ``k`` (offset ``d_k``, rigid) is at ``p_k(t) = p_mid + d_k + v (t - t_mid)`` and its range is
exact (eq. 6-7, stop-and-hop):  ``R_k(t) = |p_k(t)|``.

Shift of the range minimum, eq. (13) corrected.  The range of the reference scatterer is smallest at
``t_c = t_mid - p_mid.v / |v|^2``.  For the paper's ``v = [0, v, 0]`` this is ``t_mid + R0 sin(theta0) / v``,
so in pulses

    n0 = R0 sin(theta0) F_p / v                                             # eq. (13), corrected

Eq. (13) as printed, ``R0 sin(theta0) / (v F_p)``, has the units m / (m/s x 1/s) = s^2: it divides by
F_p where it must multiply (NOTES.md).  The paper's numbers give n0 = 4318 pulses (3 deg) and 7190 pulses
(5 deg); the printed form gives 4.8e-4 and 8.0e-4.  For any velocity the processor uses the general
``n0 = -(p_mid.v) F_p / |v|^2``.  With the paper's numbers and a 2 s dwell the minimum lies outside the
observation (1.44 s and 2.40 s after its middle): the keystone is centred outside the data, which is
allowed.

Range-frequency model and the corrections (eq. 11-12)
-----------------------------------------------------
After a centred range FFT (``f`` in -fs/2..fs/2) the echo of one scatterer is
``P(f) exp(-j 4 pi (f0 + f) R(t) / c)``.  Every correction resamples each range-frequency row in slow
time, ``t = t0 + alpha(f) (t' - t0)``, with the band-limited DFT interpolant of ``keystone.py``
(:class:`~fwdlook_cli.dsp.keystone.KeystonePlan`, or :func:`~fwdlook_cli.dsp.keystone.keystone_dft`):

* ``none``:          no resampling;
* ``keystone1``:     ``alpha = f0 / (f0 + f)`` about ``t_mid`` (eq. 11): removes the linear range walk and
  leaves the curvature (with its sign reversed);
* ``keystone2``:     ``alpha = (f0 / (f0 + f))^(1/2)`` about ``t_mid``: removes a range curve symmetric
  about ``t_mid`` and leaves half of the linear walk when the minimum is elsewhere;
* ``keystone2_n0``:  the same about ``t_c = t_mid + n0 / F_p`` (eq. 12 with the corrected eq. 13): since
  ``R(t)`` is even about ``t_c`` the range curve up to its quartic term is removed; the target then sits at
  its closest-approach range ``R(t_c)`` at every pulse.  The paper assumes theta0 (and R0, v) known: the
  processor takes them from the cube's ``/truth/targets`` (reference scatterer position and velocity) or
  from ``processing.n0_pulses``; a cube without truth needs one of those or ``keystone2_n0_est``;
* ``keystone2_n0_est``: the same with n0 estimated from the data (:func:`estimate_n0`).

The rows are zero-extended in slow time before the resampling (:func:`_keystone`): a position
``t0 + alpha (m - t0)`` that leaves the observation reads zeros rather than the other end of the dwell.
Such positions exist for ``|1 - alpha| |m - t0| >= 1``, up to ``fs / (4 f0) (|n0| + N/2)`` pulses (220 and
300 pulses of 6000 for the paper's 3 and 5 deg, in the outermost rows only); the lost samples cost about
0.1 dB of integration gain here.  The loss grows with that excursion against ``N``: a short dwell far
from the minimum (e.g. 600 pulses for the 3 deg case) loses about 1 dB.

``t_ref`` (the time the corrected data and image refer to, CONTRACT section 5) is the keystone centre:
``t_mid`` for none/keystone1/keystone2, ``t_c`` for the n0-shifted ones.

Doppler ambiguity.  The slow-time signal of row ``f`` has the Doppler ``(1 + f/f0) f_dc`` with
``f_dc = -2 Rdot(t_mid) f0 / c``.  Where it approaches or exceeds the PRF the periodic interpolant returns
the baseband tone; the keystone multiplies by ``exp(j 2 pi F tau)`` (keystone.py).  ``processing.ambiguity:
auto`` uses per row ``F = <(1 + f/f0) f_dc / F_p>`` (rounded half away from zero) with ``f_dc`` from the
known geometry (truth) or from the estimate (range walk, refined by the image); an integer forces one F
for every row.  A Doppler chirp that crosses a multiple of PRF/2 during the dwell is not handled.

Azimuth compression
-------------------
The keystone leaves the carrier phase of the ``f = 0`` row untouched, so after any correction the
target's slow-time phase is still ``-4 pi f0 R(t) / c``: a Doppler chirp of rate ``2 Rddot / lambda``
(29 Hz/s for the paper's geometry: the image smears over about 60 Doppler bins in 2 s without
compensation).  ``azimuth_compress`` therefore multiplies every range cell by the reference
``exp(+j 4 pi f0 (R_m(t) - R0) / c)`` of the straight-line range model (the paper's eq. 10 phase term)

    R_m(t)^2 = R0^2 + 2 R0 Rdot tau + |v|^2 tau^2,    tau = t - t_mid           (exact for eq. 7)

and takes the slow-time FFT (centred Doppler, unweighted).  The model is the same for every correction
(known geometry from the truth, or the estimate), so the corrections differ only in their range-migration
handling.  The reference scatterer lands at Doppler 0; a scatterer offset ``d`` lands at
``f = -2 omega (d . e_perp) / lambda``, ``omega = sqrt(|v|^2 - Rdot^2) / R0`` the line-of-sight rotation
rate at ``t_mid`` and ``e_perp`` the direction the line of sight turns to: the cross-range axis is
``x = -lambda f / (2 omega)``.

Estimating n0 (``keystone2_n0_est``)
-----------------------------------
The three model parameters fix n0 = -R0 Rdot F_p / |v|^2.  :func:`estimate_n0` (1) tracks the per-pulse
interpolated peak range and fits a quadratic: R0, Rdot (and from it the ambiguity number) and a coarse
``|v|^2 = R0 Rddot + Rdot^2``; (2) applies the n0-shifted second-order keystone at the coarse n0; (3)
searches the model over a grid around the coarse value for the sharpest image (``sum |I|^4 / (sum
|I|^2)^2`` over the target's range cells after the model phase compensation), each candidate being one
value of n0; (4) refines Rdot from the interpolated Doppler of the image peak and repeats on a finer
grid.  The grid is uniform in ``|v|^2`` (equivalently in the Doppler rate) because the sharpness lobe has
a constant width there (a chirp-rate error of ``1/T^2``, quadratic phase pi/4 at the dwell edges); in
n0 the lobe is about ``n0 lambda R0 / (2 T^2 |v|^2)`` pulses wide (37 pulses for theta0 = 3 deg, 2 s).
Settings: ``processing.n0_search.half_span_lobes`` (first grid, +- lobes around the coarse value; a
maximum on the grid's edge moves the grid, up to 8 times), ``points_per_lobe``, ``passes`` (after each pass
the grid narrows to +-2 steps around the maximum and the step is divided by 4).  Sharpness alone cannot give n0: the
range walk it leaves for an n0 error of 2 pulses is about a millimetre, so the information is in the
Doppler rate (``|v|^2``) and the Doppler centroid (``Rdot``), both measured coherently here.  The
estimator assumes one dominant scatterer (the paper's point echo): with several comparable scatterers
the per-pulse peak track of step (1) hops between them.

Metrics
-------
``migration_span_cells``: per pulse, the range profile of the corrected range-time data is oversampled
(band-limited, x4) and its peak (within the reference scatterer's range gate when the truth is known:
the min..max of its raw range history and of its predicted track after the correction, +- 3
resolution cells, ``isar/span.py``) refined by a log-parabola; the positions of the pulses where the
target is present (peak power at least a quarter of the median peak power) are smoothed by a running
mean of ``SPAN_SMOOTH_PULSES`` (32) pulses, which keeps noise jitter out of max-minus-min (keystone2_n0
on the paper scenarios, 3 / 5 deg, 20 dB: 0.09 / 0.12 range samples), and the span is max minus min,
measured in range samples (``c / (2 fs)``) and reported in range resolution cells ``c / (2 B)``
(``summary.migration_span_cells`` = ``migration_span_resolution_cells``), range samples
(``migration_span_samples``) and metres (``migration_span_m``).  With several scatterers in the gate the
track follows the strongest return per pulse.

``integration_gain_db``: 20 log10 of the image maximum within the reference scatterer's migration extent
(the range gate above, +-3 Doppler bins) over the ideal ``N a |p(0)|`` (N pulses of amplitude a, p the
compressed pulse, p(0) = 1 unweighted): perfect range alignment and phase compensation.  The sampled
compressed pulse itself loses 0.09-0.2 dB at fs = 1.2 B (its interpolated per-pulse peak), so a perfectly
compensated target reads about -0.1 dB.  A cube without truth uses N times the median per-pulse peak
amplitude of the raw echo.

Per target (truth known): position, 3 dB widths (range, cross-range), PSLR and ISLR (eq. 27, main lobe
between the first nulls, window +-16 cells, :func:`~fwdlook_cli.dsp.profile.profile_metrics`) come from the
range and Doppler cuts through the image peak within +-3 range resolution cells and +-3 Doppler bins of
the predicted position; the peak value and position from the exact band-limited interpolant of each cut
(a Doppler cut is the DFT of the slow-time record, interpolated as such: :func:`_doppler_line`).
``detected``: that peak is a local maximum inside the gate and 10 dB above the image's median power.

References
----------
.. [1] P. Serafin, C. Lesnik, K. Zielinski, "Range cell migration compensation in inverse synthetic
   aperture radar", seed 001, eq. (6)-(13) and Sec. 4.
.. [2] D. Kirkland, "Imaging moving targets using the second-order keystone transform", IET Radar Sonar
   Navig. 5(8), 902-910 (2011).
"""
