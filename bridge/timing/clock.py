"""Online estimate of the instant each record was sampled, on the host clock.

A record is received after it was on the line, never before: the receive time of a read
is an upper bound on the start of every record in it. Over USB frames that carry every
byte ready when polled, a read is also a lower bound on the bytes it did not hold: they
were not there at its frame. ``OnlineClock`` takes the middle of the lines ``host =
offset + rate * ticks`` that pass between those bounds over a sliding window (on a UART,
where only upper bounds hold, the line under them): late reads (OS latency, a burst
after a stall) do not move it, the window follows a rate that wanders, and the spread
of the lines it allows says how sure it is. How the bounds and the line are found:
docs/design/time.md.

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
from bridge.timing._fit import (
    BUCKET_TICKS,
    FRAME_DOUBT_NS,
    GRID_BIN_NS,
    MAX_PPM,
    NO_BOUND,
    Bounds,
    Centre,
    best_centre,
    bucket_lows,
    frame_after,
    frame_before,
    framed_bounds,
    grid_histogram,
    grid_phase,
    uncovered_half,
)
from bridge.timing._fit import support_slope as support_slope  # tests/ import it from here
from bridge.timing.unwrap import NS_PER_TICK

_WARM_S = 10.0  # refit ten times a second until the window is this long
# How far the rate may have moved since it was last pinned: crystals drift a few
# ppm over minutes with temperature.
_RATE_FLOOR_PPM = 0.5
_PINNED_PPM = 0.5  # the rate counts as known when the allowed slopes are this close
_SLEW_PPM_S = 0.1
# A serial line's window follows drift through the fit's midpoint; over USB the
# slope comes from recent staircase corners, and a long window lets a unit that
# beats slowly against the frame clock show two of them.
_LINE_WINDOW_S = 60.0
_FRAME_WINDOW_S = 300.0
_CHORD_TICKS = 20 * TICKS_PER_SECOND  # corners this far apart give the slope
_GRID_DECAY = 0.99  # per refit: the frame grid may drift against the host clock
_SCALAR_RUN = 16  # records; shorter runs are cheaper in plain integers than in NumPy


@dataclass(frozen=True)
class ClockState:
    """The model for status.

    ``offset_ns``: host minus nominal device time at the latest record; ``drift_ppm``:
    the device clock's rate error against the host's (positive: the unit's clock runs
    fast); ``spread_ns``: the median latency above the fit; ``samples``: points used;
    ``uncertainty_ns``: the most the latest instants can be off by, as the reads bound
    them (half the spread of the lines they allow; 0: not known, where reads bound
    records from one side only).
    """

    offset_ns: int
    drift_ppm: float
    spread_ns: int
    samples: int
    uncertainty_ns: int = 0


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
        """``at`` of one record in plain numbers.

        The same float64 operations and round-half-to-even, so the same result without
        NumPy's cost per call.
        """
        return self.y_ref + round(self.rate * float(ticks - self.x_ref) - self.bias)

    def ticks_at(self, host: int) -> int:
        """The inverse of ``at``: the ticks the line puts at host instant ``host``."""
        return self.x_ref + math.floor((float(host - self.y_ref) + self.bias) / self.rate)


class OnlineClock:
    """Maps unwrapped ticks to host ns, one ``update`` per batch of valid records.

    Each record gives an upper bound on when its first byte was on the line: the read that
    completed it (snapped to its frame, where frames carry the bytes) less ``floor_ns``,
    or, where ``update`` is given one, an earlier read that ended inside the record (also
    snapped) less the line time of the bytes it held. Where frames deliver every byte that
    is ready (``prompt``), a read that ended inside a record or right where it begins also
    bounds it from below: the bytes it did not hold were still to come when its frame was
    polled. A UART's reads bound records from above only: a driver may hold bytes a while.

    Args:
        delay_ns: From the instant a record's values describe to its first byte on the
            line: the moving-average filter's (M - 1) / 2 ms for filter width M (0xDB)
            and the unit's processing delay (``bridge.timing.stream.record_delay_ns``).
        floor_ns: The least time from the record's first byte to its receipt the transport
            allows: a serial line's time for the record (len * 10 / baud s, a UART or
            behind an adapter); on the unit's own USB port len * 1 us.
        frame_ns: The USB frame (1,000,000) where frames carry the bytes (own port or
            adapter), 0 on a UART.
        window_s: Seconds of records the fit looks at; None: 60 on a serial line, 300
            over USB frames.
        refit_s: How often the line is fitted again, in seconds of the unit's clock.
        serial: The bytes crossed a serial line before those frames (a USB-serial
            adapter): a read can end inside a record.
        byte_ns: A serial line's byte time, by which a record's next byte was still to
            come when a read ended inside it (behind an adapter).
        prompt: Each frame carries every byte (on the unit's own port, every whole
            record) that is ready when it is polled: the unit's own USB port and an
            adapter with a 1 ms latency timer; not one with a longer timer, which holds
            bytes back until a packet fills (there only the records read soonest after a
            frame bound the line from below, within a frame).

    Raises:
        ValueError: A negative delay, floor, frame or byte time, or a window or refit
            period that is not positive.
    """

    def __init__(self, delay_ns: int = 0, floor_ns: int = 0, frame_ns: int = 0,
                 window_s: float | None = None, refit_s: float = 1.0,
                 serial: bool = False, byte_ns: float = 0.0, prompt: bool = True) -> None:
        if delay_ns < 0 or floor_ns < 0 or frame_ns < 0 or byte_ns < 0:
            raise ValueError("delay_ns, floor_ns, frame_ns and byte_ns must be >= 0")
        self.serial = serial
        if window_s is None:
            window_s = _FRAME_WINDOW_S if frame_ns else _LINE_WINDOW_S
        if window_s <= 0 or refit_s <= 0:
            raise ValueError("window_s and refit_s must be positive")
        self.delay_ns = int(delay_ns)
        self.floor_ns = int(floor_ns)
        self.frame_ns = int(frame_ns)
        self.byte_ns = float(byte_ns)
        self.prompt = prompt
        self._window = round(window_s * TICKS_PER_SECOND)
        self._refit = round(refit_s * TICKS_PER_SECOND)
        bins = max(1, self.frame_ns // GRID_BIN_NS)
        self._grid = np.zeros(bins if self.frame_ns else 0)
        self._rate = float(NS_PER_TICK)
        self._last_ns: int | None = None  # the latest instant given out
        #: When a list, each fit over frames adds (its ticks, the extent of the lines its
        #: bounds allowed at them; inf when no straight line fitted): the doubt of the
        #: instants it gives out until the next fit.
        self.fits: list[tuple[int, float]] | None = None
        self.reset()

    def reset(self) -> None:
        """Start over after the tick base changed (device reset); keep rate and grid."""
        # per record: ticks; on a UART its least upper bound, over frames the receive
        # time of the read that completed it, its partial read's and that read's lead
        # (the line time of the record's bytes it held: the floor where there is none)
        self._x = np.zeros(0, np.int64)
        self._y = np.zeros(0, np.int64)
        self._p = np.zeros(0, np.int64)
        self._lead = np.zeros(0, np.int64)
        self._new_x: list[int] = []
        self._new_y: list[int] = []
        self._new_p: list[int] = []
        self._new_lead: list[int] = []
        self._line: _Line | None = None
        self._uncertainty = 0  # ``ClockState.uncertainty_ns`` of the line
        self._next_fit: int | None = None
        self._pinned: int | None = None  # ticks of the last fit that pinned the rate
        self._edge: int | None = None  # where the frames fall, as the bounds were found
        self._hi = np.zeros(0, np.int64)  # the window's bounds on each record's start
        self._lo = np.zeros(0, np.int64)
        # each quarter second's tightest bounds (the upper's, the lower's, the lower
        # points' ticks), found once, at the first fit after it is complete
        self._lows_x = np.zeros(0, np.int64)
        self._lows_y = np.zeros(0, np.int64)
        self._highs_x = np.zeros(0, np.int64)
        self._highs_y = np.zeros(0, np.int64)
        self._lows_to: int | None = None
        # receive times above the last fit, for ``state``: worked out only when asked
        self._latency: Callable[[], np.ndarray] = lambda: np.zeros(0)

    @property
    def state(self) -> ClockState:
        """The model now, for status (zeros before the first fit)."""
        line = self._line
        if line is None:
            return ClockState(0, 0.0, 0, 0)
        x = int(self._x[-1])
        offset = int(line.at(np.array([x]))[0]) - x * NS_PER_TICK
        latency = self._latency()
        spread = int(np.median(latency)) if len(latency) else 0
        return ClockState(offset, (NS_PER_TICK / line.rate - 1.0) * 1e6, spread,
                          len(self._x), self._uncertainty)

    def horizon(self, rx_ns: int) -> int | None:
        """The most ticks a record received at ``rx_ns`` can carry by the model.

        It was sampled at least the transport's floor earlier.

        Args:
            rx_ns: The receive time.

        Returns:
            Ticks, or None before the first fit.
        """
        line = self._line
        return None if line is None else line.ticks_at(rx_ns - self.floor_ns)

    def update(self, ticks: npt.ArrayLike, rx_ns: npt.ArrayLike,
               part_ns: npt.ArrayLike | None = None,
               part_lead_ns: npt.ArrayLike | None = None) -> npt.NDArray[np.int64]:
        """Sample instants of the next records: the instant their values describe.

        Args:
            ticks: The records' unwrapped ticks, increasing.
            rx_ns: The receive time of the read that completed each.
            part_ns: Per record, an earlier read that ended inside it or right where it
                begins (the completing read where there is none).
            part_lead_ns: The line time of the record's bytes that read held: 0 where it
                held none (it ended where the record begins), the floor where there is
                none.

        Returns:
            Host ns, filter delay taken out, each after the one before it (and after
            every instant given out before).

        Raises:
            ValueError: The arrays differ in length.
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
        """``update`` of a few records in plain integers (a live bridge gets one or two a read).

        The same instants without NumPy's fixed cost per call.

        Args:
            ticks: The records' unwrapped ticks, increasing.
            rx_ns: The receive time of the read that completed each.
            parts: The partial reads' receive times and line times, as ``update``'s
                ``part_ns`` and ``part_lead_ns``.

        Returns:
            Host ns, as ``update`` gives them.

        Raises:
            ValueError: ``ticks`` and ``rx_ns`` differ in length.
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
        """The line's instants at ``xs``, refitting at the ticks-determined points.

        Long runs on one line go through NumPy (``x``: ``xs`` as an array, if the caller
        has it).
        """
        floor, delay, frames = self.floor_ns, self.delay_ns, self.frame_ns
        if parts is not None and not frames:  # no frames: the least upper bound at once
            ys = [min(r, p - lead + floor) if lead > 0 else r
                  for r, p, lead in zip(ys, *parts, strict=True)]
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
            if not frames:
                self._new_y += [r - floor for r in ys[i : j + 1]]
            else:
                self._new_y += ys[i : j + 1]
                if parts is None:
                    self._new_p += ys[i : j + 1]
                    self._new_lead += [floor] * (min(j + 1, len(xs)) - i)
                else:
                    self._new_p += parts[0][i : j + 1]
                    self._new_lead += parts[1][i : j + 1]
            if j >= len(xs):
                break
            self._fit(xs[j])
            assert self._line is not None
            out.append(self._line.at_one(xs[j]) - delay)
            i = j + 1
        return out

    def _increasing(self, out: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
        """Instants that only move forward.

        A refit may lower the line by more than a sample period (late points early on,
        then prompt ones), and a subscriber must never see a later sample stamped before
        an earlier one. Such records get the least later instant (1 ns on) until the line
        has caught up.
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
        fresh = len(self._new_x)
        self._x = np.concatenate([self._x, np.array(self._new_x, np.int64)])
        self._y = np.concatenate([self._y, np.array(self._new_y, np.int64)])
        self._new_x, self._new_y = [], []
        keep = int(np.searchsorted(self._x, now - self._window))
        self._x, self._y = self._x[keep:], self._y[keep:]
        span = int(self._x[-1] - self._x[0])
        step = self._refit if span >= _WARM_S * TICKS_PER_SECOND else self._refit // 10
        self._next_fit = now + max(1, step)
        if not self.frame_ns:
            self._envelope(self._x, self._y, span >= 2 * TICKS_PER_SECOND, 0)
            return
        self._p = np.concatenate([self._p, np.array(self._new_p, np.int64)])[keep:]
        self._lead = np.concatenate([self._lead, np.array(self._new_lead, np.int64)])[keep:]
        self._new_p, self._new_lead = [], []
        self._bound(fresh, keep)
        bounds = self._buckets()
        centre = self._centre(bounds)
        if self.fits is not None:
            self.fits.append((now, math.inf if centre is None else centre.extent))
        if centre is not None:
            self._rate = centre.rate
            self._line = _Line(centre.at, centre.value, centre.rate, 0.0)
            self._uncertainty = math.ceil(centre.extent / 2)
            y, x, fit, floor = self._y, self._x, self._line, self.floor_ns
            self._latency = lambda: y - floor - fit.at(x)
            return
        # no straight line meets every bound (the rate wandered across the window):
        # the frame staircase's latest whole step gives the slope, its envelope the level
        line = self._frame_fit(bounds.xh.tolist(), bounds.yh.tolist())
        if line is not None:
            self._rate = line[2]
        self._envelope(self._x, self._hi, False, self.frame_ns)

    def _envelope(self, x: np.ndarray, upper: np.ndarray, slope: bool, frame: int) -> None:
        """The lower envelope of upper bounds as the line, judged at the middle of ``x``.

        With ``slope``, its slope is found too (else the rate so far stands); with
        ``frame``, half of the frame the points leave uncovered is taken off (the line is
        somewhere in it).
        """
        span = int(x[-1] - x[0])
        x_ref, y_ref = int(x[0]) + span // 2, int(upper[0])
        dx = (x - x_ref).astype(np.float64)
        dy = (upper - y_ref).astype(np.float64)
        if slope:
            self._rate = support_slope(dx, dy, self._rate)
        level = float(np.min(dy - self._rate * dx))
        residual = dy - self._rate * dx - level
        bias = uncovered_half(residual[dx >= 0], frame) if frame else 0.0
        y, rate = self._y[len(self._y) - len(x):], self._rate
        shift = self.floor_ns if frame else 0
        self._latency = lambda: (y - shift - y_ref).astype(np.float64) - rate * dx - level
        self._line = _Line(x_ref, y_ref + round(level), self._rate, bias)
        # over frames the line is somewhere in the part left uncovered, taken off by half;
        # on a UART reads bound records from above only: not known
        self._uncertainty = math.ceil(bias) + FRAME_DOUBT_NS if frame else 0

    def _bound(self, fresh: int, dropped: int) -> None:
        """Each record's bounds on its start (``_hi``, ``_lo``), from its reads' frames.

        The frames are found from the receive times (``grid_phase``); the newest
        ``fresh`` records' bounds are added to the window's, which lost its first
        ``dropped``, unless the frames moved: then every bound is found anew.
        """
        frame = self.frame_ns
        self._grid *= _GRID_DECAY
        self._grid += grid_histogram(self._y[len(self._y) - fresh:], frame)
        edge = grid_phase(self._grid, frame)
        start = len(self._x) - fresh
        if edge == self._edge and len(self._hi) - dropped == start >= 0:
            hi, lo = self._bounds_of(start, edge)
            self._hi = np.concatenate([self._hi[dropped:], hi])
            self._lo = np.concatenate([self._lo[dropped:], lo])
        else:
            self._hi, self._lo = self._bounds_of(0, edge)
            self._lows_to = None
        self._edge = edge

    def _bounds_of(self, start: int, edge: int) -> tuple[np.ndarray, np.ndarray]:
        """The bounds of the window's records from ``start`` on (see ``record_bounds``)."""
        return record_bounds(self._y[start:], self._p[start:], self._lead[start:], edge,
                             self.frame_ns, self.floor_ns, self.byte_ns if self.serial else 0.0,
                             self.prompt)

    def _buckets(self) -> Bounds:
        """Each whole quarter second's tightest bounds (``framed_bounds``), each found once.

        A bucket's are found at the first fit after it was complete and kept (with that
        fit's rate) while it stays in the window: the window is minutes long, a fit adds
        a second.
        """
        x, rate = self._x, self._rate
        first, newest = int(x[0]) // BUCKET_TICKS, int(x[-1]) // BUCKET_TICKS
        start = 0 if self._lows_to is None else \
            int(np.searchsorted(x, self._lows_to * BUCKET_TICKS))
        if self._lows_to is None:
            self._lows_x = self._highs_x = np.zeros(0, np.int64)
            self._lows_y = self._highs_y = np.zeros(0, np.int64)
        xs, his, los = x[start:], self._hi[start:], self._lo[start:]
        whole = (xs // BUCKET_TICKS > first) & (xs // BUCKET_TICKS < newest)
        xs, his, los = xs[whole], his[whole], los[whole]
        lows = bucket_lows(xs, his, rate) if len(xs) else np.zeros(0, np.int64)
        known = los > NO_BOUND
        highs = bucket_lows(xs[known], -los[known], -rate) if known.any() \
            else np.zeros(0, np.int64)
        old = int(np.searchsorted(self._lows_x, (first + 1) * BUCKET_TICKS))
        old_high = int(np.searchsorted(self._highs_x, (first + 1) * BUCKET_TICKS))
        self._lows_x = np.concatenate([self._lows_x[old:], xs[lows]])
        self._lows_y = np.concatenate([self._lows_y[old:], his[lows]])
        self._highs_x = np.concatenate([self._highs_x[old_high:], xs[known][highs]])
        self._highs_y = np.concatenate([self._highs_y[old_high:], los[known][highs]])
        self._lows_to = newest
        return framed_bounds(self._lows_x, self._lows_y, self._highs_x, self._highs_y,
                             self.frame_ns)

    def _centre(self, bounds: Bounds) -> Centre | None:
        """``best_centre`` at the newest record over the last quarter, half or whole window.

        Once a fit has pinned the rate, slopes are only searched as far from it as a
        crystal's temperature drift can take it since: with a single frame crossing in
        view, the points alone would allow far more.
        """
        now = int(self._x[-1])
        ppm = MAX_PPM
        if self._pinned is not None:
            ppm = min(MAX_PPM, _RATE_FLOOR_PPM
                      + _SLEW_PPM_S * (now - self._pinned) / TICKS_PER_SECOND)
        spans = [(now - self._window // part, now + 1) for part in (4, 2, 1)]
        centre = best_centre(bounds, now, self._rate, spans, ppm)
        if centre is not None and centre.rates < _PINNED_PPM * 1e-6 * NS_PER_TICK:
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


def record_bounds(rx_ns: np.ndarray, part_ns: np.ndarray, part_lead_ns: np.ndarray,
                  edge: int, frame: int, floor: int, byte_ns: float,
                  prompt: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Bounds on when each record's first byte was on the line, from its reads' frames.

    A read holds every byte its frame carried (``frame_after``): the record was on the
    line by that frame less the line time of its bytes the read held (the whole record
    for the read that completed it). Where frames carry every byte that is ready, the
    next byte a read did not hold was still to come at the frame before it
    (``frame_before``): a read that ended inside a record, or right where it begins,
    bounds the record from below by that frame less the line time up to that next byte
    (``byte_ns`` more than it held; on the unit's own USB port, where records come
    whole, the record's transfer).

    Args:
        rx_ns: The receive time of the read that completed each record.
        part_ns: Each record's partial read (the completing read where there is none).
        part_lead_ns: The line time of the record's bytes the partial read held: 0 where
            it ended where the record begins, ``floor`` where there is none.
        edge: Where the frames fall (``grid_phase``).
        frame: The frame, ns.
        floor: The record's line time (its transfer on the unit's own USB port).
        byte_ns: A serial line's byte time; 0 on the unit's own USB port.
        prompt: Whether frames carry every byte that is ready (else reads give no lower
            bounds: an adapter with a long latency timer holds bytes back).

    Returns:
        The upper and the lower bounds, ns; ``NO_BOUND`` where a record has no lower one.
    """
    hi = frame_after(rx_ns, edge, frame) - floor
    inside = (part_lead_ns > 0) & (part_lead_ns < floor)
    if inside.any():
        hi = np.where(inside, np.minimum(hi, frame_after(part_ns, edge, frame) - part_lead_ns),
                      hi)
    next_ns = round(byte_ns) if byte_ns else floor
    lo = np.where((part_lead_ns < floor) & prompt,
                  frame_before(part_ns, edge, frame) - part_lead_ns - next_ns, NO_BOUND)
    return np.asarray(hi, np.int64), np.asarray(lo, np.int64)


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
