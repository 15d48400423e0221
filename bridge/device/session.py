"""A session with one unit: bring-up, commands with timeouts and retries, streaming.

One thread owns the port. Commands can be sent while the unit streams: the framer
then expects the stream's records, the command's reply and the error reply, and
every data record that arrives while waiting is kept for the next ``read``, so a
command never costs a sample.

Nothing that writes the unit's non-volatile memory is sent unless the caller says
so for that exact command (``persist=True``); the command table decides what
persists, taking the firmware into account (``bridge.protocol.table``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from bridge.device import clock
from bridge.device.port import Port
from bridge.exceptions import (
    CommandRejected,
    CommandTimeout,
    DeviceError,
    PersistRefused,
    PortError,
    UnsupportedUnit,
)
from bridge.protocol.codec import Batch, Records, encode_command
from bridge.protocol.convert import wake_time_seconds
from bridge.protocol.framer import Framer
from bridge.protocol.table import (
    BAUD_RATES,
    DATA_CODES,
    DEFAULT_FILTER_WIDTH,
    ERROR_CODE,
    REPLIES,
    TICKS_PER_SECOND,
    Flag,
    lookup,
)

#: Record streamed when the unit has no continuous preset: accel, ang_rate, mag and M.
DEFAULT_RECORD = 0xCC
ID_FIELDS = ("model_number", "serial", "model_name", "options", "lot")
_QUIET_S = 0.05  # silence that ends a drain
_DRAIN_MAX_S = 1.0
_MAX_SETTLE_S = float(wake_time_seconds(32)) + 0.02  # Equation 1 at the widest filter


#: Model-name fragments of the units the protocol's ancestors ran on. Their 32-bit
#: timer counts 19,660,800 ticks/s (wrapping every 218 s), not 62,500, and their
#: command set is not the manual's: timed as a GX3, every instant would be wrong.
_OTHER_MODELS = ("GX2", "INERTIA-LINK", "INERTIALINK")


def _check_model(ids: dict[str, str]) -> None:
    """Refuse a 3DM-GX2 or Inertia-Link unit with what to do instead."""
    text = f"{ids.get('model_name', '')} {ids.get('model_number', '')}".upper()
    if any(other in text.replace(" ", "") for other in _OTHER_MODELS):
        raise UnsupportedUnit(
            f"the unit says it is a {ids.get('model_name', '').strip() or 'GX2-family unit'}, "
            "not a 3DM-GX3: its timer counts 19,660,800 ticks/s, not 62,500, and its "
            "commands differ, so its samples would be mistimed; use a 3DM-GX3 "
            "(-15, -25, -35 or -45)")


@dataclass
class UnitInfo:
    """What bring-up learned about the unit.

    ``firmware`` is 0xE9's version number (1127 for 1.1.27); ``ids`` the 0xEA strings by
    name (``ID_FIELDS``); ``sampling`` the 0xDB settings by name; ``record`` the record
    chosen to stream (0: none chosen); ``bring_up_ns`` when bring-up asked (realtime
    clock); ``notes`` what the unit did differently from what was asked.
    """

    firmware: int
    ids: dict[str, str]
    sampling: dict[str, int]
    baud: int
    continuous_preset: int
    record: int = 0
    bring_up_ns: int = 0
    notes: list[str] = field(default_factory=list)

    @property
    def firmware_text(self) -> str:
        """1127 -> '1.1.27', as the manual writes versions."""
        major, rest = divmod(self.firmware, 1000)
        minor, patch = divmod(rest, 100)
        return f"{major}.{minor}.{patch}"

    @property
    def little_endian(self) -> bool:
        """Whether the unit sends floats little-endian (0xDB flag bit 4)."""
        return bool(self.sampling.get("flags", 0) & Flag.LITTLE_ENDIAN_FLOATS)

    @property
    def output_hz(self) -> float:
        """Records a second: 1000 Hz / decimation."""
        return 1000.0 / max(1, self.sampling.get("decimation", 1))

    @property
    def filter_width(self) -> int:
        """The accel and gyro filter width M (0xDB); the factory's if not read."""
        return self.sampling.get("filter_width", 0) or DEFAULT_FILTER_WIDTH

    @property
    def stream_record(self) -> int:
        """The record a stream of this unit carries.

        The one chosen, else its continuous preset, else ``DEFAULT_RECORD``.
        """
        return self.record or self.continuous_preset or DEFAULT_RECORD

    def line_warning(self) -> str | None:
        """What to change when its serial line cannot carry the stream (None if it can).

        The line carries baud/10 bytes a second and the unit skips every record that
        finds it busy (the manual's Data Output Rate table): record bytes x rate must
        fit, or records go missing.

        Returns:
            One line: what the stream needs, what the line carries, which baud rate or
            decimation would fit.
        """
        record, decimation = self.stream_record, max(1, self.sampling.get("decimation", 1))
        size = REPLIES[record].length
        need = size * 1000 / decimation
        if need <= self.baud / 10:
            return None
        fixes = [f"--new-baud {b}" for b in BAUD_RATES if need <= b / 10][:1]
        fits = math.ceil(size * 10_000 / self.baud)
        if fits <= 1000:
            fixes.append(f"--decimation {fits} or more")
        return (f"the line cannot carry the stream: 0x{record:02X} ({size} bytes) at "
                f"{1000 / decimation:g} Hz needs {need:,.0f} bytes/s, {self.baud} baud "
                f"carries {self.baud // 10:,}; records will go missing (use "
                f"{' or '.join(fixes) or 'a shorter record'})")

    @property
    def period_ticks(self) -> float:
        """The output period in timer ticks: decimation x 62.5."""
        return TICKS_PER_SECOND * max(1, self.sampling.get("decimation", 1)) / 1000


