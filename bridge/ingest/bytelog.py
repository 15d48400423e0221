"""`gx3 import`: byte logs with no receive times into an archive, timed by the unit's timer.

A byte log (a data logger's, ``cat /dev/ttyUSB0``) holds what the unit sent and nothing
of when it arrived, so the unit's timer is the only clock: each record's ``time_ns`` is
the log's start plus the unit's time since its first record, less the filter delay (the
instant its values describe, as everywhere else). Rollovers are unwrapped; a jump
forward by more than the output period (from a 0xDB reply, else the timer's own steps)
is a gap (the records between were lost); a timer that goes back is a reset, whose time
since the start no byte can tell, so it starts a new epoch at the next start given
(``restarts``) or at the start of the file it begins, or the import is refused. Every
record of every data type is kept, in order; the float byte order follows 0xDB replies
as ``gx3 decode`` does. The archive says that no host clock timed it (its
``gx3.archive`` metadata, and Info with no link and no baud rate), so that nobody takes
it for a live-timed recording; ``gx3 export`` keeps its times.
"""

from __future__ import annotations

import json
from collections import Counter, deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import numpy.typing as npt

from bridge._text import counted, number
from bridge.archive.times import epoch_ns
from bridge.archive.walk import is_mcap
from bridge.archive.writer import ArchiveWriter
from bridge.bus.codec import encode_batch
from bridge.bus.gx3_pb2 import Event, Info, Status
from bridge.exceptions import LogImportError
from bridge.protocol.codec import Batch
from bridge.protocol.framer import Framer, FramerStats, other_byte_order
from bridge.protocol.table import DATA_CODES, TICKS_PER_SECOND
from bridge.timing.stream import filter_delay_ns, period_middle_ns
from bridge.timing.unwrap import NS_PER_TICK

__all__ = ["Imported", "LogFile", "import_logs", "name_time", "parse_start"]

SAMPLING = 0xDB  # the sampling settings reply: decimation, filter width, byte order
_EXPECT = frozenset(DATA_CODES | {SAMPLING})
FACTORY_FILTER_WIDTH = 15  # the manual's factory setting, where the log has no 0xDB reply
FACTORY_DECIMATION = 10  # until a 0xDB reply or the timer's steps tell the rate
_ROLLOVER_TICKS = 10 * 60 * TICKS_PER_SECOND  # a timer that goes back less than this far
_READ_BYTES = 1 << 20  # (mod 2^32) crossed its rollover; further back, it was reset
_HEAD_BYTES = 1 << 22  # of the first log, tried in the other byte order if none decoded
_LATTICE_TOLERANCE = 0.5  # ticks: a step is whole output periods to within rounding


@dataclass(frozen=True)
class LogFile:
    """One byte log and, where known, the instant of its first record (ns since the epoch).

    Attributes:
        path: The file.
        start_ns: When its first record was sampled; None: it continues the one before.
    """

    path: Path
    start_ns: int | None = None


@dataclass
class Imported:
    """What an import wrote.

    Attributes:
        unit: The unit's name.
        samples: Samples archived, by record type.
        events: Gaps, rollovers and resets found, by kind.
        missing: Records lost in the gaps.
        stats: The framer's counts (checksum failures, bytes skipped, ...).
        filter_width: The filter width whose delay was taken out.
        filter_from_log: Whether a 0xDB reply in the log gave it (else the factory's).
        decimation: The output period in ms (1000 / rate) the gaps were counted against.
        decimation_from_log: Whether a 0xDB reply gave it (else the timer's steps).
        first_ns: The first sample's ``time_ns``.
        last_ns: The last sample's ``time_ns``.
    """

    unit: str
    samples: Counter[int] = field(default_factory=Counter)
    events: Counter[str] = field(default_factory=Counter)
    missing: int = 0
    stats: FramerStats = field(default_factory=FramerStats)
    filter_width: int = FACTORY_FILTER_WIDTH
    filter_from_log: bool = False
    decimation: int = FACTORY_DECIMATION
    decimation_from_log: bool = False
    first_ns: int = 0
    last_ns: int = 0

    def text(self) -> str:
        """What was imported, in a line or two for a person.

        Returns:
            The lines.
        """
        by_type = ", ".join(f"0x{code:02X}×{number(n)}"
                            for code, n in sorted(self.samples.items()))
        span = (self.last_ns - self.first_ns) / 1e9
        events = ", ".join(counted(n, kind, "glitches" if kind == "glitch" else None)
                           for kind, n in sorted(self.events.items()))
        lost = f" ({counted(self.missing, 'record')} lost)" if self.missing else ""
        delay = (f"filter width {self.filter_width} from the log" if self.filter_from_log
                 else f"filter width {self.filter_width} assumed (the factory's; no 0xDB "
                      "reply in the log)")
        total = counted(sum(self.samples.values()), "sample")
        rate = (f"{1000 / self.decimation:g} Hz "
                f"{'from the log' if self.decimation_from_log else 'by the timer'}")
        return (f"{self.unit}: {total} ({by_type or 'none'}) at {rate} over {span:,.1f} s; "
                f"{events or 'no gap'}{lost}; {delay}\n"
                f"checksum failures: {number(self.stats.checksum_failures)}; bytes skipped: "
                f"{number(self.stats.bytes_skipped)} of {number(self.stats.bytes_fed)}")


