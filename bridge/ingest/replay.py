"""`gx3 replay`: raw captures through the live path's framer and timing, into an archive.

A replay frames a capture's bytes with the live bridge's framer and times its records
with the same ``StreamTiming``, told what the live bridge told it at the same points of
the stream, so the samples and their ``time_ns`` come out as the live bridge published
them, with no Zenoh involved. A capture without metadata (another program's) is
understood from its bytes and receive times. How, and what is inferred from what:
``docs/design/archive.md``.
"""

from __future__ import annotations

import contextlib
import functools
import itertools
import os
from collections import Counter
from collections.abc import Callable, Collection, Iterable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from google.protobuf.message import DecodeError

from bridge._workers import Workers, share_out
from bridge.archive.rawcapture import LATE_READS, REALTIME_FROM_NS, capture_metadata
from bridge.archive.reader import ArchiveReader, Messages
from bridge.archive.walk import read_archive, summary_counts
from bridge.archive.writer import ArchiveWriter
from bridge.bus.codec import encode_batch
from bridge.bus.gx3_pb2 import Event, Info
from bridge.exceptions import ArchiveReadError, ReplayError, UnusableCapture
from bridge.protocol.codec import Batch
from bridge.protocol.framer import Framer
from bridge.protocol.table import DATA_CODES, DEFAULT_BAUD, MAX_OUTPUT_HZ, TICKS_PER_SECOND
from bridge.timing.links import infer_transport
from bridge.timing.realtime import ChangeKind, ClockChange, RealtimeReads
from bridge.timing.steps import find_steps, raw_like, unwrap_timer
from bridge.timing.stream import Settings, StreamTiming
from bridge.timing.unwrap import TimingKind

SET_CONTINUOUS, SAMPLING, TIMER = 0xC4, 0xDB, 0xD7
_EXPECT = frozenset(DATA_CODES | {SET_CONTINUOUS, SAMPLING, TIMER})
_EVENT_KINDS: dict[str, Event.Kind] = {kind: getattr(Event, kind.name) for kind in TimingKind}
_CLOCK_KINDS = {ChangeKind.STEP: Event.HOST_CLOCK_STEP, ChangeKind.SLEW: Event.HOST_CLOCK_SLEW}
FACTORY_FILTER_WIDTH = 15
_SNIFF_READS = 400
_INFER_READS = 500_000  # minutes of reads: plenty to tell the link by
_GROUP = 4096  # records timed and encoded together
_FEED_BYTES = 1 << 20  # reads framed together

#: Where replayed messages go: key, payloads, receive time (one, or one per payload).
Emit = Callable[[str, Sequence[bytes], "np.ndarray | int"], None]


@dataclass
class CapturedReads:
    """One unit's reads from a raw capture, in the order they were made.

    Their receive times on the realtime clock (``rx_ns``) and on the raw monotonic clock
    (``raw_ns``; None for an older capture, which has none), their bytes, what its bridge
    said of the unit and the link (``metadata``), and the raw topic they came from.
    """

    unit: str
    rx_ns: np.ndarray
    data: list[bytes]
    metadata: dict[str, str] = field(default_factory=dict)
    topic: str = ""
    raw_ns: np.ndarray | None = None


