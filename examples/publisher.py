"""A stand-in bridge: publishes synthetic records of one unit through UnitPublisher.

For trying subscribers without hardware, and for the tests' publishing process.
Prints READY once declared, then waits for a line on stdin before publishing
``--count`` samples at ``--rate`` Hz (in reads of ``--per-read`` records, as a
serial reader would), prints DONE, and keeps its cache alive until stdin closes.

    python examples/publisher.py --listen tcp/127.0.0.1:7447 --unit imu0 --count 5000
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from bridge.bus.gx3_pb2 import Info
from bridge.bus.publish import UnitPublisher
from bridge.bus.session import open_session
from bridge.exceptions import SessionError
from bridge.protocol.codec import Batch
from bridge.protocol.table import REPLIES, TICKS_PER_SECOND


def synthetic(code: int, start: int, n: int, rx_ns: int) -> Batch:
    """n records of ``code`` whose every value is a known function of the record index,
    as one read received at ``rx_ns``."""
    index = np.arange(start, start + n)
    columns: dict[str, np.ndarray] = {}
    for f in REPLIES[code].fields:
        if f.name == "timer":
            columns[f.name] = (index * (TICKS_PER_SECOND // 1000)).astype(np.uint32)
        else:
            shape = (n, *f.shape)
            values = index.reshape(-1, *([1] * len(f.shape))) + np.zeros(shape)
            columns[f.name] = values.astype(np.uint16 if f.kind == "u16" else np.float32)
    return Batch(code, columns, index * REPLIES[code].length, np.full(n, rx_ns, np.int64),
                 False)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--zenoh-config")
    p.add_argument("--connect", action="append", default=[])
    p.add_argument("--listen", action="append", default=[])
    p.add_argument("--mode")
    p.add_argument("--unit", default="imu0")
    p.add_argument("--code", type=lambda s: int(s, 0), default=0xC8)
    p.add_argument("--count", type=int, default=5000)
    p.add_argument("--rate", type=float, default=1000.0)
    p.add_argument("--per-read", type=int, default=10)
    p.add_argument("--cache", type=int, default=5000)
    args = p.parse_args()
    try:
        session = open_session(args.zenoh_config, connect=args.connect, listen=args.listen,
                               mode=args.mode, multicast_scouting=False)
    except SessionError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    with session, UnitPublisher(session, args.unit, cache_samples=args.cache) as pub:
        pub.set_info(Info(model_name="3DM-GX3-25", firmware=1127, firmware_text="1.1.27",
                          command=args.code, decimation=1, output_rate_hz=1000.0))
        print("READY", flush=True)
        sys.stdin.readline()
        t0 = time.monotonic()
        for start in range(0, args.count, args.per_read):
            n = min(args.per_read, args.count - start)
            due = t0 + (start + n) / args.rate
            time.sleep(max(0.0, due - time.monotonic()))
            batch = synthetic(args.code, start, n, time.time_ns())
            ticks = np.arange(start, start + n, dtype=np.int64) * (TICKS_PER_SECOND // 1000)
            pub.publish_samples(batch, ticks, ticks * 16_000 + 1_700_000_000_000_000_000)
        print("DONE", flush=True)
        sys.stdin.read()
    return 0


if __name__ == "__main__":
    sys.exit(main())
