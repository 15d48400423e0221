"""Find whole replies in a byte stream cut at arbitrary places.

Fed reads of any size with their receive times, the framer returns every intact reply
exactly once, in order, as columnar ``Batch`` es, whatever the chunking: a capture
replayed with its recorded times gives the live run's records and times. A record needs
an expected echo byte, a matching checksum and every field plausible (a 16-bit additive
checksum matches garbage now and then). It carries the receive time of the read that
held its last byte and, where its bytes came in more than one read, the latest earlier
read that ended inside it. How the framer resynchronises and why its NumPy fast path
and the compiled core accept exactly the scanner's records: docs/design/protocol.md.
"""

from __future__ import annotations

import re
from bisect import bisect_right
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import TypeVar

import numpy as np

from bridge import _native as native
from bridge._text import number
from bridge.protocol.codec import (
    Batch,
    Records,
    checksum,
    checksum_rows,
    native_checks,
    plausible,
    plausible_rows,
)
from bridge.protocol.table import BYTE_ORDER_REPLY, DATA_CODES, REPLIES, Flag

_MIN_FAST = 8  # records; below this the scanner is cheaper than array set-up
_MAX_FAST = 1 << 16
_FLAGS_AT = REPLIES[BYTE_ORDER_REPLY].offset("flags")
_Out = TypeVar("_Out")


@dataclass
class FramerStats:
    """What the framer saw.

    ``checksum_failures`` counts candidates with a bad sum, ``implausible`` those
    whose sum matched but whose values no unit sends (garbage that fits the sum).
    """

    records: Counter[int] = field(default_factory=Counter)
    checksum_failures: int = 0
    implausible: int = 0
    bytes_skipped: int = 0
    resyncs: int = 0
    bytes_fed: int = 0

    def summary(self) -> str:
        """One line for people: records by type, then each count.

        Returns:
            ``records: 0xC8×1,199; checksum failures: 5; implausible: 0; bytes skipped:
            67 of 80,400; resyncs: 1``, for instance.
        """
        by_type = ", ".join(f"0x{c:02X}×{number(n)}"
                            for c, n in sorted(self.records.items())) or "none"
        return (f"records: {by_type}; checksum failures: {number(self.checksum_failures)}; "
                f"implausible: {number(self.implausible)}; "
                f"bytes skipped: {number(self.bytes_skipped)} of {number(self.bytes_fed)}; "
                f"resyncs: {number(self.resyncs)}")


class _Reads:
    """Receive time of every read with bytes still held, by the stream position it ends at.

    And the latest read whose bytes are all decided (``last_end``, ``last_ns``): where a
    record begins right where it ended, that read bounds the record from below (none of
    its bytes had come). A read received at the same time as the one before it extends
    that one.
    """

    def __init__(self) -> None:
        self.ends: list[int] = []
        self.ns: list[int] = []
        self.last_end = -1
        self.last_ns = 0

    def add(self, ends: list[int], rx_ns: list[int]) -> None:
        if self.ns and rx_ns[0] == self.ns[-1]:
            self.ends[-1] = ends[0]
            ends, rx_ns = ends[1:], rx_ns[1:]
        elif not self.ns and rx_ns[0] == self.last_ns and self.last_end >= 0:
            self.last_end = -1  # the same read, cut in two: it did not end there
        self.ends += ends
        self.ns += rx_ns

    def times(self, starts: np.ndarray,
              length: int) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """The receive times of records of ``length`` bytes at these stream positions.

        For each: the receive time of the read that completed it, and of the latest read
        before that one if it ended inside the record or right where it begins, with the
        record's bytes it had brought (0 to ``length`` - 1; else the completing read's
        time and ``length``); None, None when no record here has such a read.
        """
        ends = np.array([self.last_end, *self.ends], np.int64)
        ns = np.array([self.last_ns, *self.ns], np.int64)
        index = np.searchsorted(ends, starts + (length - 1), side="right")
        rx = ns[index]
        before = ends[index - 1] - starts
        inside = (index > 0) & (before >= 0)
        if not inside.any():
            return rx, None, None
        return rx, np.where(inside, ns[index - 1], rx), np.where(inside, before, length)

    def times_of(self, starts: list[int],
                 length: int) -> tuple[list[int], list[int] | None, list[int] | None]:
        """``times`` in plain integers, for a record or two."""
        ends, ns = self.ends, self.ns
        if len(ns) == 1:  # a live bridge: every record completed by the one read held
            one = [ns[0]] * len(starts)
            if starts and starts[0] == self.last_end:  # the read before ended right there
                return one, [self.last_ns, *one[1:]], [0, *[length] * (len(starts) - 1)]
            return one, None, None
        rx: list[int] = []
        part_ns: list[int] = []
        part_bytes: list[int] = []
        for start in starts:
            index = bisect_right(ends, start + length - 1)
            rx.append(ns[index])
            end, at = (ends[index - 1], ns[index - 1]) if index else (self.last_end,
                                                                       self.last_ns)
            before = end - start
            part_ns.append(at if before >= 0 else ns[index])
            part_bytes.append(before if before >= 0 else length)
        if part_bytes.count(length) == len(part_bytes):
            return rx, None, None
        return rx, part_ns, part_bytes

    def forget_before(self, position: int) -> None:
        done = bisect_right(self.ends, position)
        if done:
            self.last_end, self.last_ns = self.ends[done - 1], self.ns[done - 1]
        del self.ends[:done], self.ns[:done]


