"""Overlapping Allan variance of rate sensors, and the noise read off it as Kalibr does.

The rates of one contiguous stretch are integrated once (a cumulative sum: the phase),
and the Allan variance at averaging factor m is the mean square of the phase's second
differences m samples apart, over every start (overlapping). Stretches are never joined
across a gap: each adds its own sums of squares and term counts, and the variance is
their ratio over all of them, so a recording cut by cable pulls loses only the terms
that would have spanned a cut. The differences are taken in blocks of rows that stay in
cache, so memory is the phase alone (one float64 per sample and column).

The read-off follows Kalibr's wiki: the white noise density N is where the line of
slope -1/2 that the curve follows at short averaging times crosses tau = 1 s, and the
bias random walk K where the line of slope +1/2 it follows at long times crosses
tau = 3 s, both in continuous-time units (not divided by the root of the sample
period). The two lines are placed by fitting sigma^2 = N^2/tau + B0^2 + K^2 tau/3 (white
noise, a flat floor, random walk; each term non-negative) to the whole curve, each point
weighted by how many independent averages it holds; reading N^2/tau at tau = 1 s and
K^2 tau/3 at tau = 3 s then gives N and K. Reading the white noise at the curve's
minimum instead (as imu_utils does) mixes in the other terms.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = ["AllanSums", "NoiseFit", "averaging_factors", "read_off"]

FloatArray = npt.NDArray[np.float64]

#: Averaging times per decade at which the deviation is computed.
POINTS_PER_DECADE = 10
#: The flat floor of flicker (bias instability) B sits at this times B (IEEE Std 952).
FLICKER_FLOOR = math.sqrt(2.0 * math.log(2.0) / math.pi)
#: Points of the curve a fit uses: averages of at least this many samples (shorter
#: ones see the unit's own filter) and at least this many independent averages.
MIN_FACTOR = 4
MIN_AVERAGES = 4.0
#: Neighbouring points of the curve share most of their averages: the fit's variances,
#: computed as if they were independent, are scaled up by this (found on emulated
#: random walks: the spread of K over seeds).
_SHARED = 12.0
_BLOCK_ROWS = 1 << 14  # rows of one block of differences: 14 columns of them fit in cache


def averaging_factors(longest: int, per_decade: int = POINTS_PER_DECADE) -> npt.NDArray[np.int64]:
    """Averaging factors m, log-spaced from 1 to a quarter of the longest stretch.

    Args:
        longest: Samples in the longest contiguous stretch.
        per_decade: Factors per decade of averaging time.

    Returns:
        The distinct factors, ascending (just 1 for a stretch of under 8 samples).
    """
    top = max(longest // 4, 1)
    count = int(math.log10(top) * per_decade) + 1
    factors: npt.NDArray[np.int64] = np.unique(
        np.round(np.logspace(0.0, math.log10(top), max(count, 1))).astype(np.int64))
    return factors


class AllanSums:
    """Sums of squared second differences per averaging factor, over stretches.

    Args:
        factors: The averaging factors m (``averaging_factors``).
        columns: The series per sample (each axis of each sensor).
    """

    def __init__(self, factors: npt.NDArray[np.int64], columns: int) -> None:
        self.factors = factors
        self.sums = np.zeros((len(factors), columns))
        self.counts = np.zeros(len(factors), np.int64)
        self.samples = 0

    def add(self, rates: npt.ArrayLike) -> None:
        """One contiguous stretch of rates, evenly spaced, no sample missing.

        Args:
            rates: (n, columns), in any unit; the variance comes out in its square.
        """
        y = np.asarray(rates, np.float64)
        n = len(y)
        self.samples += n
        phase = np.zeros((n + 1, y.shape[1]))
        np.cumsum(y, axis=0, out=phase[1:])
        # the stretch's mean changes no second difference: taken out, the phase stays small
        steps = np.arange(n + 1, dtype=np.float64)
        for column, mean in enumerate(y.mean(axis=0).tolist()):
            phase[:, column] -= steps * mean
        del steps
        block = np.empty((_BLOCK_ROWS, y.shape[1]))
        for j, m in enumerate(self.factors.tolist()):
            terms = n + 1 - 2 * m
            if terms <= 0:
                break
            total = np.zeros(y.shape[1])
            for a in range(0, terms, _BLOCK_ROWS):
                b = min(a + _BLOCK_ROWS, terms)
                d = block[: b - a]
                np.multiply(phase[a + m : b + m], -2.0, out=d)
                d += phase[a + 2 * m : b + 2 * m]
                d += phase[a:b]
                total += np.einsum("ij,ij->j", d, d)
            self.sums[j] += total
            self.counts[j] += terms

    def variance(self) -> FloatArray:
        """The Allan variance per factor and column; NaN where no stretch was long enough.

        Returns:
            (factors, columns), the rates' unit squared.
        """
        m = self.factors.astype(np.float64)[:, None]
        with np.errstate(invalid="ignore", divide="ignore"):
            out: FloatArray = self.sums / (2.0 * m * m * self.counts[:, None])
        return out

    def averages(self) -> FloatArray:
        """Independent averages behind each factor's variance (terms over m).

        Returns:
            One per factor.
        """
        out: FloatArray = self.counts / self.factors.astype(np.float64)
        return out


@dataclass(frozen=True)
class NoiseFit:
    """What one axis's Allan curve gives.

    Attributes:
        noise_density: N, the -1/2 slope line at tau = 1 s (unit/√Hz).
        random_walk: K, the +1/2 slope line at tau = 3 s (unit/s/√Hz); an upper bound
            when ``walk_bound``.
        random_walk_sigma: K's one-sigma statistical uncertainty (0 for a bound).
        walk_bound: No +1/2 slope in the curve: K is the steepest +1/2 line that stays
            under every point, an upper bound.
        bias_instability: The flat minimum of the deviation over ``FLICKER_FLOOR``.
        bias_instability_tau: Where that minimum is, s.
    """

    noise_density: float
    random_walk: float
    random_walk_sigma: float
    walk_bound: bool
    bias_instability: float
    bias_instability_tau: float


def _solve(design: FloatArray, weights: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The non-negative least-squares coefficients of design @ c = 1 and their covariance.

    Three coefficients: every subset is tried, and the best one whose coefficients are
    all non-negative wins (the exact non-negative solution).
    """
    best: tuple[float, FloatArray, FloatArray] | None = None
    root = np.sqrt(weights)[:, None]
    for size in (1, 2, 3):
        for subset in itertools.combinations(range(design.shape[1]), size):
            a = design[:, subset] * root
            coef, *_ = np.linalg.lstsq(a, root[:, 0], rcond=None)
            if (coef < 0).any():
                continue
            residual = float(np.sum((a @ coef - root[:, 0]) ** 2))
            if best is None or residual < best[0]:
                full = np.zeros(design.shape[1])
                full[list(subset)] = coef
                cov = np.zeros((design.shape[1], design.shape[1]))
                cov[np.ix_(subset, subset)] = np.linalg.pinv(a.T @ a)
                best = (residual, full, cov)
    if best is None:  # only a zero curve: nothing to fit
        return np.zeros(design.shape[1]), np.zeros((design.shape[1], design.shape[1]))
    return best[1], best[2]


