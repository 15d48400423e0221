"""Fixtures every test module can use; shared plain helpers are in ``tests/helpers``."""

from __future__ import annotations

import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zenoh

from bridge.bus.session import open_session
from tests.helpers.processes import GX3, Sim
from tests.helpers.waiting import free_port
from tests.helpers.zenoh import zenoh_config


@pytest.fixture
def network(tmp_path: Path) -> tuple[Path, Path]:
    """A config for the bridge (listening) and one for the test's sessions (connecting)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    return (zenoh_config(tmp_path / "bridge.json5", listen=[endpoint]),
            zenoh_config(tmp_path / "client.json5", connect=[endpoint]))


@pytest.fixture
def session() -> Iterator[zenoh.Session]:
    """A Zenoh session listening on a free loopback port, scouting off."""
    with open_session(listen=["tcp/127.0.0.1:0"], multicast_scouting=False) as s:
        yield s


@pytest.fixture
def run_sim() -> Iterator[Callable[..., Sim]]:
    """Start `gx3 sim` with arguments; every process started is killed and reaped after."""
    started: list[subprocess.Popen[bytes]] = []

    def start(*args: str) -> Sim:
        proc = subprocess.Popen([GX3, "sim", *args], stdin=subprocess.DEVNULL,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        started.append(proc)
        return Sim(proc)

    yield start
    for proc in started:
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=10)
        for pipe in (proc.stdout, proc.stderr):
            if pipe is not None:
                pipe.close()
