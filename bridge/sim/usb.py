"""How a unit's bytes reach the host over the links a GX3 is really connected by.

Three links, all driven by explicit host times, so they serve virtual-time captures
and a live transport alike: ``push`` bytes the unit finished sending, then ask
``reads(now)`` for the reads that completed by ``now``. Deterministic from a seed. On
every link the reading thread wakes an OS latency after bytes reach the driver and
reads everything the driver holds by then, and now and then the host stalls; latency
only ever delays. The link models in full: ``docs/design/emulator.md``.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from bridge.device.link import ADAPTER_PACKET_BYTES, DEFAULT_LATENCY_TIMER_MS
from bridge.sim.unit import STEP_SLACK

_DRAW_BLOCK = 4096


@dataclass(frozen=True, kw_only=True)
class HostDelivery:
    """What every link shares on the host: OS latency and stalls (seconds).

    The reading thread wakes an exponential OS latency after bytes reach the driver and
    reads everything the driver holds by then, so serial reads often end mid-record;
    now and then the host ignores the port for a while (a stall), and the next read
    returns the whole backlog.

    Attributes:
        os_latency_mean_s: The mean OS latency.
        stall_every_s: Mean seconds between stalls; 0: none.
        stall_min_s: The shortest stall.
        stall_max_s: The longest stall.
        seed: Seeds the latencies and stalls.

    Raises:
        ValueError: A negative latency or interval, or stall lengths out of order.
    """

    transport: ClassVar[str] = "uart"
    os_latency_mean_s: float = 0.0003
    stall_every_s: float = 20.0
    stall_min_s: float = 0.005
    stall_max_s: float = 0.040
    seed: int = 0

    def __post_init__(self) -> None:
        if self.os_latency_mean_s < 0 or self.stall_every_s < 0:
            raise ValueError("delivery: latency and stall interval must be non-negative "
                             "(stall_every_s=0 means no stalls)")
        if not 0 <= self.stall_min_s <= self.stall_max_s:
            raise ValueError("delivery: need 0 <= stall_min_s <= stall_max_s")


@dataclass(frozen=True, kw_only=True)
class UartDelivery(HostDelivery):
    """A plain UART: each byte reaches the driver as it crosses the line."""


@dataclass(frozen=True, kw_only=True)
class UsbDelivery(HostDelivery):
    """The unit's own USB port: the host's frame grid on top of latency and stalls.

    The host controller polls the device once per frame on the host's clock, and the unit
    hands it whole records, so a record finished at t reaches the driver at the first
    frame boundary at or after t.

    Attributes:
        frame_s: The frame period (1 ms: full speed).
        frame_phase_s: Where the host's frame grid starts, host seconds.

    Raises:
        ValueError: ``frame_s`` is not positive.
    """

    transport: ClassVar[str] = "usb"
    frame_s: float = 0.001
    frame_phase_s: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.frame_s <= 0:
            raise ValueError("delivery: frame_s must be positive")


@dataclass(frozen=True, kw_only=True)
class AdapterDelivery(UsbDelivery):
    """A USB-serial adapter (FTDI-like) between the unit's serial line and the host's frames.

    Bytes cross the unit's serial line at its baud rate into the adapter's buffer. At
    each frame's poll the adapter sends full packets while it holds that many, and
    everything it holds once its latency timer (restarted by every packet it sends) has
    expired; otherwise it answers nothing.

    Attributes:
        latency_timer_s: The adapter's latency timer (1 or 16 ms, as drivers set it).
        packet_bytes: Payload bytes in a packet (62: 64 less 2 status bytes).

    Raises:
        ValueError: ``latency_timer_s`` or ``packet_bytes`` is not positive.
    """

    transport: ClassVar[str] = "usb-serial"
    latency_timer_s: float = DEFAULT_LATENCY_TIMER_MS / 1000
    packet_bytes: int = ADAPTER_PACKET_BYTES

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.latency_timer_s <= 0 or self.packet_bytes <= 0:
            raise ValueError("delivery: latency_timer_s and packet_bytes must be positive")


class _Chunk:
    """Bytes back to back: byte i is there at ``t0 + i * byte_s``; ``taken`` are gone."""

    __slots__ = ("byte_s", "data", "t0", "taken")

    def __init__(self, t0: float, byte_s: float, data: bytes) -> None:
        self.t0, self.byte_s, self.data, self.taken = t0, byte_s, data, 0

    def ready(self, t: float) -> int:
        """How many of the chunk's bytes are there by ``t`` (taken ones included)."""
        if not self.byte_s:
            return len(self.data) if t >= self.t0 else 0
        return max(0, min(len(self.data), math.floor((t - self.t0) / self.byte_s + STEP_SLACK) + 1))

    def at(self, i: int) -> float:
        """When byte ``i`` is there."""
        return self.t0 + i * self.byte_s

    @property
    def last(self) -> float:
        return self.at(len(self.data) - 1)


