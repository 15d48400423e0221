"""Timer in, sample instants out: the unwrapper and the clock model in step."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import numpy.typing as npt

from bridge.timing.clock import ClockState, OnlineClock
from bridge.timing.unwrap import TimerUnwrapper, TimingEvent, TimingKind, Unwrapped


@dataclass
class TimelineBatch:
    """One batch's timing, aligned with its records; drop those not ``valid``.

    ``ticks`` and ``time_ns`` are -1 where not valid; ``dropped`` counts samples the unit
    produced that never arrived (gaps).
    """

    ticks: npt.NDArray[np.int64]  # -1 where not valid
    time_ns: npt.NDArray[np.int64]  # -1 where not valid
    valid: npt.NDArray[np.bool_]
    events: list[TimingEvent] = field(default_factory=list)
    dropped: int = 0
    intact: bool = False  # known without looking: every record is valid


class Timeline:
    """Timer in, sample instants out: the unwrapper and the clock model in step.

    Feeds each batch's timers through the unwrapper and its valid records through the
    clock, restarting the clock at each reset (the tick base moved). A jump the receive
    times cannot back (a backlog read after a host stall) is judged by the clock as fed
    every record before it.

    Args:
        period_ticks: The output period in ticks (decimation x 62.5); None if unknown.
        delay_ns: As ``OnlineClock``'s.
        floor_ns: As ``OnlineClock``'s.
        frame_ns: As ``OnlineClock``'s.
        window_s: As ``OnlineClock``'s.
        serial: As ``OnlineClock``'s.
        byte_ns: As ``OnlineClock``'s.
        prompt: As ``OnlineClock``'s.
    """

    def __init__(self, period_ticks: float | None, delay_ns: int = 0,
                 floor_ns: int = 0, frame_ns: int = 0, window_s: float | None = None,
                 serial: bool = False, byte_ns: float = 0.0, prompt: bool = True) -> None:
        self.unwrapper = TimerUnwrapper(period_ticks)
        self.clock = OnlineClock(delay_ns, floor_ns, frame_ns, window_s, serial=serial,
                                 byte_ns=byte_ns, prompt=prompt)

    @property
    def state(self) -> ClockState:
        """The clock model now, for status."""
        return self.clock.state

    def expect_discontinuity(self, period_ticks: float | None = None) -> None:
        """The bridge reset the unit, set its timer or changed its sampling.

        Args:
            period_ticks: The new output period, if it changed.
        """
        self.unwrapper.expect_discontinuity(period_ticks)

    def update(self, timer: npt.ArrayLike, rx_ns: npt.ArrayLike,
               part_ns: npt.ArrayLike | None = None,
               part_lead_ns: npt.ArrayLike | None = None) -> TimelineBatch:
        """Ticks and sample instants of one batch's records.

        Args:
            timer: The records' timers (uint32).
            rx_ns: The receive time of the read that completed each.
            part_ns: The records' partial reads, for the clock (see
                ``OnlineClock.update``).
            part_lead_ns: The line time of the bytes each partial read held.

        Returns:
            Ticks, instants, validity and events, aligned with the records.

        Raises:
            ValueError: The arrays differ in length.
        """
        rx = np.asarray(rx_ns, np.int64)
        parts = None if part_ns is None or part_lead_ns is None else \
            np.stack([np.asarray(part_ns, np.int64), np.asarray(part_lead_ns, np.int64)])
        u = self.unwrapper.update(timer, rx, True)
        if u.pending is None:
            return self._timed(u, rx, parts)
        timers, done = np.asarray(timer), u.pending
        out = self._timed(u, rx[:done], None if parts is None else parts[:, :done])
        while done < len(rx):  # rare: a jump ahead of its receive time, judged
            self.unwrapper.judge(self.clock.horizon(int(rx[done])))
            u = self.unwrapper.update(timers[done:], rx[done:], True)
            end = done + len(u.ticks)
            out = _joined(out, self._timed(u, rx[done:end],
                                           None if parts is None else parts[:, done:end]), done)
            done = end
        return out

    def update_few(self, timers: list[int], rx_ns: list[int],
                   parts: tuple[list[int], list[int]] | None = None
                   ) -> tuple[list[int], list[int], list[TimingEvent]] | None:
        """``update`` of a few records in plain integers.

        Args:
            timers: The records' timers.
            rx_ns: The receive time of the read that completed each.
            parts: The partial reads' receive times and line times.

        Returns:
            Ticks, instants and rollovers, when the unwrapper takes the records as they
            are (each one period after the last); None: nothing changed, ask ``update``.
        """
        run = self.unwrapper.update_few(timers, rx_ns)
        if run is None:
            return None
        ticks, events = run
        return ticks, self.clock.update_few(ticks, rx_ns, parts), events

    def _timed(self, u: Unwrapped, rx: npt.NDArray[np.int64],
               parts: npt.NDArray[np.int64] | None) -> TimelineBatch:
        """Host times of one unwrapped stretch's valid records.

        The clock is restarted at each reset in it; ``parts``: the partial reads' times
        and line times, stacked.
        """
        resets = [e.index for e in u.events if e.kind == TimingKind.RESET]
        if not resets and u.all_valid:  # the common case, without index arithmetic
            time_ns = self.clock.update(u.ticks, rx, *(() if parts is None else parts))
            return TimelineBatch(u.ticks, time_ns, u.valid, u.events, u.dropped, intact=True)
        time_ns = np.full(len(rx), -1, np.int64)
        starts = [*resets, len(rx)]
        begin = 0
        for end in starts:
            part = np.flatnonzero(u.valid[begin:end]) + begin
            if len(part):
                time_ns[part] = self.clock.update(
                    u.ticks[part], rx[part], *(() if parts is None else parts[:, part]))
            if end < len(rx):
                self.clock.reset()
            begin = end
        return TimelineBatch(u.ticks, time_ns, u.valid, u.events, u.dropped)


def _joined(a: TimelineBatch, b: TimelineBatch, start: int) -> TimelineBatch:
    """Two consecutive stretches of one batch as one; ``b`` begins at ``start``."""
    return TimelineBatch(np.concatenate([a.ticks, b.ticks]), np.concatenate([a.time_ns, b.time_ns]),
                         np.concatenate([a.valid, b.valid]),
                         a.events + [replace(e, index=e.index + start) for e in b.events],
                         a.dropped + b.dropped, a.intact and b.intact)
