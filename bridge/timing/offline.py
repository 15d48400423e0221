"""Re-estimate sample instants over a whole recording (the recorder's second pass).

Online, a record's time can only use what came before it; offline, every record
has the points on both sides. At anchors a few seconds apart the smoother takes
the widest window around the anchor over which one straight line fits the frame
staircase (a long one for a unit whose phase crawls across the frame, a short
one where the rate wandered) and puts the anchor in the middle of every line
the points allow; records between anchors are interpolated. Without a frame grid
(a serial line) each anchor gets the lower envelope's line through its window.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from bridge.protocol.table import TICKS_PER_SECOND
from bridge.timing.clock import (
    bucket_minima,
    grid_histogram,
    polygon_centre,
    snap,
    support_slope,
)
from bridge.timing.unwrap import NS_PER_TICK

_WINDOWS_S = (600.0, 300.0, 120.0, 60.0, 30.0)


class OfflineClock:
    """Maps one epoch's unwrapped ticks to host ns using the whole recording.

    Parameters as ``OnlineClock``; ``anchor_s`` is the spacing of solved points.
    """

    def __init__(self, filter_delay_ns: int = 0, floor_ns: int = 0, frame_ns: int = 0,
                 anchor_s: float = 5.0) -> None:
        if filter_delay_ns < 0 or floor_ns < 0 or frame_ns < 0 or anchor_s <= 0:
            raise ValueError("filter_delay_ns, floor_ns, frame_ns must be >= 0, anchor_s > 0")
        self.filter_delay_ns = int(filter_delay_ns)
        self.floor_ns = int(floor_ns)
        self.frame_ns = int(frame_ns)
        self._anchor = max(1, round(anchor_s * TICKS_PER_SECOND))

    def smooth(self, ticks: npt.ArrayLike, rx_ns: npt.ArrayLike) -> npt.NDArray[np.int64]:
        """Sample instants (host ns) of valid records of one epoch, increasing ticks."""
        x = np.asarray(ticks, np.int64)
        y = np.asarray(rx_ns, np.int64) - self.floor_ns
        if x.shape != y.shape:
            raise ValueError(f"ticks and rx_ns differ in length: {x.shape} vs {y.shape}")
        if len(x) == 0:
            return np.zeros(0, np.int64)
        if self.frame_ns:
            y = snap(y, grid_histogram(y, self.frame_ns), self.frame_ns)
        x0, y0 = int(x[0]), int(y[0])
        dx, dy = (x - x0).astype(np.float64), (y - y0).astype(np.float64)
        rate = support_slope(dx, dy, float(NS_PER_TICK)) if len(x) > 1 else float(NS_PER_TICK)
        anchors = np.arange(x0, int(x[-1]) + self._anchor, self._anchor)
        values = np.array([self._solve(x, y, int(a), rate) for a in anchors.tolist()])
        out = y0 + np.round(np.interp(dx, (anchors - x0).astype(np.float64), values - y0))
        return np.asarray(out, np.int64) - self.filter_delay_ns

    def _solve(self, x: np.ndarray, y: np.ndarray, at: int, rate: float) -> float:
        """The line's value at ticks ``at`` from the widest window that fits."""
        for window in _WINDOWS_S:
            half = round(window * TICKS_PER_SECOND / 2)
            lo, hi = np.searchsorted(x, [at - half, at + half])
            if hi - lo < 2:
                continue
            if self.frame_ns:
                bx, by = bucket_minima(x[lo:hi], y[lo:hi], rate)
                centre = polygon_centre(bx, by, at, self.frame_ns, rate)
                if centre is not None:
                    return float(centre[1])
            else:
                return self._envelope(x[lo:hi], y[lo:hi], at, rate)
        lo, hi = np.searchsorted(x, [at - half, at + half])
        return self._envelope(x[max(0, lo - 1) : hi + 1], y[max(0, lo - 1) : hi + 1], at, rate)

    def _envelope(self, x: np.ndarray, y: np.ndarray, at: int, rate: float) -> float:
        """The lower envelope's value at ``at``; half a frame under it on USB."""
        dx, dy = (x - at).astype(np.float64), (y - int(y[0])).astype(np.float64)
        slope = support_slope(dx, dy, rate) if len(x) > 1 else rate
        return int(y[0]) + float(np.min(dy - slope * dx)) - self.frame_ns / 2