class HostDriver:
    """The host's side: bytes wait in the driver until the reading thread wakes."""

    def __init__(self, config: HostDelivery, start: float) -> None:
        self.config: HostDelivery = config
        self._latency = np.random.default_rng([config.seed, 1])
        self._drawn: list[float] = []  # latencies drawn ahead, in the order drawn
        self._next_drawn = 0
        self._stalls = np.random.default_rng([config.seed, 2])
        self._pending: deque[_Chunk] = deque()
        self._wake: float | None = None
        self._stall = (start, start)
        self._next_stall(start)
        self.stalls = 0

    def push(self, data: bytes, finished: float, byte_s: float = 0.0) -> None:
        """Hand over bytes the unit sent back to back.

        One every ``byte_s``, the last finished by host time ``finished``.
        """
        raise NotImplementedError

    def _advance(self, now: float) -> None:
        """Hand the driver what reached it by ``now`` (a link between line and driver)."""

    def reads(self, now: float) -> list[tuple[float, bytes]]:
        """Every read that completed by ``now``: (host time of the read, bytes)."""
        self._advance(now)
        out: list[tuple[float, bytes]] = []
        while self._pending:
            if self._wake is None:
                head = self._pending[0]
                self._wake = self._unstalled(head.at(head.taken) + self._os_latency())
            if self._wake > now:
                break
            chunks = []
            while self._pending:
                head = self._pending[0]
                n = head.ready(self._wake)
                if n > head.taken:
                    chunks.append(head.data[head.taken : n])
                    head.taken = n
                if n < len(head.data):
                    break
                self._pending.popleft()
            out.append((self._wake, b"".join(chunks)))
            self._wake = None
        return out

    def _os_latency(self) -> float:
        """The next read's OS latency.

        Drawn a block at a time (the same numbers as one at a time), since a UART capture
        makes a read every few bytes.
        """
        mean = self.config.os_latency_mean_s
        if not mean:
            return 0.0
        if self._next_drawn == len(self._drawn):
            self._drawn = self._latency.exponential(mean, _DRAW_BLOCK).tolist()
            self._next_drawn = 0
        self._next_drawn += 1
        return self._drawn[self._next_drawn - 1]

    def _next_stall(self, after: float) -> None:
        c = self.config
        if not c.stall_every_s:
            self._stall = (math.inf, math.inf)
            return
        begin = after + float(self._stalls.exponential(c.stall_every_s))
        self._stall = (begin, begin + float(self._stalls.uniform(c.stall_min_s, c.stall_max_s)))

    def _unstalled(self, t: float) -> float:
        """A read due during a stall happens when the stall ends."""
        while self._stall[1] <= t:
            self._next_stall(self._stall[1])
        if self._stall[0] <= t:
            self.stalls += 1
            return self._stall[1]
        return t


class UartLink(HostDriver):
    """A serial port: each byte is the driver's as soon as it has crossed the line."""

    def __init__(self, config: UartDelivery, start: float = 0.0) -> None:
        super().__init__(config, start)
        self._line_end = -math.inf

    def push(self, data: bytes, finished: float, byte_s: float = 0.0) -> None:
        """Hand over bytes the unit sent back to back (see ``HostDriver.push``)."""
        if data:
            chunk = _line_chunk(data, finished, byte_s, self._line_end)
            self._line_end = chunk.last
            self._pending.append(chunk)


