"""`gx3 record`'s engine: every unit on Zenoh into one archive, as they come and go.

A receiving thread takes what arrives off Zenoh as soon as it comes, checks it and
holds it in memory; the caller's thread hands it to the ``ArchiveWriter`` a few times
a second. So a slow disk never holds Zenoh's receive path, and through it the
publishers. Nothing is lost unrecorded: samples Zenoh missed, messages that fail their
checks and samples shed while the memory was full go into the archive as events of
their unit. Each bridge host's clock is judged against the recorder's by when its
samples arrive (``bridge.recorder.hosts``). How and why: ``docs/design/archive.md``; the
hosts' clocks: ``docs/design/time.md``.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import zenoh

from bridge._text import counted
from bridge.archive.writer import ArchiveWriter
from bridge.bus.codec import parse
from bridge.bus.gx3_pb2 import Event, Info, Status
from bridge.bus.integrity import read_raw_time, read_time
from bridge.bus.keys import ENCODINGS, unit_of
from bridge.bus.subscribe import Arrivals, RawMessage, Subscription, check, subscribe
from bridge.device import clock
from bridge.exceptions import ArchiveError
from bridge.recorder.hosts import (
    HOSTS_METADATA,
    ClockChecks,
    HostView,
    host_tolerance_ns,
    host_views,
    hosts_metadata,
)
from bridge.recorder.units import UnitRow, UnitView

LEAVES = ("imu", "status", "event")
_QUERY_TIMEOUT_S = 3.0
_INFO_TRIES = 10
_INFO_RETRY_S = 0.5
_PASS_S = 0.05  # a pass takes ~5,000 messages at 100,000/s: whole batches per key
#: How often the receiving thread empties Zenoh's channels while messages flow: no
#: message waits there longer, and a look that finds a message or two per key costs a
#: few microseconds (Zenoh's channels cannot wake a Python thread without its threads
#: taking the GIL for every sample, which a busy writer would make them wait for).
_PROMPT_S = 0.001
#: ... and once nothing has come for ``_QUIET_S``: an idle recorder barely wakes, and
#: the first message after the silence waits at most this long.
_RECEIVE_S = 0.025
_QUIET_S = 1.0
_TAKE = 10_000  # messages the receiving thread takes off one channel at a time
#: Memory the recorder holds for a stalled writer: ~15 s of 100 units at 1 kHz.
BUFFER_BYTES = 256 << 20
_OVERHEAD = 64  # bytes a held message costs besides its payload (object, list slots)
_SHEDDABLE = ("imu", "raw")  # status, events and info are few and always kept
_REASONS = {"checksum": "payload does not match its CRC-32 (damaged in transit)",
            "key": "names another unit than its key, or is not a message of the key's type"}


@dataclass
class _Span:
    """Messages of one key not archived for one reason: how many, and their span."""

    count: int = 0
    first_ns: int = 0
    last_ns: int = 0
    first_ticks: int = 0
    last_ticks: int = 0

    def add(self, n: int, first_ns: int, last_ns: int, first_ticks: int = 0,
            last_ticks: int = 0) -> None:
        if not self.count:
            self.first_ns, self.first_ticks = first_ns, first_ticks
        self.count += n
        self.last_ns, self.last_ticks = last_ns, last_ticks


@dataclass
class _Loss:
    """Samples Zenoh reported missed on one key, between two that arrived."""

    key: str
    count: int
    missed_ns: int
    before: bytes | None  # the last message of the key that arrived before them


def _instant(leaf: str, payload: bytes | None, default_ns: int) -> tuple[int, int]:
    """(time_ns, ticks) of a message: an imu sample's own, else (default_ns, 0)."""
    if leaf != "imu" or payload is None:
        return default_ns, 0
    try:
        sample = parse(payload)
    except ValueError:
        return default_ns, 0
    return sample.time_ns, sample.ticks


