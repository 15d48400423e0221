"""The archive writer: every unit's Zenoh messages into one MCAP file, or numbered parts.

Data channels keep the very protobuf bytes that came over Zenoh, with the Zenoh key as
topic; a message is logged at the instant it describes (a sample's ``time_ns``), so
every viewer's timeline is the sensors' own. Beside them go what viewers draw: each
unit's attitude as ``foxglove.FrameTransform`` (with dots along its axes) and the
fleet's events as ``foxglove.Log``. Messages are written in log-time order and at least
once a second, so a killed recorder loses at most the last 1.5 s and its file still
opens. The layout, channel by channel: ``docs/design/archive.md``.
"""

from __future__ import annotations

import contextlib
import functools
import glob
import re
import struct
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import IO, Any, TypeVar, cast

import numpy as np
from google.protobuf.descriptor import FileDescriptor
from google.protobuf.message import DecodeError, Message

from bridge import __version__
from bridge.archive.eventlog import LOG_CLASS, log_message
from bridge.archive.frames import (
    FRAME_CLASS,
    MARKER_CLASS,
    frame_messages,
    frame_picks,
    framed,
    marker_messages,
    root_message,
    sensor_to_earth,
)
from bridge.archive.mcap_writer import McapWriter
from bridge.archive.outputs import create_locked, refuse_if_written
from bridge.archive.rawcapture import LATE_READS, RAW_CLOCK, RAW_ENCODING
from bridge.bus.codec import decode_batch, parse
from bridge.bus.gx3_pb2 import Event, ImuSample, Info, Status
from bridge.bus.keys import ENCODINGS, PREFIX, check_prefix, unit_of
from bridge.bus.schema import file_descriptor_set
from bridge.device import clock
from bridge.exceptions import ArchiveError, OutputRefused

T = TypeVar("T")
PROTOBUF = "protobuf"
FRAME_LEAF = "frame"
AXES_LEAF = "axes"
LOG_LEAF = "log"
#: Message type of the channels the archive adds beside Zenoh's.
ADDED: dict[str, type[Message]] = {FRAME_LEAF: FRAME_CLASS, AXES_LEAF: MARKER_CLASS,
                                   LOG_LEAF: LOG_CLASS}
FLUSH_EVERY_S = 1.0
#: How long (receive time) a message waits for ones logged before it: not longer than
#: FLUSH_EVERY_S, so a killed recorder loses at most the last REORDER_S + FLUSH_EVERY_S.
REORDER_S = 0.5
LIBRARY = f"gx3-bridge {__version__}"
PROFILE = ""  # no registered MCAP profile fits ours (https://mcap.dev/spec/registry)

#: Message type of each key leaf, and the field that holds its time.
MESSAGES: dict[str, tuple[type[Message], str]] = {
    "imu": (ImuSample, "time_ns"),
    "status": (Status, "time_ns"),
    "event": (Event, "time_ns"),
    "info": (Info, "bring_up_time_ns"),
}


def _frame_topic(prefix: str, unit: str) -> str:
    return f"{prefix}/{unit}/{FRAME_LEAF}"


def _fleet_topic(prefix: str, leaf: str) -> str:
    """A channel of the whole fleet (no unit): the root frame, the event log."""
    return f"{prefix}/{leaf}"


def numbered(path: Path, index: int) -> Path:
    """The ``index``-th file (from 1) of a recording split into several."""
    return path.with_name(f"{path.stem}_{index:04d}{path.suffix}")


def _next_part(path: Path) -> int:
    """The index after the highest part of the recording ``path`` already there.

    A restarted recorder adds parts, never replaces one. Refused while another process
    writes that last part (one writer per recording).
    """
    pattern = re.compile(rf"{re.escape(path.stem)}_(\d{{4,}}){re.escape(path.suffix)}")
    found = [int(m[1]) for p in path.parent.glob(f"{glob.escape(path.stem)}_*")
             if (m := pattern.fullmatch(p.name))]
    last = max(found, default=0)
    if last:
        try:
            refuse_if_written(numbered(path, last))
        except OutputRefused as exc:
            raise ArchiveError(str(exc)) from None
    return last + 1


