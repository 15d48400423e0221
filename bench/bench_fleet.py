"""A fleet on this machine: UNITS emulated units at RATE Hz, one `gx3 bridge` process each,
into one `gx3 record` process, for SECONDS.

Reports samples delivered into the archive against samples the units produced, the CPU
of each bridge and of the recorder (user + system time per second of wall time), and
the latency from each record's receive stamp (``rx_ns``, when its last byte was read)
to its arrival at the recorder (the archive's receive time), both on this clock.

    python bench/bench_fleet.py --units 16 --rate 1000 --seconds 60
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from procstat import cpu_seconds

from bridge.loopback import free_port
from bridge.protocol.table import Flag
from bridge.sim.motion import MotionConfig
from bridge.sim.serve import Simulator, unit_configs
from bridge.sim.state import Sampling, Stored
from bridge.sim.unit import UnitConfig


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--units", type=int, default=16)
    parser.add_argument("--rate", type=float, default=1000.0)
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--code", default="0xC2")
    args = parser.parse_args()
    code = int(args.code, 0)
    gx3 = str(Path(sys.executable).parent / "gx3")
    decimation = round(1000 / args.rate)
    flags = int(Flag.CONING_SCULLING) if decimation == 1 else int(Flag.ORIENTATION
                                                                  | Flag.CONING_SCULLING)
    base = UnitConfig(serial="FLEET", motion=MotionConfig(seed=9), stored=Stored(
        mode_preset=2, continuous_preset=code, baud=921_600,
        sampling=Sampling(decimation=decimation, flags=flags)))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    scouting = {"multicast": {"enabled": False}, "gossip": {"enabled": False}}
    with tempfile.TemporaryDirectory() as tmp, \
            Simulator(unit_configs(args.units, base), "pty") as sim:
        rec_cfg, br_cfg = Path(tmp, "rec.json5"), Path(tmp, "bridge.json5")
        rec_cfg.write_text(json.dumps({"mode": "peer", "listen": {"endpoints": [endpoint]},
                                       "scouting": scouting}))
        br_cfg.write_text(json.dumps({"mode": "peer", "connect": {"endpoints": [endpoint]},
                                      "scouting": scouting}))
        out = Path(tmp, "fleet.mcap")
        recorder = subprocess.Popen([gx3, "record", "-o", str(out), "--zenoh-config",
                                     str(rec_cfg), "--quiet", "--history", "100000"])
        time.sleep(2.0)
        bridges = [subprocess.Popen([gx3, "bridge", "--port", port, "--baud", "921600",
                                     "--unit", f"u{i:02d}", "--zenoh-config", str(br_cfg),
                                     "--quiet"])
                   for i, port in enumerate(sim.endpoints)]
        time.sleep(10.0)  # bring-up of every bridge
        t0 = time.monotonic()
        cpu0 = [cpu_seconds(p.pid) for p in (*bridges, recorder)]
        time.sleep(args.seconds)
        cpu1 = [cpu_seconds(p.pid) for p in (*bridges, recorder)]
        wall = time.monotonic() - t0
        for b in bridges:
            b.send_signal(signal.SIGINT)
        for b in bridges:
            b.wait(timeout=60)
        time.sleep(3.0)
        recorder.send_signal(signal.SIGINT)
        recorder.wait(timeout=120)
        produced = sum(len(u.truth) for u in sim.units)
        from bridge.recorder.read import read_archive

        blocks = read_archive(out).samples()
    archived = sum(len(b) for b in blocks)
    period = 62.5 * decimation
    holes = sum(int(np.round(np.diff(np.sort(b.columns["ticks"])) / period).sum())
                - (len(b) - 1) for b in blocks if len(b) > 1)
    latency = np.concatenate([(b.receive_ns - b.columns["rx_ns"]) / 1e6 for b in blocks])
    use = [(c1 - c0) / wall for c0, c1 in zip(cpu0, cpu1, strict=True)]
    print(f"{args.units} units x {args.rate:g} Hz (0x{code:02X}) for {args.seconds:g} s")
    print(f"archived {archived:,} samples ({produced:,} produced, counting bring-up and "
          f"shutdown); missing inside the units' recorded spans: {holes:,}")
    print(f"bridge CPU: mean {100 * np.mean(use[:-1]):.1f} %, max {100 * max(use[:-1]):.1f} % "
          f"of one core each; recorder {100 * use[-1]:.0f} %")
    print(f"latency rx -> recorder: p50 {np.percentile(latency, 50):.2f} ms, "
          f"p99 {np.percentile(latency, 99):.2f} ms")


if __name__ == "__main__":
    main()