def _line_time(nbytes: int, baud: int) -> float:
    return nbytes * 10.0 / baud


#: A link is taken to hand its bytes over in large pieces until its reads say otherwise.
_PIECE_START = 64
_PIECE_SMOOTHING = 8


def pace(rest: int, piece: float, baud: int) -> float:
    """How long to sleep before reading the rest of a record cut by a read.

    Over a serial line whose reads bring ``piece`` bytes when the line wakes the reader:
    the rest's line time when it would come in several pieces (each a wake-up), else 0.
    A sleep is a timer wake-up, which costs as much CPU here as a wake-up by the link's
    bytes (~17 µs on a virtual machine): it pays only where it saves two or more.

    Args:
        rest: Bytes of the record still to come.
        piece: Bytes a read brings when the line wakes the reader.
        baud: The line's baud rate.

    Returns:
        Seconds.
    """
    return _line_time(rest, baud) if rest > 0 and piece * 2 < rest else 0.0


class Session:
    """One unit on one open port. Not thread-safe: one thread drives it.

    ``streaming`` is the record ``read`` returns (streamed, or polled with ``polling``);
    ``paced``: the port's bytes come at a UART's line rate, not in USB packets.

    Args:
        port: The open port; the session does not close it.
        firmware: The unit's 0xE9 version number, if known (``identify`` learns it): the
            command table's rules for non-volatile memory depend on it.
    """

    def __init__(self, port: Port, firmware: int | None = None) -> None:
        self.port = port
        self.firmware = firmware
        self.framer = Framer(expect=())
        self.streaming: int | None = None  # the record ``read`` returns: streamed or polled
        self.polling = False
        self.paced = False  # bytes come at the UART's line rate (not in USB packets)
        #: hears every read the session makes, in order: its bytes and receive times on
        #: the raw monotonic and the realtime clock (the host clock, a raw capture)
        self.on_reads: Callable[[list[bytes], list[int], list[int]], None] | None = None
        self._backlog: list[Batch] = []
        self._last_read = 0.0  # time.monotonic() of the last read that brought bytes
        #: The bytes a read brings when woken by the link itself (not after a sleep),
        #: smoothed: how finely the link hands its bytes over.
        self._piece = float(_PIECE_START)

    # --- reading -----------------------------------------------------------------------
    def _expect(self, *extra: int) -> None:
        codes = set(extra)
        if self.streaming is not None:
            codes.add(self.streaming)
        self.framer.expect(codes)

    def _take(self, wait_s: float, need: int = 1) -> tuple[list[bytes], list[int]]:
        """Read until ``need`` bytes came (``Port.read_until``), handing them to ``on_reads``.

        Returns the reads' bytes and raw-clock receive times, which the framer and the
        clock model use.
        """
        reads, raws, reals = self.port.read_until(need, wait_s)
        if reads:
            self._last_read = time.monotonic()
            if self.on_reads is not None:
                self.on_reads(reads, raws, reals)
        return reads, raws

    def _read(self, wait_s: float) -> list[Batch]:
        reads, rx_ns = self._take(wait_s)
        return self.framer.feed(reads[0], rx_ns[0]) if reads else []

    def read(self, wait_s: float = 0.05) -> list[Batch]:
        """Data records of the stream that arrived within ``wait_s``.

        Records that came while a command waited for its reply come first.

        Args:
            wait_s: How long to wait for bytes.

        Returns:
            Batches of the ``streaming`` record.

        Raises:
            PortError: The port is gone.
        """
        return [r if isinstance(r, Batch) else r.batch() for r in self.read_records(wait_s)]

    def read_records(self, wait_s: float = 0.05, hold_s: float = 0.0) -> list[Batch | Records]:
        """``read``, a fresh read's records as ``Records`` (a live bridge's per-read path).

        On a UART (``paced``) that hands its bytes over in small pieces (a FIFO's few
        bytes at a time), a record cut in two by a read is not waited for piece by piece:
        the rest cannot arrive before its line time, so the session sleeps that long
        first (``pace``).

        Args:
            wait_s: How long to wait for bytes.
            hold_s: Let bytes gather in the port this long after the last read before
                reading again (coalescing reads: fewer wake-ups, a few records a read); a
                byte that arrives just after a read waits that long.

        Returns:
            The backlog's batches, then the fresh read's records.

        Raises:
            PortError: The port is gone.
        """
        out: list[Batch | Records] = []
        woken = False  # whether the read below waits for the link's bytes
        # the bytes that complete the record begun (1: a whole reply is not waited for)
        rest = 1 if self.streaming is None else REPLIES[self.streaming].length - self.framer.pending
        if self._backlog:
            out += self._backlog
            self._backlog = []
        else:
            pause = self._last_read + hold_s - time.monotonic()
            if self.paced and self.streaming is not None and self.framer.pending:
                pause = max(pause, min(wait_s, pace(rest, self._piece, self.port.baud)))
            if pause > 0:
                time.sleep(pause)
            woken = pause <= 0
        reads, rx_ns = self._take(0.0 if out else wait_s, rest)
        if reads and woken:  # how large the pieces are that the link hands over
            self._piece += (len(reads[0]) - self._piece) / _PIECE_SMOOTHING
        if reads:
            out += [r for r in self.framer.feed_records(reads, rx_ns) if r.code == self.streaming]
        return out

    def drain(self, quiet_s: float = _QUIET_S, limit_s: float = _DRAIN_MAX_S) -> int:
        """Discard input until the line has been quiet for ``quiet_s``.

        Args:
            quiet_s: The silence that ends it.
            limit_s: How long it may take at most.

        Returns:
            Bytes discarded.

        Raises:
            PortError: The port is gone.
        """
        dropped = 0
        deadline = time.monotonic() + limit_s
        while time.monotonic() < deadline:
            data, _, _ = self.port.read(quiet_s)
            if not data:
                break
            dropped += len(data)
        self.framer = Framer(expect=(), little_endian=self.framer.little_endian)
        return dropped

    # --- commands ----------------------------------------------------------------------
    def send(self, name: str, persist: bool = False, **params: Any) -> None:
        """Send a command without waiting for a reply (0xFA, 0xFE, or function 3).

        Args:
            name: The command's name.
            persist: Allow it to write the unit's non-volatile memory.
            **params: Its parameters.

        Raises:
            PersistRefused: It would write non-volatile memory and ``persist`` is False.
            ProtocolError: A parameter is wrong for the command.
            PortError: The port is gone.
        """
        self._guard(name, params, persist)
        self.port.write(encode_command(name, **params))

    def _guard(self, name: str, params: dict[str, Any], persist: bool) -> None:
        cmd = lookup(name)
        if cmd.changes_nonvolatile(params, self.firmware) and not persist:
            raise PersistRefused(
                f"0x{cmd.code:02X} {cmd.name} with {params} would write the unit's non-volatile "
                "memory; ask for that change explicitly (--persist) if you mean it")

    def command(self, name: str, *, timeout: float | None = None, retries: int = 2,
                persist: bool = False, **params: Any) -> dict[str, Any]:
        """Send a command and return its decoded reply fields.

        Args:
            name: The command's name.
            timeout: Seconds to wait for each reply; None: a quarter second plus the
                line time of the reply and some.
            retries: Further attempts after the first.
            persist: Allow it to write the unit's non-volatile memory.
            **params: Its parameters.

        Returns:
            The reply's fields by name, as plain Python values.

        Raises:
            DeviceError: The command asks for the record being streamed.
            PersistRefused: It would write non-volatile memory and ``persist`` is False.
            CommandRejected: The unit answered with the error reply.
            CommandTimeout: No reply came after every attempt.
            PortError: The port is gone.
        """
        cmd = lookup(name)
        if cmd.data and cmd.code == self.streaming:
            raise DeviceError(f"0x{cmd.code:02X} is the record being received; stop "
                              "streaming or polling it first")
        self._guard(name, params, persist)
        if timeout is None:
            timeout = 0.25 + _line_time(2 * (cmd.reply_length or 0) + 200, self.port.baud)
        return self.transact(encode_command(name, **params), cmd.code, timeout, retries)

    def transact(self, raw: bytes, code: int, timeout: float = 0.5,
                 retries: int = 0) -> dict[str, Any]:
        """Write ``raw`` and wait for the reply starting with ``code``.

        No safety check: for bytes built by hand, e.g. to probe a unit.

        Args:
            raw: The bytes to send.
            code: The reply's first byte.
            timeout: Seconds to wait for each reply.
            retries: Further attempts after the first.

        Returns:
            The reply's fields by name, as plain Python values.

        Raises:
            CommandRejected: The unit answered with the error reply.
            CommandTimeout: No reply came after every attempt.
            PortError: The port is gone.
        """
        self._expect(code, ERROR_CODE)
        try:
            for _ in range(retries + 1):
                self.port.write(raw)
                reply = self._await(code, timeout)
                if reply is not None:
                    return reply
        finally:
            self._expect()
        name = REPLIES[code].name if code in REPLIES else "reply"
        raise CommandTimeout(
            f"no reply to 0x{code:02X} {name} from {self.port.url} at {self.port.baud} "
            f"baud after {retries + 1} tries; check the cable, the baud rate (--baud, or "
            "--baud auto) and that the unit is powered")

    def _await(self, code: int, timeout: float) -> dict[str, Any] | None:
        """The reply to ``code``; stream records that come meanwhile go to the backlog."""
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            reply: dict[str, Any] | None = None
            for batch in self._read(min(left, 0.05)):
                if batch.code == ERROR_CODE:
                    raise CommandRejected(
                        f"the unit answered 0x{code:02X} with the error reply 21 00 21 "
                        "(confirmation bytes not accepted)")
                if batch.code == code and batch.code != self.streaming and reply is None:
                    reply = _first_record(batch)
                elif batch.code == self.streaming:
                    self._backlog.append(batch)
            if reply is not None:
                return reply
        return None

    # --- bring-up ----------------------------------------------------------------------
    def quiesce(self) -> int:
        """Stop continuous output and wait out a wake-up: 0xFA, settle, 0xFA, drain.

        The first byte wakes a sleeping unit and is lost in its settling time
        (Equation 1); a unit that wakes into continuous mode is stopped by the second.

        Returns:
            Bytes drained.
        """
        self.streaming = None
        self.send("stop_continuous")
        time.sleep(_MAX_SETTLE_S)
        self.send("stop_continuous")
        return self.drain()

    def identify(self) -> UnitInfo:
        """Ask the unit what it is: firmware, every ID string, sampling settings, preset.

        Returns:
            What it said, with the port's baud rate and when it was asked.

        Raises:
            UnsupportedUnit: The unit is a 3DM-GX2 or an Inertia-Link, not a 3DM-GX3.
            CommandRejected: The unit refused a read.
            CommandTimeout: The unit did not answer.
        """
        firmware = int(self.command("firmware_version")["firmware"])
        self.firmware = firmware
        ids = {}
        for selector, key in enumerate(ID_FIELDS):
            ids[key] = str(self.command("device_id", selector=selector)["text"])
        _check_model(ids)
        sampling = self.command("sampling_settings", function=0)
        preset = int(self.command("continuous_preset", continuous_preset=0)["continuous_preset"])
        return UnitInfo(firmware=firmware, ids=ids,
                        sampling={k: int(v) for k, v in sampling.items()},
                        baud=self.port.baud, continuous_preset=preset,
                        bring_up_ns=clock.realtime_ns())

    def apply_sampling(self, info: UnitInfo, persist: bool = False,
                       **changes: int | None) -> None:
        """Change sampling settings (0xDB function 1, or 2 to store them).

        A setting the unit changed by its range rules is noted in ``info.notes``.

        Args:
            info: The unit's settings; they follow the unit's reply.
            persist: Store the settings in non-volatile memory.
            **changes: The settings to change by name (``decimation``, ``flags``, ...);
                None leaves one as it is.

        Raises:
            PersistRefused: The unit's firmware (before 1.1.27) would store the settings
                and ``persist`` is False.
            CommandRejected: The unit refused the settings.
            CommandTimeout: The unit did not answer.
        """
        wanted = {k: v for k, v in changes.items() if v is not None}
        if not wanted:
            return
        merged = {**info.sampling, **wanted}
        params = {k: merged[k] for k in ("decimation", "flags", "filter_width",
                                         "mag_filter_width", "up_compensation",
                                         "north_compensation")}
        params["up_compensation"] = max(1, params["up_compensation"])
        params["north_compensation"] = max(1, params["north_compensation"])
        reply = self.command("sampling_settings", persist=persist,
                             function=2 if persist else 1, **params)
        info.sampling = {k: int(v) for k, v in reply.items()}
        for key, value in wanted.items():
            if info.sampling.get(key) != value:
                info.notes.append(f"the unit set {key} to {info.sampling.get(key)}, "
                                  f"not {value} (its range rules)")

    def change_baud(self, info: UnitInfo, baud: int, persist: bool = False) -> None:
        """Change the unit's baud rate (0xD9), and the port's with it.

        The reply is verified at the old rate before the switch; if the unit does not
        answer at the new one, both go back.

        Args:
            info: The unit's settings; ``baud`` follows.
            baud: The new rate.
            persist: Store it in non-volatile memory.

        Raises:
            DeviceError: The unit kept its rate, or stopped answering at the new one.
            CommandTimeout: The unit did not answer.
        """
        old = self.port.baud
        if baud == old:
            return
        reply = self.command("comms_settings", persist=persist, port=1,
                             function=2 if persist else 1, baud=baud, config=0x02)
        if int(reply["baud"]) != baud:
            raise DeviceError(f"the unit kept {reply['baud']} baud instead of {baud}")
        time.sleep(_line_time(64, old) + 0.01)
        self.port.baud = baud
        self.drain(quiet_s=0.02, limit_s=0.2)
        try:
            self.command("firmware_version", retries=3)
        except CommandTimeout:
            self.port.baud = old
            self.drain(quiet_s=0.02, limit_s=0.2)
            self.command("firmware_version", retries=3)
            raise DeviceError(f"the unit stopped answering at {baud} baud; back at {old}") from None
        info.baud = baud

    def start_streaming(self, code: int) -> None:
        """Stream a record (0xC4) without touching the stored continuous preset.

        Args:
            code: The data record to stream.

        Raises:
            DeviceError: ``code`` is not a data record, or the unit refused to stream it.
            CommandTimeout: The unit did not answer.
        """
        if code not in DATA_CODES:
            raise DeviceError(f"0x{code:02X} is not a data record")
        # expect the records from now: the first can come in the same read as the reply
        self.streaming = code
        try:
            reply = self.command("set_continuous", command=code)
        except DeviceError:
            self.streaming = None
            raise
        if int(reply["command"]) != code:
            self.streaming = None
            raise DeviceError(f"the unit refused to stream 0x{code:02X}")

    def start_polling(self, code: int) -> None:
        """Receive a record as replies to ``poll`` instead of a continuous stream.

        Args:
            code: The data record to poll.

        Raises:
            DeviceError: ``code`` is not a data record.
        """
        if code not in DATA_CODES:
            raise DeviceError(f"0x{code:02X} is not a data record")
        self.streaming, self.polling = code, True
        self._expect()

    def poll(self) -> None:
        """Ask for one record of the polled type; it arrives through ``read``."""
        assert self.polling and self.streaming is not None
        self.port.write(bytes((self.streaming,)))

    def stop_streaming(self) -> None:
        """0xFA twice (the first may be lost in a record), leaving the port open."""
        if self.polling:
            self.streaming, self.polling = None, False
            return
        self.streaming = None
        self.send("stop_continuous")
        time.sleep(0.01)
        self.send("stop_continuous")
        self._expect()


