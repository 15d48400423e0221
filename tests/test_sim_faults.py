"""Faults on demand, seen through real ports: corruption, USB snubs, pulled cables."""

from __future__ import annotations

import contextlib
import os
import socket
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
from bridge.sim.serve import PtyEndpoint, Simulator
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
                data: bytes = port.read(300)
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
        batches = Framer({0xC2}).feed(reopen_and_read(url))
        timers = np.concatenate([b["timer"] for b in batches]).astype(np.int64)
        assert len(timers) >= 3 and (np.diff(timers) == 250).all()  # streaming again
        assert sim.slots[0].faults.disconnects >= 1


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


def test_the_link_is_ours_and_goes_on_exit(tmp_path: Path) -> None:
    link = tmp_path / "imu"
    link.symlink_to("/dev/pts/999")  # what a killed run leaves behind: replaced
    with Simulator([UnitConfig()], "pty", links=[link]) as sim:
        assert sim.endpoints == [str(link)] and link.resolve().exists()
    assert not link.exists() and not link.is_symlink()


def test_a_pulled_pty_takes_its_name_with_it(tmp_path: Path) -> None:
    """As udev removes a pulled device's link: a host retrying the name while the unit is
    away must not open whichever pty the kernel hands that number next."""
    name = tmp_path / "imu"
    link = PtyEndpoint(115_200, name)
    try:
        before = os.readlink(name)
        link.unplug()
        assert not name.is_symlink()
        link.plug()
        assert name.is_symlink() and os.readlink(name) == link.path
    finally:
        link.close()
    assert before.startswith("/dev/pts/") and not name.is_symlink()


def test_a_second_tcp_client_is_refused_and_the_first_keeps_the_unit() -> None:
    notices: list[str] = []
    with Simulator([UnitConfig()], "tcp", notify=notices.append) as sim, \
            serial.serial_for_url(sim.endpoints[0], timeout=0.05) as first:
        assert ask_until_answered(first, encode_command("firmware_version"), 7)[:1] == b"\xe9"
        host, port = sim.endpoints[0][len("socket://"):].split(":")
        with socket.create_connection((host, int(port)), timeout=5) as second:
            assert second.recv(1) == b""  # closed at once
        assert ask_until_answered(first, encode_command("firmware_version"), 7)[:1] == b"\xe9"
    assert len(notices) == 1 and "refused a second client" in notices[0]


def test_a_state_file_that_goes_unwritable_is_reported_once(tmp_path: Path) -> None:
    folder = tmp_path / "state"
    notices: list[str] = []
    with Simulator([UnitConfig(state_file=folder / "unit.json")], "tcp",
                   notify=notices.append) as sim, \
            serial.serial_for_url(sim.endpoints[0], timeout=0.05) as port:
        ask_until_answered(port, encode_command("firmware_version"), 7)
        folder.write_text("not a folder any more")
        for preset in (3, 2, 3):
            reply = ask_until_answered(port, encode_command("mode_preset", mode_preset=preset), 4)
            assert reply[:2] == bytes((0xD5, preset))
        assert sim.error is None
    assert len(notices) == 1 and "cannot save" in notices[0]


def test_a_power_cutting_disconnect_reboots_the_unit() -> None:
    faults = FaultConfig(disconnect_every_s=0.5, disconnect_s=0.2, disconnect_power_cycles=True)
    with Simulator([UnitConfig()], "tcp", faults=faults) as sim:
        faults_seen = sim.slots[0].faults
        timer = encode_command("timer", function=1, value=3_000_000_000)
        deadline = time.monotonic() + 20
        set_before: int | None = None
        while set_before is None and time.monotonic() < deadline:
            with contextlib.suppress(serial.SerialException, OSError), \
                    serial.serial_for_url(sim.endpoints[0], timeout=0.05) as port:
                if ask_until_answered(port, timer, 7, timeout=0.5):
                    set_before = faults_seen.disconnects
        assert set_before is not None
        while faults_seen.disconnects <= set_before and time.monotonic() < deadline:
            time.sleep(0.02)
        reply = b""
        while not reply and time.monotonic() < deadline:
            with contextlib.suppress(serial.SerialException, OSError), \
                    serial.serial_for_url(sim.endpoints[0], timeout=0.05) as port:
                reply = ask_until_answered(port, encode_command("timer", function=0, value=0), 7)
        assert faults_seen.disconnects > set_before and len(reply) == 7
        assert int.from_bytes(reply[1:5], "big") < 2_000_000_000  # restarted from 0


def ask_until_answered(port: serial.SerialBase, command: bytes, length: int,
                       timeout: float = 5.0) -> bytes:
    """Send until a whole reply comes (a unit settling after power-up drops what it hears)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        port.write(command)
        reply: bytes = port.read(length)
        while reply and len(reply) < length and time.monotonic() < deadline:
            reply += port.read(length - len(reply))
        if len(reply) == length:
            return reply
    return b""
