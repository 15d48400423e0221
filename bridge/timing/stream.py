"""Time one unit's record batches from the settings that decide timing.

The live pipeline and ``gx3 replay`` both time records through this class, so a
raw capture replays to the very ticks and ``time_ns`` the live bridge published:
the same timeline, told the same things (output period, filter delay, transport
floor, "streaming restarted here") at the same points of the byte stream.

Records' receive times are on the raw monotonic clock: the timeline fits the unit's
clock against it, and ``host`` (each read's realtime offset) puts every instant, and
the completing read's receive time, on the host's realtime clock.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bridge.protocol.codec import Batch
from bridge.protocol.table import PROCESSING_DELAY_S, REPLIES, TICKS_PER_SECOND
from bridge.timing.clock import ClockState
from bridge.timing.offline import OfflineClock
from bridge.timing.realtime import STEP_MIN_NS, ClockChange, RealtimeReads, RealtimeTrack
from bridge.timing.timeline import Timeline
from bridge.timing.unwrap import TimingEvent

USB_FRAME_NS = 1_000_000
USB_BYTE_NS = 1_000  # full-speed USB moves about 1 MB/s of payload
TRANSPORTS = ("uart", "usb", "usb-serial")


def filter_delay_ns(filter_width: int) -> int:
    """The moving average of width M delays the values by (M-1)/2 ms (Equations 2-5).

    Args:
        filter_width: The accel and gyro filter's width M (0xDB ``filter_width``).

    Returns:
        The delay, which every ``time_ns`` has taken out: the instant the values describe.
    """
    return (filter_width - 1) * 500_000


def period_middle_ns(record: int, decimation: int) -> int:
    """How much earlier a record's values are than an instantaneous record's of its cycle.

    DeltaAngle and DeltaVelocity integrate over the output period (``ReplySpec.integral``):
    they describe its middle, half a period before the cycle; other records, 0.

    Args:
        record: The data record.
        decimation: The output period in 1 ms cycles (0xDB ``decimation``).

    Returns:
        The difference, ns.
    """
    return decimation * 500_000 if REPLIES[record].integral else 0


def record_delay_ns(filter_width: int, record: int | None = None, decimation: int = 1) -> int:
    """From the instant a record's values describe to its first byte on the line.

    The filter's delay (``filter_delay_ns``), then the unit's calculation before it sends
    (``PROCESSING_DELAY_S``): the clock model finds when records start on the line, and
    this is what it takes out. A record of integrals over the output period
    (DeltaAngle, DeltaVelocity: ``ReplySpec.integral``) describes the period's middle,
    half a period earlier.

    Args:
        filter_width: The accel and gyro filter's width M (0xDB ``filter_width``).
        record: The data record; None: one of instantaneous values.
        decimation: The output period in 1 ms cycles (0xDB ``decimation``).

    Returns:
        The delay, ns.
    """
    middle = 0 if record is None else period_middle_ns(record, decimation)
    return filter_delay_ns(filter_width) + round(PROCESSING_DELAY_S * 1e9) + middle


@dataclass(frozen=True)
class Settings:
    """What decides a record's timing: its type, the unit's 0xDB settings, the link.

    ``transport`` is one of ``TRANSPORTS``; ``polled``: records come as replies to polls,
    not at the output rate; ``latency_timer_ms``: a USB-serial adapter's, where known.
    """

    record: int
    decimation: int
    filter_width: int
    baud: int
    transport: str = "uart"
    polled: bool = False
    latency_timer_ms: int | None = None  # a USB-serial adapter's, where known

    @property
    def period_ticks(self) -> float | None:
        """Output period in ticks (decimation x 62.5); polled records have none."""
        return None if self.polled else TICKS_PER_SECOND * self.decimation / 1000

    @property
    def frame_ns(self) -> int:
        """The host's USB frame where one carries the bytes (own port or adapter).

        0 on a plain UART.
        """
        return 0 if self.transport == "uart" else USB_FRAME_NS

    @property
    def filter_delay_ns(self) -> int:
        """How long the values lag the record's timer (``filter_delay_ns``)."""
        return filter_delay_ns(self.filter_width)

    @property
    def delay_ns(self) -> int:
        """From the instant the values describe to the record's first byte (``record_delay_ns``)."""
        return record_delay_ns(self.filter_width, self.record, self.decimation)

    @property
    def floor_ns(self) -> int:
        """The least time a record takes to reach the host.

        Its line time on a serial line (a UART, or one behind a USB-serial adapter); on
        the unit's own USB port (the baud setting has no effect there) its transfer at
        full speed's payload rate.
        """
        if self.transport == "usb":
            return REPLIES[self.record].length * USB_BYTE_NS
        return round(REPLIES[self.record].length * 10 / self.baud * 1e9)

    @property
    def serial(self) -> bool:
        """The bytes crossed a serial line before any USB frames (a USB-serial adapter)."""
        return self.transport == "usb-serial"

    def offline_clock(self) -> OfflineClock:
        """The export's second pass for records with these settings.

        Returns:
            An ``OfflineClock`` told the delay, floor and link these settings decide.
        """
        return OfflineClock(self.delay_ns, self.floor_ns, self.frame_ns, serial=self.serial,
                            byte_ns=self.byte_ns, prompt=self.prompt)

    @property
    def prompt(self) -> bool:
        """Whether each USB frame carries every byte that is ready when it is polled.

        The unit's own port hands over each record whole at the first frame after it;
        an adapter does so with a 1 ms latency timer (FTDI's, where set so) or none
        (CDC-ACM bridges), and holds bytes back up to a longer one.
        """
        return self.transport == "usb" or (self.transport == "usb-serial"
                                           and (self.latency_timer_ms or 1) <= 1)

    @property
    def byte_ns(self) -> float:
        """One byte's time on the link.

        10 bits at the baud rate on a serial line (a UART or the line into a USB-serial
        adapter), full speed's payload rate on USB.
        """
        return USB_BYTE_NS if self.transport == "usb" else 10e9 / self.baud

    def part_lead_ns(self, part_bytes: np.ndarray) -> np.ndarray:
        """The line time of a record's first ``part_bytes`` bytes.

        Args:
            part_bytes: Per record, how many of its bytes a read had brought.

        Returns:
            The floor less the time of the bytes still to come (so exactly the floor for a
            whole record), int64 ns.
        """
        missing = REPLIES[self.record].length - np.asarray(part_bytes, np.int64)
        return self.floor_ns - np.round(missing * self.byte_ns).astype(np.int64)


