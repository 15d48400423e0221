"""One `gx3 bridge` process at 1,000 Hz with the largest record (0xCC, 79 B) at 921,600 baud.

Measures the bridge's CPU (its own process: user + system time per second of wall
time) and the latency from the bridge's receive stamp of the read that completed a
record (``rx_ns``) to a subscriber callback in another process (this one), both on
this machine's clock; and that every record the emulator sent was delivered.

    python bench/bench_bridge.py --seconds 30
    python bench/bench_bridge.py --seconds 30 --floor

``--floor`` runs, in place of the bridge, the least a process can do with the same
stream: wait for each read with ``select``, read it, and put one ImuSample-sized
payload per record through the same Zenoh publisher; no framing, timing or encoding.
The bridge's CPU above that figure is what parsing and timing in Python cost.
"""

from __future__ import annotations

import argparse
import json
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import zenoh
from procstat import cpu_seconds, thread_cpu_seconds

from bridge.bus.codec import parse
from bridge.loopback import free_port
from bridge.protocol.table import Flag
from bridge.sim.motion import MotionConfig
from bridge.sim.serve import Simulator
from bridge.sim.state import Sampling, Stored
from bridge.sim.unit import UnitConfig


def floor(port: str, config: str, code: int) -> None:
    """The bare loop of ``--floor``, as its own process, until SIGINT. Each payload is
    an ImuSample's size and starts with the receive time (int64 LE ns)."""
    import os
    import select

    from bridge.bus.publish import UnitPublisher
    from bridge.bus.session import open_session
    from bridge.device.port import Port
    from bridge.protocol.table import REPLIES

    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    size = REPLIES[code].length
    padding = bytes(127)
    with open_session(config) as session:
        pub = UnitPublisher(session, "bench", cache_samples=1000)
        link = Port.open(port, 921_600)
        fd = link.raw.fileno()
        link.write(bytes([0xC4, 0xC1, 0x29, code]))
        held = 0
        put = pub._imu.put
        while not stop.is_set():
            if select.select([fd], [], [], 0.05)[0]:
                held += len(os.read(fd, 1 << 16))
                rx = time.time_ns().to_bytes(8, "little")
                for _ in range(held // size):
                    put(rx + padding)
                held %= size
        link.write(bytes([0xFA, 0x75, 0xB4]))
        link.close()
        pub.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--code", default="0xCC")
    parser.add_argument("--floor", action="store_true",
                        help="run the bare select/read/put loop in place of the bridge")
    parser.add_argument("--floor-child", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    code = int(args.code, 0)
    if args.floor_child:
        port, zenoh_config = args.floor_child
        floor(port, zenoh_config, code)
        return
    gx3 = shutil.which("gx3", path=str(Path(sys.executable).parent)) or "gx3"
    config = UnitConfig(serial="BENCH", motion=MotionConfig(seed=1), stored=Stored(
        mode_preset=2, continuous_preset=code, baud=921_600,
        sampling=Sampling(decimation=1, flags=int(Flag.CONING_SCULLING))))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
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
            payload = sample.payload.to_bytes()
            if args.floor:
                rx, tick = int.from_bytes(payload[:8], "little"), len(ticks) * 62
            else:
                msg = parse(payload)
                rx, tick = msg.rx_ns, msg.ticks
            with lock:
                latencies.append(now - rx)
                ticks.append(tick)

        client = zenoh.Config.from_json5(json.dumps({
            "mode": "peer", "connect": {"endpoints": [endpoint]}, "scouting": scouting}))
        command = [gx3, "bridge", "--port", sim.endpoints[0], "--baud", "921600", "--unit",
                   "bench", "--zenoh-config", str(cfg), "--quiet"]
        if args.floor:
            command = [sys.executable, __file__, "--code", args.code, "--floor-child",
                       sim.endpoints[0], str(cfg)]
        bridge = subprocess.Popen(command)
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
                threads0 = thread_cpu_seconds(bridge.pid)
                time.sleep(args.seconds)
                cpu1, wall1 = cpu_seconds(bridge.pid), time.monotonic()
                threads1 = thread_cpu_seconds(bridge.pid)
                time.sleep(0.5)
                sub.undeclare()
        finally:
            bridge.send_signal(signal.SIGINT)
            bridge.wait(timeout=30)
        lat = np.array(latencies) / 1e6
        t = np.array(ticks)
        steps = np.diff(t)
        missing = int(np.sum(np.round(steps / 62.5)) - len(steps))
        what = "bare select/read/put loop" if args.floor else "bridge"
        print(f"0x{code:02X} at 1,000 Hz, {args.seconds:g} s: {len(t)} samples received"
              + ("" if args.floor else f", {missing} missing from the tick sequence"))
        spent = {name: t - threads0.get(name, 0.0) for name, t in threads1.items()}
        print(f"{what} CPU: {100 * (cpu1 - cpu0) / (wall1 - wall0):.1f} % of one core; by thread: "
              + ", ".join(f"{name} {100 * t / (wall1 - wall0):.1f} %"
                          for name, t in sorted(spent.items(), key=lambda kv: -kv[1]) if t > 0))
        print(f"rx -> subscriber callback: p50 {np.percentile(lat, 50):.3f} ms, "
              f"p99 {np.percentile(lat, 99):.3f} ms, max {lat.max():.3f} ms")


if __name__ == "__main__":
    main()
