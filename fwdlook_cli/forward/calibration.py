"""Monopulse calibration: the ratio curve, boresight offset and channel imbalance in use.

A recorded cube may not say its antenna (CONTRACT.md section 3: ``/antenna`` is optional).  The
calibration then comes from the data: a stationary point scatterer P seen across the scan returns, at
pulse n, ``diff/sum = gamma R(delta_n - b)`` with

* ``delta_n = az(P from p_n) - scan_n`` its angle offset from the beam axis, from the INS position p_n;
* ``R`` the ratio curve (``tanh(k d)`` for two Gaussian beams, NOTES.md), ``b`` the boresight offset
  of the difference null from the sum-beam axis;
* ``gamma = 10^(g/20) exp(j phi)`` the difference/sum channel imbalance (its phase shows in
  Im(diff/sum), its amplitude in the ratio's scale).

The sum-beam axis is found from the sum channel alone: the two-way sum power of a point is symmetric
in ``delta``, so its power-weighted centroid over the dwell is zero; that fixes each scatterer's
azimuth without the difference channel, and ``b``, ``k``, ``g``, ``phi`` are then fitted to the pooled
(delta_n, diff/sum) of every isolated scatterer.  Uncertainties are jackknife over scatterers
(3 or more) or from the fit's covariance.

Everything here is a pure function on arrays; :func:`calibration_for_cube` picks the source that
``processing.monopulse_calibration`` asks for.  The scatterers and their samples come from
``forward/point_returns.py``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import BadInput
from .point_returns import noise_chi2_per_sample, point_returns
from .ratio_fit import fit_poly, fit_tanh, tanh_over_k

RATIO_TABLE_POINTS = 401
# ``auto`` takes the general curve only when tanh misfits grossly: at SNR 20 dB the chi^2 drop measured
# 26-28 for cubes of Gaussian AND of sinc beams alike (a small systematic misfit beyond noise), so the
# 99.9 % point of chi^2 (16) would reject the true model; 100 keeps tanh for both (README)
AUTO_TABLE_CHI2_DROP = 100.0


@dataclass
class Calibration:
    """The monopulse ratio curve in use: ``Re(diff / (gamma sum)) = R(d - b)``."""

    source: str                        # cube | data | setting
    model: str                         # tanh (exact atanh inverse) | table (monotone table)
    slope_per_deg: float               # dR/dd on the axis
    boresight_offset_deg: float = 0.0  # b: the difference null relative to the sum-beam axis
    diff_gain_db: float = 0.0          # channel imbalance, amplitude
    diff_phase_deg: float = 0.0        # channel imbalance, phase
    ratio_offset_deg: np.ndarray | None = None   # model table: offset from the null ...
    ratio: np.ndarray | None = None              # ... and R there (strictly increasing)
    sigma: dict = field(default_factory=dict)    # 1-sigma of each estimated quantity
    stats: dict = field(default_factory=dict)    # scatterers, samples, residual, notes
    pattern: str | None = None

    def offset_deg(self, ratio):
        """Offset from the sum-beam axis of a corrected ratio: R^-1(ratio) + b."""
        r = np.asarray(ratio, dtype=np.float64)
        if self.model == "tanh":
            d = np.arctanh(np.clip(r, -0.999, 0.999)) / self.slope_per_deg
        else:
            d = np.interp(r, self.ratio, self.ratio_offset_deg)
        return d + self.boresight_offset_deg

    def tanh_equivalent(self, half_span_deg: float) -> tuple[float, float, float]:
        """(k, gain_db, offset_deg) of the curve ``g tanh(k (d - b))`` nearest this calibration's ratio
        curve over +-``half_span_deg`` about its null, in the calibration's own convention: the curve's
        bend k per deg, the difference/sum gain g it holds besides ``diff_gain_db`` (in dB), and the null
        b from the sum-beam axis (``boresight_offset_deg`` plus the table's own zero crossing).  What the
        dwell image's rotation takes where the calibration is a table (it models the two-Gaussian-beam
        rotation, README "An antenna fwdlook does not model"): exact for a Gaussian pair whose imbalance
        or null offset the table holds, the nearest such pair for another antenna.  A tanh calibration
        gives its own (slope, 0, boresight offset).  Least squares: g in closed form for every k on a
        log grid about the table's slope at its null, then the grid refined twice about its best k."""
        if self.model == "tanh" or self.ratio is None:
            return float(self.slope_per_deg), 0.0, float(self.boresight_offset_deg)
        d, r = np.asarray(self.ratio_offset_deg, np.float64), np.asarray(self.ratio, np.float64)
        zero = float(np.interp(0.0, r, d))                      # the table's null (r strictly increasing)
        u = d - zero
        use = np.abs(u) <= half_span_deg
        u, r = u[use], r[use]
        slope = max(float(np.interp(0.0, u, np.gradient(r, u))), 1e-12)
        k_lo, k_hi = np.log(slope / 10.0), np.log(slope * 10.0)
        for _ in range(3):                                      # the grid, then twice finer about its best
            k = np.exp(np.linspace(k_lo, k_hi, 201))
            t = np.tanh(k[:, None] * u[None, :])
            g = (t @ r) / np.maximum(np.sum(t * t, axis=1), 1e-300)
            best = int(np.argmin(np.sum((r[None, :] - g[:, None] * t) ** 2, axis=1)))
            step = (k_hi - k_lo) / 200.0
            k_lo, k_hi = np.log(k[best]) - 2.0 * step, np.log(k[best]) + 2.0 * step
        return float(k[best]), float(20.0 * np.log10(g[best])), float(self.boresight_offset_deg + zero)

    @property
    def imbalance(self) -> complex:
        return complex(10.0 ** (self.diff_gain_db / 20.0) * np.exp(1j * np.radians(self.diff_phase_deg)))

    def stage_params(self) -> dict:
        """The settings of the ``monopulse_image`` stage (hashed with the stage)."""
        out = {"slope_per_deg": float(self.slope_per_deg), "ratio_model": self.model,
               "boresight_offset_deg": float(self.boresight_offset_deg),
               "diff_gain_db": float(self.diff_gain_db), "diff_phase_deg": float(self.diff_phase_deg)}
        if self.model == "table":
            out["ratio_offset_deg"] = [float(v) for v in self.ratio_offset_deg]
            out["ratio"] = [float(v) for v in self.ratio]
        return out

    def to_json(self) -> dict:
        out = {"source": self.source, "model": self.model, "pattern": self.pattern,
               "slope_per_deg": float(self.slope_per_deg),
               "boresight_offset_deg": float(self.boresight_offset_deg),
               "diff_gain_db": float(self.diff_gain_db), "diff_phase_deg": float(self.diff_phase_deg),
               "uncertainty": {k: float(v) for k, v in self.sigma.items()}}
        if "slope_note" in self.stats:   # only their product is determined: no number for either (it had
            # read e.g. slope 4.8e-5 per deg and gain +73.6 dB, the fit's end of a flat valley)
            out["slope_per_deg"] = out["diff_gain_db"] = None
            out["uncertainty"].pop("slope_per_deg", None)
            out["uncertainty"].pop("diff_gain_db", None)
        out.update({k: v for k, v in self.stats.items()})
        return _finite(out)

    def describe(self) -> str:
        s = self.sigma

        def pm(key):
            return f" +- {s[key]:.4g}" if key in s and np.isfinite(s[key]) else ""

        if "slope_note" in self.stats:   # only the product is determined (estimate_calibration)
            slope = (f"effective slope {self.stats['effective_slope_per_deg']:.4f}"
                     f"{pm('effective_slope_per_deg')} /deg (slope and gain apart not determined), ")
            imbalance = f"phase {self.diff_phase_deg:+.2f}{pm('diff_phase_deg')} deg"
        else:
            slope = f"slope {self.slope_per_deg:.4f}{pm('slope_per_deg')} /deg, "
            imbalance = (f"imbalance {self.diff_gain_db:+.2f}{pm('diff_gain_db')} dB {self.diff_phase_deg:+.2f}"
                         f"{pm('diff_phase_deg')} deg")
        line = (f"{self.source} ({self.model}): {slope}boresight {self.boresight_offset_deg:+.4f}"
                f"{pm('boresight_offset_deg')} deg, {imbalance}")
        if "n_scatterers" in self.stats:
            line += f" ({self.stats['n_scatterers']} scatterers, {self.stats['n_samples']} samples"
            if "noise_chi2_per_sample" in self.stats:      # 1: the samples miss the curve by their noise
                line += f", residual {self.stats['noise_chi2_per_sample']:.2f} x noise"
            line += ")"
        return line


