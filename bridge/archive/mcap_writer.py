"""A chunked, indexed MCAP writer that takes messages in bulk.

mcap's ``Writer`` builds each message record through a dozen Python calls (~30 us a
message), which caps a recorder near 30,000 messages a second. A Message record is a
fixed 31-byte head and the payload, so here a whole batch of them is laid out with one
NumPy structured array, and the message index that follows each chunk likewise; the
rare records go through mcap's own record classes. The file follows the MCAP
specification (https://mcap.dev/spec, format version 0) record for record where mcap
1.6's own writer puts them. The records one by one: ``docs/design/archive.md``.
"""

from __future__ import annotations

import functools
import os
import struct
import tempfile
import zlib
from collections.abc import Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import numpy as np
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    McapRecord,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

MAGIC = b"\x89MCAP0\r\n"
#: zstd level 1: twice level 3's speed on IMU samples, 2 % larger chunks
ZSTD_LEVEL = 1
_MESSAGE_HEAD = struct.Struct("<BQHIQQ")  # opcode, length, channel, sequence, log, publish
_BODY_FIXED = _MESSAGE_HEAD.size - 9  # a Message record's length without its data
_BULK = 16  # messages; fewer are cheaper packed one by one than laid out as an array
_INDEX_ENTRY = np.dtype([("log_time", "<u8"), ("offset", "<u8")])
_INDEX_HEAD = struct.Struct("<BQHI")
_MERGE = 1 << 16  # messages merged from spilled runs at a time


def _message_records(channel: int, first_sequence: int, log_time: np.ndarray,
                    publish_time: np.ndarray,
                    payloads: Sequence[bytes]) -> tuple[bytes, np.ndarray]:
    """Message records of ``payloads`` end to end, and each record's size in bytes.

    Many payloads of one length (a unit's samples in the bulk layout) become one
    structured array; a few, or payloads of several lengths, are packed one by one.
    """
    n = len(payloads)
    sizes = np.fromiter(map(len, payloads), np.int64, n)
    if n >= _BULK and sizes[0] and (sizes == sizes[0]).all():
        rec = np.empty(n, _records_dtype(int(sizes[0])))
        rec["opcode"] = Opcode.MESSAGE
        rec["length"] = sizes + _BODY_FIXED
        rec["channel"] = channel
        rec["sequence"] = (first_sequence + np.arange(n, dtype=np.int64)) & 0xFFFFFFFF
        rec["log_time"] = log_time
        rec["publish_time"] = publish_time
        rec["data"] = np.frombuffer(b"".join(payloads), rec.dtype["data"])
        return rec.tobytes(), sizes + _MESSAGE_HEAD.size
    parts: list[bytes] = []
    for i, (payload, log, published) in enumerate(zip(payloads, log_time.tolist(),
                                                      publish_time.tolist(), strict=True)):
        parts += (_MESSAGE_HEAD.pack(Opcode.MESSAGE, len(payload) + _BODY_FIXED, channel,
                                     (first_sequence + i) & 0xFFFFFFFF, log, published),
                  payload)
    return b"".join(parts), sizes + _MESSAGE_HEAD.size


@functools.cache
def _records_dtype(size: int) -> np.dtype[np.void]:
    """Message records with ``size``-byte payloads, as one packed NumPy record."""
    return np.dtype([("opcode", "u1"), ("length", "<u8"), ("channel", "<u2"),
                     ("sequence", "<u4"), ("log_time", "<u8"), ("publish_time", "<u8"),
                     ("data", f"V{size}")])


def _compress(zstd: zstandard.ZstdCompressor, data: bytes) -> tuple[bytes, int]:
    """A chunk's records compressed, and their CRC-32 (both let go of the GIL)."""
    return zstd.compress(data), zlib.crc32(data)


def _record(record: McapRecord) -> bytes:
    builder = RecordBuilder()
    record.write(builder)
    return bytes(builder.end())  # type: ignore[no-untyped-call]


