"""CPU time and peak memory of another process, from /proc (Linux)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

CLK_TCK = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float:
    """User + system CPU seconds the process has used so far."""
    return _cpu(Path(f"/proc/{pid}/stat"))


def thread_cpu_seconds(pid: int) -> dict[str, float]:
    """CPU seconds so far by thread name ("python" or the program's name for Python's
    threads, "tx-0", "rx-1", ... for Zenoh's), threads of one name summed."""
    out: dict[str, float] = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            name = (task / "comm").read_text().strip()
            out[name] = out.get(name, 0.0) + _cpu(task / "stat")
        except OSError:  # the thread ended meanwhile
            continue
    return out


def _cpu(stat: Path) -> float:
    fields = stat.read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


def peak_rss_mb(pid: int) -> float:
    """The most resident memory the process has used, MiB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def gx3_run(command: str, *args: str | Path) -> tuple[float, float]:
    """Wall seconds and peak resident MiB of ``gx3 COMMAND ARGS --force``, as a user runs
    it (start-up included; the peak from ``wait4``: this run's own, not earlier runs').

    Raises:
        SystemExit: The command failed.
    """
    gx3 = shutil.which("gx3", path=str(Path(sys.executable).parent)) or "gx3"
    start = time.perf_counter()
    proc = subprocess.Popen([gx3, command, *map(str, args), "--force"],
                            stderr=subprocess.DEVNULL)
    _, status, usage = os.wait4(proc.pid, 0)
    elapsed = time.perf_counter() - start
    if os.waitstatus_to_exitcode(status):
        raise SystemExit(f"gx3 {command} failed")
    return elapsed, usage.ru_maxrss / 1024
