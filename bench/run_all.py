"""Run every benchmark and print the performance table of docs/guides/performance.md (Markdown).

Each benchmark runs as its own process, one after another, so they do not compete
for the machine; the table gives each one's command and the lines it reported.
``--quick`` runs shorter versions (for trying the runner, not for the documentation).

    python bench/run_all.py > /tmp/bench.md
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent

#: (what, script and arguments, quick arguments)
BENCHMARKS: tuple[tuple[str, list[str], list[str]], ...] = (
    ("codec: framing and decoding", ["bench_codec.py"], ["bench_codec.py"]),
    ("gx3 decode", ["bench_decode.py"], ["bench_decode.py"]),
    ("emulator: 16 units at 1 kHz", ["bench_sim.py", "--units", "16", "--seconds", "10"],
     ["bench_sim.py", "--units", "4", "--seconds", "3"]),
    ("clock model against truth", ["bench_timing.py"], ["bench_timing.py"]),
    ("Zenoh publishing", ["bench_bus.py"], ["bench_bus.py"]),
    ("one bridge at 1 kHz, 0xCC", ["bench_bridge.py", "--seconds", "30"],
     ["bench_bridge.py", "--seconds", "5"]),
    ("the bridge's per-read stages", ["bench_per_read.py", "--cadence-ms", "1"],
     ["bench_per_read.py", "--records", "500", "--cadence-ms", "1"]),
    ("archive writing and export", ["bench_archive.py"], ["bench_archive.py"]),
    ("one flipped byte in an archive", ["bench_damage.py"],
     ["bench_damage.py", "--minutes", "2"]),
    ("gx3 replay", ["bench_replay.py", "--units", "4", "--rate", "100", "--minutes", "10"],
     ["bench_replay.py", "--units", "1", "--rate", "100", "--minutes", "1"]),
    ("recorder: 100 units at 1 kHz",
     ["bench_recorder.py", "--units", "100", "--rate", "1000", "--seconds", "60"],
     ["bench_recorder.py", "--units", "10", "--rate", "1000", "--seconds", "5"]),
    ("Zenoh's splice: an app stalls (payloads checked)",
     ["bench_splice.py", "--mode", "app", "--seconds", "15"],
     ["bench_splice.py", "--mode", "app", "--seconds", "5", "--grace", "4"]),
    ("recorder: its writer stalls 7 s twice at 20 kHz",
     ["bench_splice.py", "--mode", "recorder", "--seconds", "20", "--rate", "20000",
      "--stall", "7", "--every", "100000"],
     ["bench_splice.py", "--mode", "recorder", "--seconds", "5", "--rate", "20000",
      "--stall", "2", "--every", "50000", "--grace", "3"]),
    ("Rerun logging", ["bench_viz.py"], ["bench_viz.py"]),
    ("gx3 rrd: 16 units for 8 h at 100 Hz", ["bench_rrd.py"],
     ["bench_rrd.py", "--units", "2", "--hours", "0.2", "--window-start", "60",
      "--no-viewer"]),
    ("host stalls: a bridge stopped 1, 2, 3 s at 1 kHz",
     ["bench_stall.py", "--rate", "1000", "--stalls", "1,2,3"],
     ["bench_stall.py", "--rate", "500", "--stalls", "1"]),
    ("fleet: 16 bridges at 1 kHz into one recorder",
     ["bench_fleet.py", "--units", "16", "--rate", "1000", "--seconds", "60"],
     ["bench_fleet.py", "--units", "2", "--rate", "100", "--seconds", "5"]),
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="Shorter runs.")
    parser.add_argument("--only", action="append", default=[], metavar="SCRIPT",
                        help="Run only this benchmark script (repeatable).")
    args = parser.parse_args()
    rows = []
    for what, full, quick in BENCHMARKS:
        argv = quick if args.quick else full
        if args.only and argv[0] not in args.only:
            continue
        if not (HERE / argv[0]).exists():
            continue
        command = "python bench/" + " ".join(argv)
        print(f"running {command} …", file=sys.stderr, flush=True)
        started = time.monotonic()
        done = subprocess.run([sys.executable, str(HERE / argv[0]), *argv[1:]],
                              capture_output=True, text=True, check=False)
        took = time.monotonic() - started
        lines = [line for line in done.stdout.splitlines() if line.strip()]
        if done.returncode != 0:
            lines.append(f"FAILED (exit {done.returncode}): "
                         + (done.stderr.strip().splitlines() or ["?"])[-1])
        rows.append((what, command, lines, took))
    print("| benchmark | command | figures |")
    print("|---|---|---|")
    for what, command, lines, took in rows:
        figures = "<br>".join(line.replace("|", "\\|") for line in lines)
        print(f"| {what} ({took:.0f} s) | `{command}` | {figures} |")


if __name__ == "__main__":
    main()