def _finite(obj):
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    if isinstance(obj, (float, np.floating)):
        return float(obj) if np.isfinite(obj) else None
    if isinstance(obj, np.integer):
        return int(obj)
    return obj


# ----------------------------------------------------------------------------------------------
# from the cube's /antenna group, or a plain slope
# ----------------------------------------------------------------------------------------------
TABLE_SLOPE_AGREEMENT = 0.05      # relative: an /antenna slope attribute that is its ratio table's


def calibration_from_antenna(antenna: dict, beamwidth_deg: float) -> Calibration | None:
    """The /antenna group as a calibration (None when it does not fix the ratio curve)."""
    if not antenna:
        return None
    pattern = antenna.get("pattern")
    gain = float(antenna.get("diff_gain_db", 0.0))
    phase = float(antenna.get("diff_phase_deg", 0.0))
    slope = antenna.get("monopulse_slope_per_deg")
    if slope is not None and (pattern == "gaussian2" or (pattern is None and "ratio" not in antenna)):
        # a Gaussian pair (or a cube of the former layout, slope only): exact tanh
        return Calibration("cube", "tanh", float(slope), diff_gain_db=gain, diff_phase_deg=phase,
                           pattern=pattern or "gaussian2")
    if "ratio" in antenna:
        d = np.asarray(antenna["ratio_offset_deg"], dtype=np.float64)
        r = np.asarray(antenna["ratio"], dtype=np.float64)
        # the image reads the table, so its slope is the table's own at the null; the attribute only where
        # it agrees (fwdlook's designs: the exact derivative of the curve tabulated), else the table's and
        # a note (an attribute of another antenna had stood for the table in the check against the data)
        k_table = float(np.gradient(r, d)[np.argmin(np.abs(d))])
        agrees = slope is not None and abs(float(slope) - k_table) <= TABLE_SLOPE_AGREEMENT * abs(k_table)
        cal = Calibration("cube", "table", float(slope) if agrees else k_table, diff_gain_db=gain,
                          diff_phase_deg=phase, ratio_offset_deg=d, ratio=r, pattern=pattern)
        if slope is not None and not agrees:
            cal.stats["note"] = (f"/antenna attribute monopulse_slope_per_deg = {float(slope):.4g} is not its "
                                 f"ratio table's slope at the null, {k_table:.4g}: the table is used")
        return cal
    if pattern in ("gaussian2", "sinc2") and "squint_deg" in antenna:
        from ..dsp.antenna import MonopulseAntenna

        model = MonopulseAntenna(beamwidth_deg, float(antenna["squint_deg"]), pattern=pattern)
        d, r = model.ratio_table
        return Calibration("cube", "table" if pattern == "sinc2" else "tanh", model.slope_per_deg,
                           diff_gain_db=gain, diff_phase_deg=phase, ratio_offset_deg=d, ratio=r, pattern=pattern)
    return None


