"""The recorder hears samples as they flow, not in clumps a poll period apart.

Each archived message carries the moment the recorder's receiving thread took it off
Zenoh; a thread that looked only every 25 ms gave every sample of those 25 ms one
stamp (a latency floor of 25 ms for a fleet at 1 kHz).
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np

from bridge.archive.walk import read_archive
from bridge.archive.writer import ArchiveWriter
from bridge.bus.publish import UnitPublisher
from bridge.protocol.codec import Batch
from bridge.protocol.table import REPLIES
from bridge.recorder.live import Recorder
from tests.helpers.records import CODE, T0
from tests.helpers.zenoh import peer_sessions

SAMPLES = 400


def steady(pub: UnitPublisher) -> None:
    """One sample about every millisecond, as a bridge at 1 kHz puts them."""
    columns = {f.name: np.zeros((1, *f.shape), np.float32) for f in REPLIES[CODE].fields}
    for tick in range(SAMPLES):
        ticks = np.array([tick], np.int64)
        columns["timer"] = ticks.astype(np.uint32)
        times = T0 + ticks * 1_000_000
        pub.publish_samples(Batch(CODE, columns, np.arange(1), times, False), ticks, times)
        time.sleep(0.001)


def test_samples_flowing_are_taken_within_milliseconds(tmp_path: Path) -> None:
    out = tmp_path / "steady.mcap"
    rec_session, pub_session = peer_sessions(2)
    writer = ArchiveWriter(out)
    recorder = Recorder(rec_session, writer)
    pub = UnitPublisher(pub_session, "u")
    try:
        deadline = time.monotonic() + 60
        while not recorder.snapshot():  # the unit's liveliness seen
            assert time.monotonic() < deadline, "unit not seen"
            recorder.run_once(0.05)
        publisher = threading.Thread(target=steady, args=(pub,))
        publisher.start()
        deadline = time.monotonic() + 60
        while publisher.is_alive() or recorder.written < SAMPLES:
            assert time.monotonic() < deadline, f"{recorder.written} archived"
            recorder.run_once(0.1)
        publisher.join()
    finally:
        pub.close()
        recorder.close()
        writer.close()
        pub_session.close()
        rec_session.close()
    (block,) = read_archive(out).samples()
    assert len(block) == SAMPLES
    taken = np.unique(block.receive_ns)
    span_ms = (taken[-1] - taken[0]) / 1e6
    # a look every 25 ms gives at most span/25 + 1 stamps; one every few ms, many more
    assert len(taken) >= span_ms / 10, (
        f"{SAMPLES} samples over {span_ms:.0f} ms were taken in only {len(taken)} looks")
