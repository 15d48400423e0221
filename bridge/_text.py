"""Counts in the words a person reads: 1 unit, 2 units."""

from __future__ import annotations


def counted(n: int, noun: str, plural: str | None = None) -> str:
    """``n`` and the noun, singular for one: ``1 unit``, ``1,024 samples``.

    Args:
        n: How many.
        noun: The noun for one.
        plural: The noun for several, where adding an s is wrong.

    Returns:
        The count with thousands separators, and the noun.
    """
    return f"{n:,} {noun if n == 1 else plural or noun + 's'}"