@functools.cache
def _header(unit: str) -> struct.Struct:
    """The fixed header of the bulk ImuSample layout: unit, command, timer, ticks, time_ns."""
    return struct.Struct(f"<BB{len(unit.encode())}sBIBIBqBq")


@functools.cache
def _header_dtype(unit: str) -> np.dtype[np.void]:
    """``_header`` as a NumPy record, to read a batch's headers at once."""
    return np.dtype([("t0", "u1"), ("n", "u1"), ("name", "u1", len(unit.encode())),
                     ("t1", "u1"), ("command", "<u4"), ("t2", "u1"), ("timer", "<u4"),
                     ("t3", "u1"), ("ticks", "<i8"), ("t4", "u1"), ("time_ns", "<i8")])


_HEADER_TAGS = (0x0A, 0x15, 0x1D, 0x21, 0x29)
_BULK = 16  # messages; fewer are cheaper one by one than through arrays
_HOLD = 1024  # messages ``write`` holds at most before handing them on
#: chunks' worth of held messages that have a release go before the next flush: fewer,
#: larger releases sort and frame in bigger batches
_RELEASE_CHUNKS = 4


def _stamp(unit: str, payload: bytes) -> tuple[str, int, int]:
    """(unit, command, time_ns) of a serialized ImuSample.

    Read from its fixed header when it has the bulk layout (a few hundred ns), else by
    parsing it.
    """
    head = _header(unit)
    if len(payload) >= head.size:
        t0, n, name, t1, command, t2, _, t3, _, t4, time_ns = head.unpack_from(payload)
        if (t0, t1, t2, t3, t4) == _HEADER_TAGS and n == len(name) and n < 0x80:
            return name.decode(errors="replace"), command, time_ns
    msg = parse(payload)
    return msg.unit, msg.command, msg.time_ns


def stamps(unit: str, payloads: Sequence[bytes]) -> tuple[list[str], np.ndarray, np.ndarray]:
    """``_stamp`` of many ImuSamples: units, commands, times.

    Many payloads of one length whose headers all name ``unit`` are read as one array;
    any others one by one.
    """
    head = _header_dtype(unit)
    name = unit.encode()
    size = len(payloads[0]) if payloads else 0
    if (len(payloads) >= _BULK and size >= head.itemsize and len(name) < 0x80
            and set(map(len, payloads)) == {size}):
        rows = np.frombuffer(b"".join(payloads), np.uint8).reshape(len(payloads), size)
        h = np.ascontiguousarray(rows[:, : head.itemsize]).view(head)[:, 0]
        ok = (h["n"] == len(name)) & (rows[:, 2 : 2 + len(name)]
                                      == np.frombuffer(name, np.uint8)).all(axis=1)
        for tag, want in zip(("t0", "t1", "t2", "t3", "t4"), _HEADER_TAGS, strict=True):
            ok &= h[tag] == want
        if ok.all():
            return ([unit] * len(payloads), h["command"].astype(np.int64),
                    h["time_ns"].astype(np.int64))
    found = [_stamp(unit, p) for p in payloads]
    return ([f[0] for f in found], np.array([f[1] for f in found], np.int64),
            np.array([f[2] for f in found], np.int64))


@dataclass
class _File:
    """One open MCAP file and the ids registered in it."""

    path: Path
    stream: IO[bytes]
    writer: McapWriter
    opened_ns: int | None = None
    schemas: dict[str, int] = field(default_factory=dict)
    channels: dict[str, int] = field(default_factory=dict)
    rooted: bool = False  # the static root transform is written


@dataclass
class _Frames:
    """Attitude samples of one unit and record type waiting to become FrameTransforms."""

    unit: str
    sample_unit: str
    code: int
    payloads: list[bytes] = field(default_factory=list)
    receive_ns: list[int] = field(default_factory=list)


