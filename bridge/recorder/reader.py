"""Reading archives and raw captures, finished or cut short, into per-unit NumPy columns.

One sequential pass over the file's records serves a finished archive, one whose writer
was killed and a raw capture alike: a cut-off tail is measured, never parsed, and a
corrupt chunk of a finished file is skipped, so everything readable is kept. Chunks are
decompressed once and samples decoded from rows read straight out of them, so a million
samples read in about a second. How the reading goes, record by record:
``docs/design/archive.md``.
"""

from __future__ import annotations

import io
import logging
import struct
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, NamedTuple, TypeVar

import numpy as np
from google.protobuf.message import DecodeError, Message
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Attachment, Channel, Chunk, ChunkIndex, Header, Metadata, Schema
from mcap.stream_reader import get_chunk_data_stream
from mcap.summary import Summary

from bridge.bus.codec import HEADERS, decode_batch, layout, parse, peek
from bridge.bus.gx3_pb2 import Event
from bridge.exceptions import ArchiveReadError

_log = logging.getLogger(__name__)

M = TypeVar("M", bound=Message)

MAGIC = b"\x89MCAP0\r\n"
_RECORD = struct.Struct("<BQ")
_CHUNK_HEAD = struct.Struct("<QQQII")
_U64 = struct.Struct("<Q")
_U32 = struct.Struct("<I")
_MESSAGE = np.dtype([("channel", "<u2"), ("sequence", "<u4"), ("log_time", "<u8"),
                     ("publish_time", "<u8")])
_OPCODE_MESSAGE = int(Opcode.MESSAGE)


@dataclass(frozen=True)
class Damage:
    """A chunk skipped because it is corrupt, and what the index says it held."""

    offset: int
    start_ns: int
    end_ns: int
    why: str
    lost: dict[str, int] | None  # messages per topic (None: its indexes are damaged too)


