"""The recorder under a burst: many units publishing at once over real Zenoh sessions.

A recorder whose subscriptions hold only a few hundred messages must make Zenoh (and
the publishers) wait, never drop: every sample of every unit lands in the archive,
each unit's in the order it was published.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
from mcap.reader import make_reader

from bridge.archive.writer import ArchiveWriter
from bridge.bus.codec import parse
from bridge.bus.publish import UnitPublisher
from bridge.bus.subscribe import subscribe
from bridge.protocol.codec import Batch
from bridge.protocol.table import REPLIES
from bridge.recorder.live import Recorder
from tests.helpers.records import CODE, T0
from tests.helpers.zenoh import peer_sessions

UNITS = 40
PER_UNIT = 500
BURST = 50


def burst(pubs: list[UnitPublisher]) -> None:
    """Every unit's samples, ``BURST`` at a time, the units taking turns."""
    fields = REPLIES[CODE].fields
    for start in range(0, PER_UNIT, BURST):
        ticks = np.arange(start, start + BURST, dtype=np.int64)
        times = T0 + ticks * 1_000_000
        columns = {f.name: np.zeros((BURST, *f.shape), np.float32) for f in fields}
        columns["timer"] = ticks.astype(np.uint32)
        batch = Batch(CODE, columns, np.arange(BURST), times, False)
        for pub in pubs:
            pub.publish_samples(batch, ticks, times)


def test_a_burst_on_many_keys_is_archived_completely_and_in_order(tmp_path: Path) -> None:
    out = tmp_path / "burst.mcap"
    rec_session, pub_session = peer_sessions(2)
    writer = ArchiveWriter(out)
    recorder = Recorder(rec_session, writer, queue_size=300)
    pubs = [UnitPublisher(pub_session, f"u{i:02d}") for i in range(UNITS)]
    try:
        deadline = time.monotonic() + 60
        while len(recorder.snapshot()) < UNITS:  # every unit's liveliness seen
            assert time.monotonic() < deadline, "units not seen"
            recorder.run_once(0.05)
        publisher = threading.Thread(target=burst, args=(pubs,))
        publisher.start()
        deadline = time.monotonic() + 120
        while publisher.is_alive() or recorder.written < UNITS * PER_UNIT:
            assert time.monotonic() < deadline, f"{recorder.written} archived"
            recorder.run_once(0.1)
        publisher.join()
        rows = recorder.snapshot()
    finally:
        for pub in pubs:
            pub.close()
        recorder.close()
        writer.close()
        pub_session.close()
        rec_session.close()
    assert recorder.error is None and recorder.misses == 0
    assert [r.samples for r in rows] == [PER_UNIT] * UNITS
    with out.open("rb") as f:
        reader = make_reader(f)
        for i in range(UNITS):
            messages = [m for _, _, m in reader.iter_messages(topics=[f"gx3/u{i:02d}/imu"],
                                                              log_time_order=False)]
            assert [m.sequence for m in messages] == list(range(PER_UNIT))
            ticks = [parse(m.data).ticks for m in messages]
            assert ticks == list(range(PER_UNIT)), f"u{i:02d}: samples lost or out of order"


def test_closing_a_subscription_that_holds_zenoh_back(tmp_path: Path) -> None:
    """A full channel (nobody reading) must not keep close from returning."""
    rec_session, pub_session = peer_sessions(2)
    try:
        sub = subscribe("gx3/*/imu", output="raw", session=rec_session, queue_size=10)
        pub = UnitPublisher(pub_session, "u")
        deadline = time.monotonic() + 30
        while not sub.take(1, timeout=0.1):  # the route is up
            burst([pub])
            assert time.monotonic() < deadline
        burst([pub])  # far more than the channel holds
        closing = threading.Thread(target=sub.close)
        closing.start()
        closing.join(30)
        assert not closing.is_alive(), "close hangs while Zenoh waits on the full channel"
        pub.close()
    finally:
        pub_session.close()
        rec_session.close()
