"""The `gx3 sim` console script, run as a user runs it: a real process on real endpoints.

Replies are checked with a hand-written checksum and ``struct``, independently of
``bridge.protocol``, so the test sees what a host on the other end would see.
"""

from __future__ import annotations

import itertools
import os
import re
import select
import signal
import struct
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import serial
import typer.core
import typer.main
from typer.testing import CliRunner

from bridge.cli import app
from tests.helpers.processes import Sim

WRAP = 1 << 32
C2_LENGTH = 31
CC_LENGTH = 79
TIMER_START = 4_294_900_000
# Every option the brief for `gx3 sim` names; the command's own list is added below.
DOCUMENTED_OPTIONS = (
    "--pty", "--tcp", "--units", "--serial", "--model-name", "--model-number", "--firmware",
    "--timer-start", "--clock-ppm", "--seed", "--static", "--noise-accel", "--noise-gyro",
    "--noise-mag", "--gyro-bias", "--decimation", "--flags", "--continuous-preset",
    "--mode-preset", "--baud", "--flip-rate", "--drop-rate", "--stall-every", "--stall-for",
    "--disconnect-every", "--disconnect-for", "--state", "--link", "--duration",
    "--no-filter-model", "--disconnect-power-cycles", "--hard-iron", "--soft-iron", "--tumble",
    "--usb", "--usb-serial", "--latency-timer",
)


def checksum(data: bytes) -> bytes:
    """The manual's checksum: 16-bit wrapping sum of the preceding bytes, big-endian."""
    return struct.pack(">H", sum(data) & 0xFFFF)


def framed(body: bytes) -> bytes:
    return body + checksum(body)


def intact(reply: bytes, code: int, length: int) -> bool:
    return len(reply) == length and reply[0] == code and reply[-2:] == checksum(reply[:-2])


def ask(port: serial.SerialBase, command: bytes, length: int, timeout: float = 2.0) -> bytes:
    """Send one command and read its whole reply, or whatever came before the deadline."""
    port.write(command)
    port.flush()
    deadline = time.monotonic() + timeout
    reply = bytearray()
    while len(reply) < length and time.monotonic() < deadline:
        reply += port.read(length - len(reply))
    return bytes(reply)


def settle(port: serial.SerialBase, timeout: float = 5.0) -> None:
    """Wait out the unit's power-up settling (bytes sent during it are lost), then drain."""
    deadline = time.monotonic() + timeout
    while not port.read(7) and time.monotonic() < deadline:
        port.write(b"\xe9")
    time.sleep(0.05)
    port.reset_input_buffer()


def stream_records(data: bytes, code: int, length: int) -> list[bytes]:
    """Intact records of a stream joined mid-record: sync on two in a row, then walk."""
    for start in range(length):
        first, second = data[start : start + length], data[start + length : start + 2 * length]
        if intact(first, code, length) and intact(second, code, length):
            break
    else:
        return []
    records = []
    for i in range(start, len(data) - length + 1, length):
        chunk = data[i : i + length]
        assert intact(chunk, code, length), f"record at byte {i} is broken: {chunk.hex()}"
        records.append(chunk)
    return records


def timer_of(record: bytes) -> int:
    return int(struct.unpack_from(">I", record, len(record) - 6)[0])


def test_tcp_units_are_distinct_devices(run_sim: Callable[..., Sim]) -> None:
    """Three units: three socket:// lines, three serial numbers, three attitudes."""
    sim = run_sim("--tcp", "127.0.0.1:0", "--units", "3", "--static")
    urls = sim.endpoints(3)
    assert all(re.fullmatch(r"socket://127\.0\.0\.1:\d+", url) for url in urls), urls
    assert len(set(urls)) == 3
    serials, accels = [], []
    for url in urls:
        with serial.serial_for_url(url, timeout=0.05) as port:
            settle(port)
            reply = ask(port, b"\xea\x01", 20)
            assert intact(reply, 0xEA, 20) and reply[1] == 1, reply.hex()
            serials.append(reply[2:18])
            reply = ask(port, b"\xc2", C2_LENGTH)
            assert intact(reply, 0xC2, C2_LENGTH), reply.hex()
            accel = np.array(struct.unpack_from(">3f", reply, 1))
            assert np.linalg.norm(accel) == pytest.approx(1.0, abs=1e-3)
            accels.append(accel)
    assert len(set(serials)) == 3, serials
    for a, b in itertools.combinations(accels, 2):
        assert np.abs(a - b).max() > 1e-3, "two units report the same attitude"


