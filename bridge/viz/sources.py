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
from collections.abc import Callable
from pathlib import Path

import numpy as np
import zenoh
from google.protobuf.message import DecodeError

from bridge.archive.reader import ArchiveReader
from bridge.bus.codec import decode_batch, peek
from bridge.bus.gx3_pb2 import Event, Status
from bridge.bus.keys import unit_of
from bridge.bus.subscribe import RawMessage, Subscription, subscribe
from bridge.device import clock
from bridge.exceptions import OutputRefused
from bridge.viz.logger import RerunLogger


def log_archive(archive: ArchiveReader, logger: RerunLogger,
                progress: Callable[[int], None] | None = None) -> int:
    """Log an archive: every unit's samples, status and events.

    Args:
        archive: The archive read.
        logger: Where to log them; it is flushed at the end.
        progress: Hears how many samples each batch logged.

    Returns:
        The samples logged.
    """
    logged = 0
    for block in archive.samples():
        logger.log_samples(block.unit, block.code, block.columns)
        # blocks are in sample-time order; samples nothing received live (an import's,
        # rx_ns 0) have no arrival, and plotting their log time would show a host clock
        # in perfect agreement
        came = np.argsort(block.receive_ns, kind="stable")
        came = came[block.columns["rx_ns"][came] != 0]
        logger.log_arrivals(block.unit, block.receive_ns[came], block.columns["time_ns"][came])
        logged += len(block)
        if progress is not None:
            progress(len(block))
    for topic in archive.topics("status"):
        statuses = [status for _, status in archive.decoded(topic, Status)]
        if statuses:
            logger.log_status(archive.messages(topic).unit, statuses)
    by_unit: dict[str, list[Event]] = defaultdict(list)
    for unit, event in archive.events():
        by_unit[unit].append(event)
    for unit, events in by_unit.items():
        logger.log_event(unit, events)
    logger.flush()
    return logged


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
    recordings get bigger chunks, and no index of every chunk held in memory.

    Args:
        path: The file to write.
        recording_id: Rerun's id of the recording (the archive's name, say).
        prefix: The key prefix of the messages.

    Raises:
        OutputRefused: Rerun cannot create the file.
    """

    def __init__(self, path: Path, recording_id: str, prefix: str = "gx3") -> None:
        self.prefix = prefix
        try:
            self.logger = RerunLogger(path, recording_id=recording_id, latency_s=2.0,
                                      write_footer=False)
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
