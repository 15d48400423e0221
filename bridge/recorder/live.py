"""`gx3 record`'s engine: every unit on Zenoh into one archive, as they come and go.

Subscriptions to the fleet's samples, status and events (and raw reads, when asked)
buffer what arrives in Zenoh's own channels; the thread calling ``run_once`` takes it
out in bulk a few times a second and hands the ``ArchiveWriter`` each key's messages
in one call (each key's in the order they came), so receiving costs little per
message; the file is flushed at least once a second.
Units are discovered by their bridges' liveliness tokens: a unit that appears gets
its Info queried and archived; one that leaves and comes back simply continues.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zenoh

from bridge.bus.gx3_pb2 import Status
from bridge.bus.keys import ENCODINGS, read_time, unit_of
from bridge.bus.subscribe import RawMessage, Subscription, subscribe
from bridge.recorder.archive import ArchiveError, ArchiveWriter
from bridge.timing.rate import RateWindow

LEAVES = ("imu", "status", "event")
_QUERY_TIMEOUT_S = 3.0
_INFO_TRIES = 10
_INFO_RETRY_S = 0.5
_PASS_S = 0.05  # a pass takes ~5,000 messages at 100,000/s: whole batches per key


def _read_times(samples: list[zenoh.Sample], default_ns: int) -> np.ndarray:
    """The receive times the bridges attached to raw reads (``default_ns`` where none is)."""
    stamps = [read_time(None if s.attachment is None else s.attachment.to_bytes())
              for s in samples]
    return np.array([default_ns if t is None else t for t in stamps], np.int64)


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
    """Record ``<prefix>/<units>/{imu,status,event}`` (and ``raw``) into ``writer``.

    ``queue_size``: messages each subscription holds while the writer is busy; beyond
    that Zenoh waits (and, with BLOCK congestion control, so do the publishers).
    """

    def __init__(self, session: zenoh.Session, writer: ArchiveWriter, prefix: str = "gx3",
                 units: str = "*", raw: bool = False, history: int = 0,
                 on_unit: Callable[[str, bool], None] | None = None,
                 on_written: Callable[[list[RawMessage]], None] | None = None,
                 queue_size: int = 100_000) -> None:
        self.session, self.writer, self.prefix, self.units = session, writer, prefix, units
        self.views: dict[str, UnitView] = {}
        self.error: ArchiveError | None = None
        self.written = 0
        self._on_unit = on_unit
        self._on_written = on_written  # e.g. the Rerun logger of --rrd, fed in batches
        self._queue_size = queue_size
        self._answers: deque[RawMessage] = deque()  # Info replies, from the query threads
        self._stop = threading.Event()
        self._lock = threading.Lock()
        leaves = (*LEAVES, "raw") if raw else LEAVES
        self._subs: list[Subscription[RawMessage]] = []
        self._reads: Subscription[RawMessage] | None = None  # raw reads, stamped by bridges
        try:
            for leaf in leaves:
                sub = subscribe(f"{prefix}/{units}/{leaf}", output="raw", session=session,
                                history=history if leaf == "imu" else 0,
                                queue_size=queue_size)
                self._subs.append(sub)
                if leaf == "raw":
                    self._reads = sub
            self._alive = session.liveliness().declare_subscriber(
                f"{prefix}/{units}/alive", self._on_alive, history=True)
        except BaseException:
            for sub in self._subs:
                sub.close()
            raise

    @property
    def misses(self) -> int:
        return sum(sub.misses for sub in self._subs)

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
                self._answers.append(RawMessage(str(sample.key_expr), sample.payload.to_bytes(),
                                                str(sample.encoding)))
            if answers:
                return
            self._stop.wait(_INFO_RETRY_S)

    def run_once(self, wait_s: float = 0.2) -> None:
        """Write what arrives during ``wait_s``, taken in bulk every ``_PASS_S`` (or at
        least once); flush when a second has passed."""
        deadline = time.monotonic() + wait_s
        while True:
            self._pass()
            left = deadline - time.monotonic()
            if left <= 0:
                break
            time.sleep(min(_PASS_S, left))
        try:
            self.writer.tick()
        except ArchiveError as exc:
            self.error = exc

    def _pass(self) -> None:
        """Everything that has arrived into the archive, one write per key."""
        now = time.time_ns()
        written: list[RawMessage] | None = None if self._on_written is None else []
        for sub in self._subs:
            for key, samples in sub.take_by_key(self._queue_size).items():
                payloads = [s.payload.to_bytes() for s in samples]
                # a raw read's log time is when its bridge received it
                received = _read_times(samples, now) if sub is self._reads else now
                self._write(key, payloads, received, written)
        while self._answers:
            msg = self._answers.popleft()
            self._write(msg.key, [msg.payload], now, written)
        if written and self._on_written is not None:
            self._on_written(written)

    def _write(self, key: str, payloads: list[bytes], received: int | np.ndarray,
               written: list[RawMessage] | None) -> None:
        """Archive messages of one key, received at ``received`` (host ns: one for all, or
        one each), and count them in their unit's view."""
        if self.error is not None:
            return
        try:
            self.writer.write_many(key, payloads, received)
        except ArchiveError as exc:
            self.error = exc
            return
        except ValueError:  # not all of ours (nothing written): archive those that are
            payloads = self._each(key, payloads, received)
            if not payloads:
                return
        self.written += len(payloads)
        unit, leaf = self.writer.route(key)  # written: the key is one of ours
        status = None
        if leaf == "status":
            status = Status()
            status.ParseFromString(payloads[-1])
        with self._lock:
            view = self.views.get(unit)
            if view is None:
                view = self.views[unit] = UnitView(unit)
            view.bytes += sum(map(len, payloads))
            if leaf == "imu":
                now = int(np.max(received))
                view.samples += len(payloads)
                view.last_ns = now
                view.first_ns = view.first_ns or now
            elif status is not None:
                view.status = status
        if written is not None:
            encoding = ENCODINGS.get(leaf, "")
            written.extend(RawMessage(key, payload, encoding) for payload in payloads)

    def _each(self, key: str, payloads: list[bytes], received: int | np.ndarray
              ) -> list[bytes]:
        """The payloads that ``write`` takes one by one (a message on a matching key that
        is not one of ours is not archived)."""
        kept = []
        stamps = np.broadcast_to(np.asarray(received, np.int64), (len(payloads),)).tolist()
        for payload, stamp in zip(payloads, stamps, strict=True):
            try:
                self.writer.write(key, payload, stamp)
            except ValueError:
                continue
            except ArchiveError as exc:
                self.error = exc
                break
            kept.append(payload)
        return kept

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
        """Stop receiving, write what has arrived, and leave the writer to its owner."""
        self._alive.undeclare()
        self._stop.set()
        self._pass()
        for sub in self._subs:
            sub.close()
