"""A fleet on this machine: UNITS emulated units at RATE Hz, one `gx3 bridge` process each,
into one `gx3 record` process, for SECONDS.

Prints one table:

- samples the units produced against those archived (the units also send before their
  bridge is up and after it stops), and the holes: samples missing inside each unit's
  recorded span (its first to its last archived sample), with where they went (bytes
  the emulator could not write because a bridge was not reading; GAP events);
- latency "receive -> recorder": from a record's ``rx_ns`` (when the bridge's read that
  completed the record returned) to the moment the recorder's receiving thread took the
  sample off Zenoh (the archive's receive time for the message), both on this host's
  clock; p50, p99 and max over every sample archived in the measured window. A bridge
  with ``--max-latency-ms`` above 1 holds a read's records up to MS - 1 ms before it
  puts them, which counts here;
- CPU (user + system time per second of wall time, % of one core) of each bridge, of
  the recorder, of the emulator (it runs in this process; the rest of this process only
  sleeps), and of the whole machine: the rest is other processes (other jobs, kernel
  threads) and time in no process that lived through the window (interrupts: loopback
  TCP, ptys; processes that started or ended meanwhile).

    python bench/bench_fleet.py --units 16 --rate 1000 --seconds 60 [--max-latency-ms 5]
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np
from procstat import CLK_TCK, cpu_seconds, thread_cpu_seconds

from bridge.fleet.loopback import free_port, loopback_config
from bridge.protocol.table import Flag
from bridge.sim.motion import MotionConfig
from bridge.sim.serve import Simulator, unit_configs
from bridge.sim.state import Sampling, Stored
from bridge.sim.unit import UnitConfig

_BRING_UP_S = 20.0  # every bridge's bring-up, with retries on a busy machine


def every_process() -> dict[int, float]:
    """CPU seconds so far of every process on the machine, by pid."""
    out = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            out[int(stat.parent.name)] = cpu_seconds(int(stat.parent.name))
        except (OSError, ValueError, IndexError):  # ended meanwhile
            continue
    return out


def threads(processes: list[dict[str, float]]) -> str:
    """The mean % of a core of each kind of thread in ``processes``: Python's ("python",
    or the program's name), Zenoh's by role ("tx", "rx", "acc", ...)."""
    kinds: dict[str, float] = {}
    for process in processes:
        for name, use in process.items():
            kind = "python" if name in ("python", "python3", "gx3") else name.rstrip("-0123456789")
            kinds[kind] = kinds.get(kind, 0.0) + use / len(processes)
    return ", ".join(f"{kind} {use:.1f}" for kind, use in
                     sorted(kinds.items(), key=lambda item: -item[1]) if use >= 0.05)


def machine_busy() -> tuple[float, int]:
    """(CPU seconds all cores spent not idle, number of cores), from /proc/stat."""
    lines = Path("/proc/stat").read_text().splitlines()
    fields = [int(v) for v in lines[0].split()[1:]]
    idle = fields[3] + fields[4]  # idle, iowait
    cores = sum(1 for line in lines if line.startswith("cpu") and line[3].isdigit())
    return (sum(fields[:8]) - idle) / CLK_TCK, cores


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=16)
    parser.add_argument("--rate", type=float, default=1000.0)
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--code", default="0xC2")
    parser.add_argument("--max-latency-ms", type=float, default=None,
                        help="passed to every gx3 bridge (its default when not given)")
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
    budget = [] if args.max_latency_ms is None else ["--max-latency-ms",
                                                      f"{args.max_latency_ms:g}"]
    with tempfile.TemporaryDirectory() as tmp, \
            Simulator(unit_configs(args.units, base), "pty") as sim:
        rec_cfg = loopback_config(Path(tmp, "rec.json5"), listen=[endpoint])
        br_cfg = loopback_config(Path(tmp, "bridge.json5"), connect=[endpoint])
        out = Path(tmp, "fleet.mcap")
        recorder = subprocess.Popen([gx3, "record", "-o", str(out), "--zenoh-config",
                                     str(rec_cfg), "--quiet", "--history", "100000"])
        started = [recorder]
        try:
            time.sleep(2.0)
            bridges = [subprocess.Popen([gx3, "bridge", "--port", port, "--baud", "921600",
                                         "--unit", f"u{i:02d}", "--zenoh-config", str(br_cfg),
                                         "--quiet", *budget])
                       for i, port in enumerate(sim.endpoints)]
            started += bridges
            time.sleep(_BRING_UP_S)
            procs = [*(p.pid for p in bridges), recorder.pid, os.getpid()]
            t0, ns0 = time.monotonic(), time.time_ns()
            cpu0, (busy0, cores) = [cpu_seconds(pid) for pid in procs], machine_busy()
            lost0, everyone0 = [slot.lost for slot in sim.slots], every_process()
            threads0 = [thread_cpu_seconds(pid) for pid in procs[:-1]]
            time.sleep(args.seconds)
            cpu1, (busy1, _) = [cpu_seconds(pid) for pid in procs], machine_busy()
            lost1, everyone1 = [slot.lost for slot in sim.slots], every_process()
            threads1 = [thread_cpu_seconds(pid) for pid in procs[:-1]]
            wall, ns1 = time.monotonic() - t0, time.time_ns()
            for b in bridges:
                b.send_signal(signal.SIGINT)
            for b in bridges:
                b.wait(timeout=60)
            time.sleep(3.0)
            recorder.send_signal(signal.SIGINT)
            recorder.wait(timeout=120)
        finally:  # a bench that fails leaves no bridge holding ptys another program gets next
            for proc in started:
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
        produced = sum(len(u.truth) for u in sim.units)
        unwritten = (sum(lost1) - sum(lost0), sum(slot.lost for slot in sim.slots))
        from bridge.archive.walk import read_archive
        from bridge.bus.gx3_pb2 import Event

        archive = read_archive(out)
        blocks = archive.samples()
        events = [e for _, e in archive.events()]
    archived = sum(len(b) for b in blocks)
    period = 62.5 * decimation
    holes = [int(np.round(np.diff(np.sort(b.columns["ticks"])) / period).sum()) - (len(b) - 1)
             if len(b) > 1 else 0 for b in blocks]
    window = [(b.receive_ns >= ns0) & (b.receive_ns < ns1) for b in blocks]
    # a unit whose bridge came up late or stalled shows as fewer samples in the window
    whole = sum(int(w.sum()) >= 0.99 * args.rate * (ns1 - ns0) / 1e9 for w in window)
    latency = np.concatenate([(b.receive_ns - b.columns["rx_ns"])[w] / 1e6
                              for b, w in zip(blocks, window, strict=True)])
    use = [100 * (c1 - c0) / wall for c0, c1 in zip(cpu0, cpu1, strict=True)]
    bridge_use, rec_use, sim_use = use[:-2], use[-2], use[-1]
    machine = 100 * (busy1 - busy0) / wall
    by_thread = [{name: 100 * (cpu - t0.get(name, 0.0)) / wall for name, cpu in t1.items()}
                 for t0, t1 in zip(threads0, threads1, strict=True)]
    others = 100 * sum(everyone1[pid] - cpu for pid, cpu in everyone0.items()
                       if pid in everyone1 and pid not in procs) / wall
    rows = [
        ("samples produced / archived",
         f"{produced:,} / {archived:,} (produced counts bring-up and shutdown)"),
        ("holes inside the units' spans",
         f"{sum(holes):,} in all, {max(holes, default=0):,} at most in one of "
         f"{len(blocks)} units"),
        ("where samples went missing",
         f"bytes the emulator could not write (pty full: a bridge not reading): "
         f"{unwritten[0]:,} in the window, {unwritten[1]:,} in all; events archived: "
         + (", ".join(f"{Event.Kind.Name(kind)} x{n}" for kind, n in
                      sorted(Counter(e.kind for e in events).items())) or "none")
         + "".join(f"; {e.unit} GAP of {e.count} at {(e.time_ns - ns0) / 1e9:+.1f} s from "
                   "the window's start" for e in events if e.kind == Event.GAP)),
        ("receive -> recorder (ms)",
         f"p50 {np.percentile(latency, 50):.2f}, p99 {np.percentile(latency, 99):.2f}, "
         f"max {latency.max():.2f} ({len(latency):,} samples in the window; {whole} of "
         f"{args.units} units archived through all of it)"),
        ("CPU: each bridge (% of a core)",
         f"mean {np.mean(bridge_use):.1f}, min {min(bridge_use):.1f}, "
         f"max {max(bridge_use):.1f}; all {len(bridges)}: {sum(bridge_use):.0f}"),
        ("CPU: a bridge's threads", threads(by_thread[:-1])),
        ("CPU: recorder", f"{rec_use:.1f} ({threads(by_thread[-1:])})"),
        ("CPU: emulator", f"{sim_use:.1f}"),
        ("CPU: whole machine",
         f"{machine:.0f} of {100 * cores}: {others:.0f} in other processes (other jobs, "
         f"kernel threads), {machine - sum(use) - others:.0f} in no process that lived "
         "through the window (interrupts, short-lived processes)"),
    ]
    budget_note = "" if args.max_latency_ms is None else \
        f", bridges at --max-latency-ms {args.max_latency_ms:g}"
    print(f"{args.units} units x {args.rate:g} Hz (0x{code:02X}) for {args.seconds:g} s"
          f"{budget_note}")
    width = max(len(name) for name, _ in rows)
    print(f"| {'what':<{width}} | figures |\n|{'-' * (width + 2)}|---|")
    for name, figures in rows:
        print(f"| {name:<{width}} | {figures} |")


if __name__ == "__main__":
    main()
