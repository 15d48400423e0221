"""A recorder killed with SIGKILL loses at most its last REORDER_S + FLUSH_EVERY_S (1.5 s)
of messages."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from bridge.archive.repair import repair
from bridge.archive.walk import read_archive
from bridge.archive.writer import FLUSH_EVERY_S, REORDER_S, ArchiveWriter
from bridge.bus.codec import encode_batch

# Writes 0xCC samples at about 2 kHz, stamped with the wall clock, and reports on stdout
# how many it has written, and when (monotonic), every 50 ms.
_WRITER = """
import sys, time
import numpy as np
from pathlib import Path
from bridge.bus.codec import encode_batch
from tests.helpers.records import synthetic_batch
batch = synthetic_batch(0xCC, 100, 1)
from bridge.archive.writer import ArchiveWriter
writer = ArchiveWriter(Path(sys.argv[1]))
n = 0
last = time.monotonic()
while True:
    now = time.time_ns()
    t = now + np.arange(100, dtype=np.int64)
    for p, ti in zip(encode_batch("u1", batch, np.arange(n, n + 100), t, t), t.tolist()):
        writer.write("gx3/u1/imu", p, ti)
    n += 100
    time.sleep(0.05)
    print(n, time.monotonic(), flush=True)
"""


def test_sigkill_keeps_everything_older_than_the_bound(tmp_path: Path) -> None:
    path = tmp_path / "killed.mcap"
    proc = subprocess.Popen([sys.executable, "-c", _WRITER, str(path)], stdout=subprocess.PIPE,
                            text=True, cwd=Path(__file__).parent.parent)
    progress: list[tuple[int, float]] = []
    try:
        assert proc.stdout is not None
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            count, when = line.split()
            progress.append((int(count), float(when)))
            if progress[-1][1] - progress[0][1] >= 3.5:
                break
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
        if proc.stdout is not None:
            proc.stdout.close()
    assert progress and progress[-1][1] - progress[0][1] >= 3.5, progress
    last_seen = progress[-1][1]
    # what the writer had written 2.5 s before its last report (the 1.5 s bound plus a
    # wide margin)
    safe = max(n for n, when in progress if when <= last_seen - 2.5)
    archive = read_archive(path)
    assert not archive.complete
    got = archive.messages("gx3/u1/imu")
    assert len(got) >= safe, (len(got), safe, progress[-1][0])
    assert len(got) <= progress[-1][0] + 100
    ticks = archive.samples()[0].columns["ticks"]
    assert ticks.tolist() == list(range(len(got)))  # a prefix, nothing missing
    report = repair(path, tmp_path / "fixed.mcap")
    assert report.messages == archive.message_count
    assert read_archive(report.output).complete


def test_what_is_on_disk_lags_the_last_message_by_at_most_the_bound(tmp_path: Path) -> None:
    """Two units at 100 Hz on a virtual clock, the file read as a kill would leave it after
    every write: it holds every message received REORDER_S + FLUSH_EVERY_S before the
    last one, and in the order of their log times."""
    from tests.helpers.records import T0, synthetic_batch

    path = tmp_path / "a.mcap"
    now = [0.0]
    bound_ns = int((REORDER_S + FLUSH_EVERY_S) * 1e9)
    batch = synthetic_batch(0xC2, 10, 1)
    sent: list[int] = []
    with ArchiveWriter(path, clock=lambda: now[0]) as writer:
        for step in range(60):  # 6 s, a write of each unit every 100 ms
            rx = T0 + step * 100_000_000
            for k, unit in enumerate(("u1", "u2")):
                t = rx - 8_000_000 - k * 1_000_000 + np.arange(10, dtype=np.int64) * 10_000_000
                t -= 100_000_000
                writer.write_many(f"gx3/{unit}/imu", encode_batch(
                    unit, batch, np.arange(10), t, t), rx)
                sent += [rx] * 10
            now[0] += 0.1
            writer.tick()
            on_disk = read_archive(path).counts()
            kept = sum(on_disk.get(f"gx3/{u}/imu", (0, 0, 0))[0] for u in ("u1", "u2"))
            assert kept >= sum(1 for r in sent if r <= rx - bound_ns), step
