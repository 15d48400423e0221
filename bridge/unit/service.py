"""The `gx3 bridge` process: one unit's pipeline published on Zenoh.

The pipeline (device -> timing) hands samples, events, status and info to a
``BusSink``, which turns them into the gx3.v1 messages and publishes them under
the unit's keys; every read can also go out raw (``--publish-raw``) and into a raw
capture file beside it, and every sample as ROS 2 messages the way rmw_zenoh
publishes them (``--ros2``).
Operator commands that reach the unit's command queryable run on the
pipeline's thread, only when the bridge was started with ``--allow-commands``.
One unit name, one live bridge: a bridge asks for the name's liveliness token before
it declares its own, and does not start under a name a running bridge holds. Where it
sits in the product: ``docs/design/architecture.md``.
"""

from __future__ import annotations

import json
import logging
import time
from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from bridge import __version__
from bridge._text import counted, number
from bridge.archive.rawcapture import capture_metadata
from bridge.bus.events import LEVEL
from bridge.bus.gx3_pb2 import Event, HostClock, Info, Status
from bridge.device import clock
from bridge.device.actions import ACTIONS, run_action
from bridge.device.link import Link
from bridge.device.session import Session, UnitInfo
from bridge.exceptions import DeviceError, NameTaken
from bridge.protocol.codec import Records
from bridge.protocol.table import Mode
from bridge.unit.pipeline import EventKind, Pipeline, TimedSamples, UnitEvent, UnitState

if TYPE_CHECKING:  # Zenoh is imported once a unit is up: the CLI's help stays quick
    import zenoh

    from bridge.bus.publish import UnitPublisher
    from bridge.ros2.options import Ros2Options
    from bridge.ros2.rmw import UnitTopics

DECLARE_SETTLE_S = 1.0
NAME_QUERY_S = 3.0  # how long a bridge waits for a running bridge to answer for its name
GAP_LINE_S = 5.0  # gaps on the terminal: at most one line this often
EARLY_READS = 10_000  # reads kept from before the first bring-up, for a raw capture
_log = logging.getLogger(__name__)
_STATES = {UnitState.STARTING: Status.CONNECTING, UnitState.WAITING: Status.CONNECTING,
           UnitState.BRING_UP: Status.BRINGING_UP, UnitState.STREAMING: Status.STREAMING,
           UnitState.POLLING: Status.STREAMING, UnitState.LOST: Status.DISCONNECTED,
           UnitState.STOPPED: Status.STOPPED}
#: Each kind as Zenoh says it; ``waiting`` is for the log only.
_KINDS: dict[str, Event.Kind] = {kind: getattr(Event, kind.name) for kind in EventKind
                                  if kind != EventKind.WAITING}


def claim_name(session: zenoh.Session, prefix: str, unit: str) -> None:
    """Refuse a unit name that a running bridge answers for.

    Two bridges under one name would mix two units' samples under one key.

    Args:
        session: The Zenoh session.
        prefix: The key prefix.
        unit: The name.

    Raises:
        NameTaken: A running bridge answers for the name's liveliness token.
    """
    from bridge.bus.keys import UnitKeys

    key = UnitKeys(unit, prefix).alive
    if any(r.ok is not None for r in session.liveliness().get(key, timeout=NAME_QUERY_S)):
        raise NameTaken(f"a running bridge already publishes unit {unit!r} ({key} is "
                        "alive): stop it first, or give this unit another name with --unit")


def _host_clock_message(sync: clock.HostSync, offset_ns: int | None = None) -> HostClock:
    """The host's clock as the kernel reports it, and its offset at the latest read."""
    return HostClock(host=sync.host, synchronised=sync.synchronised, known=sync.known,
                     estimated_error_ns=sync.estimated_error_ns,
                     maximum_error_ns=sync.maximum_error_ns, tai_offset_s=sync.tai_offset_s,
                     state=sync.state, realtime_minus_raw_ns=offset_ns or 0)


def info_message(unit: str, port: str, info: UnitInfo, allow_commands: bool,
                 link: Link | None = None, polled: bool = False,
                 sync: clock.HostSync | None = None) -> Info:
    """The unit's Info message: identity, settings, link and its bridge host's clock."""
    s = info.sampling
    return Info(
        host_clock=_host_clock_message(sync or clock.host_sync()),
        unit=unit, port=port, baud=info.baud, firmware=info.firmware,
        firmware_text=info.firmware_text, decimation=s.get("decimation", 0),
        flags=s.get("flags", 0), filter_width=s.get("filter_width", 0),
        mag_filter_width=s.get("mag_filter_width", 0),
        up_compensation=s.get("up_compensation", 0),
        north_compensation=s.get("north_compensation", 0), command=info.record,
        mode=int(Mode.ACTIVE if polled else Mode.CONTINUOUS), bring_up_time_ns=info.bring_up_ns,
        bridge_version=__version__,
        allow_commands=allow_commands, output_rate_hz=info.output_hz,
        link=link.transport if link else "uart",
        latency_timer_ms=(link.latency_timer_ms or 0) if link else 0, **info.ids)


