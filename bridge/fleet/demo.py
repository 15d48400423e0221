"""`gx3 demo`: the whole product on one machine, no sensor needed.

An emulated fleet on real pseudo-terminals (different clock errors; one unit
crosses the timer rollover, one suffers corruption and an unplug), one `gx3 bridge`
OS process per unit, Zenoh on loopback (peers, or a `gx3 router`), and the recorder
in this process writing the MCAP archive and the Rerun recording, with a live
dashboard. Everything it starts, it stops; what it made stays in the output folder.
How the parts fit: ``docs/design/architecture.md``.
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from bridge.exceptions import DemoError
from bridge.fleet.loopback import free_port, interrupt, loopback_config
from bridge.protocol.table import BAUD_RATES, DATA_CODES, REPLIES, Flag
from bridge.sim.faults import FaultConfig
from bridge.sim.motion import MotionConfig, Mounting, handheld
from bridge.sim.serve import Simulator
from bridge.sim.state import Sampling, Stored
from bridge.sim.unit import UnitConfig

if TYPE_CHECKING:
    from bridge.recorder.units import UnitRow

CLOCK_PPM = (42.0, -27.0, 85.0, -63.0, 12.0, -95.0, 55.0, -8.0)
#: With --body, where each unit sits on the one body (unit i takes row i % 4): its axes'
#: roll, pitch, yaw against the body's (degrees), its lever arm (m, body axes) and a
#: constant extra latency on its link (s). The first is the reference gx3 align suggests.
BODY_MOUNTS: tuple[tuple[tuple[float, float, float], tuple[float, float, float], float],
                   ...] = (
    ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.0),
    ((180.0, 0.0, 90.0), (0.30, 0.0, 0.0), 0.0),
    ((2.0, -1.5, 177.0), (-0.10, 0.25, 0.05), 0.0),
    ((0.0, 90.0, 0.0), (0.0, -0.30, -0.20), 0.0032),
)
BODY_SEED = 7
ORIENTATION_RECORDS = frozenset({0xC5, 0xC6, 0xC8, 0xCC, 0xCE, 0xCF, 0xD2, 0xDF})
STARTUP_TIMEOUT_S = 60.0


@dataclass
class DemoUnit:
    """One unit of the demo fleet.

    Attributes:
        name: Its name on Zenoh.
        config: The emulated unit.
        faults: Its line faults.
        unplug: Whether its cable is pulled part-way through the run.
        notes: What it shows, in words (for the summary).
    """

    name: str
    config: UnitConfig
    faults: FaultConfig = field(default_factory=FaultConfig)
    unplug: bool = False
    notes: list[str] = field(default_factory=list)


def _line_baud(code: int, rate_hz: float) -> int:
    """The slowest baud rate that carries ``rate_hz`` records of ``code`` with a margin."""
    need = REPLIES[code].length * 10 * rate_hz * 1.25
    for baud in BAUD_RATES:
        if baud >= need:
            return baud
    raise DemoError(f"0x{code:02X} at {rate_hz:g} Hz needs {need:,.0f} baud, more than a "
                    f"UART carries ({BAUD_RATES[-1]:,}); lower --rate")


def fleet(count: int, code: int, rate_hz: float, duration_s: float,
          body: bool = False) -> list[DemoUnit]:
    """The demo fleet: clock errors of tens of ppm, a timer rollover, faults.

    Unit 2 (or the only one) crosses the timer rollover halfway; the last suffers bit
    flips and an unplug. With ``body`` every unit is fixed to one body turned by hand,
    each mounted as ``BODY_MOUNTS`` says: what ``gx3 align`` finds from the archive.

    Args:
        count: How many units.
        code: The record type they stream.
        rate_hz: Records per second.
        duration_s: How long the demo streams, seconds (the rollover comes halfway).
        body: Fix the units to one body turned by hand.

    Returns:
        The units.

    Raises:
        DemoError: The record type is not a data record, or the rate is one the units
            (or a UART) cannot give.
    """
    if code not in DATA_CODES:
        raise DemoError(f"--record-type 0x{code:02X} is not a data record")
    decimation = round(1000 / rate_hz)
    if not 1 <= decimation <= 1000:
        raise DemoError(f"--rate {rate_hz:g}: use 1 to 1000 Hz")
    if code in ORIENTATION_RECORDS and decimation < 2:
        raise DemoError(f"0x{code:02X} needs the orientation filter, which runs up to 500 Hz; "
                        "lower --rate or pick a record without orientation (e.g. 0xC2)")
    baud = _line_baud(code, 1000 / decimation)
    flags = int(Flag.ORIENTATION | Flag.CONING_SCULLING | (Flag.QUATERNION if code == 0xDF
                                                            else 0))
    stored = Stored(mode_preset=2, continuous_preset=code, baud=baud,
                    sampling=Sampling(decimation=decimation, flags=flags))
    units = []
    for i in range(count):
        config = UnitConfig(serial=f"DEMO-{i + 1}", clock_ppm=CLOCK_PPM[i % len(CLOCK_PPM)],
                            clock_wander_ppm=2.0, clock_seed=i,
                            motion=MotionConfig(seed=100 + i), stored=stored)
        unit = DemoUnit(f"imu{i + 1}", config)
        if body:
            _mount(unit, i)
        units.append(unit)
    rolling = units[min(1, count - 1)]
    ticks_to_wrap = round((duration_s / 2 + 5.0) * 62_500)
    rolling.config = replace(rolling.config, timer_start=(1 << 32) - ticks_to_wrap)
    rolling.notes.append("timer rollover")
    faulty = units[-1]
    faulty.faults = FaultConfig(bit_flip_rate=2e-4)
    faulty.unplug = True
    faulty.notes.append("bit flips, unplug")
    return units


def _mount(unit: DemoUnit, index: int) -> None:
    """Fix ``unit`` to the demo's body as ``BODY_MOUNTS`` row ``index`` says."""
    turned, arm, latency = BODY_MOUNTS[index % len(BODY_MOUNTS)]
    motion = handheld(unit.config.motion, Mounting.turned(turned, arm, BODY_SEED))
    unit.config = replace(unit.config, motion=motion, link_latency_s=latency)
    if index:
        unit.notes.append("turned ({:g}, {:g}, {:g})°, ({:g}, {:g}, {:g}) m from imu1"
                          .format(*turned, *arm))
    if latency:
        unit.notes.append(f"link +{latency * 1e3:g} ms")