@dataclass
class Timed:
    """One batch's valid records with their ticks, sample instants and receive times.

    ``time_ns`` and ``rx_ns`` are on the realtime clock (the batch's own ``rx_ns`` are the
    raw clock's); ``part``: each record's partial read as an ImuSample carries it
    (``part_rx_mono_raw_ns``, ``part_lead_ns``: the read and the line time of the bytes
    it held, the completing read and the whole record's where there is none); ``events``
    what the timeline found, ``dropped`` samples missing (gaps), ``invalid`` records
    dropped for a corrupt timer.
    """

    batch: Batch
    ticks: np.ndarray
    time_ns: np.ndarray
    rx_ns: np.ndarray
    part: tuple[np.ndarray, np.ndarray]
    events: list[TimingEvent] = field(default_factory=list)
    dropped: int = 0
    invalid: int = 0


@dataclass
class TimedFew:
    """``Timed`` of a live read's record or two, in plain integers."""

    ticks: list[int]
    time_ns: list[int]
    rx_ns: list[int]
    part: tuple[list[int], list[int]]
    events: list[TimingEvent]


class StreamTiming:
    """One timeline for a unit's whole life, from the settings that decide timing.

    Ticks keep increasing across reconnects (a gap or a reset is for the unwrapper to
    find); settings changes update it. ``configure`` before the first batch.

    Args:
        host: Each read's realtime offset: None for a live stream (``hear`` feeds it), a
            capture's reads all at once (``RealtimeReads``).
    """

    def __init__(self, host: RealtimeTrack | RealtimeReads | None = None) -> None:
        #: each read's realtime offset: live, fed by ``hear``; a capture's, all at once
        self.host = RealtimeTrack() if host is None else host
        self.timeline: Timeline | None = None
        self.settings: Settings | None = None
        #: (record length, floor ns, byte ns), with which partial reads time records,
        #: fixed by the settings and so worked out once, not per read
        self._parts = (0, 0, 0.0)
        self._last_ns: int | None = None  # the latest realtime instant given out

    @property
    def state(self) -> ClockState | None:
        """The clock model now, for status (None before ``configure``)."""
        return self.timeline.state if self.timeline else None

    def configure(self, settings: Settings, restarted: bool) -> None:
        """Apply the settings from the next record on.

        Args:
            settings: What decides the records' timing now.
            restarted: The stream began anew here (bring-up, a timer set or reset), so
                the next record may be off the old output lattice.

        Raises:
            ValueError: An unknown transport.
        """
        if settings.transport not in TRANSPORTS:
            raise ValueError(f"transport {settings.transport!r}: use one of {TRANSPORTS}")
        period = settings.period_ticks
        if self.timeline is None:
            self.timeline = Timeline(period, frame_ns=settings.frame_ns, serial=settings.serial,
                                     byte_ns=settings.byte_ns, prompt=settings.prompt)
        elif restarted or period != self.timeline.unwrapper.period_ticks:
            self.timeline.expect_discontinuity(period)
        clock = self.timeline.clock
        clock.delay_ns, clock.floor_ns = settings.delay_ns, settings.floor_ns
        clock.byte_ns, clock.prompt = settings.byte_ns, settings.prompt
        self.settings = settings
        self._parts = (REPLIES[settings.record].length, settings.floor_ns, settings.byte_ns)

    def hear(self, raws: list[int], reals: list[int]) -> list[ClockChange]:
        """The next reads' stamps on both clocks, before their records are processed.

        Args:
            raws: Their receive times on the raw monotonic clock.
            reals: The same instants on the realtime clock.

        Returns:
            The host clock's steps and slews they show.
        """
        assert isinstance(self.host, RealtimeTrack), "a capture's reads come all at once"
        return self.host.add(raws, reals)

    def process(self, batch: Batch) -> Timed:
        """Ticks and host times of a batch's records; corrupt timers are dropped.

        A record's partial read, where the framer saw one, bounds its instant too.

        Args:
            batch: The next records of the stream, their ``rx_ns`` on the raw clock.

        Returns:
            The valid records with their ticks and realtime instants, and the events.
        """
        assert self.timeline is not None and self.settings is not None, "configure() first"
        if batch.part_ns is None or batch.part_bytes is None:
            timed = self.timeline.update(batch["timer"], batch.rx_ns)
        else:
            timed = self.timeline.update(batch["timer"], batch.rx_ns, batch.part_ns,
                                         self.settings.part_lead_ns(batch.part_bytes))
        keep = timed.valid
        invalid = 0 if timed.intact else int((~keep).sum())
        if invalid:
            batch = batch.select(keep)
        map_array = self.host.map_array
        instants = map_array(timed.time_ns[keep], batch.rx_ns)
        later = np.diff(instants) if self._last_ns is None else \
            np.diff(instants, prepend=[self._last_ns])
        if ((later <= 0) & (later > -STEP_MIN_NS)).any():  # rare: see _onward
            instants = np.array(self._onward(instants.tolist()), np.int64)
        elif len(instants):
            self._last_ns = int(instants[-1])
        return Timed(batch, timed.ticks[keep], instants,
                     map_array(batch.rx_ns, batch.rx_ns), self._carried(batch), timed.events,
                     timed.dropped, invalid)

    def _onward(self, instants: list[int]) -> list[int]:
        """Realtime instants that go back only where the host's clock was stepped back.

        The clock model's instants only move forward (``OnlineClock``), but each is put on
        the realtime clock with the offset of the read that completed its record, known
        to the few µs the two stamps of a read are apart. Where the model gives records
        instants 1 ns apart (a refit that lowered the line), a later read's offset can
        put a later record before an earlier one. A move back of less than
        ``STEP_MIN_NS`` is such a wobble, and the record gets the least later instant; a
        step of the host's clock is ``STEP_MIN_NS`` or more, named, and kept.
        """
        last = self._last_ns
        for i, value in enumerate(instants):
            if last is not None and last - STEP_MIN_NS < value <= last:
                value = instants[i] = last + 1
            last = value
        self._last_ns = last
        return instants

    def _carried(self, batch: Batch) -> tuple[np.ndarray, np.ndarray]:
        """The records' partial reads as their ImuSamples carry them (``Timed.part``)."""
        assert self.settings is not None
        part_ns, part_bytes = batch.partial()
        return part_ns, self.settings.part_lead_ns(part_bytes)

    def process_few(self, timers: list[int], rx_ns: list[int],
                    part_ns: list[int] | None = None, part_bytes: list[int] | None = None
                    ) -> TimedFew | None:
        """``process`` of a live read's record or two in plain integers.

        Args:
            timers: The records' timers.
            rx_ns: The raw receive time of the read that completed each.
            part_ns: The records' partial reads, if they have them.
            part_bytes: The record's bytes each partial read had brought.

        Returns:
            Their ticks, instants and receive times, when every one is intact and one
            period after the last; None: nothing changed, ``process`` them.
        """
        assert self.timeline is not None and self.settings is not None, "configure() first"
        length, floor, byte_ns = self._parts  # as Settings.part_lead_ns, in integers
        if part_ns is None or part_bytes is None:
            run = self.timeline.update_few(timers, rx_ns)
            carried = (rx_ns, [floor] * len(rx_ns))
        else:
            leads = [floor - round((length - k) * byte_ns) for k in part_bytes]
            run = self.timeline.update_few(timers, rx_ns, (part_ns, leads))
            carried = (part_ns, leads)
        if run is None:
            return None
        ticks, instants, events = run
        host = self.host.map
        return TimedFew(ticks, self._onward(host(instants, rx_ns)), host(rx_ns, rx_ns), carried,
                        events)
