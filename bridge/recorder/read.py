"""Reading archives and raw captures, finished or cut short, into per-unit NumPy columns.

One sequential pass over the file's records serves every case: a finished archive, one
whose writer was killed (no summary, maybe a half-written chunk at the end) and a raw
capture. Each record's length is checked against the file size before it is read, so a
cut-off tail is measured (``dropped_bytes``), never parsed; everything before it is
kept. Chunks are decompressed once and their message records located with NumPy, so a
million samples read in a few seconds.
"""

from __future__ import annotations

import io
import struct
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, NamedTuple

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Attachment, Channel, Chunk, Header, Metadata, Schema
from mcap.stream_reader import get_chunk_data_stream

from bridge.bus.codec import decode_batch, peek
from bridge.bus.gx3_pb2 import Event

MAGIC = b"\x89MCAP0\r\n"
_RECORD = struct.Struct("<BQ")
_CHUNK_HEAD = struct.Struct("<QQQII")
_U64 = struct.Struct("<Q")
_MESSAGE = np.dtype([("channel", "<u2"), ("sequence", "<u4"), ("log_time", "<u8"),
                     ("publish_time", "<u8")])
_HEAD = np.arange(_MESSAGE.itemsize)
_OPCODE_MESSAGE = int(Opcode.MESSAGE)


class ArchiveReadError(ValueError):
    """A file that cannot be read as an archive; the message says what it is instead."""


@dataclass(frozen=True)
class ChannelInfo:
    """A channel: its topic, the unit and key leaf it belongs to, and its encoding."""

    id: int
    topic: str
    unit: str
    kind: str  # the topic's last chunk: imu, status, event, info, frame, raw
    message_encoding: str
    schema_id: int
    schema_name: str
    metadata: dict[str, str]


@dataclass
class _Block:
    """The message records of one chunk: header columns and where each payload lies."""

    data: bytes
    channel: np.ndarray
    sequence: np.ndarray
    log_time: np.ndarray
    publish_time: np.ndarray
    start: np.ndarray
    length: np.ndarray

    def commands(self, mask: np.ndarray, unit: str) -> np.ndarray:
        """Command bytes of the ImuSamples under ``mask``: read at their fixed place in the
        bulk layout (tags checked), parsed for messages in any other layout."""
        n = len(unit.encode())
        start = self.start[mask]
        buf = np.frombuffer(self.data, np.uint8)
        fits = self.length[mask] >= n + 7
        at = np.where(fits, start, 0)
        fits &= (buf[at] == 0x0A) & (buf[at + 1] == n) & (buf[at + 2 + n] == 0x15)
        raw = np.ascontiguousarray(buf[at[:, None] + 3 + n + np.arange(4)])
        out = raw.view("<u4")[:, 0].astype(np.int64)
        for i in np.flatnonzero(~fits).tolist():
            s, length = int(start[i]), int(self.length[mask][i])
            out[i] = peek(self.data[s : s + length])[1]
        return out

    def __len__(self) -> int:
        return len(self.channel)

    def payloads(self, mask: np.ndarray) -> list[bytes]:
        data = self.data
        return [data[s : s + n] for s, n in zip(self.start[mask].tolist(),
                                                self.length[mask].tolist(), strict=True)]


class Record(NamedTuple):
    """One message, as iterated."""

    topic: str
    log_time: int
    publish_time: int
    sequence: int
    data: bytes


@dataclass
class Messages:
    """The messages of one topic, in log-time order (publish time = receive time)."""

    topic: str
    unit: str
    kind: str
    log_time: np.ndarray
    publish_time: np.ndarray
    sequence: np.ndarray
    payloads: list[bytes]

    def __len__(self) -> int:
        return len(self.payloads)


@dataclass
class Samples:
    """Decoded ImuSamples of one unit and record type, in sample-time order.

    ``columns`` are those of bridge.bus.codec.decode_batch (command, timer, ticks,
    time_ns, rx_ns and each quantity shaped as in the command table); ``receive_ns`` is
    when the recorder received each sample.
    """

    unit: str
    code: int
    columns: dict[str, np.ndarray]
    receive_ns: np.ndarray

    def __len__(self) -> int:
        return len(self.receive_ns)