def parse_start(text: str) -> int:
    """An ISO 8601 instant with its zone, as ns since the epoch.

    Args:
        text: ``2026-11-28T06:00:00Z``, ``2026-11-28 08:00:00+02:00``, ...

    Returns:
        The instant.

    Raises:
        LogImportError: Not an ISO time, or one without a zone (a logger's clock is
            often local time: say which).
    """
    try:
        when = datetime.fromisoformat(text)
    except ValueError:
        raise LogImportError(f"--start {text!r} is not an ISO 8601 time; give one such as "
                             "2026-11-28T06:00:00Z") from None
    if when.tzinfo is None:
        raise LogImportError(f"--start {text!r} has no zone; add Z for UTC or the "
                             "logger's offset (+02:00)")
    return epoch_ns(when)


def name_time(path: Path, pattern: str) -> int:
    """The instant a logger wrote into a file's name, as ns since the epoch.

    It is UTC unless the pattern has %z.

    Args:
        path: The file; its name without the extension is matched whole.
        pattern: A ``strptime`` pattern, e.g. ``log_%Y%m%d_%H%M%S``.

    Returns:
        The instant.

    Raises:
        LogImportError: The name does not match the pattern.
    """
    try:
        when = datetime.strptime(path.stem, pattern)
    except ValueError:
        raise LogImportError(f"{path.name}: its name does not match --start-from-name "
                             f"{pattern!r} (the name without its extension is matched "
                             "whole)") from None
    return epoch_ns(when if when.tzinfo is not None else when.replace(tzinfo=UTC))