# ----------------------------------------------------------------------------------------------
# from the data
# ----------------------------------------------------------------------------------------------
NOISE_CHI2_NOTE = 1.3   # the fit's residual over its noise, per sample, above which the stats carry a note


CREDIBLE_SLOPE_FACTOR = 20.0   # the ratio curve's bend within 1/20..20 times a beam's own, 2 / beamwidth


def check_credible_null_and_slope(null_deg: float, bend_per_deg: float | None, beamwidth_deg: float,
                                  n_scatterers: int, effective_slope_per_deg: float = 1.0,
                                  effective_slope_sigma: float = 0.0) -> None:
    """A fitted ratio curve no antenna of this beamwidth has is refused as no calibration: its null
    outside the sum beam's half-power width, or, where the data determine it (``bend_per_deg`` not None),
    the curve's own bend k (its slope apart from the difference/sum gain) more than CREDIBLE_SLOPE_FACTOR
    from 2 / beamwidth (fwdlook's Gaussian designs: 0.44 times it at a 1.5 deg squint of a 6 deg beam,
    1.08 at the half-power crossing).  The boresight slope of Re(diff/sum) is not judged: it holds the
    receiver's difference/sum gain, which may be tens of dB (an independent review: a difference channel
    20 dB weaker or 30 dB stronger had been refused).  Found on a noiseless cube (an independent review):
    one track fitted to a null 22.9 deg off, which then refused the cube's right /antenna as "sign
    reversed".  And a boresight slope under 5 of its own sigma is no monopulse at all (a dead or
    disconnected difference channel, which a third review found accepted once the slope's bound was
    gone).  BadInput, which ``auto`` reads as "the data allow no calibration" (the group is taken as it
    is)."""
    k_beam = 2.0 / beamwidth_deg
    bend_ok = bend_per_deg is None or k_beam / CREDIBLE_SLOPE_FACTOR <= abs(bend_per_deg) <= CREDIBLE_SLOPE_FACTOR * k_beam
    if abs(null_deg) <= 0.5 * beamwidth_deg and bend_ok:
        if np.isfinite(effective_slope_sigma) and not abs(effective_slope_per_deg) > 5.0 * effective_slope_sigma:
            raise BadInput(f"monopulse calibration from the data: the difference channel shows no monopulse slope "
                           f"({effective_slope_per_deg:.3g} +- {effective_slope_sigma:.2g} per deg from {n_scatterers} "
                           f"scatterer(s): dead or disconnected?); allowed: processing.monopulse_calibration = cube "
                           "(with /antenna) or a slope per degree")
        return
    bend = "" if bend_per_deg is None else f", bend {bend_per_deg:.3g} per deg"
    raise BadInput(f"monopulse calibration from the data: no credible ratio curve from {n_scatterers} scatterer(s) "
                   f"(null {null_deg:+.3g} deg off the beam axis{bend}, for a {beamwidth_deg:g} deg beam); allowed: "
                   "processing.monopulse_calibration = cube (with /antenna) or a slope per degree")


