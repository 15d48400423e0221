"""One pass over an MCAP file's records, finished, cut short or damaged: ``read_archive``.

One sequential pass serves a finished archive, one whose writer was killed and a raw
capture alike: a cut-off tail is measured, never parsed, and a corrupt chunk of a
finished file is skipped (found again by the summary's chunk index), so everything
readable is kept. Chunks are decompressed once and their message records taken as
columns (``bridge.archive.records``), so a million samples read in about a second. How
the reading goes, record by record: ``docs/design/archive.md``.
"""

from __future__ import annotations

import io
import logging
import struct
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Attachment, Channel, Chunk, ChunkIndex, Header, Metadata, Schema
from mcap.stream_reader import get_chunk_data_stream
from mcap.summary import Summary

from bridge.archive.explain import describe_damage, describe_problem
from bridge.archive.mcap_writer import MAGIC
from bridge.archive.reader import ArchiveReader
from bridge.archive.records import Block, ChannelInfo, Damage, rows
from bridge.exceptions import ArchiveReadError

_log = logging.getLogger(__name__)

_RECORD = struct.Struct("<BQ")
_CHUNK_HEAD = struct.Struct("<QQQII")
_U64 = struct.Struct("<Q")
_U32 = struct.Struct("<I")
_MESSAGE = np.dtype([("channel", "<u2"), ("sequence", "<u4"), ("log_time", "<u8"),
                     ("publish_time", "<u8")])
_OPCODE_MESSAGE = int(Opcode.MESSAGE)


def _walk(archive: ArchiveReader, data: bytes, indexed: np.ndarray | None = None) -> None:
    """Schemas, channels and message records of a chunk's (or a file's) inner records.

    The chunk's message indexes (``indexed``: offsets of message records) let the walk
    jump over runs of back-to-back messages and step only through what lies between
    them, which gives exactly the records a step-by-step walk finds; an index that
    disagrees with the records is ignored.
    """
    buf = np.frombuffer(data, np.uint8)
    messages: list[int] = []
    others: list[tuple[int, int, int]] = []
    indexed = np.sort(np.zeros(0, np.int64) if indexed is None else indexed)
    indexed = indexed[np.r_[True, indexed[1:] != indexed[:-1]]] if len(indexed) else indexed
    firsts, ends = _indexed_runs(buf, indexed)
    off = 0
    for first, end in zip(firsts.tolist(), ends.tolist(), strict=True):
        while off < first:
            off = _step(data, off, messages, others)
        if off != first:  # the index points inside a record: walk it all, step by step
            _walk(archive, data)
            return
        off = end
    while off < len(data):
        off = _step(data, off, messages, others)
    for opcode, start, stop in others:
        _other(archive, opcode, data[start:stop])
    offsets = np.array(messages, np.int64)
    if len(firsts):
        offsets = np.sort(np.concatenate([offsets, indexed]))
    if len(offsets):
        head = np.ascontiguousarray(rows(buf, offsets + 9, _MESSAGE.itemsize))
        head = head.view(_MESSAGE)[:, 0]
        length = rows(buf, offsets + 1, 8).copy().view("<u8")[:, 0].astype(np.int64)
        archive.blocks.append(Block(
            data, head["channel"].copy(), head["sequence"].copy(),
            head["log_time"].astype(np.int64), head["publish_time"].astype(np.int64),
            offsets + 9 + _MESSAGE.itemsize, length - _MESSAGE.itemsize))


def _other(archive: ArchiveReader, opcode: int, body: bytes) -> None:
    """Records other than messages that an archive keeps."""
    if opcode == Opcode.SCHEMA:
        schema = Schema.read(_read_stream(body))
        archive.schemas[schema.id] = schema
    elif opcode == Opcode.CHANNEL:
        ch = Channel.read(_read_stream(body))
        archive.channels[ch.id] = _channel_info(ch, archive.schemas)
    elif opcode == Opcode.HEADER:
        archive.header = Header.read(_read_stream(body))
    elif opcode == Opcode.METADATA:
        archive.metadata.append(Metadata.read(_read_stream(body)))
    elif opcode == Opcode.ATTACHMENT:
        archive.attachments.append(Attachment.read(_read_stream(body)))


