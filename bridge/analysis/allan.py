"""Overlapping Allan variance of rate sensors, and the noise read off it as Kalibr does.

The rates of one contiguous stretch are integrated once per axis (a cumulative sum: the
phase), and the Allan variance at averaging factor m is the mean square of the phase's
second differences m samples apart, over starts at most m/16 apart (every start up to
m = 31): neighbouring starts' terms share all but 1/16 of their samples, and dropping
them leaves the estimate as precise as every start (to 1 % on white noise) at a fifth
of the cost. Stretches are never joined across a gap: each adds its own sums of squares
and term counts, and the variance is their ratio over all of them, so a recording cut
by cable pulls loses only the terms that would have spanned a cut. The differences are
taken in blocks that stay in cache, so memory is one axis's phase (one float64 a sample).

The read-off follows Kalibr's wiki: the white noise density N is where the line of
slope -1/2 that the curve follows at short averaging times crosses tau = 1 s, and the
bias random walk K where the line of slope +1/2 it follows at long times crosses
tau = 3 s, both in continuous-time units (not divided by the root of the sample
period). A GX3's samples are not white, though: the unit averages M calculation cycles
(its filter width) and sends every D-th (its decimation), so at averaging times of a
few samples the curve lies far below N²/tau, and where D > M its samples leave cycles
out and lie above it (``white_variance`` is the exact curve, per N², of the sensor's
white noise through that chain). The fit therefore models sigma^2 = N^2 w(tau) + B0^2 +
K^2 tau/3 (white noise through the chain, a flat floor, random walk; each term
non-negative) over averaging times from ``fit_start`` on, ten times the span of the
chain (M + D cycles) and clear of the analog filters ahead of it, each point weighted
by how many independent averages it holds; N and K are the sensor's own, whatever the
rate and width they were measured at. Reading the white noise at the curve's minimum
instead (as imu_utils does) mixes in the other terms.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = ["AllanSums", "NoiseFit", "averaging_factors", "fit_start", "read_off",
           "white_variance"]

FloatArray = npt.NDArray[np.float64]

#: Averaging times per decade at which the deviation is computed.
POINTS_PER_DECADE = 10
#: The flat floor of flicker (bias instability) B sits at this times B (IEEE Std 952).
FLICKER_FLOOR = math.sqrt(2.0 * math.log(2.0) / math.pi)
#: Points of the curve a fit uses: averages of at least this many samples, at least
#: this many independent averages, and averaging times from ``fit_start`` on.
MIN_FACTOR = 4
MIN_AVERAGES = 4.0
#: The fit starts this many times the chain's span (M + D calculation cycles) on ...
SPANS_BEFORE_FIT = 10
#: ... and not before this, s: the analog anti-alias filters ahead of the ADC (226 Hz
#: and up, not in the model) then change the variance by under 1 %.
MIN_FIT_TAU_S = 0.05
#: Neighbouring points of the curve share most of their averages: the fit's variances,
#: computed as if they were independent, are scaled up by this (found on emulated
#: random walks: the spread of K over seeds).
_SHARED = 12.0
#: Starts of the second differences at averaging factor m are max(1, m // this) apart.
START_STEP = 16
CYCLES_PER_S = 1000.0  # calculation cycles a second: the filter's sample rate
_BLOCK = 1 << 16  # terms of one block of differences: a few arrays of them fit in cache


def white_variance(factors: npt.ArrayLike, width: int, decimation: int) -> FloatArray:
    """The Allan variance of white sensor noise of density 1 through a GX3's filter.

    Each calculation cycle's sample holds 1000 Hz of variance per unit density (the
    fixed first stage's mean over the cycle), the unit averages the last M of them and
    sends every D-th: a record's noise is (1/M) times the sum of its M cycles. The
    difference of two adjacent means of m records weighs each cycle by how many of
    their records hold it; the sum of those weights' squares is sum_j r(j) (M - |j|D)
    over the lags |j| D < M at which two records share cycles, r(j) being the lag-j
    autocorrelation of the m records' -1 and m records' +1 (2m - 3|j| up to m, |j| - 2m
    beyond). At long averaging times it tends to 1/tau where D divides M, and to
    (D/M)/tau where D > M (the samples miss D - M of every D cycles).

    Args:
        factors: Averaging factors m, in records.
        width: M, the filter width (1 to 32).
        decimation: D, cycles per record.

    Returns:
        The variance per N², (unit/√Hz)⁻² times the rate's unit squared, per factor.
    """
    out = []
    for m in np.asarray(factors, np.int64).tolist():
        lags = np.arange(-min(2 * m, (width - 1) // decimation),
                         min(2 * m, (width - 1) // decimation) + 1)
        j = np.abs(lags)
        shared = np.where(j <= m, 2 * m - 3 * j, j - 2 * m) * (width - j * decimation)
        out.append(0.5 * CYCLES_PER_S * float(shared.sum()) / (m * width) ** 2)
    return np.array(out)


def fit_start(width: int, decimation: int) -> float:
    """Where the fit of a unit's curve starts: ``SPANS_BEFORE_FIT`` times its chain's span.

    The chain (M cycles averaged, every D-th sent) shapes the curve up to a few times
    M + D cycles; ``white_variance`` models that exactly, and starting well past it
    keeps what the model leaves out (the analog filters, a unit's own departures) out
    of the read-off too.

    Args:
        width: M, the filter width.
        decimation: D, cycles per record.

    Returns:
        The shortest averaging time fitted, s: at least ``MIN_FIT_TAU_S`` and
        ``MIN_FACTOR`` records.
    """
    return max(SPANS_BEFORE_FIT * (width + decimation) / CYCLES_PER_S, MIN_FIT_TAU_S,
               MIN_FACTOR * decimation / CYCLES_PER_S)


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
        self.terms = np.zeros(len(factors), np.int64)
        self.samples = 0

    def add(self, *parts: npt.ArrayLike) -> None:
        """One contiguous stretch of rates, evenly spaced, no sample missing.

        Args:
            parts: (n, k) arrays whose columns, in order, are the series: in any unit
                (float32 is summed as float64); the variance comes out in its square.
        """
        columns = [np.asarray(part)[:, i] for part in parts
                   for i in range(np.asarray(part).shape[1])]
        n = len(columns[0])
        self.samples += n
        phase = np.empty(n + 1)
        phase[0] = 0.0
        for column, values in enumerate(columns):
            # the stretch's mean changes no second difference: taken out, the phase stays
            # small
            np.subtract(values, np.mean(values, dtype=np.float64), out=phase[1:],
                        dtype=np.float64)
            np.cumsum(phase[1:], out=phase[1:])
            for j, m in enumerate(self.factors.tolist()):
                terms = n + 1 - 2 * m
                if terms <= 0:
                    break
                step = max(1, m // START_STEP)
                self.sums[j, column] += _squares(phase, m, terms, step)
                if not column:
                    self.counts[j] += len(range(0, terms, step))
                    self.terms[j] += terms

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
        """Independent averages behind each factor's variance (every start's terms over m).

        Returns:
            One per factor.
        """
        out: FloatArray = self.terms / self.factors.astype(np.float64)
        return out


def _squares(phase: FloatArray, m: int, terms: int, step: int) -> float:
    """The sum of squared second differences m apart of ``phase``, from every step-th start.

    Taken in blocks that stay in cache.
    """
    total = 0.0
    block = np.empty(_BLOCK)
    for a in range(0, terms, _BLOCK * step):
        b = min(a + _BLOCK * step, terms)
        d = block[: len(range(a, b, step))]
        np.multiply(phase[a + m : b + m : step], -2.0, out=d)
        d += phase[a + 2 * m : b + 2 * m : step]
        d += phase[a:b:step]
        total += float(np.einsum("i,i->", d, d))
    return total


@dataclass(frozen=True)
class NoiseFit:
    """What one axis's Allan curve gives.

    Attributes:
        noise_density: N, the sensor's white noise density: the -1/2 slope line at
            tau = 1 s (unit/√Hz); 0 when the curve shows no white noise.
        random_walk: K, the +1/2 slope line at tau = 3 s (unit/s/√Hz); an upper bound
            when ``walk_bound``.
        random_walk_sigma: K's one-sigma statistical uncertainty (0 for a bound).
        walk_bound: No +1/2 slope in the curve: K is the steepest +1/2 line that stays
            under every point of the curve, an upper bound.
        bias_instability: The flat minimum of the deviation over ``FLICKER_FLOOR``.
        bias_instability_tau: Where that minimum is, s.
        fit_tau: The shortest and longest averaging times fitted, s.
    """

    noise_density: float
    random_walk: float
    random_walk_sigma: float
    walk_bound: bool
    bias_instability: float
    bias_instability_tau: float
    fit_tau: tuple[float, float]


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
             white: npt.ArrayLike, start: float) -> NoiseFit:
    """N and K of one axis read off its Allan variance as Kalibr's wiki has it.

    Args:
        tau: Averaging times, s (m times the sample period).
        avar: The Allan variance at each (NaN: not computed).
        averages: Independent averages behind each (``AllanSums.averages``).
        white: The variance white noise of density 1 gives at each through the unit's
            filter (``white_variance``).
        start: The shortest averaging time to fit (``fit_start``); a curve that ends
            before it is fitted whole.

    Returns:
        The noise terms, in the rate's unit per √Hz (N) and per s per √Hz (K).
    """
    tau, avar = np.asarray(tau, np.float64), np.asarray(avar, np.float64)
    count, white = np.asarray(averages, np.float64), np.asarray(white, np.float64)
    shown = np.isfinite(avar) & (avar > 0)
    use = shown & (count >= MIN_AVERAGES) & (tau >= start * (1 - 1e-9))
    if not use.any():  # too short to reach the fit's start: every point it has
        use = shown
    t, v, w = tau[use], avar[use], count[use]
    if not len(t):
        return NoiseFit(0.0, 0.0, 0.0, True, 0.0, 0.0, (0.0, 0.0))
    # each point's relative variance is about 2 / (its independent averages)
    design = np.column_stack([white[use], np.ones_like(t), t]) / v[:, None]
    coef, cov = _solve(design, w / 2.0)
    density, _, walk = coef
    deviation = np.sqrt(v)
    low = int(np.argmin(deviation))
    bound = walk <= 0.0
    if bound:  # under every point drawn, not only those fitted
        k = float(np.min(np.sqrt(3.0 * avar[shown] / tau[shown])))
        sigma = 0.0
    else:
        k = math.sqrt(3.0 * walk)
        sigma = 1.5 * math.sqrt(max(cov[2, 2], 0.0) * _SHARED) / k
    return NoiseFit(noise_density=math.sqrt(max(density, 0.0)), random_walk=k,
                    random_walk_sigma=sigma, walk_bound=bool(bound),
                    bias_instability=float(deviation[low]) / FLICKER_FLOOR,
                    bias_instability_tau=float(t[low]), fit_tau=(float(t[0]), float(t[-1])))