def estimate_calibration(samples: dict, *, beamwidth_deg: float, model: str = "auto") -> Calibration:
    """Fit the ratio curve, boresight offset and imbalance to the pooled point-return samples.

    ``model``: ``tanh`` (two Gaussian beams), ``table`` (a degree-5 curve, inverted through a monotone
    table), ``auto`` (tanh unless the general curve's chi^2 is lower by more than
    ``AUTO_TABLE_CHI2_DROP`` in units of the residual variance).  The stats give the fit's residual
    against the samples' own noise (``noise_chi2_per_sample``, :func:`noise_chi2_per_sample`) and a
    note where it exceeds ``NOISE_CHI2_NOTE``.
    """
    sc, delta, z, w = samples["scatterer"], samples["offset_deg"], samples["z"], samples["weight"]
    n_s = int(sc.max()) + 1 if len(sc) else 0
    if n_s == 0 or len(z) < 30:
        raise BadInput("monopulse calibration from the data: no strong isolated point-like returns "
                       f"({samples.get('n_candidates', 0)} candidates, rejected {samples.get('rejected', {})}); "
                       "allowed: processing.monopulse_calibration = cube (with /antenna) or a slope per degree")
    k0 = 2.0 / beamwidth_deg
    use = np.abs(delta) < 0.6 * beamwidth_deg
    # iterate: fit, drop scatterers whose own residual is far above the others' (mixed returns)
    keep_s = np.ones(n_s, bool)
    for _ in range(3):
        m = use & keep_s[sc]
        params, b_j, cov, chi2, dof = fit_tanh(delta[m], z[m], w[m], k0, sc[m])
        s_eff, phi, k, b = params
        b_all = np.full(n_s, b)
        b_all[np.unique(sc[m])] = b_j
        mod = np.exp(1j * phi) * s_eff * tanh_over_k(k, delta - b_all[sc])
        e2 = np.abs(z - mod) ** 2 * 2.0 * w / (1.0 + np.abs(mod) ** 2)
        per = np.bincount(sc[use], weights=e2[use], minlength=n_s) / np.maximum(
            2.0 * np.bincount(sc[use], minlength=n_s), 1)
        med = np.median(per[keep_s])
        bad = keep_s & (per > 4.0 * med)
        if not bad.any() or keep_s.sum() - bad.sum() < 1:
            break
        keep_s &= ~bad
    m = use & keep_s[sc]
    poly, chi2_poly, poly_slope_var = fit_poly(delta[m], z[m], w[m], params, b_j, sc[m])
    s2 = chi2_poly / max(2 * m.sum() - 7 - n_s, 1)
    drop = (chi2 - chi2_poly) / s2
    chosen = "table" if (model == "table" or (model == "auto" and drop > AUTO_TABLE_CHI2_DROP)) else "tanh"
    # the chosen curve against the samples' own noise: 1 where they miss it by their noise alone
    curve = (np.exp(1j * phi) * poly(delta[m] - b_all[sc[m]]) if chosen == "table" else mod[m])
    chi2_noise = noise_chi2_per_sample(z[m], curve, samples["den"][m], samples["pow3"][m], samples["noise_power"])

    def pack(p):
        s_eff_, phi_, k_, b_ = p
        gain = 20.0 * np.log10(s_eff_ / k_) if k_ > 1e-9 else np.inf
        return np.array([s_eff_, k_, b_, gain, np.degrees(phi_)])

    names = ("effective_slope_per_deg", "slope_per_deg", "boresight_offset_deg", "diff_gain_db", "diff_phase_deg")
    est = pack(params)
    sig = np.sqrt(np.abs(np.diag(cov)))
    corr = cov[0, 2] / (sig[0] * sig[2]) if sig[0] > 0 and sig[2] > 0 else 0.0
    rel_gain = np.sqrt((sig[0] / params[0]) ** 2 + (sig[2] / max(params[2], 1e-12)) ** 2
                       - 2 * corr * sig[0] * sig[2] / (params[0] * max(params[2], 1e-12)))
    sigma = dict(zip(names, (sig[0], sig[2], sig[3], 20.0 / np.log(10.0) * rel_gain, np.degrees(sig[1]))))
    idx = np.nonzero(keep_s)[0]
    if len(idx) >= 3:   # jackknife over scatterers: includes each scatterer's azimuth error
        reps = []
        for j in idx:
            mj = m & (sc != j)
            pj, _, _, _, _ = fit_tanh(delta[mj], z[mj], w[mj], k0, sc[mj])
            pj[1] = params[1] + np.angle(np.exp(1j * (pj[1] - params[1])))
            reps.append(pack(pj))
        reps = np.array(reps)
        n = len(idx)
        jk = np.sqrt((n - 1) / n * np.sum((reps - reps.mean(axis=0)) ** 2, axis=0))
        for key, v_jk in zip(names, jk):
            sigma[key] = float(max(v_jk, sigma[key])) if np.isfinite(v_jk) else float("inf")
    model_gap = abs(float(poly.deriv()(0.0)) - float(est[0]))     # the general curve's boresight slope, apart
    if chosen == "tanh" and np.isfinite(model_gap):
        # the tanh kept by the model test still misses a curve of another shape (sinc or cosine-taper beams:
        # 5-10 % on an independent review's cubes, 7-8 sigma of the fit's own uncertainty): where the general
        # curve's boresight slope, fitted to the same samples, differs by more than both fits' own scatter,
        # the excess is the model's own error, added in quadrature
        excess2 = model_gap**2 - poly_slope_var - sigma["effective_slope_per_deg"] ** 2
        if excess2 > 0.0:
            sigma["effective_slope_per_deg"] = float(np.hypot(sigma["effective_slope_per_deg"], np.sqrt(excess2)))
    stats = {"n_scatterers": int(keep_s.sum()), "n_samples": int(m.sum()),
             "model_slope_gap_per_deg": model_gap,
             "effective_slope_per_deg": float(est[0]),
             "reduced_chi2": float(chi2 / dof), "model_test_chi2_drop": float(drop),
             "noise_chi2_per_sample": chi2_noise,
             "scatterers_m": [[float(x), float(y)] for x, y, kk in zip(samples["x_m"], samples["y_m"], keep_s) if kk],
             "rejected": dict(samples.get("rejected", {}), residual=int(n_s - keep_s.sum()))}
    if chi2_noise > NOISE_CHI2_NOTE:
        stats["noise_note"] = (f"the samples miss the fitted curve by {chi2_noise:.3g} times their noise: "
                               f"interference the curve does not hold (a neighbour's return, clutter, a channel "
                               f"fault); the uncertainties, scaled by the fit's residual, include it")
    if not sigma["slope_per_deg"] < abs(float(est[1])):      # relative uncertainty over 1, or not finite
        # a ratio curve nearly linear over the samples (a sinc pair): the data fix Re(diff/sum)'s slope,
        # the product of the curve's slope and the difference/sum gain, not the two apart (the angles
        # use the product: the same offsets either way)
        stats["slope_note"] = (f"the data fix only the boresight slope of Re(diff/sum), {float(est[0]):.4g} per deg "
                               f"(the ratio curve is nearly linear over the samples): the curve's slope and the "
                               f"difference/sum gain apart are not determined")
    check_credible_null_and_slope(float(est[2]), None if "slope_note" in stats else float(est[1]), beamwidth_deg,
                                  stats["n_scatterers"], float(est[0]), float(sigma["effective_slope_per_deg"]))
    cal = Calibration("data", "tanh", float(est[1]), boresight_offset_deg=float(est[2]),
                      diff_gain_db=float(est[3]), diff_phase_deg=float(est[4]), sigma=sigma, stats=stats)
    if chosen == "table" or not np.isfinite(est[3]):
        # the general curve: the amplitude imbalance is part of it (not separable), the phase is removed
        span = float(min(np.max(np.abs(delta[m] - params[3])), 0.6 * beamwidth_deg))
        d = np.linspace(-span, span, RATIO_TABLE_POINTS)
        r = poly(d)
        inc = np.nonzero(np.diff(r) <= 0)[0]
        if len(inc):   # keep the monotone stretch about the null
            c = RATIO_TABLE_POINTS // 2
            lo = inc[inc < c].max() + 1 if np.any(inc < c) else 0
            hi = inc[inc >= c].min() + 1 if np.any(inc >= c) else len(d)
            d, r = d[lo:hi], r[lo:hi]
        cal.model = "table"
        cal.ratio_offset_deg, cal.ratio = d, r
        cal.slope_per_deg = float(poly.deriv()(0.0))
        cal.diff_gain_db = 0.0
        cal.sigma["diff_gain_db"] = float("nan")
        cal.sigma["slope_per_deg"] = cal.sigma["effective_slope_per_deg"]
        cal.stats["effective_slope_per_deg"] = cal.slope_per_deg
        cal.stats["note"] = ("general ratio curve (tanh rejected by the model test): the amplitude imbalance "
                             "is part of the curve and not reported apart")
        cal.stats.pop("slope_note", None)          # (the table's own slope is its curve's: determined)
    return cal


