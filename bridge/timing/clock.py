"""Online estimate of the instant each record was sampled, on the host clock.

A record is received after it was sampled, never before: the receive time of a read is
an upper bound on the sample instant of every record in it. ``OnlineClock`` fits the
line ``host = offset + rate * ticks`` under a sliding window of such points: late reads
(OS latency, a burst after a stall) lie above it and do not move it, and the window
follows a rate that wanders. Over USB the receive times are first snapped to the 1 ms
frames that carried them. How the line is found (the lower hull, the frame staircase and
the polygon of the lines it allows, reads that end inside a record): docs/design/time.md.

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
    GRID_BIN_NS,
    MAX_PPM,
    best_centre,
    bucket_lows,
    bucket_minima,
    grid_histogram,
    grid_phase,
    pinned_by_bytes,
    snap_to,
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
    fast); ``spread_ns``: the median latency above the fit; ``samples``: points used.
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

    Each record's point is the least upper bound on its sample instant that its reads
    give: the completing read's receive time (snapped to its frame) less ``floor_ns``,
    or, where ``update`` is given one, an earlier read that ended inside the record
    (snapped to its frame) less the line time of the bytes it held.

    Args:
        filter_delay_ns: The unit's moving-average delay, (M - 1) / 2 ms for filter
            width M (0xDB).
        floor_ns: The least time from sample to receive the transport allows: a serial
            line's time for the record (len * 10 / baud s, a UART or behind an adapter);
            on the unit's own USB port len * 1 us.
        frame_ns: The USB frame (1,000,000) where frames carry the bytes (own port or
            adapter), 0 on a UART.
        window_s: Seconds of records the fit looks at; None: 60 on a serial line, 300
            over USB frames.
        refit_s: How often the line is fitted again, in seconds of the unit's clock.
        serial: The bytes crossed a serial line before those frames (a USB-serial
            adapter): reads that end mid-record pin each record to about a byte time at
            every frame, so the lower envelope of the snapped points is the line, as on
            a plain serial line.

    Raises:
        ValueError: A negative delay, floor or frame, or a window or refit period that
            is not positive.
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
        bins = max(1, self.frame_ns // GRID_BIN_NS)
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
        """The model now, for status (zeros before the first fit)."""
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
            part_ns: Per record, an earlier read that ended inside it (the completing
                read where there is none).
            part_lead_ns: The line time of the bytes that read held (the floor where
                there is none).

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
        """``best_centre`` at the newest record over the last quarter, half or whole window.

        Once a fit has pinned the rate, slopes are only searched as far from it as a
        crystal's temperature drift can take it since: with a single frame crossing in
        view, the points alone would allow far more.
        """
        now = int(self._x[-1])
        starts = np.searchsorted(x, [now - self._window // part for part in (4, 2, 1)]).tolist()
        ppm = MAX_PPM
        if self._pinned is not None:
            ppm = min(MAX_PPM, _RATE_FLOOR_PPM
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
        """Receive times moved down to the USB frame that carried them.

        With ``parts``, the partial reads' bounds where they are less. The window's older
        points keep their snapped times while the grid's phase and ``parts`` stay put
        (the window lost its first ``dropped`` points since the last fit); when either
        changes, every bucket minimum is found anew.
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
        """``bucket_minima`` of the window, each bucket's found once.

        A bucket's minimum is found at the first fit after it was complete and kept (with
        that fit's rate) while it stays in the window: the window is minutes long, a fit
        adds a second.
        """
        x = self._x
        first, newest = int(x[0]) // BUCKET_TICKS, int(x[-1]) // BUCKET_TICKS
        if self._lows_to is None:
            self._lows_x, self._lows_y = bucket_minima(x, upper, self._rate)
        else:
            start = int(np.searchsorted(x, self._lows_to * BUCKET_TICKS))
            lows = bucket_lows(x[start:], upper[start:], self._rate) + start
            lows = lows[(x[lows] // BUCKET_TICKS > first) & (x[lows] // BUCKET_TICKS < newest)]
            old = int(np.searchsorted(self._lows_x, (first + 1) * BUCKET_TICKS))
            self._lows_x = np.concatenate([self._lows_x[old:], x[lows]])
            self._lows_y = np.concatenate([self._lows_y[old:], upper[lows]])
        self._lows_to = newest
        return self._lows_x, self._lows_y


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
