"""The device session against the emulator, through real ptys and TCP via pyserial.

Every starting state a unit can be found in when a bridge starts: streaming,
idle, asleep, at another baud rate, sending little-endian floats. Then commands
while streaming, a baud change mid-session, the error reply and the persist guard.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace

import numpy as np
import pytest

from bridge.device.port import Port
from bridge.device.session import Session, find_baud, pace
from bridge.exceptions import CommandRejected, PersistRefused, PortError
from bridge.protocol.table import Flag, Mode
from bridge.sim.motion import MotionConfig
from bridge.sim.serve import Simulator
from bridge.sim.state import Sampling, Stored
from bridge.sim.unit import UnitConfig

BASE = UnitConfig(serial="DEV0001", motion=MotionConfig(seed=3, static=True))


@contextmanager
def unit(config: UnitConfig = BASE, transport: str = "pty") -> Iterator[tuple[Simulator, str]]:
    with Simulator([config], transport) as sim:
        yield sim, sim.endpoints[0]


@contextmanager
def session_on(url: str, baud: int = 115_200) -> Iterator[Session]:
    port = Port.open(url, baud)
    try:
        yield Session(port)
    finally:
        port.close()


def stream_some(session: Session, code: int, n: int) -> list[int]:
    """Start streaming ``code`` and return the timers of the first ``n`` records."""
    session.start_streaming(code)
    timers: list[int] = []
    for _ in range(400):
        for batch in session.read(0.05):
            assert batch.code == code
            timers += batch["timer"].tolist()
        if len(timers) >= n:
            break
    session.stop_streaming()
    return timers


@pytest.mark.parametrize("transport", ["pty", "tcp"])
def test_bring_up_reads_identity_and_settings(transport: str) -> None:
    config = replace(BASE, firmware=1127, lot="LOT7")
    with unit(config, transport) as (_, url), session_on(url) as s:
        s.quiesce()
        info = s.identify()
    assert info.firmware == 1127 and info.firmware_text == "1.1.27"
    assert info.ids == {"model_number": "6225-4220", "serial": "DEV0001",
                        "model_name": "3DM-GX3-25", "options": "5g 300d/s", "lot": "LOT7"}
    assert info.sampling["decimation"] == 10 and info.continuous_preset == 0
    assert info.period_ticks == 625.0


STARTS = {
    "streaming": Stored(mode_preset=int(Mode.CONTINUOUS), continuous_preset=0xC2),
    "idle": Stored(mode_preset=int(Mode.IDLE)),
    "little-endian": Stored(sampling=Sampling(flags=int(Flag.ORIENTATION | Flag.CONING_SCULLING
                                                        | Flag.LITTLE_ENDIAN_FLOATS))),
}


@pytest.mark.parametrize("start", sorted(STARTS))
def test_bring_up_from_every_starting_state(start: str) -> None:
    config = replace(BASE, stored=STARTS[start])
    with unit(config) as (_, url), session_on(url) as s:
        s.quiesce()
        info = s.identify()
        timers = stream_some(s, 0xCC, 20)
    assert info.little_endian == (start == "little-endian")
    steps = np.diff(np.array(timers, np.int64))
    assert len(timers) >= 20 and (steps == 625).all(), steps


def test_bring_up_wakes_a_sleeping_unit() -> None:
    with unit() as (_, url), session_on(url) as s:
        s.quiesce()
        s.send("mode", mode=int(Mode.SLEEP))
        s.drain()
        s.quiesce()
        assert s.command("mode", mode=0)["mode"] == int(Mode.ACTIVE)


def test_little_endian_records_decode_to_the_true_values() -> None:
    config = replace(BASE, stored=STARTS["little-endian"])
    with unit(config) as (_, url), session_on(url) as s:
        s.quiesce()
        s.identify()
        s.start_streaming(0xC2)
        batches = [b for _ in range(40) for b in s.read(0.05)]
        s.stop_streaming()
    accel = np.concatenate([b["accel"] for b in batches])
    assert len(accel) > 0 and all(b.little_endian for b in batches)
    assert np.allclose(np.linalg.norm(accel, axis=1), 1.0, atol=1e-3)


def test_another_baud_rate_is_found() -> None:
    config = replace(BASE, stored=Stored(baud=230_400))
    with unit(config) as (_, url):
        port, baud = find_baud(url, 115_200)
        try:
            assert baud == 230_400
            assert Session(port).command("firmware_version")["firmware"] == 1127
        finally:
            port.close()


def test_commands_while_streaming_lose_no_record() -> None:
    """A reply can make the unit skip a record (the line is busy); none sent is lost."""
    with unit() as (sim, url), session_on(url) as s:
        s.quiesce()
        s.identify()
        s.start_streaming(0xC2)
        timers: list[int] = []
        commands = 0
        while len(timers) < 60:
            if len(timers) >= 10 * (commands + 1):
                assert s.command("firmware_version")["firmware"] == 1127
                commands += 1
            for batch in s.read(0.05):
                timers += batch["timer"].tolist()
        s.stop_streaming()
        sent = sim.units[0].truth.arrays()["timer"]
    assert commands >= 5
    start = int(np.flatnonzero(sent == timers[0])[0])
    assert (sent[start : start + len(timers)] == timers).all(), "a record was lost"


def test_baud_change_mid_session() -> None:
    with unit() as (sim, url), session_on(url) as s:
        s.quiesce()
        info = s.identify()
        s.change_baud(info, 460_800)
        assert info.baud == 460_800 and s.port.baud == 460_800
        assert sim.units[0].baud == 460_800
        assert len(stream_some(s, 0xC2, 10)) >= 10


def test_error_reply_is_a_clear_error() -> None:
    with unit() as (_, url), session_on(url) as s:
        s.quiesce()
        with pytest.raises(CommandRejected, match="21 00 21"):
            s.transact(b"\xd4\xa3\x00\x00", 0xD4)  # wrong second confirmation byte


def test_nothing_is_persisted_unless_asked() -> None:
    with unit() as (sim, url), session_on(url) as s:
        s.quiesce()
        s.identify()
        with pytest.raises(PersistRefused, match="non-volatile"):
            s.command("mode_preset", mode_preset=2)
        with pytest.raises(PersistRefused):
            s.command("sampling_settings", function=2, decimation=5, flags=3, filter_width=15,
                      mag_filter_width=17, up_compensation=10, north_compensation=10)
        assert sim.units[0].stored == Stored()
        s.command("mode_preset", mode_preset=3, persist=True)
        assert sim.units[0].stored.mode_preset == 3


def test_old_firmware_refuses_a_temporary_sampling_change() -> None:
    """Before 1.1.27, 0xDB function 1 stores the settings (the manual's footnote)."""
    with unit(replace(BASE, firmware=414)) as (_, url), session_on(url) as s:
        s.quiesce()
        info = s.identify()
        with pytest.raises(PersistRefused):
            s.apply_sampling(info, decimation=5)


def test_missing_port_is_a_one_line_error(tmp_path: object) -> None:
    with pytest.raises(PortError, match="no such port"):
        Port.open("/dev/ttyGX3-does-not-exist", 115_200)


def test_busy_port_is_reported_as_busy() -> None:
    with unit() as (_, url), session_on(url), pytest.raises(PortError, match="busy"):
        Port.open(url, 115_200)


def test_the_first_streamed_record_is_kept() -> None:
    """It can arrive in the same read as the 0xC4 reply: the stream starts right there."""
    config = replace(BASE, stored=Stored(sampling=Sampling(decimation=1, flags=0)))
    for _ in range(5):
        with unit(config) as (sim, url), session_on(url) as s:
            s.quiesce()
            timers = stream_some(s, 0xC2, 5)
            sent = sim.units[0].truth.arrays()["timer"]
        assert timers[:5] == sent[:5].tolist(), "the stream's first record was dropped"


def test_a_record_cut_by_a_read_is_waited_for_only_where_it_would_come_in_pieces() -> None:
    """A UART whose FIFO hands over a few bytes at a time would wake the bridge for each:
    it sleeps for the rest's line time instead. A link that hands over large pieces (a
    pty, a driver that gathers) brings the rest in one wake-up, and a sleep, a timer
    wake-up, would only add one."""
    baud = 921_600
    assert pace(66, 13.0, baud) == pytest.approx(66 * 10 / baud)
    assert pace(66, 46.0, baud) == 0.0
    assert pace(20, 9.0, baud) == pytest.approx(20 * 10 / baud)
    assert pace(0, 1.0, baud) == 0.0
    assert pace(-4, 1.0, baud) == 0.0


def test_a_unit_gone_between_a_write_and_its_drain_is_a_port_gone() -> None:
    """pyserial drains a write with termios, whose error is no OSError: a pty whose unit
    closed it between the two says EIO there, and that is a pulled cable (the bridge
    reconnects), not an internal error that stops the bridge."""
    master, slave = os.openpty()
    port = Port.open(os.ttyname(slave), 115_200)
    os.close(master)
    try:
        with pytest.raises(PortError, match="went away") as gone:
            port.write(b"")  # nothing to write: straight to the drain
        assert gone.value.why == "port gone"
    finally:
        port.close()
        os.close(slave)