class _Timeline:
    """The unit's timer as ticks on one timeline, epoch by epoch, with what it shows."""

    def __init__(self, unit: str, result: Imported, restarts: Sequence[int]) -> None:
        self.unit, self.result = unit, result
        self.restarts = deque(restarts)  # the instants of the resets' first records
        self.last_timer: int | None = None
        self.last_ticks = 0
        self.last_code = 0
        self.epoch_ns = 0  # the epoch's first record's instant, before the filter delay
        self.epoch_ticks = 0
        self.events: list[Event] = []

    @property
    def period(self) -> float:
        """The output period in ticks (62.5 a ms: 187.5 at 3 ms)."""
        return TICKS_PER_SECOND * self.result.decimation / 1000

    def _off_lattice(self, step: np.ndarray) -> np.ndarray:
        """Steps that are not whole output periods: a corrupt timer, or a new phase."""
        periods = np.rint(step / self.period)
        return np.asarray((np.abs(step - periods * self.period) > _LATTICE_TOLERANCE)
                          | (periods < 1))

    def _glitch(self, timers: list[int], i: int) -> bool:
        """Whether record ``i``, doubtful (off the lattice, or back as at a reset), is corrupt.

        Its checksum and plausibility passed, but the record after it runs on from the one
        before it, as the live path judges (``TimerUnwrapper``).
        """
        if i + 1 >= len(timers) or self.last_timer is None:
            return False
        step = (timers[i + 1] - self.last_timer) % (1 << 32)
        return step <= _ROLLOVER_TICKS and not self._off_lattice(np.array([step]))[0]

    def sampling(self, batch: Batch) -> None:
        """A 0xDB reply: the output period and filter width from here on."""
        self.result.decimation = max(1, int(batch["decimation"][-1]))
        self.result.decimation_from_log = True
        self.result.filter_width = max(1, int(batch["filter_width"][-1]))
        self.result.filter_from_log = True

    def _learn_period(self, timers: npt.NDArray[np.integer]) -> None:
        """The output period from the timer's own steps, where no 0xDB reply gave it.

        Without it a log at any rate but the factory's 100 Hz would be all gaps. The
        median step is the period however many records the gaps lost.
        """
        steps = np.mod(np.diff(timers.astype(np.int64)), 1 << 32)
        steps = steps[(steps > 0) & (steps <= _ROLLOVER_TICKS)]
        if len(steps):
            ms = float(np.median(steps)) * 1000 / TICKS_PER_SECOND
            self.result.decimation = max(1, round(ms))

    def timed(self, batch: Batch, log: LogFile,
              first_in_file: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """The batch's records on the timeline; its rollovers, gaps, resets, glitches noted.

        Returns:
            Each record's ticks and its instant (``time_ns``), each in its own epoch, and
            which records to keep (None: all; the others' timers were corrupt).

        Raises:
            LogImportError: A start is missing, or a reset has no start.
        """
        if not self.result.decimation_from_log:
            self._learn_period(batch["timer"])
        fast = self._ticks_at_once(batch)
        if fast is not None:
            return fast, self.origin_ns + fast * NS_PER_TICK - self._middle(batch.code), None
        timers = batch["timer"].astype(np.int64).tolist()
        ticks = np.empty(len(timers), np.int64)
        origins = np.empty(len(timers), np.int64)  # a reset in the batch changes it
        keep = np.ones(len(timers), bool)
        for i, timer in enumerate(timers):
            if self.last_timer is None:
                self._new_epoch(log, timer, first=True, at_ticks=0)
            else:
                back = timer < self.last_timer
                step = (timer - self.last_timer) % (1 << 32)
                reset = back and step > _ROLLOVER_TICKS
                doubtful = reset or self._off_lattice(np.array([step]))[0]
                if doubtful and batch.code == self.last_code and self._glitch(timers, i):
                    keep[i] = False
                    self._event(Event.GLITCH, "glitch", self.last_ticks, 1,
                                f"a corrupt timer ({timer}): the record is dropped")
                    ticks[i], origins[i] = self.last_ticks, self.origin_ns
                    continue
                if reset:  # the timer began again
                    self._new_epoch(log, timer, first=first_in_file and i == 0,
                                    at_ticks=self.last_ticks + round(self.period))
                else:
                    if back:
                        self._event(Event.ROLLOVER, "rollover", self.last_ticks + step, 1,
                                    "the 32-bit timer wrapped")
                    # a record dropped for its timer arrived: it is not missing
                    lost = round(step / self.period) - 1 - int(i > 0 and not keep[i - 1])
                    if lost > 0 and batch.code == self.last_code:  # not at a mode switch
                        self.result.missing += lost
                        self._event(Event.GAP, "gap", self.last_ticks + step, lost, "")
                    self.last_ticks += step
            ticks[i], origins[i] = self.last_ticks, self.origin_ns
            self.last_timer, self.last_code = timer, batch.code
        return (ticks, origins + ticks * NS_PER_TICK - self._middle(batch.code),
                None if keep.all() else keep)

    def _middle(self, code: int) -> int:
        """How much earlier records of ``code`` describe than their cycle (``period_middle_ns``)."""
        return period_middle_ns(code, self.result.decimation)

    def _ticks_at_once(self, batch: Batch) -> np.ndarray | None:
        """``ticks`` of a batch with no reset or glitch in it (nearly all), at once."""
        if self.last_timer is None or not len(batch):
            return None
        timers = batch["timer"].astype(np.int64)
        raw = np.diff(timers, prepend=self.last_timer)
        step = raw % (1 << 32)
        back = raw < 0
        off = self._off_lattice(step)
        if batch.code != self.last_code:
            off[0] = False  # a new record type may start on a new phase
        if (back & (step > _ROLLOVER_TICKS)).any() or off.any():
            return None  # a reset or a corrupt timer: record by record
        ticks = self.last_ticks + np.cumsum(step)
        for i in np.flatnonzero(back).tolist():
            self._event(Event.ROLLOVER, "rollover", int(ticks[i]), 1, "the 32-bit timer wrapped")
        lost = np.rint(step / self.period).astype(np.int64) - 1
        if batch.code != self.last_code:
            lost[0] = 0  # not at a mode switch
        for i in np.flatnonzero(lost > 0).tolist():
            self.result.missing += int(lost[i])
            self._event(Event.GAP, "gap", int(ticks[i]), int(lost[i]), "")
        self.last_timer, self.last_ticks = int(timers[-1]), int(ticks[-1])
        self.last_code = batch.code
        return ticks

    def _new_epoch(self, log: LogFile, timer: int, first: bool, at_ticks: int) -> None:
        """An epoch from its first record's instant.

        The log's own start where the epoch begins the log, else the next of
        ``restarts``; with neither, an error that says what to give.
        """
        if first and log.start_ns is not None:
            start, source = log.start_ns, f"{log.path.name} starts"
        elif self.last_timer is None:
            raise LogImportError(f"{log.path}: give the instant of its first record "
                                 "(--start, or --start-from-name for loggers that name "
                                 "their files by time)")
        elif self.restarts:
            start, source = self.restarts.popleft(), "the next --start gives"
        else:
            where = "at its first record" if first else "inside it"
            raise LogImportError(
                f"{log.path}: the unit's timer began again {where} (reset "
                f"{self.result.events['reset'] + 1}, at timer {timer}), and no byte tells "
                "when; give that record's instant as a further --start (one per reset, in "
                "order), or name each log by its start (--start-from-name)")
        self.epoch_ns, self.epoch_ticks = start, at_ticks
        self.last_ticks = at_ticks
        if self.last_timer is not None:
            self._event(Event.RESET, "reset", at_ticks, 1,
                        f"the timer began again at {timer}; {source} a new epoch")

    def _event(self, kind: Event.Kind, name: str, ticks: int, count: int, detail: str) -> None:
        self.result.events[name] += 1
        at = self.origin_ns + ticks * NS_PER_TICK
        self.events.append(Event(unit=self.unit, time_ns=at, ticks=ticks, kind=kind,
                                 count=count, detail=detail))

    @property
    def origin_ns(self) -> int:
        """The instant of ticks 0 in this epoch: a record's instant is this plus its ticks.

        The epoch's start plus device time since its first record, less the filter delay.
        """
        delay = filter_delay_ns(self.result.filter_width)
        return self.epoch_ns - self.epoch_ticks * NS_PER_TICK - delay


def import_logs(logs: Sequence[LogFile], out: Path, unit: str, prefix: str = "gx3",
                little_endian: bool = False,
                on_bytes: Callable[[int], None] | None = None,
                restarts: Sequence[int] = ()) -> Imported:
    """Frame one unit's byte logs, in order, into an archive timed by its timer.

    Args:
        logs: The logs in the order they were written; the first has its start.
        out: The archive to write (a command's temporary file: it is written whole).
        unit: The unit's name in the archive's keys.
        prefix: The keys' first chunk.
        little_endian: Floats start little-endian (0xDB replies switch it).
        on_bytes: Hears how many bytes were read, read by read.
        restarts: The instant of each reset's first record, in order (ns since the
            epoch), for resets that do not begin a log with its own start.

    Returns:
        What was imported.

    Raises:
        LogImportError: A log is an MCAP file, every log is empty, no record in the
            logs, a start missing, a reset whose time the logs cannot tell, or more
            restarts than resets.
        OSError: A log cannot be read.
        ArchiveError: The archive cannot be written.
    """
    _check_logs(logs)
    result = Imported(unit)
    framer = Framer(_EXPECT, little_endian=little_endian)
    timeline = _Timeline(unit, result, restarts)
    starts = {str(log.path): log.start_ns for log in logs}
    writer = ArchiveWriter(out, prefix=prefix, metadata={
        "host_clock": "none", "timed_by": "the unit's timer (gx3 import)",
        "logs": json.dumps([str(log.path) for log in logs]),
        "starts_ns": json.dumps(starts), "restarts_ns": json.dumps(list(restarts))})
    info_code = [0]  # the record type of the last Info written

    def take(batch: Batch, log: LogFile, first_in_file: bool) -> None:
        """One batch the framer found: settings kept, records timed and written."""
        if batch.code == SAMPLING:
            timeline.sampling(batch)
            return
        ticks, time_ns, keep = timeline.timed(batch, log, first_in_file)
        if keep is not None:
            batch, ticks, time_ns = batch.select(keep), ticks[keep], time_ns[keep]
        if batch.code != info_code[0]:  # the first records, or the unit switched type
            info_code[0] = batch.code
            _info(writer, prefix, unit, log, batch, result, int(time_ns[0]))
        _events(writer, prefix, timeline)  # first: the writer orders over a window
        _samples(writer, prefix, unit, batch, ticks, time_ns, result)

    try:
        for log in logs:
            first_in_file = True
            with log.path.open("rb") as stream:
                while chunk := stream.read(_READ_BYTES):
                    for batch in framer.feed(chunk):
                        take(batch, log, first_in_file)
                        first_in_file = first_in_file and batch.code == SAMPLING
                    if on_bytes is not None:
                        on_bytes(len(chunk))
        for batch in framer.flush():
            take(batch, logs[-1], False)
        result.stats = framer.stats
        if not result.samples:
            raise LogImportError(_nothing_found(logs, little_endian))
        if timeline.restarts:
            raise LogImportError(
                f"{len(restarts) + 1} --start given, but the logs hold "
                f"{counted(len(restarts) - len(timeline.restarts) + 1, 'epoch')}: give "
                "one --start per epoch (the first record's, then one per reset)")
        _status(writer, prefix, unit, logs[-1], result, info_code[0])
        writer.add_metadata("gx3.import", {
            "unit": unit, "filter_width": str(result.filter_width),
            "filter_width_from": "log" if result.filter_from_log else "factory",
            "decimation": str(result.decimation),
            "decimation_from": "log" if result.decimation_from_log else "timer",
            "checksum_failures": str(framer.stats.checksum_failures),
            "bytes_skipped": str(framer.stats.bytes_skipped)})
    except BaseException:
        writer.abandon()
        raise
    writer.close()
    return result


def _check_logs(logs: Sequence[LogFile]) -> None:
    """Refuse, saying what they are, logs that are no unit's bytes at all.

    An archive given by mistake would otherwise be "not a 3DM-GX3 byte log", and an
    empty log hold no record: neither says what to do.
    """
    for log in logs:
        if is_mcap(log.path):
            raise LogImportError(f"{log.path} is an MCAP archive, not a byte log: gx3 "
                                 "export, rrd and allan read it as it is (a raw capture "
                                 "of a bridge's: gx3 replay)")
    if all(log.path.stat().st_size == 0 for log in logs):
        what = "is empty" if len(logs) == 1 else "are all empty"
        raise LogImportError(f"{', '.join(str(log.path) for log in logs)} {what}: nothing "
                             "to import")


def _nothing_found(logs: Sequence[LogFile], little_endian: bool) -> str:
    """Why no record came out, with the option to change where the other byte order works."""
    names = ", ".join(str(log.path) for log in logs)
    with logs[0].path.open("rb") as stream:
        head = stream.read(_HEAD_BYTES)
    found = other_byte_order(head, _EXPECT, little_endian)
    if found:
        fix = "--little-endian" if not little_endian else "without --little-endian"
        return (f"no record found in {names}, but {found:,} in its first "
                f"{len(head):,} bytes with floats {'big' if little_endian else 'little'}"
                f"-endian: try {fix}")
    return f"no record found in {names}: not a 3DM-GX3 byte log"


def _status(writer: ArchiveWriter, prefix: str, unit: str, log: LogFile, result: Imported,
            code: int) -> None:
    """The import's totals as the unit's Status at its last sample, as a bridge's at its end.

    It has no host clock (unknown) and no clock model: no host received a byte.
    """
    stats = result.stats
    status = Status(unit=unit, time_ns=result.last_ns, state=Status.STOPPED, port=str(log.path),
                    command=code, output_rate_hz=1000 / result.decimation,
                    samples=sum(result.samples.values()), dropped=result.missing,
                    checksum_failures=stats.checksum_failures, implausible=stats.implausible,
                    bytes_skipped=stats.bytes_skipped, resyncs=stats.resyncs,
                    glitches=result.events["glitch"])
    writer.write(f"{prefix}/{unit}/status", status.SerializeToString(), result.last_ns)


def _info(writer: ArchiveWriter, prefix: str, unit: str, log: LogFile, batch: Batch,
          result: Imported, at_ns: int) -> None:
    """The unit's Info as the log shows it: no link, no baud rate (no host timed it)."""
    info = Info(unit=unit, port=str(log.path), command=batch.code,
                decimation=result.decimation, filter_width=result.filter_width,
                flags=0x10 if batch.little_endian else 0,
                output_rate_hz=1000 / result.decimation, bring_up_time_ns=at_ns)
    writer.write(f"{prefix}/{unit}/info", info.SerializeToString(), at_ns)


def _samples(writer: ArchiveWriter, prefix: str, unit: str, batch: Batch, ticks: np.ndarray,
             time_ns: np.ndarray, result: Imported) -> None:
    if not len(batch):
        return
    none = np.zeros(len(batch), np.int64)  # no receive time: nothing received it live
    writer.write_many(f"{prefix}/{unit}/imu", encode_batch(unit, batch, ticks, time_ns, none),
                      time_ns)
    result.samples[batch.code] += len(batch)
    result.first_ns = result.first_ns or int(time_ns[0])
    result.last_ns = int(time_ns[-1])


def _events(writer: ArchiveWriter, prefix: str, timeline: _Timeline) -> None:
    for event in timeline.events:
        writer.write(f"{prefix}/{event.unit}/event", event.SerializeToString(), event.time_ns)
    timeline.events.clear()
