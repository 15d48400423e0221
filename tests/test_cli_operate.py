"""The operator commands on a port: `gx3 info`, `gx3 configure`, `gx3 set-timer` as a user
types them, against the emulator on a pseudo-terminal."""

from __future__ import annotations

import json
import subprocess
from collections.abc import Iterator

import pytest

from bridge.sim.motion import MotionConfig
from bridge.sim.serve import Simulator
from bridge.sim.state import Sampling, Stored
from bridge.sim.unit import UnitConfig
from tests.test_bridge_process import GX3

UNIT = UnitConfig(serial="OPER0001", motion=MotionConfig(seed=5),
                  stored=Stored(mode_preset=1, baud=115_200, sampling=Sampling(decimation=10)))


@pytest.fixture
def port() -> Iterator[str]:
    with Simulator([UNIT], "pty") as sim:
        yield sim.endpoints[0]


def gx3(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([GX3, *args], capture_output=True, text=True, timeout=60,
                          stdin=subprocess.DEVNULL)


def test_info_and_a_temporary_change_on_a_port(port: str) -> None:
    info = gx3("info", "--port", port, "--json")
    assert info.returncode == 0, info.stderr
    assert json.loads(info.stdout)["serial"] == "OPER0001"
    assert json.loads(info.stdout)["sampling"]["decimation"] == 10
    changed = gx3("configure", "-p", port, "--decimation", "4", "--json")
    assert changed.returncode == 0, changed.stderr
    assert json.loads(changed.stdout)["sampling"]["decimation"] == 4
    timer = gx3("set-timer", "--port", port, "--value", "77", "--json")
    assert timer.returncode == 0, timer.stderr


def test_a_lasting_change_needs_yes_and_a_target_is_required(port: str) -> None:
    refused = gx3("configure", "--port", port, "--mode-preset", "2")
    assert refused.returncode != 0
    assert "lasting change" in refused.stderr and "--yes" in refused.stderr
    assert "Traceback" not in refused.stderr
    nowhere = gx3("reset")
    assert nowhere.returncode != 0 and "--port" in nowhere.stderr and "--unit" in nowhere.stderr