@dataclass
class _Held:
    """Message records added and not yet written: end to end, with a row each."""

    data: bytes
    channel: np.ndarray
    log_time: np.ndarray
    start: np.ndarray
    size: np.ndarray


@dataclass
class _OpenChunk:
    """Records of the chunk in progress and the index of its messages."""

    parts: list[bytes | memoryview] = field(default_factory=list)
    size: int = 0
    messages: int = 0
    start: int = 0
    end: int = 0
    index: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=list)

    def add(self, record: bytes | memoryview) -> None:
        self.parts.append(record)
        self.size += len(record)


def _joined(held: list[_Held]) -> tuple[np.ndarray, ...]:
    """Held pieces as one: bytes, and log time, start, size and channel of each record."""
    data = np.frombuffer(b"".join(h.data for h in held), np.uint8)
    base = np.cumsum([0] + [len(h.data) for h in held[:-1]]).tolist()
    return (data, np.concatenate([h.log_time for h in held]),
            np.concatenate([h.start + b for h, b in zip(held, base, strict=True)]),
            np.concatenate([h.size for h in held]), np.concatenate([h.channel for h in held]))


def _read(fd: int, at: int, size: int) -> bytes:
    parts = []
    while size:
        part = os.pread(fd, size, at)
        if not part:
            raise OSError(f"the sort's spill file ends {size} bytes short")
        parts.append(part)
        at += len(part)
        size -= len(part)
    return b"".join(parts)


@dataclass
class _Run:
    """Held messages spilled, sorted, to the spill file.

    Records start at ``ends[:-1]`` and end at ``ends[1:]``.
    """

    channel: np.ndarray
    log_time: np.ndarray
    ends: np.ndarray
    at: int = 0  # records before it are written


def _gather(data: np.ndarray, start: np.ndarray, size: np.ndarray) -> bytes:
    """The byte ranges (``start``, ``size``) of ``data`` end to end.

    The records of each size are moved as rows of a window view, one row copy each
    (there are few sizes).
    """
    total = int(size.sum())
    out = np.empty(total, np.uint8)
    at = np.cumsum(size) - size
    for width in np.unique(size).tolist():
        if width:
            pick = np.flatnonzero(size == width)
            _windows(out, width, True)[at[pick]] = _windows(data, width)[start[pick]]
    return out.tobytes()


def _windows(buf: np.ndarray, width: int, writeable: bool = False) -> np.ndarray:
    """Every ``width`` bytes of ``buf`` as a row, row k starting at byte k (a view)."""
    return np.lib.stride_tricks.as_strided(buf, (max(len(buf) - width + 1, 0), width),
                                           (1, 1), writeable=writeable)


