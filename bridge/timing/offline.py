"""Re-estimate sample instants over a whole recording (the recorder's second pass).

Online, a record's time can only use what came before it; offline, every record
has the points on both sides. At anchors a few seconds apart the smoother takes
the shortest window around the anchor in which the frame staircase pins one
straight line (a long one for a unit whose phase crawls across the frame, a
short one where it sweeps the frame and wander would bend a longer line) and
puts the anchor in the middle of every line the points allow; records between
anchors are interpolated. Without a frame grid (a serial line), or where wander
bends every window so that no straight line fits its staircase, an anchor gets
the lower envelope's line through the shortest window, less half of the frame
its points leave uncovered: nothing where the phase has swept the frame (the
envelope then runs along the staircase's corners), half a frame where it has not.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from bridge.protocol.table import TICKS_PER_SECOND
from bridge.timing.clock import (
    best_centre,
    bucket_minima,
    grid_histogram,
    grid_phase,
    snap_to,
    support_slope,
    uncovered_half,
)
from bridge.timing.unwrap import NS_PER_TICK

# Shortest first. The longest lets a unit that beats slowly against the frame clock
# and crossed a frame boundary once keep that crossing in view ten minutes later.
_WINDOWS_S = (60.0, 120.0, 300.0, 600.0, 1200.0)


class OfflineClock:
    """Maps one epoch's unwrapped ticks to host ns using the whole recording.

    Parameters as ``OnlineClock``; ``anchor_s`` is the spacing of solved points.
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
        """Sample instants (host ns) of valid records of one epoch, increasing ticks;
        ``part_ns``, ``part_lead_ns`` as ``OnlineClock.update``'s."""
        x = np.asarray(ticks, np.int64)
        y = np.asarray(rx_ns, np.int64) - self.floor_ns
        if x.shape != y.shape:
            raise ValueError(f"ticks and rx_ns differ in length: {x.shape} vs {y.shape}")
        if len(x) == 0:
            return np.zeros(0, np.int64)
        if part_ns is None or part_lead_ns is None:
            q, g = y, np.zeros(0, np.int64)
        else:
            q = np.asarray(part_ns, np.int64) - self.floor_ns
            g = self.floor_ns - np.asarray(part_lead_ns, np.int64)
            if q.shape != y.shape or g.shape != y.shape:
                raise ValueError("part_ns and part_lead_ns must match rx_ns in length")
        if self.frame_ns:
            phase = grid_phase(grid_histogram(y, self.frame_ns), self.frame_ns)
            y = snap_to(y, phase, self.frame_ns)
            if len(g):
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
        staircase = self.frame_ns and not self.serial
        bx, by = bucket_minima(x, y, rate) if staircase else (empty, empty)
        values = np.array([self._solve(x, y, bx, by, int(a), rate) for a in anchors.tolist()])
        out = y0 + np.round(np.interp(dx, (anchors - x0).astype(np.float64), values - y0))
        return np.asarray(out, np.int64) - self.filter_delay_ns

    def _solve(self, x: np.ndarray, y: np.ndarray, bx: np.ndarray, by: np.ndarray, at: int,
               rate: float) -> float:
        """The line's value at ticks ``at`` from the window around it that pins it best."""
        halves = [round(w * TICKS_PER_SECOND / 2) for w in _WINDOWS_S]
        if len(bx):
            spans = [(int(np.searchsorted(bx, at - h)), int(np.searchsorted(bx, at + h)))
                     for h in halves]
            centre = best_centre(bx, by, at, self.frame_ns, rate, spans)
            if centre is not None:
                return float(centre[1])
        lo, hi = np.searchsorted(x, [at - halves[0], at + halves[0]])
        lo, hi = max(0, lo - 1), max(hi + 1, lo + 2)
        return self._envelope(x[lo:hi], y[lo:hi], at, rate)

    def _envelope(self, x: np.ndarray, y: np.ndarray, at: int, rate: float) -> float:
        """The lower envelope's value at ``at``, less half of the frame uncovered."""
        dx, dy = (x - at).astype(np.float64), (y - int(y[0])).astype(np.float64)
        slope = support_slope(dx, dy, rate) if len(x) > 1 else rate
        residual = dy - slope * dx
        level = float(np.min(residual))
        if self.serial or not self.frame_ns:
            return int(y[0]) + level
        return int(y[0]) + level - uncovered_half(residual - level, self.frame_ns)
