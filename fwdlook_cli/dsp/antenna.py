"""Scanning amplitude-comparison monopulse antennas: two squinted beams, or a measured pattern.

Families (``antenna.pattern``):

* ``gaussian2``: two squinted Gaussian beams, one-way voltage ``e(u) = exp(-(ln 2 / 2) u^2)``;
* ``sinc2``: two squinted uniform-aperture beams, ``e(u) = sinc(X3 u)`` (``np.sinc``, X3 = 0.44295 so
  that ``e(1)^2 = 1/2``);
* ``table``: a measured pattern, sum and difference voltage gains against the angle offset
  (:class:`TableAntenna`, read by :func:`read_pattern_file`).

For the two-beam families ``u`` is the offset from a beam's own axis in units of the element's one-way
half-power half-width ``w`` (degrees), the beams are squinted by ``+-s = +-rho w`` and, normalised so
that the sum is 1 on boresight,

    Sigma(d) = [e((d - s)/w) + e((d + s)/w)] / (2 e(rho)),
    Delta(d) = [e((d - s)/w) - e((d + s)/w)] / (2 e(rho)),

so Delta > 0 towards +x of the beam axis (CONTRACT.md section 3).  The crossover level of the two
beams is ``20 log10 e(rho)`` dB one-way (``rho = 1``: the textbook design, beams crossing at their
half-power points, squint = half the element beamwidth).  ``w`` is solved so that the SUM beam's
one-way 3 dB width is ``beamwidth_3db_deg``.  For the Gaussian pair the ratio is exactly
``Delta/Sigma = tanh(k d)`` with ``k = 2 beta s = ln 2 rho / w`` (NOTES.md); its inverse is ``atanh``.
Every other ratio curve is inverted through a monotone table over the main lobe.

Design solver.  Given a crossover level, ``rho`` follows and the sum beam's half-width in element units
``v_h(rho)`` is unique as long as the sum has no dip on boresight (``e''(rho) <= 0``: crossover no
deeper than -4.34 dB for Gaussian beams, -7.5 dB for sinc beams).  Given a squint, ``s / h =
rho / v_h(rho)`` (h = half the sum beamwidth) rises with rho to a maximum and falls again: a squint
beyond that maximum cannot form the sum beam (0.3205 x the beamwidth for Gaussian beams, a little
above the textbook 0.3204), and below it there are up to two designs; the one whose crossover is
nearer the textbook -3 dB is taken (give ``antenna.crossover_db`` to choose the other).  The former
solver bracketed beta in [0, 1/(2 s^2)], where the 3 dB excess is not monotonic, and refused the
textbook design.

The transmitted pattern is the sum beam, so the echo gains are ``Sigma^2`` (sum channel) and
``Sigma Delta`` (difference channel).  The elevation pattern is flat.
"""
from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from ..limits import MAX_MONOPULSE_SLOPE_PER_DEG

PATTERNS = ("gaussian2", "sinc2", "table")
DEFAULT_CROSSOVER_DB = -3.0
TEXTBOOK_CROSSOVER_DB = -10.0 * np.log10(2.0)
HALF_POWER = 1.0 / np.sqrt(2.0)
_LN2 = np.log(2.0)


