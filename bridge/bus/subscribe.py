"""Subscribing to gx3 keys from an application: typed samples, NumPy batches or raw bytes.

An advanced subscriber with recovery: after a short link loss the samples come back
from the publisher's cache, in order; what cannot come back is counted in
``misses`` (and passed to ``on_miss``), never silently bridged.

Each publisher's key is declared on the session as it appears (``routes``), which keeps
Zenoh's routing of a sample cheap however many units there are.

Samples wait in a bounded Zenoh FIFO channel and are taken out in bulk by the reading
thread: Zenoh's threads never need the GIL for a sample, and a full channel holds
Zenoh (and, with BLOCK congestion control, the publishers) back instead of dropping.

Every message on a gx3 data key is checked as it is taken out (bridge/bus/integrity.py):
one whose payload does not match the CRC-32 in its attachment, or that names another
unit than its key's, never reaches the app; it is counted in ``rejected`` and passed
to ``on_reject``.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, Generic, Literal, NamedTuple, TypedDict, TypeVar, Unpack, overload

import numpy as np
import zenoh
from zenoh.ext import HistoryConfig, Miss, RecoveryConfig, declare_advanced_subscriber

from bridge.bus.codec import decode_batch, parse, peek
from bridge.bus.gx3_pb2 import ImuSample
from bridge.bus.integrity import BAD_CHECKSUM, NOT_OF_KEY, SEALED, agree, intact
from bridge.bus.keys import PREFIX, fleet
from bridge.bus.routes import PublisherKeys
from bridge.bus.session import ZenohOptions, condense

T = TypeVar("T")
_IDLE_S = 0.005  # how long a reader waits before looking into an empty channel again


class RawMessage(NamedTuple):
    """One message as it came: for archiving the very bytes (MCAP) or other types."""

    key: str
    payload: bytes
    encoding: str


@dataclass(frozen=True)
class SampleBatch:
    """Consecutive samples of one unit and record type, as columns.

    ``columns`` holds each quantity (shaped as in the command table, e.g. m is
    (n, 3, 3)) and command, timer, ticks, time_ns, rx_ns, rx_mono_raw_ns.
    ``batch["accel"]`` is ``batch.columns["accel"]``; ``len(batch)`` the sample count.
    """

    unit: str
    code: int
    columns: dict[str, np.ndarray]

    def __len__(self) -> int:
        return len(self.columns["ticks"])

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]


@dataclass
class Arrivals:
    """Checked messages of one key, in the order they came.

    Their payloads and attachments (a raw read's attachment holds its receive time), and
    the Zenoh samples.
    """

    payloads: list[bytes]
    attachments: list[bytes | None]
    samples: list[zenoh.Sample]


#: ``on_reject(key, reason, count)``: messages of ``key`` that failed a check.
RejectHandler = Callable[[str, str, int], None]


def _route(key: str) -> tuple[str, str] | None:
    """(unit, leaf) of a gx3 key whose messages are checked, else None."""
    head, _, leaf = key.rpartition("/")
    unit = head.rpartition("/")[2]
    return (unit, leaf) if unit and leaf in SEALED else None


def check(got: list[zenoh.Sample], on_reject: RejectHandler | None = None
          ) -> dict[str, Arrivals]:
    """The samples that pass their checks, by key.

    Args:
        got: Samples as they arrived.
        on_reject: Hears ``(key, reason, count)`` of the others, per key and reason
            (``BAD_CHECKSUM``, ``NOT_OF_KEY``).

    Returns:
        Each key's messages that passed, in the order they came; keys with none left out.
    """
    groups: dict[str, Arrivals] = {}
    for sample in got:
        key = str(sample.key_expr)
        group = groups.get(key)
        if group is None:
            group = groups[key] = Arrivals([], [], [])
        group.payloads.append(sample.payload.to_bytes())
        attachment = sample.attachment
        group.attachments.append(None if attachment is None else attachment.to_bytes())
        group.samples.append(sample)
    for key, group in groups.items():
        route = _route(key)
        if route is None:
            continue
        whole = list(map(intact, group.payloads, group.attachments))
        sound = [ok and fits for ok, fits in
                 zip(whole, agree(*route, group.payloads), strict=True)]
        if all(sound):
            continue
        if on_reject is not None:
            for reason, n in ((BAD_CHECKSUM, whole.count(False)),
                              (NOT_OF_KEY, whole.count(True) - sound.count(True))):
                if n:
                    on_reject(key, reason, n)
        groups[key] = Arrivals([p for p, ok in zip(group.payloads, sound, strict=True) if ok],
                               [a for a, ok in zip(group.attachments, sound, strict=True) if ok],
                               [s for s, ok in zip(group.samples, sound, strict=True) if ok])
    return {key: group for key, group in groups.items() if group.payloads}


class Subscription(Generic[T]):
    """A context-managed iterator over what arrives on a key expression.

    Iteration blocks until something arrives; with ``idle_timeout`` it ends after
    that many seconds of silence. ``close`` (or leaving the ``with``) undeclares
    the subscriber and closes the session if this subscription opened it. ``misses``,
    ``rejected`` and ``received`` count what could not be recovered, what failed its
    checks and what arrived. ``subscribe`` makes one.

    Args:
        session: The session to declare the subscriber on.
        key: The key expression.
        convert: Turns checked arrivals into the items iterated.
        own_session: Close ``session`` with the subscription.
        history: Past samples to ask each publisher's cache for.
        max_batch: Most messages taken out of the channel at once.
        queue_size: The channel's capacity, in samples.
        idle_timeout: Seconds of silence that end iteration; None: never.
        on_miss: As ``subscribe``'s.
        on_reject: As ``subscribe``'s.
        on_conflict: As ``subscribe``'s.
    """

    def __init__(self, session: zenoh.Session, key: str,
                 convert: Callable[[dict[str, Arrivals]], list[T]], *, own_session: bool,
                 history: int, max_batch: int, queue_size: int, idle_timeout: float | None,
                 on_miss: Callable[[str, int], None] | None,
                 on_reject: RejectHandler | None = None,
                 on_conflict: Callable[[str, list[str]], None] | None = None) -> None:
        self.key = key
        self.misses = 0
        self.rejected = 0
        self.received = 0
        self._session = session if own_session else None
        self._convert = convert
        self._max_batch = max_batch
        self._idle_timeout = idle_timeout
        self._on_miss = on_miss
        self._on_reject = on_reject
        self._closed = threading.Event()
        self._lock = threading.Lock()
        self._pending: list[T] = []
        self._routes: PublisherKeys | None = None
        try:
            # before the first sample can come
            self._routes = PublisherKeys(session, key, on_conflict)
            self._sub = declare_advanced_subscriber(
                session, key, zenoh.handlers.FifoChannel(queue_size),
                history=HistoryConfig(detect_late_publishers=True, max_samples=history)
                if history else None,
                recovery=RecoveryConfig(heartbeat=True, periodic_queries=None))
            # in Zenoh's own thread, in step with the samples (not queued to another)
            self._listener = self._sub.sample_miss_listener(
                zenoh.handlers.Callback(self._missed, indirect=False))
        except BaseException:
            if self._routes is not None:
                self._routes.close()
            if self._session is not None:
                self._session.close()
            raise
        self._try_recv: Callable[[], zenoh.Sample | None] = self._sub.handler.try_recv

    def _missed(self, miss: Miss) -> None:
        """Called by Zenoh before it delivers the first sample after the loss."""
        with self._lock:
            self.misses += miss.nb
        if self._on_miss is not None:
            source = miss.source
            key = None if self._routes is None else self._routes.key_of(str(source.zid),
                                                                        int(source.eid))
            self._on_miss(key or str(source), miss.nb)

    def _rejected(self, key: str, reason: str, n: int) -> None:
        with self._lock:
            self.rejected += n
        if self._on_reject is not None:
            self._on_reject(key, reason, n)

    def take(self, limit: int, timeout: float | None = 0.0) -> list[zenoh.Sample]:
        """Up to ``limit`` samples as they arrived.

        Args:
            limit: The most samples taken.
            timeout: Seconds to wait for the first (None: until something arrives or
                the subscription closes).

        Returns:
            Those that pass their checks, each key's in the order they came; [] after
            the timeout or once closed.
        """
        return [s for group in self._take(limit, timeout).values() for s in group.samples]

    def _take(self, limit: int, timeout: float | None) -> dict[str, Arrivals]:
        deadline = None if timeout is None else time.monotonic() + timeout
        while not self._closed.is_set():
            got = self._drain(limit)
            wait = _IDLE_S if deadline is None else min(_IDLE_S, deadline - time.monotonic())
            if got or wait <= 0:
                self.received += len(got)
                return check(got, self._rejected)
            self._closed.wait(wait)
        return {}

    def _drain(self, limit: int) -> list[zenoh.Sample]:
        got: list[zenoh.Sample] = []
        append, try_recv = got.append, self._try_recv
        try:
            while len(got) < limit and (sample := try_recv()) is not None:
                append(sample)
        except zenoh.ZError:  # the channel is closed: the subscriber is gone
            pass
        return got

    def take_by_key(self, limit: int) -> dict[str, Arrivals]:
        """What has arrived and passes its checks, by key, without waiting.

        Args:
            limit: The most messages taken.

        Returns:
            Each key's messages, in the order they came.
        """
        return self._take(limit, 0.0)

    def get(self, timeout: float | None = None) -> T | None:
        """The next item.

        Args:
            timeout: Seconds to wait (None: until something arrives or the subscription
                closes).

        Returns:
            The item, or None after the timeout or once closed.
        """
        if not self._pending:
            self._pending = self._convert(self._take(self._max_batch, timeout))
            self._pending.reverse()
        return self._pending.pop() if self._pending else None

    def __iter__(self) -> Iterator[T]:
        while True:
            item = self.get(self._idle_timeout)
            if item is None:
                return
            yield item

    def close(self) -> None:
        """Undeclare, release Zenoh if it waits on a full channel, close an owned session."""
        if self._closed.is_set():
            return
        self._closed.set()
        # a Zenoh thread waiting on the full channel holds the subscriber's lock, which
        # undeclaring needs: empty the channel until the undeclaring is through
        undeclaring = threading.Thread(target=self._undeclare, name="gx3-undeclare")
        undeclaring.start()
        while undeclaring.is_alive():
            while self._drain(1 << 16):
                pass
            undeclaring.join(_IDLE_S)
        # what Zenoh still delivers (a recovery under way) finds the channel gone
        self._try_recv = _nothing
        if self._session is not None:
            self._session.close()

    def _undeclare(self) -> None:
        self._listener.undeclare()
        self._sub.undeclare()
        if self._routes is not None:
            self._routes.close()

    def __enter__(self) -> Subscription[T]:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


def _nothing() -> None:
    return None


def _samples(got: dict[str, Arrivals]) -> list[ImuSample]:
    return [parse(p) for group in got.values() for p in group.payloads]


def _batches(got: dict[str, Arrivals]) -> list[SampleBatch]:
    groups: dict[tuple[str, int], list[bytes]] = {}
    for group in got.values():
        for payload in group.payloads:
            groups.setdefault(peek(payload), []).append(payload)
    return [SampleBatch(unit, code, decode_batch(unit, code, payloads))
            for (unit, code), payloads in groups.items()]


def _raw(got: dict[str, Arrivals]) -> list[RawMessage]:
    return [RawMessage(key, payload, str(s.encoding)) for key, group in got.items()
            for payload, s in zip(group.payloads, group.samples, strict=True)]


class SubscribeOptions(TypedDict, total=False):
    """The keyword arguments of ``subscribe`` besides ``output``."""

    session: zenoh.Session | None
    zenoh_config: str | Path | None
    connect: Sequence[str]
    listen: Sequence[str]
    mode: str | None
    multicast_scouting: bool | None
    history: int
    on_miss: Callable[[str, int], None] | None
    on_reject: RejectHandler | None
    on_conflict: Callable[[str, list[str]], None] | None
    idle_timeout: float | None
    max_batch: int
    queue_size: int


@overload
def subscribe(key: str = ..., *, output: Literal["samples"] = ...,
              **options: Unpack[SubscribeOptions]) -> Subscription[ImuSample]: ...
@overload
def subscribe(key: str = ..., *, output: Literal["batches"],
              **options: Unpack[SubscribeOptions]) -> Subscription[SampleBatch]: ...
@overload
def subscribe(key: str = ..., *, output: Literal["raw"],
              **options: Unpack[SubscribeOptions]) -> Subscription[RawMessage]: ...
def subscribe(key: str = fleet("imu", PREFIX), *, output: str = "samples",
              session: zenoh.Session | None = None, zenoh_config: str | Path | None = None,
              connect: Sequence[str] = (), listen: Sequence[str] = (), mode: str | None = None,
              multicast_scouting: bool | None = None, history: int = 0,
              on_miss: Callable[[str, int], None] | None = None,
              on_reject: RejectHandler | None = None,
              on_conflict: Callable[[str, list[str]], None] | None = None,
              idle_timeout: float | None = None, max_batch: int = 1000,
              queue_size: int = 100_000) -> Subscription[Any]:
    """Subscribe to a key expression: samples, NumPy batches or raw messages.

    Items of one key come in the order they were published.

    Args:
        key: The key expression; default every unit's samples, ``gx3/*/imu``.
        output: "samples" yields gx3.v1.ImuSample messages, "batches" a SampleBatch per
            unit and record type of what arrived together, "raw" a RawMessage (key,
            payload bytes, encoding) for any key.
        session: A session to use; None: the subscription opens (and closes) its own
            from ``zenoh_config`` and the flags below.
        zenoh_config: A JSON5 Zenoh configuration file.
        connect: Endpoints to connect to, over the file's.
        listen: Endpoints to listen on, over the file's.
        mode: "peer", "client" or "router", over the file's.
        multicast_scouting: Turn multicast scouting on or off, over the file's.
        history: Past samples to ask each publisher's cache for.
        on_miss: ``on_miss(source, n)`` hears of samples that could not be recovered
            (``source``: the key they were published on, where known; ``misses`` keeps
            the total), called by Zenoh's thread before the first sample after them is
            delivered.
        on_reject: ``on_reject(key, reason, n)`` hears of messages that failed their
            checks ("checksum" or "key"; ``rejected`` keeps the total).
        on_conflict: ``on_conflict(key, sessions)`` hears of two sessions publishing on
            one key (two bridges under one name).
        idle_timeout: Seconds of silence that end iteration; None: never.
        max_batch: Most messages taken out of Zenoh's channel at once.
        queue_size: The channel's capacity, in samples.

    Returns:
        The subscription, a context-managed iterator.

    Raises:
        ValueError: An unknown ``output`` or an invalid key expression.
        SessionError: The subscription's own session could not be opened.
    """
    converters: dict[str, Callable[[dict[str, Arrivals]], list[Any]]] = {
        "samples": _samples, "batches": _batches, "raw": _raw}
    if output not in converters:
        raise ValueError(f"output {output!r}: use one of {', '.join(converters)}")
    try:
        zenoh.KeyExpr(key)
    except zenoh.ZError as exc:
        raise ValueError(f"key expression {key!r}: {condense(exc)}") from None
    own = session is None
    if session is None:
        session = ZenohOptions(zenoh_config, connect, listen, mode, multicast_scouting).open()
    return Subscription(session, key, converters[output], own_session=own, history=history,
                        max_batch=max_batch, queue_size=queue_size, idle_timeout=idle_timeout,
                        on_miss=on_miss, on_reject=on_reject, on_conflict=on_conflict)
