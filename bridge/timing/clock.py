"""Online estimate of the instant each record was sampled, on the host clock.

A record is received after it was sampled, never before: the host time of a read
is an upper bound on the sample instant of every record in it. On a serial line
the estimator keeps a sliding window of (ticks, receive time) points and fits
the line ``host = offset + rate * ticks`` that lies under all of them and is
highest mid-window (the lower convex hull's edge there), found by walking the
hull's edges from the last rate. Late points (OS latency, a burst after a stall) lie
above the line and do not move it; the window follows a rate that wanders.

USB adds a quantisation the hull cannot see through: bytes reach the host only
at the 1 ms frame boundaries of the host controller, so the lowest receive time
is up to a frame late, and for a unit whose clock beats slowly against the frame
clock it stays that late for minutes. The frame grid is found from the receive
times themselves (they crowd in just after each boundary) and each receive time
is snapped down to its frame. The earliest point of each quarter second was then
read in the frame that carried it, which bounds the line from both sides: not
above the point, less than one frame under it. The lines that meet every such
bound form a polygon; the estimate at the newest record is the middle of its
extent there. That is half a frame of honest doubt for a unit whose phase has
never crossed a frame boundary, and a few microseconds once crossings have been
seen. Wander bends long windows, so the shortest trailing window that pins the
line is used. When no straight line fits any of them, the slope comes from the
two latest corners of the frame staircase and half the frame the points have
not covered is taken off.

A read that ends inside a record bounds it too: over a serial line, the record
began no later than that read's time (snapped to its frame, where frames carry the
bytes) less the line time of the bytes it held, which pins the record to about a
byte time. Behind a USB-serial adapter whose reads often end mid-record the points
are then the line's to a byte, and the lower envelope of a minute of them (as on a
UART) replaces the polygon; where its packets end with records (a 16 ms latency
timer with records that divide its 62-byte packet) only the frames carry the time,
and the polygon stays. On the unit's own USB port (no ``serial``) they are left out:
only a record that straddles a frame boundary has one, and a bound that tight from
above, with none to match it from below, would pull the polygon's middle early.

Arithmetic is on integers and float64 in a fixed order, and the fit is redone
only at ticks-determined points, so the output depends on the records alone,
not on how they are split into ``update`` calls.
"""

from __future__ import annotations

import math
from bisect import bisect_left
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from bridge.protocol.table import TICKS_PER_SECOND
from bridge.timing.unwrap import NS_PER_TICK

_MAX_PPM = 500.0  # the manual promises +-100 ppm; searched well beyond that
_MAX_STEPS = 32  # passes a search may take; a few find the answer, rounding may want more
_START_PPM = 2.0  # the first bracket around the last fit's rate
_WARM_S = 10.0  # refit ten times a second until the window is this long
_GRID_BIN_NS = 1_000
_PINNED_NS = 100_000  # a polygon this narrow at the newest record needs no longer window
# How far the rate may have moved since it was last pinned: crystals drift a few
# ppm over minutes with temperature.
_RATE_FLOOR_PPM = 0.5
_PINNED_PPM = 0.5  # the rate counts as known when the allowed slopes are this close
_SLEW_PPM_S = 0.1
_GRID_MARGIN_NS = 100_000  # snap this much before the estimated frame boundary
_BUCKET_TICKS = TICKS_PER_SECOND // 4
# A serial line's window follows drift through the fit's midpoint; over USB the
# slope comes from recent staircase corners, and a long window lets a unit that
# beats slowly against the frame clock show two of them.
_LINE_WINDOW_S = 60.0
_FRAME_WINDOW_S = 300.0
_CHORD_TICKS = 20 * TICKS_PER_SECOND  # corners this far apart give the slope
_GRID_GUARD_NS = 25_000  # residuals this close to a frame are not trusted as same-frame
_GRID_DECAY = 0.99  # per refit: the frame grid may drift against the host clock
_PARTIAL_SHARE = 0.1  # of a window's records with a read ending inside: pinned to bytes
_SCALAR_RUN = 16  # records; shorter runs are cheaper in plain integers than in NumPy


@dataclass(frozen=True)
class ClockState:
    """The model for status: host minus nominal device time at the latest record, the
    device clock's rate error against the host's (ppm; positive: the unit's clock runs
    fast), the median latency above the fit, points used.
    """

    offset_ns: int
    drift_ppm: float
    spread_ns: int
    samples: int