class ArchiveWriter:
    """Write Zenoh messages (key, payload bytes, receive time) into an MCAP archive.

    Units and message types get their channels on first sight. A message is logged at
    the instant it describes: an ImuSample at its ``time_ns``, a Status, Event or Info
    at its own time (``time_ns``, ``bring_up_time_ns``), or at its receive time where
    that is unset; its publish time is its receive time (a raw read's, its stamp on the
    raw monotonic clock). Messages are written in log-time order, each once
    ``reorder_s`` of receive time has passed its log time (the receive clock runs on
    with ``clock`` while none arrive). Call ``tick()`` at least once a second while no
    messages arrive, so the last ones reach the disk; ``close()`` finishes the file with
    its summary and index. Each file is locked while written.

    Args:
        path: The archive to create. With ``split_bytes`` or ``split_seconds``, the name
            of its numbered parts (``run.mcap``: ``run_0001.mcap``, ``run_0002.mcap``,
            ...), numbered on after any parts already there.
        prefix: The key prefix of the messages (``gx3``).
        chunk_size: Bytes of records in an MCAP chunk before it is compressed.
        split_bytes: Start the next part once the current one reaches this size.
        split_seconds: Start the next part once the current one is this old, in seconds
            of receive time.
        frames: Whether attitude samples also become ``foxglove.FrameTransform`` and
            axis dots for viewers.
        frame_rate_hz: Frames per second and unit at most (None or 0: every attitude
            sample).
        frame_spacing: Metres between neighbouring units in the frames' scene.
        reorder_s: How long (receive time) a message waits for those logged before it;
            None sorts the whole file when it is finished (a replay writes unit after
            unit).
        metadata: Written into every file, as its ``gx3.archive`` metadata record.
        clock: Monotonic seconds: the clock of flushes and of the reorder window.
        force: Replace an existing file (not a split's parts: those continue after the
            last), unless another process writes it.

    Raises:
        ArchiveError: The file exists (without ``force``), another process writes it,
            or it cannot be created.
    """

    def __init__(self, path: Path, *, prefix: str = PREFIX, chunk_size: int = 1 << 20,
                 split_bytes: int | None = None, split_seconds: float | None = None,
                 frames: bool = True, frame_rate_hz: float | None = 25.0,
                 frame_spacing: float = 0.5, reorder_s: float | None = REORDER_S,
                 metadata: dict[str, str] | None = None,
                 clock: Callable[[], float] = time.monotonic, force: bool = False) -> None:
        self.path = Path(path)
        self.force = force
        self._first_part = 1
        self.prefix = check_prefix(prefix)
        self.chunk_size = chunk_size
        self.split_bytes = split_bytes
        self.split_ns = None if split_seconds is None else int(split_seconds * 1e9)
        self.frames = frames
        self.frame_period_ns = int(1e9 / frame_rate_hz) if frame_rate_hz else 0
        self.frame_spacing = frame_spacing
        self.reorder_ns = None if reorder_s is None else int(reorder_s * 1e9)
        self.metadata = dict(metadata or {})
        self.paths: list[Path] = []
        self.messages = 0
        self.late = 0
        self._rx_latest: int | None = None
        self._rx_seen_at = 0.0
        self._clock = clock
        self._flushed = clock()
        self._slots: dict[str, int] = {}
        self._rates: dict[str, float] = {}  # output rate per unit, from its Info
        self._frame_due: dict[str, int] = {}
        self._routes: dict[str, tuple[str, str]] = {}
        self._splits = split_bytes is not None or split_seconds is not None
        self._pending: dict[tuple[str, str, int], _Frames] = {}
        self._sequence: dict[str, int] = {}
        self._broken: ArchiveError | None = None
        self._file: _File | None = None
        # messages ``write`` holds for ``write_many``, by key: payloads, receive times
        self._held: dict[str, tuple[list[bytes], list[int]]] = {}
        self._holding = 0
        self._draining = False
        self._open()

    # -- files ---------------------------------------------------------------------------

    def _open(self) -> None:
        """Create the next file exclusively and lock it (``bridge.archive.outputs``).

        An existing one is never truncated; split parts continue after those already there.
        """
        if self._splits and not self.paths:
            self._first_part = _next_part(self.path)
        index = self._first_part + len(self.paths)
        path = numbered(self.path, index) if self._splits else self.path
        try:
            stream = create_locked(path, self.force and not self._splits)
        except OutputRefused as exc:
            raise ArchiveError(str(exc)) from None
        except OSError as exc:
            raise self._fail(path, exc, opening=True) from None
        writer = McapWriter(stream, chunk_size=self.chunk_size, spill_dir=path.parent)
        self._file = _File(path, stream, writer)
        self.paths.append(path)
        self._guard(writer.start, PROFILE, LIBRARY)
        meta = {"prefix": self.prefix, "file_index": str(index),
                "frame_convention": "REP-103: gx3_world (ENU) > gx3_world_ned > "
                                    "gx3_<unit>_frd; rotation = sensor-to-earth "
                                    "(M transposed), x y z w",
                **self.metadata}
        self._guard(writer.add_metadata, "gx3.archive", meta)
        self._guard(stream.flush)  # a file killed in its first second still opens

    def _fail(self, path: Path, exc: OSError, opening: bool = False) -> ArchiveError:
        why = exc.strerror or str(exc)
        if opening:
            return ArchiveError(f"{path}: cannot write the archive ({why}); "
                                "choose a writable path")
        self._broken = ArchiveError(f"{path}: {why}; the archive stops here "
                                    "(what was written stays readable)")
        return self._broken

    def _guard(self, call: Callable[..., T], *args: Any) -> T:
        if self._broken is not None:
            raise self._broken
        try:
            return call(*args)
        except OSError as exc:
            assert self._file is not None
            raise self._fail(self._file.path, exc) from None

    def _register(self, topic: str, unit: str, leaf: str) -> int:
        """The channel of ``topic`` in the current file, registered on first sight."""
        f = self._current()
        if leaf == "raw":
            schema_id, encoding = 0, RAW_ENCODING
            meta = {"unit": unit, "zenoh_encoding": ENCODINGS["raw"], **RAW_CLOCK}
        else:
            cls = ADDED[leaf] if leaf in ADDED else MESSAGES[leaf][0]
            name = cls.DESCRIPTOR.full_name
            schema_id = f.schemas.get(name, 0)
            if not schema_id:
                schema = file_descriptor_set(cast(FileDescriptor, cls.DESCRIPTOR.file))
                schema_id = self._guard(f.writer.register_schema, name, PROTOBUF, schema)
                f.schemas[name] = schema_id
            encoding = PROTOBUF
            meta = {"unit": unit}
            if leaf in ENCODINGS:
                meta["zenoh_encoding"] = ENCODINGS[leaf]
        if leaf == "imu":
            self._slots.setdefault(unit, len(self._slots))
        cid = self._guard(f.writer.register_channel, topic, encoding, schema_id, meta)
        f.channels[topic] = cid
        return cid

    def _current(self) -> _File:
        if self._file is None:
            raise ArchiveError(f"{self.path}: the archive is closed")
        return self._file

    def _add(self, topic: str, unit: str, leaf: str, log_ns: np.ndarray,
             payloads: Sequence[bytes], receive_ns: np.ndarray,
             publish_ns: np.ndarray | None = None) -> int:
        """Hand messages of one topic to the file's writer; returns how many were taken.

        All are taken, unless the file splits by size: then about a chunk's worth, so the
        caller can look at the file's size. Their publish times are ``publish_ns``, by
        default their receive times.
        """
        f = self._current()
        cid = f.channels.get(topic) or self._register(topic, unit, leaf)
        n = len(payloads)
        if self.split_bytes is not None and n > 1:
            sizes = np.cumsum(np.fromiter(map(len, payloads), np.int64, n))
            n = min(n, int(np.searchsorted(sizes, self.chunk_size)) + 1)
        seq = self._sequence.get(topic, 0)
        if leaf == "raw":  # a read's realtime stamp is its log time: keep a late one's
            late = np.flatnonzero(f.writer.late_among(log_ns[:n]))
            if len(late):
                self._guard(f.writer.add_metadata, LATE_READS, {
                    "topic": topic, "sequence": ",".join(map(str, (seq + late).tolist())),
                    "receive_ns": ",".join(map(str, log_ns[late].tolist()))})
        published = receive_ns if publish_ns is None else publish_ns
        self._guard(f.writer.add, cid, seq, log_ns[:n], published[:n], payloads[:n])
        self._sequence[topic] = seq + n
        self.messages += n
        if n:
            self._saw(int(receive_ns[:n].max()))
        return n

    def _saw(self, rx: int) -> None:
        """Keep the latest receive time and when it came: the reorder window's clock."""
        if self._rx_latest is None or rx > self._rx_latest:
            self._rx_latest, self._rx_seen_at = rx, self._clock()

    def route(self, key: str) -> tuple[str, str]:
        """The unit and the leaf of a key, checked once per key.

        Args:
            key: A Zenoh key, ``<prefix>/<unit>/<leaf>``.

        Returns:
            (unit, leaf).

        Raises:
            ValueError: The key is not one the archive has a channel for.
        """
        known = self._routes.get(key)
        if known is not None:
            return known
        unit = unit_of(key, self.prefix)
        leaf = key[len(self.prefix) + len(unit) + 2:]
        if leaf not in MESSAGES and leaf != "raw":
            raise ValueError(f"{key}: no archive channel for '{leaf}'; archived leaves are "
                             + ", ".join([*MESSAGES, "raw"]))
        self._routes[key] = unit, leaf
        return unit, leaf

    # -- writing -------------------------------------------------------------------------

    def write(self, key: str, payload: bytes, receive_ns: int | None = None) -> None:
        """Archive one message as it came from Zenoh (or one raw read).

        It is checked at once (a bad key or payload raises here), then held with the
        other messages of its key: they go to ``write_many`` together when many are
        held, and at every flush, tick and close, so a message reaches the disk as
        soon as before. Each topic keeps its order; between topics the file's order
        can differ from the order of the calls, except in a recording split by age,
        where a message of another key hands over the ones held first.

        Args:
            key: The message's Zenoh key.
            payload: Its bytes, as published.
            receive_ns: When it was received, host ns on the realtime clock; now when
                omitted.

        Raises:
            ValueError: The key is not one the archive has a channel for, or the payload
                is not a message of the key's type.
            ArchiveError: The archive is closed, or a write failed (the archive stops
                there; what was written stays readable).
        """
        if self._broken is not None:
            raise self._broken
        self._current()  # a closed archive takes nothing
        unit, leaf = self.route(key)
        if leaf == "imu":
            _stamp(unit, payload)
        elif leaf != "raw":
            self._logged_at(key, leaf, payload)
        if self.split_ns is not None and key not in self._held:
            self._drain()
        payloads, received = self._held.setdefault(key, ([], []))
        payloads.append(payload)
        received.append(clock.realtime_ns() if receive_ns is None else receive_ns)
        self._saw(received[-1])
        self._holding += 1
        if self._holding >= _HOLD or self._clock() - self._flushed >= FLUSH_EVERY_S:
            self._drain()

    def _drain(self) -> None:
        """Hand the messages ``write`` holds to ``write_many``, key by key."""
        if not self._held:
            return
        held, self._held, self._holding = self._held, {}, 0
        self._draining = True  # every key in before the reorder window lets any go
        try:
            for key, (payloads, received) in held.items():
                self.write_many(key, payloads, np.array(received, np.int64))
        finally:
            self._draining = False
        self._release_if_full()

    def write_many(self, key: str, payloads: Sequence[bytes],
                   receive_ns: int | np.ndarray, publish_ns: np.ndarray | None = None) -> None:
        """Archive messages of one key at once: what ``write`` gives message by message.

        Args:
            key: The messages' Zenoh key.
            payloads: Their bytes, as published.
            receive_ns: When they were received, host ns: one time for all, or one each.
            publish_ns: Raw reads' stamps on the raw monotonic clock, their publish times
                (``bridge.archive.rawcapture``); by default the receive times are.

        Raises:
            ValueError: The key is not one the archive has a channel for, a payload is
                not a message of its type, or the times do not match the payloads.
            ArchiveError: The archive is closed, or a write failed.
        """
        if self._broken is not None:
            raise self._broken
        self._drain()
        n = len(payloads)
        rx = np.asarray(receive_ns, np.int64)
        if rx.ndim == 0:
            rx = np.full(n, rx, np.int64)
        if rx.shape != (n,):
            raise ValueError(f"{key}: {n} payloads but {rx.size} receive times")
        published = rx if publish_ns is None else np.asarray(publish_ns, np.int64)
        if published.shape != (n,):
            raise ValueError(f"{key}: {n} payloads but {published.size} publish times")
        unit, leaf = self.route(key)
        units: list[str] = []
        codes = np.zeros(0, np.int64)
        if leaf == "imu":
            units, codes, log_ns = stamps(unit, payloads)
        elif leaf == "raw":
            log_ns = rx
        else:
            log_ns = np.array([self._logged_at(key, leaf, p) for p in payloads], np.int64)
            log_ns = np.where(log_ns == 0, rx, log_ns)
            if leaf == "info" and payloads:
                self._rates[unit] = Info.FromString(payloads[-1]).output_rate_hz
        done = 0
        while done < n:
            if self._splits:
                self._maybe_split(int(rx[done]))
            end = self._split_due(rx, done)
            taken = self._add(key, unit, leaf, log_ns[done:end], payloads[done:end],
                              rx[done:end], published[done:end])
            if leaf == "imu" and self.frames:
                self._queue_frames(unit, units[done : done + taken],
                                   codes[done : done + taken], log_ns[done : done + taken],
                                   payloads[done : done + taken], rx[done : done + taken])
            elif leaf == "event":
                self._write_logs(unit, log_ns[done : done + taken],
                                 payloads[done : done + taken], rx[done : done + taken])
            done += taken
            if not self._draining:
                self._release_if_full()
        if self._clock() - self._flushed >= FLUSH_EVERY_S:
            self.flush()

    @staticmethod
    def _logged_at(key: str, leaf: str, payload: bytes) -> int:
        """Log time of a Status, Event or Info: its own time field (0 when unset)."""
        cls, time_field = MESSAGES[leaf]
        try:
            return int(getattr(cls.FromString(payload), time_field))
        except DecodeError:
            raise ValueError(f"{key}: payload is not a {cls.DESCRIPTOR.full_name} "
                             f"({len(payload)} bytes)") from None

    def _write_logs(self, unit: str, log_ns: np.ndarray, payloads: Sequence[bytes],
                    rx: np.ndarray) -> None:
        """The events just archived, again as foxglove.Log on the fleet's log channel."""
        rate = self._rates.get(unit, 0.0)
        logs = [log_message(unit, Event.FromString(p), t, rate)
                for p, t in zip(payloads, log_ns.tolist(), strict=True)]
        self._add_all(_fleet_topic(self.prefix, LOG_LEAF), LOG_LEAF, log_ns, logs, rx)

    def _add_all(self, topic: str, leaf: str, log_ns: np.ndarray,
                 payloads: Sequence[bytes], rx: np.ndarray, unit: str = "") -> None:
        """``_add`` until every message is taken.

        A file split by size takes a chunk's worth at a time.
        """
        done = 0
        while done < len(payloads):
            done += self._add(topic, unit, leaf, log_ns[done:], payloads[done:], rx[done:])

    def _split_due(self, rx: np.ndarray, start: int) -> int:
        """Index of the first message after ``start`` that starts a new file by age."""
        f = self._current()
        if self.split_ns is None or f.opened_ns is None:
            return len(rx)
        late = np.flatnonzero(rx[start + 1 :] - f.opened_ns >= self.split_ns)
        return start + 1 + int(late[0]) if len(late) else len(rx)

    def _queue_frames(self, unit: str, units: list[str], codes: np.ndarray,
                      log_ns: np.ndarray, payloads: Sequence[bytes], rx: np.ndarray) -> None:
        """Keep the samples that become FrameTransforms: at most one a period per unit.

        Records without attitude get none.
        """
        code_list = codes.tolist()
        kinds = set(code_list)
        if not any(map(framed, kinds)):
            return
        eligible = (None if all(map(framed, kinds))
                    else [i for i, c in enumerate(code_list) if framed(c)])
        times = log_ns if eligible is None else log_ns[eligible]
        picks, due = frame_picks(times, self._frame_due.get(unit), self.frame_period_ns)
        if due is not None:
            self._frame_due[unit] = due
        chosen = picks if eligible is None else [eligible[k] for k in picks]
        if len(kinds) == 1 and units.count(units[0]) == len(units):  # a unit's own samples
            self._frames_of(unit, units[0], code_list[0], chosen, payloads, rx)
            return
        keys = [(units[i], code_list[i]) for i in chosen]
        for sample_unit, code in dict.fromkeys(keys):
            mine = [i for i, k in zip(chosen, keys, strict=True) if k == (sample_unit, code)]
            self._frames_of(unit, sample_unit, code, mine, payloads, rx)

    def _frames_of(self, unit: str, sample_unit: str, code: int, chosen: list[int],
                   payloads: Sequence[bytes], rx: np.ndarray) -> None:
        """Queue the ``chosen`` samples, all of ``sample_unit`` and record type ``code``."""
        group = self._pending.get((unit, sample_unit, code))
        if group is None:
            group = self._pending[(unit, sample_unit, code)] = _Frames(unit, sample_unit, code)
        group.payloads += [payloads[i] for i in chosen]
        group.receive_ns += rx[chosen].tolist()

    def _write_frames(self) -> None:
        """Turn queued attitude samples into FrameTransforms, in bulk."""
        pending, self._pending = self._pending, {}
        made = []
        for g in pending.values():
            try:
                cols = decode_batch(g.sample_unit, g.code, g.payloads)
            except ValueError:  # a malformed sample among them gets no frame; the rest do
                g = self._decodable(g)
                cols = decode_batch(g.sample_unit, g.code, g.payloads)
            xyzw = sensor_to_earth(cols)
            ok = np.isfinite(xyzw).all(axis=1)
            times = cols["time_ns"][ok]
            frames = frame_messages(g.unit, self._slots[g.unit], times, xyzw[ok],
                                    self.frame_spacing, self.prefix)
            if frames:
                made.append((g.unit, times, frames, np.asarray(g.receive_ns, np.int64)[ok]))
        f = self._current()
        if made and not f.rooted:  # the root before the file's first frame, at its time
            at = min(int(m[1].min()) for m in made)
            received = min(int(m[3].min()) for m in made)
            self._add_all(_fleet_topic(self.prefix, FRAME_LEAF), FRAME_LEAF,
                          np.array([at], np.int64), [root_message(at, self.prefix)],
                          np.array([received], np.int64))
            f.rooted = True
        for unit, times, frames, rx in made:
            self._add_all(_frame_topic(self.prefix, unit), FRAME_LEAF, times, frames, rx, unit)
            self._add_all(f"{self.prefix}/{unit}/{AXES_LEAF}", AXES_LEAF, times,
                          marker_messages(unit, times, self.prefix), rx, unit)

    @staticmethod
    def _decodable(g: _Frames) -> _Frames:
        """The samples of ``g`` that decode on their own."""
        kept = _Frames(g.unit, g.sample_unit, g.code)
        for payload, rx in zip(g.payloads, g.receive_ns, strict=True):
            try:
                decode_batch(g.sample_unit, g.code, [payload])
            except ValueError:
                continue
            kept.payloads.append(payload)
            kept.receive_ns.append(rx)
        return kept

    def _maybe_split(self, rx: int) -> None:
        """Start the next file before a message received at ``rx`` if this one is full or old.

        A file's age counts from the receive time of its first message.
        """
        f = self._current()
        if f.opened_ns is None:
            f.opened_ns = rx
        old = self.split_ns is not None and rx - f.opened_ns >= self.split_ns
        if old or (self.split_bytes is not None
                   and f.stream.tell() + f.writer.held_bytes >= self.split_bytes):
            self._roll()
            self._current().opened_ns = rx

    def _roll(self) -> None:
        self._finish()
        self._open()

    def _release(self) -> None:
        """Write, in log-time order, the messages ``reorder_s`` of receive time has passed."""
        if self.reorder_ns is None or self._rx_latest is None:
            return
        self._write_frames()
        now = self._rx_latest + int((self._clock() - self._rx_seen_at) * 1e9)
        self._guard(self._current().writer.release, now - self.reorder_ns)

    def _release_if_full(self) -> None:
        """Release before the next flush when much is held (a writer faster than live)."""
        if self._current().writer.held_bytes > _RELEASE_CHUNKS * self.chunk_size:
            self._release()

    def flush(self) -> None:
        """Write what the reorder window lets go, close the open chunk, hand it to the OS.

        A crash keeps what was flushed.

        Raises:
            ArchiveError: The archive is closed, or a write failed.
        """
        self._drain()
        self._write_frames()
        self._release()
        self._guard(self._current().writer.flush)
        self._flushed = self._clock()

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """Write a metadata record into the file being written.

        For what its writer learnt only as the recording went: the ``metadata`` given at
        the start go into every file.

        Args:
            name: The record's name (``gx3.hosts``, ...).
            data: Its key-value pairs.

        Raises:
            ArchiveError: The archive is closed, or a write failed.
        """
        self._guard(self._current().writer.add_metadata, name, data)

    def tick(self) -> None:
        """Flush if the last flush is a second old: call this while messages pause.

        Raises:
            ArchiveError: A write failed.
        """
        if self._file is not None and self._clock() - self._flushed >= FLUSH_EVERY_S:
            self.flush()

    def _finish(self) -> None:
        f = self._current()
        try:
            if self._broken is None:
                self._write_frames()
                self._guard(f.writer.release)
                self.late += f.writer.late
                if f.writer.late:
                    self._guard(f.writer.flush)
                    self._guard(f.writer.add_metadata, "gx3.order", {
                        "late_messages": str(f.writer.late),
                        "reorder_window_ns": str(self.reorder_ns),
                        "note": "messages that came later than the reorder window are "
                                "logged at the time of the last message written before "
                                "them; their own time is in their payload (a raw read's "
                                f"in the {LATE_READS} records)"})
                self._guard(f.writer.finish)
        finally:
            self._file = None
            f.writer.close()
            try:
                f.stream.close()
            except OSError as exc:
                if self._broken is None:
                    raise self._fail(f.path, exc) from None

    def abandon(self) -> None:
        """Stop without finishing the file.

        For an output that is thrown away (a batch command that failed or was
        interrupted), where finishing is only a wait.
        """
        if self._file is not None:
            f, self._file = self._file, None
            f.writer.close()
            with contextlib.suppress(OSError):
                f.stream.close()

    def close(self) -> None:
        """Finish the file (summary and index); safe to call twice, and after an error.

        Raises:
            ArchiveError: Finishing the file failed (what was written stays readable).
        """
        if self._file is not None:
            try:
                self._drain()
            finally:
                self._finish()

    def __enter__(self) -> ArchiveWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