def calibration_for_cube(cube, setting, *, t_ref_index=None, model: str = "auto") -> Calibration:
    """The calibration ``processing.monopulse_calibration`` asks for (auto | cube | data | slope)."""
    bw = float(cube.radar["beamwidth_3db_deg"])
    if isinstance(setting, (int, float)) and not isinstance(setting, bool):
        return Calibration("setting", "tanh", float(setting))
    from_cube = calibration_from_antenna(cube.antenna, bw)
    if setting == "cube":
        if from_cube is None:
            raise BadInput("processing.monopulse_calibration = 'cube': the cube has no /antenna group that "
                           "fixes the ratio curve; allowed: auto, data, or a slope per degree")
        return from_cube
    if setting == "auto" and from_cube is not None:
        return from_cube
    samples = point_returns(cube.sum, cube.diff, cube.range_m, cube.scan_angle_deg, cube.position_m,
                            beamwidth_deg=bw, t_ref_index=t_ref_index,
                            samples_per_resolution=float(cube.radar["fs_hz"]) / float(cube.radar["bandwidth_hz"]))
    cal = estimate_calibration(samples, beamwidth_deg=bw, model=model)
    if from_cube is not None:  # a check on the cube's own antenna
        cal.stats["cube_effective_slope_per_deg"] = float(from_cube.slope_per_deg
                                                          * 10.0 ** (from_cube.diff_gain_db / 20.0))
        cal.stats["cube_slope_per_deg"] = float(from_cube.slope_per_deg)
        cal.stats["cube_diff_gain_db"] = float(from_cube.diff_gain_db)
        cal.stats["cube_diff_phase_deg"] = float(from_cube.diff_phase_deg)
    return cal