def _status_message(unit: str, port: str, info: UnitInfo | None, status: dict[str, Any]) -> Status:
    model = status.get("clock")
    sync = status.get("host_sync")
    msg = Status(
        unit=unit, time_ns=clock.realtime_ns(),
        connected=status["state"] in (UnitState.STREAMING, UnitState.POLLING),
        state=_STATES.get(status["state"], Status.STATE_UNSPECIFIED),
        samples_per_s=status["samples_per_s"], port=port,
        **{k: status[k] for k in ("samples", "dropped", "checksum_failures", "implausible",
                                  "bytes_skipped", "resyncs", "reconnects", "glitches")})
    if info is not None:
        msg.command = info.record
        msg.output_rate_hz = info.output_hz
        msg.baud = info.baud
    if model is not None and model.offset_ns:
        # the model is fitted on the raw clock: the offset on the realtime clock, as the
        # samples' time_ns are, at the latest read
        msg.clock_offset_ns = int(model.offset_ns) + (status.get("host_offset_ns") or 0)
        msg.clock_drift_ppm = float(model.drift_ppm)
        msg.clock_spread_ns = float(model.spread_ns)
        msg.time_uncertainty_ns = int(model.uncertainty_ns)
    if sync is not None:
        msg.host_clock.CopyFrom(_host_clock_message(sync, status.get("host_offset_ns")))
    return msg


def _event_message(unit: str, event: UnitEvent) -> Event:
    return Event(unit=unit, time_ns=event.time_ns, ticks=event.ticks,
                 kind=_KINDS.get(event.kind, Event.KIND_UNSPECIFIED),
                 count=event.count or 1, detail=event.detail,
                 clock_change_ns=event.clock_change_ns)


def _command_handler(pipeline: Pipeline) -> Callable[[str], str]:
    """What the unit's command queryable answers, on a bridge started with --allow-commands.

    A JSON request ``{"action": NAME, "params": {...}, "confirm": bool}`` in, the JSON
    result out; a ValueError becomes the query's error reply.
    """
    def handle(text: str) -> str:
        try:
            request = json.loads(text or "{}")
            name = str(request.get("action", ""))
            params = dict(request.get("params") or {})
            confirm = bool(request.get("confirm"))
        except (ValueError, AttributeError, TypeError):
            raise ValueError("the request is not a JSON object with an action") from None
        if name not in ACTIONS:
            raise ValueError(f"unknown action {name!r}; known: {', '.join(ACTIONS)}")

        def action(session: Session, info: UnitInfo) -> dict[str, Any]:
            return run_action(name, session, info, params, confirm)

        try:
            return json.dumps(pipeline.submit(action, ACTIONS[name].effect))
        except (DeviceError, TimeoutError) as exc:
            raise ValueError(str(exc)) from None
    return handle


