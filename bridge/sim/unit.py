"""One emulated 3DM-GX3: the device's behaviour in time, with no I/O.

A transport hands it the bytes the host sent (``receive``) and asks for the bytes that
have finished crossing the line by a given host time (``poll``); everything else
follows the manual, from the command table. Time is host monotonic seconds throughout;
the unit's clock is derived from it. How it follows the manual, and where it had to
choose: ``docs/design/emulator.md``.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, overload

import numpy as np

from bridge.protocol.codec import command_length, encode_replies, encode_reply, parse_command
from bridge.protocol.convert import wake_time_seconds
from bridge.protocol.table import (
    CALCULATION_CYCLE_S,
    DATA_CODES,
    ERROR_REPLY,
    PROCESSING_DELAY_S,
    REPLIES,
    STATIONARY_TEST_BITS,
    TICKS_PER_SECOND,
    Command,
    Flag,
    Mode,
)
from bridge.sim import state
from bridge.sim.clock import UnitClock
from bridge.sim.motion import Motion, MotionConfig, SignalChain
from bridge.sim.state import USER_EEPROM, Sampling, Stored

_HALF_TICKS_PER_CYCLE = 2 * TICKS_PER_SECOND // 1000  # 62.5 ticks a cycle, counted in halves
# Continuous records are computed in vectorised blocks up to LOOKAHEAD_S ahead.
# A transport spreads that work over its units with ``plan``; ``poll`` plans
# itself only when less than URGENT_S is left.
LOOKAHEAD_S = 0.1
URGENT_S = 0.005
# Host times are monotonic seconds since boot: after months of uptime a float64 holds
# them to ~1 ns, and a device -> host -> device round trip is off by a few of those.
# Comparisons allow this much, far below a cycle (1 ms) or a byte's line time (>= 10 us):
# in seconds, or as a fraction of the step counted (a cycle, a byte, a USB frame).
_SLACK_S = 1e-7
STEP_SLACK = 1e-6
# The manual gives no inter-byte timeout; a partial command older than this is dropped,
# so that bytes cut short by an unplug do not swallow the next session's first command.
INTER_BYTE_TIMEOUT_S = 0.1
USB_LINE_BAUD = 12_000_000
# An awake unit sets every self-test bit the manual names, in every mode. The 5 V flag
# that drops in idle mode has no bit number in the manual.
STATIONARY_TEST_OK = sum(1 << bit for bit in STATIONARY_TEST_BITS)
_ORIENTATION_FIELDS = ("m", "c", "euler", "quaternion", "stab_accel", "stab_mag")
_MAG_FIELDS = ("mag", "stab_mag")
_RAW_FIELDS = ("raw_accel", "raw_ang_rate", "temperature")


@dataclass(frozen=True)
class UnitConfig:
    """Identity, clock and motion of one unit; ``stored`` is its factory memory.

    Attributes:
        serial: Its serial number, as 0xEA reports it (selector 1).
        model_number: Its model number (0xEA selector 0).
        model_name: Its model name (0xEA selector 2).
        options: Its options, such as the sensor ranges (0xEA selector 3).
        lot: Its lot (0xEA selector 4).
        firmware: Its firmware version as 0xE9 reports it (1127: 1.1.27).
        timer_start: The timer's value at power-up.
        clock_ppm: The constant rate error of its clock, ppm.
        clock_wander_ppm: The most a slow, smooth wander adds to that error, ppm.
        clock_wander_period_s: The time scale of the wander, s.
        clock_seed: Seeds the wander.
        motion: What the unit experiences.
        stored: Its non-volatile memory as it left the factory.
        state_file: Where its non-volatile memory is kept across runs (it starts from
            the file when there is one); None: in memory only.
        truth_length: Records whose truth is kept (``SimUnit.truth``).
        filter_model: Whether its filters (``SignalChain``) are modelled: their delay
            and their averaging of the noise.
        usb: On its own USB port: the baud rate has no effect on the line, and a record
            goes to the host whole, once its last byte is in the port's buffer.
        processing_delay_s: From the end of a record's cycle to its first byte on the line.
        link_latency_s: A constant delay its link adds each way (a long cable, a
            converter, a wireless serial link): one that no clock model can see.
    """

    serial: str = "SIM0001"
    model_number: str = "6225-4220"
    model_name: str = "3DM-GX3-25"
    options: str = "5g 300d/s"
    lot: str = "SIM"
    firmware: int = 1127
    timer_start: int = 0
    clock_ppm: float = 0.0
    clock_wander_ppm: float = 0.0
    clock_wander_period_s: float = 300.0
    clock_seed: int = 0
    motion: MotionConfig = field(default_factory=MotionConfig)
    stored: Stored = field(default_factory=Stored)
    state_file: Path | None = None
    truth_length: int = 100_000
    filter_model: bool = True
    usb: bool = False  # on its own USB port: the baud rate has no effect on the line
    processing_delay_s: float = PROCESSING_DELAY_S
    link_latency_s: float = 0.0

    def id_string(self, selector: int) -> str:
        """The device ID string 0xEA reports.

        Args:
            selector: 0 model number, 1 serial, 2 model name, 3 options, 4 lot.

        Returns:
            The string.
        """
        return (self.model_number, self.serial, self.model_name, self.options, self.lot)[selector]


#: One record's truth: its cycle's instant (host wall clock, ns), the instant its values
#: describe (ns, earlier by the filter delay, and for integrals over the output period
#: by half that period more), device time of the cycle (s), timer, record type, and the
#: true attitude quaternion at the end of the filter's delay (scalar first, earth to
#: sensor).
TruthRow = tuple[int, int, float, int, int, np.ndarray]


class TruthLog:
    """What the last ``capacity`` records really were, kept as columns.

    Columns, not an object per record: a fleet at 1 kHz would otherwise fill the
    heap with millions of objects and stall the emulator in garbage collection.
    Rows wait in a short list and go into the columns a few hundred at a time (a row
    at a time cost a fleet of 16 units at 1 kHz 3 % of a core). Safe to read from
    another thread while the unit runs.

    Args:
        capacity: Records kept at most; older ones make way.
    """

    _BATCH = 256

    def __init__(self, capacity: int) -> None:
        self._columns: dict[str, np.ndarray] = {
            "time_ns": np.zeros(capacity, np.int64),
            "value_ns": np.zeros(capacity, np.int64),
            "device_s": np.zeros(capacity),
            "timer": np.zeros(capacity, np.uint32),
            "code": np.zeros(capacity, np.uint8),
            "quaternion": np.zeros((capacity, 4)),
        }
        self._capacity = capacity
        self._written = 0
        self._rows: list[TruthRow] = []
        self._lock = threading.Lock()

    def append(self, row: TruthRow) -> None:
        """Keep the truth of one record sent.

        Args:
            row: The record's truth (see ``TruthRow``).
        """
        with self._lock:
            self._rows.append(row)
            if len(self._rows) >= self._BATCH:
                self._store()

    def _store(self) -> None:
        """Put the waiting rows into the columns (caller holds the lock).

        Only the last ``capacity`` of them can be kept.
        """
        rows = self._rows[-self._capacity :]
        at = (self._written + len(self._rows) - len(rows) + np.arange(len(rows))) \
            % self._capacity
        for column, values in zip(self._columns.values(), zip(*rows, strict=True),
                                  strict=True):
            column[at] = values
        self._written += len(self._rows)
        self._rows = []

    def __len__(self) -> int:
        with self._lock:
            return min(self._written + len(self._rows), self._capacity)

    def arrays(self) -> dict[str, np.ndarray]:
        """The records kept, as columns.

        Returns:
            Copies of every column, oldest record first: ``time_ns`` (host ns of the
            record's calculation cycle), ``value_ns`` (host ns of the instant its values
            describe: ``time_ns`` less the filter delay, and for DeltaAngle and
            DeltaVelocity, integrals over the output period, half that period more),
            ``device_s``, ``timer``, ``code`` and ``quaternion`` (the true attitude at
            ``time_ns`` less the filter delay, scalar first, earth to sensor).
        """
        with self._lock:
            if self._rows:
                self._store()
            n, start = min(self._written, self._capacity), self._written % self._capacity
            order = np.arange(start - n, start) % self._capacity
            return {name: column[order] for name, column in self._columns.items()}


class _Segment:
    """Bytes leaving the unit back to back from ``start`` at ``baud``.

    An empty segment marks a continuous record skipped because the line was busy.
    """

    __slots__ = ("baud", "data", "rate", "sent", "start", "truth")

    def __init__(self, start: float, data: bytes, baud: int, truth: TruthRow | None) -> None:
        self.start, self.data, self.baud, self.truth, self.sent = start, data, baud, truth, 0
        self.rate = baud / 10.0

    @property
    def end(self) -> float:
        return self.start + len(self.data) / self.rate


def _monotonic_to_wall_ns() -> int:
    """Wall clock minus monotonic clock, from readings taken together.

    Not from a ``now`` captured earlier, which would put every ground-truth time late.
    """
    return time.time_ns() - time.monotonic_ns()


class SimUnit:
    """The device model. Not thread-safe: one transport thread drives it.

    Commands are answered from the command table at the end of the next 1 ms calculation
    cycle, one per cycle; the line carries baud/10 bytes per second, and a continuous
    record that finds it busy is skipped; the timer runs at 62,500 ticks per second of
    the unit's own clock, which is off by ``clock_ppm``. Continuous records are computed
    a little ahead in vectorised blocks, and the part of that plan not yet started is
    dropped whenever a command changes state.

    Args:
        config: The unit.
        now: Host monotonic seconds at power-up; None: now.
        wall_ns: Wall clock minus host monotonic clock, ns, for the truth's host times;
            None: this host's, read now.

    Raises:
        StateFileError: ``config.state_file`` is there but not a unit's state.
    """

    def __init__(self, config: UnitConfig, now: float | None = None,
                 wall_ns: int | None = None) -> None:
        now = time.monotonic() if now is None else now
        self.config = config
        self.motion = Motion(config.motion, None if config.motion.mounting is None
                             else self._body_time)
        self.stored = state.load(config.state_file, config.stored)
        self._t0 = now
        self._clock = UnitClock(now, config.clock_ppm, config.clock_wander_ppm,
                                config.clock_wander_period_s, config.clock_seed)
        self._wall_offset_ns = _monotonic_to_wall_ns() if wall_ns is None else wall_ns
        self._scale = 1.0 + config.clock_ppm * 1e-6
        self.truth = TruthLog(config.truth_length)
        self.records_skipped = 0
        self.records_sent = 0
        self._plan: deque[_Segment] = deque()
        self._line_free = now
        self._sent_until = now
        self._new_phase = False
        self._inbox = bytearray()
        self._last_byte = now
        self._queue: deque[tuple[float, bytes]] = deque()
        self._busy_until = now
        self._sleep_timer = 0
        self.state_error: OSError | None = None
        self._restart(now, config.timer_start)

    # --- clock -------------------------------------------------------------------------
    @overload
    def device_time(self, host: float) -> float: ...
    @overload
    def device_time(self, host: np.ndarray) -> np.ndarray: ...
    def device_time(self, host: Any) -> Any:
        """Device seconds at host time ``host``, counted from the unit's start.

        Args:
            host: Host monotonic seconds: a float, or an array.

        Returns:
            Device seconds, a float or an array as ``host`` is.
        """
        if self._clock.wanders:
            return self._clock.device(host)
        return (host - self._t0) * self._scale

    @overload
    def host_time(self, device: float) -> float: ...
    @overload
    def host_time(self, device: np.ndarray) -> np.ndarray: ...
    def host_time(self, device: Any) -> Any:
        """Host time at device seconds ``device``: the inverse of ``device_time``.

        Args:
            device: Device seconds: a float, or an array.

        Returns:
            Host monotonic seconds, a float or an array as ``device`` is.
        """
        if self._clock.wanders:
            return self._clock.host(device)
        return self._t0 + device / self._scale

    def _host_times(self, device: np.ndarray) -> np.ndarray:
        """``host_time`` at many instants: its arithmetic takes arrays as they are."""
        return np.asarray(self.host_time(device))

    def _cycle_after(self, host: float) -> int:
        """Index of the first calculation cycle ending at or after ``host``."""
        return math.ceil(float(self.device_time(host)) / CALCULATION_CYCLE_S - STEP_SLACK)

    def _cycle_at(self, host: float) -> int:
        """The calculation cycle nearest ``host`` (events happen on cycle boundaries)."""
        return round(float(self.device_time(host)) / CALCULATION_CYCLE_S)

    def timer_at(self, cycles: np.ndarray | int) -> np.ndarray:
        """The timer at cycle boundaries: 62.5 ticks a cycle, rounded half up, exactly.

        Args:
            cycles: Indexes of calculation cycles.

        Returns:
            The timer at the end of each, uint32.
        """
        elapsed = np.asarray(cycles, np.int64) - self._timer_epoch
        ticks = (elapsed * _HALF_TICKS_PER_CYCLE + 1) >> 1
        return ((ticks + self._timer_value) & 0xFFFF_FFFF).astype(np.uint32)

    def _set_timer(self, host: float, value: int) -> None:
        self._timer_epoch = self._cycle_at(host)
        self._timer_value = value

    # --- state -------------------------------------------------------------------------
    def power_cycle(self, now: float) -> None:
        """Power returns at ``now`` (a USB-powered unit replugged): it boots from scratch.

        Args:
            now: Host monotonic seconds.
        """
        self._plan.clear()
        self._line_free = self._sent_until = self._busy_until = now
        self._restart(now, 0)

    def _restart(self, at: float, timer_value: int) -> None:
        """Power-on or reset: input is dropped, output starts after Equation 1's settling."""
        self._inbox.clear()
        self._queue.clear()
        self._boot(at, timer_value,
                   at + float(wake_time_seconds(self.stored.sampling.filter_width)))

    def _boot(self, host: float, timer_value: int, ready: float) -> None:
        """Power-up, reset or wake from deep sleep: RAM reloads from non-volatile memory."""
        self._set_timer(host, timer_value)
        s = self.stored
        self.sampling = s.sampling
        self.baud = s.baud
        self.accel_bias = np.array(s.accel_bias)
        self.gyro_bias = np.array(s.gyro_bias)
        self._ready = ready
        self._wake(Mode(s.mode_preset))

    def _wake(self, preset: Mode) -> None:
        self.continuous_command = self.stored.continuous_preset
        if preset == Mode.CONTINUOUS and self.continuous_command == 0:
            preset = Mode.ACTIVE
        self.mode = preset
        self._stream_from = self._ready
        self._stream_phase = self._cycle_after(self._ready)

    @property
    def line_baud(self) -> int:
        """The pace of the line: the UART's baud rate, or USB full speed (12 Mbit/s)."""
        return USB_LINE_BAUD if self.config.usb else self.baud

    @property
    def little_endian(self) -> bool:
        """Whether it sends floats little-endian (a flag of its sampling settings)."""
        return bool(self.sampling.flags & Flag.LITTLE_ENDIAN_FLOATS)

    @property
    def period(self) -> float:
        """Seconds between continuous records: the decimation's cycles."""
        return self.sampling.decimation * CALCULATION_CYCLE_S

    def _persist(self, **changes: Any) -> None:
        """Keep the change; a file that cannot be written is kept in ``state_error``, once."""
        self.stored = replace(self.stored, **changes)
        try:
            state.save(self.config.state_file, self.stored)
        except OSError as exc:
            if self.state_error is None:
                self.state_error = exc

    # --- transport interface -------------------------------------------------------------
    def receive(self, data: bytes, now: float) -> None:
        """Take bytes from the host.

        Args:
            data: The bytes.
            now: When they arrived, host monotonic seconds (its link's latency later
                they reach the unit).
        """
        now += self.config.link_latency_s
        if now < self._ready or not data:
            return
        if self.mode in (Mode.SLEEP, Mode.DEEP_SLEEP):
            self._wake_up(now)
            return
        if now - self._last_byte > INTER_BYTE_TIMEOUT_S:
            self._inbox.clear()
        self._last_byte = now
        self._inbox += data
        while self._inbox:
            size = command_length(self._inbox[0])
            if size is None:
                del self._inbox[0]
                continue
            if len(self._inbox) < size:
                break
            self._queue.append((now, bytes(self._inbox[:size])))
            del self._inbox[:size]

    def poll(self, now: float) -> bytes:
        """Run the unit up to ``now``.

        Args:
            now: Host monotonic seconds; not before the last call's.

        Returns:
            The bytes that finished crossing the line since the last call.
        """
        return b"".join(data for _, data in self.poll_line(now))

    def poll_line(self, now: float) -> list[tuple[int, bytes]]:
        """As ``poll``, with the baud rate each run of bytes went out at (0xD9 changes it).

        Args:
            now: Host monotonic seconds; not before the last call's.

        Returns:
            (baud, bytes) runs, in the order they went out: those that finished crossing
            the line its link's latency before ``now``.
        """
        while self._queue:
            arrived, raw = self._queue[0]
            at = self.host_time(max(self._cycle_after(arrived), self._cycle_after(self._busy_until))
                                * CALCULATION_CYCLE_S)
            if at > now:
                break
            self._queue.popleft()
            self._busy_until = at + CALCULATION_CYCLE_S
            self._execute(raw, at)
        if self.planned_until < now + URGENT_S:
            self.plan(now)
        return self._transmit(now - self.config.link_latency_s)

    @property
    def planned_until(self) -> float:
        """Host time up to which continuous output is computed (inf when not streaming)."""
        streaming = self.mode == Mode.CONTINUOUS and self.continuous_command in DATA_CODES
        return self._stream_from if streaming else math.inf

    def plan(self, now: float) -> None:
        """Compute continuous output up to ``LOOKAHEAD_S`` past ``now``.

        Args:
            now: Host monotonic seconds.
        """
        self._plan_stream(now + LOOKAHEAD_S)

    # --- output --------------------------------------------------------------------------
    def _schedule(self, at: float, data: bytes, truth: TruthRow | None = None,
                  skippable: bool = False) -> None:
        """Queue bytes for the line; a skippable record that finds the line busy is lost."""
        if at < self._line_free - _SLACK_S:
            if skippable:
                self._plan.append(_Segment(at, b"", self.line_baud, None))
                return
            at = self._line_free
        seg = _Segment(at, data, self.line_baud, truth)
        self._plan.append(seg)
        self._line_free = seg.end

    def _cancel_after(self, at: float) -> None:
        """Forget planned output that has not started by ``at`` (state changed then)."""
        while self._plan and self._plan[-1].start > at and self._plan[-1].sent == 0:
            self._plan.pop()
        busy = [seg.end for seg in self._plan if seg.data]
        self._line_free = max(at, self._sent_until, *busy)

    def _transmit(self, now: float) -> list[tuple[int, bytes]]:
        out: list[tuple[int, bytes]] = []
        while self._plan and self._plan[0].start <= now:
            seg = self._plan[0]
            if not seg.data:
                self.records_skipped += 1
                self._plan.popleft()
                continue
            if seg.truth is not None:
                self.truth.append(seg.truth)
                self.records_sent += 1
                seg.truth = None
            done = min(len(seg.data), int((now - seg.start) * seg.rate + STEP_SLACK))
            if self.config.usb and done < len(seg.data):
                done = seg.sent  # its own USB port hands the host a record whole
            if done > seg.sent:
                chunk = seg.data[seg.sent : done]
                if out and out[-1][0] == seg.baud:
                    out[-1] = (seg.baud, out[-1][1] + chunk)
                else:
                    out.append((seg.baud, chunk))
            seg.sent = done
            if done < len(seg.data):
                break
            self._sent_until = seg.end
            self._plan.popleft()
        return out

    # --- continuous mode -----------------------------------------------------------------
    def _plan_stream(self, horizon: float) -> None:
        if self.planned_until == math.inf:
            return
        first = max(self._cycle_after(self._stream_from), self._cycle_after(self._ready))
        step = self.sampling.decimation
        k0 = self._stream_phase
        first = k0 + math.ceil((first - k0) / step) * step
        last = self._cycle_after(horizon)
        if first > last:
            return
        cycles = np.arange(first, last + 1, step)
        code = self.continuous_command
        records, truths = self._records(code, cycles)
        size = REPLIES[code].length
        delay = self.config.processing_delay_s
        for i, at in enumerate(self._host_times(cycles * CALCULATION_CYCLE_S).tolist()):
            self._schedule(at + delay, records[i * size : (i + 1) * size], truths[i],
                           skippable=True)
        self._stream_from = float(self.host_time((cycles[-1] + 1) * CALCULATION_CYCLE_S))

    def _start_stream(self, code: int, at: float) -> None:
        """Stream ``code`` from the first cycle after this command's reply."""
        self.mode = Mode.CONTINUOUS
        self.continuous_command = code
        self._new_phase = True

    def signal_chain(self) -> SignalChain:
        """What its filters do now, from its sampling settings (``SignalChain``).

        Without the filter model: a bare sensor's widths of 1 (no delay, no averaging).

        Returns:
            The chain.
        """
        s = self.sampling
        coning = bool(s.flags & Flag.CONING_SCULLING)
        if not self.config.filter_model:
            return SignalChain(coning_sculling=coning)
        return SignalChain(s.filter_width, s.mag_filter_width, coning)

    def filter_delays(self) -> tuple[float, float]:
        """Seconds by which accel/gyro-derived and magnetometer values lag their cycle.

        A moving average of M samples at 1 kHz delays by exactly (M - 1)/2 ms at every
        frequency (``SignalChain``).

        Returns:
            (accel and gyro delay, magnetometer delay), seconds; zero without the filter
            model.
        """
        return self.signal_chain().delays()

    def _sample(self, device: np.ndarray, period: float, names: list[str]
                ) -> dict[str, np.ndarray]:
        """The motion through the unit's signal chain at the end of cycles at ``device``.

        At least the quantities ``names`` and the quaternion (the truth, always computed).
        """
        return self.motion.sample(device, period, self.signal_chain(), [*names, "quaternion"])

    def _body_time(self, device: np.ndarray) -> np.ndarray:
        """A shared body's time at device times: host seconds since power-up.

        Units that power up together see one motion, whatever their clocks.
        """
        return self._host_times(device) - self._t0

    def _records(self, code: int, cycles: np.ndarray) -> tuple[bytes, list[TruthRow]]:
        """The bytes of one record of ``code`` per calculation cycle, and their truth."""
        device = cycles * CALCULATION_CYCLE_S
        names = [f.name for f in REPLIES[code].fields if f.name != "timer"]
        sample = self._sample(device, self.period, names)
        timers = self.timer_at(cycles)
        columns = {"timer": timers, **{name: self._reported(name, sample) for name in names}}
        data = encode_replies(code, columns, len(cycles), self.little_endian)
        wall = self._host_times(device) * 1e9 + self._wall_offset_ns
        # integrals over the period (DeltaAngle, DeltaVelocity) describe its middle
        middle = self.period / 2 if REPLIES[code].integral else 0.0
        valued = self._host_times(device - self.filter_delays()[0] - middle) * 1e9 \
            + self._wall_offset_ns
        truths = list(zip(wall.astype(np.int64).tolist(), valued.astype(np.int64).tolist(),
                          device.tolist(), timers.tolist(), [code] * len(cycles),
                          sample["quaternion"], strict=True))
        return data, truths

    def _reported(self, name: str, sample: dict[str, np.ndarray]) -> np.ndarray:
        """A quantity as the unit reports it in its current state and settings."""
        value = sample[name].copy()
        flags = self.sampling.flags
        if name in ("accel", "stab_accel", "delta_vel"):
            value -= self.accel_bias * (self.period if name == "delta_vel" else 1.0)
        if name in ("ang_rate", "delta_ang"):
            value -= self.gyro_bias * (self.period if name == "delta_ang" else 1.0)
        if self.mode == Mode.IDLE:
            value[:] = 0 if name in _RAW_FIELDS else np.nan
        if name in _MAG_FIELDS and flags & Flag.DISABLE_MAG:
            value[:] = np.nan
        if name in _ORIENTATION_FIELDS and not flags & Flag.ORIENTATION:
            value[:] = np.nan
        if name == "quaternion" and not flags & Flag.QUATERNION:
            value[:] = np.nan
        if flags & Flag.SUPPRESS_NAN and value.dtype.kind == "f":
            value = np.nan_to_num(value, nan=0.0)
        return value

    # --- commands ------------------------------------------------------------------------
    def _execute(self, raw: bytes, at: float) -> None:
        """Act on one command at the end of cycle ``at``, as the manual has it in every mode.

        Records planned for later cycles are planned again after the reply, so that a
        reply leaves at once and in timer order with the records around it.
        """
        self._cancel_after(at)
        self._reply(raw, at)
        if self._new_phase:
            self._stream_from = self._line_free
            self._stream_phase = self._cycle_after(self._stream_from)
        else:
            self._stream_from = self.host_time((self._cycle_at(at) + 1) * CALCULATION_CYCLE_S)
        self._new_phase = False

    def _reply(self, raw: bytes, at: float) -> None:
        parsed = parse_command(raw)
        cmd = parsed.command
        if not parsed.confirmed:
            self._schedule(at, ERROR_REPLY)
            return
        if cmd.data:
            self._reply_data(cmd.code, at)
            return
        handler = getattr(self, f"_do_{cmd.name}", None)
        if handler is None:
            return
        values = handler(at, **_normalise(cmd, parsed.params))
        if values is not None and cmd.replies(parsed.params):
            self._schedule(at, encode_reply(cmd.code, self.little_endian, **values))

    def _reply_data(self, code: int, at: float) -> None:
        cycle = np.array([self._cycle_after(at)])
        data, truths = self._records(code, cycle)
        self._schedule(at + self.config.processing_delay_s, data, truths[0])

    def _timer_now(self, at: float) -> int:
        return int(self.timer_at(self._cycle_at(at)))

    def _do_set_continuous(self, at: float, command: int | None) -> dict[str, Any]:
        if command == 0:
            self.mode = Mode.ACTIVE
            self.continuous_command = 0
        elif command is not None:
            self._start_stream(command, at)
        return {"command": self.continuous_command, "timer": self._timer_now(at)}

    def _do_write_accel_bias(self, at: float, accel_bias: list[float]) -> dict[str, Any]:
        self.accel_bias = np.array(accel_bias, dtype=np.float32).astype(np.float64)
        return {"accel_bias": self.accel_bias, "timer": self._timer_now(at)}

    def _do_write_gyro_bias(self, at: float, gyro_bias: list[float]) -> dict[str, Any]:
        self.gyro_bias = np.array(gyro_bias, dtype=np.float32).astype(np.float64)
        return {"gyro_bias": self.gyro_bias, "timer": self._timer_now(at)}

    def _do_capture_gyro_bias(self, at: float, sampling_time_ms: int) -> None:
        """Average the gyro for the sampling time, then answer; a moving unit gets it wrong."""
        n = max(1, sampling_time_ms)
        start = self._cycle_after(at)
        device = np.arange(start, start + n) * CALCULATION_CYCLE_S
        done = self.host_time(device[-1] + CALCULATION_CYCLE_S)
        rate = self._sample(device, CALCULATION_CYCLE_S, ["ang_rate"])["ang_rate"]
        self.gyro_bias = rate.mean(axis=0)
        self._busy_until = max(self._busy_until, done)
        values = {"gyro_bias": self.gyro_bias, "timer": self._timer_now(done)}
        self._schedule(done, encode_reply(0xCD, self.little_endian, **values))

    def _do_transfer_to_nonvolatile(self, at: float, quantity: int | None) -> dict[str, Any]:
        if quantity == 1:
            self._persist(accel_bias=tuple(self.accel_bias.tolist()))
        elif quantity == 2:
            self._persist(gyro_bias=tuple(self.gyro_bias.tolist()))
        return {"quantity": 0xFFFF if quantity is None else quantity,
                "timer": self._timer_now(at)}

    def _do_mode(self, at: float, mode: int | None) -> dict[str, Any]:
        if mode in (Mode.SLEEP, Mode.DEEP_SLEEP):
            # The clocks stop: the timer holds, and what the host sent after the
            # sleep command is dropped without waking the unit.
            self._sleep_timer = self._timer_now(at)
            self._inbox.clear()
            self._queue.clear()
        if mode in (Mode.ACTIVE, Mode.IDLE, Mode.SLEEP, Mode.DEEP_SLEEP):
            self.mode = Mode(mode)
        elif mode == Mode.CONTINUOUS and self.stored.continuous_preset in DATA_CODES:
            self._start_stream(self.stored.continuous_preset, at)
        return {"mode": int(self.mode)}

    def _wake_up(self, now: float) -> None:
        """Any byte wakes a sleeping unit into its preset mode after the settling time."""
        ready = now + float(wake_time_seconds(self.sampling.filter_width))
        if self.mode == Mode.DEEP_SLEEP:
            self._boot(now, 0, ready)
        else:
            self._set_timer(now, self._sleep_timer)
            self._ready = ready
            self._wake(Mode(self.stored.mode_preset))

    def _do_mode_preset(self, at: float, mode_preset: int | None) -> dict[str, Any]:
        if mode_preset:
            self._persist(mode_preset=mode_preset)
        return {"mode_preset": self.stored.mode_preset}

    def _do_continuous_preset(self, at: float, continuous_preset: int | None) -> dict[str, Any]:
        if continuous_preset:
            self._persist(continuous_preset=continuous_preset)
        return {"continuous_preset": self.stored.continuous_preset}

    def _do_timer(self, at: float, function: int | None, value: int) -> dict[str, Any]:
        if function == 1:
            self._set_timer(at, value)
        elif function == 2:
            return {"timer": value}
        return {"timer": self._timer_now(at)}

    def _do_comms_settings(self, at: float, port: int | None, function: int | None,
                           baud: int | None, config: int) -> dict[str, Any] | None:
        if port not in (None, 1):
            return {"port": port, "baud": 0, "config": 0}
        if function in (1, 2) and baud is not None:
            self._schedule(at, encode_reply(0xD9, port=1, baud=baud, config=0x02))
            self.baud = baud
            if function == 2:
                self._persist(baud=baud)
            return None
        return {"port": 1, "baud": self.baud, "config": 0x02}

    def _do_stationary_test(self, at: float) -> dict[str, Any]:
        return {"test_result": STATIONARY_TEST_OK}

    def _do_sampling_settings(self, at: float, function: int | None, **new: int) -> dict[str, Any]:
        if function in (1, 2, 3):
            current = asdict(self.sampling)
            merged = {k: current[k] if v is None else v for k, v in new.items()}
            if merged["flags"] & (Flag.ORIENTATION | Flag.QUATERNION):
                merged["decimation"] = max(2, merged["decimation"])
            self._new_phase = merged["decimation"] != self.sampling.decimation
            self.sampling = Sampling(**merged)
            if function == 2:
                self._persist(sampling=self.sampling)
        return asdict(self.sampling)

    def _do_realign_up_north(self, at: float, function: int | None, up_realign: int | None,
                             north_realign: int | None) -> dict[str, Any]:
        return {}

    def _do_write_eeprom(self, at: float, address: int, value: int) -> dict[str, Any]:
        if any(address in r for r in USER_EEPROM):
            self._persist(eeprom=self.stored.with_word(address, value).eeprom)
        return {"word": self.stored.word(address)}

    def _do_read_eeprom(self, at: float, address: int) -> dict[str, Any]:
        return {"word": self.stored.word(address)}

    def _do_firmware_version(self, at: float) -> dict[str, Any]:
        return {"firmware": self.config.firmware}

    def _do_device_id(self, at: float, selector: int | None) -> dict[str, Any]:
        """An unknown selector has no current value to return: 0xFF and a blank string."""
        if selector is None:
            return {"selector": 0xFF, "text": ""}
        return {"selector": selector, "text": self.config.id_string(selector)}

    def _do_stop_continuous(self, at: float) -> None:
        self.mode = Mode.ACTIVE

    def _do_device_reset(self, at: float) -> None:
        self._restart(at, 0)


def _normalise(cmd: Command, params: dict[str, Any]) -> dict[str, Any]:
    """Apply the manual's range rules: clamp into range, ignore (None) outside a set."""
    out = {}
    for f in cmd.params:
        if f.is_pad:
            continue
        value = params[f.name]
        if f.allowed is not None and value not in f.allowed:
            value = None
        elif f.lo is not None and f.hi is not None:
            value = int(min(max(value, f.lo), f.hi))
        out[f.name] = value
    return out

