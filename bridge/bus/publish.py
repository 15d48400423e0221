"""Everything one bridge declares on Zenoh for its unit.

Data keys use BLOCK congestion control and RELIABLE reliability: telemetry is
never dropped silently. They go through zenoh.ext's advanced publisher, whose
cache lets a subscriber that lost its link for a moment recover the samples,
and whose heartbeat lets it count exactly what it could not recover. Each message
carries the CRC-32 of its payload in its attachment (bridge/bus/integrity.py), so a
payload damaged on the way is caught. One imu put in ``STAMP_EVERY`` also carries the
instant it was put, which the latencies are measured on (``bridge.bus.metrics``), so
that the other reads pay nothing for them.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from types import TracebackType
from typing import Any

import numpy as np
import zenoh
from zenoh.ext import (
    AdvancedPublisher,
    CacheConfig,
    MissDetectionConfig,
    declare_advanced_publisher,
)

from bridge import _native as native
from bridge.bus.codec import RecordBatch, encode_batch, encode_records, native_layout
from bridge.bus.gx3_pb2 import Event, Info, Status
from bridge.bus.integrity import seal, seals
from bridge.bus.keys import ENCODINGS, PREFIX, UnitKeys
from bridge.device import clock
from bridge.protocol.codec import Records

#: Default imu cache: five seconds at the unit's top rate of 1 kHz.
CACHE_SAMPLES = 5000
#: One imu put in this many carries the instant it was put (its last message's
#: attachment, ``bridge.bus.integrity``): 6 a second at 100 Hz, 62 at 1 kHz.
STAMP_EVERY = 16
HEARTBEAT_S = 0.5
REFUSAL = ("commands are disabled on this bridge: restart it with --allow-commands "
           "to let operators act on the unit over Zenoh")

#: An operator command handler: command text in, one-line result out; raising
#: ValueError answers the query with that error.
CommandHandler = Callable[[str], str]


def declare_data_publisher(session: zenoh.Session, key: str, encoding: str,
                           cache: int, heartbeat_s: float = HEARTBEAT_S) -> AdvancedPublisher:
    """A data key's publisher, as every bridge declares it (also measured by the bench).

    BLOCK congestion control, RELIABLE, a cache of ``cache`` samples, heartbeats for
    miss detection, and publisher detection.

    Args:
        session: The session to declare it on.
        key: The key.
        encoding: The payloads' encoding (``ENCODINGS``).
        cache: Samples the cache holds for subscribers that recover.
        heartbeat_s: Seconds between heartbeats.

    Returns:
        The publisher; the caller undeclares it.
    """
    return declare_advanced_publisher(
        session, key, encoding=encoding,
        congestion_control=zenoh.CongestionControl.BLOCK,
        reliability=zenoh.Reliability.RELIABLE,
        cache=CacheConfig(max_samples=cache),
        sample_miss_detection=MissDetectionConfig(heartbeat=heartbeat_s,
                                                  sporadic_heartbeat=None),
        publisher_detection=True)


def sealed_records(unit: str, records: Records, ticks: list[int], time_ns: list[int],
                   rx_ns: list[int], part_rx_ns: list[int],
                   part_lead_ns: list[int]) -> tuple[list[bytes], list[bytes]]:
    """The ImuSample payloads of a live read's records and their attachments (``seal``).

    In one call of the compiled core where it is built, else ``encode_records`` and
    ``seals``, with the same bytes.

    Args:
        unit: The unit's name.
        records: The records; their own ``rx_ns`` are the raw clock's.
        ticks: Each record's unwrapped ticks.
        time_ns: Each record's sample instant.
        rx_ns: The completing reads' realtime stamps.
        part_rx_ns: Each partial read's raw-clock stamp, as ``records.rx_ns`` are.
        part_lead_ns: The line time of the record's bytes each held.

    Returns:
        The payloads and their attachments.
    """
    times = (ticks, time_ns, rx_ns, records.rx_ns, part_rx_ns, part_lead_ns)
    core = native.records
    if core is None:
        payloads = encode_records(unit, records.code, records.little_endian, records.wire,
                                  times)
        return payloads, seals(payloads)
    return core.messages(*native_layout(records.code, unit, records.little_endian),
                         records.wire, times)


class UnitPublisher:
    """Everything one unit puts on Zenoh, declared together and undeclared together.

    The imu, status and event publishers (and raw, if asked), the info and command
    queryables and the liveliness token. The session stays the caller's; use as a
    context manager or call ``close``. ``published`` counts the samples put.

    Args:
        session: The session to declare them on.
        unit: The unit's name.
        prefix: The keys' prefix.
        cache_samples: Samples the imu cache holds for subscribers that recover.
        heartbeat_s: Seconds between the publishers' heartbeats.
        on_command: Answers operator commands (JSON text in, one line out; raising
            ValueError answers with that error).
        allow_commands: Whether ``on_command`` is asked at all; without, every command
            is refused with what to do.
        raw: Declare the raw publisher (``publish_raw``).
        on_stamped: Hears ``(received_ns, published_ns)`` of each put stamped with its
            publish time (one in ``STAMP_EVERY``): when the read that completed its last
            record was received, and when the put returned (with BLOCK congestion
            control, once Zenoh took the samples), on the realtime clock.

    Raises:
        BadName: The unit name or the prefix cannot be used in a key.
    """

    def __init__(self, session: zenoh.Session, unit: str, *, prefix: str = PREFIX,
                 cache_samples: int = CACHE_SAMPLES, heartbeat_s: float = HEARTBEAT_S,
                 on_command: CommandHandler | None = None, allow_commands: bool = False,
                 raw: bool = False,
                 on_stamped: Callable[[int, int], None] | None = None) -> None:
        self.keys = UnitKeys(unit, prefix)
        self.unit = unit
        self.published = 0
        self._on_stamped = on_stamped
        self._unstamped = 0  # puts before the next stamped one
        self._info: bytes | None = None
        self._on_command = on_command if allow_commands else None
        self._lock = threading.Lock()
        self._closed = False
        self._declared: list[Any] = []
        try:
            self._imu = self._advanced(session, "imu", cache_samples, heartbeat_s)
            self._status = self._advanced(session, "status", 1, heartbeat_s)
            self._event = self._advanced(session, "event", 100, heartbeat_s)
            self._raw = self._advanced(session, "raw", 100, heartbeat_s) if raw else None
            self._declared.append(session.declare_queryable(self.keys.info, self._answer_info))
            self._declared.append(session.declare_queryable(self.keys.command,
                                                            self._answer_command))
            self._declared.append(session.liveliness().declare_token(self.keys.alive))
        except BaseException:
            self.close()
            raise

    def _advanced(self, session: zenoh.Session, leaf: str, cache: int,
                  heartbeat_s: float) -> AdvancedPublisher:
        pub = declare_data_publisher(session, getattr(self.keys, leaf), ENCODINGS[leaf], cache,
                                     heartbeat_s)
        self._declared.append(pub)
        return pub

    def publish_samples(self, batch: RecordBatch, ticks: np.ndarray, time_ns: np.ndarray,
                        rx_ns: np.ndarray | None = None,
                        part: tuple[np.ndarray, np.ndarray] | None = None) -> int:
        """One ImuSample per record of ``batch``, each sealed with its CRC-32.

        Args:
            batch: The records.
            ticks: Each record's unwrapped timer, from the timing model.
            time_ns: Each record's host-clock instant, filter delay taken out.
            rx_ns: The completing reads' realtime stamps, ``batch.rx_ns`` then being
                their raw-clock ones (a live bridge's); None: ``batch.rx_ns`` are
                realtime stamps, with no raw ones.
            part: Each record's partial read (``part_rx_mono_raw_ns``, ``part_lead_ns``).

        Returns:
            Samples put.
        """
        if rx_ns is None:
            return self._put_imu(encode_batch(self.unit, batch, ticks, time_ns, batch.rx_ns,
                                              part=part), received_ns=batch.rx_ns)
        return self._put_imu(encode_batch(self.unit, batch, ticks, time_ns, rx_ns,
                                          batch.rx_ns, part), received_ns=rx_ns)

    def publish_records(self, records: Records, ticks: list[int], time_ns: list[int],
                        rx_ns: list[int], part_rx_ns: list[int],
                        part_lead_ns: list[int]) -> int:
        """``publish_samples`` of a live read's record or two, from their wire bytes.

        Args:
            records: The records; their ``rx_ns`` are the raw clock's.
            ticks: Each record's unwrapped timer.
            time_ns: Each record's host-clock instant.
            rx_ns: The completing reads' realtime stamps.
            part_rx_ns: Each record's partial read, as ``sealed_records`` takes it.
            part_lead_ns: The same.

        Returns:
            Samples put.
        """
        return self._put_imu(*sealed_records(self.unit, records, ticks, time_ns, rx_ns,
                                             part_rx_ns, part_lead_ns), received_ns=rx_ns)

    def _put_imu(self, payloads: list[bytes], attachments: list[bytes] | None = None, *,
                 received_ns: Sequence[int] | np.ndarray) -> int:
        """Put ImuSample payloads back to back, each sealed with its CRC-32.

        One call in ``STAMP_EVERY`` seals its last payload with the instant of the put too.
        """
        put = self._imu.put
        sealed = attachments or seals(payloads)
        self._unstamped -= 1
        stamped = self._unstamped < 0 and bool(payloads)
        if stamped:
            self._unstamped = STAMP_EVERY - 1
            published = clock.realtime_ns()
            sealed = [*sealed[:-1], seal(payloads[-1], published)]
        for payload, attachment in zip(payloads, sealed, strict=True):
            put(payload, attachment=attachment)
        self.published += len(payloads)
        if stamped and self._on_stamped is not None:  # once put (BLOCK: once Zenoh took it)
            self._on_stamped(int(received_ns[-1]), clock.realtime_ns())
        return len(payloads)

    def publish_status(self, status: Status) -> None:
        """Put a Status, sealed; its ``unit`` is set to this unit's if empty.

        Args:
            status: The message.

        Raises:
            ValueError: It names another unit.
        """
        payload = self._own(status).SerializeToString()
        self._status.put(payload, attachment=seal(payload))

    def publish_event(self, event: Event) -> None:
        """Put an Event, sealed; its ``unit`` is set to this unit's if empty.

        Args:
            event: The message.

        Raises:
            ValueError: It names another unit.
        """
        payload = self._own(event).SerializeToString()
        self._event.put(payload, attachment=seal(payload))

    def publish_raw(self, data: bytes, raw_ns: int, real_ns: int) -> None:
        """Put the bytes of one read, its checksum and host receive times attached.

        Args:
            data: The read's bytes.
            raw_ns: Its receive time on the raw monotonic clock.
            real_ns: The same instant on the realtime clock.

        Raises:
            ValueError: The publisher was declared without ``raw=True``.
        """
        if self._raw is None:
            raise ValueError("this UnitPublisher was declared without raw=True")
        self._raw.put(data, attachment=seal(data, real_ns, raw_ns))

    def set_info(self, info: Info) -> None:
        """What the info queryable answers from now on.

        Args:
            info: The message; its ``unit`` is set to this unit's if empty.

        Raises:
            ValueError: It names another unit.
        """
        self._info = self._own(info).SerializeToString()

    def _own(self, message: Any) -> Any:
        if not message.unit:
            message.unit = self.unit
        elif message.unit != self.unit:
            raise ValueError(f"a {type(message).__name__} of unit {message.unit!r} cannot go out "
                             f"on the publisher of unit {self.unit!r}")
        return message

    def _answer_info(self, query: zenoh.Query) -> None:
        if self._info is None:
            query.reply_err(f"{self.unit}: no Info yet, the unit is still being brought up")
        else:
            query.reply(self.keys.info, self._info, encoding=ENCODINGS["info"],
                        attachment=seal(self._info))

    def _answer_command(self, query: zenoh.Query) -> None:
        if self._on_command is None:
            query.reply_err(f"{self.unit}: {REFUSAL}")
            return
        text = query.payload.to_string() if query.payload is not None else str(query.parameters)
        try:
            result = self._on_command(text)
        except ValueError as exc:
            query.reply_err(f"{self.unit}: {exc}")
            return
        query.reply(self.keys.command, result, encoding=ENCODINGS["command"])

    def close(self) -> None:
        """Undeclare everything (the liveliness token goes first); safe to call twice."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        for entity in reversed(self._declared):
            entity.undeclare()
        self._declared.clear()

    def __enter__(self) -> UnitPublisher:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
