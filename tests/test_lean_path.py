"""A live bridge's per-read path gives what the batch path (``gx3 replay``) gives.

The bridge takes each read's record or two as plain bytes and integers; a raw capture
replays through the framer's bulk path, the array timing and the bulk encoder. The
same byte stream, cut into reads in many ways (a record a read, several, every read
ending mid-record, random cuts down to single bytes) and carrying garbage, a record
with a bad checksum, a corrupt timer that matches its checksum, lost records and a
timer rollover, must give byte-identical payloads, the same ticks and time_ns and the
same events both ways, whatever the link (UART, native USB, a USB-serial adapter).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pytest

from bridge.bus.codec import encode_batch
from bridge.bus.integrity import seals
from bridge.bus.publish import sealed_records
from bridge.device.session import UnitInfo
from bridge.protocol.codec import Records, checksum, encode_replies
from bridge.protocol.framer import Framer
from bridge.protocol.table import REPLIES
from bridge.timing.stream import Settings, StreamTiming
from bridge.unit.pipeline import Options, Pipeline, TimedSamples, UnitEvent
from tests.helpers.records import T0

CODE = 0xCC
SIZE = REPLIES[CODE].length
BAUD = 921_600
BYTE_NS = 10 * 1_000_000_000 // BAUD
N = 3000


@dataclass
class Collect:
    """The pipeline's sink: what the Zenoh publisher would put, and the events."""

    payloads: list[bytes] = field(default_factory=list)
    ticks: list[int] = field(default_factory=list)
    time_ns: list[int] = field(default_factory=list)
    events: list[tuple[str, int, int]] = field(default_factory=list)
    lean: int = 0  # records that took the plain-integer path
    partial: int = 0  # of those, records with a read that ended inside them

    def info(self, info: UnitInfo) -> None:
        pass

    def samples(self, samples: TimedSamples) -> None:
        records = samples.records
        if isinstance(records, Records):  # as UnitPublisher.publish_records
            self.lean += len(records)
            self.partial += len(records) - (records.part_bytes or [SIZE] * len(records)).count(SIZE)
            payloads, attachments = sealed_records("u1", records, *samples.lists())
            assert attachments == seals(payloads)
            self.payloads += payloads
        else:  # as UnitPublisher.publish_samples
            self.payloads += encode_batch("u1", samples.batch, samples.ticks, samples.time_ns,
                                          samples.rx_ns, samples.batch.rx_ns, samples.part)
        self.ticks += samples.ticks.tolist()
        self.time_ns += samples.time_ns.tolist()

    def event(self, event: UnitEvent) -> None:
        self.events.append((event.kind, event.ticks, event.count))

    def status(self, status: dict[str, Any]) -> None:
        pass


def stream(seed: int) -> tuple[bytes, np.ndarray, list[int]]:
    """0xCC at 1 kHz and 921,600 baud: the bytes, each byte's arrival time, and where
    each record ends. The timer wraps after a second; the damage is spread through."""
    rng = np.random.default_rng(seed)
    timer = (2**32 - 62_500 + np.floor(np.arange(N) * 62.5 + 0.5)).astype(np.int64) % 2**32
    timer[1500] += 7  # a corrupt timer whose record still matches its checksum
    columns = {"accel": rng.normal(0, 1, (N, 3)), "ang_rate": rng.normal(0, 1, (N, 3)),
               "mag": rng.normal(0, 0.5, (N, 3)), "m": rng.uniform(-1, 1, (N, 3, 3)),
               "timer": timer.astype(np.uint32)}
    raw = encode_replies(CODE, columns, N)
    records = [bytearray(raw[i * SIZE : (i + 1) * SIZE]) for i in range(N)]
    records[900][10] ^= 0x40  # a bad checksum: the record is lost
    data = bytearray()
    arrival: list[int] = []
    ends: list[int] = []
    for i, rec in enumerate(records):
        if 2000 <= i < 2005:  # lost on the way: a gap
            continue
        start = T0 + i * 1_000_000 + int(rng.integers(0, 20_000))
        if i == 500:  # line noise between two records
            noise = rng.integers(0, 256, 37, dtype=np.uint8).tobytes()
            data += noise
            arrival += [start - BYTE_NS * (37 - k) for k in range(37)]
        data += rec
        arrival += [start + BYTE_NS * (k + 1) for k in range(SIZE)]
        ends.append(len(data))
    assert checksum(records[1500][:-2]) == int.from_bytes(records[1500][-2:], "big")
    return bytes(data), np.array(arrival, np.int64), ends


