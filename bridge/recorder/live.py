"""`gx3 record`'s engine: every unit on Zenoh into one archive, as they come and go.

Subscriptions to the fleet's samples, status and events (and raw reads, when asked)
feed one queue; one thread drains it into the ``ArchiveWriter``, so messages are
written in the order they arrived and the file is flushed at least once a second.
Units are discovered by their bridges' liveliness tokens: a unit that appears gets
its Info queried and archived; one that leaves and comes back simply continues.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import zenoh

from bridge.bus.gx3_pb2 import Status
from bridge.bus.keys import unit_of
from bridge.bus.subscribe import RawMessage, Subscription, subscribe
from bridge.recorder.archive import ArchiveError, ArchiveWriter
from bridge.timing.rate import RateWindow

LEAVES = ("imu", "status", "event")
_QUERY_TIMEOUT_S = 3.0
_INFO_TRIES = 10
_INFO_RETRY_S = 0.5


@dataclass
class UnitView:
    """What the terminal shows of one unit."""

    name: str
    alive: bool = True
    samples: int = 0
    bytes: int = 0
    first_ns: int = 0
    last_ns: int = 0
    status: Status | None = None
    joined: int = 1
    meter: RateWindow = field(default_factory=lambda: RateWindow(3.0))

    def rate(self, now: float) -> float:
        return self.meter.rate(now, self.samples)


class Recorder:
    """Record ``<prefix>/<units>/{imu,status,event}`` (and ``raw``) into ``writer``."""

    def __init__(self, session: zenoh.Session, writer: ArchiveWriter, prefix: str = "gx3",
                 units: str = "*", raw: bool = False, history: int = 0,
                 on_unit: Callable[[str, bool], None] | None = None,
                 on_written: Callable[[list[RawMessage]], None] | None = None) -> None:
        self.session, self.writer, self.prefix, self.units = session, writer, prefix, units
        self.views: dict[str, UnitView] = {}
        self.error: ArchiveError | None = None
        self.written = 0
        self._on_unit = on_unit
        self._on_written = on_written  # e.g. the Rerun logger of --rrd, fed in batches
        self._queue: queue.Queue[RawMessage] = queue.Queue(maxsize=200_000)
        self._stop = threading.Event()
        self._lock = threading.Lock()
        leaves = (*LEAVES, "raw") if raw else LEAVES
        self._subs: list[Subscription[RawMessage]] = []
        self._pumps: list[threading.Thread] = []
        try:
            for leaf in leaves:
                sub = subscribe(f"{prefix}/{units}/{leaf}", output="raw", session=session,
                                history=history if leaf == "imu" else 0)
                self._subs.append(sub)
            self._alive = session.liveliness().declare_subscriber(
                f"{prefix}/{units}/alive", self._on_alive, history=True)
        except BaseException:
            for sub in self._subs:
                sub.close()
            raise
        for sub in self._subs:
            pump = threading.Thread(target=self._pump, args=(sub,), daemon=False,
                                    name="gx3-record-pump")
            pump.start()
            self._pumps.append(pump)

    @property
    def misses(self) -> int:
        return sum(sub.misses for sub in self._subs)

    def _pump(self, sub: Subscription[RawMessage]) -> None:
        while not self._stop.is_set():
            msg = sub.get(timeout=0.2)
            if msg is not None:
                self._queue.put(msg)

    def _on_alive(self, sample: zenoh.Sample) -> None:
        unit = unit_of(str(sample.key_expr), self.prefix)
        joined = sample.kind == zenoh.SampleKind.PUT
        with self._lock:
            view = self.views.get(unit)
            if view is None:
                view = self.views[unit] = UnitView(unit)
            elif joined and not view.alive:
                view.joined += 1
            view.alive = joined
        if joined:
            threading.Thread(target=self._archive_info, args=(unit,), daemon=True).start()
        if self._on_unit is not None:
            self._on_unit(unit, joined)

    def _archive_info(self, unit: str) -> None:
        """A unit that appears gets its Info (identity and settings) into the archive; a
        bridge still bringing its unit up answers "no Info yet", so ask again."""
        for _ in range(_INFO_TRIES):
            if self._stop.is_set():
                return
            try:
                replies = self.session.get(f"{self.prefix}/{unit}/info",
                                           timeout=_QUERY_TIMEOUT_S)
                answers = [r.ok for r in replies if r.ok is not None]
            except zenoh.ZError:
                return
            for sample in answers:
                self._queue.put(RawMessage(str(sample.key_expr), sample.payload.to_bytes(),
                                           str(sample.encoding)))
            if answers:
                return
            self._stop.wait(_INFO_RETRY_S)

    def run_once(self, wait_s: float = 0.2) -> None:
        """Write what arrived (waiting up to ``wait_s``); flush when a second has passed."""
        deadline = time.monotonic() + wait_s
        written: list[RawMessage] = []
        while True:
            try:
                msg = self._queue.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                break
            if self._write(msg):
                written.append(msg)
            if time.monotonic() >= deadline:
                break
        if written and self._on_written is not None:
            self._on_written(written)
        try:
            self.writer.tick()
        except ArchiveError as exc:
            self.error = exc

    def _write(self, msg: RawMessage) -> bool:
        """Archive one message; False if it was not (an error, or not one of ours)."""
        if self.error is not None:
            return False
        now = time.time_ns()
        try:
            self.writer.write(msg.key, msg.payload, now)
        except ArchiveError as exc:
            self.error = exc
            return False
        except ValueError:
            return False  # not a message of ours on a matching key: not archived
        self.written += 1
        unit = unit_of(msg.key, self.prefix)
        leaf = msg.key.rsplit("/", 1)[-1]
        with self._lock:
            view = self.views.get(unit)
            if view is None:
                view = self.views[unit] = UnitView(unit)
            view.bytes += len(msg.payload)
            if leaf == "imu":
                view.samples += 1
                view.last_ns = now
                view.first_ns = view.first_ns or now
            elif leaf == "status":
                status = Status()
                status.ParseFromString(msg.payload)
                view.status = status
        return True

    def snapshot(self) -> list[dict[str, Any]]:
        """One row per unit for the terminal view."""
        now = time.monotonic()
        rows = []
        with self._lock:
            for view in sorted(self.views.values(), key=lambda v: v.name):
                s = view.status
                rows.append({
                    "unit": view.name, "alive": view.alive, "rate": view.rate(now),
                    "samples": view.samples, "dropped": s.dropped if s else 0,
                    "checksum_failures": s.checksum_failures if s else 0,
                    "resyncs": s.resyncs if s else 0, "reconnects": s.reconnects if s else 0,
                    "offset_ms": (s.clock_offset_ns / 1e6) if s else None,
                    "drift_ppm": s.clock_drift_ppm if s else None,
                    "recorded_s": (view.last_ns - view.first_ns) / 1e9,
                    "bytes": view.bytes, "joined": view.joined})
        return rows

    def close(self) -> None:
        """Stop receiving, write what is queued, and leave the writer to its owner."""
        self._alive.undeclare()
        for sub in self._subs:
            sub.close()
        self._stop.set()
        for pump in self._pumps:
            pump.join()
        written: list[RawMessage] = []
        while True:
            try:
                msg = self._queue.get_nowait()
            except queue.Empty:
                break
            if self._write(msg):
                written.append(msg)
        if written and self._on_written is not None:
            self._on_written(written)