def test_the_magnetometer_reads_through_the_iron_given(run_sim: Callable[..., Sim]) -> None:
    """--hard-iron and --soft-iron reach the unit: 0xC7 reads soft @ field + hard."""
    sim = run_sim("--tcp", "127.0.0.1:0", "--static", "--hard-iron", "1,-2,3",
                  "--soft-iron", "2,0,0,0,2,0,0,0,2")
    (url,) = sim.endpoints(1)
    with serial.serial_for_url(url, timeout=0.05) as port:
        settle(port)
        reply = ask(port, b"\xc7", 19)
        assert intact(reply, 0xC7, 19), reply.hex()
    field = (np.array(struct.unpack_from(">3f", reply, 1)) - [1, -2, 3]) / 2
    assert np.linalg.norm(field) == pytest.approx(np.hypot(0.2, 0.45), rel=1e-4)


def test_pty_endpoint_opens_with_pyserial(run_sim: Callable[..., Sim]) -> None:
    sim = run_sim("--pty", "--firmware", "4242")
    (path,) = sim.endpoints(1)
    assert Path(path).exists(), path
    with serial.Serial(path, 115_200, timeout=0.05) as port:
        settle(port)
        assert ask(port, b"\xe9", 7) == framed(b"\xe9" + struct.pack(">I", 4242))


def test_timer_rolls_over_through_zero(run_sim: Callable[..., Sim]) -> None:
    """Started 67,296 ticks (~1.08 s) before the rollover, the stream wraps through 0."""
    sim = run_sim("--tcp", "127.0.0.1:0", "--timer-start", str(TIMER_START),
                  "--continuous-preset", "0xC2", "--mode-preset", "2", "--decimation", "10")
    (url,) = sim.endpoints(1)
    data = bytearray()
    records: list[bytes] = []
    with serial.serial_for_url(url, timeout=0.05) as port:
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline:
            data += port.read(4096)
            records = stream_records(bytes(data), 0xC2, C2_LENGTH)
            timers = [timer_of(r) for r in records]
            if any(b < a for a, b in itertools.pairwise(timers)) and timers[-1] > 1000:
                break
    timers = [timer_of(r) for r in records]
    assert len(timers) > 20
    assert timers[0] >= TIMER_START
    assert any(b < a for a, b in itertools.pairwise(timers)), "no rollover within 3 s"
    assert {(b - a) % WRAP for a, b in itertools.pairwise(timers)} == {625}


@pytest.mark.parametrize("timer_ms", [1, 16])
def test_usb_serial_delivers_adapter_packets_that_end_mid_record(
        run_sim: Callable[..., Sim], timer_ms: int) -> None:
    """Behind an adapter the host reads 62-byte packets (a 16 ms timer never runs out
    at 100 Hz of 79-byte records: a packet fills first) or whatever each 1 ms frame
    carried (1 ms timer); either way reads end mid-record, and the stream is intact."""
    sim = run_sim("--pty", "--usb-serial", "--latency-timer", str(timer_ms),
                  "--continuous-preset", "0xCC", "--mode-preset", "2", "--decimation", "10")
    (path,) = sim.endpoints(1)
    chunks: list[bytes] = []
    with serial.Serial(path, 115_200, timeout=0.05) as port:
        deadline = time.monotonic() + 20.0
        while sum(map(len, chunks)) < 60 * CC_LENGTH and time.monotonic() < deadline:
            if select.select([port.fileno()], [], [], 0.5)[0]:
                chunks.append(os.read(port.fileno(), 4096))
    data = b"".join(chunks)
    records = stream_records(data, 0xCC, CC_LENGTH)
    assert len(records) >= 50, f"{len(data)} bytes, {len(records)} records"
    start = data.index(records[0])
    ends = np.cumsum([len(c) for c in chunks])
    assert np.mean((ends[ends > start] - start) % CC_LENGTH != 0) > 0.5
    if timer_ms == 16:  # every packet after the first was a full one
        whole = sum(len(c) for c in chunks[1:] if len(c) % 62 == 0)
        assert whole >= 0.8 * sum(len(c) for c in chunks[1:]), [len(c) for c in chunks]


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_signal_stops_it_with_a_summary(run_sim: Callable[..., Sim],
                                        sig: signal.Signals) -> None:
    sim = run_sim("--tcp", "127.0.0.1:0", "--serial", "SIGTEST")
    (url,) = sim.endpoints(1)
    with serial.serial_for_url(url, timeout=0.05) as port:
        settle(port)
        assert intact(ask(port, b"\xc2", C2_LENGTH), 0xC2, C2_LENGTH)
    code, stderr = sim.stop(sig)
    assert code == 0, stderr
    assert "Traceback" not in stderr
    assert re.search(r"SIGTEST: 1 record sent", stderr), stderr