@dataclass(frozen=True)
class _Line:
    x_ref: int  # ticks, absolute
    y_ref: int  # host ns, absolute
    rate: float  # ns per tick
    bias: float  # ns to take off (unresolved part of a USB frame)

    def at(self, ticks: np.ndarray) -> np.ndarray:
        dx = (ticks - self.x_ref).astype(np.float64)
        return self.y_ref + np.round(self.rate * dx - self.bias).astype(np.int64)

    def at_one(self, ticks: int) -> int:
        """``at`` of one record in plain numbers: the same float64 operations and
        round-half-to-even, so the same result without NumPy's cost per call.
        """
        return self.y_ref + round(self.rate * float(ticks - self.x_ref) - self.bias)

    def ticks_at(self, host: int) -> int:
        """The inverse of ``at``: the ticks the line puts at host instant ``host``."""
        return self.x_ref + math.floor((float(host - self.y_ref) + self.bias) / self.rate)


class OnlineClock:
    """Maps unwrapped ticks to host ns, one ``update`` per batch of valid records.

    ``filter_delay_ns``: the unit's moving-average delay, (M - 1) / 2 ms for filter
    width M. ``floor_ns``: the least time from sample to receive the transport
    allows (a UART's line time of the record, len * 10 / baud s; USB: len * 1 us).
    ``frame_ns``: the USB frame (1 ms) or 0 for a plain serial line. ``serial``: the
    bytes crossed a serial line before those frames (a USB-serial adapter): reads that
    end mid-record pin each record to about a byte time at every frame, so the lower
    envelope of the snapped points is the line, as on a plain serial line.

    Each record's point is the least upper bound on its sample instant that its reads
    give: the completing read's receive time (snapped to its frame) less ``floor_ns``,
    or, where ``update`` is given one, an earlier read that ended inside the record
    (snapped to its frame) less the line time of the bytes it held.
    """

    def __init__(self, filter_delay_ns: int = 0, floor_ns: int = 0, frame_ns: int = 0,
                 window_s: float | None = None, refit_s: float = 1.0,
                 serial: bool = False) -> None:
        if filter_delay_ns < 0 or floor_ns < 0 or frame_ns < 0:
            raise ValueError("filter_delay_ns, floor_ns and frame_ns must be >= 0")
        self.serial = serial
        if window_s is None:
            window_s = _FRAME_WINDOW_S if frame_ns else _LINE_WINDOW_S
        if window_s <= 0 or refit_s <= 0:
            raise ValueError("window_s and refit_s must be positive")
        self.filter_delay_ns = int(filter_delay_ns)
        self.floor_ns = int(floor_ns)
        self.frame_ns = int(frame_ns)
        self._window = round(window_s * TICKS_PER_SECOND)
        self._refit = round(refit_s * TICKS_PER_SECOND)
        bins = max(1, self.frame_ns // _GRID_BIN_NS)
        self._grid = np.zeros(bins if self.frame_ns else 0)
        self._rate = float(NS_PER_TICK)
        self._last_ns: int | None = None  # the latest instant given out
        #: When a list, each fit over the frame staircase adds (its ticks, the extent of
        #: the lines it allowed at them; inf when no straight line fitted): the doubt of
        #: the instants it gives out until the next fit.
        self.fits: list[tuple[int, float]] | None = None
        self.reset()

    def reset(self) -> None:
        """Start over after the tick base changed (device reset); keep rate and grid."""
        self._x = np.zeros(0, np.int64)
        self._y = np.zeros(0, np.int64)
        # with frames, each record's partial read: receive time less the floor, and the
        # line time of the bytes it did not hold (zero where there is none)
        self._q = np.zeros(0, np.int64)
        self._g = np.zeros(0, np.int64)
        self._new_x: list[int] = []
        self._new_y: list[int] = []
        self._new_q: list[int] = []
        self._new_g: list[int] = []
        self._line: _Line | None = None
        self._next_fit: int | None = None
        self._pinned: int | None = None  # ticks of the last fit that pinned the rate
        self._snapped = np.zeros(0, np.int64)  # the window's receive times, snapped
        self._phase: int | None = None
        self._parts = False  # whether the snapped points take the partial reads in
        # bucket minima of the whole quarter seconds gone by, and the first bucket not
        # yet taken: each is found once, at the first fit after it is complete
        self._lows_x = np.zeros(0, np.int64)
        self._lows_y = np.zeros(0, np.int64)
        self._lows_to: int | None = None
        # receive times above the last fit, for ``state``: worked out only when asked
        self._latency: Callable[[], np.ndarray] = lambda: np.zeros(0)

    @property
    def state(self) -> ClockState:
        line = self._line
        if line is None:
            return ClockState(0, 0.0, 0, 0)
        x = int(self._x[-1])
        offset = int(line.at(np.array([x]))[0]) - x * NS_PER_TICK
        latency = self._latency()
        spread = int(np.median(latency)) if len(latency) else 0
        return ClockState(offset, (NS_PER_TICK / line.rate - 1.0) * 1e6, spread,
                          len(self._x))

    def horizon(self, rx_ns: int) -> int | None:
        """The most ticks a record received at ``rx_ns`` can carry by the model (it was
        sampled at least the transport's floor earlier); None before the first fit.
        """
        line = self._line
        return None if line is None else line.ticks_at(rx_ns - self.floor_ns)

    def update(self, ticks: npt.ArrayLike, rx_ns: npt.ArrayLike,
               part_ns: npt.ArrayLike | None = None,
               part_lead_ns: npt.ArrayLike | None = None) -> npt.NDArray[np.int64]:
        """Sample instants (host ns) of records with increasing ``ticks`` received at
        ``rx_ns``: the instant their values describe, filter delay taken out.
        ``part_ns``, ``part_lead_ns``: per record, an earlier read that ended inside it
        and the line time of the bytes it held (the completing read and the floor where
        there is none).
        """
        x = np.asarray(ticks, np.int64)
        y = np.asarray(rx_ns, np.int64)
        if x.shape != y.shape:
            raise ValueError(f"ticks and rx_ns differ in length: {x.shape} vs {y.shape}")
        parts = None
        if part_ns is not None and part_lead_ns is not None:
            p, lead = np.asarray(part_ns, np.int64), np.asarray(part_lead_ns, np.int64)
            if p.shape != y.shape or lead.shape != y.shape:
                raise ValueError("part_ns and part_lead_ns must match rx_ns in length")
            parts = (p.tolist(), lead.tolist())
        return self._increasing(np.array(self._instants(x.tolist(), y.tolist(), x, parts),
                                         np.int64))

    def update_few(self, ticks: list[int], rx_ns: list[int],
                   parts: tuple[list[int], list[int]] | None = None) -> list[int]:
        """``update`` of a few records in plain integers (a live bridge gets one or two a
        read): the same instants without NumPy's fixed cost per call. ``parts``: the
        partial reads' receive times and line times, as ``update``'s.
        """
        if len(ticks) != len(rx_ns):
            raise ValueError(f"ticks and rx_ns differ in length: {len(ticks)} vs {len(rx_ns)}")
        out = self._instants(ticks, rx_ns, None, parts)
        if not out:
            return out
        # ``_increasing`` in plain integers: each instant at least 1 ns after the one before
        last = self._last_ns
        least = out[0] if last is None else last + 1
        for i, value in enumerate(out):
            least = max(least, value - i)
            out[i] = least + i
        self._last_ns = out[-1]
        return out

    def _instants(self, xs: list[int], ys: list[int], x: np.ndarray | None,
                  parts: tuple[list[int], list[int]] | None) -> list[int]:
        """The line's instants at ``xs``, refitting at the ticks-determined points; long
        runs on one line in NumPy (``x``: ``xs`` as an array, if the caller has it).
        """
        floor, delay = self.floor_ns, self.filter_delay_ns
        if parts is not None and not self.frame_ns:  # no frames: the least bound at once
            ys = [min(r, p - lead + floor) for r, p, lead in zip(ys, *parts, strict=True)]
        keep_parts = self.serial and self.frame_ns
        out: list[int] = []
        i = 0
        while i < len(xs):
            # records before the next refit point follow the current line
            j = i if self._next_fit is None else bisect_left(xs, self._next_fit, i)
            line = self._line
            if j > i and line is not None:
                if j - i > _SCALAR_RUN:
                    run = x[i:j] if x is not None else np.array(xs[i:j], np.int64)
                    out += (line.at(run) - delay).tolist()
                else:
                    out += [line.at_one(t) - delay for t in xs[i:j]]
            self._new_x += xs[i : j + 1]
            self._new_y += [r - floor for r in ys[i : j + 1]]
            if keep_parts:
                if parts is None:
                    self._new_q += self._new_y[len(self._new_q):]
                    self._new_g += [0] * (len(self._new_y) - len(self._new_g))
                else:
                    self._new_q += [p - floor for p in parts[0][i : j + 1]]
                    self._new_g += [floor - lead for lead in parts[1][i : j + 1]]
            if j >= len(xs):
                break
            self._fit(xs[j])
            assert self._line is not None
            out.append(self._line.at_one(xs[j]) - delay)
            i = j + 1
        return out

    def _increasing(self, out: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
        """Instants that only move forward: a refit may lower the line by more than a
        sample period (late points early on, then prompt ones), and a subscriber must
        never see a later sample stamped before an earlier one. Such records get the
        least later instant (1 ns on) until the line has caught up.
        """
        if not len(out):
            return out
        last = self._last_ns
        if (last is not None and out[0] <= last) or (len(out) > 1 and (np.diff(out) <= 0).any()):
            start = out[0] if last is None else last + 1
            ramp = np.arange(len(out), dtype=np.int64)
            out = np.maximum.accumulate(np.maximum(out, start + ramp) - ramp) + ramp
        self._last_ns = int(out[-1])
        return out

    # --- fitting -------------------------------------------------------------------------
    def _fit(self, now: int) -> None:
        new_y = np.array(self._new_y, np.int64)
        self._x = np.concatenate([self._x, np.array(self._new_x, np.int64)])
        self._y = np.concatenate([self._y, new_y])
        self._new_x, self._new_y = [], []
        keep = int(np.searchsorted(self._x, now - self._window))
        self._x, self._y = self._x[keep:], self._y[keep:]
        if self.serial and self.frame_ns:
            self._q = np.concatenate([self._q, np.array(self._new_q, np.int64)])[keep:]
            self._g = np.concatenate([self._g, np.array(self._new_g, np.int64)])[keep:]
            self._new_q, self._new_g = [], []
        span = int(self._x[-1] - self._x[0])
        step = self._refit if span >= _WARM_S * TICKS_PER_SECOND else self._refit // 10
        self._next_fit = now + max(1, step)
        # Frames alone carry the time unless reads ending inside records pin them to bytes.
        staircase = self.frame_ns and not (self.serial and pinned_by_bytes(self._g))
        upper = self._snap(new_y, keep, not staircase) if self.frame_ns else self._y
        if not staircase and self.frame_ns:  # the envelope over a serial line's window
            start = int(np.searchsorted(self._x, now - _LINE_WINDOW_S * TICKS_PER_SECOND))
            x, upper = self._x[start:], upper[start:]
            span = int(x[-1] - x[0])
        else:
            x = self._x
        x_ref = int(x[0]) + span // 2
        y_ref = int(upper[0])
        bias = 0.0
        if staircase:
            bx, by = self._bucket_minima(upper)
            centre = self._centre(bx, by)
            if self.fits is not None:
                self.fits.append((now, math.inf if centre is None else centre[3]))
            if centre is not None:
                self._rate = centre[2]
                self._line = _Line(centre[0], centre[1], centre[2], 0.0)
                y, x, fit = self._y, self._x, self._line
                self._latency = lambda: y - fit.at(x)
                return
            line = self._frame_fit(bx.tolist(), by.tolist())
            if line is not None:
                x_ref, y_ref, self._rate = line
        dx = (x - x_ref).astype(np.float64)
        dy = (upper - y_ref).astype(np.float64)
        if not staircase and span >= 2 * TICKS_PER_SECOND:
            self._rate = support_slope(dx, dy, self._rate)
        level = float(np.min(dy - self._rate * dx))
        residual = dy - self._rate * dx - level
        if staircase:
            bias = uncovered_half(residual[dx >= 0], self.frame_ns)
        y, rate = self._y[len(self._y) - len(x):], self._rate
        self._latency = lambda: (y - y_ref).astype(np.float64) - rate * dx - level
        self._line = _Line(x_ref, y_ref + round(level), self._rate, bias)

    def _centre(self, x: np.ndarray, y: np.ndarray) -> tuple[int, int, float, float, float] | None:
        """``best_centre`` at the newest record over the last quarter, half or whole
        of the window. Once a fit has pinned the rate, slopes are only searched as
        far from it as a crystal's temperature drift can take it since: with a
        single frame crossing in view, the points alone would allow far more.
        """
        now = int(self._x[-1])
        starts = np.searchsorted(x, [now - self._window // part for part in (4, 2, 1)]).tolist()
        ppm = _MAX_PPM
        if self._pinned is not None:
            ppm = min(_MAX_PPM, _RATE_FLOOR_PPM
                      + _SLEW_PPM_S * (now - self._pinned) / TICKS_PER_SECOND)
        centre = best_centre(x, y, now, self.frame_ns, self._rate,
                             [(a, len(x)) for a in starts], ppm)
        if centre is not None and centre[4] < _PINNED_PPM * 1e-6 * NS_PER_TICK:
            self._pinned = now
        return centre

    def _frame_fit(self, x: list[int], y: list[int]) -> tuple[int, int, float] | None:
        """The latest whole step of the frame staircase: anchor point and slope.

        Snapped to frames, a unit's points form a staircase whose treads follow
        the frame clock; the true line touches the corner of every tread, so the
        slope is that of a hull edge between two corners. The first and last edges
        run along partial treads and are not used; with fewer than two corners the
        slope so far stands.
        """
        corners = _lower_hull(x, y)[1:-1]
        if len(corners) < 2:
            return None
        b = corners[-1]
        older = [c for c in corners[:-1] if b[0] - c[0] >= _CHORD_TICKS] or corners[:1]
        a = older[-1]
        if b[0] - a[0] < _CHORD_TICKS // 4:
            return None
        return a[0], a[1], (b[1] - a[1]) / (b[0] - a[0])

    def _snap(self, new_y: np.ndarray, dropped: int, parts: bool) -> np.ndarray:
        """Receive times moved down to the USB frame that carried them, and with ``parts``
        the partial reads' bounds where they are less. The window's older points keep
        their snapped times while the grid's phase and ``parts`` stay put (the window
        lost its first ``dropped`` points since the last fit); when either changes,
        every bucket minimum is found anew.
        """
        self._grid *= _GRID_DECAY
        self._grid += grid_histogram(new_y, self.frame_ns)
        phase = grid_phase(self._grid, self.frame_ns)
        old = len(self._y) - len(new_y)
        if (phase, parts) == (self._phase, self._parts) \
                and len(self._snapped) - dropped == old >= 0:
            fresh = self._least(old, phase, parts)
            self._snapped = np.concatenate([self._snapped[dropped:], fresh])
        else:
            self._snapped = self._least(0, phase, parts)
            self._lows_to = None
        self._phase, self._parts = phase, parts
        return self._snapped

    def _least(self, start: int, phase: int, parts: bool) -> np.ndarray:
        """The window's points from ``start`` on, snapped: each record's least bound."""
        frame = self.frame_ns
        full = snap_to(self._y[start:], phase, frame)
        if not parts:
            return full
        return np.asarray(np.minimum(full, snap_to(self._q[start:], phase, frame)
                                     + self._g[start:]))

    def _bucket_minima(self, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``bucket_minima`` of the window, each bucket's found at the first fit after it
        was complete and kept (with that fit's rate) while it stays in the window: the
        window is minutes long, a fit adds a second.
        """
        x = self._x
        first, newest = int(x[0]) // _BUCKET_TICKS, int(x[-1]) // _BUCKET_TICKS
        if self._lows_to is None:
            self._lows_x, self._lows_y = bucket_minima(x, upper, self._rate)
        else:
            start = int(np.searchsorted(x, self._lows_to * _BUCKET_TICKS))
            lows = bucket_lows(x[start:], upper[start:], self._rate) + start
            lows = lows[(x[lows] // _BUCKET_TICKS > first) & (x[lows] // _BUCKET_TICKS < newest)]
            old = int(np.searchsorted(self._lows_x, (first + 1) * _BUCKET_TICKS))
            self._lows_x = np.concatenate([self._lows_x[old:], x[lows]])
            self._lows_y = np.concatenate([self._lows_y[old:], upper[lows]])
        self._lows_to = newest
        return self._lows_x, self._lows_y


def pinned_by_bytes(gain: np.ndarray) -> bool:
    """Whether enough records had a read end inside them (``gain``: the line time of the
    bytes that read did not hold, 0 where none did) for the lower envelope of the points
    to be the line. Behind a USB-serial adapter whose packets happen to end with records
    (a 16 ms latency timer, records that divide its packet) the frames alone carry the
    time, as on native USB.
    """
    return bool(len(gain)) and float(np.count_nonzero(gain)) >= _PARTIAL_SHARE * len(gain)


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
    return np.bincount((y % frame) // _GRID_BIN_NS, minlength=max(1, frame // _GRID_BIN_NS))


def grid_phase(histogram: np.ndarray, frame: int) -> int:
    """Where in the frame the boundary lies, from the receive times folded onto it: the
    edge the times lie least far after. Their total distance after bin edge e is
    sum(h c) - e sum(h) + frame (the times in bins before e); the first term is the
    same for every edge and left out.
    """
    h = np.asarray(histogram, np.float64)
    cost = frame * (np.cumsum(h) - h) - float(h.sum()) * _GRID_BIN_NS * np.arange(len(h))
    return int(np.argmin(cost)) * _GRID_BIN_NS + _GRID_BIN_NS // 2 - _GRID_MARGIN_NS


def snap_to(y: np.ndarray, phase: int, frame: int) -> np.ndarray:
    return np.asarray((y - phase) // frame * frame + phase + _GRID_MARGIN_NS)


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
    buckets = x[lows] // _BUCKET_TICKS
    lows = lows[(buckets > x[0] // _BUCKET_TICKS) & (buckets < x[-1] // _BUCKET_TICKS)]
    return x[lows], y[lows]


def bucket_lows(x: np.ndarray, y: np.ndarray, rate: float) -> np.ndarray:
    """Index of the point least above a line of slope ``rate`` in each quarter second of
    ticks (the first, on a tie), for every stretch ``x`` touches, in order.
    """
    v = (y - y[0]).astype(np.float64) - rate * (x - x[0]).astype(np.float64)
    buckets = x // _BUCKET_TICKS
    starts = np.concatenate(([0], np.flatnonzero(buckets[1:] != buckets[:-1]) + 1))
    sizes = np.diff(np.concatenate((starts, [len(v)])))
    lowest = np.flatnonzero(v == np.repeat(np.minimum.reduceat(v, starts), sizes))
    kb = buckets[lowest]
    return lowest[np.concatenate(([True], kb[1:] != kb[:-1]))]


def best_centre(x: np.ndarray, y: np.ndarray, at: int, frame: int, prior: float,
                spans: list[tuple[int, int]],
                ppm: float = _MAX_PPM) -> tuple[int, int, float, float, float] | None:
    """``polygon_centre`` over the shortest span (index range, shortest first) that
    pins the line at ``at``, else the one that pins it best: a unit whose phase
    sweeps the frame is pinned by a short span, which wander bends least; a unit
    that beats slowly needs a long one. Slopes are searched within ``ppm`` of
    ``prior``.
    """
    best: tuple[int, int, float, float, float] | None = None
    for lo, hi in spans:
        found = polygon_centre(x[lo:hi], y[lo:hi], at, frame, prior, ppm)
        if found is not None and (best is None or found[3] < best[3]):
            best = found
        if best is not None and best[3] < _PINNED_NS:
            break
    return best


def polygon_centre(x: np.ndarray, y: np.ndarray, now: int, frame: int, prior: float,
                   ppm: float = _MAX_PPM) -> tuple[int, int, float, float, float] | None:
    """The middle of every line the frame staircase allows, judged at ticks ``now``.

    Each point (read in the frame that carried it) says the line lies at most one
    frame under it and not above it. When one straight line can meet all of
    them, the lines that do form a polygon; its extent at ``now`` is the honest
    uncertainty there (returned after the slope, then the slopes' spread), and its
    middle the estimate: half a frame wide for a unit
    that has never crossed a frame boundary, narrowing with every crossing. When
    no straight line fits (the rate wandered within the window), None.

    Every search is over a piecewise-linear function of the slope r, convex or
    concave: each step follows the linear piece it stands on to where that piece
    would give the answer, so a few passes over the points find it exactly.
    """
    if len(x) < 2:
        return None
    newest = int(y[-1])
    dx = (x - now).astype(np.float64)
    dy = (y - newest).astype(np.float64)  # in integers first: ns since 1970 exceed float64's
    band = _Band(dx, dy)
    lo, hi = prior * (1 - ppm * 1e-6), prior * (1 + ppm * 1e-6)
    best = band.narrowest(lo, hi)
    if band.width(best)[0] > frame:
        return None
    low_rate, high_rate = band.reach(best, lo, frame), band.reach(best, hi, frame)
    r_top, _ = _peak(dx, dy, low_rate, high_rate, band.ranges)
    r_bottom, _ = _peak(-dx, -dy, low_rate, high_rate, band.ranges)
    top = float((dy - r_top * dx).min())
    bottom = float((dy - r_bottom * dx).max()) - frame
    return (now, newest + round((top + bottom) / 2), (low_rate + high_rate) / 2, top - bottom,
            high_rate - low_rate)


class _Band:
    """The spread of ``dy - r dx`` over the points, a convex function of the slope r,
    and the linear piece of it at each r (its value and slope there).
    """

    def __init__(self, dx: np.ndarray, dy: np.ndarray) -> None:
        self.dx, self.dy = dx, dy
        self._v = np.empty_like(dy)
        self.ranges = _ranges(dx, dy)

    def tie(self, r: float) -> float:
        return _tie(self.ranges, r)

    def width(self, r: float) -> tuple[float, float]:
        v = self._v
        np.multiply(r, self.dx, out=v)
        np.subtract(self.dy, v, out=v)
        top, bottom = int(v.argmax()), int(v.argmin())
        return float(v[top] - v[bottom]), float(self.dx[bottom] - self.dx[top])

    def narrowest(self, lo: float, hi: float) -> float:
        """The r in [lo, hi] where the spread is least: where the lines of the pieces on
        either side of it cross, unless a piece there is higher.
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
        """Between ``inside`` (spread <= level) and ``outside``, the r where the spread
        reaches ``level`` (``outside`` if it never does). From the outside each piece's
        line lies under the convex spread, so following it never overshoots.
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


def _lower_hull(x: list[int], y: list[int]) -> list[tuple[int, int]]:
    """Andrew's monotone chain on integers (exact: collinear treads stay collinear)."""
    hull: list[tuple[int, int]] = []
    for p in zip(x, y, strict=True):
        while len(hull) >= 2:
            (x1, y1), (x2, y2) = hull[-2], hull[-1]
            if (x2 - x1) * (p[1] - y1) - (y2 - y1) * (p[0] - x1) > 0:
                break
            hull.pop()
        hull.append(p)
    return hull


def support_slope(dx: np.ndarray, dy: np.ndarray, prior: float) -> float:
    """The slope of the highest line under every point, judged at dx = 0: the lower
    hull's edge over dx = 0, clamped to ``_MAX_PPM`` around ``prior``. The search starts
    a few ppm around ``prior`` (a refit's rate is close to the last one) and widens
    until the answer is inside.
    """
    if not len(dx):
        return prior
    ppm = _START_PPM
    while True:
        r, inside = _peak(dx, dy, prior * (1 - ppm * 1e-6), prior * (1 + ppm * 1e-6))
        if inside or ppm >= _MAX_PPM:
            return r
        ppm = min(_MAX_PPM, ppm * 8)


def _ranges(dx: np.ndarray, dy: np.ndarray) -> tuple[float, float]:
    """The largest magnitudes of dx and dy, which bound float64's rounding of dy - r dx."""
    return float(np.abs(dx).max()), float(np.abs(dy).max())


def _tie(ranges: tuple[float, float], r: float) -> float:
    """float64 rounds dy - r dx by ~1e-16 of its magnitude: closer than this is a tie."""
    dx_range, dy_range = ranges
    return 1e-14 * (dy_range + abs(r) * dx_range)


def _peak(dx: np.ndarray, dy: np.ndarray, lo: float, hi: float,
          ranges: tuple[float, float] | None = None) -> tuple[float, bool]:
    """The r in [lo, hi] where ``min(dy - r dx)`` is highest, and whether it is inside
    (not at an end). ``ranges``: ``_ranges(dx, dy)`` when the caller has them.

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
