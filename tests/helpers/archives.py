"""Archives and raw captures written for tests, and what tests read back out of archives."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bridge.archive.rawcapture import RawCaptureWriter
from bridge.archive.reader import ArchiveReader
from bridge.archive.walk import read_archive
from bridge.archive.writer import ArchiveWriter
from bridge.bus.codec import encode_batch
from bridge.bus.gx3_pb2 import Event, Info, Status
from bridge.protocol.codec import Batch
from tests.helpers.records import T0, synthetic_batch

PERIOD = 10_000_000  # ns between a unit's samples in the fleet: 100 Hz
LATENCY = 3_000_000  # ns from a sample's time to its receive time in the fleet


@dataclass
class Written:
    """What a test wrote: per topic (log time, receive time, payload), and the batches."""

    messages: dict[str, list[tuple[int, int, bytes]]] = field(default_factory=dict)
    batches: dict[str, Batch] = field(default_factory=dict)
    times: dict[str, np.ndarray] = field(default_factory=dict)

    def add(self, topic: str, log_ns: int, rx: int, payload: bytes) -> None:
        self.messages.setdefault(topic, []).append((log_ns, rx, payload))


#: unit -> (record type, samples, first sample index): u2 appears mid-run, u3 has no attitude
FLEET = {"u1": (0xCC, 300, 0), "u2": (0xDF, 200, 60), "u3": (0xC2, 150, 10)}


Feed = list[tuple[int, str, bytes, int]]  # (receive ns, key, payload, log ns)


def fleet_feed() -> tuple[Written, Feed]:
    """Three units at 100 Hz, with status each second, events, info and one raw read, in
    the order they are received."""
    written = Written()
    feed: Feed = []
    for k, (unit, (code, n, first)) in enumerate(FLEET.items()):
        euler = np.stack([np.linspace(0, 1, n), np.linspace(0, -0.5, n),
                          np.linspace(-3, 3, n)], axis=1)
        batch = synthetic_batch(code, n, k + 1, euler)
        time_ns = T0 + (first + np.arange(n, dtype=np.int64)) * PERIOD + k * 1000
        rx = time_ns + LATENCY
        payloads = encode_batch(unit, batch, np.arange(n, dtype=np.int64) * 625, time_ns, rx)
        written.batches[unit] = batch
        written.times[unit] = time_ns
        for p, t, r in zip(payloads, time_ns.tolist(), (rx + 500).tolist(), strict=True):
            feed.append((r, f"gx3/{unit}/imu", p, t))
        for s in range(0, n, 100):
            t = int(time_ns[s])
            status = Status(unit=unit, time_ns=t, samples=s, connected=True).SerializeToString()
            feed.append((t + 1, f"gx3/{unit}/status", status, t))
        gap = Event(unit=unit, time_ns=int(time_ns[n // 2]), ticks=625 * (n // 2),
                    kind=Event.GAP, count=3, detail="3 records missing")
        feed.append((int(time_ns[n // 2]) + 2, f"gx3/{unit}/event", gap.SerializeToString(),
                     int(time_ns[n // 2])))
        info = Info(unit=unit, model_name="3DM-GX3-25", bring_up_time_ns=int(time_ns[0]) - 5)
        feed.append((int(time_ns[0]) - 4, f"gx3/{unit}/info", info.SerializeToString(),
                     int(time_ns[0]) - 5))
    feed.append((T0 + 7, "gx3/u1/raw", b"\xcc\x00\x01raw bytes", T0 + 7))
    feed.sort(key=lambda f: f[0])
    for receive_ns, key, payload, log_ns in feed:
        written.add(key, log_ns, receive_ns, payload)
    return written, feed


def write_fleet(path: Path, **options: object) -> Written:
    """The ``fleet_feed`` archived at ``path`` (``options``: the ArchiveWriter's)."""
    written, feed = fleet_feed()
    with ArchiveWriter(path, **options) as writer:  # type: ignore[arg-type]
        for receive_ns, key, payload, _ in feed:
            writer.write(key, payload, receive_ns)
    return written


YAW_RATE = 0.5  # rad/s
ACCEL_RATE = 0.25  # g/s


def write_two_units(path: Path, names: tuple[str, str] = ("u1", "u2"),
                    infos: dict[str, Info] | None = None) -> None:
    """u1 at 100 Hz from T0 + 3 ms; u2 at 40 Hz from T0 + 11 ms, with 0.3 s missing; the
    Info in ``infos`` archived first."""
    with ArchiveWriter(path) as writer:
        for unit, info in (infos or {}).items():
            writer.write(f"gx3/{unit}/info", info.SerializeToString(), T0)
        for unit, period, offset, gap in ((names[0], 10_000_000, 3_000_000, None),
                                          (names[1], 25_000_000, 11_000_000, (40, 52))):
            n = 2_000_000_000 // period
            keep = np.ones(n, bool)
            if gap:
                keep[gap[0] : gap[1]] = False
            t = T0 + offset + np.arange(n, dtype=np.int64) * period
            s = (t - T0) / 1e9
            euler = np.stack([np.zeros(n), np.zeros(n), -1.0 + YAW_RATE * s], axis=1)
            batch = synthetic_batch(0xC8, n, 1, euler)
            batch.columns["accel"][:, 0] = ACCEL_RATE * s
            payloads = encode_batch(unit, batch, np.arange(n), t, t)
            for i in np.flatnonzero(keep).tolist():
                writer.write(f"gx3/{unit}/imu", payloads[i], int(t[i]))


def write_capture(path: Path, reads: list[tuple[int, bytes]],
                  metadata: dict[str, str] | None = None) -> Path:
    """A raw capture of unit u1's ``reads`` (receive ns, bytes) on gx3/u1/raw, with the
    ``metadata`` a replay reads if given (none: as another program writes one)."""
    writer = RawCaptureWriter(path, "gx3", "u1", metadata)
    for rx, data in reads:
        writer.write(data, rx)
    writer.close()
    return path


def so_far(path: Path) -> ArchiveReader | None:
    """An archive being written, as read now; None before its header is written."""
    if not path.exists() or not path.stat().st_size:
        return None
    return read_archive(path)


def samples_in(path: Path, unit: str) -> int:
    """Samples of ``unit`` in an archive being written (flushed every second)."""
    archive = so_far(path)
    return 0 if archive is None else sum(len(b) for b in archive.samples([unit]))


def topics_in(path: Path) -> list[str]:
    """The topics of an archive being written (none before its header is written)."""
    archive = so_far(path)
    return [] if archive is None else archive.topics()


def events_in(path: Path, unit: str) -> list[Event]:
    """``unit``'s events in an archive being written (none before its header is written)."""
    archive = so_far(path)
    return [] if archive is None else [e for _, e in archive.events([unit])]


def sample_columns(path: Path, unit: str) -> dict[str, np.ndarray]:
    """A unit's samples in an archive, in tick order: what replay must reproduce."""
    blocks = read_archive(path).samples([unit])
    out = {k: np.concatenate([b.columns[k] for b in blocks])
           for k in ("ticks", "time_ns", "rx_ns", "accel", "m")}
    order = np.argsort(out["ticks"], kind="stable")
    return {k: v[order] for k, v in out.items()}


def archived_events(path: Path, unit: str, kind: int) -> list[Event]:
    """``unit``'s events of ``kind`` in an archive."""
    return [e for _, e in read_archive(path).events([unit]) if e.kind == kind]
