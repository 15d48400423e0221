"""What feeds the Rerun logger: a finished (or cut-short) archive, or the live fleet.

``log_archive`` renders an MCAP archive with the same layout a live view has;
``LiveFeed`` subscribes to units' samples, status and events on Zenoh and logs them
as they arrive; ``RrdWriter`` writes what a recording archives into a Rerun file as it
is archived (``gx3 record --rrd``). Each hands the logger whole columns, never one call
per sample.
"""

from __future__ import annotations

import contextlib
import threading
from collections import defaultdict
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Generic, TypeVar

import numpy as np
import zenoh
from google.protobuf.message import DecodeError

from bridge.archive.reader import ArchiveReader
from bridge.archive.walk import read_samples_archive
from bridge.bus.codec import decode_batch, peek
from bridge.bus.gx3_pb2 import Event, Status
from bridge.bus.keys import unit_of
from bridge.bus.subscribe import RawMessage, Subscription, subscribe
from bridge.device import clock
from bridge.exceptions import OutputRefused
from bridge.viz.logger import RerunLogger

M = TypeVar("M", Status, Event)


#: Bins a thinned ``RrdWriter`` gathers before it writes them (about 2 minutes at 1 Hz):
#: each send makes a chunk of Rerun's, whose overhead a few rows would not repay.
TEE_BINS = 128
#: Statuses or events of a unit gathered before they are logged together: a day's are a
#: few hundred thousand, one send each chunk of an archive would make a tiny Rerun chunk.
_GATHER = 4096


def log_archive(path: Path, logger: RerunLogger, *, units: Sequence[str] | None = None,
                start_ns: int | None = None, end_ns: int | None = None,
                progress: Callable[[int], None] | None = None,
                on_problem: Callable[[str], None] | None = None) -> int:
    """Log an archive, or a window of some of its units: samples, status and events.

    The archive is read a chunk at a time, and only the chunks that can hold the window
    (``bridge.archive.walk.read_archive``), so memory stays that of a chunk and of what
    the logger holds, however long the archive. An archive cut short is logged up to its
    last complete chunk; a corrupt chunk or a message that is not what its topic says is
    left out, and said once.

    Args:
        path: The archive.
        logger: Where to log them; it is flushed at the end.
        units: Only these units; None: every unit.
        start_ns: Only what was logged at or after this instant (host ns); None: from the
            start.
        end_ns: Only what was logged before this instant; None: to the end.
        progress: Hears how many samples each batch logged.
        on_problem: Hears, once, what is wrong with an archive cut short or damaged.

    Returns:
        The samples logged.

    Raises:
        ArchiveReadError: The file is missing, empty, unreadable or not MCAP at all.
    """
    feed = _ArchiveFeed(logger, units, start_ns, end_ns, progress)
    read_samples_archive(path, on_problem=on_problem, on_blocks=feed.take,
                         between=(start_ns, end_ns))
    return feed.close()


class _Held(Generic[M]):
    """Messages of each unit held to be logged together, ``_GATHER`` at a time.

    Args:
        log: Logs a unit's messages.
    """

    def __init__(self, log: Callable[[str, list[M]], None]) -> None:
        self.log: Callable[[str, list[M]], None] = log
        self.items: dict[str, list[M]] = defaultdict(list)

    def add(self, unit: str, items: list[M]) -> None:
        """Hold a unit's messages; log them once ``_GATHER`` are held."""
        self.items[unit].extend(items)
        if len(self.items[unit]) >= _GATHER:
            self.log(unit, self.items.pop(unit))

    def flush(self) -> None:
        """Log every message held."""
        for unit in list(self.items):
            if items := self.items.pop(unit):
                self.log(unit, items)


class _ArchiveFeed:
    """An archive's chunks, as they are read, into a logger: the messages of a window."""

    def __init__(self, logger: RerunLogger, units: Sequence[str] | None, start_ns: int | None,
                 end_ns: int | None, progress: Callable[[int], None] | None) -> None:
        self.logger, self.progress = logger, progress
        self.units = None if units is None else sorted(units)
        self.lo = -(1 << 63) if start_ns is None else start_ns
        self.hi = (1 << 63) - 1 if end_ns is None else end_ns
        self.logged = 0
        self.statuses: _Held[Status] = _Held(logger.log_status)
        self.events: _Held[Event] = _Held(logger.log_event)

    def take(self, archive: ArchiveReader) -> None:
        """Log what a chunk (or a whole archive) holds of the window."""
        for block in archive.samples(self.units):
            time_ns = block.columns["time_ns"]
            inside = (time_ns >= self.lo) & (time_ns < self.hi)
            if not inside.any():
                continue
            columns = block.columns if inside.all() else {
                name: column[inside] for name, column in block.columns.items()}
            self.logger.log_samples(block.unit, block.code, columns)
            # blocks are in sample-time order; samples nothing received live (an
            # import's, rx_ns 0) have no arrival, and plotting their log time would show a
            # host clock in perfect agreement
            receive_ns = block.receive_ns[inside]
            came = np.argsort(receive_ns, kind="stable")
            came = came[columns["rx_ns"][came] != 0]
            self.logger.log_arrivals(block.unit, receive_ns[came], columns["time_ns"][came])
            self.logged += len(receive_ns)
            if self.progress is not None:
                self.progress(len(receive_ns))
        wanted = None if self.units is None else set(self.units)
        statuses = {c.topic: c.unit for c in archive.channels.values() if c.kind == "status"
                    and (wanted is None or c.unit in wanted)}
        for topic, unit in statuses.items():
            self.statuses.add(unit, [s for t, s in archive.decoded(topic, Status)
                                     if self.lo <= t < self.hi])
        for unit, event in archive.events(self.units):
            if self.lo <= event.time_ns < self.hi:
                self.events.add(unit, [event])

    def close(self) -> int:
        """Log what is held and flush the logger; the samples logged."""
        self.statuses.flush()
        self.events.flush()
        self.logger.flush()
        return self.logged