class BusSink:
    """Publishes what the pipeline produces under the unit's keys.

    The unit's name is known only after its first bring-up (its serial number,
    unless the operator named it), so the publisher is declared then; listeners
    registered with ``on_unit`` learn the name and the unit's description.

    Args:
        session: The Zenoh session to publish on.
        prefix: The key prefix.
        unit: The unit's name; None: from its serial number, at its first bring-up.
        port: The port, as the Info and Status name it.
        allow_commands: Answer operator commands on the unit's command queryable.
        cache_s: Seconds of samples the publisher's cache keeps for late subscribers.
        quiet: Log only disconnects and why the unit is not up, not every event.
        raw: Also publish every read raw (``<prefix>/<unit>/raw``).
        ros2: Also publish the samples on ROS 2 as these options ask; None: not.
    """

    def __init__(self, session: zenoh.Session, prefix: str, unit: str | None, port: str,
                 allow_commands: bool, cache_s: float, quiet: bool = False,
                 raw: bool = False, ros2: Ros2Options | None = None) -> None:
        self.session, self.prefix, self.unit, self.port = session, prefix, unit, port
        self.allow_commands, self.cache_s, self.quiet = allow_commands, cache_s, quiet
        self.raw, self.ros2_options = raw, ros2
        self.ros2: UnitTopics | None = None  # the unit's ROS 2 topics, with ros2_options
        # a unit that never comes up (a wrong baud rate) must not fill the memory
        self._early_reads: deque[tuple[bytes, int, int]] = deque(maxlen=EARLY_READS)
        self._read_listeners: list[Callable[[bytes, int, int], None]] = []
        self.publisher: UnitPublisher | None = None
        self.pipeline: Pipeline | None = None
        self._info: UnitInfo | None = None
        self._listeners: list[Callable[[str, dict[str, str]], None]] = []
        self._status_listeners: list[Callable[[Status], None]] = []
        self._stamp_listeners: list[Callable[[str, int, int], None]] = []
        self._lines = _EventLines()

    def attach(self, pipeline: Pipeline) -> None:
        """Serve this pipeline: its link, options and operator commands.

        Args:
            pipeline: The pipeline that hands this sink what it produces.
        """
        self.pipeline = pipeline

    def on_unit(self, listener: Callable[[str, dict[str, str]], None]) -> None:
        """Tell ``listener(name, metadata)`` the unit's name and description when it is up.

        Args:
            listener: Hears the name and the unit's capture metadata
                (``capture_metadata``) at each bring-up.
        """
        self._listeners.append(listener)

    def info(self, info: UnitInfo) -> None:
        """Publish the unit's Info; at its first bring-up, declare its publisher first.

        Args:
            info: The unit as brought up.

        Raises:
            NameTaken: A running bridge already publishes a unit of this name.
        """
        from bridge.bus.keys import check_unit
        from bridge.bus.publish import UnitPublisher

        self._info = info
        if self.unit is None:
            self.unit = check_unit(_name_from_serial(info.ids.get("serial", "")))
        assert self.pipeline is not None
        message = info_message(self.unit, self.port, info, self.allow_commands,
                               self.pipeline.link, self.pipeline.options.poll_hz is not None)
        if self.publisher is not None:
            if self.ros2 is not None:  # a bring-up may change the rate and the width
                self.ros2.use_settings(info.output_hz, info.filter_width)
            self.publisher.set_info(message)
            return
        claim_name(self.session, self.prefix, self.unit)
        self.publisher = UnitPublisher(
            self.session, self.unit, prefix=self.prefix,
            cache_samples=max(1, round(self.cache_s * info.output_hz)),
            on_command=_command_handler(self.pipeline), allow_commands=self.allow_commands,
            raw=self.raw, on_stamped=self._stamped)
        if self.ros2_options is not None:
            from bridge.ros2.rmw import UnitTopics

            o = self.ros2_options
            self.ros2 = UnitTopics(self.session, o.domain, self.prefix, self.unit, o.distro,
                                   o.noise, o.orientation_stddev)
            self.ros2.use_settings(info.output_hz, info.filter_width)
        self.publisher.set_info(message)
        for listener in self._listeners:
            listener(self.unit, capture_metadata(message))
        # Let the new publisher's declaration reach subscribers that already run (a
        # recorder) before the first sample, which they would otherwise miss.
        time.sleep(DECLARE_SETTLE_S)
        for read in self._early_reads:
            self._deliver(*read)
        self._early_reads.clear()

    def on_read(self, listener: Callable[[bytes, int, int], None]) -> None:
        """Tell ``listener`` every read from the port (a raw capture).

        Args:
            listener: Hears ``(data, raw_ns, real_ns)``: the read and its receive times
                on the raw monotonic and the realtime clock.
        """
        self._read_listeners.append(listener)

    def read(self, data: bytes, raw_ns: int, real_ns: int) -> None:
        """Take a read from the port: to the read listeners, and published raw with ``raw``.

        The reads of the first bring-up wait for the unit's name (and publisher).

        Args:
            data: The read.
            raw_ns: Its receive time on the raw monotonic clock.
            real_ns: Its receive time on the realtime clock.
        """
        if not (self.raw or self._read_listeners):
            return
        if self.publisher is None:
            self._early_reads.append((data, raw_ns, real_ns))
        else:
            self._deliver(data, raw_ns, real_ns)

    def _deliver(self, data: bytes, raw_ns: int, real_ns: int) -> None:
        for listener in self._read_listeners:
            listener(data, raw_ns, real_ns)
        if self.raw and self.publisher is not None:
            self.publisher.publish_raw(data, raw_ns, real_ns)

    def samples(self, samples: TimedSamples) -> None:
        """Publish timed samples (and on ROS 2, with ``ros2``).

        Args:
            samples: The samples.
        """
        if self.publisher is not None:
            if isinstance(samples.records, Records):
                self.publisher.publish_records(samples.records, *samples.lists())
            else:
                self.publisher.publish_samples(samples.batch, samples.ticks, samples.time_ns,
                                               samples.rx_ns, samples.part)
            if self.ros2 is not None:
                self.ros2.publish(samples.batch, samples.time_ns)

    def event(self, event: UnitEvent) -> None:
        """Log an event, and publish it (``waiting`` is for the log only).

        Args:
            event: What happened.
        """
        if not self.quiet or event.kind in (EventKind.DISCONNECT, EventKind.WAITING):
            self._lines.event(event)
        # "waiting" (why the unit is not up yet) is for the log; status carries the state
        if self.publisher is not None and self.unit is not None and event.kind in _KINDS:
            self.publisher.publish_event(_event_message(self.unit, event))

    def status(self, status: dict[str, Any]) -> None:
        """Publish the unit's Status.

        Args:
            status: The pipeline's state, counters and clock model.
        """
        self._lines.flush(time.monotonic())
        if self.publisher is not None and self.unit is not None:
            message = _status_message(self.unit, self.port, self._info, status)
            self.publisher.publish_status(message)
            for listener in self._status_listeners:
                listener(message)

    def on_status(self, listener: Callable[[Status], None]) -> None:
        """Tell ``listener`` each Status as it is published (once a second).

        Args:
            listener: Hears the message (``bridge.bus.metrics.Health.status``).
        """
        self._status_listeners.append(listener)

    def on_stamped(self, listener: Callable[[str, int, int], None]) -> None:
        """Tell ``listener`` of each put stamped with its publish time (one in 16).

        Args:
            listener: Hears ``(unit, received_ns, published_ns)``: when the read that
                completed the put's last record was received, and when the put returned
                (``bridge.bus.publish.UnitPublisher``).
        """
        self._stamp_listeners.append(listener)

    def _stamped(self, received_ns: int, published_ns: int) -> None:
        if self.unit is not None:
            for listener in self._stamp_listeners:
                listener(self.unit, received_ns, published_ns)

    def close(self) -> None:
        """Log the gaps held back, and undeclare the publishers."""
        self._lines.flush(None)
        if self.ros2 is not None:
            self.ros2.close()
            self.ros2 = None
        if self.publisher is not None:
            self.publisher.close()
            self.publisher = None

    def summary(self) -> str:
        """The closing line: totals as the pipeline ends (not the last 1 Hz status).

        Returns:
            The line.
        """
        if self.pipeline is None or self.unit is None:
            return f"{self.port}: no unit brought up"
        c = self.pipeline.counters
        return (f"{self.unit}: {counted(c.samples, 'sample')}, {number(c.dropped)} dropped, "
                f"{counted(c.reconnects, 'reconnect')}, "
                f"{counted(c.checksum_failures, 'checksum failure')}")