class Recorder:
    """Record ``<prefix>/<units>/{imu,status,event}`` (and ``raw``) into an archive.

    Receiving starts at once, on a thread of its own; call ``run_once`` in a loop to
    write what arrives, and ``close`` at the end. A unit that appears (its bridge's
    liveliness token) gets its Info queried and archived; one that leaves and comes back
    simply continues. What was not archived is archived as events of its unit: samples
    Zenoh reports missed (LOST), messages that fail their checks (REJECTED), samples
    shed while the buffer was full (SHED), and a unit name published by two bridges at
    once (DUPLICATE_UNIT). A bridge host whose clock is provably ahead of the
    recorder's, or (with a tolerance) may be behind by more than it, gets a
    HOST_CLOCK_OFFSET event for each of its units, once when it starts and again only
    once it has cleared; ``close`` writes each host's bound over the whole recording
    (``gx3.hosts``).

    Args:
        session: The Zenoh session to subscribe on.
        writer: The archive; the recorder writes into it, its owner closes it.
        prefix: The key prefix of the bridges.
        units: Which units, as a key expression chunk (``*``, ``lab-*``).
        raw: Also record the units' raw reads (bridges run with --publish-raw).
        history: Samples to ask each bridge's cache for at the start.
        on_unit: Hears ``(unit, joined)`` as units appear and leave.
        on_written: Hears each batch of messages written (a Rerun logger, say).
        queue_size: Messages each Zenoh channel holds until the receiving thread takes
            them.
        buffer_bytes: Memory held for a writer that falls behind; once it is full, imu
            and raw samples are shed until the writer takes what is held.
        on_event: Hears ``(unit, event)`` of each event the recorder itself archives.
        max_host_offset_ms: How far behind the recorder's clock a bridge host's may be
            (strictly, how late its samples may arrive) before a HOST_CLOCK_OFFSET event
            says so; None: no such check (a host ahead of the recorder is always told).
        on_latency: Hears ``(unit, seconds)``: for the messages of a unit its bridge
            stamped with their publish time (one put in 16), how long from then until
            they were handed to the archive's writer (two hosts' clocks); None: not
            measured.

    Raises:
        ValueError: ``max_host_offset_ms`` is not above 0.
    """

    def __init__(self, session: zenoh.Session, writer: ArchiveWriter, prefix: str = "gx3",
                 units: str = "*", raw: bool = False, history: int = 0,
                 on_unit: Callable[[str, bool], None] | None = None,
                 on_written: Callable[[list[RawMessage]], None] | None = None,
                 queue_size: int = 100_000, buffer_bytes: int = BUFFER_BYTES,
                 on_event: Callable[[str, Event], None] | None = None,
                 max_host_offset_ms: float | None = None,
                 on_latency: Callable[[str, list[float]], None] | None = None) -> None:
        self.max_host_offset_ns = host_tolerance_ns(max_host_offset_ms)
        self._on_latency = on_latency
        self._clock_checks = ClockChecks(self.max_host_offset_ns)
        self.session, self.writer, self.prefix, self.units = session, writer, prefix, units
        self.views: dict[str, UnitView] = {}
        self.error: ArchiveError | None = None
        self.written = 0
        self.buffer_bytes = buffer_bytes
        #: messages not archived, by the event kind that accounts for them
        self.losses = {Event.LOST: 0, Event.REJECTED: 0, Event.SHED: 0}
        self._on_unit = on_unit
        self._on_written = on_written  # e.g. the Rerun logger of --rrd, fed in batches
        self._on_event = on_event
        self._answers: deque[zenoh.Sample] = deque()  # Info replies, from the query threads
        self._stop = threading.Event()
        self._lock = threading.Lock()  # the views
        # what the receiving thread holds for the writer, guarded by _held_lock
        self._held_lock = threading.RLock()  # a reject is reported while it is held
        # by key: payloads, receive times, a raw read's raw-clock stamps (its publish
        # time in the archive; an older bridge's reads have none: their receive time),
        # and the publish times the bridge stamped some of them with
        self._held: dict[str, tuple[list[bytes], list[int], list[int], list[int]]] = {}
        self._held_bytes = 0
        self._shedding = False
        self._last: dict[str, bytes] = {}  # the last message of each key that arrived
        self._open_losses: dict[str, list[_Loss]] = {}
        self._losses: list[tuple[_Loss, bytes | None]] = []  # with the message after them
        self._rejects: dict[tuple[str, str], _Span] = {}
        self._shed: dict[str, _Span] = {}
        self._notes: list[tuple[str, Event]] = []
        self._conflicts: set[tuple[str, tuple[str, ...]]] = set()
        leaves = (*LEAVES, "raw") if raw else LEAVES
        self._subs: list[Subscription[RawMessage]] = []
        try:
            for leaf in leaves:
                sub = subscribe(f"{prefix}/{units}/{leaf}", output="raw", session=session,
                                history=history if leaf == "imu" else 0,
                                queue_size=queue_size, on_reject=self._rejected,
                                on_miss=self._missed_on(len(self._subs)),
                                on_conflict=self._conflict if leaf == "imu" else None)
                self._subs.append(sub)
            self._alive = session.liveliness().declare_subscriber(
                f"{prefix}/{units}/alive", self._on_alive, history=True)
        except BaseException:
            for sub in self._subs:
                sub.close()
            raise
        self._receiver = threading.Thread(target=self._receive, name="gx3-receive")
        self._receiver.start()

    @property
    def misses(self) -> int:
        """Samples Zenoh reported missed so far, on every subscription."""
        return sum(sub.misses for sub in self._subs)

    @property
    def received(self) -> int:
        """Messages taken off Zenoh so far (checked or not, held or shed)."""
        return sum(sub.received for sub in self._subs)

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
        """Get the Info (identity and settings) of a unit that appears into the archive.

        A bridge still bringing its unit up answers "no Info yet", so ask again.
        """
        for _ in range(_INFO_TRIES):
            if self._stop.is_set():
                return
            try:
                replies = self.session.get(f"{self.prefix}/{unit}/info",
                                           timeout=_QUERY_TIMEOUT_S)
                answers = [r.ok for r in replies if r.ok is not None]
            except zenoh.ZError:
                return
            self._answers.extend(answers)
            if answers:
                return
            self._stop.wait(_INFO_RETRY_S)

    # -- the receiving thread and Zenoh's callbacks ---------------------------------------

    def _receive(self) -> None:
        """Take what arrives off Zenoh's channels into memory until close."""
        heard = -_QUIET_S
        while not self._stop.is_set():
            started = time.monotonic()
            full = taken = False
            for sub in self._subs:
                with self._held_lock:
                    n = self._hold(sub.take_by_key(_TAKE))
                full |= n >= _TAKE
                taken |= n > 0
            if taken:
                heard = started
            if not full:  # else more is waiting: go on at once
                period = _PROMPT_S if started - heard < _QUIET_S else _RECEIVE_S
                self._stop.wait(period - (time.monotonic() - started))

    def _hold(self, groups: dict[str, Arrivals]) -> int:
        """Keep checked messages for the writer (caller holds ``_held_lock``).

        Shed imu and raw ones while the held memory is over its cap.
        """
        now = clock.realtime_ns()
        n = 0
        for key, got in groups.items():
            leaf = key.rpartition("/")[2]
            payloads = got.payloads
            n += len(payloads)
            for loss in self._open_losses.pop(key, []):
                self._losses.append((loss, payloads[0]))
            self._last[key] = payloads[-1]
            size = sum(map(len, payloads)) + _OVERHEAD * len(payloads)
            if leaf in _SHEDDABLE and (self._shedding or
                                       self._held_bytes + size > self.buffer_bytes):
                # until the writer takes what is held: each key's shed samples are one run
                self._shedding = True
                first_ns, first_ticks = _instant(leaf, payloads[0], now)
                last_ns, last_ticks = _instant(leaf, payloads[-1], now)
                self._shed.setdefault(key, _Span()).add(len(payloads), first_ns, last_ns,
                                                        first_ticks, last_ticks)
                continue
            self._held_bytes += size
            held, received, published, stamps = self._held.setdefault(key, ([], [], [], []))
            held += payloads
            if leaf == "raw":  # a raw read's time is when its bridge received it
                reals = [now if t is None else t for t in map(read_time, got.attachments)]
                received += reals
                published += [real if raw is None else raw for raw, real
                              in zip(map(read_raw_time, got.attachments), reals, strict=True)]
            else:
                received += [now] * len(payloads)
                if self._on_latency is not None:  # one put in 16 carries its instant
                    stamps += [t for a in got.attachments
                               if a is not None and len(a) > 4 and (t := read_time(a))]
        return n

    def _missed_on(self, index: int) -> Callable[[str, int], None]:
        def missed(key: str, count: int) -> None:
            """Note a loss: Zenoh's thread, before it delivers the first sample after it.

            What came before it is taken first, so the loss has its place among them.
            """
            with self._held_lock:
                self._hold(self._subs[index].take_by_key(1 << 30))
                loss = _Loss(key, count, clock.realtime_ns(), self._last.get(key))
                self._open_losses.setdefault(key, []).append(loss)
        return missed

    def _rejected(self, key: str, reason: str, count: int) -> None:
        now = clock.realtime_ns()
        with self._held_lock:
            self._rejects.setdefault((key, reason), _Span()).add(count, now, now)

    def _conflict(self, key: str, sessions: list[str]) -> None:
        if (key, tuple(sessions)) in self._conflicts:
            return
        self._conflicts.add((key, tuple(sessions)))
        unit = self._unit(key)
        now = clock.realtime_ns()
        note = Event(unit=unit, time_ns=now, kind=Event.DUPLICATE_UNIT, count=len(sessions),
                     detail=f"{key} is published by {len(sessions)} sessions at once "
                            f"({', '.join(sessions)}): two bridges run under the name "
                            f"{unit!r}, and its samples mix two sources")
        with self._held_lock:
            self._notes.append((unit, note))

    def _unit(self, key: str) -> str:
        try:
            return unit_of(key, self.prefix)
        except ValueError:  # a loss whose publisher was never seen: no key to name
            return "unknown"

    # -- the writer's side --------------------------------------------------------------

    def run_once(self, wait_s: float = 0.2) -> None:
        """Write what arrives during ``wait_s``; flush when a second has passed.

        What arrived is taken in bulk every ``_PASS_S`` (or at least once). A write that
        fails stops the archiving: ``error`` says why.

        Args:
            wait_s: How long to run, in seconds.
        """
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
        """Write everything held into the archive, one write per key.

        Then the events that account for what was not archived.
        """
        now = clock.realtime_ns()
        with self._held_lock:
            held, self._held, self._held_bytes = self._held, {}, 0
            self._shedding = False
            notes, self._notes = self._notes, []
            losses, self._losses = self._losses, []
            rejects, self._rejects = self._rejects, {}
            shed, self._shed = self._shed, {}
        answers = check([self._answers.popleft() for _ in range(len(self._answers))],
                        self._rejected)
        written: list[RawMessage] | None = None if self._on_written is None else []
        for key, (payloads, received, published, stamps) in held.items():
            self._write(key, payloads, np.array(received, np.int64), written,
                        np.array(published, np.int64) if published else None)
            if stamps and self._on_latency is not None and self.error is None:
                archived = clock.realtime_ns()
                self._on_latency(self._unit(key), [(archived - t) / 1e9 for t in stamps])
        for key, got in answers.items():
            self._write(key, got.payloads, now, written)
        notes += self._clock_checks.events(self.hosts(now), now)
        notes += [self._lost(loss, after, now) for loss, after in losses]
        notes += [self._unarchived(key, Event.REJECTED, span,
                                   f"{span.count} message(s) rejected: {_REASONS[reason]}")
                  for (key, reason), span in rejects.items()]
        notes += [self._unarchived(key, Event.SHED, span,
                                   f"{span.count} message(s) shed: the recorder's buffer "
                                   f"({self.buffer_bytes >> 20} MiB) was full while the "
                                   "archive could not be written fast enough")
                  for key, span in shed.items()]
        for unit, note in notes:
            if note.kind in self.losses:
                self.losses[note.kind] += note.count
            self._write(f"{self.prefix}/{unit}/event", [note.SerializeToString()], now,
                        written, heard=False)
            if self._on_event is not None:
                self._on_event(unit, note)
        if written and self._on_written is not None:
            self._on_written(written)

    def _lost(self, loss: _Loss, after: bytes | None, now: int) -> tuple[str, Event]:
        """The event of samples missed between ``loss.before`` and ``after``.

        ``after`` is None when none came after them; on imu their ticks and times are
        spread evenly between.
        """
        leaf = loss.key.rpartition("/")[2]
        t0, k0 = _instant(leaf, loss.before, loss.missed_ns)
        t1, k1 = _instant(leaf, after, loss.missed_ns)
        span = _Span()
        if k0 and k1 and k1 > k0:
            step_t, step_k = (t1 - t0) / (loss.count + 1), (k1 - k0) / (loss.count + 1)
            span.add(loss.count, round(t0 + step_t), round(t1 - step_t), round(k0 + step_k),
                     round(k1 - step_k))
        else:
            span.add(loss.count, loss.missed_ns, loss.missed_ns)
        where = f" after ticks {k0}" if k0 else ""
        return self._unarchived(loss.key, Event.LOST, span,
                                f"{counted(loss.count, 'message')} lost in transit{where} (not "
                                "recoverable from the publisher's cache)")

    def _unarchived(self, key: str, kind: int, span: _Span, detail: str
                    ) -> tuple[str, Event]:
        unit = self._unit(key)
        leaf = key.rpartition("/")[2]
        return unit, Event(unit=unit, time_ns=span.first_ns, ticks=span.first_ticks,
                           kind=kind, count=span.count, leaf=leaf,  # type: ignore[arg-type]
                           end_time_ns=span.last_ns, end_ticks=span.last_ticks,
                           detail=f"{key}: {detail}")

    def _write(self, key: str, payloads: list[bytes], received: int | np.ndarray,
               written: list[RawMessage] | None, published: np.ndarray | None = None,
               heard: bool = True) -> None:
        """Archive messages of one key, and count them in their unit's view.

        ``received``: host ns, one for all or one each; ``published``: raw reads'
        raw-clock stamps; ``heard``: they came from the unit's bridge (not the recorder's
        own events). Samples also go into the unit's clock bound.
        """
        if self.error is not None:
            return
        bulk = True
        try:
            self.writer.write_many(key, payloads, received, published)
        except ArchiveError as exc:
            self.error = exc
            return
        except ValueError:  # not all of ours (nothing written): archive those that are
            bulk = False
            payloads = self._each(key, payloads, received)
            if not payloads:
                return
        self.written += len(payloads)
        unit, leaf = self.writer.route(key)  # written: the key is one of ours
        status = Status.FromString(payloads[-1]) if leaf == "status" else None
        info = Info.FromString(payloads[-1]) if leaf == "info" else None
        with self._lock:
            view = self.views.get(unit)
            if view is None:
                view = self.views[unit] = UnitView(unit)
            view.bytes += sum(map(len, payloads))
            if heard:
                view.heard_ns = max(view.heard_ns, int(np.max(received)))
            if leaf == "imu":
                now = int(np.max(received))
                view.samples += len(payloads)
                view.last_ns = now
                view.first_ns = view.first_ns or now
                if bulk:  # (the rare rest have no receive time each: left out)
                    view.host.lags.add(payloads, np.broadcast_to(np.asarray(received, np.int64),
                                                            (len(payloads),)))
            elif status is not None:
                view.status = status
                if view.first_offset_ns is None and status.clock_offset_ns:
                    view.first_offset_ns = status.clock_offset_ns
                view.host.learn(status, status.time_ns)
            elif info is not None:
                view.host.learn(info, info.bring_up_time_ns)
        if written is not None:
            encoding = ENCODINGS.get(leaf, "")
            written.extend(RawMessage(key, payload, encoding) for payload in payloads)

    def hosts(self, now_ns: int | None = None) -> list[HostView]:
        """Every bridge host's clock against the recorder's (``host_views``).

        Args:
            now_ns: The end of the last ``HOST_WINDOW_S`` s that ``bound_ns`` covers, on
                the recorder's realtime clock; None: now.

        Returns:
            One row per host, by name, unnamed ones last.
        """
        now = clock.realtime_ns() if now_ns is None else now_ns
        with self._lock:
            return host_views([v.host for v in sorted(self.views.values(),
                                                      key=lambda v: v.name)], now)

    def _each(self, key: str, payloads: list[bytes], received: int | np.ndarray
              ) -> list[bytes]:
        """The payloads that ``write`` takes one by one.

        A message on a matching key that is not one of ours is not archived.
        """
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

    def snapshot(self) -> list[UnitRow]:
        """What the terminal shows of the units.

        Returns:
            A row per unit, by name.
        """
        now = time.monotonic()
        with self._lock:
            return [view.row(now) for view in sorted(self.views.values(),
                                                     key=lambda v: v.name)]

    def close(self) -> None:
        """Stop receiving and write what has arrived; the writer stays open, its owner's.

        The losses still open (nothing came after them) are written too, and the hosts'
        clocks over the recording (``gx3.hosts``, in the file being written). A write
        that fails is kept in ``error``.
        """
        self._alive.undeclare()
        self._stop.set()
        self._receiver.join()
        with self._held_lock:
            for sub in self._subs:
                self._hold(sub.take_by_key(1 << 30))
            for losses in self._open_losses.values():
                self._losses += [(loss, None) for loss in losses]
            self._open_losses.clear()
        self._pass()
        for sub in self._subs:
            sub.close()
        with self._lock:
            for view in self.views.values():
                view.host.lags.read()  # every sample in the bound over the recording
        hosts = self.hosts()
        if self.error is None and hosts:
            try:
                self.writer.add_metadata(HOSTS_METADATA, hosts_metadata(hosts))
            except ArchiveError as exc:
                self.error = exc
