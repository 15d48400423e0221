"""Where a live bridge's CPU goes, stage by stage, without the port or Zenoh.

A 1 kHz 0xCC stream is fed from memory as the pty gives it (each record in two reads,
cut at a varying place), through what ``gx3 bridge`` runs per read: the framer
(``Framer.feed_records``), the pipeline's timing (``Pipeline.process``) and the
encoding of each ImuSample with its CRC (``sealed_records``, as
``UnitPublisher.publish_records`` does before its puts: in the compiled core where it
is built; ``GX3_NATIVE=0`` measures the pure-Python paths). Each stage's thread CPU
is summed. ``--cadence-ms`` sleeps between records as a live bridge waits for the
next one: the caches go cold, and the same work costs several times what it costs
back to back (``--cadence-ms 0``).

    python bench/bench_per_read.py --records 3000 --cadence-ms 1
"""

from __future__ import annotations

import argparse
import time
from collections import Counter
from typing import Any

import numpy as np

from bridge.bus.codec import encode_batch
from bridge.bus.integrity import seals
from bridge.bus.publish import sealed_records
from bridge.device.session import UnitInfo
from bridge.protocol.codec import Records, encode_replies
from bridge.protocol.framer import Framer
from bridge.timing.stream import Settings
from bridge.unit.pipeline import Options, Pipeline, TimedSamples, UnitEvent

CODE = 0xCC
T0 = 1_763_000_000_000_000_000


class Encode:
    """The pipeline's sink: the payloads and attachments the publisher would put."""

    def __init__(self, spent: Counter[str]) -> None:
        self.spent = spent
        self.records = 0

    def info(self, info: UnitInfo) -> None:
        pass

    def samples(self, samples: TimedSamples) -> None:
        start = time.thread_time_ns()
        records = samples.records
        if isinstance(records, Records):
            sealed_records("bench", records, *samples.lists())
        else:  # the first record of a stream: the batch path
            seals(encode_batch("bench", samples.batch, samples.ticks, samples.time_ns,
                               samples.rx_ns, samples.batch.rx_ns, samples.part))
        self.records += len(records)
        self.spent["encode + CRC"] += time.thread_time_ns() - start

    def event(self, event: UnitEvent) -> None:
        pass

    def status(self, status: dict[str, Any]) -> None:
        pass


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--records", type=int, default=3000)
    parser.add_argument("--cadence-ms", type=float, default=1.0,
                        help="wall time between records (0: back to back)")
    args = parser.parse_args()
    n = args.records
    rng = np.random.default_rng(1)
    raw = encode_replies(CODE, {
        "accel": rng.normal(size=(n, 3)), "ang_rate": rng.normal(size=(n, 3)),
        "mag": rng.normal(size=(n, 3)), "m": rng.uniform(-1, 1, (n, 3, 3)),
        "timer": np.floor(np.arange(n) * 62.5 + 1000.5).astype(np.uint32)}, n)
    size = len(raw) // n
    ends = [e for i in range(n) for e in (i * size + int(rng.integers(20, 60)), (i + 1) * size)]
    spent: Counter[str] = Counter()
    sink = Encode(spent)
    pipeline = Pipeline(Options(url="/dev/ttyS0", baud=921_600), sink)
    pipeline.timing.configure(Settings(record=CODE, decimation=1, filter_width=15,
                                       baud=921_600), restarted=True)
    framer = Framer(expect=[CODE])
    start = 0
    for end in ends:
        rx_ns = T0 + end * 1_000_000 // size + 200_000
        t0 = time.thread_time_ns()
        found = framer.feed_records([raw[start:end]], [rx_ns])
        t1 = time.thread_time_ns()
        spent["framer"] += t1 - t0
        for records in found:
            before = spent["encode + CRC"]
            pipeline.process(records)
            spent["timing"] += time.thread_time_ns() - t1 - (spent["encode + CRC"] - before)
        start = end
        if args.cadence_ms:
            time.sleep(args.cadence_ms / 2000)  # two reads a record
    total = sum(spent.values())
    print(f"0x{CODE:02X}, {sink.records} records in {len(ends)} reads, "
          f"{args.cadence_ms:g} ms between records: {total / sink.records / 1e3:.1f} µs "
          "per record: " + ", ".join(f"{k} {v / sink.records / 1e3:.1f}"
                                     for k, v in spent.most_common()))


if __name__ == "__main__":
    main()