class UsbLink(HostDriver):
    """Native USB: bytes reach the driver at the frame after they finished."""

    def __init__(self, config: UsbDelivery, start: float = 0.0) -> None:
        super().__init__(config, start)
        self.usb = config

    def frame_index(self, t: float) -> int:
        """The index of the first frame boundary at or after host time ``t``."""
        c = self.usb
        return math.ceil((t - c.frame_phase_s) / c.frame_s - STEP_SLACK)

    def frame_time(self, k: float) -> float:
        """The host time of frame boundary ``k``."""
        return self.usb.frame_phase_s + k * self.usb.frame_s

    def frame_at(self, t: float) -> float:
        """The first frame boundary at or after host time ``t``."""
        return self.frame_time(self.frame_index(t))

    def push(self, data: bytes, finished: float, byte_s: float = 0.0) -> None:
        """Hand over a record the unit finished at ``finished`` (see ``HostDriver.push``).

        The unit's own port hands the host controller whole records: the record reaches
        the driver at the first frame boundary at or after its last byte, never split.
        """
        if data:
            self._pending.append(_Chunk(self.frame_at(finished), 0.0, data))


class AdapterLink(UsbLink):
    """A USB-serial adapter: the unit's line into its buffer, packets out at frames."""

    def __init__(self, config: AdapterDelivery, start: float = 0.0) -> None:
        super().__init__(config, start)
        self.adapter = config
        self._line: deque[_Chunk] = deque()
        self._line_end = -math.inf
        self._frame = self.frame_index(start)  # the next poll not yet answered
        self._sent = -math.inf  # frame index of the last packet (the timer has expired)
        self.packets = 0

    def push(self, data: bytes, finished: float, byte_s: float = 0.0) -> None:
        """Hand over bytes the unit sent back to back (see ``HostDriver.push``)."""
        if data:
            chunk = _line_chunk(data, finished, byte_s, self._line_end)
            self._line_end = chunk.last
            self._line.append(chunk)

    def _advance(self, now: float) -> None:
        c = self.adapter
        timer_frames = c.latency_timer_s / c.frame_s - STEP_SLACK
        while self._line and self.frame_time(self._frame) <= now:
            frame = self.frame_time(self._frame)
            held = self._held(frame)
            expired = self._frame - self._sent >= timer_frames
            if held >= c.packet_bytes or (expired and held):
                self._send(frame, held if expired else held - held % c.packet_bytes)
                self._sent = self._frame
                self._frame += 1
                continue
            # Nothing to send: skip to the poll at which the buffer fills a packet or
            # the timer finds a byte waiting.
            # Bytes pushed later can only fill the buffer sooner: never skip past ``now``.
            full = self._arrival(c.packet_bytes)
            timer = max(self.frame_time(self._sent) + c.latency_timer_s, self._arrival(1))
            after = self.frame_index(now)
            if self.frame_time(after) <= now:
                after += 1
            self._frame = max(self._frame + 1, min(self.frame_index(min(full, timer)), after))

    def _held(self, t: float) -> int:
        return sum(chunk.ready(t) - chunk.taken for chunk in self._line)

    def _arrival(self, count: int) -> float:
        """When the adapter will hold ``count`` unsent bytes (inf: never, as things stand)."""
        for chunk in self._line:
            left = len(chunk.data) - chunk.taken
            if left >= count:
                return chunk.at(chunk.taken + count - 1)
            count -= left
        return math.inf

    def _send(self, frame: float, count: int) -> None:
        out = []
        self.packets += -(-count // self.adapter.packet_bytes)
        while count:
            chunk = self._line[0]
            n = min(count, len(chunk.data) - chunk.taken)
            out.append(chunk.data[chunk.taken : chunk.taken + n])
            chunk.taken += n
            count -= n
            if chunk.taken == len(chunk.data):
                self._line.popleft()
        self._pending.append(_Chunk(frame, 0.0, b"".join(out)))


def _line_chunk(data: bytes, finished: float, byte_s: float, after: float) -> _Chunk:
    """Bytes that crossed a serial line back to back, never before the line's last byte.

    A live transport learns of bytes late, in runs.
    """
    return _Chunk(max(finished - (len(data) - 1) * byte_s, after), byte_s, data)


def link_for(delivery: HostDelivery, start: float = 0.0) -> HostDriver:
    """The link model a delivery describes."""
    if isinstance(delivery, AdapterDelivery):
        return AdapterLink(delivery, start)
    if isinstance(delivery, UsbDelivery):
        return UsbLink(delivery, start)
    if isinstance(delivery, UartDelivery):
        return UartLink(delivery, start)
    raise TypeError(f"no link model for {type(delivery).__name__}")
