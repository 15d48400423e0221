"""`gx3 demo` as a new user runs it: one command, everything started and stopped."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import psutil

from bridge.recorder.reader import read_archive
from tests.helpers.mcap_order import order_problems
from tests.helpers.processes import GX3
from tests.helpers.rrd import rerun_rows


def test_demo_runs_the_fleet_and_reports_the_fault(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    proc = psutil.Popen([GX3, "demo", "--duration", "5", "--units", "2", "-o", str(out)],
                        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                        env={"COLUMNS": "120", "PATH": str(Path(GX3).parent),
                             **{k: v for k, v in os.environ.items() if k == "PYTHONPATH"}})
    children: set[int] = set()
    while proc.poll() is None:
        try:
            children |= {c.pid for c in proc.children(recursive=True)}
        except psutil.NoSuchProcess:
            break
        try:
            proc.wait(timeout=0.5)
        except psutil.TimeoutExpired:
            continue
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 0, stderr
    assert len(children) >= 2, "the bridges were not separate processes"
    assert not [p for p in children if psutil.pid_exists(p)
                and psutil.Process(p).status() != psutil.STATUS_ZOMBIE], "stray processes"
    archive = read_archive(out / "demo.mcap")
    assert archive.complete and archive.units() == ["imu1", "imu2"]
    assert order_problems(out / "demo.mcap") == []  # on main: 63 % of it out of order
    for unit in ("imu1", "imu2"):
        assert sum(len(b) for b in archive.samples([unit])) > 200
        assert rerun_rows(out / "demo.rrd", f"/plots/accel/x/{unit}") > 200
    lines = {line.split()[0]: line.split() for line in stderr.splitlines()
             if line.startswith("imu")}
    reconnects = int(lines["imu2"][5])
    assert reconnects >= 1, stderr
    assert "unplug" in stderr and "rerun" in stderr