class McapWriter:
    """Write one MCAP file to ``stream``: ``start``, register, ``add`` in bulk, ``finish``.

    Messages are written in log-time order (what ``mcap doctor --strict-message-order``
    asks): ``add`` holds them, and ``release`` (or ``flush``) writes those logged up to
    a time, sorted, so chunks never overlap. A message added later than one already
    written is written at that one's log time (its own time is in its payload) and
    counted in ``late``. Ids of schemas and channels count from 1 in registration order,
    as mcap's writer gives them. Errors of the stream (a full disk) propagate as OSError.
    """

    def __init__(self, stream: IO[bytes], chunk_size: int = 1 << 20,
                 spill_bytes: int = 16 << 20, spill_dir: Path | None = None) -> None:
        self.stream = stream
        self.chunk_size = chunk_size
        self.spill_bytes = spill_bytes
        self.spill_dir = spill_dir
        self.late = 0
        self._zstd = zstandard.ZstdCompressor(level=ZSTD_LEVEL)
        self._worker = ThreadPoolExecutor(1, thread_name_prefix="gx3-mcap-zstd")
        self._closed: tuple[Future[tuple[bytes, int]], _OpenChunk, int] | None = None
        self._schemas: list[Schema] = []
        self._channels: list[Channel] = []
        self._chunk = _OpenChunk()
        self._held: list[_Held] = []
        self._runs: list[_Run] = []
        self._spill_fd: int | None = None
        self._spilled = 0  # bytes in the spill file
        self.held_bytes = 0
        self._chunk_indexes: list[ChunkIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._counts: dict[int, int] = {}
        self._messages = 0
        self._start = 0
        self._end = 0
        self._metadata = 0

    def start(self, profile: str, library: str) -> None:
        """Write the magic and the Header record."""
        self.stream.write(MAGIC + _record(Header(profile, library)))

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        """Add a Schema record to the chunk in progress; its id (from 1)."""
        schema = Schema(id=len(self._schemas) + 1, name=name, encoding=encoding, data=data)
        self._schemas.append(schema)
        self._chunk.add(_record(schema))
        return schema.id

    def register_channel(self, topic: str, message_encoding: str, schema_id: int,
                         metadata: dict[str, str]) -> int:
        """Add a Channel record to the chunk in progress; its id (from 1)."""
        channel = Channel(id=len(self._channels) + 1, topic=topic,
                          message_encoding=message_encoding, schema_id=schema_id,
                          metadata=dict(metadata))
        self._channels.append(channel)
        self._chunk.add(_record(channel))
        return channel.id

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """Write a Metadata record at top level, after the chunk last closed."""
        self._write_closed()
        record = _record(Metadata(name=name, metadata=dict(data)))
        self._metadata_indexes.append(MetadataIndex(self.stream.tell(), len(record), name))
        self.stream.write(record)
        self._metadata += 1

    def late_among(self, log_time: np.ndarray) -> np.ndarray:
        """Which of these log times ``add`` would write later than logged.

        Those before the last message already written.
        """
        log_time = np.asarray(log_time, np.int64)
        return log_time < self._end if self._messages else np.zeros(len(log_time), bool)

    def add(self, channel: int, first_sequence: int, log_time: np.ndarray,
            publish_time: np.ndarray, payloads: Sequence[bytes]) -> None:
        """Hold messages of ``channel`` until a ``release`` reaches their log time.

        Their sequence numbers count from ``first_sequence``.
        """
        if not len(payloads):
            return
        log_time = np.asarray(log_time, np.int64)
        behind = self.late_among(log_time)
        if behind.any():
            self.late += int(behind.sum())
            log_time = np.maximum(log_time, self._end)
        records, sizes = _message_records(channel, first_sequence, log_time,
                                         np.asarray(publish_time, np.int64), payloads)
        self._held.append(_Held(records, np.full(len(sizes), channel, np.uint16), log_time,
                                np.cumsum(sizes) - sizes, sizes))
        self.held_bytes += len(records)
        if self.held_bytes > self.spill_bytes:
            self._spill()

    def release(self, upto: int | None = None) -> None:
        """Write the held messages logged at or before ``upto`` (None: all), in log-time order.

        Messages of one time go in the order added; chunks close as they fill.
        """
        if self._runs:
            self._spill()
            self._merge(upto)
            return
        held, self._held, self.held_bytes = self._held, [], 0
        if not held:
            return
        data, log, start, size, channel = _joined(held)
        order = np.argsort(log, kind="stable")
        cut = len(order) if upto is None else int(np.searchsorted(log[order], upto, "right"))
        kept = np.sort(order[cut:])
        if len(kept):
            self._held = [_Held(_gather(data, start[kept], size[kept]), channel[kept],
                                log[kept], np.cumsum(size[kept]) - size[kept], size[kept])]
            self.held_bytes = len(self._held[0].data)
        out = order[:cut]
        ends = np.cumsum(size[out])
        done = 0
        while done < len(out):
            before = int(ends[done - 1]) if done else 0
            fit = int(np.searchsorted(ends[done:] - before, self.chunk_size - self._chunk.size,
                                      "right"))
            stop = min(len(out), done + fit + 1)
            part = out[done:stop]
            self._take(_gather(data, start[part], size[part]), channel[part], log[part],
                       ends[done:stop] - size[part] - before)
            done = stop
            if self._chunk.size > self.chunk_size:
                self._close_chunk()

    def _spill(self) -> None:
        """Move the held messages, sorted, to a run in a temporary file.

        Memory stays flat while a whole file waits to be sorted.
        """
        if not self._held:
            return
        data, log, start, size, channel = _joined(self._held)
        order = np.argsort(log, kind="stable")
        if self._spill_fd is None:  # a file with no name: gone with the writer
            self._spill_fd, name = tempfile.mkstemp(prefix=".gx3-sort-", dir=self.spill_dir)
            os.unlink(name)
        records = memoryview(_gather(data, start[order], size[order]))
        at = self._spilled
        while records:
            written = os.pwrite(self._spill_fd, records, self._spilled)
            records = records[written:]
            self._spilled += written
        self._runs.append(_Run(channel[order], log[order],
                               at + np.r_[0, np.cumsum(size[order])]))
        self._held, self.held_bytes = [], 0

    def _merge(self, upto: int | None) -> None:
        """Write the messages of the spilled runs logged up to ``upto``, in log-time order.

        A slice of time at a time, each run's part of it read in one piece.
        """
        logs = np.concatenate([r.log_time[r.at :] for r in self._runs])
        if upto is not None:
            logs = logs[logs <= upto]
        logs.sort()
        for hi in np.unique(np.r_[logs[_MERGE - 1 :: _MERGE], logs[-1:]]).tolist():
            for run in self._runs:
                stop = int(np.searchsorted(run.log_time, hi, "right"))
                if stop > run.at:
                    sizes = np.diff(run.ends[run.at : stop + 1])
                    assert self._spill_fd is not None
                    self._held.append(_Held(_read(self._spill_fd, int(run.ends[run.at]),
                                                  int(sizes.sum())),
                                            run.channel[run.at : stop],
                                            run.log_time[run.at : stop],
                                            np.cumsum(sizes) - sizes, sizes))
                    run.at = stop
            runs, self._runs = self._runs, []
            self.release()
            self._runs = runs
        self._runs = [r for r in self._runs if r.at < len(r.log_time)]

    def _take(self, records: bytes, channel: np.ndarray, log_time: np.ndarray,
              offsets: np.ndarray) -> None:
        """Append message records (in log-time order) to the chunk in progress."""
        chunk, n = self._chunk, len(log_time)
        first, last = int(log_time[0]), int(log_time[-1])
        if not chunk.messages:
            chunk.start = first
        chunk.end = last
        chunk.index.append((channel, log_time, chunk.size + offsets))
        chunk.add(records)
        chunk.messages += n
        if not self._messages:
            self._start = first
        self._end = last
        self._messages += n
        ids, counts = np.unique(channel, return_counts=True)
        for cid, count in zip(ids.tolist(), counts.tolist(), strict=True):
            self._counts[cid] = self._counts.get(cid, 0) + count

    def _close_chunk(self) -> None:
        """Close the chunk in progress.

        A chunk without messages is not closed: its schemas and channels wait for the
        next. It is compressed on a worker thread while the next one fills, and written
        when that one closes or at the next flush.
        """
        chunk = self._chunk
        if not chunk.messages:
            return
        data = b"".join(chunk.parts)
        packed = self._worker.submit(_compress, self._zstd, data)
        self._write_closed()
        self._closed = (packed, chunk, len(data))
        self._chunk = _OpenChunk()

    def _write_closed(self) -> None:
        """Write the chunk last closed and its message indexes (channel by channel)."""
        if self._closed is None:
            return
        packed, chunk, size = self._closed
        self._closed = None
        compressed, crc = packed.result()
        record = _record(Chunk(compression="zstd", data=compressed,
                               message_start_time=chunk.start, message_end_time=chunk.end,
                               uncompressed_crc=crc, uncompressed_size=size))
        chunk_at = self.stream.tell()
        channel = np.concatenate([c for c, _, _ in chunk.index])
        by_channel = np.argsort(channel, kind="stable")
        entries = np.empty(len(channel), _INDEX_ENTRY)
        entries["log_time"] = np.concatenate([t for _, t, _ in chunk.index])[by_channel]
        entries["offset"] = np.concatenate([o for _, _, o in chunk.index])[by_channel]
        ids, firsts = np.unique(channel[by_channel], return_index=True)
        indexes: list[bytes] = []
        offsets: dict[int, int] = {}
        at = chunk_at + len(record)
        for cid, lo, hi in zip(ids.tolist(), firsts.tolist(), [*firsts[1:].tolist(),
                                                                len(channel)], strict=True):
            body = entries[lo:hi].tobytes()
            offsets[cid] = at
            indexes.append(_INDEX_HEAD.pack(Opcode.MESSAGE_INDEX, 2 + 4 + len(body), cid,
                                            len(body)) + body)
            at += len(indexes[-1])
        self.stream.write(record)
        self.stream.write(b"".join(indexes))
        self._chunk_indexes.append(ChunkIndex(
            message_start_time=chunk.start, message_end_time=chunk.end,
            chunk_start_offset=chunk_at, chunk_length=len(record),
            message_index_offsets=offsets, message_index_length=at - chunk_at - len(record),
            compression="zstd", compressed_size=len(compressed), uncompressed_size=size))

    def flush(self) -> None:
        """Close the chunk in progress and hand what is written to the OS.

        Held messages wait for their ``release``. A writer killed after a flush leaves
        every chunk flushed before it readable by a streaming reader; the messages still
        held are lost with it.
        """
        self._close_chunk()
        self._write_closed()
        self.stream.flush()

    def close(self) -> None:
        """Stop the compression thread; safe to call twice.

        ``finish`` does it; call this when not finishing, after a write error.
        """
        self._closed = None
        self._runs = []
        if self._spill_fd is not None:
            os.close(self._spill_fd)
            self._spill_fd = None
        self._worker.shutdown(wait=True)

    def finish(self) -> None:
        """Write every held message, close the last chunk, write the summary and footer.

        The stream stays open.
        """
        try:
            self.release()
            self._close_chunk()
            self._write_closed()
        finally:
            self.close()
        self.stream.write(_record(DataEnd(0)))
        summary_start = self.stream.tell()
        stats = Statistics(message_count=self._messages, schema_count=len(self._schemas),
                           channel_count=len(self._channels), attachment_count=0,
                           metadata_count=self._metadata, chunk_count=len(self._chunk_indexes),
                           message_start_time=self._start, message_end_time=self._end,
                           channel_message_counts=dict(self._counts))
        groups: list[tuple[Opcode, Sequence[McapRecord]]] = [
            (Opcode.SCHEMA, self._schemas), (Opcode.CHANNEL, self._channels),
            (Opcode.STATISTICS, [stats]), (Opcode.CHUNK_INDEX, self._chunk_indexes),
            (Opcode.METADATA_INDEX, self._metadata_indexes)]
        summary = bytearray()
        offsets = []
        for opcode, records in groups:
            if records:
                start = len(summary)
                summary += b"".join(_record(r) for r in records)
                offsets.append(SummaryOffset(opcode, summary_start + start,
                                             len(summary) - start))
        offset_start = summary_start + len(summary)
        summary += b"".join(_record(r) for r in offsets)
        footer_head = struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, offset_start)
        crc = zlib.crc32(footer_head, zlib.crc32(summary))
        self.stream.write(bytes(summary))
        self.stream.write(_record(Footer(summary_start, offset_start, crc)) + MAGIC)
