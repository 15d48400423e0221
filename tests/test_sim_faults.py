"""Faults on demand, seen through real ports: corruption, USB snubs, pulled cables."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import serial

from bridge.protocol.codec import encode_command
from bridge.protocol.framer import Framer
from bridge.sim.faults import FaultConfig
from bridge.sim.motion import MotionConfig
from bridge.sim.serve import Simulator
from bridge.sim.state import Sampling, Stored
from bridge.sim.unit import UnitConfig

STREAMING = Stored(mode_preset=2, continuous_preset=0xC2, sampling=Sampling(decimation=4, flags=0))


def streaming_unit(seed: int = 1) -> UnitConfig:
    return UnitConfig(motion=MotionConfig(seed=seed), stored=STREAMING)


def read_for(port: serial.SerialBase, seconds: float) -> list[tuple[float, bytes]]:
    """Every read with its arrival time, as a host driver sees it."""
    out = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        data = port.read(4096)
        if data:
            out.append((time.monotonic(), data))
    return out


@pytest.fixture
def flipping() -> Iterator[Simulator]:
    with Simulator([streaming_unit()], "tcp", faults=FaultConfig(bit_flip_rate=2e-3,
                                                                 drop_rate=5e-4)) as sim:
        yield sim


def test_corruption_costs_only_the_damaged_records(flipping: Simulator) -> None:
    with serial.serial_for_url(flipping.endpoints[0], timeout=0.05) as port:
        data = b"".join(d for _, d in read_for(port, 2.0))
    sent_timers = flipping.units[0].truth.arrays()["timer"]
    framer = Framer({0xC2})
    timers = np.concatenate([b["timer"] for b in framer.feed(data)]).astype(np.int64)
    sent = len(data) / 31
    expected_damaged = sent * 31 * (2e-3 + 5e-4)
    damaged = int((np.diff(timers) // 250 - 1).sum())
    assert framer.stats.checksum_failures > 0
    assert damaged <= 2 * expected_damaged + 5, (damaged, expected_damaged)
    assert len(timers) >= 0.8 * sent, (len(timers), sent)
    # At this fault rate a record now and then takes two flips that cancel in the
    # additive checksum; no framer can catch those, so a few per thousand may pass.
    genuine = np.isin(timers, sent_timers)
    assert genuine.mean() >= 0.995, timers[~genuine]


def test_usb_snubs_hold_bytes_back_then_burst() -> None:
    faults = FaultConfig(stall_every_s=0.3, stall_s=0.15)
    with Simulator([streaming_unit()], "tcp", faults=faults) as sim, serial.serial_for_url(
            sim.endpoints[0], timeout=0.01) as port:
        reads = read_for(port, 2.0)
    times = np.array([t for t, _ in reads])
    sizes = np.array([len(d) for _, d in reads])
    gaps = np.diff(times)
    assert gaps.max() >= 0.12
    after_gap = sizes[1:][gaps >= 0.12]
    assert after_gap.max() >= 0.1 * 250 * 31
    framer = Framer({0xC2})
    timers = np.concatenate([b["timer"] for b in framer.feed(b"".join(d for _, d in reads))])
    assert set(np.diff(timers.astype(np.int64))) == {250}


def reopen_and_read(url: str, timeout: float = 5.0) -> bytes:
    """Open the port again until the unit is back, as a driver's reconnect loop does."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            with serial.serial_for_url(url, baudrate=115_200, timeout=0.3) as port:
                data = port.read(300)
        except (serial.SerialException, OSError):
            time.sleep(0.05)
            continue
        if data:
            return data
    return b""


@pytest.mark.parametrize("transport", ["tcp", "pty"])
def test_a_pulled_cable_ends_the_connection_and_the_unit_comes_back(
        transport: str, tmp_path: Path) -> None:
    faults = FaultConfig(disconnect_every_s=0.3, disconnect_s=0.4)
    links = [tmp_path / "imu"] if transport == "pty" else None
    with Simulator([streaming_unit()], transport, faults=faults, links=links) as sim:
        url = sim.endpoints[0]
        with serial.serial_for_url(url, baudrate=115_200, timeout=0.05) as port, \
                pytest.raises(serial.SerialException):
            read_for(port, 5.0)
        assert Framer({0xC2}).feed(reopen_and_read(url))
        assert sim.slots[0].faults.disconnects >= 1 or not sim.slots[0].plugged


def test_a_host_at_the_wrong_baud_rate_does_not_stop_the_unit() -> None:
    with Simulator([UnitConfig()], "pty") as sim:
        with serial.Serial(sim.endpoints[0], 9600, timeout=0.05) as wrong:
            wrong.write(encode_command("firmware_version") * 3)
            wrong.flush()
            read_for(wrong, 0.2)
        with serial.Serial(sim.endpoints[0], 115_200, timeout=0.05) as right:
            reply = b""
            deadline = time.monotonic() + 5.0
            while len(reply) < 7 and time.monotonic() < deadline:
                right.write(encode_command("firmware_version"))
                reply = right.read(7)
        assert sim.error is None
        assert reply[:1] == b"\xe9" and len(reply) == 7
