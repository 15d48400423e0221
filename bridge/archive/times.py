"""Instants of an archive as people give them: ``--start``, ``--end`` (ISO, or seconds)."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime

from bridge.exceptions import TimeSpanError

__all__ = ["TimeBound", "TimeSpan", "epoch_ns", "parse_time"]


@dataclass(frozen=True)
class TimeBound:
    """A --start/--end bound: absolute host time in ns, or seconds from the first sample."""

    ns: int
    relative: bool

    def resolve(self, first_ns: int) -> int:
        """The bound in host ns, for a recording whose first sample is at ``first_ns``."""
        return first_ns + self.ns if self.relative else self.ns


def parse_time(text: str) -> TimeBound:
    """``2026-11-22T02:50:00Z`` (ISO 8601; no zone = UTC) or ``12.5`` (s from the start).

    Raises:
        TimeSpanError: It is neither.
    """
    try:
        return TimeBound(round(float(text) * 1e9), relative=True)
    except ValueError:
        pass
    try:
        when = datetime.fromisoformat(text)
    except ValueError:
        raise TimeSpanError(f"{text!r} is neither an ISO time such as 2026-11-22T02:50:00Z "
                            "nor seconds from the start such as 12.5") from None
    return TimeBound(epoch_ns(when if when.tzinfo is not None else when.replace(tzinfo=UTC)),
                     relative=False)


def epoch_ns(when: datetime) -> int:
    """An aware ``datetime`` as ns since the epoch, exactly (no float in between)."""
    delta = when - datetime(1970, 1, 1, tzinfo=UTC)
    return (delta.days * 86_400 + delta.seconds) * 10**9 + delta.microseconds * 1000


class TimeSpan:
    """A command's --start and --end: the samples it takes, from the start up to the end.

    Every command with --start and --end reads them through this one class, so that each
    refuses the same spans in the same words. An end that is not after the start is
    refused when the span is made where the two are of one kind (two ISO times, or two
    offsets from the first sample), before anything is read; else by ``resolve``, once
    the first sample's instant is known. Either way the user is told what is wrong, not
    that no sample matched.

    Args:
        start: The first instant: an ISO time, or seconds from the first sample; None:
            from the first sample.
        end: The end instant (exclusive), as ``start``; None: to the last sample.

    Raises:
        TimeSpanError: Either is not a time, or the end is not after the start.
    """

    def __init__(self, start: str | None = None, end: str | None = None) -> None:
        self.start, self.end = start, end
        self._start = parse_time(start) if start else None
        self._end = parse_time(end) if end else None
        if (self._start is not None and self._end is not None
                and self._start.relative == self._end.relative):
            self.resolve(0)

    def resolve(self, first_ns: int) -> tuple[int | None, int | None]:
        """The span in host ns, for a recording whose first sample is at ``first_ns``.

        Args:
            first_ns: The instant of the first sample (ns since the epoch).

        Returns:
            The start and the end (exclusive), None where not given.

        Raises:
            TimeSpanError: The end is not after the start.
        """
        lo = None if self._start is None else self._start.resolve(first_ns)
        hi = None if self._end is None else self._end.resolve(first_ns)
        if lo is not None and hi is not None and hi <= lo:
            where = "the same instant as" if hi == lo else "before"
            raise TimeSpanError(f"--end {self.end} is {where} --start {self.start}, so no "
                                "sample can lie between them; give an --end after the start")
        return lo, hi
