"""What was read of an archive, and what it is asked: topics, units, messages, samples.

``read_archive`` (``bridge.archive.walk``) fills an ``ArchiveReader``; its samples are
decoded by ``bridge.archive.samples`` and it is put in words by ``bridge.archive.explain``.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple, TypeVar

import numpy as np
from google.protobuf.message import DecodeError, Message
from mcap.records import Attachment, Header, Metadata, Schema

from bridge.archive.explain import describe_contents
from bridge.archive.records import Block, ChannelInfo, Damage
from bridge.archive.samples import ArchivedSamples, decode_samples
from bridge.bus.gx3_pb2 import Event

_log = logging.getLogger(__name__)

M = TypeVar("M", bound=Message)


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
    blocks: list[Block] = field(default_factory=list)
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

        Read straight out of the chunks (``bridge.archive.samples``). Messages that are
        not samples of their unit are left out, and said once (``skip``).

        Args:
            units: Only these units; None: every unit.
            codes: Only these record types (command bytes); None: every type.

        Returns:
            Sample columns, by unit and then record type.
        """
        chosen = self.units() if units is None else sorted(set(units))
        return decode_samples(self.blocks, self.channels.values(), chosen, codes, self.skip)

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
        return describe_contents(self)