def bracketed_root(f, a: float, b: float, xtol: float = 2e-12) -> float:
    """A root of the continuous ``f`` in [a, b], where f(a) and f(b) differ in sign, to ``xtol`` (plus
    4 ulp of the root, scipy's ``brentq`` tolerance), without importing scipy.optimize (a quarter of a
    second of every command's start): the design solver's roots (``brentq`` finds the same ones to that
    tolerance: tests/test_antenna_models.py).

    The Illinois method (false position whose retained end has its value halved, so that both ends
    close in: superlinear, as many evaluations as ``brentq`` within a few), each step kept inside the
    bracket, and a bisection wherever two steps have not halved it, so that it never takes more steps
    than about twice a bisection's."""
    fa, fb = float(f(a)), float(f(b))
    if fa == 0.0 or fb == 0.0:
        return float(a if fa == 0.0 else b)
    if (fa < 0.0) == (fb < 0.0):
        raise ValueError(f"f({a}) and f({b}) have the same sign: no bracketed root")
    eps4 = 4.0 * np.finfo(float).eps
    width_before, side = [abs(b - a)] * 2, 0
    for _ in range(400):                        # ends by the tolerance long before (bisections at worst)
        m = 0.5 * (a + b)
        if abs(b - a) <= 2.0 * (xtol + eps4 * abs(m)):
            return float(m)
        c = (a * fb - b * fa) / (fb - fa)       # false position
        if abs(b - a) > 0.5 * width_before[0] or not min(a, b) < c < max(a, b):
            c, side = m, 0                       # two steps without halving the bracket: bisect
        fc = float(f(c))
        if fc == 0.0:
            return float(c)
        width_before = [width_before[1], abs(b - a)]
        if (fc < 0.0) == (fb < 0.0):            # c replaces b; a retained twice in a row: halve f(a)
            b, fb = c, fc
            if side == -1:
                fa *= 0.5
            side = -1
        else:
            a, fa = c, fc
            if side == 1:
                fb *= 0.5
            side = 1
    return float(0.5 * (a + b))


_SINC_X3 = bracketed_root(lambda x: np.sinc(x) ** 2 - 0.5, 0.1, 0.9, xtol=1e-15)   # 0.442946


class AntennaDesignError(ValueError):
    """An antenna design that cannot be built; ``key`` names the scenario key at fault."""

    def __init__(self, message: str, key: str = "antenna.squint_deg"):
        super().__init__(message)
        self.key = key


# ----------------------------------------------------------------------------------------------
# element patterns, in units of the element's half-power half-width
# ----------------------------------------------------------------------------------------------
def _element(pattern: str, u):
    u = np.asarray(u, dtype=np.float64)
    if pattern == "gaussian2":
        return np.exp(-0.5 * _LN2 * u * u)
    return np.sinc(_SINC_X3 * u)


def _element_log_derivative(pattern: str, u: float) -> float:
    """e'(u)/e(u) (per element unit)."""
    if pattern == "gaussian2":
        return -_LN2 * u
    x = np.pi * _SINC_X3 * u
    return np.pi * _SINC_X3 * (1.0 / np.tan(x) - 1.0 / x)


def _sum_units(pattern: str, v, rho):
    return (_element(pattern, v - rho) + _element(pattern, v + rho)) / (2.0 * _element(pattern, rho))


@functools.lru_cache(maxsize=None)
def rho_limit(pattern: str) -> float:
    """Largest squint/element-half-width ratio without a boresight dip of the sum (e''(rho) = 0)."""
    if pattern == "gaussian2":
        return float(1.0 / np.sqrt(_LN2))

    def second(u):  # d^2/dy^2 (sin y / y) at y = pi X3 u
        y = np.pi * _SINC_X3 * u
        return -np.sin(y) / y - 2.0 * np.cos(y) / y**2 + 2.0 * np.sin(y) / y**3

    return float(bracketed_root(second, 0.5, 2.0, xtol=1e-14))


def crossover_db_of_rho(pattern: str, rho) -> np.ndarray:
    return 20.0 * np.log10(np.abs(_element(pattern, rho)))


def rho_of_crossover(pattern: str, crossover_db: float) -> float:
    level = 10.0 ** (crossover_db / 20.0)
    if pattern == "gaussian2":
        return float(np.sqrt(-2.0 * np.log(level) / _LN2))
    return float(bracketed_root(lambda u: np.sinc(_SINC_X3 * u) - level, 0.0, 1.0 / _SINC_X3, xtol=1e-14))


def _half_width_units(pattern: str, rho: float) -> float:
    """v_h: the sum's one-way half-power half-width in element units (the first crossing)."""
    v_max = rho + (6.0 if pattern == "gaussian2" else 1.0 / _SINC_X3)
    v = np.linspace(0.0, v_max, 4001)
    below = np.nonzero(_sum_units(pattern, v, rho) < HALF_POWER)[0]
    i = int(below[0])
    return float(bracketed_root(lambda x: _sum_units(pattern, x, rho) - HALF_POWER, v[i - 1], v[i], xtol=1e-14))


