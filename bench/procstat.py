"""CPU time and peak memory of another process (from /proc, Linux), and of a gx3 command."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
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


def load() -> str:
    """The machine's load over the last minute, so a figure says what else was running."""
    return f"load average {os.getloadavg()[0]:.2f}"


def gx3_measured(*args: str | Path) -> tuple[float, float, str]:
    """Wall seconds, peak resident MiB and what it said (stderr) of ``gx3 ARGS``, as a
    user runs it (start-up included).

    Raises:
        SystemExit: The command failed.
    """
    gx3 = shutil.which("gx3", path=str(Path(sys.executable).parent)) or "gx3"
    start = time.perf_counter()
    with tempfile.TemporaryFile() as said:
        proc = subprocess.Popen([gx3, *map(str, args)], stderr=said)
        _, status, usage = os.wait4(proc.pid, 0)  # this run's own peak, not earlier runs'
        elapsed = time.perf_counter() - start
        said.seek(0)
        text = said.read().decode()
    if os.waitstatus_to_exitcode(status):
        raise SystemExit(f"gx3 {args[0]} failed: {text.strip()}")
    return elapsed, usage.ru_maxrss / 1024, text


def gx3_run(command: str, *args: str | Path) -> tuple[float, float]:
    """Wall seconds and peak resident MiB of ``gx3 COMMAND ARGS --force``."""
    elapsed, peak, _ = gx3_measured(command, *args, "--force")
    return elapsed, peak
