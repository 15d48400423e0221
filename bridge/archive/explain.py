"""An archive in words for a person: what it holds, and what could not be read of it."""

from __future__ import annotations

from collections import Counter
from typing import TYPE_CHECKING

import numpy as np

from bridge._text import counted, number

if TYPE_CHECKING:
    from bridge.archive.reader import ArchiveReader


def describe_contents(archive: ArchiveReader) -> str:
    """What the file holds, in words (``ArchiveReader.summary``).

    Args:
        archive: What ``read_archive`` read.

    Returns:
        Its size and state, then topics with their message counts and time ranges,
        then units and record types with their sample counts: one line each.
    """
    lines = [f"{archive.path}: {counted(archive.size, 'byte')}, "
             f"{counted(archive.message_count, 'message')}, "
             f"{counted(archive.chunks, 'chunk')}, "
             + (f"{len(archive.damage)} corrupt chunk(s) skipped, " if archive.damage else "")
             + ("complete" if archive.complete else
             f"not finished ({counted(archive.dropped_bytes, 'byte')} dropped"
             + (f": {archive.problem}" if archive.problem else "") + ")")]
    for topic, (n, t0, t1) in archive.counts().items():
        lines.append(f"  {topic}: {counted(n, 'message')}, {(t1 - t0) / 1e9:.3f} s "
                     f"from {np.datetime64(t0, 'ns')}Z")
    for s in archive.samples():
        lines.append(f"  {s.unit} 0x{s.code:02X}: {counted(len(s), 'sample')}")
    return "\n".join(lines)


def describe_damage(archive: ArchiveReader) -> str:
    """One line about the corrupt chunks skipped: where, when, and what was lost."""
    lost: Counter[str] = Counter()
    unknown = 0
    for d in archive.damage:
        if d.lost is None:
            unknown += 1
        else:
            lost.update(d.lost)
    start = min(d.start_ns for d in archive.damage)
    end = max(d.end_ns for d in archive.damage)
    topics = ", ".join(f"{t} {number(n)}" for t, n in sorted(lost.items()))
    return (f"{archive.path}: skipped {len(archive.damage)} corrupt chunk(s) at byte(s) "
            + ", ".join(str(d.offset) for d in archive.damage)
            + f" ({archive.damage[0].why}): lost {counted(sum(lost.values()), 'message')}"
            + (f" ({topics})" if topics else "")
            + (f" and those of {unknown} chunk(s) whose index is damaged too" if unknown
               else "")
            + f", logged from {np.datetime64(start, 'ns')}Z to {np.datetime64(end, 'ns')}Z"
            "; the rest is read")


def describe_problem(archive: ArchiveReader) -> str:
    """One line about a file that did not read to its end.

    Args:
        archive: What ``read_archive`` read.

    Returns:
        The line; empty when the file read to its end.
    """
    if archive.complete and not archive.dropped_bytes:
        return ""
    return (f"{archive.path}: not finished, read up to its last complete chunk "
            f"({counted(archive.dropped_bytes, 'byte')} dropped; {archive.problem})")