@dataclass
class Archive:
    """Everything readable in one MCAP file.

    ``complete`` is true for a finished file (footer and closing magic present);
    ``dropped_bytes`` counts the unreadable tail of one that is not (a record cut short
    or corrupt), and ``problem`` says what stopped the reading.
    """

    path: Path
    size: int
    header: Header | None = None
    complete: bool = False
    dropped_bytes: int = 0
    problem: str | None = None
    chunks: int = 0
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, ChannelInfo] = field(default_factory=dict)
    metadata: list[Metadata] = field(default_factory=list)
    attachments: list[Attachment] = field(default_factory=list)
    blocks: list[_Block] = field(default_factory=list)

    # -- what is in it -------------------------------------------------------------------

    @property
    def message_count(self) -> int:
        return sum(len(b.channel) for b in self.blocks)

    def topics(self, kind: str | None = None) -> list[str]:
        return sorted({c.topic for c in self.channels.values() if kind in (None, c.kind)})

    def units(self) -> list[str]:
        return sorted({c.unit for c in self.channels.values() if c.unit})

    def _ids(self, topic: str | None = None, kind: str | None = None,
             unit: str | None = None) -> np.ndarray:
        """Ids of the channels that match (a topic can have several after a merge)."""
        return np.array([c.id for c in self.channels.values()
                         if topic in (None, c.topic) and kind in (None, c.kind)
                         and unit in (None, c.unit)], np.uint16)

    def first_sample_ns(self) -> int | None:
        """Log time (= live time_ns) of the earliest ImuSample, if any."""
        ids = self._ids(kind="imu")
        firsts = [int(b.log_time[m].min()) for b in self.blocks
                  if (m := np.isin(b.channel, ids)).any()]
        return min(firsts) if firsts else None

    def counts(self) -> dict[str, tuple[int, int, int]]:
        """Per topic: (messages, first log time, last log time) in ns."""
        out: dict[str, tuple[int, int, int]] = {}
        for topic in self.topics():
            m = self.messages(topic)
            if len(m):
                out[topic] = (len(m), int(m.log_time[0]), int(m.log_time[-1]))
        return out

    # -- messages ------------------------------------------------------------------------

    def messages(self, topic: str) -> Messages:
        """Every message of ``topic``, in log-time order."""
        ids = self._ids(topic)
        info = next(c for c in self.channels.values() if c.topic == topic) if len(ids) else None
        parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        payloads: list[bytes] = []
        for block in self.blocks:
            mask = np.isin(block.channel, ids)
            if mask.any():
                parts.append((block.log_time[mask], block.publish_time[mask],
                              block.sequence[mask]))
                payloads.extend(block.payloads(mask))
        log, pub, seq = (np.concatenate([p[i] for p in parts]) if parts
                         else np.zeros(0, np.int64) for i in range(3))
        order = np.argsort(log, kind="stable")
        return Messages(topic, info.unit if info else "", info.kind if info else "",
                        log[order], pub[order], seq[order], [payloads[i] for i in order])

    def iter_messages(self, topics: Iterable[str] | None = None,
                      units: Iterable[str] | None = None) -> Iterator[Record]:
        """Messages of ``topics`` and ``units`` (default: all) merged in log-time order."""
        chosen = self.topics() if topics is None else list(topics)
        if units is not None:
            keep = set(units)
            chosen = [t for t in chosen if any(c.unit in keep for c in self.channels.values()
                                               if c.topic == t)]
        msgs = [self.messages(t) for t in chosen]
        if not msgs:
            return
        which = np.repeat(np.arange(len(msgs)), [len(m) for m in msgs]).tolist()
        index = np.concatenate([np.arange(len(m)) for m in msgs]).tolist()
        times = np.concatenate([m.log_time for m in msgs])
        for k in np.argsort(times, kind="stable").tolist():
            m, i = msgs[which[k]], index[k]
            yield Record(m.topic, int(m.log_time[i]), int(m.publish_time[i]),
                         int(m.sequence[i]), m.payloads[i])

    # -- decoded -------------------------------------------------------------------------

    def samples(self, units: Iterable[str] | None = None,
                codes: Iterable[int] | None = None) -> list[Samples]:
        """ImuSamples decoded in bulk, one ``Samples`` per unit and record type."""
        wanted_codes = None if codes is None else set(codes)
        groups: dict[tuple[str, int], tuple[list[bytes], list[np.ndarray], list[np.ndarray]]]
        groups = {}
        chosen = self.units() if units is None else sorted(set(units))
        for unit, ids in ((u, self._ids(kind="imu", unit=u)) for u in chosen):
            for block in self.blocks:
                mask = np.isin(block.channel, ids)
                if not mask.any():
                    continue
                commands = block.commands(mask, unit)
                payloads = block.payloads(mask)
                logs, pubs = block.log_time[mask], block.publish_time[mask]
                for code in np.unique(commands).tolist():
                    if wanted_codes is not None and code not in wanted_codes:
                        continue
                    pick = commands == code
                    group = groups.setdefault((unit, code), ([], [], []))
                    group[0].extend(p for p, ok in zip(payloads, pick.tolist(), strict=True)
                                    if ok)
                    group[1].append(logs[pick])
                    group[2].append(pubs[pick])
        out: list[Samples] = []
        for (unit, code), (found, log_parts, pub_parts) in sorted(groups.items()):
            order = np.argsort(np.concatenate(log_parts), kind="stable")
            try:
                cols = decode_batch(unit, code, found)
            except ValueError as exc:
                raise ArchiveReadError(f"{self.path}: unit {unit}: {exc}") from None
            out.append(Samples(unit, code, {k: v[order] for k, v in cols.items()},
                               np.concatenate(pub_parts)[order]))
        return out

    def events(self, units: Iterable[str] | None = None) -> list[tuple[str, Event]]:
        """(unit, Event) of every event channel, in time order."""
        wanted = None if units is None else set(units)
        out: list[tuple[int, str, Event]] = []
        for topic in self.topics("event"):
            msgs = self.messages(topic)
            if wanted is not None and msgs.unit not in wanted:
                continue
            for t, p in zip(msgs.log_time.tolist(), msgs.payloads, strict=True):
                out.append((t, msgs.unit, Event.FromString(p)))
        out.sort(key=lambda e: e[0])
        return [(u, e) for _, u, e in out]

    def summary(self) -> str:
        """Units, record types, message counts and time ranges, one line each."""
        lines = [f"{self.path}: {self.size} bytes, {self.message_count} messages, "
                 f"{self.chunks} chunks, " + ("complete" if self.complete else
                 f"not finished ({self.dropped_bytes} bytes dropped"
                 + (f": {self.problem}" if self.problem else "") + ")")]
        for topic, (n, t0, t1) in self.counts().items():
            lines.append(f"  {topic}: {n} messages, {(t1 - t0) / 1e9:.3f} s "
                         f"from {np.datetime64(t0, 'ns')}Z")
        for s in self.samples():
            lines.append(f"  {s.unit} 0x{s.code:02X}: {len(s)} samples")
        return "\n".join(lines)