def _chunk(archive: ArchiveReader, body: bytes, indexes: list[bytes]) -> None:
    """A chunk, decompressed once; ``indexes`` are the bodies of its message indexes."""
    start, end_time, size, crc, n = _CHUNK_HEAD.unpack_from(body)
    at = _CHUNK_HEAD.size
    compression = body[at : at + n].decode()
    (length,) = _U64.unpack_from(body, at + n)
    data_at = at + n + 8
    if data_at + length > len(body):
        raise ValueError("chunk data longer than the chunk")
    chunk = Chunk(compression=compression, data=body[data_at : data_at + length],
                  message_end_time=end_time, message_start_time=start,
                  uncompressed_crc=crc, uncompressed_size=size)
    stream, n_bytes = get_chunk_data_stream(chunk, validate_crc=True)
    offsets = [_index_offsets(index) for index in indexes]
    _walk(archive, stream.read(n_bytes), np.concatenate(offsets) if offsets else None)
    archive.chunks += 1


def _index_offsets(body: bytes) -> np.ndarray:
    """The message offsets a message index lists (none for one that is malformed)."""
    if len(body) < 6:
        return np.zeros(0, np.int64)
    (length,) = _U32.unpack_from(body, 2)
    if length % 16 or 6 + length > len(body):
        return np.zeros(0, np.int64)
    offsets: np.ndarray = np.frombuffer(body, "<u8", length // 8, 6)[1::2]
    clipped: np.ndarray = np.minimum(offsets, 1 << 62).astype(np.int64)
    return clipped


def is_mcap(path: Path) -> bool:
    """Whether the file starts as MCAP does: an archive or a raw capture, not raw bytes.

    One that cannot be read is left to whoever opens it, to say why.
    """
    try:
        with path.open("rb") as stream:
            return stream.read(len(MAGIC)) == MAGIC
    except OSError:
        return False


def _open(path: Path) -> tuple[IO[bytes], int]:
    try:
        stream = path.open("rb")
    except FileNotFoundError:
        raise ArchiveReadError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise ArchiveReadError(f"{path} is a directory; give an .mcap file") from None
    except PermissionError:
        raise ArchiveReadError(f"{path}: permission denied") from None
    size = path.stat().st_size
    head = stream.read(len(MAGIC))
    if size == 0:
        stream.close()
        raise ArchiveReadError(f"{path}: empty file; nothing was recorded into it")
    if head != MAGIC:
        stream.close()
        raise ArchiveReadError(f"{path}: not an MCAP file (no MCAP magic at its start); "
                               "give an archive or a raw capture written by gx3")
    return stream, size


def _message_indexes(stream: IO[bytes], pos: int, size: int) -> list[bytes]:
    """Bodies of the whole message index records that follow a chunk.

    The stream is left after them.
    """
    out: list[bytes] = []
    while True:
        head = stream.read(9)
        if len(head) == 9:
            opcode, length = _RECORD.unpack(head)
            if opcode == Opcode.MESSAGE_INDEX and pos + 9 + length <= size:
                out.append(stream.read(length))
                pos += 9 + length
                continue
        stream.seek(-len(head), io.SEEK_CUR)
        return out


def _summary(stream: IO[bytes]) -> Summary | None:
    """The summary at the end of a finished file (None when there is none to trust)."""
    try:
        stream.seek(0)
        summary = make_reader(stream, validate_crcs=True).get_summary()
    except Exception:  # no footer, or a damaged one: read without it
        return None
    finally:
        stream.seek(len(MAGIC))
    return summary


def _inside(chunks: dict[int, ChunkIndex], pos: int) -> ChunkIndex | None:
    """The indexed chunk whose record or message indexes hold byte ``pos``."""
    return next((c for start, c in chunks.items()
                 if start <= pos < _after(chunks, c)), None)


def _after(chunks: dict[int, ChunkIndex], chunk: ChunkIndex) -> int:
    """Where the records after ``chunk`` and its message indexes start."""
    return chunk.chunk_start_offset + chunk.chunk_length + chunk.message_index_length


def _damage(archive: ArchiveReader, stream: IO[bytes], index: ChunkIndex, why: str,
            channels: dict[int, Channel]) -> None:
    """Note a chunk skipped.

    Its time span comes from the chunk index, its messages per topic from its message
    indexes (when those are intact).
    """
    lost: dict[str, int] | None = {}
    for cid, offset in index.message_index_offsets.items():
        stream.seek(offset)
        head = stream.read(9 + 6)
        ch = channels.get(cid)
        if len(head) < 15 or head[0] != Opcode.MESSAGE_INDEX or ch is None or lost is None:
            lost = None
            continue
        (length,) = _U32.unpack_from(head, 11)
        lost[ch.topic] = lost.get(ch.topic, 0) + length // 16
    archive.damage.append(Damage(index.chunk_start_offset, index.message_start_time,
                                 index.message_end_time, why, lost))


def _hand_over(archive: ArchiveReader, on_blocks: Callable[[ArchiveReader], None] | None
               ) -> None:
    """Give the messages read so far to ``on_blocks`` and drop them (counted: ``streamed``)."""
    if on_blocks is not None and archive.blocks:
        on_blocks(archive)
        archive.streamed += sum(len(b) for b in archive.blocks)
        archive.blocks.clear()


def read_archive(path: Path | str, progress: Callable[[int], None] | None = None,
                 warn: Callable[[str], None] = _log.warning,
                 on_blocks: Callable[[ArchiveReader], None] | None = None,
                 between: tuple[int | None, int | None] = (None, None)) -> ArchiveReader:
    """Read what is readable of an MCAP file: an archive or a raw capture.

    Never raises on a damaged tail: the archive reports it (``complete``,
    ``dropped_bytes``, ``problem``). In a finished file, the summary's chunk index lets a
    corrupt chunk (its CRC, compression or records) be skipped and the reading go on
    after it; ``damage`` says what was lost.

    Args:
        path: The file.
        progress: Called with the bytes read so far, as the reading goes.
        warn: Hears, once each, the corrupt chunks skipped and the messages left out.
        on_blocks: Streams the file instead of keeping it: called with the archive each
            time a chunk (or a loose message) has been read, when the archive's
            messages are that chunk's alone (``samples``, ``messages``); they are
            dropped after the call, so memory stays that of one chunk however long the
            file. None: every message is kept.
        between: Messages logged from the first instant (host ns) up to the second
            (excluded) are wanted; None: open on that side. In a finished file the
            summary's chunk index says which chunks can hold them, and no other is read
            (the summary's schemas and channels stand in for theirs), so a window of an
            hour of a day-long archive reads an hour's chunks. Messages outside it can
            still come with those chunks, and a file cut short is read whole: callers
            keep what they want.

    Returns:
        Everything readable in the file.

    Raises:
        ArchiveReadError: The file is missing, empty, unreadable or not MCAP at all.
    """
    path = Path(path)
    stream, size = _open(path)
    archive = ArchiveReader(path, size, warn=warn)
    pos = len(MAGIC)
    summary = False
    with stream:
        index = _summary(stream)
        chunks = {} if index is None else {c.chunk_start_offset: c for c in index.chunk_indexes}
        summary_channels = {} if index is None else index.channels
        start, end = between
        if index is not None and between != (None, None):  # chunks left unread name none
            archive.schemas.update(index.schemas)
            archive.channels.update((cid, _channel_info(ch, index.schemas))
                                    for cid, ch in index.channels.items())
        while True:
            _hand_over(archive, on_blocks)
            head = stream.read(9)
            if len(head) < 9:
                archive.problem = "the file ends without a summary (the writer did not finish)" \
                    if not head else "a record header is cut short"
                break
            opcode, length = _RECORD.unpack(head)
            inside = None
            if chunks and not summary and (
                    pos + 9 + length > size or (opcode == Opcode.CHUNK) != (pos in chunks)):
                inside = _inside(chunks, pos)
            if inside is not None:  # a corrupt record head in a chunk or its indexes
                if inside.chunk_start_offset == pos:
                    _damage(archive, stream, inside, f"corrupt record head at byte {pos}",
                            summary_channels)
                pos = _after(chunks, inside)
                stream.seek(pos)
                continue
            if pos + 9 + length > size:
                archive.problem = f"a record at byte {pos} is cut short"
                break
            if opcode == Opcode.CHUNK and pos in chunks and not _overlaps(chunks[pos], start, end):
                pos = _after(chunks, chunks[pos])
                stream.seek(pos)
                continue
            body = stream.read(length)
            try:
                if opcode == Opcode.CHUNK and pos in chunks:
                    try:
                        _chunk(archive, body, _message_indexes(stream, pos + 9 + length, size))
                    except Exception as exc:  # a corrupt chunk: on at the next
                        _damage(archive, stream, chunks[pos], f"{type(exc).__name__}: {exc}",
                                summary_channels)
                    pos = _after(chunks, chunks[pos])
                    stream.seek(pos)
                    continue
                if opcode == Opcode.CHUNK:
                    indexes = _message_indexes(stream, pos + 9 + length, size)
                    _chunk(archive, body, indexes)
                    pos += sum(9 + len(index) for index in indexes)
                elif opcode == Opcode.MESSAGE:
                    _walk(archive, head + body)
                elif opcode == Opcode.DATA_END:
                    summary = True  # what follows repeats the data section
                elif opcode == Opcode.FOOTER:
                    archive.complete = stream.read(len(MAGIC)) == MAGIC
                    pos += 9 + length + (len(MAGIC) if archive.complete else 0)
                    if not archive.complete:
                        archive.problem = "the closing magic bytes are missing"
                    break
                elif not summary:
                    _other(archive, opcode, body)
            except Exception as exc:  # a corrupt record: keep what came before it
                archive.problem = f"corrupt record at byte {pos} ({type(exc).__name__}: {exc})"
                break
            pos += 9 + length
            if progress is not None:
                progress(pos)
    _hand_over(archive, on_blocks)
    archive.dropped_bytes = size - pos
    if archive.dropped_bytes and archive.complete:
        archive.problem = f"{archive.dropped_bytes} bytes after the end of the file"
    if index is not None:  # the summary's channels stand in for those lost with a chunk
        for b in archive.blocks:
            for cid in set(np.unique(b.channel).tolist()) - set(archive.channels):
                if cid in index.channels:
                    archive.schemas.update(index.schemas)
                    archive.channels[cid] = _channel_info(index.channels[cid], index.schemas)
    if archive.damage:
        warn(describe_damage(archive))
    return archive


def _overlaps(chunk: ChunkIndex, start: int | None, end: int | None) -> bool:
    """Whether a chunk can hold messages logged from ``start`` up to ``end`` (excluded)."""
    return ((start is None or chunk.message_end_time >= start)
            and (end is None or chunk.message_start_time < end))


def read_samples_archive(path: Path, on_read: Callable[[int], None] | None = None,
                         on_problem: Callable[[str], None] | None = None,
                         on_blocks: Callable[[ArchiveReader], None] | None = None,
                         between: tuple[int | None, int | None] = (None, None)
                         ) -> ArchiveReader:
    """Read an archive to take samples from; one with nothing readable is refused.

    Args:
        path: The archive.
        on_read: Hears the bytes read so far, as the reading goes (a progress bar).
        on_problem: Hears, once, what is wrong with an archive that was cut short or
            damaged, and what to do about it; the readable rest is read.
        on_blocks: Streams it chunk by chunk instead of keeping it (``read_archive``).
        between: Read only the chunks that can hold messages logged in this span
            (``read_archive``).

    Returns:
        Everything readable in the archive.

    Raises:
        ArchiveReadError: The file is missing, empty, unreadable or not MCAP at all.
        ValueError: Nothing in it can be read as messages (with no ``between``).
    """
    archive = read_archive(path, on_read, on_blocks=on_blocks, between=between)
    if not archive.message_count and between == (None, None):
        raise ValueError(f"{path}: nothing readable in it ({archive.problem or 'no messages'})"
                         "; is it an archive written by gx3?")
    problem = describe_problem(archive)
    if problem and on_problem is not None:
        on_problem(f"{problem}; `gx3 repair` makes a finished copy")
    return archive



def _read_stream(body: bytes) -> ReadDataStream:
    return ReadDataStream(io.BytesIO(body))


@dataclass(frozen=True)
class SampleSpan:
    """What an archive holds of samples, known before they are decoded.

    Attributes:
        counts: Samples of each unit that has a channel of them.
        first_ns: When the earliest sample was taken (its log time: the live
            ``time_ns``); None: there is none.
        last_ns: When the latest was, or a little after (a finished file's summary
            bounds it by the end of the last chunk that holds samples); None: there is
            none.
    """

    counts: dict[str, int]
    first_ns: int | None
    last_ns: int | None

    def seconds(self) -> float:
        """Seconds from the first sample to the last (0 without two)."""
        if self.first_ns is None or self.last_ns is None:
            return 0.0
        return (self.last_ns - self.first_ns) / 1e9


def sample_span(path: Path | str, progress: Callable[[int], None] | None = None) -> SampleSpan:
    """Which units an archive holds samples of, how many, and from when to when.

    A finished file's summary tells, with the one or two chunks that can hold its
    earliest sample: seconds for a day-long archive. A file without a usable summary (cut
    short) is read through once, a chunk at a time.

    Args:
        path: The archive.
        progress: Hears the bytes read so far, while a file without a summary is read.

    Returns:
        The samples' units, counts and span.

    Raises:
        ArchiveReadError: The file is missing, empty, unreadable or not MCAP at all.
    """
    path = Path(path)
    stream, _ = _open(path)
    with stream:
        index = _summary(stream)
    if index is None or index.statistics is None:
        return _span_by_reading(path, progress)
    imu = {cid: info for cid, ch in index.channels.items()
           if (info := _channel_info(ch, index.schemas)).kind == "imu"}
    counts: dict[str, int] = {}
    for cid, info in imu.items():
        counts[info.unit] = (counts.get(info.unit, 0)
                             + index.statistics.channel_message_counts.get(cid, 0))
    counts = {unit: n for unit, n in counts.items() if n}
    holding = [c for c in index.chunk_indexes if not imu.keys().isdisjoint(
        c.message_index_offsets)]
    if not holding:
        return SampleSpan(counts, None, None)
    # the chunk that ends first holds a sample no later than its end: the earliest sample
    # is in a chunk that starts by then
    earliest = min(c.message_end_time for c in holding)
    first = read_archive(path, between=(None, earliest + 1)).first_sample_ns()
    return SampleSpan(counts, first, max(c.message_end_time for c in holding))


def _span_by_reading(path: Path, progress: Callable[[int], None] | None) -> SampleSpan:
    """``sample_span`` of a file read through, a chunk at a time."""
    counts: dict[str, int] = {}
    times: list[int] = []

    def take(archive: ArchiveReader) -> None:
        units = {cid: c.unit for cid, c in archive.channels.items() if c.kind == "imu"}
        for block in archive.blocks:
            for cid in set(np.unique(block.channel).tolist()) & units.keys():
                logged = block.log_time[block.channel == cid]
                counts[units[cid]] = counts.get(units[cid], 0) + len(logged)
                times.extend((int(logged.min()), int(logged.max())))

    read_archive(path, progress, on_blocks=take)
    return SampleSpan(counts, min(times, default=None), max(times, default=None))


def summary_counts(path: Path, kind: str) -> dict[str, int] | None:
    """Messages per topic of one kind (the topic's last chunk), from a finished file's summary.

    No chunk is read. None when the file has no usable summary (cut short, or not MCAP:
    ``read_archive`` says which).
    """
    try:
        with path.open("rb") as stream:
            summary = make_reader(stream).get_summary()
    except Exception:  # whatever the file holds: read_archive will tell
        return None
    if summary is None or summary.statistics is None:
        return None
    counts = summary.statistics.channel_message_counts
    return {ch.topic: counts.get(cid, 0) for cid, ch in summary.channels.items()
            if _channel_info(ch, summary.schemas).kind == kind}


def _channel_info(ch: Channel, schemas: dict[int, Schema]) -> ChannelInfo:
    parts = ch.topic.split("/")
    # a fleet channel (the root frame, the event log) says so with an empty unit
    unit = ch.metadata["unit"] if "unit" in ch.metadata else (
        parts[-2] if len(parts) >= 3 else "")
    schema = schemas.get(ch.schema_id)
    return ChannelInfo(ch.id, ch.topic, unit, parts[-1], ch.message_encoding, ch.schema_id,
                       schema.name if schema else "", dict(ch.metadata))


def _step(data: bytes, off: int, messages: list[int], others: list[tuple[int, int, int]]
          ) -> int:
    """One record of a chunk's (or a file's) inner records at ``off``; where the next starts."""
    if off + 9 > len(data):
        raise ValueError("record header cut short inside a chunk")
    opcode, length = _RECORD.unpack_from(data, off)
    body = off + 9
    if body + length > len(data):
        raise ValueError("record longer than its chunk")
    if opcode == _OPCODE_MESSAGE:
        messages.append(off)
    else:
        others.append((opcode, body, body + length))
    return int(body + length)


def _indexed_runs(buf: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(first, end) of each run of back-to-back message records at ``offsets``.

    The offsets are sorted and unique; there are no runs when one is anything but a
    whole message record in the chunk.
    """
    none = np.zeros(0, np.int64), np.zeros(0, np.int64)
    if not len(offsets) or offsets[0] < 0 or offsets[-1] + 9 + _MESSAGE.itemsize > len(buf):
        return none
    head = rows(buf, offsets, 9)
    length = head[:, 1:].copy().view("<u8")[:, 0]
    ends = offsets + 9 + np.minimum(length, len(buf)).astype(np.int64)
    if ((head[:, 0] != _OPCODE_MESSAGE).any() or (length < _MESSAGE.itemsize).any()
            or ends[-1] > len(buf) or (ends[:-1] > offsets[1:]).any()):
        return none
    breaks = np.flatnonzero(ends[:-1] != offsets[1:])
    return offsets[np.r_[0, breaks + 1]], ends[np.r_[breaks, len(offsets) - 1]]