def _gx3_executable() -> list[str]:
    """This installation's `gx3`, run with this interpreter."""
    beside = Path(sys.executable).parent / "gx3"
    return [str(beside)] if beside.exists() else [sys.executable, "-m", "bridge"]


@dataclass
class _Processes:
    """Child processes, stopped by SIGINT (then killed) in reverse order."""

    children: list[tuple[str, subprocess.Popen[bytes], IO[bytes]]] = field(default_factory=list)

    def start(self, name: str, args: list[str], log: Path) -> subprocess.Popen[bytes]:
        out = log.open("wb")
        proc = subprocess.Popen([*_gx3_executable(), *args], stdout=out, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL)
        self.children.append((name, proc, out))
        return proc

    def failed(self) -> list[str]:
        return [name for name, proc, _ in self.children if proc.poll() not in (None, 0)]

    def stop(self) -> None:
        interrupt(proc for _, proc, _ in reversed(self.children))
        for _, _, out in self.children:
            out.close()


@dataclass(frozen=True)
class UnitOutcome:
    """What one unit's run gave, beside the truth the emulator knows (the demo's summary).

    Attributes:
        unit: Its name.
        samples: Samples archived.
        dropped: Records its bridge found missing.
        checksum_failures: Records its bridge's framer refused.
        resyncs: Times its bridge's framer lost the records' boundaries.
        reconnects: Times its bridge reopened the port.
        drift_ppm: The drift its bridge found; None if it found none yet.
        true_ppm: The drift the emulator gave its clock.
        notes: What it shows, in words (``DemoUnit.notes``).
    """

    unit: str
    samples: int
    dropped: int
    checksum_failures: int
    resyncs: int
    reconnects: int
    drift_ppm: float | None
    true_ppm: float
    notes: str


