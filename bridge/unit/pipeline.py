"""One unit from serial bytes to timed samples, kept alive through faults.

The pipeline owns the port: it brings the unit up, streams (or polls), unwraps the
timer, maps ticks to host time, and hands every sample, event and status to a
``Sink`` (the Zenoh publisher in ``gx3 bridge``; a list in tests). A pulled cable
or a silent unit is reported, retried with backoff, and followed by a fresh
bring-up when the unit is back, so a restarted or power-cycled unit resumes alone.
Where it sits in the product: ``docs/design/architecture.md``.
"""

from __future__ import annotations

import contextlib
import functools
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from bridge.device import clock
from bridge.device.link import SYSFS, Link, find_link
from bridge.device.port import Port
from bridge.device.session import Session, UnitInfo, find_baud
from bridge.exceptions import DeviceError, PortError
from bridge.protocol.codec import Batch, Records
from bridge.timing.rate import RateWindow
from bridge.timing.realtime import ChangeKind, ClockChange
from bridge.timing.stream import Settings, StreamTiming
from bridge.timing.unwrap import TimingKind

_RETRY_FIRST_S = 0.2
_RETRY_MAX_S = 5.0
UNSYNCHRONISED = ("the host clock is not synchronised (no chrony, ntpd or PTP daemon "
                  "disciplines it): time_ns is only as true as this clock; see the docs on "
                  "a fleet's clocks")
#: The part of a latency budget kept for what follows a read: the wake-up, framing,
#: timing and the put. The rest of the budget is how long reads may gather.
PUBLISH_RESERVE_S = 0.001


@dataclass(frozen=True)
class Options:
    """What the operator asked of the bridge; None leaves the unit's own setting.

    Attributes:
        url: The port: a device path, or a pyserial URL (``socket://``).
        baud: The unit's baud rate; None: find it.
        record: The record type to stream (command byte).
        decimation: Calculation cycles (1 ms) per record.
        flags: The sampling settings' flags.
        filter_width: The accel and gyro filter's width.
        mag_filter_width: The magnetometer filter's width.
        new_baud: A baud rate to move the unit to.
        persist: Store the settings in the unit's non-volatile memory.
        poll_hz: Poll the unit this often instead of streaming.
        transport: The link: ``uart``, ``usb``, ``usb-serial`` or ``auto`` (by device
            name).
        silence_s: A unit that sends nothing for this long is lost, and brought up again.
        sysfs: Where a USB-serial adapter's latency timer is read.
        max_latency_s: The longest a byte may wait between arriving and its samples
            going out; above ``PUBLISH_RESERVE_S``, reads gather (fewer wake-ups and puts
            in bursts).
    """

    url: str
    baud: int | None = 115_200  # None: find it
    record: int | None = None
    decimation: int | None = None
    flags: int | None = None
    filter_width: int | None = None
    mag_filter_width: int | None = None
    new_baud: int | None = None
    persist: bool = False
    poll_hz: float | None = None
    transport: str = "auto"  # uart, usb, usb-serial or auto (by device name)
    silence_s: float = 1.0
    sysfs: Path = SYSFS  # where a USB-serial adapter's latency timer is read
    #: The longest a byte may wait between arriving and its samples going out; above
    #: ``PUBLISH_RESERVE_S`` reads gather (fewer wake-ups and puts in bursts).
    max_latency_s: float = PUBLISH_RESERVE_S

    @property
    def hold_s(self) -> float:
        """How long reads may gather within the latency budget."""
        return max(0.0, self.max_latency_s - PUBLISH_RESERVE_S)