def cuts(kind: str, ends: list[int], total: int, seed: int) -> list[int]:
    """Where the reads end."""
    rng = np.random.default_rng(seed)
    if kind == "record":
        points = ends
    elif kind == "several":
        points = ends[2::3]
    elif kind == "mid-record":
        points = [e - SIZE // 2 for e in ends]
    else:
        points = np.cumsum(rng.choice([1, 2, 5, 40, 79, 80, 150, 300], 4 * N)).tolist()
    return sorted({p for p in points if 0 < p < total} | {total})


def receive_times(arrival: np.ndarray, read_ends: list[int], seed: int) -> np.ndarray:
    """Each read's receive time: its last byte's arrival plus the host's latency, never
    before the read before it."""
    rng = np.random.default_rng(seed)
    rx = arrival[np.array(read_ends) - 1] + rng.exponential(150_000, len(read_ends)).astype(
        np.int64)
    return np.maximum.accumulate(rx)


def settings(transport: str) -> Settings:
    return Settings(record=CODE, decimation=1, filter_width=15, baud=BAUD, transport=transport)


def batch_path(data: bytes, read_ends: list[int], rx: np.ndarray, transport: str) -> Collect:
    """What ``gx3 replay`` does with the capture: all reads framed at once, one batch
    timed and encoded at a time."""
    out = Collect()
    timing = StreamTiming()
    timing.configure(settings(transport), restarted=True)
    for batch in Framer(expect=[CODE]).feed_reads(data, np.array(read_ends), rx):
        timed = timing.process(batch)
        out.events += [(e.kind, e.ticks, e.count) for e in timed.events]
        out.payloads += encode_batch("u1", timed.batch, timed.ticks, timed.time_ns,
                                     timed.rx_ns, timed.batch.rx_ns, timed.part)
        out.ticks += timed.ticks.tolist()
        out.time_ns += timed.time_ns.tolist()
    return out


def live_path(data: bytes, read_ends: list[int], rx: np.ndarray, transport: str) -> Collect:
    """What the bridge does: each read framed as it comes, its records through the
    pipeline to the sink."""
    out = Collect()
    pipeline = Pipeline(Options(url="/dev/ttyS0", baud=BAUD), out)
    pipeline.timing.configure(settings(transport), restarted=True)
    framer = Framer(expect=[CODE])
    start = 0
    for end, rx_ns in zip(read_ends, rx.tolist(), strict=True):
        for records in framer.feed_records([data[start:end]], [rx_ns]):
            pipeline.process(records)
        start = end
    return out


@pytest.mark.parametrize("transport", ["uart", "usb", "usb-serial"])
@pytest.mark.parametrize("kind", ["record", "several", "mid-record", "random"])
def test_reads_however_cut_give_the_batch_paths_payloads_times_and_events(
        kind: str, transport: str) -> None:
    data, arrival, ends = stream(7)
    read_ends = cuts(kind, ends, len(data), 8)
    rx = receive_times(arrival, read_ends, 9)
    live = live_path(data, read_ends, rx, transport)
    replay = batch_path(data, read_ends, rx, transport)
    assert len(replay.payloads) == N - 5 - 1 - 1  # lost, bad checksum, corrupt timer
    assert live.payloads == replay.payloads
    assert live.ticks == replay.ticks
    assert live.time_ns == replay.time_ns
    assert live.events == replay.events
    assert {e[0] for e in live.events} >= {"rollover", "gap", "glitch"}
    # the plain-integer path carried the stream, the batch path only its upsets
    assert live.lean >= 0.95 * len(live.payloads)
    if kind in ("mid-record", "random"):  # their partial reads went the plain way too
        assert live.partial >= 0.3 * live.lean
