"""What ``gx3 record`` runs, set up and torn down in one place: a ``Recording``.

A recording is the archive's writer, the Zenoh session it records from, the
``Recorder`` between them, and optionally a file that shows what is archived as it is
archived (a Rerun recording: ``bridge.viz.RrdWriter``, which the caller hands in, so
that the recorder needs no viewer). Entering opens them in the order that refuses a bad
output before anything is written, and leaves nothing behind when a later step fails;
leaving closes them in the order that loses nothing, whatever ended the block (Ctrl-C
included)::

    import threading
    from pathlib import Path

    from bridge.bus import ZenohOptions
    from bridge.recorder import Recording
    from bridge.viz import RrdWriter

    stop = threading.Event()  # set it (a signal handler, say) to end the recording
    with Recording(Path("fleet.mcap"), ZenohOptions(connect=["tcp/10.0.0.5:7447"]),
                   rrd=Path("fleet.rrd"), rrd_writer=RrdWriter) as recording:
        recording.run(stop, duration_s=60)
    if recording.error is not None:
        raise recording.error
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import ExitStack, suppress
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Protocol

from bridge.archive.writer import ArchiveWriter
from bridge.bus.session import ZenohOptions
from bridge.exceptions import ArchiveError, OutputRefused
from bridge.recorder.hosts import host_tolerance_ns, recorder_metadata
from bridge.recorder.live import Recorder

if TYPE_CHECKING:
    import threading

    import zenoh
    from prometheus_client.core import Metric

    from bridge.bus.gx3_pb2 import Event
    from bridge.bus.metrics import MetricsServer
    from bridge.bus.subscribe import RawMessage

__all__ = ["Mirror", "Recording"]

#: How long ``run`` waits for messages at a time, seconds: how often ``every`` is called.
RUN_STEP_S = 0.25


class Mirror(Protocol):
    """A file that shows what a recording archives, batch by batch (a Rerun recording)."""

    def log(self, messages: list[RawMessage]) -> None:
        """Take a batch of messages, as written into the archive."""

    def close(self) -> None:
        """Finish the file: the recording has ended."""


class Recording:
    """Record the fleet on Zenoh into an archive: ``gx3 record``, as a context manager.

    Entering opens, in this order: the archive (first, so that a file that is refused is
    said before anything else opens; after a check of ``rrd``), the Zenoh session,
    ``rrd``, then the ``Recorder``. If a step fails, what was opened is closed, and the
    archive, with nothing recorded in it, is removed. Leaving closes, in this order: the
    Recorder (what has arrived is written, and the hosts' clocks), ``rrd``, the archive
    (finished with its index), the session.

    Args:
        archive: The archive: a path (an ``ArchiveWriter`` is opened on entry with
            ``prefix``, ``split_bytes``, ``split_seconds``, ``force`` and the recorder's
            host and clock sync as metadata), or a writer the caller opened (to hold its
            lock from earlier on); the recording closes either.
        session: Where to record from: how to open a session (closed on leaving), or an
            open session (the caller's, left open). Default: Zenoh's own configuration.
        prefix: The key prefix of the bridges.
        units: Which units, as a key expression chunk (``*``, ``lab-*``).
        raw: Also record the units' raw reads (bridges run with ``--publish-raw``).
        history: Samples to ask each bridge's cache for on joining.
        max_host_offset_ms: How far behind the recorder's clock a bridge host's may be
            before it is told (``Recorder``); None: no tolerance.
        split_bytes: With a path: start a new numbered part at this size.
        split_seconds: With a path: start a new numbered part after this many seconds.
        force: Replace an existing archive (with a path) and an existing ``rrd``.
        metadata: With a path: more entries for the archive's ``gx3.archive`` metadata.
        rrd: Also write what is archived into this file, as it is archived, through
            ``rrd_writer``.
        rrd_writer: Opens ``rrd``: called with its path and a recording id (the
            archive's name) once the archive is open; what it gives hears every batch
            written and is closed after the recorder. ``bridge.viz.RrdWriter`` writes a
            Rerun recording. Required with ``rrd``; it raises ``OutputRefused`` when
            the file cannot be written.
        on_written: More to hand every batch written (a live viewer, say); they stay
            the caller's.
        on_unit: Hears ``(unit, joined)`` as units appear and leave.
        on_event: Hears ``(unit, event)`` of each event the recorder itself archives.
        metrics: Serve the recorder's health to Prometheus at this ``ADDR:PORT``: what it
            archived of each unit, when it last heard from each, and how long samples
            took from their bridge to the archive (each unit's own numbers are its
            bridge's to serve); None: not.

    Attributes:
        writer: The archive's writer (once entered).
        recorder: The recorder (once entered).
        started: When recording began, on ``time.monotonic``.

    Raises:
        ValueError: ``max_host_offset_ms`` is not above 0, or ``rrd`` comes without
            ``rrd_writer``.
    """

    def __init__(self, archive: Path | ArchiveWriter,
                 session: ZenohOptions | zenoh.Session | None = None, *,
                 prefix: str = "gx3", units: str = "*", raw: bool = False, history: int = 0,
                 max_host_offset_ms: float | None = None, split_bytes: int | None = None,
                 split_seconds: float | None = None, force: bool = False,
                 metadata: Mapping[str, str] | None = None, rrd: Path | None = None,
                 rrd_writer: Callable[[Path, str], Mirror] | None = None,
                 on_written: Sequence[Callable[[list[RawMessage]], None]] = (),
                 on_unit: Callable[[str, bool], None] | None = None,
                 on_event: Callable[[str, Event], None] | None = None,
                 metrics: str | None = None) -> None:
        host_tolerance_ns(max_host_offset_ms)  # refused before anything opens
        if rrd is not None and rrd_writer is None:
            raise ValueError(f"rrd {rrd}: give the rrd_writer that writes it")
        self._archive = archive
        self._session_from = ZenohOptions() if session is None else session
        self.prefix, self.units, self.raw, self.history = prefix, units, raw, history
        self.max_host_offset_ms = max_host_offset_ms
        self.split_bytes, self.split_seconds, self.force = split_bytes, split_seconds, force
        self.metadata = dict(metadata or {})
        self.rrd = rrd
        self._rrd_writer = rrd_writer
        self._on_written = list(on_written)
        self._on_unit, self._on_event = on_unit, on_event
        self._writer = archive if isinstance(archive, ArchiveWriter) else None
        self._session: zenoh.Session | None = None
        self._own_session = False
        self._mirror: Mirror | None = None
        self._recorder: Recorder | None = None
        self.metrics = metrics
        self._metrics: MetricsServer | None = None
        self.started = 0.0

    @property
    def path(self) -> Path:
        """The archive's path (the name of its numbered parts when it is split)."""
        return self._archive.path if isinstance(self._archive, ArchiveWriter) else self._archive

    @property
    def writer(self) -> ArchiveWriter:
        """The archive's writer."""
        if self._writer is None:
            raise RuntimeError("the recording has not started: enter it first")
        return self._writer

    @property
    def recorder(self) -> Recorder:
        """The recorder: its units' rows (``snapshot``), hosts, counts and error."""
        if self._recorder is None:
            raise RuntimeError("the recording has not started: enter it first")
        return self._recorder

    @property
    def paths(self) -> list[Path]:
        """The files written (one, or each numbered part)."""
        return [] if self._writer is None else list(self._writer.paths)

    @property
    def error(self) -> ArchiveError | None:
        """The write that failed and ended the recording (finishing the file included)."""
        return None if self._recorder is None else self._recorder.error

    @property
    def elapsed_s(self) -> float:
        """Seconds since recording began."""
        return time.monotonic() - self.started

    def __enter__(self) -> Recording:
        """Open the archive, the session, ``rrd`` and the recorder.

        Returns:
            The recording.

        Raises:
            OutputRefused: ``rrd`` is the archive's own file, or cannot be written (a
                folder, another process's, an existing file without ``force``, or its
                writer cannot create it).
            ArchiveError: The archive exists (without ``force``), another process writes
                it, or it cannot be created.
            BadName: ``prefix`` cannot be a chunk of a key.
            SessionError: The Zenoh session cannot be opened.
        """
        try:
            self._open()
        except BaseException:
            self._close(discard=True)
            raise
        return self

    def _open(self) -> None:
        from bridge.archive.outputs import refuse
        from bridge.device import clock

        on_latency = None
        if self.metrics is not None:  # a busy port is said before any file is made
            from bridge.bus.metrics import Health, MetricsServer

            health = Health(extra=self._archived_metrics, latencies=["archive"])
            self._metrics = MetricsServer(self.metrics, health)
            on_latency = health.latencies["archive"].observe
        if self.rrd is not None:
            if self.rrd.absolute() == self.path.absolute():
                raise OutputRefused(f"--rrd {self.rrd} is the archive's own file; give the "
                                    "recording another name")
            refuse(self.rrd, force=self.force)
        if self._writer is None:
            assert isinstance(self._archive, Path)
            self._writer = ArchiveWriter(
                self._archive, prefix=self.prefix, split_bytes=self.split_bytes,
                split_seconds=self.split_seconds, force=self.force,
                metadata={**recorder_metadata(clock.host_sync()), **self.metadata})
        if isinstance(self._session_from, ZenohOptions):
            self._session, self._own_session = self._session_from.open(), True
        else:
            self._session = self._session_from
        if self.rrd is not None:
            assert self._rrd_writer is not None  # (__init__ refused one without)
            self._mirror = self._rrd_writer(self.rrd, self.path.stem)
        listeners = [*([self._mirror.log] if self._mirror is not None else []),
                     *self._on_written]
        self.started = time.monotonic()
        self._recorder = Recorder(
            self._session, self._writer, self.prefix, self.units, self.raw, self.history,
            on_unit=self._on_unit, on_written=_to_each(listeners) if listeners else None,
            on_event=self._on_event, max_host_offset_ms=self.max_host_offset_ms,
            on_latency=on_latency)

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        """Close the recorder, ``rrd``, the archive and the session, in order.

        A failure to finish the archive is kept in ``error``.
        """
        self._close(discard=False)

    def run(self, stop: threading.Event, duration_s: float | None = None,
            every: Callable[[], None] | None = None) -> None:
        """Record until ``stop`` is set, the duration is over, or a write fails (``error``).

        Args:
            stop: Ends the recording when set.
            duration_s: Seconds after recording began to stop; None: no limit.
            every: Called after each step (a quarter of a second at most), to show
                progress.
        """
        recorder = self.recorder
        while not stop.is_set() and recorder.error is None:
            if duration_s is not None and self.elapsed_s >= duration_s:
                break
            recorder.run_once(RUN_STEP_S)
            if every is not None:
                every()

    def _close(self, discard: bool) -> None:
        """Close what is open: recorder, ``rrd``, archive, session, in that order.

        With ``discard``, nothing was recorded: the archive's files are removed.
        """
        with ExitStack() as steps:  # each runs, even after one that failed; last first
            steps.callback(self._close_session)
            steps.callback(self._close_archive, discard)
            steps.callback(self._close_mirror)
            steps.callback(self._close_recorder)
            steps.callback(self._close_metrics)

    def _archived_metrics(self) -> Iterator[Metric]:
        """What the recorder archived, for Prometheus (nothing before it starts)."""
        from bridge.bus.gx3_pb2 import Event
        from bridge.bus.metrics import recorder_metrics

        recorder = self._recorder
        if recorder is not None:
            unarchived = {Event.Kind.Name(kind).lower(): count
                          for kind, count in dict(recorder.losses).items()}
            yield from recorder_metrics(recorder.snapshot(), recorder.written,
                                        recorder.misses, archive_bytes=self._archive_bytes(),
                                        unarchived=unarchived)

    def _archive_bytes(self) -> int:
        """Bytes in the archive's files so far, as the disk has them (a scrape's thread)."""
        total = 0
        for part in self.paths:
            with suppress(OSError):  # a part moved away: not counted
                total += part.stat().st_size
        return total

    def _close_metrics(self) -> None:
        server, self._metrics = self._metrics, None
        if server is not None:
            server.close()

    def _close_recorder(self) -> None:
        if self._recorder is not None:
            self._recorder.close()

    def _close_mirror(self) -> None:
        mirror, self._mirror = self._mirror, None
        if mirror is not None:
            mirror.close()

    def _close_archive(self, discard: bool) -> None:
        writer = self._writer
        if writer is None:
            return
        if discard:
            with suppress(ArchiveError):  # the file goes: why it failed matters no more
                writer.close()
            for part in writer.paths:
                part.unlink(missing_ok=True)
            return
        try:
            writer.close()
        except ArchiveError as exc:
            if self._recorder is None:
                raise
            self._recorder.error = self._recorder.error or exc

    def _close_session(self) -> None:
        session, self._session = self._session, None
        if session is not None and self._own_session:
            session.close()


def _to_each(listeners: list[Callable[[list[RawMessage]], None]]
             ) -> Callable[[list[RawMessage]], None]:
    """What hands each batch written to every one of ``listeners``, in order."""

    def hand(messages: list[RawMessage]) -> None:
        for listen in listeners:
            listen(messages)

    return hand