_SQUINT_ROWS = 25       # rows of _squint_curve's grid per block: 400 kB per temporary


@functools.lru_cache(maxsize=None)
def _squint_curve(pattern: str):
    """rho grid over (0, rho_limit] and s/h = rho / v_h(rho) on it (vectorised first crossings)."""
    rho = np.linspace(1e-3, rho_limit(pattern), 500)
    v_max = rho[-1] + (6.0 if pattern == "gaussian2" else 1.0 / _SINC_X3)
    v = np.linspace(0.0, v_max, 2001)
    vh = np.empty_like(rho)
    # in blocks of rho rows (each row on its own: the same numbers): the whole 500 x 2001 grid at once
    # held about 30 MiB of float64 temporaries, the high-water mark of every command's start
    for r0 in range(0, len(rho), _SQUINT_ROWS):
        r = rho[r0:r0 + _SQUINT_ROWS]
        sig = _sum_units(pattern, v[None, :], r[:, None])
        i = np.argmax(sig < HALF_POWER, axis=1)
        s0, s1 = sig[np.arange(len(r)), i - 1], sig[np.arange(len(r)), i]
        vh[r0:r0 + len(r)] = v[i - 1] + (v[i] - v[i - 1]) * (s0 - HALF_POWER) / (s0 - s1)
    return rho, rho / vh


def max_squint_deg(pattern: str, beamwidth_3db_deg: float) -> float:
    """The largest squint with which two beams of this family can form the sum beam."""
    rho, q = _squint_curve(pattern)
    j = int(np.argmax(q))
    lo, hi = rho[max(j - 1, 0)], rho[min(j + 1, len(rho) - 1)]
    from scipy.optimize import minimize_scalar

    res = minimize_scalar(lambda r: -r / _half_width_units(pattern, r), bounds=(lo, hi), method="bounded",
                          options={"xatol": 1e-10})
    return float(-res.fun * beamwidth_3db_deg / 2.0)


def _rho_for_squint(pattern: str, beamwidth_3db_deg: float, squint_deg: float) -> float:
    h = beamwidth_3db_deg / 2.0
    target = squint_deg / h
    rho, q = _squint_curve(pattern)
    # the curve's sampled maximum is below the true one by at most its interpolation error (~1e-5):
    # a squint 1e-4 below it is within the limit, and only one nearer needs the exact maximum (a
    # bounded minimisation, scipy.optimize: its import is a quarter of a second of a command's start)
    s_max = q.max() * h if target <= q.max() - 1e-4 else max_squint_deg(pattern, beamwidth_3db_deg)
    if squint_deg > s_max:
        raise AntennaDesignError(
            f"too large for a {beamwidth_3db_deg:g} deg sum beam (two {pattern} beams this far apart "
            f"cannot form it); allowed: squint_deg <= {s_max:.4f} ({s_max / beamwidth_3db_deg:.4f} x the "
            f"beamwidth)", "antenna.squint_deg")
    f = q - target
    roots = []
    for i in np.nonzero(np.sign(f[:-1]) != np.sign(f[1:]))[0]:
        g = lambda r: r / _half_width_units(pattern, r) - target  # noqa: E731
        roots.append(bracketed_root(g, rho[i], rho[i + 1], xtol=1e-14))
    if not roots:  # at the fold, within the grid step
        roots = [rho[int(np.argmax(q))]]
    cross = crossover_db_of_rho(pattern, np.array(roots))
    return float(roots[int(np.argmin(np.abs(cross - TEXTBOOK_CROSSOVER_DB)))])