@dataclass(frozen=True)
class ChannelInfo:
    """A channel: its topic, the unit and key leaf it belongs to, and its encoding."""

    id: int
    topic: str
    unit: str
    kind: str  # the topic's last chunk: imu, status, event, info, frame, log, raw
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

    def commands(self, picked: np.ndarray, unit: str) -> np.ndarray:
        """Command bytes of the ImuSamples at indexes ``picked``.

        Read at their fixed place in the bulk layout (tags checked), parsed for messages
        in any other layout.
        """
        n = len(unit.encode())
        start, length = self.start[picked], self.length[picked]
        buf = np.frombuffer(self.data, np.uint8)
        fits = length >= n + 7
        long_enough = np.flatnonzero(fits)
        at = start[long_enough]
        fits[long_enough] = (buf[at] == 0x0A) & (buf[at + 1] == n) & (buf[at + 2 + n] == 0x15)
        out = np.zeros(len(start), np.int64)
        out[long_enough] = _rows(buf, at + 3 + n, 4).copy().view("<u4")[:, 0]
        for i in np.flatnonzero(~fits).tolist():
            s = int(start[i])
            try:
                out[i] = peek(self.data[s : s + int(length[i])])[1]
            except ValueError:
                out[i] = -1  # not an ImuSample: left out, and counted, by ``samples``
        return out

    def __len__(self) -> int:
        return len(self.channel)

    def payloads(self, picked: np.ndarray) -> list[bytes]:
        data = self.data
        return [data[s : s + n] for s, n in zip(self.start[picked].tolist(),
                                                self.length[picked].tolist(), strict=True)]

    def rows(self, picked: np.ndarray, width: int) -> np.ndarray:
        """(len(picked), width) bytes of the payloads at indexes ``picked``, all ``width`` long.

        Straight out of the chunk, no bytes object each.
        """
        return _rows(np.frombuffer(self.data, np.uint8), self.start[picked], width)


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
class ArchivedSamples:
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
class ArchiveReader:
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
    damage: list[Damage] = field(default_factory=list)
    skipped: Counter[str] = field(default_factory=Counter)
    warn: Callable[[str], None] = _log.warning
    streamed: int = 0  # messages handed to read_archive's on_blocks and dropped

    def skip(self, topic: str, count: int, why: str) -> None:
        """Leave out ``count`` bad messages of ``topic`` and say so, once per topic and reason.

        Args:
            topic: Where the messages are.
            count: How many are left out.
            why: Why, in words that follow "skipped N message(s)".
        """
        if count:
            if not self.skipped[f"{topic}: {why}"]:
                self.warn(f"{self.path}: {topic}: skipped {count} message(s) {why}")
            self.skipped[f"{topic}: {why}"] += count

    # -- what is in it -------------------------------------------------------------------

    @property
    def message_count(self) -> int:
        """Messages read, on every channel (those streamed and dropped too)."""
        return self.streamed + sum(len(b.channel) for b in self.blocks)

    def topics(self, kind: str | None = None) -> list[str]:
        """The topics read, sorted.

        Args:
            kind: Only topics whose last chunk is this (``imu``, ``status``, ``event``,
                ``info``, ``raw``, ...); None: every topic.

        Returns:
            Topic names.
        """
        return sorted({c.topic for c in self.channels.values() if kind in (None, c.kind)})

    def units(self) -> list[str]:
        """The units that have a channel.

        Returns:
            Their names, sorted.
        """
        return sorted({c.unit for c in self.channels.values() if c.unit})

    def _ids(self, topic: str | None = None, kind: str | None = None,
             unit: str | None = None) -> np.ndarray:
        """Ids of the channels that match (a topic can have several after a merge)."""
        return np.array([c.id for c in self.channels.values()
                         if topic in (None, c.topic) and kind in (None, c.kind)
                         and unit in (None, c.unit)], np.uint16)

    def first_sample_ns(self) -> int | None:
        """When the earliest sample was taken.

        Returns:
            Log time (= live ``time_ns``) of the earliest ImuSample; None if there is none.
        """
        ids = self._ids(kind="imu")
        firsts = [int(b.log_time[m].min()) for b in self.blocks
                  if (m := np.isin(b.channel, ids)).any()]
        return min(firsts) if firsts else None

    def counts(self) -> dict[str, tuple[int, int, int]]:
        """How many messages each topic holds, and when.

        Returns:
            Topic -> (messages, first log time, last log time), times in ns.
        """
        channel = np.concatenate([b.channel for b in self.blocks]) if self.blocks \
            else np.zeros(0, np.uint16)
        log = np.concatenate([b.log_time for b in self.blocks]) if self.blocks \
            else np.zeros(0, np.int64)
        out: dict[str, tuple[int, int, int]] = {}
        for topic in self.topics():
            times = log[np.isin(channel, self._ids(topic))]
            if len(times):
                out[topic] = (len(times), int(times.min()), int(times.max()))
        return out

    # -- messages ------------------------------------------------------------------------

    def messages(self, topic: str) -> Messages:
        """Every message of one topic, in log-time order.

        Args:
            topic: The topic; one that is not there gives no messages.

        Returns:
            Their times, sequence numbers and payloads.
        """
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
        """Messages of several topics, merged in log-time order.

        Args:
            topics: The topics; None: every topic.
            units: Only the topics of these units; None: every unit's.

        Yields:
            One record per message.
        """
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
                codes: Iterable[int] | None = None) -> list[ArchivedSamples]:
        """ImuSamples decoded in bulk, one ``ArchivedSamples`` per unit and record type.

        Each chunk's messages are grouped by unit and command with array operations; a
        group whose messages all have the bulk layout's size reaches the decoder as rows
        read straight out of the chunks, any other as one bytes object per message.
        Messages that are not samples of their unit are left out, and said once
        (``skip``).

        Args:
            units: Only these units; None: every unit.
            codes: Only these record types (command bytes); None: every type.

        Returns:
            Sample columns, by unit and then record type.
        """
        wanted_codes = None if codes is None else set(codes)
        chosen = self.units() if units is None else sorted(set(units))
        unit_of = np.full(1 << 16, -1, np.int64)  # channel id -> index in chosen
        for c in self.channels.values():
            if c.kind == "imu" and c.unit in chosen:
                unit_of[c.id] = chosen.index(c.unit)
        groups: dict[tuple[str, int], list[tuple[_Block, np.ndarray]]] = {}
        for block in self.blocks:
            which = unit_of[block.channel]
            for k in np.unique(which[which >= 0]).tolist():
                picked = np.flatnonzero(which == k)
                commands = block.commands(picked, chosen[k])
                for code in np.unique(commands).tolist():
                    if wanted_codes is None or code in wanted_codes:
                        groups.setdefault((chosen[k], code), []).append(
                            (block, picked[commands == code]))
        out: list[ArchivedSamples] = []
        for (unit, code), parts in sorted(groups.items(), key=lambda g: g[0]):
            topic = self._topic(unit, "imu")
            try:
                layout(code, unit)
            except ValueError:
                self.skip(topic, sum(len(p) for _, p in parts), "that are not ImuSamples "
                          "of a known record type")
                continue
            try:
                cols = _decode(unit, code, parts)
            except ValueError:  # a message that is not this unit's, or corrupt: leave it out
                kept = [(b, p[_decodable(unit, code, b, p)]) for b, p in parts]
                bad = sum(len(p) for _, p in parts) - sum(len(p) for _, p in kept)
                self.skip(topic, bad, f"that do not decode as {unit}'s 0x{code:02X} samples "
                          "(another unit's name, or corrupt)")
                parts = [(b, p) for b, p in kept if len(p)]
                if not parts:
                    continue
                cols = _decode(unit, code, parts)
            order = np.argsort(np.concatenate([b.log_time[p] for b, p in parts]), kind="stable")
            out.append(ArchivedSamples(unit, code, {k: v[order] for k, v in cols.items()},
                               np.concatenate([b.publish_time[p] for b, p in parts])[order]))
        return out

    def _topic(self, unit: str, kind: str) -> str:
        return next((c.topic for c in self.channels.values()
                     if c.unit == unit and c.kind == kind), f"{unit}/{kind}")

    def decoded(self, topic: str, cls: type[M]) -> list[tuple[int, M]]:
        """Every message of a topic that parses as ``cls`` and names the topic's unit.

        The others are left out, and said once (``skip``).

        Args:
            topic: The topic.
            cls: The protobuf message class of its messages (``Status``, ``Info``, ...).

        Returns:
            (log time, message) pairs, in log-time order.
        """
        msgs = self.messages(topic)
        out: list[tuple[int, M]] = []
        bad = 0
        for t, payload in zip(msgs.log_time.tolist(), msgs.payloads, strict=True):
            try:
                msg = cls.FromString(payload)
            except DecodeError:
                bad += 1
                continue
            if getattr(msg, "unit", msgs.unit) not in (msgs.unit, ""):
                bad += 1
                continue
            out.append((t, msg))
        self.skip(topic, bad, f"that are not {cls.DESCRIPTOR.full_name}s of unit {msgs.unit}")
        return out

    def events(self, units: Iterable[str] | None = None) -> list[tuple[str, Event]]:
        """The events of every unit, in time order.

        Args:
            units: Only these units' events; None: every unit's.

        Returns:
            (unit, Event) pairs.
        """
        wanted = None if units is None else set(units)
        out: list[tuple[int, str, Event]] = []
        for topic in self.topics("event"):
            unit = next(c.unit for c in self.channels.values() if c.topic == topic)
            if wanted is not None and unit not in wanted:
                continue
            out += [(t, unit, event) for t, event in self.decoded(topic, Event)]
        out.sort(key=lambda e: e[0])
        return [(u, e) for _, u, e in out]

    def summary(self) -> str:
        """What the file holds, in words.

        Returns:
            Its size and state, then topics with their message counts and time ranges,
            then units and record types with their sample counts: one line each.
        """
        lines = [f"{self.path}: {self.size} bytes, {self.message_count} messages, "
                 f"{self.chunks} chunks, "
                 + (f"{len(self.damage)} corrupt chunk(s) skipped, " if self.damage else "")
                 + ("complete" if self.complete else
                 f"not finished ({self.dropped_bytes} bytes dropped"
                 + (f": {self.problem}" if self.problem else "") + ")")]
        for topic, (n, t0, t1) in self.counts().items():
            lines.append(f"  {topic}: {n} messages, {(t1 - t0) / 1e9:.3f} s "
                         f"from {np.datetime64(t0, 'ns')}Z")
        for s in self.samples():
            lines.append(f"  {s.unit} 0x{s.code:02X}: {len(s)} samples")
        return "\n".join(lines)