def _first_record(batch: Batch) -> dict[str, Any]:
    """The fields of a batch's first record as plain Python values."""
    out: dict[str, Any] = {}
    for name, column in batch.columns.items():
        value = column[0].tolist()
        out[name] = value.decode("ascii", "replace").rstrip("\x00 ") \
            if isinstance(value, bytes) else value
    return out


def find_baud(url: str, first: int, candidates: Iterable[int] = BAUD_RATES) -> tuple[Port, int]:
    """Open ``url`` at the baud rate a unit answers 0xE9 on.

    Args:
        url: The device path or pyserial URL.
        first: The rate tried first.
        candidates: The others, tried in order.

    Returns:
        The open port and the rate.

    Raises:
        PortError: The port cannot be opened.
        CommandTimeout: No unit answered at any rate.
    """
    order = [first, *[b for b in candidates if b != first]]
    port = Port.open(url, order[0])
    try:
        for baud in order:
            port.baud = baud
            session = Session(port)
            session.quiesce()
            try:
                session.command("firmware_version", timeout=0.3, retries=1)
                return port, baud
            except DeviceError:
                continue
    except PortError:
        port.close()
        raise
    port.close()
    raise CommandTimeout(f"{url}: no unit answered at {', '.join(str(b) for b in order)} baud; "
                      "check the cable and the unit's power")
