"""Numbers as a person reads them: counts (1 unit, 2 units), instants (UTC, ISO 8601).

Every count a command prints goes through ``number`` (or ``counted``, which adds the
noun), so that 2,094 instants never stand beside 7858 samples.
"""

from __future__ import annotations

from datetime import UTC, datetime


def number(n: int) -> str:
    """A count with thousands separators: ``13,400``.

    Args:
        n: How many.

    Returns:
        The text.
    """
    return f"{n:,}"


def counted(n: int, noun: str, plural: str | None = None) -> str:
    """``n`` and the noun, singular for one: ``1 unit``, ``1,024 samples``.

    Args:
        n: How many.
        noun: The noun for one.
        plural: The noun for several, where adding an s is wrong.

    Returns:
        The count with thousands separators, and the noun.
    """
    return f"{number(n)} {noun if n == 1 else plural or noun + 's'}"


def utc_text(ns: int, timespec: str = "seconds") -> str:
    """An instant as ISO 8601 in UTC, with Z: ``2026-11-28T06:00:00Z``.

    Args:
        ns: Nanoseconds since the epoch.
        timespec: How much of the time to give (``seconds``, ``milliseconds``, ...).

    Returns:
        The text.
    """
    return datetime.fromtimestamp(ns / 1e9, UTC).isoformat(timespec=timespec).replace(
        "+00:00", "Z")