# ----------------------------------------------------------------------------------------------
# the models
# ----------------------------------------------------------------------------------------------
class _RatioInverse:
    """Shared by every model: the ratio curve, its monotone main-lobe table and the inverse."""

    pattern: str
    beamwidth_3db_deg: float

    def ratio(self, offset_deg):
        """Re(Delta/Sigma) against the angle offset from the beam axis."""
        s = self.sum_voltage(offset_deg)
        return self.diff_voltage(offset_deg) / np.where(np.abs(s) > 1e-300, s, 1e-300)

    def two_way_gains(self, offset_deg):
        """(sum, difference) echo amplitude gains: Sigma^2 and Sigma*Delta."""
        s = self.sum_voltage(offset_deg)
        return s * s, s * self.diff_voltage(offset_deg)

    @functools.cached_property
    def ratio_table(self):
        """(offset_deg, ratio) strictly increasing over the main lobe (|offset| up to ``main_lobe_deg``)."""
        half = self.main_lobe_deg
        d = np.linspace(-half, half, 1201)
        return d, self.ratio(d)

    @functools.cached_property
    def main_lobe_deg(self) -> float:
        """Half-extent of the main lobe where the ratio rises strictly and the sum stays above -20 dB."""
        d = np.linspace(0.0, 2.0 * self.beamwidth_3db_deg, 4001)
        r = self.ratio(d)
        s = self.sum_voltage(d)
        bad = (np.diff(r) <= 0) | (s[1:] < 0.1) | (s[:-1] < 0.1)
        n = int(np.argmax(bad)) if bad.any() else len(d) - 1
        neg = self.ratio(-d)
        bad_n = (np.diff(neg) >= 0) | (self.sum_voltage(-d)[1:] < 0.1)
        n_n = int(np.argmax(bad_n)) if bad_n.any() else len(d) - 1
        return float(d[max(min(n, n_n), 2)])

    def ratio_to_offset_deg(self, ratio, max_ratio: float = 0.999):
        """Inverse of the ratio curve: exact atanh for Gaussian beams, the monotone table otherwise."""
        r = np.asarray(ratio, dtype=np.float64)
        if self.pattern == "gaussian2":
            return np.arctanh(np.clip(r, -max_ratio, max_ratio)) / self.slope_per_deg
        d, rt = self.ratio_table
        return np.interp(r, rt, d)

    def two_way_3db_width_deg(self) -> float:
        """Two-way (sum^2 power) 3 dB width: the real-beam image's angular resolution."""
        f = lambda x: 4.0 * np.log(np.abs(self.sum_voltage(x)) + 1e-300) + np.log(2.0)  # noqa: E731
        half = self.beamwidth_3db_deg / 2.0
        return bracketed_root(f, 0.0, half) + bracketed_root(lambda x: f(-x), 0.0, half)

    def to_attrs(self) -> dict:
        """The /antenna group's attributes (CONTRACT.md section 3 extension); datasets via ratio_table."""
        out = {"pattern": self.pattern, "squint_deg": float(self.squint_deg),
               "monopulse_slope_per_deg": float(self.slope_per_deg),
               "crossover_db": float(self.crossover_db), "main_lobe_deg": float(self.main_lobe_deg)}
        if self.pattern == "gaussian2":
            out["beta_per_deg2"] = float(self.beta_per_deg2)
        return out