SLOPE_CONTRADICTION = 0.2     # relative; the data's boresight slope against /antenna's (below)
SLOPE_CONTRADICTION_SIGMA = 5.0


def antenna_contradiction(cube, data_calibration: Calibration | None = None) -> str | None:
    """Where the data contradict the cube's /antenna group, what they say (else None): the difference /
    sum phase the data give (``data_calibration``, else :func:`calibration_for_cube` with ``data``)
    more than 90 deg from the group's ``diff_phase_deg``.  A difference channel of the opposite sign
    is such a case (CONTRACT.md section 3 fixes the sign); under ``auto`` the group would mirror every
    monopulse angle about the beam axis.  Or the boresight slope of Re(diff / sum) (the ratio curve's
    slope times the difference/sum gain, which is what the data measure) more than
    ``SLOPE_CONTRADICTION`` (20 %) and ``SLOPE_CONTRADICTION_SIGMA`` (5) of the data's uncertainty
    from the group's: every angle would scale by that much (0.6 deg at the edge of a 6 deg beam).  On
    fwdlook's own cubes the two agree to 0.2-3 % for Gaussian beams and a measured table, 7 % for
    sinc2 beams (a tanh fitted to a curve of another shape; tests/test_calibration.py).  None where
    the cube has no /antenna group or the data allow no calibration (no strong isolated point-like
    returns: nothing to check against)."""
    if not cube.antenna or cube.diff is None:
        return None
    cal = data_calibration
    if cal is None:
        try:
            cal = calibration_for_cube(cube, "data")
        except BadInput:
            return None
    if "cube_diff_phase_deg" not in cal.stats:
        return None
    gap = (cal.diff_phase_deg - cal.stats["cube_diff_phase_deg"] + 180.0) % 360.0 - 180.0
    if abs(gap) > 90.0:
        return (f"the data's difference/sum phase is {gap:+.0f} deg from /antenna's: the difference channel's "
                f"sign is reversed against CONTRACT.md section 3, or /antenna is wrong")
    data_slope = cal.stats["effective_slope_per_deg"]
    cube_slope = cal.stats["cube_effective_slope_per_deg"]        # set beside cube_diff_phase_deg
    sigma = cal.sigma.get("effective_slope_per_deg", np.inf)
    if (abs(cube_slope - data_slope) > SLOPE_CONTRADICTION * abs(data_slope)
            and abs(cube_slope - data_slope) > SLOPE_CONTRADICTION_SIGMA * sigma):
        if data_slope == 0.0:      # (the cube reader refuses an all-zero difference channel before this)
            return "the data show no monopulse slope at boresight: a dead difference channel, or /antenna is wrong"
        return (f"the data's monopulse slope at boresight is {data_slope:.4g} +- {sigma:.2g} per deg, /antenna's "
                f"{cube_slope:.4g} ({100.0 * (cube_slope / data_slope - 1.0):+.0f} %): its angles would be "
                f"{data_slope / cube_slope:.2f} times the data's; /antenna is wrong or belongs to another antenna")
    return None


