"""The operator commands as a user types them: `gx3 info`, `gx3 configure`, `gx3 set-timer`
on a port, against the emulator on a pseudo-terminal, and `gx3 info --unit` through a
running bridge."""

from __future__ import annotations

import json
import subprocess
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import pytest
import zenoh

from bridge.bus.remote import ask_units
from bridge.exceptions import RemoteError
from bridge.sim.motion import MotionConfig
from bridge.sim.serve import Simulator
from bridge.sim.state import Sampling, Stored
from bridge.sim.unit import UnitConfig
from tests.helpers.cli import gx3_here
from tests.helpers.processes import GX3, bridge_process
from tests.helpers.waiting import free_port, wait_for

UNIT = UnitConfig(serial="OPER0001", motion=MotionConfig(seed=5),
                  stored=Stored(mode_preset=1, baud=115_200, sampling=Sampling(decimation=10)))


@pytest.fixture
def port() -> Iterator[str]:
    with Simulator([UNIT], "pty") as sim:
        yield sim.endpoints[0]


def gx3(*args: str) -> subprocess.CompletedProcess[str]:
    """``gx3 ARGS`` in this process: exit code, stdout and stderr."""
    done = gx3_here(*args)
    return subprocess.CompletedProcess(args, done.exit_code, done.stdout, done.stderr)


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


def test_info_shows_the_presets_as_a_person_reads_them(port: str) -> None:
    """The stored presets, named (the unit's JSON keeps the numbers the unit gave)."""
    stored = gx3("configure", "--port", port, "--continuous-preset", "0xCC", "--mode-preset",
                 "2", "--yes")
    assert stored.returncode == 0, stored.stderr
    text = gx3("info", "--port", port)
    assert text.returncode == 0, text.stderr
    rows = {line.split(None, 1)[0]: line.split(None, 1)[1].strip()
            for line in text.stdout.splitlines() if line.strip() and not line.startswith(" ")}
    assert rows["continuous_preset"] == "0xCC (accel, ang_rate, mag, m)"
    assert rows["mode_preset"] == "2 (continuous)"
    assert rows["firmware"] == "1.1.27"
    assert "record" not in rows and "streaming" not in rows  # nothing streams on a port
    as_json = json.loads(gx3("info", "--port", port, "--json").stdout)
    assert (as_json["continuous_preset"], as_json["mode_preset"]) == (0xCC, 2)


def test_a_lasting_change_needs_yes_and_a_target_is_required(port: str) -> None:
    refused = gx3("configure", "--port", port, "--mode-preset", "2")
    assert refused.returncode != 0
    assert "lasting change" in refused.stderr and "--yes" in refused.stderr
    assert "Traceback" not in refused.stderr
    nowhere = gx3("reset")
    assert nowhere.returncode != 0 and "--port" in nowhere.stderr and "--unit" in nowhere.stderr


def test_info_on_a_gx2_says_it_is_not_a_gx3_with_exit_2() -> None:
    with Simulator([replace(UNIT, model_name="3DM-GX2")], "pty") as sim:
        result = gx3("info", "--port", sim.endpoints[0])
    assert result.returncode == 2
    assert result.stderr.startswith("error: the unit says it is a 3DM-GX2, not a 3DM-GX3")
    assert len(result.stderr.splitlines()) == 1


def peer(path: Path, listen: list[str] | None = None, connect: list[str] | None = None) -> Path:
    """A peer on loopback, multicast scouting off, gossip on (Zenoh's default)."""
    path.write_text(json.dumps({"mode": "peer", "listen": {"endpoints": listen or []},
                                "connect": {"endpoints": connect or []},
                                "scouting": {"multicast": {"enabled": False}}}))
    return path


def info_ok(config: Path) -> bool:
    """Whether `gx3 info --unit oper` (its code, in this process, a fresh session) works."""
    try:
        answers = ask_units("gx3", "oper", "info", {}, zenoh_config=config)
    except RemoteError:
        return False
    return [(unit, ok, result["serial"]) for unit, ok, result in answers] == \
        [("oper", True, "OPER0001")]


def test_info_finds_a_bridge_reached_through_another_peer_every_time(
        port: str, tmp_path: Path) -> None:
    """The operator's peer connects to another peer (a recorder's; here the test's),
    learns of the bridge from it by gossip and connects to it a moment after its own
    session opened: a query sent at once found no bridge about a third of the time."""
    bridge_at, hub_at = (f"tcp/127.0.0.1:{free_port()}" for _ in range(2))
    operator = peer(tmp_path / "operator.json5", connect=[hub_at])
    hub = peer(tmp_path / "hub.json5", listen=[hub_at], connect=[bridge_at])
    with bridge_process(port, peer(tmp_path / "bridge.json5", listen=[bridge_at]),
                        "--unit", "oper"), \
            zenoh.open(zenoh.Config.from_file(str(hub))):
        wait_for(lambda: info_ok(operator), what="the bridge")
        answered = sum(info_ok(operator) for _ in range(100))
        assert answered == 100
        cli = [subprocess.run([GX3, "info", "--unit", "oper", "--zenoh-config", str(operator),
                               "--json"], capture_output=True, text=True, timeout=60)
               for _ in range(3)]
        with pytest.raises(RemoteError, match="no bridge is running for gx3/ghost"):
            ask_units("gx3", "ghost", "info", {}, zenoh_config=operator, discovery=0.5)
    assert [(c.returncode, json.loads(c.stdout or "{}").get("serial")) for c in cli] == \
        [(0, "OPER0001")] * 3, [c.stderr for c in cli]
