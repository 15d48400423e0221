"""Benchmark: one emulator process serving N units in continuous mode at 1 kHz.

Run by hand: `python bench/bench_sim.py [--units 16] [--seconds 10] [--code 0xC2]
[--noise]`. Starts `gx3 sim --pty` in its own process (as a user would; --noise gives
every unit sensor noise and bias random walks, which its filter chain then averages),
opens every pty at
921,600 baud, reads them all from one thread, and reports per unit the record
rate achieved, records lost, and the pacing jitter: the spread of each record's
arrival time (the time of the read that completed it) around a straight-line fit
of arrival time against the unit's own timer. Reads are only timestamped while
measuring and framed afterwards, so the reader's own work does not count as jitter.
"""

from __future__ import annotations

import argparse
import os
import selectors
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import serial

from bridge.protocol.framer import Framer
from bridge.protocol.table import REPLIES, TICKS_PER_SECOND


def _cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=16)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--code", default="0xC2", help="continuous record type")
    parser.add_argument("--noise", action="store_true",
                        help="give the units noise densities and random walks")
    args = parser.parse_args()
    noise = ["--accel-noise-density", "0.002", "--accel-random-walk", "0.0002",
             "--gyro-noise-density", "0.0001", "--gyro-random-walk", "0.00001"]
    code = int(args.code, 0)
    gx3 = shutil.which("gx3") or str(Path(sys.executable).with_name("gx3"))
    proc = subprocess.Popen(
        [gx3, "sim", "--pty", "--units", str(args.units), "--continuous-preset", args.code,
         "--mode-preset", "2", "--decimation", "1", "--flags", "0", "--baud", "921600",
         *(noise if args.noise else [])],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    ports: list[serial.Serial] = []
    try:
        assert proc.stdout is not None
        paths = [proc.stdout.readline().strip() for _ in range(args.units)]
        ports = [serial.Serial(p, 921_600, timeout=0) for p in paths]
        time.sleep(0.5)
        for port in ports:
            port.reset_input_buffer()
        reads: list[list[tuple[float, bytes]]] = [[] for _ in ports]
        sel = selectors.DefaultSelector()
        for i, port in enumerate(ports):
            sel.register(port.fileno(), selectors.EVENT_READ, i)
        cpu0, t0 = _cpu_seconds(proc.pid), time.monotonic()
        while time.monotonic() - t0 < args.seconds:
            for key, _ in sel.select(0.1):
                reads[key.data].append((time.monotonic(), os.read(key.fd, 65536)))
        elapsed = time.monotonic() - t0
        cpu = (_cpu_seconds(proc.pid) - cpu0) / elapsed
        rss = _rss_mib(proc.pid)
    finally:
        for port in ports:
            port.close()
        proc.terminate()
        proc.wait(timeout=10)
    rates, residuals, lost, bad = [], [], 0, 0
    size = REPLIES[code].length
    for unit_reads in reads:
        framer = Framer([code])
        batches = framer.feed(b"".join(data for _, data in unit_reads))
        ticks = np.concatenate([b["timer"] for b in batches]).astype(np.int64)
        ends = np.concatenate([b.offsets for b in batches]) + size
        received = np.cumsum([len(data) for _, data in unit_reads])
        arrived = np.array([t for t, _ in unit_reads])[np.searchsorted(received, ends)]
        steps = np.diff(ticks) & 0xFFFF_FFFF
        lost += int(np.round(steps / (TICKS_PER_SECOND / 1000)).sum() - len(steps))
        seconds = np.concatenate([[0], np.cumsum(steps)]) / TICKS_PER_SECOND
        fit = np.polyfit(seconds, arrived, 1)
        residuals.append(arrived - np.polyval(fit, seconds))
        rates.append(len(ticks) / elapsed)
        bad += framer.stats.checksum_failures
    res = np.concatenate(residuals) * 1e3
    print(f"{args.units} units x 0x{code:02X} at 1000 Hz, 921600 baud, "
          f"{'noise and random walks' if args.noise else 'no noise'}, {elapsed:.1f} s; "
          f"load average {os.getloadavg()[0]:.2f}")
    print(f"  records/s per unit: min {min(rates):.1f}  mean {np.mean(rates):.1f}  "
          f"total {sum(rates):.0f}")
    print(f"  records lost (timer gaps): {lost}  checksum failures: {bad}")
    print(f"  arrival jitter around the device timer (ms): std {res.std():.3f}  "
          f"p99 {np.percentile(np.abs(res), 99):.3f}  max {np.abs(res).max():.3f}")
    print(f"  emulator CPU: {cpu * 100:.0f} % of one core, resident memory {rss:.0f} MiB")


if __name__ == "__main__":
    main()