def test_state_file_keeps_the_mode_preset(run_sim: Callable[..., Sim], tmp_path: Path) -> None:
    """0xD5 writes non-volatile memory: a second run on the same --state file still has it."""
    state = tmp_path / "unit.json"
    first = run_sim("--tcp", "127.0.0.1:0", "--state", str(state))
    (url,) = first.endpoints(1)
    with serial.serial_for_url(url, timeout=0.05) as port:
        settle(port)
        assert ask(port, b"\xd5\xba\x89\x03", 4) == framed(b"\xd5\x03")
    assert first.stop()[0] == 0
    assert state.exists()
    second = run_sim("--tcp", "127.0.0.1:0", "--state", str(state))
    (url,) = second.endpoints(1)
    with serial.serial_for_url(url, timeout=0.05) as port:
        settle(port)
        assert ask(port, b"\xd5\xba\x89\x00", 4) == framed(b"\xd5\x03")
        assert ask(port, b"\xd4\xa3\x47\x00", 4) == framed(b"\xd4\x03"), "woke in idle"
    assert second.stop()[0] == 0


@pytest.mark.parametrize("args", [
    ("--pty", "--tcp", "127.0.0.1:0"),
    (),
    ("--tcp", "127.0.0.1:0", "--flags", "0x1FFFF"),
], ids=["both-transports", "no-transport", "flags"])
def test_bad_arguments_fail_with_one_line(args: tuple[str, ...]) -> None:
    done = CliRunner().invoke(app, ["sim", *args])  # no unit starts when an option is bad
    assert done.exit_code != 0
    assert done.stdout == ""
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, done.stderr
    assert "error" in lines[0].lower()
    assert "Traceback" not in done.stderr


def test_help_mentions_every_option() -> None:
    group = typer.main.get_command(app)
    assert isinstance(group, typer.core.TyperGroup)
    command = group.commands["sim"]
    declared = {opt for param in command.params for opt in param.opts if opt.startswith("--")}
    done = CliRunner().invoke(app, ["sim", "--help"], env={"COLUMNS": "80"})
    assert done.exit_code == 0, done.stderr
    missing = [opt for opt in sorted(declared | set(DOCUMENTED_OPTIONS))
               if not re.search(re.escape(opt) + r"(?![\w-])", done.stdout)]
    assert not missing, done.stdout


def run_in_process(*args: str) -> tuple[int, str]:
    """`gx3 sim ARGS` in this process (no unit starts when an option is bad): code, stderr."""
    result = CliRunner().invoke(app, ["sim", *args])
    assert not isinstance(result.exception, Exception) or isinstance(
        result.exception, SystemExit), result.exception
    return result.exit_code, result.stderr


def state_file(tmp_path: Path, text: str) -> str:
    path = tmp_path / "unit.json"
    path.write_text(text)
    return str(path)


BAD_OPTIONS: list[tuple[tuple[str, ...], str]] = [
    (("--firmware", "-5"), "--firmware"),
    (("--firmware", "4294967296"), "--firmware"),
    (("--flags", "0x1FFFF"), "--flags"),
    (("--flags", "bits"), "--flags"),
    (("--model-name", "Modèle"), "--model-name"),
    (("--model-name", "M" * 17), "--model-name"),
    (("--model-number", "6225\n4220"), "--model-number"),
    (("--serial", "ABCDEFGHIJKLMNO", "--units", "2"), "--serial"),
    (("--seed", "-1"), "--seed"),
    (("--clock-ppm", "nan"), "--clock-ppm"),
    (("--clock-ppm", "1e9"), "--clock-ppm"),
    (("--flip-rate", "-0.1"), "--flip-rate"),
    (("--drop-rate", "1.5"), "--drop-rate"),
    (("--stall-every", "-1"), "--stall-every"),
    (("--stall-for", "inf"), "--stall-for"),
    (("--disconnect-every", "nan"), "--disconnect-every"),
    (("--disconnect-for", "-2"), "--disconnect-for"),
    (("--duration", "nan"), "--duration"),
    (("--duration", "-1"), "--duration"),
    (("--units", "0"), "--units"),
    (("--decimation", "0"), "--decimation"),
    (("--mode-preset", "4"), "--mode-preset"),
    (("--timer-start", "-1"), "--timer-start"),
    (("--continuous-preset", "0x01"), "--continuous-preset"),
    (("--baud", "9600"), "--baud"),
    (("--noise-gyro", "-1"), "--noise-gyro"),
    (("--hard-iron", "0.1,0.2"), "--hard-iron"),
    (("--hard-iron", "0.1,x,0"), "--hard-iron"),
    (("--hard-iron", "nan,0,0"), "--hard-iron"),
    (("--soft-iron", "1,0,0,0,1,0,0,0"), "--soft-iron"),
    (("--soft-iron", "1,0,0,0,0,0,0,0,1"), "--soft-iron"),
    (("--static", "--tumble"), "--static/--tumble"),
    (("--usb", "--usb-serial"), "--usb/--usb-serial"),
    (("--latency-timer", "16"), "--latency-timer"),
    (("--usb-serial", "--latency-timer", "0"), "--latency-timer"),
    (("--mount", "180,0,90"), "--mount"),
    (("--lever-arm", "0.3,0,0"), "--lever-arm"),
    (("--body", "--mount", "400,0,0"), "--mount"),
    (("--body", "--mount", "0,0,0", "--mount", "0,0,0"), "--mount"),
    (("--body", "--lever-arm", "0.3,0"), "--lever-arm"),
    (("--body", "--tumble"), "--body/--tumble"),
    (("--link-latency", "-1"), "--link-latency"),
    (("--link-latency", "1", "--link-latency", "2"), "--link-latency"),
]


