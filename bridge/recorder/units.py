"""What the recorder knows of each unit, and the row the terminal shows of it."""

from __future__ import annotations

from dataclasses import dataclass, field

from bridge.bus.gx3_pb2 import Status
from bridge.recorder.hosts import UnitHost
from bridge.timing.rate import RateWindow


@dataclass(frozen=True)
class UnitRow:
    """One unit as the terminal (``gx3 record``, ``gx3 demo``) and Prometheus show it.

    Attributes:
        unit: Its name.
        alive: Whether its bridge is on the network (its liveliness token).
        rate: Samples a second archived, over the last few seconds.
        samples: Samples archived.
        dropped: Records its bridge found missing (its latest Status).
        checksum_failures: Records its bridge's framer refused.
        resyncs: Times its bridge's framer lost the records' boundaries.
        reconnects: Times its bridge reopened the port.
        offset_ms: How far its clock offset moved since its first Status with a clock
            model (the offset itself is an instant near the epoch); None before one.
        drift_ppm: Its clock's drift; None until the model has measured the rate.
        recorded_s: Seconds from its first sample archived to its last.
        bytes: Bytes of its messages archived.
        joined: Times its bridge joined.
        heard_ns: When its last message was received (host ns; 0: none yet).
    """

    unit: str
    alive: bool
    rate: float
    samples: int
    dropped: int
    checksum_failures: int
    resyncs: int
    reconnects: int
    offset_ms: float | None
    drift_ppm: float | None
    recorded_s: float
    bytes: int
    joined: int
    heard_ns: int


@dataclass
class UnitView:
    """What the recorder has seen of one unit: its messages, its latest Status, its host."""

    name: str
    alive: bool = True
    samples: int = 0
    bytes: int = 0
    first_ns: int = 0
    last_ns: int = 0
    heard_ns: int = 0  # its last message's receive time, whatever its kind
    status: Status | None = None
    #: the clock offset of its first status with a clock model: the row shows how far
    #: the offset has moved since (the offset itself is an instant near the epoch)
    first_offset_ns: int | None = None
    joined: int = 1
    meter: RateWindow = field(default_factory=lambda: RateWindow(3.0))
    host: UnitHost = field(init=False)

    def __post_init__(self) -> None:
        self.host = UnitHost(self.name)

    def row(self, now: float) -> UnitRow:
        """The unit's row.

        Args:
            now: Now, on ``time.monotonic``: the end of the rate's window.

        Returns:
            What the terminal shows of it.
        """
        s = self.status
        return UnitRow(
            unit=self.name, alive=self.alive, rate=self.meter.rate(now, self.samples),
            samples=self.samples, dropped=s.dropped if s else 0,
            checksum_failures=s.checksum_failures if s else 0,
            resyncs=s.resyncs if s else 0, reconnects=s.reconnects if s else 0,
            offset_ms=None if s is None or self.first_offset_ns is None
            or not s.clock_offset_ns else (s.clock_offset_ns - self.first_offset_ns) / 1e6,
            # exactly 0 until the model has measured the rate (see gx3.proto)
            drift_ppm=s.clock_drift_ppm if s and s.clock_offset_ns and s.clock_drift_ppm
            else None,
            recorded_s=(self.last_ns - self.first_ns) / 1e9, bytes=self.bytes,
            joined=self.joined, heard_ns=self.heard_ns)