class MonopulseAntenna(_RatioInverse):
    """Two squinted beams (``gaussian2`` or ``sinc2``) forming sum and difference patterns (degrees).

    ``MonopulseAntenna(beamwidth_3db_deg, squint_deg)`` keeps its former meaning (two Gaussian beams);
    ``squint_deg=None`` (or "auto") takes the squint from ``crossover_db`` (default -3 dB).
    """

    def __init__(self, beamwidth_3db_deg: float, squint_deg: float | str | None = None, *,
                 pattern: str = "gaussian2", crossover_db: float | None = None):
        if pattern not in ("gaussian2", "sinc2"):
            raise AntennaDesignError(f"pattern {pattern!r}; allowed: gaussian2, sinc2 (table: TableAntenna)",
                                     "antenna.pattern")
        bw = float(beamwidth_3db_deg)
        if not bw > 0:
            raise AntennaDesignError(f"beamwidth {bw:g}; allowed: > 0", "antenna.beamwidth_3db_deg")
        self.pattern = pattern
        self.beamwidth_3db_deg = bw
        if squint_deg is None or squint_deg == "auto":
            c = DEFAULT_CROSSOVER_DB if crossover_db is None else float(crossover_db)
            c_lim = float(crossover_db_of_rho(pattern, rho_limit(pattern)))
            if not c < 0.0:
                raise AntennaDesignError(f"crossover {c:g} dB; allowed: below 0 dB", "antenna.crossover_db")
            if c < c_lim - 1e-12:
                raise AntennaDesignError(
                    f"two {pattern} beams crossing at {c:g} dB form a sum beam with a dip on boresight; "
                    f"allowed: crossover_db >= {c_lim:.3f} dB (the boresight-dip limit)", "antenna.crossover_db")
            rho = min(rho_of_crossover(pattern, c), rho_limit(pattern))
        else:
            s = float(squint_deg)
            if not s > 0:
                raise AntennaDesignError(f"squint {s:g}; allowed: > 0", "antenna.squint_deg")
            rho = _rho_for_squint(pattern, bw, s)
        self.rho = rho
        self.element_halfwidth_deg = bw / 2.0 / _half_width_units(pattern, rho)
        self.squint_deg = float(squint_deg) if squint_deg not in (None, "auto") else rho * self.element_halfwidth_deg
        self.crossover_db = float(crossover_db_of_rho(pattern, rho))
        # boresight slope dR/dd = -e'(rho) / (w e(rho)); Gaussian: ln 2 rho / w = 2 beta s
        self.slope_per_deg = float(-_element_log_derivative(pattern, rho) / self.element_halfwidth_deg)
        self.beta_per_deg2 = (float(0.5 * _LN2 / self.element_halfwidth_deg**2) if pattern == "gaussian2"
                              else float("nan"))

    def __repr__(self):
        return (f"MonopulseAntenna({self.beamwidth_3db_deg:g}, squint_deg={self.squint_deg:.4f}, "
                f"pattern={self.pattern!r}, crossover_db={self.crossover_db:.3f})")

    def _beams(self, offset_deg):
        d = np.asarray(offset_deg, dtype=np.float64)
        w, rho = self.element_halfwidth_deg, self.rho
        norm = 2.0 * _element(self.pattern, rho)
        return _element(self.pattern, d / w - rho) / norm, _element(self.pattern, d / w + rho) / norm

    def sum_voltage(self, offset_deg):
        if self.pattern == "gaussian2":   # closed form, exact ratio tanh(k d)
            d = np.asarray(offset_deg, dtype=np.float64)
            return np.exp(-self.beta_per_deg2 * d**2) * np.cosh(self.slope_per_deg * d)
        plus, minus = self._beams(offset_deg)
        return plus + minus

    def diff_voltage(self, offset_deg):
        if self.pattern == "gaussian2":
            d = np.asarray(offset_deg, dtype=np.float64)
            return np.exp(-self.beta_per_deg2 * d**2) * np.sinh(self.slope_per_deg * d)
        plus, minus = self._beams(offset_deg)
        return plus - minus

    def ratio(self, offset_deg):
        if self.pattern == "gaussian2":
            return np.tanh(self.slope_per_deg * np.asarray(offset_deg, dtype=np.float64))
        return super().ratio(offset_deg)


