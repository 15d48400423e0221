"""Host stalls: a `gx3 bridge` process stopped (SIGSTOP) for each of STALLS seconds, then
let go (SIGCONT), as a suspended or starved host does, with a `gx3 record` process
archiving what it publishes. The unit is the emulator on a pty at RATE Hz, 921,600 baud.

    python bench/bench_stall.py --rate 1000 --code 0xCC --stalls 1,2,3

For each stall: the records the unit sent that never reached the archive (by the
emulator's truth), the counts of the GAP events the bridge reported for them and the
RESET events; then over the whole run, |ticks - truth| and the worst |time_ns - truth|
in the 2 s after each stall, live (as published) and exported (`gx3 export`'s estimate
over the whole recording).
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bridge.archive.walk import read_archive
from bridge.bus.gx3_pb2 import Event
from bridge.export.tables import offline_times, sample_table
from bridge.fleet.loopback import free_port, loopback_config
from bridge.sim.motion import MotionConfig
from bridge.sim.serve import Simulator
from bridge.sim.state import Sampling, Stored
from bridge.sim.unit import UnitConfig

SETTLE_S = 3.0  # streaming before the first stall and between stalls


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--rate", type=float, default=1000.0)
    parser.add_argument("--code", default="0xCC")
    parser.add_argument("--stalls", default="1,2,3", help="seconds, comma-separated")
    args = parser.parse_args()
    stalls = [float(s) for s in args.stalls.split(",")]
    gx3 = str(Path(sys.executable).parent / "gx3")
    unit = UnitConfig(serial="STALL", motion=MotionConfig(seed=3), clock_ppm=40.0,
                      stored=Stored(mode_preset=2, continuous_preset=int(args.code, 0),
                                    baud=921_600,
                                    sampling=Sampling(decimation=round(1000 / args.rate))))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with tempfile.TemporaryDirectory() as tmp, Simulator([unit], "pty") as sim:
        rec_cfg = loopback_config(Path(tmp, "rec.json5"), listen=[endpoint])
        br_cfg = loopback_config(Path(tmp, "bridge.json5"), connect=[endpoint])
        out = Path(tmp, "stall.mcap")
        recorder = subprocess.Popen([gx3, "record", "-o", str(out), "--zenoh-config",
                                     str(rec_cfg), "--quiet", "--history", "100000"])
        time.sleep(2.0)
        bridge = subprocess.Popen([gx3, "bridge", "--port", sim.endpoints[0], "--baud",
                                   "921600", "--unit", "a", "--zenoh-config", str(br_cfg),
                                   "--quiet"])
        time.sleep(5.0)  # bring-up
        woke: list[int] = []
        for seconds in stalls:
            time.sleep(SETTLE_S)
            os.kill(bridge.pid, signal.SIGSTOP)
            time.sleep(seconds)
            os.kill(bridge.pid, signal.SIGCONT)
            woke.append(time.time_ns())
        time.sleep(SETTLE_S)
        bridge.send_signal(signal.SIGINT)
        bridge.wait(timeout=60)
        truth = sim.units[0].truth.arrays()
        time.sleep(2.0)
        recorder.send_signal(signal.SIGINT)
        recorder.wait(timeout=60)
        archive = read_archive(out)
        table = sample_table(archive, ["a"], re_estimate=offline_times(archive))
        events = [e for _, e in archive.events(["a"])]
    order = np.argsort(table["ticks"], kind="stable")
    ticks, timer = table["ticks"][order], table["timer"][order]
    at = np.searchsorted(truth["timer"], timer)  # the timer only rises within this run
    assert (truth["timer"][at] == timer).all(), "an archived record the unit never sent"
    missing = np.diff(at) - 1
    gaps = {e.ticks: e.count for e in events if e.kind == Event.GAP}
    resets = sum(e.kind == Event.RESET for e in events)
    value_ns = truth["value_ns"][at]
    device = truth["device_s"][at] * 62_500
    tick_error = np.abs((ticks - ticks[0]) - (device - device[0])).max()
    print(f"0x{int(args.code, 0):02X} at {args.rate:g} Hz, 921,600 baud; {len(ticks):,} "
          f"samples archived, {int(missing.sum()):,} missing, {len(gaps)} GAP events "
          f"counting {sum(gaps.values()):,}, {resets} RESET events, |ticks - truth| max "
          f"{tick_error:g}")
    print(f"{'stall s':>8} {'lost':>6} {'GAP counts':>16} {'live ms':>8} {'export ms':>9}")
    for seconds, wake in zip(stalls, woke, strict=True):
        # the stall's records: the holes whose next record came within 1 s of waking
        near = (table["rx_ns"][order][1:] >= wake - 1e9) & (table["rx_ns"][order][1:] < wake + 1e9)
        holes = np.flatnonzero((missing > 0) & near)
        counts = [gaps.get(int(ticks[h + 1]), 0) for h in holes]
        after = (value_ns >= wake) & (value_ns < wake + 2e9)
        live = np.abs(table["live_time_ns"][order] - value_ns)[after].max() / 1e6
        exported = np.abs(table["time_ns"][order] - value_ns)[after].max() / 1e6
        print(f"{seconds:8g} {int(missing[holes].sum()):6d} "
              f"{'+'.join(map(str, counts)) or '0':>16} {live:8.3f} {exported:9.3f}")


if __name__ == "__main__":
    main()
