"""Instants of an archive as people give them: ``--start``, ``--end`` (ISO, or seconds)."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime

__all__ = ["TimeBound", "parse_time"]


@dataclass(frozen=True)
class TimeBound:
    """A --start/--end bound: absolute host time in ns, or seconds from the first sample."""

    ns: int
    relative: bool

    def resolve(self, first_ns: int) -> int:
        """The bound in host ns, for a recording whose first sample is at ``first_ns``."""
        return first_ns + self.ns if self.relative else self.ns


def parse_time(text: str) -> TimeBound:
    """``2026-11-22T02:50:00Z`` (ISO 8601; no zone = UTC) or ``12.5`` (s from the start)."""
    try:
        return TimeBound(round(float(text) * 1e9), relative=True)
    except ValueError:
        pass
    try:
        when = datetime.fromisoformat(text)
    except ValueError:
        raise ValueError(f"{text!r} is neither an ISO time such as 2026-11-22T02:50:00Z nor "
                         "seconds from the start such as 12.5") from None
    if when.tzinfo is None:
        when = when.replace(tzinfo=UTC)
    delta = when - datetime(1970, 1, 1, tzinfo=UTC)
    return TimeBound((delta.days * 86_400 + delta.seconds) * 10**9
                     + delta.microseconds * 1000, relative=False)
