"""Re-estimate sample instants over a whole recording (gx3 export's second pass).

Online, a record's time can only use what came before it; offline, every record has
the bounds on both sides. The smoother solves anchors a few seconds apart, each from
the window around it that pins the line best, and interpolates the records between
them. Over USB frames the live clock is run on the same records too, and where the
offline pass is no surer the live instant stands: never worse than live. How the
windows and anchors are chosen: docs/design/time.md.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from bridge.protocol.table import TICKS_PER_SECOND
from bridge.timing._fit import (
    NO_BOUND,
    Bounds,
    best_centre,
    bucket_minima,
    framed_bounds,
    grid_histogram,
    grid_phase,
    support_slope,
    uncovered_half,
)
from bridge.timing.clock import OnlineClock, record_bounds
from bridge.timing.unwrap import NS_PER_TICK

# Shortest first. The longest lets a unit that beats slowly against the frame clock
# and crossed a frame boundary once keep that crossing in view ten minutes later; where
# reads end inside records, the shortest pins the line to a byte.
_WINDOWS_S = (20.0, 60.0, 120.0, 300.0, 600.0, 1200.0)
_PINNED = 0.25  # of a frame: an extent this narrow means a crossing pinned the line
_SURER = 0.75  # or this much narrower than live's


class Estimate(NamedTuple):
    """Sample instants and how sure each is.

    ``time_ns``: host ns, the instant each record's values describe; ``uncertainty_ns``:
    the most each can be off by, as the reads bound it (half the spread of the lines
    they allow; 0: not known, where reads bound records from one side only).
    """

    time_ns: npt.NDArray[np.int64]
    uncertainty_ns: npt.NDArray[np.int64]


class OfflineClock:
    """Maps one epoch's unwrapped ticks to host ns using the whole recording.

    Args:
        delay_ns: As ``OnlineClock``'s.
        floor_ns: As ``OnlineClock``'s.
        frame_ns: As ``OnlineClock``'s.
        anchor_s: The spacing of solved points, seconds of the unit's clock.
        serial: As ``OnlineClock``'s.
        byte_ns: As ``OnlineClock``'s.
        prompt: As ``OnlineClock``'s.

    Raises:
        ValueError: A negative delay, floor, frame or byte time, or an anchor spacing
            that is not positive.
    """

    def __init__(self, delay_ns: int = 0, floor_ns: int = 0, frame_ns: int = 0,
                 anchor_s: float = 5.0, serial: bool = False, byte_ns: float = 0.0,
                 prompt: bool = True) -> None:
        if delay_ns < 0 or floor_ns < 0 or frame_ns < 0 or byte_ns < 0 or anchor_s <= 0:
            raise ValueError("delay_ns, floor_ns, frame_ns, byte_ns must be >= 0, "
                             "anchor_s > 0")
        self.delay_ns = int(delay_ns)
        self.floor_ns = int(floor_ns)
        self.frame_ns = int(frame_ns)
        self.serial = serial
        self.byte_ns = float(byte_ns)
        self.prompt = prompt
        self._anchor = max(1, round(anchor_s * TICKS_PER_SECOND))

    def smooth(self, ticks: npt.ArrayLike, rx_ns: npt.ArrayLike,
               part_ns: npt.ArrayLike | None = None,
               part_lead_ns: npt.ArrayLike | None = None) -> npt.NDArray[np.int64]:
        """Sample instants of the valid records of one epoch (``estimate``'s ``time_ns``).

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
        return self.estimate(ticks, rx_ns, part_ns, part_lead_ns).time_ns

    def estimate(self, ticks: npt.ArrayLike, rx_ns: npt.ArrayLike,
                 part_ns: npt.ArrayLike | None = None,
                 part_lead_ns: npt.ArrayLike | None = None) -> Estimate:
        """Sample instants of the valid records of one epoch, and how sure each is.

        Args:
            ticks: The records' unwrapped ticks, increasing.
            rx_ns: The receive time of the read that completed each.
            part_ns: As ``OnlineClock.update``'s.
            part_lead_ns: As ``OnlineClock.update``'s.

        Returns:
            Host ns, filter delay taken out, and the most each can be off by.

        Raises:
            ValueError: The arrays differ in length.
        """
        x = np.asarray(ticks, np.int64)
        rx = np.asarray(rx_ns, np.int64)
        if x.shape != rx.shape:
            raise ValueError(f"ticks and rx_ns differ in length: {x.shape} vs {rx.shape}")
        if len(x) == 0:
            return Estimate(np.zeros(0, np.int64), np.zeros(0, np.int64))
        floor = self.floor_ns
        if part_ns is None or part_lead_ns is None:
            p, lead = rx, np.full(len(rx), floor, np.int64)
        else:
            p, lead = np.asarray(part_ns, np.int64), np.asarray(part_lead_ns, np.int64)
            if p.shape != rx.shape or lead.shape != rx.shape:
                raise ValueError("part_ns and part_lead_ns must match rx_ns in length")
        if self.frame_ns:
            edge = grid_phase(grid_histogram(rx, self.frame_ns), self.frame_ns)
            y, lo = record_bounds(rx, p, lead, edge, self.frame_ns, floor,
                                  self.byte_ns if self.serial else 0.0, self.prompt)
        else:
            y = np.where(lead > 0, np.minimum(rx - floor, p - lead), rx - floor)
            lo = np.full(len(y), NO_BOUND, np.int64)
        x0, y0 = int(x[0]), int(y[0])
        dx, dy = (x - x0).astype(np.float64), (y - y0).astype(np.float64)
        # The lower envelope's slope under the middle of the recording: the mean rate to
        # within a frame over half the span (judged at an end it is the first hull
        # edge's, which a staircase can tilt by hundreds of ppm).
        rate = support_slope(dx - dx[-1] / 2, dy, float(NS_PER_TICK))
        anchors = np.arange(x0, int(x[-1]) + self._anchor, self._anchor)
        polygon = bool(self.frame_ns)
        bounds = _bucket_bounds(x, y, lo, rate, self.frame_ns) if polygon else None
        # the envelope's window (on a UART, or over frames where no straight line meets
        # every bound) is the shortest: as short as wander wants
        half = round(_WINDOWS_S[0] * TICKS_PER_SECOND / 2)
        solved = [self._solve(x, y, bounds, int(a), rate, half) for a in anchors.tolist()]
        values = np.array([v for v, _ in solved])
        step = np.round(np.interp(dx, (anchors - x0).astype(np.float64), values))
        out: npt.NDArray[np.int64] = y0 + step.astype(np.int64) - self.delay_ns
        if not polygon:
            return Estimate(out, np.zeros(len(out), np.int64))
        # Where the bounds leave the offline pass no surer than live (no frame crossing
        # in any window: neither knows more than the other) the live instant stands,
        # unless no straight line fitted live: offline is never worse than live.
        doubts = np.array([d for _, d in solved])
        after = np.minimum(np.searchsorted(anchors, x, side="right"), len(anchors) - 1)
        doubt = np.maximum(doubts[after], doubts[np.maximum(after - 1, 0)])
        clock = OnlineClock(self.delay_ns, floor, self.frame_ns, serial=self.serial,
                            byte_ns=self.byte_ns, prompt=self.prompt)
        clock.fits = []
        live = clock.update(x, rx, p, lead)
        fit_at = np.array([t for t, _ in clock.fits], np.int64)
        fit_doubt = np.array([math.inf] + [d for _, d in clock.fits])
        live_doubt = fit_doubt[np.searchsorted(fit_at, x, side="right")]
        sure = (doubt < _PINNED * self.frame_ns) | (doubt < _SURER * live_doubt)
        extent = np.where(sure, doubt, live_doubt)
        return Estimate(np.where(sure, out, live),
                        np.where(np.isfinite(extent), np.ceil(extent / 2), 0).astype(np.int64))

    def _solve(self, x: np.ndarray, y: np.ndarray, bounds: Bounds | None, at: int,
               rate: float, half: int) -> tuple[float, float]:
        """The line's value at ticks ``at``, from the window around it that pins it best.

        The value is less ``y[0]`` (in float64 the absolute value would be rounded to
        256 ns), with the extent of the lines the bounds allow there (inf: the
        envelope's); ``half``: half the envelope's window, where no polygon does.
        """
        if bounds is not None:
            spans = [(at - h, at + h) for h in
                     (round(w * TICKS_PER_SECOND / 2) for w in _WINDOWS_S)]
            centre = best_centre(bounds, at, rate, spans)
            if centre is not None:
                return float(centre.value - int(y[0])), centre.extent
        # the shortest window, moved inside the recording near its ends: a window cut
        # short there would let the envelope pivot on the last few points
        middle = max(int(x[0]) + half, min(at, int(x[-1]) - half))
        lo, hi = np.searchsorted(x, [middle - half, middle + half])
        lo, hi = max(0, lo - 1), max(hi + 1, lo + 2)
        return self._envelope(x[lo:hi], y[lo:hi], int(y[0]), at, middle, rate), math.inf

    def _envelope(self, x: np.ndarray, y: np.ndarray, base: int, at: int, middle: int,
                  rate: float) -> float:
        """The lower envelope's value at ``at`` less ``base``.

        Its slope is judged at ``middle``; over frames, half of the frame the points
        leave uncovered is taken off.
        """
        dx, dy = (x - middle).astype(np.float64), (y - int(y[0])).astype(np.float64)
        slope = support_slope(dx, dy, rate) if len(x) > 1 else rate
        residual = dy - slope * dx
        level = float(np.min(residual)) + slope * (at - middle)
        if not self.frame_ns:
            return (int(y[0]) - base) + level
        return (int(y[0]) - base) + level - uncovered_half(residual - float(np.min(residual)),
                                                           self.frame_ns)


def _bucket_bounds(x: np.ndarray, hi: np.ndarray, lo: np.ndarray, rate: float,
                   frame: int) -> Bounds:
    """Each whole quarter second's tightest bounds, as ``OnlineClock`` keeps them."""
    xh, yh = bucket_minima(x, hi, rate)
    known = lo > NO_BOUND
    xl, neg = bucket_minima(x[known], -lo[known], -rate)
    return framed_bounds(xh, yh, xl, -neg, frame)