def _decode(unit: str, code: int, parts: list[tuple[_Block, np.ndarray]]
            ) -> dict[str, np.ndarray]:
    """decode_batch of the messages ``parts`` pick out of their chunks.

    Rows read straight out of the chunks when all have the size of one bulk layout (an
    older bridge's too), else a bytes object each.
    """
    found: np.ndarray | list[bytes] | None = None
    for header in HEADERS:
        size = layout(code, unit, header).size
        if all((b.length[p] == size).all() for b, p in parts):
            found = np.concatenate([b.rows(p, size) for b, p in parts])
            break
    if found is None:
        found = [payload for b, p in parts for payload in b.payloads(p)]
    return decode_batch(unit, code, found)


def _decodable(unit: str, code: int, block: _Block, picked: np.ndarray) -> np.ndarray:
    """Which of the messages at ``picked`` decode as ``unit``'s samples of ``code``.

    The bulk layout's fixed bytes are checked at once, any other message parsed on its own.
    """
    lay = layout(code, unit)
    ok = np.zeros(len(picked), bool)
    sized = np.flatnonzero(block.length[picked] == lay.size)
    if len(sized):
        rows = block.rows(picked[sized], lay.size)
        ok[sized] = (rows[:, lay.const_mask] == lay.template.view(np.uint8)[lay.const_mask]
                     ).all(axis=1)
    for i in np.flatnonzero(~ok).tolist():
        try:
            msg = parse(block.payloads(picked[i : i + 1])[0])
        except ValueError:
            continue
        ok[i] = msg.unit == unit and msg.command == code
    return ok


