"""Cost of publishing samples: encode (bulk NumPy vs protobuf objects) and encode + put.

A unit at 1 kHz is 1,000 samples/s; the whole bridge must stay under 5 % of one core,
so publishing should cost well under 50 µs per sample. Publishes through a real
UnitPublisher to a subscriber in another process on loopback and reports CPU time of
this process per sample.

    python bench/bench_bus.py [--samples 100000] [--per-read 10]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from collections.abc import Callable

import numpy as np

from bridge.bus.codec import encode_batch, record_quantities
from bridge.bus.gx3_pb2 import ImuSample
from bridge.bus.publish import UnitPublisher
from bridge.bus.session import open_session
from bridge.fleet.loopback import free_port
from bridge.protocol.codec import Batch
from bridge.protocol.table import REPLIES

SUBSCRIBER = """
import sys, threading, zenoh
n = int(sys.argv[2]); c = zenoh.Config()
c.insert_json5("connect/endpoints", '["%s"]' % sys.argv[1])
c.insert_json5("scouting/multicast/enabled", "false")
got = [0]; done = threading.Event()
def on(s):
    got[0] += 1
    if got[0] >= n: done.set()
with zenoh.open(c) as s:
    sub = s.declare_subscriber("gx3/bench/imu", on)
    print("READY", flush=True)
    done.wait(600); print(got[0], flush=True); sub.undeclare()
"""


def batch_of(code: int, n: int, rng: np.random.Generator) -> Batch:
    columns = {f.name: rng.normal(size=(n, *f.shape)).astype(np.float32) for f in
               REPLIES[code].fields if f.kind == "f32"}
    columns["timer"] = np.arange(n, dtype=np.uint32)
    return Batch(code, columns, np.arange(n), np.zeros(n, np.int64), False)


def per_sample_us(fn: Callable[[], object], batches: int, per_read: int) -> float:
    t = time.process_time()
    for _ in range(batches):
        fn()
    return (time.process_time() - t) / (batches * per_read) * 1e6


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--samples", type=int, default=100_000)
    p.add_argument("--per-read", type=int, default=10)
    args = p.parse_args()
    rng = np.random.default_rng(0)
    k = args.per_read
    times = np.arange(k, dtype=np.int64)
    print(f"{'record':8s} {'bytes':>5s} {'bulk encode':>12s} {'protobuf encode':>16s} "
          f"{'encode+put':>11s} {'CPU at 1 kHz':>12s}")
    for code in (0xC2, 0xC8, 0xCC):
        batch = batch_of(code, k, rng)
        reps = max(1, 20_000 // k)

        def bulk_encode(b: Batch = batch) -> None:
            encode_batch("bench", b, times, times, times)
        bulk = per_sample_us(bulk_encode, reps, k)

        def objects(b: Batch = batch) -> None:
            for i in range(len(b)):
                ImuSample(unit="bench", command=b.code, timer=int(b["timer"][i]), ticks=i,
                          time_ns=i, rx_ns=i, **{q: b[q][i].reshape(-1).tolist()
                                                  for q in record_quantities(b.code)}
                          ).SerializeToString()
        proto = per_sample_us(objects, reps, k)

        endpoint = f"tcp/127.0.0.1:{free_port()}"
        n = args.samples // k * k
        sub = subprocess.Popen([sys.executable, "-c", SUBSCRIBER, endpoint, str(n)],
                               stdout=subprocess.PIPE, text=True)
        assert sub.stdout is not None
        with open_session(listen=[endpoint], multicast_scouting=False) as session, \
                UnitPublisher(session, "bench") as pub:
            assert sub.stdout.readline().strip() == "READY"
            time.sleep(1.0)  # routes settle
            t = time.process_time()
            for _ in range(n // k):
                pub.publish_samples(batch, times, times, times)
            put = (time.process_time() - t) / n * 1e6
            received = int(sub.stdout.readline())
        sub.wait()
        size = len(encode_batch("bench", batch, times, times, times)[0])
        print(f"0x{code:02X}     {size:5d} {bulk:9.2f} µs {proto:13.2f} µs {put:8.2f} µs "
              f"{put / 10:10.2f} %   ({received}/{n} received)")


if __name__ == "__main__":
    main()
