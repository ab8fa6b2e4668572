"""Scanning amplitude-comparison monopulse antenna: two squinted Gaussian beams.

Each beam's one-way voltage pattern is ``g_pm(d) = exp(-beta (d -+ s)^2)`` in the angle offset ``d``
(degrees, ground-plane azimuth minus beam pointing angle) with squint ``s``.  The sum and difference
patterns, normalised so that the sum is 1 on boresight, are

    Sigma(d) = exp(-beta d^2) cosh(2 beta s d),      Delta(d) = exp(-beta d^2) sinh(2 beta s d),

so the monopulse ratio is exactly ``Delta/Sigma = tanh(k d)`` with slope ``k = 2 beta s`` per degree
(NOTES.md: not linear; the inverse ``atanh(r)/k`` is exact).  ``beta`` is solved so that the SUM
beam's one-way 3 dB width equals the scenario beamwidth; the two-way (transmit on sum, receive on
sum) 3 dB width is then about beamwidth/sqrt(2) (4.24 deg for the paper's 6 deg).  The transmitted
pattern is the sum beam, so the echo gains are ``Sigma^2`` (sum channel) and ``Sigma Delta``
(difference channel), and Re(diff/sum) > 0 for a target towards +x of the beam axis (CONTRACT.md 3).
The elevation pattern is taken as flat: the scene spans a fraction of a degree in depression.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import brentq


def _solve_beta(beamwidth_3db_deg: float, squint_deg: float) -> float:
    half = beamwidth_3db_deg / 2.0
    beta_max = 1.0 / (2.0 * squint_deg**2)  # beyond it the sum beam has a dip on boresight

    def excess(beta):  # log one-way sum power at the half-beamwidth, plus 3 dB
        return 2.0 * (-beta * half**2 + np.log(np.cosh(2.0 * beta * squint_deg * half))) + np.log(2.0)

    hi = beta_max * (1.0 - 1e-9)
    if excess(hi) >= 0.0:
        raise ValueError(f"too large for a {beamwidth_3db_deg:g} deg sum beam (two Gaussian beams "
                         f"this far apart cannot give it); allowed: below about "
                         f"{0.25 * beamwidth_3db_deg:.2f} deg")
    return brentq(excess, 1e-12, hi, xtol=1e-15, rtol=1e-14)


@dataclass(frozen=True)
class MonopulseAntenna:
    """Two squinted Gaussian beams forming sum and difference patterns (angles in degrees)."""

    beamwidth_3db_deg: float
    squint_deg: float
    beta_per_deg2: float = field(init=False)

    def __post_init__(self):
        object.__setattr__(self, "beta_per_deg2", _solve_beta(self.beamwidth_3db_deg, self.squint_deg))

    @property
    def slope_per_deg(self) -> float:
        """Monopulse slope k: Delta/Sigma = tanh(k d), so k = d(ratio)/d(angle) on boresight."""
        return 2.0 * self.beta_per_deg2 * self.squint_deg

    def sum_voltage(self, offset_deg):
        d = np.asarray(offset_deg, dtype=np.float64)
        return np.exp(-self.beta_per_deg2 * d**2) * np.cosh(self.slope_per_deg * d)

    def diff_voltage(self, offset_deg):
        d = np.asarray(offset_deg, dtype=np.float64)
        return np.exp(-self.beta_per_deg2 * d**2) * np.sinh(self.slope_per_deg * d)

    def two_way_gains(self, offset_deg):
        """(sum, difference) echo amplitude gains: Sigma^2 and Sigma*Delta."""
        s = self.sum_voltage(offset_deg)
        return s * s, s * self.diff_voltage(offset_deg)

    def ratio_to_offset_deg(self, ratio, max_ratio: float = 0.999):
        """Exact inverse of the monopulse ratio: d = atanh(Re(diff/sum)) / k (ratio clipped)."""
        r = np.clip(np.asarray(ratio, dtype=np.float64), -max_ratio, max_ratio)
        return np.arctanh(r) / self.slope_per_deg

    def two_way_3db_width_deg(self) -> float:
        """Two-way (sum^2 power) 3 dB width: the real-beam image's angular resolution."""
        f = lambda d: 4.0 * np.log(self.sum_voltage(d)) + np.log(2.0)  # noqa: E731
        return 2.0 * brentq(f, 0.0, self.beamwidth_3db_deg)