class _Runs:
    """Accepted records gathered into runs of one type and byte order, decoded once per run.

    Each run is a list of chunks: consecutive records' bytes and the stream position of
    the first.
    """

    def __init__(self) -> None:
        self.runs: list[tuple[int, bool, list[tuple[bytes, int]]]] = []

    def add(self, code: int, little_endian: bool, data: bytes, start: int) -> None:
        if self.runs and self.runs[-1][:2] == (code, little_endian):
            self.runs[-1][2].append((data, start))
        else:
            self.runs.append((code, little_endian, [(data, start)]))

    def batches(self, reads: _Reads) -> list[Batch]:
        out = []
        for code, little_endian, chunks in self.runs:
            size = REPLIES[code].length
            block = np.frombuffer(b"".join(data for data, _ in chunks), np.uint8)
            starts = np.concatenate([start + size * np.arange(len(data) // size, dtype=np.int64)
                                     for data, start in chunks])
            rx_ns, part_ns, part_bytes = reads.times(starts, size)
            out.append(Batch.from_block(code, block.reshape(len(starts), -1), starts, rx_ns,
                                        little_endian, part_ns, part_bytes))
        return out

    def records(self, reads: _Reads) -> list[Records]:
        out = []
        for code, little_endian, chunks in self.runs:
            size = REPLIES[code].length
            wire: list[bytes] = []
            starts: list[int] = []
            for data, start in chunks:
                if len(data) == size:
                    wire.append(data)
                    starts.append(start)
                else:
                    wire += [data[i : i + size] for i in range(0, len(data), size)]
                    starts += range(start, start + len(data), size)
            out.append(Records(code, little_endian, wire, starts,
                               *reads.times_of(starts, size)))
        return out


class Framer:
    """Streaming reply framer.

    Reads with the same receive time count as one (a read cut in two says nothing new),
    and an empty read as none. ``stats`` counts what it saw.

    Args:
        expect: The reply codes that may arrive (a continuous preset, or the replies to
            commands in flight, plus 0x21 for errors); None: every data record, blind.
        little_endian: The float byte order to start with; an accepted 0xDB reply sets
            it for the records after it.

    Raises:
        ValueError: An expected code starts no reply.
    """

    def __init__(self, expect: Iterable[int] | None = None, little_endian: bool = False) -> None:
        self.little_endian = little_endian
        self.stats = FramerStats()
        self._buf = bytearray()
        self._reads = _Reads()
        self._base = 0
        self._locked = False
        self._chunk = 256
        self._checked: tuple[int, int, bool, np.ndarray] | None = None
        self.expect(DATA_CODES if expect is None else expect)

    def expect(self, codes: Iterable[int]) -> None:
        """Change which replies may arrive from here on.

        Args:
            codes: Their first bytes; none at all skips every byte.

        Raises:
            ValueError: A code starts no reply.
        """
        codes = frozenset(codes)
        unknown = [f"0x{c:02X}" for c in codes if c not in REPLIES]
        if unknown:
            raise ValueError(f"no reply starts with {', '.join(unknown)}")
        self._lengths = {c: REPLIES[c].length for c in codes}
        self._header = re.compile(b"[" + b"".join(re.escape(bytes((c,))) for c in codes) + b"]"
                                  if codes else b"(?!)")  # nothing expected: skip every byte

    @property
    def expected(self) -> frozenset[int]:
        """The reply codes that may arrive."""
        return frozenset(self._lengths)

    @property
    def pending(self) -> int:
        """Bytes held back waiting for the rest of a possible record."""
        return len(self._buf)

    def feed(self, data: bytes | bytearray | memoryview, rx_ns: int = 0) -> list[Batch]:
        """Take the next read.

        Args:
            data: Its bytes.
            rx_ns: Its receive time (ns, any clock; records carry it on).

        Returns:
            The records decided so far, one batch per run of one type and byte order; a
            record begun and not yet whole waits for the next read.
        """
        return self._take(data, [len(data)], [rx_ns], _Runs.batches)

    def feed_records(self, reads: list[bytes], rx_ns: list[int]) -> list[Records]:
        """``feed`` of a live bridge's reads, the records as ``Records``.

        A record or two without array set-up (``Records.batch`` gives the very
        ``Batch``). The reads are one, or the pieces a record came in while the port read
        on until it was whole: one scan for them all, the records and times that feeding
        them one by one gives. As ``feed_reads``, an empty read is no read and of reads
        received at one time the last stands for them.

        Args:
            reads: The reads' bytes, in order.
            rx_ns: Their receive times.

        Returns:
            The records decided so far, one ``Records`` per run of one type and byte
            order.
        """
        if len(reads) == 1:
            return self._take(reads[0], [len(reads[0])], rx_ns, _Runs.records)
        pieces = [(data, rx) for data, rx in zip(reads, rx_ns, strict=True) if data]
        ends: list[int] = []
        times: list[int] = []
        end = 0
        for i, (data, rx) in enumerate(pieces):
            end += len(data)
            if i + 1 == len(pieces) or rx != pieces[i + 1][1]:
                ends.append(end)
                times.append(rx)
        return self._take(b"".join(reads), ends, times, _Runs.records)

    def feed_reads(self, data: bytes | bytearray | memoryview, ends: np.ndarray,
                   rx_ns: np.ndarray) -> list[Batch]:
        """Take many reads at once (a replay): one scan instead of one per read.

        Gives the records and times that feeding them one by one gives.

        Args:
            data: The reads' bytes end to end.
            ends: Where each read ends in ``data``, rising to ``len(data)``.
            rx_ns: Each read's receive time.

        Returns:
            The records decided so far, as ``feed`` returns them.

        Raises:
            ValueError: ``ends`` and ``rx_ns`` differ in shape, or ``ends`` does not rise
                to the bytes given.
        """
        ends = np.asarray(ends, np.int64)
        rx_ns = np.asarray(rx_ns, np.int64)
        if ends.shape != rx_ns.shape or ends.ndim != 1:
            raise ValueError(f"ends and rx_ns differ in shape: {ends.shape} vs {rx_ns.shape}")
        last = int(ends[-1]) if len(ends) else 0
        sizes = np.diff(ends, prepend=0)
        if last != len(data) or (sizes < 0).any():
            raise ValueError(f"read ends must rise to the {len(data)} bytes given")
        ends, rx_ns = ends[sizes > 0], rx_ns[sizes > 0]  # an empty read is no read
        one = np.append(rx_ns[1:] != rx_ns[:-1], True)  # the last of equal-time reads
        return self._take(data, ends[one].tolist(), rx_ns[one].tolist(), _Runs.batches)

    def _take(self, data: bytes | bytearray | memoryview, ends: list[int], rx_ns: list[int],
              out: Callable[[_Runs, _Reads], list[_Out]]) -> list[_Out]:
        if len(data):
            self.stats.bytes_fed += len(data)
            base = self._base + len(self._buf)
            self._reads.add([base + end for end in ends], rx_ns)
            self._buf += data
        buf = self._buf
        if buf and self._lengths.get(buf[0], 0) > len(buf):
            return []  # a record begun and not yet whole: the scan would stop right there
        return self._scan(False, out)

    def flush(self) -> list[Batch]:
        """End of stream: decide on every byte still held back.

        Returns:
            The last records; a record cut short is skipped and counted.
        """
        return self._scan(True, _Runs.batches)

    def _scan(self, final: bool, out: Callable[[_Runs, _Reads], list[_Out]]) -> list[_Out]:
        buf, lengths, stats, core = self._buf, self._lengths, self.stats, native.records
        runs = _Runs()
        pos, n = 0, len(buf)
        fast = True
        while pos < n:
            code = buf[pos]
            size = lengths.get(code)
            if size is None:
                found = self._header.search(buf, pos + 1)
                nxt = found.start() if found else n
                self._lose_step(nxt - pos)
                pos = nxt
                continue
            if pos + size > n:
                if not final:
                    break
                self._lose_step(1)
                pos += 1
                continue
            # A 0xDB reply changes how the next record decodes: the scanner takes it.
            if core is not None and code != BYTE_ORDER_REPLY:
                good = core.intact(buf, pos, size, code, (n - pos) // size,
                                   native_checks(code, self.little_endian))
                if good:  # else the one that failed is counted below, as without the core
                    runs.add(code, self.little_endian, bytes(buf[pos : pos + good * size]),
                             self._base + pos)
                    stats.records[code] += good
                    self._locked = True
                    pos += good * size
                    continue
            elif (fast and self._locked and code != BYTE_ORDER_REPLY
                    and (n - pos) // size >= _MIN_FAST):
                good, fast = self._fast(buf, pos, code, size, runs)
                pos += good * size
                continue
            rec = bytes(buf[pos : pos + size])
            if checksum(rec[:-2]) != (rec[-2] << 8 | rec[-1]):
                stats.checksum_failures += 1
            elif plausible(code, rec, self.little_endian):
                runs.add(code, self.little_endian, rec, self._base + pos)
                stats.records[code] += 1
                if code == BYTE_ORDER_REPLY:
                    flags = rec[_FLAGS_AT] << 8 | rec[_FLAGS_AT + 1]
                    self.little_endian = bool(flags & Flag.LITTLE_ENDIAN_FLOATS)
                self._locked = True
                fast = True
                pos += size
                continue
            else:
                stats.implausible += 1
            self._lose_step(1)
            pos += 1
        del buf[:pos]
        self._base += pos
        decided = out(runs, self._reads)
        self._reads.forget_before(self._base)
        return decided

    def _checked_from(self, start: int, code: int, size: int) -> np.ndarray | None:
        """The checks already made on the records at ``start``, if a block covered them.

        A flipped bit costs one record but keeps the alignment, so the block checked
        before it still answers for the records after it.
        """
        if self._checked is None:
            return None
        origin, checked_code, little_endian, ok = self._checked
        if (checked_code, little_endian) != (code, self.little_endian) or start < origin:
            return None
        index, misaligned = divmod(start - origin, size)
        return None if misaligned or index >= len(ok) else ok[index:]

    def _lose_step(self, skipped: int) -> None:
        if self._locked:
            self._locked = False
            self.stats.resyncs += 1
        self.stats.bytes_skipped += skipped

    def _fast(self, buf: bytearray, pos: int, code: int, size: int,
              runs: _Runs) -> tuple[int, bool]:
        """Accept the longest run of intact ``code`` records at ``pos``.

        Returns its length and whether every record checked was intact (if not, the
        scanner must look at the one that failed before the fast path runs again).
        """
        start = self._base + pos
        ok = self._checked_from(start, code, size)
        if ok is None:
            count = min(self._chunk, (len(buf) - pos) // size)
            block = np.frombuffer(buf, np.uint8, count * size, pos).reshape(count, size)
            wire = block[:, -2].astype(np.uint32) << 8 | block[:, -1]
            ok = (checksum_rows(block[:, :-2]) == wire) & (block[:, 0] == code)
            ok &= plausible_rows(code, block, self.little_endian)
            del block
            self._checked = (start, code, self.little_endian, ok)
            fresh = True
        else:
            fresh = False
        good = len(ok) if ok.all() else int(np.argmin(ok))
        if fresh:
            self._chunk = min(_MAX_FAST, self._chunk * 2) if good == len(ok) else max(64, 2 * good)
        if good:
            runs.add(code, self.little_endian, bytes(buf[pos : pos + good * size]),
                     self._base + pos)
            self.stats.records[code] += good
        return good, good == len(ok)


def other_byte_order(data: bytes, expect: Iterable[int], little_endian: bool) -> int:
    """Records ``data`` holds with floats in the other byte order, where nothing decoded.

    ``gx3 decode`` and ``gx3 import`` say so with the option to change, but only when
    those records make up most of the bytes: a few checksum matches in garbage are not a
    byte order.

    Args:
        data: The bytes that gave no record (the start of a file is enough).
        expect: The reply codes looked for.
        little_endian: The byte order they were read with.

    Returns:
        How many records the other order gives, or 0 when they are too few to count.
    """
    other = Framer(expect, little_endian=not little_endian)
    found = sum(len(b) for b in other.feed(data) + other.flush())
    return found if found and other.stats.bytes_skipped <= len(data) // 2 else 0