def read_off(tau: npt.ArrayLike, avar: npt.ArrayLike, averages: npt.ArrayLike,
             period: float) -> NoiseFit:
    """N and K of one axis read off its Allan variance as Kalibr's wiki has it.

    Args:
        tau: Averaging times, s (m times the sample period).
        avar: The Allan variance at each (NaN: not computed).
        averages: Independent averages behind each (``AllanSums.averages``).
        period: The sample period, s.

    Returns:
        The noise terms, in the rate's unit per √Hz (N) and per s per √Hz (K).
    """
    tau, avar = np.asarray(tau, np.float64), np.asarray(avar, np.float64)
    count = np.asarray(averages, np.float64)
    use = (np.isfinite(avar) & (avar > 0) & (count >= MIN_AVERAGES)
           & (tau >= MIN_FACTOR * period * (1 - 1e-9)))
    if not use.any():  # too short for MIN_FACTOR averages: every point it has
        use = np.isfinite(avar) & (avar > 0)
    t, v, w = tau[use], avar[use], count[use]
    if not len(t):
        return NoiseFit(0.0, 0.0, 0.0, True, 0.0, 0.0)
    # each point's relative variance is about 2 / (its independent averages)
    design = np.column_stack([1.0 / t, np.ones_like(t), t]) / v[:, None]
    coef, cov = _solve(design, w / 2.0)
    white, _, walk = coef
    deviation = np.sqrt(v)
    low = int(np.argmin(deviation))
    bound = walk <= 0.0
    if bound:
        k = float(np.min(np.sqrt(3.0 * v / t)))
        sigma = 0.0
    else:
        k = math.sqrt(3.0 * walk)
        sigma = 1.5 * math.sqrt(max(cov[2, 2], 0.0) * _SHARED) / k
    return NoiseFit(noise_density=math.sqrt(max(white, 0.0)), random_walk=k,
                    random_walk_sigma=sigma, walk_bound=bool(bound),
                    bias_instability=float(deviation[low]) / FLICKER_FLOOR,
                    bias_instability_tau=float(t[low]))