def _name_from_serial(serial: str) -> str:
    """A key-safe unit name from a serial number ("gx3-unit" when it has none)."""
    name = "".join(c if c.isalnum() or c in "-_." else "-" for c in serial.strip())
    return name or "gx3-unit"


def _stamp(time_ns: int) -> str:
    return time.strftime("%H:%M:%S", time.localtime(time_ns / 1e9))


def _level(kind: str) -> int:
    """An event's log level: its severity in every viewer (bridge/bus/events.py)."""
    known = _KINDS.get(kind)
    return logging.getLevelNamesMapping()["INFO" if known is None else LEVEL[known]]


def _print_event(event: UnitEvent) -> None:
    if event.kind == EventKind.GAP:  # how many went missing, even when one did
        count = f" ({counted(event.count, 'sample')} missing)"
    else:
        count = f" ({event.count})" if event.count > 1 else ""
    _log.log(_level(event.kind), f"{event.kind}{count} {event.detail}".rstrip(), extra={
        "event": event.kind, "count": event.count, "time_ns": event.time_ns})


class _EventLines:
    """Events on the terminal, a line each, but gaps summed into a line every ``GAP_LINE_S``.

    A line too slow for the output rate gaps at every other record. (On the bus and in
    archives each gap stays an event of its own.)
    """

    def __init__(self) -> None:
        self._gaps: list[UnitEvent] = []
        self._printed: float | None = None  # monotonic time of the last gap line

    def event(self, event: UnitEvent) -> None:
        if event.kind != EventKind.GAP:
            _print_event(event)
            return
        self._gaps.append(event)
        self.flush(time.monotonic())

    def flush(self, now: float | None) -> None:
        """Print the gaps held back once ``GAP_LINE_S`` has passed since the last gap line.

        ``now`` None: at once.
        """
        gaps = self._gaps
        if not gaps or (now is not None and self._printed is not None
                        and now - self._printed < GAP_LINE_S):
            return
        self._gaps, self._printed = [], now
        if len(gaps) == 1:
            _print_event(gaps[0])
            return
        missing = sum(e.count for e in gaps)
        _log.log(_level(EventKind.GAP), f"gap ({missing:,} samples missing in {len(gaps):,} "
                 f"gaps since {_stamp(gaps[0].time_ns)})", extra={
                      "event": "gap", "count": missing, "gaps": len(gaps),
                      "time_ns": gaps[-1].time_ns})
