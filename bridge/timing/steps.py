"""Host clock steps found in receive times alone: captures with no raw-clock stamps.

Another program's capture, or one from before reads were stamped on the raw clock, has
realtime receive times only, and the host may have stepped that clock while it ran. A
step shows in the data itself, as a lasting move of the lower envelope of receive time
less nominal device time (``find_steps``). Each step found is taken out from the first
record it shows in (``raw_like``), giving receive times on a clock that was never
stepped, as a raw clock's would be; the realtime ones stay for mapping instants back
onto the stepped clock (``bridge.timing.realtime``). How a step is told from a stall or
a backlog: docs/design/time.md.

Steps of ``THRESHOLD_NS`` and more are found; smaller ones stay in the data as the
clock model would take any change of latency.
"""

from __future__ import annotations

import numpy as np

from bridge.protocol.table import TICKS_PER_SECOND
from bridge.timing.unwrap import NS_PER_TICK

THRESHOLD_NS = 2_000_000
_BUCKET_TICKS = TICKS_PER_SECOND // 2
_CONFIRM = 6  # half seconds the envelope must stay at its new level
_HISTORY = 20  # half seconds of envelope the level before a step is judged from
_BREAK_TICKS = 600 * TICKS_PER_SECOND  # a timer jump longer than this starts anew


def unwrap_timer(timer: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """32-bit timers as increasing ticks, and where each stretch of one epoch begins.

    A timer that went back, or jumped ten minutes, is a reset. Rough, for finding steps:
    the unwrapper proper times the records.

    Args:
        timer: The records' timers, in the order they were read.

    Returns:
        The ticks, and the index of each epoch's first record (0 first).
    """
    step = np.mod(np.diff(np.asarray(timer, np.int64)), 1 << 32)
    breaks = np.flatnonzero(step > _BREAK_TICKS) + 1
    step[step > _BREAK_TICKS] = 0
    return np.concatenate([[0], np.cumsum(step)]), np.concatenate([[0], breaks])


def find_steps(ticks: np.ndarray, rx_ns: np.ndarray) -> list[tuple[int, int]]:
    """Each step of the clock that stamped ``rx_ns``.

    Args:
        ticks: The ticks of records of one epoch, in the order they were read.
        rx_ns: Their receive times on the (realtime) clock that may have stepped.

    Returns:
        Per step, the index of the first record on the new clock and the step's size in
        ns.
    """
    ticks = np.asarray(ticks, np.int64)
    y = np.asarray(rx_ns, np.int64) - ticks * NS_PER_TICK
    steps: list[tuple[int, int]] = []
    bucket = ticks // _BUCKET_TICKS
    starts = np.concatenate([[0], np.flatnonzero(np.diff(bucket)) + 1, [len(y)]])
    good: list[tuple[int, int]] = []  # (tick, envelope) of settled half seconds
    lows = _lows(y, starts)
    j = 0
    while j < len(starts) - 1:
        t = ticks[starts[j]]
        line = _Line(good)
        if not good or abs(int(lows[j]) - line.at(int(t))) <= THRESHOLD_NS:
            good = [*good[-_HISTORY + 1:], (int(t), int(lows[j]))]
            j += 1
            continue
        ahead = np.arange(j, min(j + _CONFIRM, len(starts) - 1))
        devs = lows[ahead] - line.at(ticks[starts[ahead]])
        size = int(np.median(devs))
        if abs(size) <= THRESHOLD_NS or np.abs(devs - size).max() > THRESHOLD_NS or \
                (size > 0 and len(devs) < 2):
            j += 1  # a stall, a backlog or a stray record: not a level that stays
            continue
        lo, hi = starts[max(0, j - 1)], starts[min(j + 2, len(starts) - 1)]
        moved = y[lo:hi] - line.at(ticks[lo:hi]) - size // 2
        if size < 0:  # the first lower than the old level allows
            first = int(lo + np.argmax(moved < 0))
        else:  # the first from which every record stays above it
            below = np.flatnonzero(np.minimum.accumulate(moved[::-1])[::-1] <= 0)
            first = int(lo + (below[-1] + 1 if len(below) else 0))
        steps.append((first, size))
        y[first:] -= size
        lows = _lows(y, starts)
    return steps


def _lows(y: np.ndarray, starts: np.ndarray) -> np.ndarray:
    return np.minimum.reduceat(y, starts[:-1]) if len(y) else np.zeros(0, np.int64)


class _Line:
    """The envelope expected from the settled half seconds before.

    Their line where there are several (the unit's drift), else the last one's level.
    """

    def __init__(self, good: list[tuple[int, int]]) -> None:
        self.tick, self.level, self.slope = (good[-1][0], float(good[-1][1]), 0.0) if good \
            else (0, 0.0, 0.0)
        if len(good) >= 3:
            t = np.array([g[0] for g in good], np.float64) - self.tick
            v = np.array([g[1] for g in good], np.float64) - self.level
            self.slope, base = np.polyfit(t, v, 1)
            self.level += base

    def at(self, ticks: np.ndarray | int) -> np.ndarray:
        return np.round(self.level + self.slope * (np.asarray(ticks) - self.tick)).astype(
            np.int64)


def raw_like(real_ns: np.ndarray, completing: np.ndarray,
             steps: list[tuple[int, int]]) -> np.ndarray:
    """Receive times of every read with the steps taken out.

    Each step is taken out from the read that completed the first record on the new
    clock. A read between that one and the read before it (part of that record) goes
    with whichever side keeps the reads in order.

    Args:
        real_ns: Every read's receive time on the clock that stepped.
        completing: Each record's read (index into ``real_ns``).
        steps: ``find_steps``' answer.

    Returns:
        The reads' receive times as a clock that never stepped would give them.
    """
    real = np.asarray(real_ns, np.int64)
    moved = np.zeros(len(real), np.int64)
    for first, size in steps:
        after = int(completing[first])
        before = int(completing[first - 1]) if first > 0 else -1
        moved[after:] += size
        lo = real[before] - moved[before] if before >= 0 else np.iinfo(np.int64).min
        hi = real[after] - moved[after]
        for i in range(before + 1, after):
            # on the new clock if that keeps it between its neighbours, or if neither does
            if lo < real[i] - moved[i] - size < hi or not lo < real[i] - moved[i] < hi:
                moved[i] += size
    return real - moved
