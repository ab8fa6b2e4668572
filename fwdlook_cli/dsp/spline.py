"""The antiderivative of a not-a-knot cubic spline on a uniform grid, without ``scipy.interpolate``.

``scipy.interpolate.CubicSpline(x, y).antiderivative()`` is what the ``tracking`` keystone's Doppler
history needs (``forward.motion.DopplerPhaseHistory``: Psi = 2 pi int f_b dt on the pulse grid), and
importing ``scipy.interpolate`` (with ``scipy.optimize``, ``scipy.linalg``, ``scipy.sparse`` and
``scipy.spatial``, which it imports) is a quarter of a second of every ``tracking`` command's start.
On a uniform grid the spline's slopes have a closed form, computed here with array operations only.

The slopes s_i at the knots of the C^2 cubic interpolant satisfy, for the interior knots
(h the step, y the data)::

    s_{i-1} + 4 s_i + s_{i+1} = 3 (y_{i+1} - y_{i-1}) / h,      i = 1 .. n-2,

and not-a-knot (the third derivative continuous at x_1 and x_{n-2}; on a piece it is
6 (s_i + s_{i+1}) / h^2 - 12 (y_{i+1} - y_i) / h^3)::

    s_0 - s_2 = 2 (D_0 - D_1) / h,     s_{n-3} - s_{n-1} = 2 (D_{n-3} - D_{n-2}) / h,   D_i = y_{i+1} - y_i.

The operator s_{i-1} + 4 s_i + s_{i+1} has the Green's function g_k = lambda^|k| / (2 sqrt 3) with
lambda = sqrt 3 - 2 (lambda^2 + 4 lambda + 1 = 0), so a particular solution is the convolution
p = g * r (|lambda|^32 < 1e-18: 65 taps are the exact kernel to rounding), and every solution is
p_i + A lambda^i + B lambda^(n-1-i); the two end conditions fix A and B (a 2 x 2 system).  Each piece is
then the cubic Hermite interpolant of (y_i, s_i, y_{i+1}, s_{i+1}), and its antiderivative the quartic
whose constants make the antiderivative continuous and zero at x_0, as scipy's ``antiderivative()``
does; outside [x_0, x_{n-1}] the end pieces are extended (scipy's ``extrapolate=True``).  Agreement with
scipy to rounding: ``tests/test_spline.py``.
"""
from __future__ import annotations

import numpy as np

_LAMBDA = np.sqrt(3.0) - 2.0
_TAPS = 32                                    # |lambda|^32 = 5e-19: the kernel beyond is below rounding
_KERNEL = _LAMBDA ** np.abs(np.arange(-_TAPS, _TAPS + 1)) / (2.0 * np.sqrt(3.0))
MIN_KNOTS = 8                                 # fewer: scipy's CubicSpline (its special cases for n < 4)


def is_uniform(x, rtol: float = 1e-9) -> bool:
    """Whether the increasing knots ``x`` have one step to ``rtol``."""
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 1 or len(x) < 2:
        return False
    step = np.diff(x)
    h = (x[-1] - x[0]) / (len(x) - 1)
    return bool(h > 0 and np.all(np.abs(step - h) <= rtol * h))


def not_a_knot_slopes(y, h: float):
    """The first derivatives at the knots of the not-a-knot cubic spline of ``y`` [n] (n >= MIN_KNOTS) on
    a grid of step ``h`` (module docstring)."""
    y = np.asarray(y, dtype=np.float64)
    n = len(y)
    if n < MIN_KNOTS:
        raise ValueError(f"{n} knots; the closed form needs at least {MIN_KNOTS}")
    d = np.diff(y)
    r = np.zeros(n)
    r[1:-1] = 3.0 * (y[2:] - y[:-2]) / h
    p = np.convolve(r, _KERNEL)[_TAPS:_TAPS + n]                    # particular solution, all i
    lam = _LAMBDA
    e0 = 2.0 * (d[0] - d[1]) / h - (p[0] - p[2])
    e1 = 2.0 * (d[n - 3] - d[n - 2]) / h - (p[n - 3] - p[n - 1])
    # s_i = p_i + A lam^i + B lam^(n-1-i) in the two end conditions
    m = np.array([[1.0 - lam ** 2, lam ** (n - 1) - lam ** (n - 3)],
                  [lam ** (n - 3) - lam ** (n - 1), lam ** 2 - 1.0]])
    a, b = np.linalg.solve(m, np.array([e0, e1]))
    i = np.arange(n, dtype=np.float64)
    return p + a * lam ** i + b * lam ** (n - 1 - i)


class UniformSplineAntiderivative:
    """``CubicSpline(x, y).antiderivative()`` for uniform knots ``x``: call it as ``anti(t, nu=0)`` (the
    nu-th derivative, 0 <= nu <= 4, at the times ``t``; any shape)."""

    def __init__(self, x, y):
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        if not is_uniform(x) or len(x) != len(y):
            raise ValueError("uniform increasing knots and one value per knot are needed")
        self.x = x
        h = (x[-1] - x[0]) / (len(x) - 1)
        s = not_a_knot_slopes(y, h)
        dx = np.diff(x)                                          # the pieces' own widths (as scipy)
        slope = np.diff(y) / dx
        c2 = (3.0 * slope - 2.0 * s[:-1] - s[1:]) / dx           # cubic Hermite piece: y + s t + c2 t^2 + c3 t^3
        c3 = (s[:-1] + s[1:] - 2.0 * slope) / dx ** 2
        q = np.stack([c3 / 4.0, c2 / 3.0, s[:-1] / 2.0, y[:-1], np.zeros_like(c3)])   # quartic, highest first
        # constants: the antiderivative continuous and zero at x_0 (each piece's integral over its width)
        width = q[0] * dx
        for k in range(1, 4):
            width = (width + q[k]) * dx
        q[4, 1:] = np.cumsum(width)[:-1]
        self._coef = q                                           # [5, n - 1]
        self._h = h

    def __call__(self, t, nu: int = 0):
        if not 0 <= int(nu) <= 4:
            raise ValueError(f"derivative order {nu}; allowed: 0 to 4")
        t = np.asarray(t, dtype=np.float64)
        x, q = self.x, self._coef
        i = np.clip(np.floor((t - x[0]) / self._h), 0, q.shape[1] - 1).astype(np.intp)
        # the knot found by the uniform step is the piece's own, or its neighbour within rounding
        i -= (t < x[i]) & (i > 0)
        i += (i + 1 < q.shape[1]) & (t >= x[np.minimum(i + 1, len(x) - 1)])
        u = t - x[i]
        # nu-th derivative of sum_k q_k u^(4-k): Horner over the differentiated coefficients
        out = np.zeros(np.shape(t))
        for k in range(0, 5 - int(nu)):
            power = 4 - k
            factor = float(np.prod(np.arange(power - int(nu) + 1, power + 1))) if nu else 1.0
            out = out * u + factor * q[k][i]
        return out