@dataclass
class Demo:
    """Runs the demo; ``show(rows, elapsed)`` draws the dashboard.

    Attributes:
        output: The folder it writes into: the archive, the Rerun recording, logs.
        units: The fleet (``fleet``).
        duration_s: How long to stream once every unit streams, seconds.
        router: Run the bridges as Zenoh clients of a ``gx3 router``, not as peers.
        viewer: A Rerun recording to mirror the live data into.
        show: Draws the dashboard: the units' rows and the seconds streamed.
        force: Replace an earlier run's archive in ``output``.
        stop: Set it to end the run early.
        rows: The units' rows: as the dashboard last showed them while it runs, every
            sample archived once it has run.
    """

    output: Path
    units: list[DemoUnit]
    duration_s: float
    router: bool = False
    viewer: Any = None  # a Rerun recording to mirror the live data into
    show: Callable[[list[UnitRow], float], None] = lambda rows, elapsed: None
    force: bool = False  # replace an earlier run's archive in ``output``
    stop: threading.Event = field(default_factory=threading.Event)
    rows: list[UnitRow] = field(default_factory=list)

    @property
    def archive(self) -> Path:
        """The MCAP archive it writes."""
        return self.output / "demo.mcap"

    @property
    def rrd(self) -> Path:
        """The Rerun recording it writes."""
        return self.output / "demo.rrd"

    def run(self) -> None:
        """Run the demo to its end (or ``stop``), then stop all it started.

        Raises:
            DemoError: A bridge stopped, the units did not stream in time, or the archive
                could not be written; it says where the logs are.
            ArchiveError: The archive could not be created.
        """
        from bridge.archive.writer import ArchiveWriter
        from bridge.bus.session import open_session
        from bridge.exceptions import ArchiveError
        from bridge.recorder.live import Recorder
        from bridge.viz.logger import RerunLogger
        from bridge.viz.sources import log_messages

        self.output.mkdir(parents=True, exist_ok=True)
        # first: its lock keeps a second demo out of this folder before anything is written
        writer = ArchiveWriter(self.archive, force=self.force)
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        procs = _Processes()
        loggers: list[RerunLogger] = []
        session = None
        try:
            if self.router:
                mode = "client"
                procs.start("router", ["router", "--listen", endpoint],
                            self.output / "router.log")
                recorder_cfg = loopback_config(self.output / "zenoh-recorder.json5",
                                               connect=[endpoint], mode=mode)
            else:
                mode = "peer"
                recorder_cfg = loopback_config(self.output / "zenoh-recorder.json5",
                                               listen=[endpoint], mode=mode, gossip=True)
            bridge_cfg = loopback_config(self.output / "zenoh-bridges.json5",
                                         connect=[endpoint], mode=mode, gossip=mode != "client")
            links = [self.output / f"{u.name}.tty" for u in self.units]
            loggers.append(RerunLogger(self.rrd, [u.name for u in self.units],
                                       recording_id="demo"))
            if self.viewer is not None:
                loggers.append(RerunLogger(self.viewer, [u.name for u in self.units],
                                           window_s=30))
            if self.router:
                time.sleep(0.5)  # the router's port opens as it starts
            session = open_session(recorder_cfg)

            def to_rerun(messages: list[Any]) -> None:
                for logger in loggers:
                    log_messages(logger, messages, "gx3")

            recorder = Recorder(session, writer, on_written=to_rerun)
            with Simulator([u.config for u in self.units], "pty", links=links,
                           faults=[u.faults for u in self.units]) as sim:
                for unit, link in zip(self.units, links, strict=True):
                    procs.start(unit.name, ["bridge", "--port", str(link), "--baud",
                                            str(unit.config.stored.baud), "--unit", unit.name,
                                            "--zenoh-config", str(bridge_cfg)],
                                self.output / f"{unit.name}.log")
                self._stream(sim, recorder, procs)
                procs.stop()
                recorder.run_once(1.0)
            recorder.close()
            # what the bridges published after the last look is archived too: count it
            self.rows = recorder.snapshot()
            try:
                writer.close()
            except ArchiveError as exc:
                raise DemoError(str(exc)) from None
        finally:
            writer.close()
            procs.stop()
            for logger in loggers:
                logger.close()
            if session is not None:
                session.close()

    def _stream(self, sim: Simulator, recorder: Any, procs: _Processes) -> None:
        """Wait for every unit to stream, then run for the duration (unplugging one)."""
        started = time.monotonic()
        streaming_since: float | None = None
        unplugged = False
        while not self.stop.is_set():
            recorder.run_once(0.25)
            if recorder.error is not None:
                raise DemoError(str(recorder.error))
            broken = procs.failed()
            if broken:
                raise DemoError(f"{', '.join(broken)} stopped; see its log in {self.output}")
            self.rows = recorder.snapshot()
            now = time.monotonic()
            live = {r.unit for r in self.rows if r.samples > 0}
            if streaming_since is None:
                if live >= {u.name for u in self.units}:
                    streaming_since = now
                elif now - started > STARTUP_TIMEOUT_S:
                    raise DemoError("the bridges did not start streaming within "
                                    f"{STARTUP_TIMEOUT_S:.0f} s; see the logs in {self.output}")
            else:
                elapsed = now - streaming_since
                if not unplugged and elapsed >= 0.3 * self.duration_s:
                    unplugged = True
                    for i, unit in enumerate(self.units):
                        if unit.unplug:
                            sim.unplug(i, max(1.0, 0.1 * self.duration_s))
                if elapsed >= self.duration_s:
                    break
            self.show(self.rows, 0.0 if streaming_since is None else now - streaming_since)

    def summary(self) -> list[UnitOutcome]:
        """What the run gave, unit by unit.

        Returns:
            Per unit: what arrived, what went wrong, and the drift found against the
            truth.
        """
        by_name = {r.unit: r for r in self.rows}
        out = []
        for unit in self.units:
            r = by_name.get(unit.name)
            out.append(UnitOutcome(
                unit=unit.name, samples=r.samples if r else 0, dropped=r.dropped if r else 0,
                checksum_failures=r.checksum_failures if r else 0,
                resyncs=r.resyncs if r else 0, reconnects=r.reconnects if r else 0,
                drift_ppm=r.drift_ppm if r else None, true_ppm=unit.config.clock_ppm,
                notes=", ".join(unit.notes)))
        return out