class TimedSamples:
    """One run of records of one type, with their device and host times.

    A live read's record or two come as ``Records`` with plain lists of ticks and
    times (published as they are); ``batch``, ``ticks``, ``time_ns`` and ``rx_ns`` are
    arrays, made from them only when asked for. The records' own ``rx_ns`` are their
    completing reads' receive times on the raw monotonic clock; ``rx_ns`` here the same
    reads' on the realtime clock, as ``time_ns`` is.

    Args:
        records: The records.
        ticks: Their unwrapped device timer.
        time_ns: The host-clock instants their values describe, ns.
        rx_ns: Their completing reads' receive times on the realtime clock, ns.
        part: Their partial reads, as ImuSamples carry them (``part_rx_mono_raw_ns``,
            ``part_lead_ns``).
    """

    def __init__(self, records: Batch | Records, ticks: np.ndarray | list[int],
                 time_ns: np.ndarray | list[int], rx_ns: np.ndarray | list[int],
                 part: tuple[np.ndarray, np.ndarray] | tuple[list[int], list[int]]) -> None:
        self.records = records
        self.tick_values = ticks
        self.time_values = time_ns
        self.rx_values = rx_ns
        self.part_values = part

    @functools.cached_property
    def batch(self) -> Batch:
        """The records as a batch of columns."""
        records = self.records
        return records if isinstance(records, Batch) else records.batch()

    @functools.cached_property
    def ticks(self) -> np.ndarray:
        """The unwrapped device timer, int64."""
        return np.asarray(self.tick_values, np.int64)

    @functools.cached_property
    def time_ns(self) -> np.ndarray:
        """The instants the values describe, host ns, int64."""
        return np.asarray(self.time_values, np.int64)

    @functools.cached_property
    def rx_ns(self) -> np.ndarray:
        """The completing reads' receive times on the realtime clock, ns, int64."""
        return np.asarray(self.rx_values, np.int64)

    @functools.cached_property
    def part(self) -> tuple[np.ndarray, np.ndarray]:
        """The partial reads as ImuSamples carry them (raw stamp, line time held)."""
        return (np.asarray(self.part_values[0], np.int64),
                np.asarray(self.part_values[1], np.int64))

    def lists(self) -> tuple[list[int], list[int], list[int], list[int], list[int]]:
        """Ticks, instants, receive times and partial reads in plain integers.

        As a live read's come.

        Returns:
            (ticks, time_ns, rx_ns, part_rx_mono_raw_ns, part_lead_ns).
        """
        return (_plain(self.tick_values), _plain(self.time_values), _plain(self.rx_values),
                _plain(self.part_values[0]), _plain(self.part_values[1]))


def _plain(values: np.ndarray | list[int]) -> list[int]:
    return values if isinstance(values, list) else [int(v) for v in values.tolist()]


class UnitState(StrEnum):
    """Where a unit's pipeline is (``Status.state`` says it on Zenoh)."""

    STARTING = "starting"
    WAITING = "waiting"  # for the unit to answer (not up yet)
    BRING_UP = "bring-up"
    STREAMING = "streaming"
    POLLING = "polling"
    LOST = "lost"  # the port or the unit went away; retrying
    STOPPED = "stopped"


class EventKind(StrEnum):
    """What happened to a unit's stream: the timeline's kinds and the pipeline's own.

    The timeline's are those of ``TimingKind``. ``Event.Kind`` says each on Zenoh
    (``waiting`` is for the log only).
    """

    ROLLOVER = TimingKind.ROLLOVER.value
    RESET = TimingKind.RESET.value
    GAP = TimingKind.GAP.value
    GLITCH = TimingKind.GLITCH.value
    RECONNECT = "reconnect"
    DISCONNECT = "disconnect"
    RESYNC = "resync"
    BRING_UP = "bring_up"
    COMMAND = "command"
    WAITING = "waiting"
    HOST_CLOCK_STEP = "host_clock_step"
    HOST_CLOCK_SLEW = "host_clock_slew"


@dataclass
class UnitEvent:
    """Something that happened to a unit's stream.

    Attributes:
        kind: What happened.
        time_ns: When, host ns on the realtime clock.
        ticks: The unit's unwrapped timer at it, where it has one.
        count: How many: records of a gap, bytes of a resync, ...
        detail: What happened, in words.
        clock_change_ns: For a host clock step or slew: how far the clock moved.
    """

    kind: EventKind
    time_ns: int
    ticks: int = 0
    count: int = 0
    detail: str = ""
    clock_change_ns: int = 0  # a host clock step or slew: how far the clock moved


@dataclass
class Counters:
    """Running totals for status."""

    samples: int = 0
    dropped: int = 0
    glitches: int = 0
    reconnects: int = 0
    checksum_failures: int = 0
    implausible: int = 0
    bytes_skipped: int = 0
    resyncs: int = 0
    state: UnitState = UnitState.STARTING
    meter: RateWindow = field(default_factory=lambda: RateWindow(5.0))

    def rate(self, now: float) -> float:
        """Samples per second over the last few seconds.

        Args:
            now: Monotonic seconds.

        Returns:
            The rate.
        """
        return self.meter.rate(now, self.samples)


