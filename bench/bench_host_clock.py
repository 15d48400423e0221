"""A disciplined host clock under a live fleet: steps, slews and a leap second.

A `gx3 bridge` and a `gx3 record` process, their realtime clocks moved by a clock script
(GX3_HOST_CLOCK_SCRIPT) as chrony, ntpd and PTP move a host's clock while its raw
monotonic clock runs on; the unit is the emulator on a pty at RATE Hz, 921,600 baud.
Events, each SETTLE_S apart: a step of +STEP ms, a step of -STEP ms, a slew of
+STEP ms at 83,333 ppm (chrony's fastest), a slew of -SLOW ms at 500 ppm (ntpd's), a
leap second (a step of -1 s at the moved clock's midnight).

    python bench/bench_host_clock.py --rate 500

For each event: |time_ns - truth on the moved clock| of the samples taken while it ran
and in the 2 s after it (p50, p99, max, in ms), live (as the bridge published it and the
archive holds it) and exported (`gx3 export`'s re-estimate); the events the archive
names; samples the unit sent that the archive lacks. Then the same over everything
from the first event on.
"""

from __future__ import annotations

import argparse
import json
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
from bridge.device.clock import SCRIPT_ENV, ClockScript
from bridge.export.tables import offline_times, sample_table
from bridge.fleet.loopback import free_port, loopback_config
from bridge.sim.motion import MotionConfig
from bridge.sim.serve import Simulator
from bridge.sim.state import Sampling, Stored
from bridge.sim.unit import UnitConfig

DAY_NS = 86_400 * 10**9
AFTER_NS = 2 * 10**9


def write_script(path: Path, changes: list[dict[str, float]]) -> None:
    part = path.with_suffix(".part")
    part.write_text(json.dumps({"changes": changes}))
    os.replace(part, path)


def stats(error_ns: np.ndarray) -> str:
    if not len(error_ns):
        return "no samples"
    ms = np.abs(error_ns) / 1e6
    return f"{np.median(ms):.3f} / {np.percentile(ms, 99):.3f} / {ms.max():.3f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--rate", type=float, default=500.0)
    parser.add_argument("--step-ms", type=float, default=50.0)
    parser.add_argument("--slow-ms", type=float, default=10.0, help="the 500 ppm slew")
    parser.add_argument("--settle", type=float, default=4.0, help="s between events")
    args = parser.parse_args()
    gx3 = str(Path(sys.executable).parent / "gx3")
    unit = UnitConfig(serial="CLOCK", motion=MotionConfig(seed=3), clock_ppm=40.0,
                      stored=Stored(mode_preset=2, continuous_preset=0xCC, baud=921_600,
                                    sampling=Sampling(decimation=round(1000 / args.rate))))
    step, slow = round(args.step_ms * 1e6), round(args.slow_ms * 1e6)
    settle = round(args.settle * 1e9)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with tempfile.TemporaryDirectory() as tmp, Simulator([unit], "pty") as sim:
        rec_cfg = loopback_config(Path(tmp, "rec.json5"), listen=[endpoint])
        br_cfg = loopback_config(Path(tmp, "bridge.json5"), connect=[endpoint])
        out, script = Path(tmp, "clock.mcap"), Path(tmp, "clock.json")
        start = time.time_ns()
        first = start + 10 * 10**9
        plan = [("step +", {"at_ns": first, "step_ns": step}),
                ("step -", {"at_ns": first + settle, "step_ns": -step}),
                ("slew 83,333 ppm", {"at_ns": first + 2 * settle, "slew_ns": step,
                                     "ppm": 83_333.0}),
                ("slew 500 ppm", {"at_ns": first + 3 * settle, "slew_ns": -slow, "ppm": 500.0})]
        slow_ns = round(slow / 500.0 * 1e6)
        leap_at = first + 4 * settle + slow_ns
        moved_by = step - slow  # where the moved clock stands after the slews
        midnight = ((leap_at + moved_by) // DAY_NS + 1) * DAY_NS
        base = {"at_ns": 0, "step_ns": midnight - (leap_at + moved_by)}
        plan.append(("leap second", {"at_ns": leap_at, "step_ns": -1_000_000_000}))
        changes = [base] + [c for _, c in plan]
        write_script(script, changes)
        env = {**os.environ, SCRIPT_ENV: str(script)}
        rec = subprocess.Popen([gx3, "record", "-o", str(out), "--zenoh-config", str(rec_cfg),
                                "--quiet", "--history", "100000"], env=env,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        bridge = subprocess.Popen([gx3, "bridge", "--port", sim.endpoints[0], "--baud",
                                   "921600", "--unit", "a", "--zenoh-config", str(br_cfg)],
                                  env=env, stdout=subprocess.DEVNULL,
                                  stderr=subprocess.DEVNULL)
        end = leap_at + settle
        while time.time_ns() < end:
            time.sleep(0.5)
            print(f"\r{(end - time.time_ns()) / 1e9:5.1f} s to go", end="", file=sys.stderr)
        print(file=sys.stderr)
        for proc in (bridge, rec):
            proc.send_signal(signal.SIGINT)
            proc.wait(timeout=60)
        truth = sim.units[0].truth.arrays()
        archive = read_archive(out)
        table = sample_table(archive, ["a"], re_estimate=offline_times(archive))
        events = [e for _, e in archive.events(["a"])]
        moved = ClockScript(script)
    order = np.argsort(table["ticks"], kind="stable")
    table = {k: v[order] for k, v in table.items()}
    timer = table["timer"]
    upto = truth["timer"][: np.argmax(truth["timer"] == timer[-1]) + 1]
    at = np.searchsorted(upto, timer)
    begun = int(np.flatnonzero(upto == timer[0])[0])
    value = truth["value_ns"][at]
    true_ns = value + np.array([moved.shift(int(v)) for v in value])
    lost = len(upto) - begun - len(timer)
    print(f"{args.rate:g} Hz 0xCC; steps of {args.step_ms:g} ms; |time_ns - truth| ms "
          "p50 / p99 / max, live | exported:")
    for name, change in plan:
        length = round(abs(change.get("slew_ns", 0)) / change.get("ppm", 1) * 1e6)
        during = (value >= change["at_ns"]) & (value < change["at_ns"] + length + AFTER_NS)
        print(f"  {name:16s} {stats(table['live_time_ns'][during] - true_ns[during]):24s} | "
              f"{stats(table['time_ns'][during] - true_ns[during])}")
    since = value >= first
    print(f"  {'from the first':16s} {stats(table['live_time_ns'][since] - true_ns[since]):24s}"
          f" | {stats(table['time_ns'][since] - true_ns[since])}")
    named = [(Event.Kind.Name(e.kind), round(e.clock_change_ns / 1e6, 3)) for e in events
             if e.kind in (Event.HOST_CLOCK_STEP, Event.HOST_CLOCK_SLEW)]
    print(f"events: {named}")
    print(f"samples the unit sent that the archive lacks: {lost}")


if __name__ == "__main__":
    main()