class TableAntenna(_RatioInverse):
    """A measured pattern: sum and difference one-way VOLTAGE gains (linear, difference signed so that
    it is positive towards +x of the axis) against the angle offset in degrees, linearly interpolated,
    zero outside the table.  Normalised so that the sum is 1 on boresight."""

    pattern = "table"

    def __init__(self, offset_deg, sum_gain, diff_gain, *, beamwidth_3db_deg: float | None = None,
                 source: str = "pattern table", tolerance: float = 0.05):
        d = np.asarray(offset_deg, dtype=np.float64)
        s = np.asarray(sum_gain, dtype=np.float64)
        g = np.asarray(diff_gain, dtype=np.float64)
        key = "antenna.pattern_file"
        if d.ndim != 1 or d.shape != s.shape or d.shape != g.shape or len(d) < 8:
            raise AntennaDesignError(f"{source}: expected three columns offset_deg, sum, diff of equal "
                                     f"length (at least 8 rows)", key)
        if not (np.all(np.isfinite(d)) and np.all(np.isfinite(s)) and np.all(np.isfinite(g))):
            raise AntennaDesignError(f"{source}: NaN/Inf in the table; allowed: finite values", key)
        if np.any(np.diff(d) <= 0):
            raise AntennaDesignError(f"{source}: offset_deg not strictly increasing", key)
        if not (d[0] < 0 < d[-1]):
            raise AntennaDesignError(f"{source}: offset_deg must span the boresight (0)", key)
        s0 = float(np.interp(0.0, d, s))
        if not s0 > 0:
            raise AntennaDesignError(f"{source}: sum gain on boresight is {s0:g}; allowed: > 0", key)
        self._d, self._s, self._g = d, s / s0, g / s0
        self.source = source
        measured = self._measured_beamwidth()
        if not np.isfinite(measured):
            raise AntennaDesignError(f"{source}: the sum gain never falls to -3 dB inside the table", key)
        if beamwidth_3db_deg is not None and abs(measured / beamwidth_3db_deg - 1.0) > tolerance:
            raise AntennaDesignError(
                f"{source}: the table's sum beam is {measured:.3f} deg wide at -3 dB, "
                f"antenna.beamwidth_3db_deg = {beamwidth_3db_deg:g}; allowed: within {100 * tolerance:g} %", key)
        self.beamwidth_3db_deg = float(beamwidth_3db_deg if beamwidth_3db_deg is not None else measured)
        eps = 1e-3 * self.beamwidth_3db_deg
        self.slope_per_deg = float((self.ratio(eps) - self.ratio(-eps)) / (2 * eps))
        if not self.slope_per_deg > 0:
            raise AntennaDesignError(f"{source}: the difference gain does not rise through boresight "
                                     f"(slope {self.slope_per_deg:g} /deg); allowed: positive towards +x", key)
        if self.slope_per_deg > MAX_MONOPULSE_SLOPE_PER_DEG:   # a cube's /antenna is held to it too (io/raw.py)
            raise AntennaDesignError(f"{source}: the ratio's slope through boresight is {self.slope_per_deg:.4g} per "
                                     f"degree; allowed: up to {MAX_MONOPULSE_SLOPE_PER_DEG:g} (as "
                                     f"processing.monopulse_calibration)", key)
        self.squint_deg = float("nan")
        self.crossover_db = float("nan")

    def _measured_beamwidth(self) -> float:
        d = np.linspace(self._d[0], self._d[-1], 20001)
        low = self.sum_voltage(d) < HALF_POWER
        right = np.nonzero(low & (d > 0))[0]
        left = np.nonzero(low & (d < 0))[0]
        if not len(right) or not len(left):
            return float("nan")
        return float(d[right[0]] - d[left[-1]])

    def sum_voltage(self, offset_deg):
        return np.interp(np.asarray(offset_deg, dtype=np.float64), self._d, self._s, left=0.0, right=0.0)

    def diff_voltage(self, offset_deg):
        return np.interp(np.asarray(offset_deg, dtype=np.float64), self._d, self._g, left=0.0, right=0.0)


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def read_pattern_file(path: str | Path, beamwidth_3db_deg: float | None = None) -> TableAntenna:
    """A measured pattern from CSV (columns offset_deg, sum, diff; '#' comments, optional header) or
    HDF5 (datasets ``offset_deg``, ``sum``, ``diff`` at the root or in ``/antenna``)."""
    path = Path(path)
    key = "antenna.pattern_file"
    if not path.exists():
        raise AntennaDesignError(f"{path}: pattern file not found", key)
    if path.is_dir():
        raise AntennaDesignError(f"{path}: a folder, not a pattern file (CSV or HDF5)", key)
    if path.suffix.lower() in (".h5", ".hdf5", ".hdf"):
        import h5py

        try:
            with h5py.File(path, "r") as f:
                grp = f["antenna"] if "antenna" in f and "offset_deg" in f["antenna"] else f
                cols = [np.asarray(grp[name][()], dtype=np.float64) for name in ("offset_deg", "sum", "diff")]
        except (OSError, KeyError) as exc:
            raise AntennaDesignError(f"{path}: expected HDF5 datasets offset_deg, sum, diff ({exc})", key) from None
    else:
        where = ""
        try:
            rows, header_seen = [], False
            for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
                line = line.split("#", 1)[0].strip()
                if not line:
                    continue
                parts = [p for p in line.replace(",", " ").split()]
                where = f" (line {number}: {line[:60]!r})"
                try:
                    rows.append([float(p) for p in parts])
                except ValueError:
                    # a header is the first row and holds no number (a first row of numbers with one
                    # garbled cell had been dropped as a header: an independent review)
                    if rows or header_seen or any(_is_number(p) for p in parts):
                        raise
                    header_seen = True
                    continue
                if len(rows[-1]) != 3:
                    raise ValueError("columns")
            where = ""
            arr = np.array(rows, dtype=np.float64)
            if arr.ndim != 2 or arr.shape[1] != 3:
                raise ValueError("columns")
        except (OSError, UnicodeDecodeError, ValueError):
            raise AntennaDesignError(f"{path}: expected CSV rows offset_deg, sum, diff (numbers){where}", key) from None
        cols = [arr[:, 0], arr[:, 1], arr[:, 2]]
    return TableAntenna(*cols, beamwidth_3db_deg=beamwidth_3db_deg, source=str(path))


