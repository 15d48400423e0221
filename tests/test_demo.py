"""`gx3 demo` as a new user runs it: one command, everything started and stopped."""

from __future__ import annotations

import os
import re
import signal
import subprocess
from pathlib import Path

import psutil

from bridge.archive.walk import read_archive
from tests.helpers.mcap_order import order_problems
from tests.helpers.processes import GX3
from tests.helpers.rrd import rerun_rows


def test_demo_runs_the_fleet_and_reports_the_fault(tmp_path: Path) -> None:
    """Also what it prints off a terminal (a CI log: stderr is a pipe here), with the
    virtual environment not on the PATH, as after the quickstart in a new shell."""
    out = tmp_path / "demo"
    proc = psutil.Popen([GX3, "demo", "--duration", "5", "--units", "2", "-o", str(out)],
                        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                        env=_SHELL_WITHOUT_THE_VENV, cwd=tmp_path)
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
    for unit in ("imu1", "imu2"):  # the summary counts what the archive holds
        assert int(lines[unit][1].replace(",", "")) == sum(
            len(b) for b in archive.samples([unit])), stderr
    assert re.search(r"^demo: \d+ of 5 s, [\d,]+ samples from 2 of 2 units$", stderr, re.M), \
        "no progress off a terminal"
    assert "not yet known" not in stderr and "+0.0 (" not in stderr, stderr
    # the suggestions run as printed, in a shell that does not have the venv's PATH
    exports = [line.strip() for line in stderr.splitlines() if " export " in line]
    assert exports and all(line.startswith(("gx3 ", "/", ".", "'")) for line in exports)
    for line in exports:
        done = subprocess.run(line, shell=True, capture_output=True, text=True, cwd=tmp_path,
                              env=_SHELL_WITHOUT_THE_VENV, timeout=120, check=False)
        assert done.returncode == 0, (line, done.stderr)
    assert (out / "demo.parquet").exists() and (out / "aligned.csv").exists()
    viewers = [line.split()[0] for line in stderr.splitlines() if line.strip().startswith(
        ("rerun ", "/", "."))and " export " not in line]
    assert viewers and all(os.access(Path(tmp_path, v), os.X_OK) if not v.startswith("/")
                           else os.access(v, os.X_OK) for v in viewers), viewers
    # no display in this shell: Rerun's web viewer, which needs none, and where to open it
    assert all(" --serve-web --bind 127.0.0.1 --port 9876 --web-viewer-port 9090 " in line
               for line in stderr.splitlines() if line.strip().split()[:1] == [viewers[0]])
    assert ("open http://127.0.0.1:9090/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A9876%2Fproxy in "
            "a browser") in stderr
    for unit in ("imu1", "imu2"):  # each bridge's own account, in the folder
        log = (out / f"{unit}.log").read_text()
        assert "bring_up 3DM-GX3-25" in log and f"{unit}: " in log, log
    assert "disconnect" in (out / "imu2.log").read_text()


def test_an_interrupted_demo_keeps_its_results_and_exits_130(tmp_path: Path) -> None:
    """Ctrl-C ends a demo early: everything it started stops, what it recorded is kept
    and summarised, and the exit status says it was interrupted (130)."""
    out = tmp_path / "demo"
    proc = subprocess.Popen([GX3, "demo", "--duration", "60", "--units", "1", "-o", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=_SHELL_WITHOUT_THE_VENV)
    assert proc.stderr is not None
    for line in proc.stderr:  # progress lines, off a terminal
        if re.match(r"demo: \d+ of 60 s", line):
            break
    proc.send_signal(signal.SIGINT)
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    assert "interrupted after" in stderr and "Traceback" not in stderr, stderr
    archive = read_archive(out / "demo.mcap")
    assert archive.complete and sum(len(b) for b in archive.samples(["imu1"])) > 0


#: A new shell after the quickstart: the system's PATH, not the venv's bin folder.
_SHELL_WITHOUT_THE_VENV = {
    "COLUMNS": "120", "PATH": "/usr/bin:/bin",
    **{k: v for k, v in os.environ.items() if k in ("PYTHONPATH", "HOME")}}
