"""Cost of `gx3 bridge --ros2`: CPU per sample of the ROS 2 copy (CDR build, attachment,
put) on top of the gx3.v1 publishing, through real Zenoh sessions on loopback with a
subscriber matched. Without --ros2 none of this runs.

    python bench/bench_ros2.py [--samples 20000]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np
from bench_bus import batch_of, per_sample_us

from bridge.bus.session import open_session
from bridge.fleet.loopback import free_port
from bridge.protocol.codec import Batch
from bridge.protocol.convert import euler_to_m
from bridge.ros2.rmw import UnitTopics


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--samples", type=int, default=20_000)
    args = p.parse_args()
    rng = np.random.default_rng(0)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with open_session(listen=[endpoint], multicast_scouting=False) as here, \
            open_session(connect=[endpoint], multicast_scouting=False) as there:
        sub = there.declare_subscriber("0/gx3/**", lambda _: None)
        topics = UnitTopics(here, 0, "gx3", "bench")
        deadline = time.monotonic() + 10
        while not topics.imu.matched and time.monotonic() < deadline:
            time.sleep(0.05)
        print(f"{'record':8s} {'per read':>8s} {'µs CPU / sample':>16s}")
        for code in (0xC2, 0xC8, 0xCC):
            for per_read in (1, 10):
                batch = batch_of(code, per_read, rng)
                if "m" in batch.columns:  # a rotation, as a unit sends
                    m = euler_to_m(rng.normal(size=(per_read, 3))).astype(np.float32)
                    batch = replace(batch, columns={**batch.columns, "m": m})
                stamps = time.time_ns() + np.arange(per_read, dtype=np.int64)

                def publish(b: Batch = batch, t: np.ndarray = stamps) -> None:
                    topics.publish(b, t)
                us = per_sample_us(publish, max(1, args.samples // per_read), per_read)
                print(f"0x{code:02X}     {per_read:8d} {us:16.1f}")
        topics.close()
        sub.undeclare()


if __name__ == "__main__":
    main()