# -- scanning --------------------------------------------------------------------------


def _read_stream(body: bytes) -> ReadDataStream:
    return ReadDataStream(io.BytesIO(body))


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
    head = _rows(buf, offsets, 9)
    length = head[:, 1:].copy().view("<u8")[:, 0]
    ends = offsets + 9 + np.minimum(length, len(buf)).astype(np.int64)
    if ((head[:, 0] != _OPCODE_MESSAGE).any() or (length < _MESSAGE.itemsize).any()
            or ends[-1] > len(buf) or (ends[:-1] > offsets[1:]).any()):
        return none
    breaks = np.flatnonzero(ends[:-1] != offsets[1:])
    return offsets[np.r_[0, breaks + 1]], ends[np.r_[breaks, len(offsets) - 1]]


def _rows(buf: np.ndarray, starts: np.ndarray, width: int) -> np.ndarray:
    """(len(starts), width) bytes of ``buf`` from each start: one row copy each.

    Through a view of every window of ``width`` bytes, made without
    sliding_window_view's checks.
    """
    windows = np.ndarray((max(len(buf) - width + 1, 0), width), np.uint8, buf, strides=(1, 1))
    rows: np.ndarray = windows[starts]
    return rows


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
        head = np.ascontiguousarray(_rows(buf, offsets + 9, _MESSAGE.itemsize))
        head = head.view(_MESSAGE)[:, 0]
        length = _rows(buf, offsets + 1, 8).copy().view("<u8")[:, 0].astype(np.int64)
        archive.blocks.append(_Block(
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
                 on_blocks: Callable[[ArchiveReader], None] | None = None) -> ArchiveReader:
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
    topics = ", ".join(f"{t} {n}" for t, n in sorted(lost.items()))
    return (f"{archive.path}: skipped {len(archive.damage)} corrupt chunk(s) at byte(s) "
            + ", ".join(str(d.offset) for d in archive.damage)
            + f" ({archive.damage[0].why}): lost {sum(lost.values())} messages"
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
            f"({archive.dropped_bytes} bytes dropped; {archive.problem})")
