"""Benchmark: one emulator process serving N units in continuous mode at 1 kHz.

Run by hand: `python bench/bench_sim.py [--units 16] [--seconds 10]`. Starts
`gx3 sim --pty` in its own process (as a user would), opens every pty at
921,600 baud, reads them all from one thread, and reports per unit the record
rate achieved, records lost, and the pacing jitter: the spread of each record's
arrival time around a straight-line fit of arrival time against the unit's own
timer (what a host sees, scheduling effects included).
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
from bridge.protocol.table import TICKS_PER_SECOND


def _cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=16)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--code", default="0xC2", help="continuous record type")
    args = parser.parse_args()
    code = int(args.code, 0)
    gx3 = shutil.which("gx3") or str(Path(sys.executable).with_name("gx3"))
    proc = subprocess.Popen(
        [gx3, "sim", "--pty", "--units", str(args.units), "--continuous-preset", args.code,
         "--mode-preset", "2", "--decimation", "1", "--flags", "0", "--baud", "921600"],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    ports: list[serial.Serial] = []
    try:
        assert proc.stdout is not None
        paths = [proc.stdout.readline().strip() for _ in range(args.units)]
        ports = [serial.Serial(p, 921_600, timeout=0) for p in paths]
        time.sleep(0.5)
        for port in ports:
            port.reset_input_buffer()
        framers = [Framer([code]) for _ in ports]
        arrivals: list[list[np.ndarray]] = [[] for _ in ports]
        timers: list[list[np.ndarray]] = [[] for _ in ports]
        sel = selectors.DefaultSelector()
        for i, port in enumerate(ports):
            sel.register(port.fileno(), selectors.EVENT_READ, i)
        cpu0, t0 = _cpu_seconds(proc.pid), time.monotonic()
        while time.monotonic() - t0 < args.seconds:
            for key, _ in sel.select(0.1):
                i = key.data
                data = os.read(key.fd, 65536)
                now = time.monotonic()
                for batch in framers[i].feed(data):
                    timers[i].append(batch["timer"].astype(np.int64))
                    arrivals[i].append(np.full(len(batch), now))
        elapsed = time.monotonic() - t0
        cpu = (_cpu_seconds(proc.pid) - cpu0) / elapsed
    finally:
        for port in ports:
            port.close()
        proc.terminate()
        proc.wait(timeout=10)
    rates, residuals, lost, bad = [], [], 0, 0
    for i in range(len(ports)):
        ticks = np.concatenate(timers[i])
        arrived = np.concatenate(arrivals[i])
        steps = np.diff(ticks) & 0xFFFF_FFFF
        lost += int(np.round(steps / (TICKS_PER_SECOND / 1000)).sum() - len(steps))
        seconds = np.concatenate([[0], np.cumsum(steps)]) / TICKS_PER_SECOND
        fit = np.polyfit(seconds, arrived, 1)
        residuals.append(arrived - np.polyval(fit, seconds))
        rates.append(len(ticks) / elapsed)
        bad += framers[i].stats.checksum_failures
    res = np.concatenate(residuals) * 1e3
    print(f"{args.units} units x 0x{code:02X} at 1000 Hz, 921600 baud, {elapsed:.1f} s")
    print(f"  records/s per unit: min {min(rates):.1f}  mean {np.mean(rates):.1f}  "
          f"total {sum(rates):.0f}")
    print(f"  records lost (timer gaps): {lost}  checksum failures: {bad}")
    print(f"  arrival jitter around the device timer (ms): std {res.std():.3f}  "
          f"p99 {np.percentile(np.abs(res), 99):.3f}  max {np.abs(res).max():.3f}")
    print(f"  emulator CPU: {cpu * 100:.0f} % of one core")


if __name__ == "__main__":
    main()