def log_messages(logger: RerunLogger, messages: list[RawMessage], prefix: str,
                 arrival_ns: int | None = None) -> int:
    """Log Zenoh messages as they came, any mix of units and kinds.

    Samples are decoded in bulk per unit and record type; a message that does not parse
    is left out.

    Args:
        logger: Where to log them.
        messages: The messages (samples, status and events).
        prefix: The key prefix they came under.
        arrival_ns: When they reached this process, which the bridge hosts' clocks are
            judged against (``RerunLogger.log_arrivals``); None: not judged.

    Returns:
        The samples logged.
    """
    samples: dict[tuple[str, int], list[bytes]] = defaultdict(list)
    logged = 0
    for msg in messages:
        unit = unit_of(msg.key, prefix)
        leaf = msg.key.rsplit("/", 1)[-1]
        if leaf == "imu":
            try:
                samples[(unit, peek(msg.payload)[1])].append(msg.payload)
            except ValueError:
                continue
        elif leaf in ("status", "event"):  # one that does not parse is left out
            with contextlib.suppress(DecodeError):
                if leaf == "status":
                    logger.log_status(unit, Status.FromString(msg.payload))
                else:
                    logger.log_event(unit, Event.FromString(msg.payload))
    for (unit, code), payloads in samples.items():
        try:
            columns = decode_batch(unit, code, payloads)
        except ValueError:
            continue
        logger.log_samples(unit, code, columns)
        if arrival_ns is not None:
            logger.log_arrivals(unit, np.full(len(payloads), arrival_ns), columns["time_ns"])
        logged += len(payloads)
    return logged


class RrdWriter:
    """What a recording archives, written into a Rerun recording file as it is archived.

    What ``bridge.recorder.Recording`` opens for its ``rrd`` (``gx3 record --rrd``): it
    hears each batch written (``log``) and is closed after the recorder. Long
    recordings get bigger chunks, and no index of every chunk held in memory; one that
    runs for days, ``max_rate_hz`` (``RerunLogger``'s thinning).

    Args:
        path: The file to write.
        recording_id: Rerun's id of the recording (the archive's name, say).
        prefix: The key prefix of the messages.
        max_rate_hz: Thin the samples to this many bins a second; None: every sample.

    Raises:
        OutputRefused: Rerun cannot create the file.
        ValueError: ``max_rate_hz`` is not above 0.
    """

    def __init__(self, path: Path, recording_id: str, prefix: str = "gx3",
                 max_rate_hz: float | None = None) -> None:
        self.prefix = prefix
        # thinned: a line's rows written TEE_BINS bins at a time, not two every 2 s
        latency_s = 2.0 if max_rate_hz is None else max(2.0, TEE_BINS / max_rate_hz)
        try:
            self.logger = RerunLogger(path, recording_id=recording_id, latency_s=latency_s,
                                      write_footer=False, max_rate_hz=max_rate_hz)
        except (OSError, RuntimeError) as exc:  # Rerun says RuntimeError
            why = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
            raise OutputRefused(f"--rrd {path}: cannot write ({why})") from None

    def log(self, messages: list[RawMessage]) -> None:
        """Log a batch of messages as written (``log_messages``).

        Args:
            messages: The batch.
        """
        log_messages(self.logger, messages, self.prefix)

    def close(self) -> None:
        """Finish the file."""
        self.logger.close()


class LiveFeed:
    """The fleet's samples, status and events on Zenoh, into a logger until ``close``.

    Args:
        session: The Zenoh session to subscribe on.
        logger: Where to log them.
        prefix: The key prefix of the bridges.
        units: Which units, as a key expression chunk (``*``, ``lab-*``).
    """

    def __init__(self, session: zenoh.Session, logger: RerunLogger, prefix: str = "gx3",
                 units: str = "*") -> None:
        self.logger, self.prefix = logger, prefix
        self.samples = 0
        self._stop = threading.Event()
        self._subs: list[Subscription[RawMessage]] = []
        try:
            for leaf in ("imu", "status", "event"):
                self._subs.append(subscribe(f"{prefix}/{units}/{leaf}", output="raw",
                                            session=session, max_batch=4096))
        except BaseException:
            self.close()
            raise
        self._threads = [threading.Thread(target=self._pump, args=(sub,), name="gx3-view")
                         for sub in self._subs]
        for thread in self._threads:
            thread.start()

    def _pump(self, sub: Subscription[RawMessage]) -> None:
        while not self._stop.is_set():
            first = sub.get(timeout=0.2)
            if first is None:
                self.logger.flush()
                continue
            arrival = clock.realtime_ns()
            batch = [first]
            while (more := sub.get(timeout=0)) is not None and len(batch) < 4096:
                batch.append(more)
            self.samples += log_messages(self.logger, batch, self.prefix, arrival)

    def close(self) -> None:
        """Stop: unsubscribe and wait for the logging threads."""
        self._stop.set()
        for sub in self._subs:
            sub.close()
        for thread in getattr(self, "_threads", []):
            thread.join()