class Sink(Protocol):
    """Where a pipeline hands what it produces (the Zenoh publisher; a list in tests)."""

    def info(self, info: UnitInfo) -> None:
        """Take the unit as brought up: before its first sample, and after each change.

        Args:
            info: The unit's identity and settings.
        """
        ...

    def samples(self, samples: TimedSamples) -> None:
        """Take timed samples, as they come.

        Args:
            samples: One run of records of one type, with their times.
        """
        ...

    def event(self, event: UnitEvent) -> None:
        """Take something that happened to the stream, as it happens.

        Args:
            event: What happened.
        """
        ...

    def status(self, status: dict[str, Any]) -> None:
        """Take the pipeline's status, once a second.

        Args:
            status: The state, counters, clock model and host clock.
        """
        ...


Action = Callable[[Session, UnitInfo], dict[str, Any]]


class Pipeline:
    """Run one unit until ``stop`` is set.

    ``submit`` queues operator actions that run between reads, on the port's own thread.

    Args:
        options: What the operator asked of the bridge.
        sink: Where samples, events, status and info go.
        on_read: Hears every read from the port as ``(data, raw_ns, real_ns)``: its
            receive times on the raw monotonic and the realtime clock (a raw capture).
    """

    def __init__(self, options: Options, sink: Sink,
                 on_read: Callable[[bytes, int, int], None] | None = None) -> None:
        self.options = options
        self.sink = sink
        self.on_read = on_read
        self.counters = Counters()
        self.info: UnitInfo | None = None
        self.timing = StreamTiming()
        self.error: Exception | None = None
        self.came_up = False  # the unit was brought up at least once
        self.link: Link = find_link(options.url, options.transport, options.sysfs)
        self._warned: str | None = None  # the link warning given (given once)
        self._host_checked = False  # whether the host clock's sync state was looked at
        self.waiting_for: str | None = None  # why the unit is not up, while it is not
        self.last_failure = ""  # the last failed attempt's message
        self._actions: queue.Queue[tuple[Action, str, queue.Queue[Any]]] = queue.Queue()

    def submit(self, action: Action, effect: str = "none", timeout: float = 120.0
               ) -> dict[str, Any]:
        """Run ``action(session, info)`` on the pipeline's thread; its result or error.

        Args:
            action: Runs with the unit's session and info; returns its result.
            effect: What the action does to the stream: "reconfigure" (settings
                changed: timing follows them), "restart" (the unit resets: bring it up
                again) or "none".
            timeout: Seconds to wait for the result.

        Returns:
            The action's result.

        Raises:
            TimeoutError: The unit did not finish the action in time.
            DeviceError: The unit refused the action (raised here as the action raised
                it).
            PortError: The port failed during the action.
            ValueError: The action's parameters are wrong.
        """
        done: queue.Queue[Any] = queue.Queue(maxsize=1)
        self._actions.put((action, effect, done))
        try:
            result = done.get(timeout=timeout)
        except queue.Empty:
            raise TimeoutError(f"the unit did not finish the command within {timeout:g} s") \
                from None
        if isinstance(result, BaseException):
            raise result
        return dict(result)

    # --- lifecycle -----------------------------------------------------------------------
    def run(self, stop: threading.Event) -> None:
        """Keep the unit streaming until ``stop`` is set.

        An unexpected error is kept in ``error`` (and ends the run, setting ``stop``), so
        the process can report it and exit.

        Args:
            stop: Ends the run.
        """
        try:
            self._run(stop)
        except Exception as exc:
            self.error = exc
            self.counters.state = UnitState.STOPPED
            stop.set()

    def _run(self, stop: threading.Event) -> None:
        backoff = _RETRY_FIRST_S
        lost_at: int | None = None
        while not stop.is_set():
            session: Session | None = None
            try:
                session = self._open()
                self._bring_up(session)
            except BaseException as exc:
                if session is not None:
                    self._close(session, clean=stop.is_set())
                if not isinstance(exc, (PortError, DeviceError)):
                    raise  # not a unit that may come up later: retrying cannot help
                self._wait(exc, lost=lost_at is not None)
                stop.wait(backoff)
                backoff = min(_RETRY_MAX_S, backoff * 2)
                continue
            backoff = _RETRY_FIRST_S
            self.waiting_for = None
            if lost_at is not None:
                self.counters.reconnects += 1
                gap = (clock.raw_ns() - lost_at) / 1e9
                self._event(EventKind.RECONNECT, detail=f"back after {gap:.1f} s")
            lost_at = None
            try:
                self._stream(session, stop)
            except _Restart:
                self.counters.state = UnitState.BRING_UP
            except (PortError, DeviceError) as exc:
                lost_at = clock.raw_ns()
                self.counters.state = UnitState.LOST
                self._event(EventKind.DISCONNECT, detail=str(exc))
            finally:
                self._close(session, clean=stop.is_set())
        self.counters.state = UnitState.STOPPED

    def _wait(self, exc: PortError | DeviceError, lost: bool) -> None:
        """Say why the unit is not up once, and again only when the reason changes.

        A retry every few seconds must not flood the log or look like a new fault.
        """
        self.counters.state = UnitState.LOST if lost else UnitState.WAITING
        if exc.why != self.waiting_for:
            self._event(EventKind.WAITING, detail=f"{exc}; retrying, with pauses growing to "
                                          f"{_RETRY_MAX_S:g} s")
        self.waiting_for = exc.why
        self.last_failure = str(exc)

    def _open(self) -> Session:
        o = self.options
        self.link = find_link(o.url, o.transport, o.sysfs)  # a replug may bring a new timer
        if o.baud is None:
            port, _ = find_baud(o.url, 115_200)
        else:
            port = Port.open(o.url, o.baud)
        session = Session(port)
        session.on_reads = self._heard
        session.paced = self.transport != "usb"  # bytes come at a serial line's pace
        return session

    def _heard(self, reads: list[bytes], raws: list[int], reals: list[int]) -> None:
        """Hear every read, before its records.

        The host clock's offset at it first (its steps and slews said as events), then
        ``on_read`` (a raw capture).
        """
        for change in self.timing.hear(raws, reals):
            self._clock_changed(change)
        if self.on_read is not None:
            for data, raw, real in zip(reads, raws, reals, strict=True):
                self.on_read(data, raw, real)

    def _clock_changed(self, change: ClockChange) -> None:
        kind = EventKind.HOST_CLOCK_STEP if change.kind == ChangeKind.STEP \
            else EventKind.HOST_CLOCK_SLEW
        self.sink.event(UnitEvent(kind, change.real_ns, detail=change.describe(),
                                  clock_change_ns=change.size_ns))

    def _close(self, session: Session, clean: bool) -> None:
        if clean:
            with contextlib.suppress(PortError, DeviceError):
                session.stop_streaming()
        session.port.close()

    def _bring_up(self, session: Session) -> None:
        o = self.options
        self.counters.state = UnitState.BRING_UP
        session.quiesce()
        info = session.identify()
        session.apply_sampling(info, o.persist, decimation=o.decimation, flags=o.flags,
                               filter_width=o.filter_width, mag_filter_width=o.mag_filter_width)
        if o.new_baud is not None:
            session.change_baud(info, o.new_baud, o.persist)
        info.record = o.record or info.stream_record
        self.info = info
        # streaming restarts on a new phase of the output lattice: announce it
        self._start_timing(info, discontinuity=True)
        self.sink.info(info)  # before the first sample: subscribers must know of it first
        if o.poll_hz is None:
            session.start_streaming(info.record)
        else:
            session.start_polling(info.record)
        warnings = [info.line_warning()] if o.poll_hz is None and self.transport != "usb" \
            else []
        link_warning = self.link.warning()
        if link_warning != self._warned:
            self._warned = link_warning
            warnings.append(link_warning)
        if not self._host_checked:  # once: the host's state is not the unit's
            self._host_checked = True
            sync = clock.host_sync()
            if sync.known and not sync.synchronised:
                warnings.append(UNSYNCHRONISED)
        self._event(EventKind.BRING_UP, detail=f"{info.ids.get('model_name', '')} "
                    f"{info.ids.get('serial', '')} firmware {info.firmware_text}, "
                    f"0x{info.record:02X} at {info.output_hz:g} Hz over {self.link.describe()}"
                    + "".join(f"; {w}" for w in warnings if w))
        self.counters.state = UnitState.STREAMING if o.poll_hz is None else UnitState.POLLING
        self.came_up = True

    def _start_timing(self, info: UnitInfo, discontinuity: bool = False) -> None:
        self.timing.configure(Settings(
            record=info.record, decimation=max(1, info.sampling.get("decimation", 1)),
            filter_width=max(1, info.sampling.get("filter_width", 1)), baud=info.baud,
            transport=self.transport, polled=self.options.poll_hz is not None,
            latency_timer_ms=self.link.latency_timer_ms),
            restarted=discontinuity)

    @property
    def transport(self) -> str:
        """The link to the unit: "uart", "usb" or "usb-serial".

        "usb" is its own USB port (/dev/ttyACM*), "usb-serial" an adapter (/dev/ttyUSB*).
        """
        return self.link.transport

    def _stream(self, session: Session, stop: threading.Event) -> None:
        assert self.info is not None
        last_data = time.monotonic()
        next_status = time.monotonic() + 1.0
        next_poll = time.monotonic()
        poll_hz, hold_s = self.options.poll_hz, self.options.hold_s
        while not stop.is_set():
            if self._actions.queue:  # a peek without the queue's lock, once a read
                self._run_actions(session)
            wait = 0.05
            if poll_hz is not None:
                if time.monotonic() >= next_poll:
                    next_poll = max(next_poll + 1.0 / poll_hz, time.monotonic())
                    session.poll()
                wait = max(0.0, min(wait, next_poll - time.monotonic()))
            # Silence is judged from before the read: a host that stalls this thread
            # after a read that held no whole record has not heard a silent unit.
            asked = time.monotonic()
            batches = session.read_records(wait, hold_s)
            now = time.monotonic()
            if batches:
                last_data = now
                for batch in batches:
                    self.process(batch)
            elif asked - last_data > self.options.silence_s:
                raise DeviceError(f"{self.options.url}: the unit fell silent for "
                                  f"{now - last_data:.1f} s")
            if now >= next_status:
                next_status += 1.0
                self._status(session)

    def process(self, records: Batch | Records) -> None:
        """Time one read's records of the stream and hand them to the sink.

        A live read's record or two go through in plain integers while they are intact
        and one period apart; anything else (a gap, a glitch, a reset, a backlog) through
        the batch path, with the same ticks, times and events either way.

        Args:
            records: The records of one read, of the streamed type.
        """
        if isinstance(records, Records):
            few = self.timing.process_few(records.timers(), records.rx_ns, records.part_ns,
                                          records.part_bytes)
            if few is not None:
                for ev in few.events:
                    self._event(EventKind(ev.kind), ticks=ev.ticks, count=ev.count)
                self.counters.samples += len(records)
                self.sink.samples(TimedSamples(records, few.ticks, few.time_ns, few.rx_ns,
                                                few.part))
                return
            records = records.batch()
        timed = self.timing.process(records)
        for ev in timed.events:
            self._event(EventKind(ev.kind), ticks=int(ev.ticks), count=int(ev.count))
        self.counters.glitches += sum(ev.kind == TimingKind.GLITCH for ev in timed.events)
        self.counters.dropped += timed.dropped
        if len(timed.batch):
            self.counters.samples += len(timed.batch)
            self.sink.samples(TimedSamples(timed.batch, timed.ticks, timed.time_ns, timed.rx_ns,
                                            timed.part))

    def _run_actions(self, session: Session) -> None:
        assert self.info is not None
        while True:
            try:
                action, effect, done = self._actions.get_nowait()
            except queue.Empty:
                return
            try:
                result = action(session, self.info)
            except (DeviceError, PortError, ValueError) as exc:
                done.put(exc)
                self._event(EventKind.COMMAND, detail=f"refused: {exc}")
                continue
            done.put(result)
            self._event(EventKind.COMMAND, detail=f"{effect}: {result}"[:200])
            if effect == "restart":
                raise _Restart
            if effect in ("reconfigure", "discontinuity"):
                self._start_timing(self.info, discontinuity=True)
                self.sink.info(self.info)

    def _status(self, session: Session) -> None:
        c = self.counters
        stats = session.framer.stats
        c.checksum_failures = stats.checksum_failures
        c.implausible = stats.implausible
        c.bytes_skipped = stats.bytes_skipped
        c.resyncs = stats.resyncs
        model = self.timing.state
        self.sink.status({
            "state": c.state, "samples": c.samples, "samples_per_s": c.rate(time.monotonic()),
            "dropped": c.dropped, "glitches": c.glitches, "reconnects": c.reconnects,
            "checksum_failures": c.checksum_failures, "implausible": c.implausible,
            "bytes_skipped": c.bytes_skipped, "resyncs": c.resyncs,
            "clock": model, "host_sync": clock.host_sync(),
            "host_offset_ns": self.timing.host.offset_ns,
        })

    def _event(self, kind: EventKind, ticks: int = 0, count: int = 0, detail: str = "") -> None:
        self.sink.event(UnitEvent(kind, clock.realtime_ns(), ticks, count, detail))


class _Restart(Exception):
    """The unit was reset on purpose: bring it up again, no disconnect to report."""