def _read_times(archive: ArchiveReader, messages: Messages
                ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """A raw topic's receive times on the realtime and the raw clock, and the reads' order.

    The times are in the order the reads were made; the raw ones are None for an older
    capture, which has none.

    A publish time of 10^18 or more is an older capture's realtime stamp. Otherwise it is
    the raw stamp and the log time the realtime one, except for a read an archive wrote
    later than its reorder window, at the log time of the message before it: its own is
    in the archive's ``gx3.late_reads`` records.
    """
    order = np.argsort(messages.sequence, kind="stable")  # the order they were read in
    log = messages.log_time[order].astype(np.int64)
    published = messages.publish_time[order].astype(np.int64)
    if len(published) == 0 or (published >= REALTIME_FROM_NS).any():
        return np.where(published >= REALTIME_FROM_NS, published, log), None, order
    late: dict[int, int] = {}
    for m in archive.metadata:
        if m.name == LATE_READS and m.metadata.get("topic") == messages.topic:
            late.update(zip(map(int, m.metadata["sequence"].split(",")),
                            map(int, m.metadata["receive_ns"].split(",")), strict=True))
    if late:
        sequence = messages.sequence[order].astype(np.int64)
        fix = np.flatnonzero(np.isin(sequence, list(late)))
        log[fix] = [late[int(s)] for s in sequence[fix]]
    return log, published, order


def captures(path: Path, prefix: str = "gx3",
             topics: Collection[str] | None = None) -> list[CapturedReads]:
    """Every unit's raw reads in a file: a bridge's --capture file, or an archive.

    Args:
        path: The file.
        prefix: The key prefix the reads were recorded under (named in the error).
        topics: Only these raw topics; None: every unit's.

    Returns:
        Each unit's reads.

    Raises:
        UnusableCapture: The file holds no raw reads.
        ArchiveReadError: The file is missing, empty or not MCAP.
    """
    archive: ArchiveReader = read_archive(path)
    meta = {m.metadata.get("unit", ""): dict(m.metadata) for m in archive.metadata
            if m.name == "gx3.capture"}
    for topic in archive.topics("info"):  # an archive of reads that came over Zenoh
        for payload in archive.messages(topic).payloads[:1]:
            with contextlib.suppress(DecodeError):  # a damaged Info: settings from the bytes
                info = Info.FromString(payload)
                meta.setdefault(info.unit, capture_metadata(info))
    out = []
    for topic in archive.topics("raw"):
        if topics is not None and topic not in topics:
            continue
        messages = archive.messages(topic)
        real, raw, order = _read_times(archive, messages)
        out.append(CapturedReads(messages.unit, real,
                                 [messages.payloads[i] for i in order.tolist()],
                                 meta.get(messages.unit, {}), topic, raw))
    if not out:
        raise UnusableCapture(f"{path}: no raw reads in it (topics {prefix}/<unit>/raw); record "
                          "one with gx3 bridge --capture FILE.mcap")
    return out


@dataclass
class Replayed:
    """What the replay of one unit gave.

    The samples archived, the events by kind, the settings its records were timed with
    at the end, and what was inferred from the bytes (a capture without metadata).
    """

    unit: str
    samples: int = 0
    events: Counter[str] = field(default_factory=Counter)
    settings: Settings | None = None
    inferred: list[str] = field(default_factory=list)


def _latency_timer_ms(text: str | None) -> int | None:
    """A capture's latency timer, ms; None where it was not known."""
    return int(text) if text and text.isdigit() and int(text) > 0 else None


class _UnitReplay:
    """Frames and times one unit's reads exactly as its live bridge did."""

    def __init__(self, capture: CapturedReads, transport: str | None = None) -> None:
        self.capture = capture
        self.result = Replayed(capture.unit)
        little_endian = self._little_endian()
        #: the receive times records are timed by: the raw clock's, or for a capture that
        #: has realtime stamps only, those with the host clock's steps taken out: found
        #: first as on any link, for telling the link by, then again over its frames
        records = None if capture.raw_ns is not None else self._record_reads(little_endian)
        self.steady = self._unstepped(records, 0) if records is not None else \
            np.asarray(capture.raw_ns)
        self.settings = self._initial_settings(little_endian, transport)
        if records is not None and self.settings.frame_ns:
            self.steady = self._unstepped(records, self.settings.frame_ns)
        self.framer = Framer(_EXPECT, little_endian=little_endian)
        self.host = RealtimeReads(self.steady, capture.rx_ns)
        self.timing = StreamTiming(self.host)
        self._pending: list[Batch] = []
        self._pending_records = 0
        #: the Info's flags and magnetometer filter width beyond ``settings``: the
        #: capture's metadata's until a 0xDB reply in it says otherwise
        self._flags = int(capture.metadata.get("flags", "0"))
        self._mag_filter_width = 0  # not known

    # --- what the capture says, or what its bytes show ----------------------------------
    def _initial_settings(self, little_endian: bool, transport: str | None) -> Settings:
        """From the capture's metadata, or else its bytes and receive times.

        A ``transport`` given overrides the link either gives.
        """
        meta = self.capture.metadata
        if {"record", "decimation", "filter_width", "baud"} <= meta.keys():
            return Settings(record=int(meta["record"], 0), decimation=int(meta["decimation"]),
                            filter_width=int(meta["filter_width"]), baud=int(meta["baud"]),
                            transport=transport or meta.get("transport", "uart"),
                            polled=meta.get("polled") == "true",
                            latency_timer_ms=None if transport else
                            _latency_timer_ms(meta.get("latency_timer_ms")))
        record, decimation = self._sniff()
        self.result.inferred += [f"record 0x{record:02X}", f"decimation {decimation}",
                                 f"filter width {FACTORY_FILTER_WIDTH} (factory)"]
        settings = Settings(record=record, decimation=decimation,
                            filter_width=FACTORY_FILTER_WIDTH, baud=DEFAULT_BAUD)
        if transport:
            return replace(settings, transport=transport)
        link = infer_transport(self.steady[:_INFER_READS],
                               self.capture.data[:_INFER_READS], record, little_endian)
        self.result.inferred.append(link.describe())
        baud = link.baud
        if baud is None and link.transport != "usb":
            # the line's pace did not show: the manual's pairing of rate and baud rate
            rate = 1000 / decimation
            baud = next((b for b, most in sorted(MAX_OUTPUT_HZ.items()) if most >= rate),
                        max(MAX_OUTPUT_HZ))
            self.result.inferred.append(f"baud {baud} (the manual's Table 5 pairs "
                                        f"{rate:g} Hz with it; the reads did not show it)")
        return replace(settings, transport=link.transport, baud=baud or DEFAULT_BAUD,
                       latency_timer_ms=link.latency_timer_ms)

    def _sniff_batches(self, little_endian: bool) -> list[Batch]:
        framer = Framer(DATA_CODES, little_endian=little_endian)
        reads = self.capture.data[:_SNIFF_READS]
        return [b for found in frame_reads(framer, np.arange(len(reads)), reads) for b in found]

    def _record_reads(self, little_endian: bool) -> tuple[np.ndarray, np.ndarray]:
        """Every data record's timer and the read that completed it (index into reads)."""
        framer = Framer(DATA_CODES, little_endian=little_endian)
        found = [b for group in frame_reads(framer, np.arange(len(self.capture.data)),
                                            self.capture.data) for b in group]
        found += framer.flush()
        if not found:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        return (np.concatenate([b["timer"] for b in found]),
                np.concatenate([b.rx_ns for b in found]))

    def _unstepped(self, records: tuple[np.ndarray, np.ndarray], frame_ns: int) -> np.ndarray:
        """The capture's realtime receive times with the host clock's steps taken out.

        The steps are those the data records (``_record_reads``) show
        (``bridge.timing.steps``), epoch by epoch; ``frame_ns``: the USB frame that carried
        the reads, 0 on a UART.
        """
        timers, reads = records
        if not len(timers):
            return self.capture.rx_ns
        ticks, epochs = unwrap_timer(timers)
        steps: list[tuple[int, int]] = []
        for lo, hi in itertools.pairwise([*epochs.tolist(), len(ticks)]):
            steps += [(lo + first, size) for first, size
                      in find_steps(ticks[lo:hi], self.capture.rx_ns[reads[lo:hi]], frame_ns)]
        return raw_like(self.capture.rx_ns, reads, steps)

    def _little_endian(self) -> bool:
        """The float byte order the capture starts in (a 0xDB reply may switch it)."""
        flags = self.capture.metadata.get("flags")
        if flags is not None:
            return bool(int(flags) & 0x10)
        big = sum(len(b) for b in self._sniff_batches(False))
        little = sum(len(b) for b in self._sniff_batches(True))
        if little > big:
            self.result.inferred.append("little-endian floats")
        return little > big

    def _sniff(self) -> tuple[int, int]:
        batches = self._sniff_batches(False) or self._sniff_batches(True)
        if not batches:
            raise UnusableCapture(f"{self.capture.unit}: no record found in the first "
                              f"{_SNIFF_READS} reads: not a capture of a 3DM-GX3")
        counts: Counter[int] = Counter()
        for b in batches:
            counts[b.code] += len(b)
        record = counts.most_common(1)[0][0]
        timers = np.concatenate([b["timer"] for b in batches if b.code == record])
        steps = np.mod(np.diff(timers.astype(np.int64)), np.int64(1 << 32))
        steps = steps[steps > 0]
        period = float(np.median(steps)) if len(steps) else 625.0
        return record, max(1, min(1000, round(period / (TICKS_PER_SECOND / 1000))))

    # --- replay --------------------------------------------------------------------------
    def _info(self, emit: Emit, prefix: str, at_ns: int) -> None:
        """The unit's Info, as its bridge published it.

        So the archive is complete, and the offline time estimate knows the settings.
        """
        s, meta = self.settings, self.capture.metadata
        info = Info(unit=self.capture.unit, port=meta.get("port", ""), baud=s.baud,
                    command=s.record, decimation=s.decimation, filter_width=s.filter_width,
                    flags=self._flags, output_rate_hz=1000 / s.decimation,
                    firmware_text=meta.get("firmware", ""), link=s.transport,
                    latency_timer_ms=s.latency_timer_ms or 0, bring_up_time_ns=at_ns,
                    mag_filter_width=self._mag_filter_width)
        emit(f"{prefix}/{self.capture.unit}/info", [info.SerializeToString()], at_ns)

    def run(self, emit: Emit, prefix: str) -> Replayed:
        if len(self.capture.rx_ns):
            self._info(emit, prefix, int(self.capture.rx_ns[0]))
        for change in self.host.changes():
            self._clock_changed(change, emit, prefix)
        for found in frame_reads(self.framer, self.steady, self.capture.data):
            for batch in found:
                self._batch(batch, emit, prefix)
        for batch in self.framer.flush():
            self._batch(batch, emit, prefix)
        self._flush(emit, prefix)
        self.result.settings = self.settings
        return self.result

    def _flush(self, emit: Emit, prefix: str) -> None:
        """Time and archive the records gathered since the last settings change in one go.

        The timing gives the same results however records are grouped.
        """
        pending, self._pending, self._pending_records = self._pending, [], 0
        if pending:
            self._samples(Batch.concatenate(pending), emit, prefix)

    def _batch(self, batch: Batch, emit: Emit, prefix: str) -> None:
        if batch.code in DATA_CODES and batch.code != self.settings.record:
            # the unit was switched to another record with no 0xC4 reply in the capture
            # (a logger's commands, not the bridge's): its records are kept and timed as
            # they are, the timer running on
            self._flush(emit, prefix)
            self.settings = replace(self.settings, record=batch.code)
            if self.timing.timeline is not None:
                self.timing.configure(self.settings, restarted=False)
        if batch.code in DATA_CODES:
            if self.timing.timeline is None:  # the capture began mid-stream
                self.timing.configure(self.settings, restarted=False)
            self._pending.append(batch)
            self._pending_records += len(batch)
            if self._pending_records >= _GROUP:
                self._flush(emit, prefix)
            return
        self._flush(emit, prefix)  # what came before a settings change is timed by them
        if batch.code == SAMPLING:
            self.settings = replace(self.settings,
                                    decimation=max(1, int(batch["decimation"][-1])),
                                    filter_width=max(1, int(batch["filter_width"][-1])))
            self._flags = int(batch["flags"][-1])
            self._mag_filter_width = int(batch["mag_filter_width"][-1])
            if self.timing.timeline is not None:
                self.timing.configure(self.settings, restarted=True)
        elif batch.code == SET_CONTINUOUS:
            self.settings = replace(self.settings, record=int(batch["command"][-1]))
            self.timing.configure(self.settings, restarted=True)
        elif batch.code == TIMER and self.timing.timeline is not None:
            self.timing.configure(self.settings, restarted=True)
        if batch.code in (SAMPLING, SET_CONTINUOUS):
            # the unit's own word on its settings, as its bridge publishes Info after
            # bring-up: what the archive's readers (the export's timing) go by
            read = batch.rx_ns[-1:]
            self._info(emit, prefix, int(self.host.map_array(read, read)[0]))

    def _clock_changed(self, change: ClockChange, emit: Emit, prefix: str) -> None:
        """A step or slew of the host clock, as the live bridge published it."""
        unit = self.capture.unit
        self.result.events[f"host clock {change.kind}"] += 1
        event = Event(unit=unit, time_ns=change.real_ns, kind=_CLOCK_KINDS[change.kind],
                      count=1, detail=change.describe(), clock_change_ns=change.size_ns)
        emit(f"{prefix}/{unit}/event", [event.SerializeToString()], change.real_ns)

    def _samples(self, batch: Batch, emit: Emit, prefix: str) -> None:
        unit = self.capture.unit
        timed = self.timing.process(batch)
        for ev in timed.events:
            self.result.events[ev.kind] += 1
            # the live bridge tells right after the read that held the record
            read = batch.rx_ns[min(max(ev.index, 0), len(batch) - 1) :][:1]
            at = int(self.host.map_array(read, read)[0])
            event = Event(unit=unit, time_ns=at, ticks=int(ev.ticks),
                          kind=_EVENT_KINDS.get(ev.kind, Event.KIND_UNSPECIFIED),
                          count=max(1, int(ev.count)))
            emit(f"{prefix}/{unit}/event", [event.SerializeToString()], at)
        if not len(timed.batch):
            return
        payloads = encode_batch(unit, timed.batch, timed.ticks, timed.time_ns, timed.rx_ns,
                                timed.batch.rx_ns if self.capture.raw_ns is not None
                                else np.zeros(len(timed.batch), np.int64),
                                timed.part if self.capture.raw_ns is not None else None)
        emit(f"{prefix}/{unit}/imu", payloads, timed.rx_ns)
        self.result.samples += len(payloads)


def frame_reads(framer: Framer, rx_ns: np.ndarray, reads: list[bytes]) -> Iterator[list[Batch]]:
    """The framer's records from ``reads`` (received at ``rx_ns``), a megabyte of reads at a time.

    The same records and times as read by read, for a fraction of the cost.
    """
    sizes = np.fromiter(map(len, reads), np.int64, len(reads))
    ends = np.cumsum(sizes)
    cuts = np.searchsorted(ends, np.arange(_FEED_BYTES, int(ends[-1]) if len(ends) else 0,
                                           _FEED_BYTES), side="right")
    bounds = [0, *np.unique(cuts).tolist(), len(reads)]
    for lo, hi in itertools.pairwise(bounds):
        if hi > lo:
            start = ends[lo] - sizes[lo]
            yield framer.feed_reads(b"".join(reads[lo:hi]), ends[lo:hi] - start, rx_ns[lo:hi])


def replay(paths: Iterable[Path], out: Path, prefix: str = "gx3",
           on_unit: Callable[[Replayed], None] | None = None,
           jobs: int | None = 1,
           on_samples: Callable[[int], None] | None = None,
           transport: str | None = None) -> list[Replayed]:
    """Replay every unit of every capture into one archive.

    With ``jobs`` > 1, worker processes replay at once and the archive is written here:
    a capture file each, or a unit each when there are fewer files than jobs (a fleet's
    archive recorded with --raw). Units are independent, so each gets the same samples;
    only their messages interleave in the file differently.

    A capture without metadata (another program's) is understood from its bytes: the
    record type is the most common data record, the rate comes from the timer steps,
    the float byte order from whichever decodes, the filter width is the factory's 15
    unless a 0xDB reply says otherwise, and the link (UART, USB, or a USB-serial adapter
    and its latency timer) comes from the receive times; ``Replayed.inferred`` says
    what was inferred.

    Args:
        paths: Raw captures (a bridge's --capture files) or archives holding raw reads.
        out: The archive to write.
        prefix: The key prefix of the captures' raw topics and of the archive's messages.
        on_unit: Hears each unit's result as it finishes.
        jobs: Processes replaying at once; None: one per core.
        on_samples: Hears how many samples each write added to the archive.
        transport: Time every unit as on this link (``uart``, ``usb``, ``usb-serial``),
            whatever its capture says or shows.

    Returns:
        Each unit's result, in the order of ``paths``.

    Raises:
        UnusableCapture: A file holds no raw reads, or none a 3DM-GX3 sent.
        ArchiveReadError: A file is missing, empty or not MCAP.
        ArchiveError: The archive cannot be written.
        ReplayError: A worker process stopped.
    """
    paths = list(paths)
    jobs = max(1, (os.cpu_count() or 1) if jobs is None else jobs)
    tasks = _tasks(paths, jobs) if jobs > 1 else []
    if len(tasks) > 1:
        return _replay_in_workers(tasks, out, prefix, on_unit, on_samples,
                                  min(jobs, len(tasks)), transport)
    results = []
    with _archive(out, prefix) as writer:
        emit = _counted(writer.write_many, on_samples)
        for path in paths:
            for capture in captures(path, prefix):
                results.append(_UnitReplay(capture, transport).run(emit, prefix))
                if on_unit is not None:
                    on_unit(results[-1])
    return results


def _counted(emit: Emit, on_samples: Callable[[int], None] | None) -> Emit:
    """``emit`` that tells ``on_samples`` how many samples each write added."""
    if on_samples is None:
        return emit
    tell = on_samples

    def counted(key: str, payloads: Sequence[bytes], receive_ns: np.ndarray | int) -> None:
        emit(key, payloads, receive_ns)
        if key.endswith("/imu"):
            tell(len(payloads))

    return counted


@dataclass(frozen=True)
class _Task:
    """What one worker replays: a whole capture file, or one unit's raw topic in it."""

    index: int  # the file's place in the caller's list
    path: Path
    topic: str | None
    weight: int  # to share the work out: bytes of a file, reads of a topic


def _tasks(paths: list[Path], jobs: int) -> list[_Task]:
    """A task per file when there are files enough for the jobs, else one per unit."""
    if len(paths) < jobs:
        return _unit_tasks(paths)
    return [_Task(i, path, None, path.stat().st_size) for i, path in enumerate(paths)]


@contextlib.contextmanager
def _archive(out: Path, prefix: str) -> Iterator[ArchiveWriter]:
    """The replay's archive, sorted whole: finished when the replay is.

    It is abandoned unfinished when the replay fails or is interrupted (the caller throws
    the file away), so Ctrl-C is not held up by finishing a file nobody keeps.
    """
    writer = ArchiveWriter(out, prefix=prefix, reorder_s=None)
    try:
        yield writer
    except BaseException:
        writer.abandon()
        raise
    writer.close()


def _unit_tasks(paths: list[Path]) -> list[_Task]:
    """A task per unit (raw topic) of each file.

    Counted from its summary (or, for a file cut short, from its chunks); a file with
    none is a task of its own (its worker says what is wrong with it).
    """
    tasks = []
    for i, path in enumerate(paths):
        counts = summary_counts(path, "raw")
        if counts is None:
            with contextlib.suppress(ArchiveReadError):
                archive = read_archive(path)
                counts = {t: len(archive.messages(t)) for t in archive.topics("raw")}
        tasks += [_Task(i, path, t, n) for t, n in sorted((counts or {}).items())] or \
            [_Task(i, path, None, 0)]
    return tasks


@dataclass(frozen=True)
class _Emitted:
    """Messages of one key a worker replayed, for the archive (what ``Emit`` takes)."""

    key: str
    payloads: list[bytes]
    receive_ns: np.ndarray | int


@dataclass(frozen=True)
class _UnitDone:
    """A unit a worker replayed: its result, with its file's place and its raw topic.

    Results are put in the order each unit has replayed alone.
    """

    index: int
    topic: str
    result: Replayed


def _replay_in_workers(tasks: list[_Task], out: Path, prefix: str,
                       on_unit: Callable[[Replayed], None] | None,
                       on_samples: Callable[[int], None] | None,
                       jobs: int, transport: str | None) -> list[Replayed]:
    """``replay`` with the tasks shared out by weight among ``jobs`` processes.

    They start before the archive writer's thread does (``Workers``), and their messages
    are archived here as they come.
    """
    shares = share_out(tasks, [t.weight for t in tasks], jobs)
    work = functools.partial(_replay_share, prefix=prefix, transport=transport)
    done: list[_UnitDone] = []
    with Workers(work, shares, error=ReplayError, what="replay") as sent, \
            _archive(out, prefix) as writer:
        emit = _counted(writer.write_many, on_samples)
        for message in sent:
            if isinstance(message, _Emitted):
                emit(message.key, message.payloads, message.receive_ns)
            else:
                done.append(message)
                if on_unit is not None:
                    on_unit(message.result)
    return [d.result for d in sorted(done, key=lambda d: (d.index, d.topic))]


def _replay_share(tasks: list[_Task], send: Callable[[_Emitted | _UnitDone], None],
                  prefix: str, transport: str | None) -> None:
    """Replay ``tasks`` in a worker, sending their messages and each unit's result."""

    def emit(key: str, payloads: Sequence[bytes], receive_ns: np.ndarray | int) -> None:
        send(_Emitted(key, list(payloads), receive_ns))

    # one read of a file for all of its units this worker has (None: every unit)
    files: dict[tuple[int, Path], list[str] | None] = {}
    for task in tasks:
        key = (task.index, task.path)
        files[key] = None if task.topic is None else [*(files.get(key) or []), task.topic]
    for (index, path), topics in files.items():
        for capture in captures(path, prefix, topics):
            result = _UnitReplay(capture, transport).run(emit, prefix)
            send(_UnitDone(index, capture.topic, result))