@pytest.mark.parametrize(("args", "option"), BAD_OPTIONS,
                         ids=[" ".join(args) for args, _ in BAD_OPTIONS])
def test_every_bad_option_is_named_in_one_line(args: tuple[str, ...], option: str) -> None:
    code, stderr = run_in_process("--tcp", "127.0.0.1:0", *args)
    assert code == 2
    assert stderr.count("\n") == 1 and stderr.startswith(f"error: {option}: "), stderr


@pytest.mark.parametrize("tcp", ["127.0.0.1:99999", "127.0.0.1:65535 --units 2", "nohost"])
def test_a_tcp_port_out_of_range_is_refused(tcp: str) -> None:
    address, *more = tcp.split()
    code, stderr = run_in_process("--tcp", address, *more)
    assert code == 2 and stderr.startswith("error: --tcp: ") and stderr.count("\n") == 1, stderr


BAD_STATE = {
    "not-json": "{",
    "not-an-object": "[1, 2]",
    "unknown-field": '{"mode_presett": 1}',
    "mode-preset": '{"mode_preset": 7}',
    "continuous-preset": '{"continuous_preset": 1}',
    "decimation": '{"sampling": {"decimation": 0}}',
    "filter-width": '{"sampling": {"filter_width": 40}}',
    "flags": '{"sampling": {"flags": 65536}}',
    "float-decimation": '{"sampling": {"decimation": 2.5}}',
    "sampling-shape": '{"sampling": [10]}',
    "unknown-sampling-field": '{"sampling": {"rate": 10}}',
    "baud": '{"baud": 9600}',
    "accel-bias-length": '{"accel_bias": [1, 2]}',
    "gyro-bias-nan": '{"gyro_bias": [NaN, 0, 0]}',
    "gyro-bias-text": '{"gyro_bias": ["a", 0, 0]}',
    "eeprom-address": '{"eeprom": {"4096": 1}}',
    "eeprom-value": '{"eeprom": {"1": 70000}}',
    "eeprom-key": '{"eeprom": {"one": 1}}',
}


@pytest.mark.parametrize("text", BAD_STATE.values(), ids=BAD_STATE.keys())
def test_a_state_file_of_the_wrong_shape_or_range_is_refused(tmp_path: Path, text: str) -> None:
    code, stderr = run_in_process("--tcp", "127.0.0.1:0", "--state", state_file(tmp_path, text))
    assert code == 2
    assert stderr.startswith("error: --state: ") and stderr.count("\n") == 1, stderr


def test_a_state_path_that_cannot_be_written_is_refused(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("")
    for path in (tmp_path / "file" / "unit.json", tmp_path):
        code, stderr = run_in_process("--tcp", "127.0.0.1:0", "--state", str(path))
        assert code == 2 and stderr.startswith("error: --state: "), stderr


def test_link_is_refused_with_tcp_and_never_replaces_a_file(tmp_path: Path) -> None:
    code, stderr = run_in_process("--tcp", "127.0.0.1:0", "--link", str(tmp_path / "imu"))
    assert code == 2 and stderr.startswith("error: --link: "), stderr
    precious = tmp_path / "notes.txt"
    precious.write_text("keep me")
    code, stderr = run_in_process("--pty", "--link", str(precious))
    assert code == 2 and stderr.startswith("error: --link: ") and "pty" not in stderr.split(
        ":")[1], stderr
    assert precious.read_text() == "keep me"
    code, stderr = run_in_process("--pty", "--link", str(tmp_path / "missing" / "imu"))
    assert code == 2 and stderr.startswith("error: --link: cannot make "), stderr


def test_help_names_no_command_that_does_not_exist() -> None:
    result = CliRunner().invoke(app, ["sim", "--help"], env={"COLUMNS": "200"})
    assert result.exit_code == 0
    assert "gx3 bridge" not in result.output
    assert "what a serial program opens" in " ".join(result.output.split())