SLOPE_BEAM_FACTOR = 2.0    # the largest slope the dwell weights take, in units of the Gaussian dip limit


def check_slope_forms_a_beam(cal: Calibration, cube) -> None:
    """The dwell weights model the sum beam as two Gaussian beams, exp(-beta d^2) cosh(k d)
    (``forward.dwell_grid.pattern_weight``), whose maximum stays on boresight while k^2 <= 2 beta (the
    boresight-dip limit).  A slope above twice that limit is no antenna of this beamwidth (fwdlook's own designs
    reach 0.82 of it with Gaussian beams and 0.91 with sinc2 beams at their widest squint): its modelled
    two-way weight peaks k / (4 beta) off boresight at exp(k^2 / (8 beta)) and overflowed the joint
    fit's dictionary (a slope of 5 /deg for a 6 deg beam: exp(64)).  BadInput naming where the slope
    came from (``cal.source``)."""
    slope_per_deg, beamwidth_deg = float(cal.slope_per_deg), float(cube.radar["beamwidth_3db_deg"])
    limit = SLOPE_BEAM_FACTOR * float(np.sqrt(2.0 * pattern_beta_per_deg2(cube)))
    if slope_per_deg <= limit:
        return
    where = {"setting": f"processing.monopulse_calibration = {slope_per_deg:g}",
             "cube": f"/antenna monopulse_slope_per_deg = {slope_per_deg:g}",
             "table": f"the Gaussian pair nearest the ratio table, slope {slope_per_deg:.4g} per deg,"}.get(
                 cal.source, f"the monopulse slope from the data, {slope_per_deg:.4g} /deg,")
    raise BadInput(f"{where}: with imaging: dwell, a slope of at most {limit:.3g} per deg for a "
                   f"{beamwidth_deg:g} deg beam (twice the largest two Gaussian beams of that width can have, "
                   f"{limit / SLOPE_BEAM_FACTOR:.3g}); allowed: a slope that fits the beam, or imaging: cpi")


