"""Re-estimate sample instants over a whole recording (the recorder's second pass).

Online, a record's time can only use what came before it; offline, every record has
the points on both sides. The smoother solves anchors a few seconds apart, each from
the window around it that pins the line best, and interpolates the records between
them. Over USB frames the live clock is run on the same records too, and where the
offline pass is no surer the live instant stands: never worse than live. How the
windows and anchors are chosen: docs/design/time.md.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from bridge.protocol.table import TICKS_PER_SECOND
from bridge.timing._fit import (
    best_centre,
    bucket_minima,
    grid_histogram,
    grid_phase,
    pinned_by_bytes,
    snap_to,
    support_slope,
    uncovered_half,
)
from bridge.timing.clock import OnlineClock
from bridge.timing.unwrap import NS_PER_TICK

# Shortest first. The longest lets a unit that beats slowly against the frame clock
# and crossed a frame boundary once keep that crossing in view ten minutes later.
_WINDOWS_S = (60.0, 120.0, 300.0, 600.0, 1200.0)
# Over a serial line the envelope's window is as short as wander wants, and behind an
# adapter's frames long enough for the unit's phase to sweep this much of a frame (past
# a byte time at any common baud rate), so that some reads were prompt to a byte.
_LINE_S = (20.0, 300.0)
_SWEEP = 0.125
_PINNED = 0.25  # of a frame: an extent this narrow means a crossing pinned the line
_SURER = 0.75  # or this much narrower than live's


class OfflineClock:
    """Maps one epoch's unwrapped ticks to host ns using the whole recording.

    Args:
        filter_delay_ns: As ``OnlineClock``'s.
        floor_ns: As ``OnlineClock``'s.
        frame_ns: As ``OnlineClock``'s.
        anchor_s: The spacing of solved points, seconds of the unit's clock.
        serial: As ``OnlineClock``'s.

    Raises:
        ValueError: A negative delay, floor or frame, or an anchor spacing that is not
            positive.
    """

    def __init__(self, filter_delay_ns: int = 0, floor_ns: int = 0, frame_ns: int = 0,
                 anchor_s: float = 5.0, serial: bool = False) -> None:
        if filter_delay_ns < 0 or floor_ns < 0 or frame_ns < 0 or anchor_s <= 0:
            raise ValueError("filter_delay_ns, floor_ns, frame_ns must be >= 0, anchor_s > 0")
        self.filter_delay_ns = int(filter_delay_ns)
        self.floor_ns = int(floor_ns)
        self.frame_ns = int(frame_ns)
        self.serial = serial
        self._anchor = max(1, round(anchor_s * TICKS_PER_SECOND))

    def smooth(self, ticks: npt.ArrayLike, rx_ns: npt.ArrayLike,
               part_ns: npt.ArrayLike | None = None,
               part_lead_ns: npt.ArrayLike | None = None) -> npt.NDArray[np.int64]:
        """Sample instants of the valid records of one epoch.

        Args:
            ticks: The records' unwrapped ticks, increasing.
            rx_ns: The receive time of the read that completed each.
            part_ns: As ``OnlineClock.update``'s.
            part_lead_ns: As ``OnlineClock.update``'s.

        Returns:
            Host ns, filter delay taken out.

        Raises:
            ValueError: The arrays differ in length.
        """
        x = np.asarray(ticks, np.int64)
        y = np.asarray(rx_ns, np.int64) - self.floor_ns
        if x.shape != y.shape:
            raise ValueError(f"ticks and rx_ns differ in length: {x.shape} vs {y.shape}")
        if len(x) == 0:
            return np.zeros(0, np.int64)
        rx = y + self.floor_ns
        live_parts: tuple[np.ndarray, ...] = ()
        if part_ns is None or part_lead_ns is None:
            q, g = y, np.zeros(0, np.int64)
        else:
            q = np.asarray(part_ns, np.int64) - self.floor_ns
            g = self.floor_ns - np.asarray(part_lead_ns, np.int64)
            if q.shape != y.shape or g.shape != y.shape:
                raise ValueError("part_ns and part_lead_ns must match rx_ns in length")
            live_parts = (q + self.floor_ns, self.floor_ns - g)
        # Frames alone carry the time unless reads ending inside records pin them to bytes.
        staircase = bool(self.frame_ns) and not (self.serial and pinned_by_bytes(g))
        if self.frame_ns:
            phase = grid_phase(grid_histogram(y, self.frame_ns), self.frame_ns)
            y = snap_to(y, phase, self.frame_ns)
            if len(g) and not staircase:
                y = np.minimum(y, snap_to(q, phase, self.frame_ns) + g)
        elif len(g):
            y = np.minimum(y, q + g)
        x0, y0 = int(x[0]), int(y[0])
        dx, dy = (x - x0).astype(np.float64), (y - y0).astype(np.float64)
        # The lower envelope's slope under the middle of the recording: the mean rate to
        # within a frame over half the span (judged at an end it is the first hull
        # edge's, which a staircase can tilt by hundreds of ppm).
        rate = support_slope(dx - dx[-1] / 2, dy, float(NS_PER_TICK))
        anchors = np.arange(x0, int(x[-1]) + self._anchor, self._anchor)
        empty = np.zeros(0, np.int64)
        bx, by = bucket_minima(x, y, rate) if staircase else (empty, empty)
        half = round(self._line_window(rate) * TICKS_PER_SECOND / 2) if not staircase \
            else round(_WINDOWS_S[0] * TICKS_PER_SECOND / 2)
        solved = [self._solve(x, y, bx, by, int(a), rate, staircase, half)
                  for a in anchors.tolist()]
        values = np.array([v for v, _ in solved])
        step = np.round(np.interp(dx, (anchors - x0).astype(np.float64), values))
        out: npt.NDArray[np.int64] = y0 + step.astype(np.int64) - self.filter_delay_ns
        if not staircase:
            return out
        # Where the staircase leaves the offline pass no surer than live (no frame crossing
        # in any window: neither knows more than the other) the live instant stands,
        # unless no straight line fitted live: offline is never worse than live.
        doubts = np.array([d for _, d in solved])
        after = np.minimum(np.searchsorted(anchors, x, side="right"), len(anchors) - 1)
        doubt = np.maximum(doubts[after], doubts[np.maximum(after - 1, 0)])
        clock = OnlineClock(self.filter_delay_ns, self.floor_ns, self.frame_ns,
                            serial=self.serial)
        clock.fits = []
        live = clock.update(x, rx, *live_parts)
        fit_at = np.array([t for t, _ in clock.fits], np.int64)
        fit_doubt = np.array([math.inf] + [d for _, d in clock.fits])
        live_doubt = fit_doubt[np.searchsorted(fit_at, x, side="right")]
        sure = (doubt < _PINNED * self.frame_ns) | (doubt < _SURER * live_doubt)
        return np.where(sure, out, live)

    def _solve(self, x: np.ndarray, y: np.ndarray, bx: np.ndarray, by: np.ndarray, at: int,
               rate: float, staircase: bool, half: int) -> tuple[float, float]:
        """The line's value at ticks ``at``, from the window around it that pins it best.

        The value is less ``y[0]`` (in float64 the absolute value would be rounded to
        256 ns), with the extent of the lines the staircase allows there (inf: the
        envelope's); ``half``: half the envelope's window, where no staircase does.
        """
        halves = [round(w * TICKS_PER_SECOND / 2) for w in _WINDOWS_S]
        if len(bx):
            spans = [(int(np.searchsorted(bx, at - h)), int(np.searchsorted(bx, at + h)))
                     for h in halves]
            centre = best_centre(bx, by, at, self.frame_ns, rate, spans)
            if centre is not None:
                return float(centre[1] - int(y[0])), centre[3]
        # the shortest window, moved inside the recording near its ends: a window cut
        # short there would let the envelope pivot on the last few points
        middle = max(int(x[0]) + half, min(at, int(x[-1]) - half))
        lo, hi = np.searchsorted(x, [middle - half, middle + half])
        lo, hi = max(0, lo - 1), max(hi + 1, lo + 2)
        return self._envelope(x[lo:hi], y[lo:hi], int(y[0]), at, middle, rate,
                              staircase), math.inf

    def _line_window(self, rate: float) -> float:
        """Seconds of envelope.

        The shortest on a UART; behind frames, long enough for the unit's phase to sweep
        ``_SWEEP`` of a frame at its rate against the host's.
        """
        if not self.frame_ns:
            return _LINE_S[0]
        ppm = abs(NS_PER_TICK / rate - 1.0) * 1e6
        sweep_s = _SWEEP * self.frame_ns / 1e3 / max(ppm, 1e-9)  # phase moves ppm us/s
        return min(_LINE_S[1], max(_LINE_S[0], sweep_s))

    def _envelope(self, x: np.ndarray, y: np.ndarray, base: int, at: int, middle: int,
                  rate: float, staircase: bool) -> float:
        """The lower envelope's value at ``at`` less ``base``.

        Its slope is judged at ``middle``; half of the frame uncovered is taken off.
        """
        dx, dy = (x - middle).astype(np.float64), (y - int(y[0])).astype(np.float64)
        slope = support_slope(dx, dy, rate) if len(x) > 1 else rate
        residual = dy - slope * dx
        level = float(np.min(residual)) + slope * (at - middle)
        if not staircase:
            return (int(y[0]) - base) + level
        return (int(y[0]) - base) + level - uncovered_half(residual - float(np.min(residual)),
                                                  self.frame_ns)
