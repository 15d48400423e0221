"""The fleet guide's configuration files: systemd units and udev rules that really work
(test_shipped_files installs them and runs systemd-analyze verify on the result)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

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
