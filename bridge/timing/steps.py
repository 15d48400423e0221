"""Host clock steps found in receive times alone: captures with no raw-clock stamps.

Another program's capture, or one from before reads were stamped on the raw clock, has
realtime receive times only, and the host may have stepped that clock while it ran. A
step shows in the data itself, as a lasting move of the lower envelope of receive time
less nominal device time (``find_steps``). Each step found is taken out from the first
record it shows in (``raw_like``), giving receive times on a clock that was never
stepped, as a raw clock's would be; the realtime ones stay for mapping instants back
onto the stepped clock (``bridge.timing.realtime``). How a step is told from a stall or
a backlog, and how its size is measured: docs/design/time.md.

Steps of ``THRESHOLD_NS`` and more are found; smaller ones stay in the data as the
clock model would take any change of latency.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bridge.protocol.table import TICKS_PER_SECOND
from bridge.timing._fit import grid_histogram, grid_phase
from bridge.timing.unwrap import NS_PER_TICK

THRESHOLD_NS = 2_000_000
_BUCKET_TICKS = TICKS_PER_SECOND // 2
_CONFIRM = 6  # half seconds ahead the new level is judged from
_HOLD = 2  # half seconds a rise must hold to be a step (a backlog's falls at once)
_HISTORY = 20  # half seconds of envelope the level before a step is judged from
_BREAK_TICKS = 600 * TICKS_PER_SECOND  # a timer jump longer than this starts anew
_SIDE_TICKS = 3 * TICKS_PER_SECOND  # the stretch either side a step is measured over
_GUARD_TICKS = TICKS_PER_SECOND // 20  # left out next to a step: reads may be on either clock
# a frame's jump of the envelope (1 ms) stands out of a tread's fine structure, a few
# hundred µs at most (an adapter's packets): a third of a frame tells it
_JUMP_NS = 300_000  # the envelope this far below the records next to a step has jumped
# the staircase jumps every few tens of seconds (a frame / the unit's rate error), so a
# tenth of a second next to a step rarely holds a jump, and holds several reads at 100 Hz
_NEAR_TICKS = TICKS_PER_SECOND // 10  # the records next to a step its envelope is taken from
_TRUST_NS = 50_000  # a record this far under a measured line is not on its clock
_READ_RECORDS = 4096  # records one read holds at most (a backlog's), looked back over
_RATE_PPM = 150.0  # the unit's rate is within this of nominal (the manual: 100)


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


def find_steps(ticks: np.ndarray, rx_ns: np.ndarray, frame_ns: int = 0) -> list[tuple[int, int]]:
    """Each step of the clock that stamped ``rx_ns``.

    The half-second envelope tells roughly where a step is and that it is one
    (``_envelope_steps``); the lines under the records either side then place its first
    record (``_located``) and measure it to microseconds (``_settled``), where half a
    second of envelope leaves it a millisecond or more out. Over USB frames, the shift of
    the frames' phase gives the size within a frame exactly (``_on_grid``).

    Args:
        ticks: The ticks of records of one epoch, in the order they were read.
        rx_ns: Their receive times on the (realtime) clock that may have stepped.
        frame_ns: The USB frame where frames carried the reads (native USB, an adapter),
            0 on a UART.

    Returns:
        Per step, the index of the first record on the new clock and the step's size in
        ns.
    """
    ticks = np.asarray(ticks, np.int64)
    rx = np.asarray(rx_ns, np.int64)
    bucket = ticks // _BUCKET_TICKS
    starts = np.concatenate([[0], np.flatnonzero(np.diff(bucket)) + 1, [len(rx)]])
    rough = _envelope_steps(ticks[starts[:-1]], _lows(rx - ticks * NS_PER_TICK, starts))
    # where each step may lie: the half second it showed in and the one before
    spans = [(int(starts[j - 1]), int(starts[j + 1])) for j, _ in rough]
    located: list[tuple[int, int]] = []
    for m, (j, size) in enumerate(rough):
        first = _located(ticks, rx, spans, m)
        first = int(starts[j]) if first is None else first
        if not located or first > located[-1][0]:  # else the envelope showed one step twice
            located.append((first, size))
    bounds = [0, *[first for first, _ in located], len(rx)]
    steps = [_settled(ticks, rx, bounds[k], first, bounds[k + 2], size)
             for k, (first, size) in enumerate(located)]
    if frame_ns:
        bounds = [0, *[first for first, _ in steps], len(rx)]
        steps = [(first, _on_grid(ticks, rx, (bounds[k], first, bounds[k + 2]), size, frame_ns))
                 for k, (first, size) in enumerate(steps)]
    return [step for step in steps if abs(step[1]) >= THRESHOLD_NS]  # else latency misled


def _lows(y: np.ndarray, starts: np.ndarray) -> np.ndarray:
    return np.minimum.reduceat(y, starts[:-1]) if len(y) else np.zeros(0, np.int64)


def _envelope_steps(ticks: np.ndarray, lows: np.ndarray) -> list[tuple[int, int]]:
    """The half seconds a step shows in, and its size as the envelope has it.

    Each half second's envelope is judged against the line of the settled ones before;
    one that moved past ``THRESHOLD_NS`` starts a step if the level it moved to holds.

    Args:
        ticks: The ticks each half second begins at.
        lows: The envelope of each half second: its least receive less device time.

    Returns:
        Per step, the index of the half second it showed in and its rough size (ns).
    """
    lows = lows.copy()
    good: list[tuple[int, int]] = []  # (tick, envelope) of settled half seconds
    steps: list[tuple[int, int]] = []
    j = 0
    while j < len(lows):
        line = _Line.through(good) if good else None
        if line is None or abs(int(lows[j]) - int(line.at(int(ticks[j])))) <= THRESHOLD_NS:
            good = [*good[-_HISTORY + 1:], (int(ticks[j]), int(lows[j]))]
            j += 1
            continue
        ahead = slice(j, j + _CONFIRM)
        size = _held_level(lows[ahead] - line.at(ticks[ahead]))
        if size is None:
            j += 1  # a stall, a backlog or a stray record: not a level that stays
            continue
        steps.append((j, size))
        lows[j:] -= size  # judged again on the old level, it settles
    return steps


def _held_level(moved: np.ndarray) -> int | None:
    """How far the envelope moved from a half second on, if that is a level it holds.

    The new level is the least of the half seconds from there on, up to one that drops
    more than ``THRESHOLD_NS`` below those before it: the next step, which may come
    soon. A move down holds by itself: no read comes earlier than the unit's clock
    allows. A move up must hold for ``_HOLD`` half seconds: a backlog read after a
    stall falls along a slope of one at once, and a half second with no prompt read
    is back at the old level in the next.

    Args:
        moved: From the half second that moved on, how far each is off the old line.

    Returns:
        The level's size in ns; None where it is no step.
    """
    before = np.minimum.accumulate(np.concatenate([moved[:1], moved[:-1]]))
    dropped = moved < before - THRESHOLD_NS
    run = moved[: int(np.argmax(dropped)) if dropped.any() else len(moved)]
    size = int(run.min())
    if abs(size) <= THRESHOLD_NS or (size > 0 and len(run) < _HOLD):
        return None
    return size


def _located(ticks: np.ndarray, rx: np.ndarray, spans: list[tuple[int, int]],
             m: int) -> int | None:
    """The first record on the new clock of step ``m``, within its span.

    It is placed between the lines of the few seconds either side of the span, which
    reach across it: ``_first_record``.

    Args:
        ticks: Every record's ticks.
        rx: Every record's receive time, ns.
        spans: Per step, the records it may lie among.
        m: The step.

    Returns:
        The record's index; None where the records either side do not tell.
    """
    lo, hi = spans[m]
    before = _stretch(ticks, spans[m - 1][1] if m else 0, lo, -_SIDE_TICKS)
    after = _stretch(ticks, spans[m + 1][0] if m + 1 < len(spans) else len(rx), hi,
                     _SIDE_TICKS)
    lines = _Line.pair(ticks, rx, before, after)
    if lines is None:
        return None
    back = lines[1].level < lines[0].level
    return _first_record(ticks, rx, (lo, hi), lines[0] if back else lines[1], back,
                         abs(lines[1].level - lines[0].level) // 2)


def _settled(ticks: np.ndarray, rx: np.ndarray, begin: int, first: int, end: int,
             rough: int) -> tuple[int, int]:
    """The step the envelope placed at record ``first``: its first record and size.

    Measured from the lines either side, leaving out the reads next to the step that
    may be on either clock; placed again with those lines (``_placed``); and measured
    again right up to the read it came at, so that a jump of the envelope (a link's
    frame) misleads only where it comes with the step itself.

    Args:
        ticks: Every record's ticks.
        rx: Every record's receive time, ns.
        begin: The previous step's first record (0: none).
        first: This step's first record, as the envelope placed it.
        end: The next step's first record (the number of records: none).
        rough: The step's size as the envelope had it, ns: kept where no record either
            side can measure it.

    Returns:
        The index of the first record on the new clock, and the step's size in ns.
    """
    lines = _measured(ticks, rx, begin, first, end, _GUARD_TICKS)
    if lines is None:
        return first, rough
    first = _placed(ticks, rx, first, lines)
    lines = _measured(ticks, rx, begin, first, end, 0) or lines
    return first, lines[1].level - lines[0].level  # both anchored at its first record


def _on_grid(ticks: np.ndarray, rx: np.ndarray, at: tuple[int, int, int], size: int,
             frame: int) -> int:
    """A step sized by how far it moved the phase of the frames the reads came at.

    Reads over USB come at the host controller's frames, which a step of the realtime
    clock does not move: only their stamps move, by the step, so the phase of the frames
    moves by the step modulo a frame, measured to a microsecond over the few seconds of
    reads either side. The envelope's size (within half a frame, unless a jump of the
    frame staircase came with the step) gives the whole frames.

    Args:
        ticks: Every record's ticks.
        rx: Every record's receive time, ns.
        at: The previous step's first record (0: none), this step's, and the next step's
            (the number of records: none).
        size: The step's size as the envelope's lines measured it, ns.
        frame: The USB frame, ns.

    Returns:
        The step's size, ns.
    """
    begin, first, end = at
    before = _stretch(ticks, begin, first, -_SIDE_TICKS, _GUARD_TICKS)
    after = _stretch(ticks, end, first, _SIDE_TICKS, _GUARD_TICKS)
    if before[0] >= before[1] or after[0] >= after[1]:
        return size
    phase_before, phase_after = (grid_phase(grid_histogram(rx[lo:hi], frame), frame)
                                 for lo, hi in (before, after))
    moved = (phase_after - phase_before) % frame
    return moved + frame * round((size - moved) / frame)


def _placed(ticks: np.ndarray, rx: np.ndarray, first: int,
            lines: tuple[_Line, _Line]) -> int:
    """Step ``first`` moved past the reads next to it that its measured lines place.

    Where a read on the old clock came later than half the step (or one on the new
    clock did, after a step back), the envelope placed it on the wrong side; the lines
    measured either side, to microseconds, put it back.

    Args:
        ticks: Every record's ticks.
        rx: Every record's receive time, ns.
        first: The step's first record, as the envelope placed it.
        lines: The lines before and after the step, anchored at its first record.

    Returns:
        The first record on the new clock.
    """
    back = lines[1].level < lines[0].level
    near = _stretch(ticks, 0, first, -_GUARD_TICKS) if back else \
        _stretch(ticks, len(ticks), first, _GUARD_TICKS)
    moved = _first_record(ticks, rx, _read_aligned(rx, near), lines[0] if back else lines[1],
                          back, _TRUST_NS)
    return first if moved is None else moved


def _read_aligned(rx: np.ndarray, span: tuple[int, int]) -> tuple[int, int]:
    """``span`` begun at the first record of the read its first record came in."""
    lo, hi = span
    if lo >= hi:
        return span
    back = max(0, lo - _READ_RECORDS)
    other = np.flatnonzero(rx[back:lo] != rx[lo])
    return (back + int(other[-1]) + 1 if len(other) else back), hi


def _stretch(ticks: np.ndarray, stop: int, edge: int, reach: int,
             guard: int = 0) -> tuple[int, int]:
    """The records between ``guard`` and ``reach`` ticks before or after record ``edge``.

    They stop short of record ``stop`` (another step's first, or an end) by ``guard``
    too: next to a step, reads may be on either clock.

    Args:
        ticks: Every record's ticks (one epoch: never decreasing).
        stop: The record the stretch stops at: 0 or one before ``edge`` when reaching
            back, the number of records or one after it when reaching forward.
        edge: The record it reaches from.
        reach: How far it reaches, ticks; negative: back.
        guard: Ticks left out next to ``edge`` and next to a step at ``stop``.

    Returns:
        The stretch's index range.
    """
    n = len(ticks)
    if edge >= n:
        return n, n
    at = int(ticks[edge])
    if reach < 0:
        lo = int(np.searchsorted(ticks, at + reach))
        if stop > 0:
            lo = max(lo, int(np.searchsorted(ticks, int(ticks[stop]) + guard)))
        return lo, max(lo, int(np.searchsorted(ticks, at - guard)))
    hi = int(np.searchsorted(ticks, at + reach))
    if stop < n:
        hi = min(hi, int(np.searchsorted(ticks, int(ticks[stop]) - guard)))
    return min(hi, int(np.searchsorted(ticks, at + guard))), hi


def _measured(ticks: np.ndarray, rx: np.ndarray, begin: int, first: int, end: int,
              guard: int) -> tuple[_Line, _Line] | None:
    """The envelope's lines either side of the step at record ``first``.

    The envelope continues across a step, shifted by it, so its lines over the few
    seconds right before and right after (``_Line.pair``) give the size to
    microseconds. A stretch the envelope jumped in (a link's frame) is cut at the jump
    (``_unjumped``).

    Args:
        ticks: Every record's ticks.
        rx: Every record's receive time, ns.
        begin: The previous step's first record (0: none).
        first: This step's first record.
        end: The next step's first record (the number of records: none).
        guard: Ticks left out next to each step, where reads may be on either clock.

    Returns:
        The lines before and after, anchored at the ticks of record ``first``: the
        step's size is the difference of their levels. None where no record either side
        could measure it.
    """
    at = int(ticks[first])
    before = _stretch(ticks, begin, first, -_SIDE_TICKS, guard)
    after = _stretch(ticks, end, first, _SIDE_TICKS, guard)
    lines = _Line.pair(ticks, rx, _unjumped(ticks, rx, before, True),
                       _unjumped(ticks, rx, after, False))
    return None if lines is None else (lines[0].moved_to(at), lines[1].moved_to(at))


def _unjumped(ticks: np.ndarray, rx: np.ndarray, window: tuple[int, int],
              ends_at_step: bool) -> tuple[int, int]:
    """``window`` up to a jump of the envelope down, counting from the step.

    On a link with frames the envelope is flat between its jumps (the unit's records
    keep their phase against the frames, and come at whole milliseconds), so a record
    ``_JUMP_NS`` below the least of those within ``_NEAR_TICKS`` of the step is beyond a
    jump,
    where the envelope would hold the step's line down; so may be the records up to
    ``_GUARD_TICKS`` before it, which came late. Without frames the envelope only
    drifts, by about that over the stretch, and a cut there costs nothing.

    Args:
        ticks: Every record's ticks.
        rx: Every record's receive time, ns.
        window: The stretch's records.
        ends_at_step: Whether the stretch ends at the step (else it begins there).

    Returns:
        The records from the step up to the jump; ``window`` where there is none.
    """
    lo, hi = window
    if lo >= hi:
        return window
    t = ticks[lo:hi]
    y = rx[lo:hi] - t * NS_PER_TICK
    outward = y[::-1] if ends_at_step else y
    near = int(np.count_nonzero(t >= t[-1] - _NEAR_TICKS if ends_at_step
                                else t <= t[0] + _NEAR_TICKS))
    beyond = np.flatnonzero(outward < outward[:near].min() - _JUMP_NS)
    if not len(beyond):
        return window
    if ends_at_step:
        jump = int(ticks[hi - 1 - int(beyond[0])])
        return lo + int(np.searchsorted(ticks[lo:hi], jump + _GUARD_TICKS, "right")), hi
    jump = int(ticks[lo + int(beyond[0])])
    return lo, lo + int(np.searchsorted(ticks[lo:hi], jump - _GUARD_TICKS))


@dataclass(frozen=True)
class _Line:
    """A line of receive time less nominal device time, against ticks.

    Attributes:
        tick: The ticks the line is anchored at.
        level: Its value there, ns.
        slope: Its slope, ns per tick: the unit's rate error.
    """

    tick: int
    level: int
    slope: float = 0.0

    @classmethod
    def through(cls, good: list[tuple[int, int]]) -> _Line:
        """The envelope expected from the settled half seconds before.

        Their line where there are several (the unit's drift), else the last one's level.
        """
        tick, level = good[-1]
        if len(good) < 3:
            return cls(tick, level)
        t = np.array([g[0] for g in good], np.float64) - tick
        v = np.array([g[1] for g in good], np.float64) - level
        slope, base = np.polyfit(t, v, 1)
        return cls(tick, level + round(float(base)), float(slope))

    @classmethod
    def pair(cls, ticks: np.ndarray, rx: np.ndarray, before: tuple[int, int],
             after: tuple[int, int]) -> tuple[_Line, _Line] | None:
        """The highest two parallel lines, one under the records of each window.

        Their common slope is the one at which they stand highest together between the
        windows: the envelope's own across a step between them, which only moves the
        second line by the step. It is searched within ``_RATE_PPM`` of nominal, the
        unit's rate and the staircase's flat both being within that, so that a jump of
        the envelope cannot tilt it.

        Args:
            ticks: Every record's ticks.
            rx: Every record's receive time, ns.
            before: The index range of the records before.
            after: That of the records after.

        Returns:
            The line under each; None where a window is empty.
        """
        if before[1] <= before[0] or after[1] <= after[0]:
            return None
        at = (int(ticks[before[1] - 1]) + int(ticks[after[0]])) // 2
        sides = [((ticks[lo:hi] - at).astype(np.float64),
                  (rx[lo:hi] - rx[lo]).astype(np.float64)) for lo, hi in (before, after)]
        rate = _common_rate(sides, float(NS_PER_TICK), _RATE_PPM)
        first, second = (
            cls(at, int(rx[lo]) + round(float((dy - rate * dx).min())) - at * NS_PER_TICK,
                rate - NS_PER_TICK) for (dx, dy), (lo, _) in zip(sides, (before, after),
                                                                  strict=True))
        return first, second

    def at(self, ticks: np.ndarray | int) -> np.ndarray:
        return self.level + np.round(self.slope * (np.asarray(ticks) - self.tick)).astype(
            np.int64)

    def moved_to(self, tick: int) -> _Line:
        """The same line, anchored at ``tick``."""
        return _Line(tick, int(self.at(tick)), self.slope)


def _common_rate(sides: list[tuple[np.ndarray, np.ndarray]], prior: float,
                 ppm: float) -> float:
    """The slope r at which the lowest ``dy - r dx`` of each side, summed, is highest.

    The sum is concave in r and piecewise linear, each piece set by the lowest point of
    each side; each pass meets the pieces at the ends of the bracket, as
    ``bridge.timing._fit.support_slope`` does for one side, so a few passes find it.

    Args:
        sides: Per side, its points' ticks (from where the lines are judged) and host
            times (from a reference of its own).
        prior: The nominal slope, ns per tick.
        ppm: How far around it the slope is searched, ppm.

    Returns:
        The slope, ns per tick.
    """
    def piece(r: float) -> tuple[float, float]:
        lowest = [int((dy - r * dx).argmin()) for dx, dy in sides]
        return (sum(float(dy[i] - r * dx[i]) for (dx, dy), i in zip(sides, lowest, strict=True)),
                -sum(float(dx[i]) for (dx, _), i in zip(sides, lowest, strict=True)))

    lo, hi = prior * (1 - ppm * 1e-6), prior * (1 + ppm * 1e-6)
    (v_lo, g_lo), (v_hi, g_hi) = piece(lo), piece(hi)
    if g_lo <= 0 or g_hi >= 0:
        return lo if g_lo <= 0 else hi
    tie = 1e-12 * sum(float(np.abs(dy).max()) + hi * float(np.abs(dx).max()) for dx, dy in sides)
    for _ in range(64):
        r = (v_hi - v_lo + g_lo * lo - g_hi * hi) / (g_lo - g_hi)
        if not lo < r < hi:
            break
        v, g = piece(r)
        if v >= v_lo + g_lo * (r - lo) - tie or g == 0:
            return r
        if g > 0:
            lo, v_lo, g_lo = r, v, g
        else:
            hi, v_hi, g_hi = r, v, g
    return (lo + hi) / 2


def _first_record(ticks: np.ndarray, rx: np.ndarray, span: tuple[int, int], line: _Line,
                  back: bool, margin: int) -> int | None:
    """The first record on the new clock among the records of ``span``.

    Latency only ever lifts a record, so one more than ``margin`` under ``line`` is
    not on that line's clock: after a step back, ``line`` is the old clock's and such a
    record the new's; after a step forward, ``line`` is the new clock's and such a
    record the old's. The records of one read (they share a receive time) go together:
    a step back starts at the first read that reaches under the line, a step forward
    after the last one. A read that reaches under neither goes with the side it is
    least late on: the old clock after a step back, the new one after a step forward.

    Args:
        ticks: Every record's ticks.
        rx: Every record's receive time, ns.
        span: The records the step lies among, from the first of a read on.
        line: The line a step leaves records under.
        back: Whether the clock stepped back.
        margin: How far under ``line`` a record must be, ns.

    Returns:
        The record's index; None where no record reaches under the line, or (a step
        forward) the last read does.
    """
    lo, hi = span
    t = ticks[lo:hi]
    under = rx[lo:hi] - t * NS_PER_TICK < line.at(t) - margin
    if not under.any():
        return None
    read = np.concatenate([[0], np.cumsum(np.diff(rx[lo:hi]) != 0)])
    first_read = read[under].min() if back else read[under].max() + 1
    index = lo + int(np.searchsorted(read, first_read))
    return index if index < hi else None


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
