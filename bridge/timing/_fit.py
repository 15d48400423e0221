"""The line fits of the clocks: lower envelopes, the USB frame grid, the bounds' polygon.

Shared by ``OnlineClock`` (``bridge.timing.clock``) and ``OfflineClock``
(``bridge.timing.offline``), so that both fit one way. A record's bounds are its ticks
and when it was on the line by, or not yet (host ns); the lines here pass between them,
or lie under the upper ones where there are no others. The geometry (the lower hull,
the frame grid, the polygon of the lines the bounds allow): docs/design/time.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from bridge.protocol.table import TICKS_PER_SECOND

MAX_PPM = 500.0  # the manual promises +-100 ppm; searched well beyond that
_MAX_STEPS = 32  # passes a search may take; a few find the answer, rounding may want more
_START_PPM = 2.0  # the first bracket around the last fit's rate
GRID_BIN_NS = 1_000
_PINNED_NS = 100_000  # a polygon this narrow at the newest record needs no longer window
FRAME_DOUBT_NS = 10_000  # how far a frame boundary may be from where the reads put it
NO_BOUND = -(2**62)  # a record with no lower bound
BUCKET_TICKS = TICKS_PER_SECOND // 4
_GRID_GUARD_NS = 25_000  # residuals this close to a frame are not trusted as same-frame


def uncovered_half(residual: np.ndarray, frame: int) -> float:
    """Half the frame that snapped points above a lower-envelope line leave uncovered.

    The true line is under every snapped point and less than a frame under it; where
    the unit's phase has swept the frame the residuals cover it and the envelope is
    the line, where it has not the line is somewhere in the gap: take off half.
    Residuals within a guard of a whole frame may be reads a frame late.
    """
    same = residual[residual < frame - _GRID_GUARD_NS]
    return (frame - float(same.max())) / 2 if len(same) else 0.0


def grid_histogram(y: np.ndarray, frame: int) -> np.ndarray:
    """Receive times folded onto one frame, in 1 us bins."""
    return np.bincount((y % frame) // GRID_BIN_NS, minlength=max(1, frame // GRID_BIN_NS))


def grid_phase(histogram: np.ndarray, frame: int) -> int:
    """Where in the frame the boundary lies, from the receive times folded onto it.

    It is the edge the times lie least far after: no read comes before the frame that
    carried its bytes. Their total distance after bin edge e is sum(h c) - e sum(h) +
    frame (the times in bins before e); the first term is the same for every edge and
    left out.
    """
    h = np.asarray(histogram, np.float64)
    cost = frame * (np.cumsum(h) - h) - float(h.sum()) * GRID_BIN_NS * np.arange(len(h))
    return int(np.argmin(cost)) * GRID_BIN_NS


def frame_after(y: np.ndarray, edge: int, frame: int) -> np.ndarray:
    """No earlier than the frame boundary that delivered reads received at ``y``.

    Boundaries lie at ``edge`` + k ``frame``, known to ``FRAME_DOUBT_NS``: a read within
    that of the next boundary may have been delivered by it. An upper bound on when the
    read's bytes were on the line.
    """
    d = FRAME_DOUBT_NS
    return np.asarray(edge + (y - edge + d) // frame * frame + d)


def frame_before(y: np.ndarray, edge: int, frame: int) -> np.ndarray:
    """No later than the frame boundary that delivered reads received at ``y``.

    A read within ``FRAME_DOUBT_NS`` after a boundary may have been delivered by the one
    before. A lower bound on when the bytes the read did not hold were still to come.
    """
    d = FRAME_DOUBT_NS
    return np.asarray(edge + (y - edge - d) // frame * frame - d)


def bucket_minima(x: np.ndarray, y: np.ndarray, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """The earliest-received point of each short stretch of ticks.

    Within a quarter second the unit's phase against the frame grid barely moves,
    so the point nearest the line is one that was read in the frame that carried
    it: a lower bound on the line as well as an upper one. The stretches at the
    ends of ``x`` are partial and left out.
    """
    if not len(x):
        return x, y
    lows = bucket_lows(x, y, rate)
    buckets = x[lows] // BUCKET_TICKS
    lows = lows[(buckets > x[0] // BUCKET_TICKS) & (buckets < x[-1] // BUCKET_TICKS)]
    return x[lows], y[lows]


def bucket_lows(x: np.ndarray, y: np.ndarray, rate: float) -> np.ndarray:
    """Index of the point least above a line of slope ``rate`` in each quarter second of ticks.

    The first on a tie, for every stretch ``x`` touches, in order.
    """
    v = (y - y[0]).astype(np.float64) - rate * (x - x[0]).astype(np.float64)
    buckets = x // BUCKET_TICKS
    starts = np.concatenate(([0], np.flatnonzero(buckets[1:] != buckets[:-1]) + 1))
    sizes = np.diff(np.concatenate((starts, [len(v)])))
    lowest = np.flatnonzero(v == np.repeat(np.minimum.reduceat(v, starts), sizes))
    kb = buckets[lowest]
    return lowest[np.concatenate(([True], kb[1:] != kb[:-1]))]


@dataclass(frozen=True)
class Bounds:
    """Points a line of the unit's clock passes between, as ticks and host ns.

    The line lies not above any upper point (``xh``, ``yh``: a record was on the line by
    then) and above every lower point (``xl``, ``yl``: it was not yet). Each pair is
    sorted by ticks.
    """

    xh: np.ndarray
    yh: np.ndarray
    xl: np.ndarray
    yl: np.ndarray

    def between(self, start: int, end: int) -> Bounds:
        """The points with ticks in [start, end)."""
        h = np.searchsorted(self.xh, [start, end])
        ll = np.searchsorted(self.xl, [start, end])
        return Bounds(self.xh[h[0]:h[1]], self.yh[h[0]:h[1]], self.xl[ll[0]:ll[1]],
                      self.yl[ll[0]:ll[1]])


def framed_bounds(xh: np.ndarray, yh: np.ndarray, xl: np.ndarray, yl: np.ndarray,
                  frame: int) -> Bounds:
    """The bounds of records read over frames that carry every byte ready when polled.

    ``xh``, ``yh``: each quarter second's tightest upper bound; ``xl``, ``yl``: its
    tightest lower bound where it has one. Below each tightest upper bound a frame (and
    the frames' doubt either side) is a lower bound too: the record read soonest after
    the frame that carried it came within a frame of it.
    """
    xs = np.concatenate([xl, xh])
    ys = np.concatenate([yl, yh - frame - 2 * FRAME_DOUBT_NS])
    order = np.argsort(xs, kind="stable")
    return Bounds(xh, yh, xs[order], ys[order])


class Centre(NamedTuple):
    """The middle of every line some bounds allow, judged at ticks ``at``.

    ``value``: host ns there; ``rate``: the middle of the slopes allowed (ns per tick);
    ``extent``: how far apart the highest and lowest allowed lines are there (ns), the
    honest doubt of ``value`` (twice its most error); ``rates``: the spread of the
    slopes allowed.
    """

    at: int
    value: int
    rate: float
    extent: float
    rates: float


def best_centre(bounds: Bounds, at: int, prior: float, spans: list[tuple[int, int]],
                ppm: float = MAX_PPM) -> Centre | None:
    """``polygon_centre`` over the shortest span of ticks that pins the line at ``at``.

    ``spans`` are [start, end) ranges of ticks, shortest first; where none pins the line,
    the one that pins it best. A unit whose phase sweeps the frame is pinned by a short
    span, which wander bends least; a unit that beats slowly needs a long one. Slopes are
    searched within ``ppm`` of ``prior``.
    """
    best: Centre | None = None
    for start, end in spans:
        found = polygon_centre(bounds.between(start, end), at, prior, ppm)
        if found is not None and (best is None or found.extent < best.extent):
            best = found
        if best is not None and best.extent < _PINNED_NS:
            break
    return best


def polygon_centre(bounds: Bounds, now: int, prior: float,
                   ppm: float = MAX_PPM) -> Centre | None:
    """The middle of every straight line that passes between ``bounds``, judged at ``now``.

    When one straight line can pass between all the points, the lines that do form a
    polygon in (offset, slope); its extent at ``now`` is the honest uncertainty there and
    its middle the estimate. Where the points come from frames alone, a unit that has
    never crossed a frame boundary leaves half a frame of doubt, narrowing with every
    crossing; reads that end inside records pin it to a byte time. When no straight line
    fits (the rate wandered within the span), or nothing bounds it from one side, None.

    Every search is over a piecewise-linear function of the slope r, convex or concave:
    each step follows the linear piece it stands on to where that piece would give the
    answer, so a few passes over the points find it exactly.
    """
    b = bounds
    if len(b.xh) < 2 or len(b.xl) < 2:
        return None
    newest = int(b.yh[-1])
    # in integers first: ns since 1970 exceed float64's
    dxh, dyh = (b.xh - now).astype(np.float64), (b.yh - newest).astype(np.float64)
    dxl, dyl = (b.xl - now).astype(np.float64), (b.yl - newest).astype(np.float64)
    band = _Band(dxh, dyh, dxl, dyl)
    lo, hi = prior * (1 - ppm * 1e-6), prior * (1 + ppm * 1e-6)
    best = band.narrowest(lo, hi)
    if band.width(best)[0] > band.tie(best):
        return None
    low_rate, high_rate = band.reach(best, lo, 0.0), band.reach(best, hi, 0.0)
    r_top, _ = _peak(dxh, dyh, low_rate, high_rate, band.ranges)
    r_bottom, _ = _peak(-dxl, -dyl, low_rate, high_rate, band.ranges)
    top = float((dyh - r_top * dxh).min())
    bottom = float((dyl - r_bottom * dxl).max())
    return Centre(now, newest + round((top + bottom) / 2), (low_rate + high_rate) / 2,
                  top - bottom, high_rate - low_rate)


class _Band:
    """How far the lower points rise above the upper ones for a line of slope r.

    ``max(yl - r xl) - min(yh - r xh)``, a convex function of r: a line of slope r passes
    between the points where it is not above 0. And the linear piece of it at each r
    (its value and slope there).
    """

    def __init__(self, dxh: np.ndarray, dyh: np.ndarray, dxl: np.ndarray,
                 dyl: np.ndarray) -> None:
        self.dxh, self.dyh, self.dxl, self.dyl = dxh, dyh, dxl, dyl
        self._vh = np.empty_like(dyh)
        self._vl = np.empty_like(dyl)
        (xh, yh), (xl, yl) = _ranges(dxh, dyh), _ranges(dxl, dyl)
        self.ranges = (max(xh, xl), max(yh, yl))

    def tie(self, r: float) -> float:
        return _tie(self.ranges, r)

    def width(self, r: float) -> tuple[float, float]:
        vh, vl = self._vh, self._vl
        np.multiply(r, self.dxh, out=vh)
        np.subtract(self.dyh, vh, out=vh)
        np.multiply(r, self.dxl, out=vl)
        np.subtract(self.dyl, vl, out=vl)
        under, over = int(vh.argmin()), int(vl.argmax())
        return float(vl[over] - vh[under]), float(self.dxh[under] - self.dxl[over])

    def narrowest(self, lo: float, hi: float) -> float:
        """The r in [lo, hi] where the width is least.

        That is where the lines of the pieces on either side of it cross, unless a piece
        there is higher.
        """
        w_lo, s_lo = self.width(lo)
        w_hi, s_hi = self.width(hi)
        if s_lo >= 0:
            return lo
        if s_hi <= 0:
            return hi
        for _ in range(_MAX_STEPS):
            r = (w_hi - w_lo + s_lo * lo - s_hi * hi) / (s_lo - s_hi)
            if not lo < r < hi:  # the pieces at the ends meet at (or past) one of them
                return hi if r >= hi else lo
            w, s = self.width(r)
            if w - (w_lo + s_lo * (r - lo)) <= self.tie(r) or s == 0:
                return r
            if s > 0:
                hi, w_hi, s_hi = r, w, s
            else:
                lo, w_lo, s_lo = r, w, s
        return (lo + hi) / 2

    def reach(self, inside: float, outside: float, level: float) -> float:
        """The r between ``inside`` (width <= level) and ``outside`` where the width is ``level``.

        ``outside`` if it never gets there. From the outside each piece's line lies under
        the convex width, so following it never overshoots.
        """
        r = outside
        w, s = self.width(r)
        for _ in range(_MAX_STEPS):
            if w <= level + self.tie(r) or s == 0:
                break
            step = r - (w - level) / s
            if not min(inside, r) <= step <= max(inside, r) or step == r:
                break
            r = step
            w, s = self.width(r)
        return r


def support_slope(dx: np.ndarray, dy: np.ndarray, prior: float) -> float:
    """The slope of the highest line under every point, judged at dx = 0.

    That is the lower hull's edge over dx = 0, clamped to ``MAX_PPM`` around ``prior``.
    The search starts a few ppm around ``prior`` (a refit's rate is close to the last
    one) and widens until the answer is inside.

    Args:
        dx: The points' ticks, less the ticks the slope is judged at.
        dy: Their host times, less a reference.
        prior: The last slope (ns per tick).

    Returns:
        The slope, ns per tick.
    """
    if not len(dx):
        return prior
    ppm = _START_PPM
    while True:
        r, inside = _peak(dx, dy, prior * (1 - ppm * 1e-6), prior * (1 + ppm * 1e-6))
        if inside or ppm >= MAX_PPM:
            return r
        ppm = min(MAX_PPM, ppm * 8)


def _ranges(dx: np.ndarray, dy: np.ndarray) -> tuple[float, float]:
    """The largest magnitudes of dx and dy, which bound float64's rounding of dy - r dx."""
    return float(np.abs(dx).max()), float(np.abs(dy).max())


def _tie(ranges: tuple[float, float], r: float) -> float:
    """float64 rounds dy - r dx by ~1e-16 of its magnitude: closer than this is a tie."""
    dx_range, dy_range = ranges
    return 1e-14 * (dy_range + abs(r) * dx_range)


def _peak(dx: np.ndarray, dy: np.ndarray, lo: float, hi: float,
          ranges: tuple[float, float] | None = None) -> tuple[float, bool]:
    """The r in [lo, hi] where ``min(dy - r dx)`` is highest, and whether it is inside.

    Inside: not at an end. ``ranges``: ``_ranges(dx, dy)`` when the caller has them.

    The function is concave; its peak is where the lowest point moves from one side
    of dx = 0 to the other. The line through the lowest points on either side is
    tried: if no point lies under it, its slope is the peak; otherwise the point
    under it replaces the one on its side. A few passes find the edge of thousands.
    """
    v = np.empty_like(dy)

    def lowest(r: float) -> int:
        np.multiply(r, dx, out=v)
        np.subtract(dy, v, out=v)
        return int(v.argmin())

    i, j = lowest(lo), lowest(hi)
    if dx[i] > 0:
        return lo, False  # falling from lo on
    if dx[j] <= 0:
        return hi, False  # still rising at hi
    tie = _tie(ranges or _ranges(dx, dy), max(abs(lo), abs(hi)))
    for _ in range(_MAX_STEPS):
        r = float((dy[j] - dy[i]) / (dx[j] - dx[i]))
        if not lo < r < hi:  # the pieces at the ends meet at (or past) one of them
            return (hi if r >= hi else lo), True
        k = lowest(r)
        if (dy[i] - r * dx[i]) - v[k] <= tie:
            return r, True
        if dx[k] > 0:
            j, hi = k, r
        else:
            i, lo = k, r
    return (lo + hi) / 2, True

