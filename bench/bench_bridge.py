"""One `gx3 bridge` process at 1,000 Hz with the largest record (0xCC, 79 B) at 921,600 baud.

Measures the bridge's CPU (its own process: user + system time per second of wall
time) and the latency from the bridge's receive stamp of the read that completed a
record (``rx_ns``) to a subscriber callback in another process (this one), both on
this machine's clock; and that every record the emulator sent was delivered.

    python bench/bench_bridge.py --seconds 30
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

from bridge.bus.codec import parse
from bridge.protocol.table import Flag
from bridge.sim.motion import MotionConfig
from bridge.sim.serve import Simulator
from bridge.sim.state import Sampling, Stored
from bridge.sim.unit import UnitConfig

CLK_TCK = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--code", default="0xCC")
    args = parser.parse_args()
    code = int(args.code, 0)
    gx3 = shutil.which("gx3", path=str(Path(sys.executable).parent)) or "gx3"
    config = UnitConfig(serial="BENCH", motion=MotionConfig(seed=1), stored=Stored(
        mode_preset=2, continuous_preset=code, baud=921_600,
        sampling=Sampling(decimation=1, flags=int(Flag.CONING_SCULLING))))
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        endpoint = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    scouting = {"multicast": {"enabled": False}, "gossip": {"enabled": False}}
    with tempfile.TemporaryDirectory() as tmp, Simulator([config], "pty") as sim:
        cfg = Path(tmp, "bridge.json5")
        cfg.write_text(json.dumps({"mode": "peer", "listen": {"endpoints": [endpoint]},
                                   "scouting": scouting}))
        latencies: list[int] = []
        ticks: list[int] = []
        lock = threading.Lock()

        def on_sample(sample: zenoh.Sample) -> None:
            now = time.time_ns()
            msg = parse(sample.payload.to_bytes())
            with lock:
                latencies.append(now - msg.rx_ns)
                ticks.append(msg.ticks)

        client = zenoh.Config.from_json5(json.dumps({
            "mode": "peer", "connect": {"endpoints": [endpoint]}, "scouting": scouting}))
        bridge = subprocess.Popen([gx3, "bridge", "--port", sim.endpoints[0], "--baud",
                                   "921600", "--unit", "bench", "--zenoh-config", str(cfg),
                                   "--quiet"])
        try:
            with zenoh.open(client) as session:
                sub = session.declare_subscriber("gx3/bench/imu", on_sample)
                while True:
                    with lock:
                        if len(ticks) > 2000:
                            break
                    time.sleep(0.1)
                with lock:
                    latencies.clear()
                    ticks.clear()
                cpu0, wall0 = cpu_seconds(bridge.pid), time.monotonic()
                time.sleep(args.seconds)
                cpu1, wall1 = cpu_seconds(bridge.pid), time.monotonic()
                time.sleep(0.5)
                sub.undeclare()
        finally:
            bridge.send_signal(signal.SIGINT)
            bridge.wait(timeout=30)
        lat = np.array(latencies) / 1e6
        t = np.array(ticks)
        steps = np.diff(t)
        missing = int(np.sum(np.round(steps / 62.5)) - len(steps))
        print(f"0x{code:02X} at 1,000 Hz, {args.seconds:g} s: {len(t)} samples received, "
              f"{missing} missing from the tick sequence")
        print(f"bridge CPU: {100 * (cpu1 - cpu0) / (wall1 - wall0):.1f} % of one core")
        print(f"rx -> subscriber callback: p50 {np.percentile(lat, 50):.3f} ms, "
              f"p99 {np.percentile(lat, 99):.3f} ms, max {lat.max():.3f} ms")


if __name__ == "__main__":
    main()
