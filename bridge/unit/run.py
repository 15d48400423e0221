"""What ``gx3 bridge`` runs: one unit's pipeline published on a Zenoh session, until stopped.

``UnitBridge`` holds what the bridge was asked for; ``run`` opens the session, claims the
unit's name, publishes through a ``BusSink`` (and ROS 2 with ``ros2``), writes the
raw capture, runs the ``Pipeline`` on a thread of its own until ``stop``, the duration or
the give-up time, then closes everything in reverse order and says how it went::

    import threading

    from bridge.unit import Options
    from bridge.unit.run import UnitBridge

    stop = threading.Event()  # set it (a signal handler, say) to end the run
    outcome = UnitBridge(Options(url="/dev/ttyACM0"), unit="imu0").run(stop)
    print(outcome.summary)
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from bridge.archive.rawcapture import RawCaptureWriter
from bridge.bus.session import ZenohOptions
from bridge.exceptions import CaptureError, NameTaken, UnsupportedUnit
from bridge.unit.pipeline import Options, Pipeline

if TYPE_CHECKING:  # its module reads message definitions: loaded only with --ros2
    from bridge.ros2.options import Ros2Options

if TYPE_CHECKING:
    from bridge.bus.metrics import Health

__all__ = ["BridgeOutcome", "UnitBridge"]

_log = logging.getLogger(__name__)
#: How often the run looks at the clock and at the pipeline while it runs, seconds.
POLL_S = 0.2


@dataclass(frozen=True)
class BridgeOutcome:
    """How a bridge's run ended.

    Attributes:
        came_up: The unit was brought up at least once.
        gave_up: The run ended because the unit was not up by ``give_up_after_s``.
        last_failure: Why the last attempt to bring the unit up failed ("" if none did).
        internal_error: An unexpected error the pipeline stopped on (a bug, not the
            unit's or the port's doing); None if it did not.
        summary: What the unit did, in one line per counter, for a person.
    """

    came_up: bool
    gave_up: bool
    last_failure: str
    internal_error: Exception | None
    summary: str


def _log_capture_error(exc: CaptureError) -> None:
    _log.error("%s", exc)


def _log_capture_stopped(exc: CaptureError) -> None:
    _log.warning("capture stopped: %s", exc)


@dataclass
class UnitBridge:
    """One unit bridged onto Zenoh: what ``gx3 bridge`` was asked for.

    Attributes:
        options: The port and what to ask of the unit.
        prefix: The first chunk of every key.
        unit: The unit's name in the keys; None: its serial number.
        zenoh: Where the session's configuration comes from.
        allow_commands: Carry out operator commands that arrive over Zenoh.
        cache_s: Seconds of samples kept for subscribers that lose their link.
        quiet: Log only disconnects and why the unit is not up.
        publish_raw: Also publish every read on ``<prefix>/<unit>/raw``.
        ros2: Also publish every sample as ROS 2 does over rmw_zenoh: the domain, the
            distribution and the unit's measured noise; None: not.
        capture: Also write every read, with its receive times, to this raw capture
            (opened at the unit's first bring-up, once its name is known).
        force: Replace an existing capture file.
        on_capture_error: Hears why the capture could not be opened (the run goes on
            without it); by default, the log.
        on_capture_stopped: Hears why writing the capture failed (it stops there, the
            run goes on); by default, the log.
        metrics: Serve the unit's health to Prometheus at this ``ADDR:PORT``; None: not.
    """

    options: Options
    prefix: str = "gx3"
    unit: str | None = None
    zenoh: ZenohOptions = field(default_factory=ZenohOptions)
    allow_commands: bool = False
    cache_s: float = 10.0
    quiet: bool = False
    publish_raw: bool = False
    ros2: Ros2Options | None = None
    capture: Path | None = None
    force: bool = False
    on_capture_error: Callable[[CaptureError], None] = _log_capture_error
    on_capture_stopped: Callable[[CaptureError], None] = _log_capture_stopped
    metrics: str | None = None

    def run(self, stop: threading.Event | None = None, duration_s: float | None = None,
            give_up_after_s: float | None = None) -> BridgeOutcome:
        """Bridge the unit until ``stop`` is set, the duration is over or the run gives up.

        A port that is missing or busy, or a unit that does not answer, is retried; the
        pipeline keeps the unit streaming through pulled cables and resets. Whatever
        ends the run, the pipeline is stopped and the sink, the capture and the session
        are closed.

        Args:
            stop: Ends the run when set (it is set when the run ends); None: a new one.
            duration_s: End the run this many seconds after it starts; None: no limit.
            give_up_after_s: End the run if the unit has not come up this many seconds
                after the start (0: after the first failed try); None: keep trying.

        Returns:
            How the run ended, and the unit's summary.

        Raises:
            MetricsError: The metrics' address cannot be served.
            SessionError: The Zenoh session cannot be opened.
            NameTaken: A running bridge already publishes the unit's name.
            UnsupportedUnit: The unit on the port is not a 3DM-GX3.
        """
        stop = threading.Event() if stop is None else stop
        with ExitStack() as closing:
            health = None
            if self.metrics is not None:
                from bridge.bus.metrics import Health, MetricsServer

                health = Health(latencies=["publish"])
                closing.enter_context(MetricsServer(self.metrics, health))
            return self._run(stop, duration_s, give_up_after_s, health)

    def _run(self, stop: threading.Event, duration_s: float | None,
             give_up_after_s: float | None, health: Health | None) -> BridgeOutcome:
        from bridge.unit.service import BusSink, claim_name

        session = self.zenoh.open()
        if self.unit is not None:
            try:
                claim_name(session, self.prefix, self.unit)
            except BaseException:
                session.close()
                raise
        writer: list[RawCaptureWriter] = []

        def write_capture(data: bytes, raw_ns: int, real_ns: int) -> None:
            if not writer or writer[0].stopped:
                return
            try:
                writer[0].write(data, real_ns, raw_ns)
            except CaptureError as exc:
                self.on_capture_stopped(exc)
                writer[0].stopped = True

        with session:
            sink = BusSink(session, self.prefix, self.unit, self.options.url,
                           self.allow_commands, self.cache_s, quiet=self.quiet,
                           raw=self.publish_raw, ros2=self.ros2)
            pipeline = Pipeline(self.options, sink, on_read=sink.read)
            sink.attach(pipeline)
            if health is not None:
                publish = health.latencies["publish"]
                sink.on_status(health.status)
                sink.on_stamped(lambda unit, received_ns, published_ns: publish.observe(
                    unit, [(published_ns - received_ns) / 1e9]))
            if self.capture is not None:
                capture = self.capture
                sink.on_unit(lambda name, meta: self._open_capture(writer, capture, name, meta))
                sink.on_read(write_capture)
            worker = threading.Thread(target=pipeline.run, args=(stop,), name="gx3-pipeline")
            worker.start()
            try:
                gave_up = _wait(worker, pipeline, stop, duration_s, give_up_after_s)
            finally:
                stop.set()
                worker.join()
                sink.close()
                for w in writer:
                    w.close()
        if isinstance(pipeline.error, (NameTaken, UnsupportedUnit)):
            raise pipeline.error
        return BridgeOutcome(pipeline.came_up, gave_up, pipeline.last_failure, pipeline.error,
                             sink.summary())

    def _open_capture(self, writer: list[RawCaptureWriter], path: Path, unit: str,
                      metadata: dict[str, str]) -> None:
        """Open the raw capture once the unit's name is known (its first bring-up)."""
        if writer:
            return
        try:
            writer.append(RawCaptureWriter(path, self.prefix, unit, metadata, self.force))
        except CaptureError as exc:
            self.on_capture_error(exc)


def _wait(worker: threading.Thread, pipeline: Pipeline, stop: threading.Event,
          duration_s: float | None, give_up_after_s: float | None) -> bool:
    """Wait for the end of the run; whether it gave up on a unit that never came up."""
    started = time.monotonic()
    while worker.is_alive() and not stop.is_set():
        elapsed = time.monotonic() - started
        if duration_s is not None and elapsed >= duration_s:
            stop.set()
        if give_up_after_s is not None and elapsed >= give_up_after_s \
                and pipeline.last_failure and not pipeline.came_up:
            stop.set()
            return True
        stop.wait(POLL_S)
    return False
