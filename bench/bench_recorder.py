"""`gx3 record` under a fleet's load: UNITS units at RATE Hz for SECONDS into one archive.

Load generators (PROCS processes, each publishing a share of the units through the
same UnitPublisher a bridge uses, 10 records per put burst as a USB read delivers
them) feed one `gx3 record` process. Reports the recorder's CPU and peak memory,
the bytes per sample on disk, the samples lost (published minus archived), and those
archived but not as published (each is checked).

    python bench/bench_recorder.py --units 100 --rate 1000 --seconds 60
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from procstat import cpu_seconds, peak_rss_mb

from bridge.fleet.loopback import free_port, loopback_config

CODE = 0xCC


def imu_messages(path: Path) -> int:
    """The samples in an archive, from its summary (decoding each is not needed to count)."""
    from mcap.reader import make_reader

    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    counts = summary.statistics.channel_message_counts
    return sum(counts.get(c.id, 0) for c in summary.channels.values()
               if c.topic.endswith("/imu"))


def damaged(path: Path, per_unit: int) -> int:
    """Archived samples that are not as published: each unit's ticks are 0, 62, 124, ...
    once each and every quantity is 0, so a payload mangled in transit shows."""
    from bridge.archive.walk import read_archive

    bad = 0
    expected = np.arange(per_unit) * 62
    for block in read_archive(path).samples():
        ticks = block.columns["ticks"]
        wrong = ~np.isin(ticks, expected)
        for name in ("accel", "ang_rate", "mag", "m"):
            wrong |= (block.columns[name].reshape(len(ticks), -1) != 0).any(axis=1)
        bad += int(wrong.sum()) + len(ticks[~wrong]) - len(np.unique(ticks[~wrong]))
    return bad


def publish(config: str, units: list[str], rate: float, seconds: float) -> None:
    """One load generator: its units publish ``rate`` Hz each, in bursts of 10."""
    from bridge.bus.publish import UnitPublisher
    from bridge.bus.session import open_session
    from bridge.protocol.codec import Batch, encode_replies
    from bridge.protocol.table import REPLIES

    spec = REPLIES[CODE]
    burst = 10
    columns = {f.name: np.zeros((burst, *f.shape), np.float32) for f in spec.fields
               if f.name != "timer"}
    columns["timer"] = np.zeros(burst, np.uint32)
    block = np.frombuffer(encode_replies(CODE, columns, burst), np.uint8)
    from bridge.protocol.codec import decode_block
    decoded = decode_block(CODE, block.reshape(burst, -1))
    with open_session(config) as session:
        pubs = [UnitPublisher(session, u, cache_samples=int(rate * 5)) for u in units]
        print("READY", flush=True)
        sys.stdin.readline()
        t0 = time.monotonic()
        n = 0
        while n < rate * seconds:
            due = t0 + (n + burst) / rate
            time.sleep(max(0.0, due - time.monotonic()))
            ticks = np.arange(n, n + burst, dtype=np.int64) * 62
            now = time.time_ns()
            rx = np.full(burst, now, np.int64)
            batch = Batch(CODE, {**decoded, "timer": ticks.astype(np.uint32)},
                          np.arange(burst), rx, False)
            for pub in pubs:
                pub.publish_samples(batch, ticks, rx)
            n += burst
        print(f"PUBLISHED {n * len(pubs)}", flush=True)
        sys.stdin.readline()
        for pub in pubs:
            pub.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--units", type=int, default=100)
    parser.add_argument("--rate", type=float, default=1000.0)
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--procs", type=int, default=4)
    parser.add_argument("--publish", nargs="*", help=argparse.SUPPRESS)
    parser.add_argument("--config", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.publish is not None:
        publish(args.config, args.publish, args.rate, args.seconds)
        return
    gx3 = str(Path(sys.executable).parent / "gx3")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with tempfile.TemporaryDirectory() as tmp:
        rec_cfg = loopback_config(Path(tmp, "rec.json5"), listen=[endpoint])
        pub_cfg = loopback_config(Path(tmp, "pub.json5"), connect=[endpoint])
        out = Path(tmp, "load.mcap")
        recorder = subprocess.Popen([gx3, "record", "-o", str(out), "--zenoh-config",
                                     str(rec_cfg), "--quiet"])
        time.sleep(2.0)
        names = [f"u{i:03d}" for i in range(args.units)]
        gens = [subprocess.Popen([sys.executable, __file__, "--config", str(pub_cfg),
                                  "--rate", str(args.rate), "--seconds", str(args.seconds),
                                  "--publish", *names[i :: args.procs]],
                                 stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
                for i in range(args.procs)]
        for g in gens:
            assert g.stdout is not None and g.stdout.readline().strip() == "READY"
        time.sleep(2.0)
        cpu0, wall0 = cpu_seconds(recorder.pid), time.monotonic()
        for g in gens:
            assert g.stdin is not None
            g.stdin.write("go\n")
            g.stdin.flush()
        published = 0
        for g in gens:
            assert g.stdout is not None
            published += int(g.stdout.readline().split()[1])
        time.sleep(3.0)
        cpu1, wall1 = cpu_seconds(recorder.pid), time.monotonic()
        rss = peak_rss_mb(recorder.pid)
        recorder.send_signal(signal.SIGINT)
        recorder.wait(timeout=120)
        for g in gens:
            assert g.stdin is not None
            g.stdin.write("done\n")
            g.stdin.close()
            g.wait(timeout=60)
        archived = imu_messages(out)
        size = out.stat().st_size
        bad = damaged(out, round(args.rate * args.seconds))
    print(f"{args.units} units x {args.rate:g} Hz for {args.seconds:g} s "
          f"({args.units * args.rate:,.0f} samples/s offered)")
    print(f"published {published:,}, archived {archived:,}, lost {published - archived:,}; "
          f"{bad:,} not decoded as published")
    print(f"recorder CPU {100 * (cpu1 - cpu0) / (wall1 - wall0):.0f} % of one core, "
          f"peak memory {rss:.0f} MiB, {size / max(1, archived):.1f} bytes per sample on disk")


if __name__ == "__main__":
    main()
