"""Zenoh's splice under back-pressure, against the product: is every damaged payload caught?

A publishing process puts one unit's samples through UnitPublisher (BLOCK, RELIABLE) as
fast as it can, every value a known function of the sample's index; a receiving process
takes them with ``bridge.subscribe`` and stalls now and then:

- ``--mode app``: an app that stops reading for STALL s every EVERY samples, with a small
  channel (QUEUE), so Zenoh's receive path waits and the publisher's BLOCK puts outlive
  ``wait_before_close`` (WBC_US, short here to provoke it): Zenoh closes the link mid-write
  and splices bytes into payloads (stack-facts, "Zenoh under back-pressure"). Reports the
  samples rejected (CRC or unit) and any accepted sample whose values are not as published.
- ``--mode recorder``: the recorder's engine whose writer stalls STALL s every EVERY
  samples; its receiving thread keeps Zenoh's channel empty, so no link should close.
  Reports the archive against what was published and the events accounting for the rest.

    python bench/bench_splice.py --mode app --seconds 15 --stall 0.5 --every 20000
    python bench/bench_splice.py --mode recorder --seconds 20 --rate 20000 --stall 7 \
        --every 100000
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bridge.fleet.loopback import free_port

CODE = 0xC2
STEP = 62  # ticks between samples (1 kHz)


def config(endpoint: str, listen: bool, wbc_us: int) -> str:
    return json.dumps({
        "mode": "peer", ("listen" if listen else "connect"): {"endpoints": [endpoint]},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "transport": {"link": {"tx": {"queue": {"congestion_control": {"block": {
            "wait_before_close": wbc_us}}}}}}})


def publish(args: argparse.Namespace) -> None:
    import zenoh

    from bridge.bus.publish import UnitPublisher
    from bridge.protocol.codec import Batch
    from bridge.protocol.table import REPLIES

    zenoh.init_log_from_env_or("error")
    session = zenoh.open(zenoh.Config.from_json5(config(args.endpoint, False, args.wbc_us)))
    pub = UnitPublisher(session, "u", cache_samples=1000)
    time.sleep(1.5)
    burst = 10
    n = 0
    t0 = time.monotonic()
    t_end = t0 + args.seconds
    while time.monotonic() < t_end:
        if args.rate:
            time.sleep(max(0.0, t0 + n / args.rate - time.monotonic()))
        index = np.arange(n, n + burst)
        columns = {f.name: np.repeat(index.astype(np.float32), int(np.prod(f.shape))).reshape(
            burst, *f.shape) for f in REPLIES[CODE].fields}
        ticks = index * STEP
        columns["timer"] = ticks.astype(np.uint32)
        pub.publish_samples(Batch(CODE, columns, index, ticks, False), ticks, ticks)
        n += burst
    print(f"PUBLISHED {n}", flush=True)
    time.sleep(args.grace)
    pub.close()
    session.close()


def wrong(columns: dict[str, np.ndarray]) -> int:
    """Samples whose values are not the function of their ticks that was published."""
    index = columns["ticks"] / STEP
    bad = columns["ticks"] % STEP != 0
    for name in ("accel", "ang_rate"):
        bad |= (columns[name] != index[:, None]).any(axis=1)
    bad |= columns["time_ns"] != columns["ticks"]
    return int(bad.sum())


def receive_app(args: argparse.Namespace) -> None:
    import zenoh

    from bridge.bus.subscribe import subscribe

    zenoh.init_log_from_env_or("error")
    session = zenoh.open(zenoh.Config.from_json5(config(args.endpoint, True, args.wbc_us)))
    sub = subscribe("gx3/*/imu", output="batches", session=session, queue_size=args.queue,
                    idle_timeout=args.grace)
    print("READY", flush=True)
    got, bad, seen = 0, 0, set()
    for batch in sub:
        before = got // args.every
        got += len(batch)
        bad += wrong(batch.columns)
        seen.update((batch["ticks"] // STEP).tolist())
        if got // args.every > before:
            time.sleep(args.stall)
    sub.close()
    print(json.dumps({"accepted": got, "unique": len(seen), "rejected": sub.rejected,
                      "accepted_but_wrong": bad, "reported_missed": sub.misses}), flush=True)
    session.close()


def receive_recorder(args: argparse.Namespace) -> None:
    import zenoh

    from bridge.archive.walk import read_archive
    from bridge.archive.writer import ArchiveWriter
    from bridge.bus.gx3_pb2 import Event
    from bridge.recorder.live import Recorder

    zenoh.init_log_from_env_or("error")
    session = zenoh.open(zenoh.Config.from_json5(config(args.endpoint, True, args.wbc_us)))
    out = Path(args.out)
    writer = ArchiveWriter(out)
    rec = Recorder(session, writer, buffer_bytes=args.buffer_mb << 20)
    print("READY", flush=True)
    stalled_at = 0
    quiet_since = time.monotonic()
    last = 0
    while time.monotonic() - quiet_since < args.grace:
        if rec.received - stalled_at >= args.every:
            stalled_at = rec.received
            time.sleep(args.stall)  # the writer stalls; Zenoh is still emptied
        rec.run_once(0.2)
        if rec.received != last:
            last, quiet_since = rec.received, time.monotonic()
    rec.close()
    writer.close()
    session.close()
    archive = read_archive(out)
    blocks = archive.samples(["u"])
    columns = {k: np.concatenate([b.columns[k] for b in blocks])
               for k in ("ticks", "time_ns", "accel", "ang_rate")}
    counts = {Event.Kind.Name(k): 0 for k in (Event.LOST, Event.REJECTED, Event.SHED)}
    for _, event in archive.events(["u"]):
        if event.leaf == "imu" and Event.Kind.Name(event.kind) in counts:
            counts[Event.Kind.Name(event.kind)] += event.count
    print(json.dumps({"archived": len(columns["ticks"]),
                      "unique": len(np.unique(columns["ticks"])),
                      "archived_but_wrong": wrong(columns), "events": counts}), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--mode", choices=("app", "recorder"), default="app")
    parser.add_argument("--seconds", type=float, default=15.0)
    parser.add_argument("--rate", type=float, default=0.0,
                        help="samples/s to publish (0: as fast as possible)")
    parser.add_argument("--stall", type=float, default=0.5)
    parser.add_argument("--every", type=int, default=20_000)
    parser.add_argument("--queue", type=int, default=1000)
    parser.add_argument("--buffer-mb", type=int, default=256)
    parser.add_argument("--wbc-us", type=int, default=100_000)
    parser.add_argument("--grace", type=float, default=8.0)
    parser.add_argument("--role", help=argparse.SUPPRESS)
    parser.add_argument("--endpoint", help=argparse.SUPPRESS)
    parser.add_argument("--out", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.role == "pub":
        return publish(args)
    if args.role == "sub":
        return receive_app(args) if args.mode == "app" else receive_recorder(args)
    with tempfile.TemporaryDirectory() as tmp:
        common = [sys.argv[0], "--mode", args.mode, "--seconds", str(args.seconds),
                  "--rate", str(args.rate),
                  "--stall", str(args.stall), "--every", str(args.every), "--queue",
                  str(args.queue), "--buffer-mb", str(args.buffer_mb), "--wbc-us",
                  str(args.wbc_us), "--grace", str(args.grace), "--endpoint",
                  f"tcp/127.0.0.1:{free_port()}", "--out", str(Path(tmp, "splice.mcap"))]
        sub = subprocess.Popen([sys.executable, *common, "--role", "sub"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        assert sub.stdout is not None
        assert sub.stdout.readline().strip() == "READY"
        pub = subprocess.run([sys.executable, *common, "--role", "pub"], capture_output=True,
                             text=True, check=True)
        out, err = sub.communicate()
    published = int(pub.stdout.split()[-1])
    closes = (pub.stdout + pub.stderr).count("Closing transport")
    print(f"mode {args.mode}: published {published:,}; the publisher's Zenoh closed the link "
          f"{closes} time(s)")
    print(out.strip().splitlines()[-1] if out.strip() else err[-2000:])


if __name__ == "__main__":
    main()
