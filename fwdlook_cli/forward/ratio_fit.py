"""The ratio-curve fits of a data calibration (``forward/calibration.py``): the tanh curve of two Gaussian
beams with one null offset per scatterer, the general degree-5 curve beside it, and that curve's slope
variance.  Pure functions on the pooled samples (offsets ``delta``, ratios ``z``, weights)."""
from __future__ import annotations

import numpy as np


def tanh_over_k(k, u):
    """tanh(k u) / k, continuous through k = 0 (where it is u)."""
    k = float(k)
    return u if abs(k) < 1e-9 else np.tanh(k * u) / k


def fit_tanh(delta, z, weight, k0, sc=None):
    """Weighted least squares of z = exp(j phi) S tanh(k (delta - b_j)) / k.

    S is the effective slope of Re(diff/sum) on the null (the receiver gain included), k the curve's
    own curvature scale: the amplitude imbalance is S / k, seen only through the tanh's bend.  Each
    scatterer j has its own null offset b_j (its azimuth from the sum envelope has an error of its
    own); the boresight offset is their mean.  Returns [S, phi, k, mean b], the b_j, the covariance
    of the first four (scaled by the reduced chi^2), chi^2 and dof.
    """
    from scipy.optimize import least_squares

    sc = np.zeros(len(z), np.int64) if sc is None else sc
    labels, sc = np.unique(sc, return_inverse=True)
    n_s = len(labels)
    rot = np.sum(weight * z * np.sign(delta))
    phi0 = float(np.angle(rot))

    def model(p):
        s_eff, phi, k = p[:3]
        return np.exp(1j * phi) * s_eff * tanh_over_k(k, delta - p[3:][sc])

    def resid(p):
        m = model(p)
        e = (z - m) * np.sqrt(2.0 * weight / (1.0 + np.abs(m) ** 2))
        return np.concatenate([e.real, e.imag])

    x = np.real(z * np.exp(-1j * phi0))
    inner = np.abs(delta) < 0.5 / max(k0, 1e-6)
    if inner.sum() > 10:
        s0 = float(np.sum(weight[inner] * x[inner] * delta[inner]) / np.sum(weight[inner] * delta[inner] ** 2))
    else:
        s0 = k0
    res = least_squares(resid, x0=np.r_[s0, phi0, s0, np.zeros(n_s)], method="lm", x_scale="jac")
    p = res.x.copy()
    p[2] = abs(p[2])
    if p[0] < 0:
        p[0], p[1] = -p[0], p[1] + np.pi
    p[1] = float(np.angle(np.exp(1j * p[1])))
    dof = max(2 * len(z) - len(p), 1)
    chi2 = float(np.sum(res.fun ** 2))
    try:
        cov_all = np.linalg.inv(res.jac.T @ res.jac) * chi2 / dof
    except np.linalg.LinAlgError:
        cov_all = np.full((len(p), len(p)), np.nan)
    # the mean null offset and its variance (the b_j block averaged)
    avg = np.r_[np.zeros(3), np.full(n_s, 1.0 / n_s)]
    tr = np.vstack([np.eye(len(p))[:3], avg])
    cov = tr @ cov_all @ tr.T
    b_j = p[3:]
    return np.r_[p[:3], b_j.mean()], b_j, cov, chi2, dof


def fit_poly(delta, z, weight, params, b_j, sc, degree=5):
    """The general ratio curve: a degree-5 polynomial through Re(z e^{-j phi}) against u = delta - b_j,
    with the tanh fit's weights (so that the two chi^2 compare).  Returns it, its chi^2, and the variance
    of its boresight slope (its linear coefficient in u, from the weighted least-squares covariance
    scaled by the fit's own residual, as ``np.polyfit(..., cov=True)`` scales it)."""
    s_eff, phi, k, _b = params
    _, sc = np.unique(sc, return_inverse=True)
    u = delta - b_j[sc]
    m = s_eff * tanh_over_k(k, u)
    sw = np.sqrt(2.0 * weight / (1.0 + m**2))
    zr = z * np.exp(-1j * phi)
    poly = np.polynomial.Polynomial.fit(u, zr.real, degree, w=sw)
    resid_real = float(np.sum((sw * (zr.real - poly(u))) ** 2))
    chi2 = resid_real + float(np.sum((sw * zr.imag) ** 2))
    design = np.vander(u, degree + 1, increasing=True) * sw[:, None]
    scale = np.sqrt(np.sum(design**2, axis=0))
    scaled = design / np.where(scale > 0, scale, 1.0)
    try:
        cov = np.linalg.inv(scaled.T @ scaled) / np.outer(scale, scale)
        slope_var = float(cov[1, 1]) * resid_real / max(len(u) - degree - 1, 1)
    except np.linalg.LinAlgError:
        slope_var = float("inf")
    return poly, chi2, slope_var