def antenna_from_scenario(ant: dict):
    """The antenna model of a resolved scenario's ``antenna`` section."""
    if ant.get("pattern", "gaussian2") == "table":
        if not ant.get("pattern_file"):
            raise AntennaDesignError("required when antenna.pattern is table", "antenna.pattern_file")
        return read_pattern_file(ant["pattern_file"], ant["beamwidth_3db_deg"])
    return MonopulseAntenna(ant["beamwidth_3db_deg"], ant.get("squint_deg", "auto"),
                            pattern=ant.get("pattern", "gaussian2"), crossover_db=ant.get("crossover_db"))


def sum_voltage_for(beamwidth_3db_deg: float, attrs: dict | None):
    """The one-way sum voltage gain against the offset from the beam axis (deg) of a cube's antenna, as
    a function, where its ``/antenna`` attributes fix it: a Gaussian pair by its beta and slope (the
    closed form), a two-beam design by its pattern and squint; None otherwise (a measured table, whose
    cube holds the ratio curve only, or a recorded cube that does not say)."""
    a = attrs or {}
    pattern = a.get("pattern", "gaussian2")
    try:
        beta, slope = float(a.get("beta_per_deg2", np.nan)), float(a.get("monopulse_slope_per_deg", np.nan))
        if pattern == "gaussian2" and np.isfinite(beta) and np.isfinite(slope):
            return lambda d: np.exp(-beta * np.asarray(d) ** 2) * np.cosh(slope * np.asarray(d))
        if pattern in ("gaussian2", "sinc2") and np.isfinite(float(a.get("squint_deg", np.nan))):
            return MonopulseAntenna(float(beamwidth_3db_deg), float(a["squint_deg"]), pattern=pattern).sum_voltage
    except (AntennaDesignError, TypeError, ValueError):
        pass
    return None


def two_way_width_for(beamwidth_3db_deg: float, attrs: dict | None) -> float:
    """Two-way 3 dB width of a cube's antenna: its ``/antenna`` attributes when they name a two-beam
    design, else two Gaussian beams crossing at -3 dB with that sum beamwidth (never a default squint)."""
    a = attrs or {}
    try:
        if a.get("pattern", "gaussian2") in ("gaussian2", "sinc2") and np.isfinite(float(a.get("squint_deg", np.nan))):
            return _two_way_width(float(beamwidth_3db_deg), float(a["squint_deg"]), str(a.get("pattern", "gaussian2")))
    except (AntennaDesignError, TypeError, ValueError):
        pass
    return _two_way_width(float(beamwidth_3db_deg), None, "gaussian2")


@functools.lru_cache(maxsize=64)
def _two_way_width(beamwidth_3db_deg: float, squint_deg, pattern: str) -> float:
    """The two-way width of one design, found once (a root search of 4 ms: the chain's outputs and the
    dwell imaging ask for the same design in every run)."""
    if squint_deg is None:
        return MonopulseAntenna(beamwidth_3db_deg).two_way_3db_width_deg()
    return MonopulseAntenna(beamwidth_3db_deg, squint_deg, pattern=pattern).two_way_3db_width_deg()
