"""The shipped configuration files: systemd units and udev rules that really work
(test_shipped_files installs them and runs systemd-analyze verify on the result), and the
Zenoh pair that lets gx3 processes meet on one machine by hand."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from bridge.archive.walk import read_archive
from bridge.bus.session import open_session
from bridge.sim.serve import Simulator
from tests.helpers.archives import samples_in
from tests.helpers.processes import bridge_process, recorder
from tests.helpers.units import TWO_UNITS
from tests.helpers.waiting import free_port, wait_for

ROOT = Path(__file__).resolve().parent.parent
GX3 = Path(sys.executable).parent / "gx3"


@pytest.mark.parametrize("unit", ["gx3-bridge@.service", "gx3-record.service"])
def test_systemd_units_run_real_command_lines(unit: str) -> None:
    """Every option an ExecStart passes is one its gx3 command takes."""
    text = (ROOT / "configs" / "systemd" / unit).read_text()
    line = text.split("ExecStart=", 1)[1].split("\nKillSignal", 1)[0].replace("\\\n", " ")
    words = line.split()
    command = words[1]
    options = {w for w in words if w.startswith("--")}
    done = subprocess.run([str(GX3), command, "--help"], capture_output=True, text=True,
                          timeout=60, check=False, env={"COLUMNS": "200"})
    assert done.returncode == 0
    assert options and all(option in done.stdout for option in options), options


def test_udev_rules_name_units_under_dev_gx3_for_systemd() -> None:
    lines = (ROOT / "configs" / "udev" / "99-gx3.rules").read_text().splitlines()
    rules = [line for line in lines if line.startswith('SUBSYSTEM=="tty"')]
    assert rules
    assert all('SYMLINK+="gx3/' in r and 'TAG+="systemd"' in r for r in rules)


def _loopback_pair(folder: Path) -> tuple[Path, Path]:
    """configs/loopback/listen.json5 and connect.json5 as shipped, but for their one port
    (the same in both, Zenoh's 7447), a free one: another test may hold 7447."""
    port = free_port()
    pair = []
    for name in ("listen", "connect"):
        text = (ROOT / "configs" / "loopback" / f"{name}.json5").read_text()
        assert text.count("tcp/127.0.0.1:7447") == 1, name
        pair.append(folder / f"{name}.json5")
        pair[-1].write_text(text.replace("tcp/127.0.0.1:7447", f"tcp/127.0.0.1:{port}"))
    return pair[0], pair[1]


def test_loopback_configs_let_a_bridge_a_recorder_and_an_app_meet_on_one_machine(
        tmp_path: Path) -> None:
    """Getting started's recipe: an emulated unit, its bridge on listen.json5, the recorder
    and an app on connect.json5, each its own process (the recorder started first: a
    connector waits for the listener)."""
    listen, connect = _loopback_pair(tmp_path)
    archive = tmp_path / "still.mcap"
    with Simulator(TWO_UNITS[:1], "pty") as sim:
        rec = recorder(archive, connect)
        try:
            with bridge_process(sim.endpoints[0], listen, "--unit", "still"), \
                    open_session(connect) as app:
                heard = threading.Event()
                sub = app.declare_subscriber("gx3/still/imu", lambda _: heard.set())
                wait_for(lambda: heard.is_set() and samples_in(archive, "still") >= 100,
                         what="the app's and the recorder's samples")
                sub.undeclare()
        finally:
            rec.send_signal(signal.SIGINT)
            _, stderr = rec.communicate(timeout=60)
    assert rec.returncode == 0, stderr.decode()
    assert read_archive(archive).complete and samples_in(archive, "still") >= 100