def pattern_beta_per_deg2(cube) -> float:
    """beta of the Gaussian beams (the dwell weights' envelope): the cube's; for a ``gaussian2`` /antenna
    without it, the one its squint and slope fix; for a cube without ``/antenna``, the one of two beams
    crossing at -3 dB with its sum beamwidth (the ratio itself comes from the calibration in use, never
    from this)."""
    antenna = cube.antenna or {}
    if "beta_per_deg2" in antenna:
        return float(antenna["beta_per_deg2"])
    squint, slope = antenna.get("squint_deg"), antenna.get("monopulse_slope_per_deg")
    if antenna.get("pattern") == "gaussian2" and squint and slope and float(squint) > 0 and float(slope) > 0:
        # the pair CONTRACT.md names fixes it: Delta/Sigma = tanh(k d) with k = 2 beta s (dsp/antenna.py); the
        # default design's beta had put a boresight point of such a cube in two ghosts 0.9 deg off (a review)
        return float(slope) / (2.0 * float(squint))
    from ..dsp.antenna import MonopulseAntenna

    return MonopulseAntenna(cube.radar["beamwidth_3db_deg"]).beta_per_deg2


def antenna_checked(scn, cube) -> bool:
    """Whether :func:`check_antenna_against_data` has anything to check: ``auto`` and an /antenna group."""
    return (scn["processing"].get("monopulse_calibration", "auto") == "auto" and bool(cube.antenna)
            and cube.diff is not None)


def check_antenna_against_data(scn, cube, source):
    """A cube read from a file, processed with ``monopulse_calibration: auto`` (the /antenna group where
    there is one): refused where the data contradict the group (``forward.calibration.
    antenna_contradiction``: a reversed difference channel would mirror every angle, silently).  A
    cube simulated in this process carries its own antenna and is not checked.  Out of core too: the
    check reads the cube in blocks of pulses (``forward/point_returns.py``), its memory bounded by them."""
    if not antenna_checked(scn, cube):
        return
    contradiction = antenna_contradiction(cube)
    if contradiction:
        raise BadInput(f"{source}: processing.monopulse_calibration = auto: {contradiction}; allowed: data "
                       f"(calibrate from the data), cube (/antenna as it is) or a slope per degree")