# -- scanning --------------------------------------------------------------------------


def _read_stream(body: bytes) -> ReadDataStream:
    return ReadDataStream(io.BytesIO(body))


def _channel_info(ch: Channel, schemas: dict[int, Schema]) -> ChannelInfo:
    parts = ch.topic.split("/")
    unit = ch.metadata.get("unit") or (parts[-2] if len(parts) >= 3 else "")
    schema = schemas.get(ch.schema_id)
    return ChannelInfo(ch.id, ch.topic, unit, parts[-1], ch.message_encoding, ch.schema_id,
                       schema.name if schema else "", dict(ch.metadata))


def _walk(archive: Archive, data: bytes) -> None:
    """Schemas, channels and message records of a chunk's (or a file's) inner records."""
    starts: list[int] = []
    lengths: list[int] = []
    off, end = 0, len(data)
    unpack = _RECORD.unpack_from
    while off < end:
        if off + 9 > end:
            raise ValueError("record header cut short inside a chunk")
        opcode, length = unpack(data, off)
        body = off + 9
        if body + length > end:
            raise ValueError("record longer than its chunk")
        if opcode == _OPCODE_MESSAGE:
            starts.append(body)
            lengths.append(length)
        else:
            _other(archive, opcode, data[body : body + length])
        off = body + length
    if starts:
        offsets = np.array(starts, np.int64)
        buf = np.frombuffer(data, np.uint8)
        head = np.ascontiguousarray(buf[offsets[:, None] + _HEAD]).view(_MESSAGE)[:, 0]
        archive.blocks.append(_Block(
            data, head["channel"].copy(), head["sequence"].copy(),
            head["log_time"].astype(np.int64), head["publish_time"].astype(np.int64),
            offsets + _MESSAGE.itemsize, np.array(lengths, np.int64) - _MESSAGE.itemsize))


def _other(archive: Archive, opcode: int, body: bytes) -> None:
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


def _chunk(archive: Archive, body: bytes) -> None:
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
    _walk(archive, stream.read(n_bytes))
    archive.chunks += 1


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


def read_archive(path: Path | str, progress: Callable[[int], None] | None = None) -> Archive:
    """Read what is readable of an MCAP file; ``progress`` gets the bytes read so far.

    Never raises on a damaged tail: the archive reports it (``complete``,
    ``dropped_bytes``, ``problem``). Raises ArchiveReadError when the file is missing,
    empty or not MCAP at all.
    """
    path = Path(path)
    stream, size = _open(path)
    archive = Archive(path, size)
    pos = len(MAGIC)
    summary = False
    with stream:
        while True:
            head = stream.read(9)
            if len(head) < 9:
                archive.problem = "the file ends without a summary (the writer did not finish)" \
                    if not head else "a record header is cut short"
                break
            opcode, length = _RECORD.unpack(head)
            if pos + 9 + length > size:
                archive.problem = f"a record at byte {pos} is cut short"
                break
            body = stream.read(length)
            try:
                if opcode == Opcode.CHUNK:
                    _chunk(archive, body)
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
    archive.dropped_bytes = size - pos
    if archive.dropped_bytes and archive.complete:
        archive.problem = f"{archive.dropped_bytes} bytes after the end of the file"
    return archive


def describe_problem(archive: Archive) -> str:
    """One line about a file that did not read to its end; empty when it did."""
    if archive.complete and not archive.dropped_bytes:
        return ""
    return (f"{archive.path}: not finished, read up to its last complete chunk "
            f"({archive.dropped_bytes} bytes dropped; {archive.problem})")
