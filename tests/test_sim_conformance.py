"""The emulator against the DCP manual, seen only through a serial port.

Commands and expected replies are built by hand from the manual's byte tables
(``struct`` and a hand-written checksum), never through ``bridge.protocol``, so a
misreading shared by the codec and the emulator cannot pass unseen. Where a reply
carries a timer or sensor values that cannot be predicted to the bit, the test
checks its frame and the physics of a unit held still instead.
"""

from __future__ import annotations

import itertools
import math
import struct
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import astuple, dataclass, replace

import numpy as np
import pytest
import serial

from bridge.sim.motion import MotionConfig
from bridge.sim.serve import Simulator
from bridge.sim.unit import UnitConfig

TRANSPORTS = ("pty", "tcp")
TICKS_PER_S = 62_500
WRAP = 1 << 32
ERROR_REPLY = b"\x21\x00\x21"
FIRMWARE = 1127
ID_STRINGS = ("6225-4220", "CONF0001", "3DM-GX3-25", "5g 300d/s", "LOT42")
FIELD_GAUSS = np.array([0.2, 0.0, 0.45])
CONFIG = UnitConfig(
    model_number=ID_STRINGS[0], serial=ID_STRINGS[1], model_name=ID_STRINGS[2],
    options=ID_STRINGS[3], lot=ID_STRINGS[4], firmware=FIRMWARE,
    motion=MotionConfig(seed=7, static=True, earth_field_gauss=tuple(FIELD_GAUSS),
                        temperature_c=25.0),
)

#: Data records from the Command Reference: the struct codes of the fields between
#: the echo byte and the timer, and the reply length the byte table gives.
RECORDS: dict[int, tuple[str, int]] = {
    0xC1: ("6f", 31), 0xC2: ("6f", 31), 0xC3: ("6f", 31), 0xC5: ("9f", 43),
    0xC6: ("9f", 43), 0xC7: ("3f", 19), 0xC8: ("15f", 67), 0xCB: ("9f", 43),
    0xCC: ("18f", 79), 0xCE: ("3f", 19), 0xCF: ("6f", 31), 0xD1: ("4H", 15),
    0xD2: ("9f", 43), 0xD3: ("9f", 43), 0xDF: ("4f", 23),
}
ORIENTATION_BIT = 1 << 0
LITTLE_ENDIAN_BIT = 1 << 4
DISABLE_MAG_BIT = 1 << 8
GRAVITY_BIT = 1 << 11
QUATERNION_BIT = 1 << 12


def hexid(code: int) -> str:
    return f"0x{code:02X}"


# --- frames, by the manual's "Calculating The Checksum" ------------------------------------
def checksum(data: bytes) -> bytes:
    """16-bit wrapping sum of every preceding byte, sent big-endian."""
    total = 0
    for byte in data:
        total = (total + byte) & 0xFFFF
    return struct.pack(">H", total)


def framed(body: bytes) -> bytes:
    """A whole reply: echo byte and fields, then their checksum."""
    return body + checksum(body)


def assert_frame(reply: bytes, code: int, length: int) -> None:
    """Length, echo byte and checksum of one reply."""
    assert len(reply) == length, f"{hexid(code)}: {len(reply)} of {length} bytes: {reply.hex()}"
    assert reply[0] == code, f"{hexid(code)}: echo byte is {hexid(reply[0])}"
    assert reply[-2:] == checksum(reply[:-2]), f"{hexid(code)}: bad checksum in {reply.hex()}"


def timer_of(reply: bytes) -> int:
    """The big-endian unsigned timer that precedes the checksum."""
    return int(struct.unpack_from(">I", reply, len(reply) - 6)[0])


def gaps(records: list[bytes]) -> list[int]:
    """Timer steps between successive records, across the rollover."""
    return [(timer_of(b) - timer_of(a)) % WRAP for a, b in itertools.pairwise(records)]


def find_records(data: bytes, code: int, length: int) -> list[bytes]:
    """The longest run of back-to-back intact records of ``code`` anywhere in ``data``."""
    best: list[bytes] = []
    for start in range(len(data) - length + 1):
        run = []
        i = start
        while i + length <= len(data):
            chunk = data[i : i + length]
            if chunk[0] != code or chunk[-2:] != checksum(chunk[:-2]):
                break
            run.append(chunk)
            i += length
        if len(run) > len(best):
            best = run
    return best


def split_replies(data: bytes, lengths: dict[int, int]) -> list[bytes]:
    """Cut a stream of whole replies by their echo bytes."""
    out = []
    i = 0
    while i < len(data):
        assert data[i] in lengths, f"unexpected byte {hexid(data[i])} at {i} in {data.hex()}"
        out.append(data[i : i + lengths[data[i]]])
        i += lengths[data[i]]
    return out


# --- commands, by the manual's byte tables -----------------------------------------------------
def set_continuous(code: int) -> bytes:
    return bytes((0xC4, 0xC1, 0x29, code))


def write_accel_bias(bias: tuple[float, float, float]) -> bytes:
    return b"\xc9\xb7\x44" + struct.pack(">3f", *bias)


def write_gyro_bias(bias: tuple[float, float, float]) -> bytes:
    return b"\xca\x12\xa5" + struct.pack(">3f", *bias)


def capture_gyro_bias(ms: int) -> bytes:
    return b"\xcd\xc1\x29" + struct.pack(">H", ms)


def transfer(quantity: int) -> bytes:
    return b"\xd0\xc1\x29" + struct.pack(">H", quantity)


def mode(selector: int) -> bytes:
    return bytes((0xD4, 0xA3, 0x47, selector))


def mode_preset(selector: int) -> bytes:
    return bytes((0xD5, 0xBA, 0x89, selector))


def continuous_preset(code: int) -> bytes:
    return bytes((0xD6, 0xC6, 0x6B, code))


def timer(function: int, value: int = 0) -> bytes:
    return b"\xd7\xc1\x29" + struct.pack(">BI", function, value)


def comms(function: int, baud: int = 115_200) -> bytes:
    """0xD9 on UART1 with the port enabled (configuration bit 1)."""
    return b"\xd9\xc3\x55" + struct.pack(">BBIBB", 1, function, baud, 0x02, 0)


def realign(function: int, up: int = 10, north: int = 10) -> bytes:
    """0xDD; up and north are realign times in tenths of a second, 255 to skip."""
    return b"\xdd\x54\x4c" + bytes((function, up, north)) + bytes(4)


def write_word(address: int, value: int) -> bytes:
    return b"\xe4\xc1\x29\x00" + struct.pack(">HH", address, value)


def read_word(address: int) -> bytes:
    return b"\xe5\x00" + struct.pack(">H", address)


def device_id(selector: int) -> bytes:
    return bytes((0xEA, selector))


FIRMWARE_VERSION = b"\xe9"
STATIONARY_TEST = b"\xda"
STOP = b"\xfa\x75\xb4"
RESET = b"\xfe\x9e\x3a"
FIRMWARE_REPLY = framed(b"\xe9" + struct.pack(">I", FIRMWARE))


@dataclass(frozen=True)
class Sampling:
    """The 0xDB settings in wire order."""

    decimation: int
    flags: int
    filter_width: int
    mag_filter_width: int
    up_compensation: int
    north_compensation: int

    def pack(self) -> bytes:
        return struct.pack(">HHBBHH", *astuple(self))

    def command(self, function: int) -> bytes:
        return b"\xdb\xa8\xb9" + bytes((function,)) + self.pack() + bytes(6)


#: Parameters a 0xDB read (function 0) carries; the unit ignores them.
ANY_SAMPLING = Sampling(10, 0x0003, 15, 17, 10, 10)


# --- the host -------------------------------------------------------------------------------
class Host:
    """The host's end of one serial port: send commands, read replies against deadlines."""

    def __init__(self, port: serial.SerialBase) -> None:
        self.port = port

    def send(self, data: bytes) -> None:
        self.port.write(data)
        self.port.flush()

    def read(self, n: int, timeout: float = 1.0) -> bytes:
        """Up to ``n`` bytes, waiting at most ``timeout`` seconds for all of them."""
        deadline = time.monotonic() + timeout
        out = bytearray()
        while len(out) < n and time.monotonic() < deadline:
            out += self.port.read(n - len(out))
        return bytes(out)

    def listen(self, seconds: float) -> bytes:
        """Everything that arrives within ``seconds``."""
        deadline = time.monotonic() + seconds
        out = bytearray()
        while time.monotonic() < deadline:
            out += self.port.read(4096)
        return bytes(out)

    def ask(self, command: bytes, length: int, timeout: float = 5.0) -> bytes:
        """Send one command and read its fixed-length reply, all of it or fail."""
        self.send(command)
        reply = self.read(length, timeout)
        assert len(reply) == length, (
            f"{hexid(command[0])}: {len(reply)} of {length} bytes: {reply.hex()}")
        return reply

    def ask_settled(self, command: bytes, length: int, within: float = 10.0) -> bytes:
        """Ask until answered: a unit settling after a wake-up or reset drops what it hears."""
        deadline = time.monotonic() + within
        asked = 0
        while True:
            self.send(command)
            asked += 1
            reply = self.read(length, timeout=0.25)
            if reply or time.monotonic() > deadline:
                break
        reply += self.read(length - len(reply), timeout=5.0)
        if asked > 1:  # a busy machine may answer an earlier try late: drop its echo
            self.drain(settle=0.5)
        assert len(reply) == length, f"{hexid(command[0])}: {len(reply)} of {length} bytes"
        return reply

    def drain(self, settle: float = 0.03) -> None:
        """Drop what arrives within ``settle`` seconds and anything already unread."""
        time.sleep(settle)
        self.port.reset_input_buffer()

    def record(self, code: int, little_endian: bool = False) -> tuple[np.ndarray, int]:
        """Poll one data record: its values (floats or integers) and its timer."""
        fmt, length = RECORDS[code]
        reply = self.ask(bytes((code,)), length)
        assert_frame(reply, code, length)
        values = struct.unpack_from(("<" if little_endian else ">") + fmt, reply, 1)
        return np.array(values, dtype=np.float64), timer_of(reply)

    def timer(self) -> tuple[float, int, float]:
        """The unit's timer, bracketed by the host times of the request and of the reply."""
        before = time.monotonic()
        reply = self.ask(timer(0), 7)
        after = time.monotonic()
        assert_frame(reply, 0xD7, 7)
        return before, timer_of(reply), after

    def sampling(self, function: int = 0, settings: Sampling = ANY_SAMPLING) -> Sampling:
        """Send 0xDB and return the settings the reply reports."""
        reply = self.ask(settings.command(function), 19)
        assert_frame(reply, 0xDB, 19)
        return Sampling(*struct.unpack_from(">HHBBHH", reply, 1))

    @contextmanager
    def sampling_kept(self) -> Iterator[Sampling]:
        """The current 0xDB settings, put back however the test ends."""
        saved = self.sampling()
        try:
            yield saved
        finally:
            self.sampling(1, saved)


@contextmanager
def serve(transport: str, config: UnitConfig = CONFIG) -> Iterator[Host]:
    """One unit on ``transport`` with a host port open on it; both closed on exit."""
    with Simulator([config], transport) as sim:
        endpoint = sim.endpoints[0]
        if transport == "pty":
            port = serial.Serial(endpoint, 115_200, timeout=0.05)
        else:
            port = serial.serial_for_url(endpoint, timeout=0.05)
        try:
            host = Host(port)
            host.ask_settled(FIRMWARE_VERSION, 7)  # bytes sent while it powers up are lost
            yield host
        finally:
            port.close()


@pytest.fixture(scope="module", params=TRANSPORTS)
def shared(request: pytest.FixtureRequest) -> Iterator[Host]:
    """One unit per transport for the tests that leave its state as they found it."""
    with serve(request.param) as host:
        yield host


@pytest.fixture
def host(shared: Host) -> Iterator[Host]:
    """The shared unit, handed over with nothing unread and left not streaming."""
    shared.port.reset_input_buffer()
    yield shared
    shared.send(STOP)
    shared.drain(0.01)


@pytest.fixture(params=TRANSPORTS)
def transport(request: pytest.FixtureRequest) -> str:
    """For tests that run a unit of their own: stored settings, resets, special configs."""
    return str(request.param)


def still_gravity(m: np.ndarray) -> np.ndarray:
    """Accel of a still unit: specific force -g, g = +z (down) in NED, so M·(0, 0, -1)."""
    return -m[:, 2]


def orientation(host: Host) -> np.ndarray:
    """M from 0xC5, row-major as the manual sends it."""
    values, _ = host.record(0xC5)
    return values.reshape(3, 3)


# --- the test's own tables --------------------------------------------------------------------
@pytest.mark.parametrize("code", sorted(RECORDS), ids=hexid)
def test_record_table_matches_manual_lengths(code: int) -> None:
    """Echo byte + fields + 4-byte timer + 2-byte checksum adds up to the manual's length."""
    fmt, length = RECORDS[code]
    assert 1 + struct.calcsize(">" + fmt) + 4 + 2 == length


def test_error_reply_checksum_is_its_own_byte() -> None:
    """The manual: the error reply's checksum is always 0x00 0x21."""
    assert framed(b"\x21") == ERROR_REPLY


# --- data records -----------------------------------------------------------------------------
@pytest.mark.parametrize("code", sorted(RECORDS), ids=hexid)
def test_data_record_is_framed_and_finite(host: Host, code: int) -> None:
    values, _ = host.record(code)
    if code == 0xDF:
        assert np.isnan(values).all(), "quaternion is off by default"
    else:
        assert np.isfinite(values).all()


def test_raw_outputs_are_17_bit_codes(host: Host) -> None:
    values, _ = host.record(0xC1)
    assert ((values >= 0) & (values <= 131_071)).all()


def test_still_unit_feels_one_g_and_no_rotation(host: Host) -> None:
    values, _ = host.record(0xC2)
    assert np.linalg.norm(values[:3]) == pytest.approx(1.0, abs=1e-3)
    assert np.abs(values[3:]).max() < 1e-6


def test_orientation_matrix_is_a_rotation_consistent_with_gravity(host: Host) -> None:
    """M is orthonormal and, with v_local = M·v_earth, maps gravity onto Accel."""
    m = orientation(host)
    assert m @ m.T == pytest.approx(np.eye(3), abs=1e-5)
    assert np.linalg.det(m) == pytest.approx(1.0, abs=1e-5)
    values, _ = host.record(0xC8)
    assert values[:3] == pytest.approx(still_gravity(m), abs=1e-5)
    assert values[3:6] == pytest.approx(np.zeros(3), abs=1e-6)
    assert values[6:].reshape(3, 3) == pytest.approx(m, abs=1e-6)


def test_update_matrix_of_still_unit_is_identity(host: Host) -> None:
    values, _ = host.record(0xC6)
    assert values.reshape(3, 3) == pytest.approx(np.eye(3), abs=1e-6)


def test_magnetometer_records_see_the_earth_field(host: Host) -> None:
    m = orientation(host)
    field = m @ FIELD_GAUSS
    values, _ = host.record(0xC7)
    assert values == pytest.approx(field, abs=1e-5)
    values, _ = host.record(0xCB)
    assert values[:3] == pytest.approx(still_gravity(m), abs=1e-5)
    assert values[6:9] == pytest.approx(field, abs=1e-5)
    values, _ = host.record(0xCC)
    assert values[:3] == pytest.approx(still_gravity(m), abs=1e-5)
    assert values[6:9] == pytest.approx(field, abs=1e-5)
    assert values[9:].reshape(3, 3) == pytest.approx(m, abs=1e-6)


def test_stabilised_record_of_still_unit_equals_the_measured_one(host: Host) -> None:
    """0xD2: StabAccel equals Accel and StabMag equals Magnetometer when nothing moves."""
    m = orientation(host)
    values, _ = host.record(0xD2)
    assert values[:3] == pytest.approx(still_gravity(m), abs=1e-5)
    assert values[3:6] == pytest.approx(np.zeros(3), abs=1e-6)
    assert values[6:9] == pytest.approx(m @ FIELD_GAUSS, abs=1e-5)


def test_stabilised_accel_follows_a_written_accel_bias(host: Host) -> None:
    """AccelBias feeds "all on-board filtering that uses Accel", and a still unit's StabAccel
    equals Accel: after 0xC9 and a fast 0xDD up realignment they point the same way."""
    try:
        host.ask(write_accel_bias((0.0625, -0.0625, 0.0)), 19)
        host.send(realign(0, up=1, north=255))
        assert_frame(host.read(7), 0xDD, 7)
        time.sleep(0.5)
        accel, _ = host.record(0xC2)
        stab, _ = host.record(0xD2)
        cosine = accel[:3] @ stab[:3] / np.linalg.norm(accel[:3]) / np.linalg.norm(stab[:3])
        assert math.degrees(math.acos(min(1.0, cosine))) < 0.5
    finally:
        host.ask(write_accel_bias((0.0, 0.0, 0.0)), 19)


def test_deltas_integrate_over_the_output_period(host: Host) -> None:
    period = host.sampling().decimation / 1000.0
    accel, _ = host.record(0xC2)
    deltas, _ = host.record(0xC3)
    with_mag, _ = host.record(0xD3)
    for values in (deltas, with_mag):
        assert np.abs(values[:3]).max() < 1e-7
        assert values[3:6] == pytest.approx(accel[:3] * period, abs=1e-6)
    assert np.linalg.norm(with_mag[6:9]) == pytest.approx(np.linalg.norm(FIELD_GAUSS), abs=1e-5)


def test_euler_angles_follow_from_m(host: Host) -> None:
    """The manual's "M to Euler" (ZYX): roll, pitch, yaw from M23/M33, -M13, M12/M11."""
    m = orientation(host)
    expected = [math.atan2(m[1, 2], m[2, 2]), math.asin(-m[0, 2]), math.atan2(m[0, 1], m[0, 0])]
    values, _ = host.record(0xCE)
    assert values == pytest.approx(expected, abs=1e-5)
    values, _ = host.record(0xCF)
    assert values[:3] == pytest.approx(expected, abs=1e-5)
    assert np.abs(values[3:]).max() < 1e-6


def test_temperatures_are_12_bit_codes(host: Host) -> None:
    """Four 12-bit A/D codes; the magnetometer one converts (Equation 16) to the set 25 °C."""
    values, _ = host.record(0xD1)
    assert (values < 4096).all()
    celsius = -((3.0 * values[0] / 4096.0) - 1.8583) / 11.67e-3
    assert celsius == pytest.approx(25.0, abs=1.0)


def test_quaternion_is_nan_until_flag_bit_12(host: Host) -> None:
    """0xDF needs 0xDB bit 12 (the 0xDF section's "bit 11" disables gravity compensation)."""
    with host.sampling_kept() as saved:
        values, _ = host.record(0xDF)
        assert np.isnan(values).all()
        host.sampling(1, replace(saved, flags=saved.flags | GRAVITY_BIT))
        values, _ = host.record(0xDF)
        assert np.isnan(values).all()
        host.sampling(1, replace(saved, flags=saved.flags | ORIENTATION_BIT | QUATERNION_BIT))
        q, _ = host.record(0xDF)
        assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-6)
        assert q[0] >= 0
        q0, q1, q2, q3 = q
        from_q = 2 * np.array([
            [q0**2 - 0.5 + q1**2, q1 * q2 + q0 * q3, q1 * q3 - q0 * q2],
            [q1 * q2 - q0 * q3, q0**2 - 0.5 + q2**2, q2 * q3 + q0 * q1],
            [q1 * q3 + q0 * q2, q2 * q3 - q0 * q1, q0**2 - 0.5 + q3**2],
        ])
        assert from_q == pytest.approx(orientation(host), abs=1e-5)


def test_little_endian_flag_swaps_floats_only(host: Host) -> None:
    """0xDB bit 4: floats little-endian; the timer and checksum stay big-endian."""
    with host.sampling_kept() as saved:
        host.sampling(1, replace(saved, flags=saved.flags | LITTLE_ENDIAN_BIT))
        before, _, _ = host.timer()
        values, stamp = host.record(0xC2, little_endian=True)
        _, after, _ = host.timer()
        assert np.linalg.norm(values[:3]) == pytest.approx(1.0, abs=1e-3)
        assert (stamp - before) % WRAP <= (after - before) % WRAP
        codes, _ = host.record(0xD1)
        assert (codes < 4096).all(), "temperatures are integers, not floats"


def test_timer_counts_62500_ticks_per_second(host: Host) -> None:
    """Between two polls the unsigned timer advances by the host time between them."""
    a0, t0, b0 = host.timer()
    time.sleep(0.4)
    a1, t1, b1 = host.timer()
    ticks = (t1 - t0) % WRAP
    assert (a1 - b0) * TICKS_PER_S - 2 <= ticks <= (b1 - a0) * TICKS_PER_S + 2
    before = time.monotonic()
    _, r0 = host.record(0xC2)
    middle = time.monotonic()
    time.sleep(0.1)
    _, r1 = host.record(0xC2)
    after = time.monotonic()
    assert (after - before) * TICKS_PER_S + 2 >= (r1 - r0) % WRAP >= 0.1 * TICKS_PER_S - 2
    assert (r1 - r0) % WRAP >= (after - middle - 1.0) * TICKS_PER_S  # a loaded host's margin


def test_commands_are_answered_in_order(host: Host) -> None:
    """Several commands in one write are buffered and answered one per cycle, in order."""
    host.send(FIRMWARE_VERSION + STATIONARY_TEST + b"\xc2")
    replies = host.read(7 + 7 + 31)
    assert replies[:7] == FIRMWARE_REPLY
    assert_frame(replies[7:14], 0xDA, 7)
    assert_frame(replies[14:], 0xC2, 31)


# --- continuous output ---------------------------------------------------------------------
def test_set_continuous_streams_until_stopped(host: Host) -> None:
    period_ticks = host.sampling().decimation * TICKS_PER_S / 1000
    host.send(set_continuous(0xC2))
    reply = host.read(8)
    assert_frame(reply, 0xC4, 8)
    assert reply[1] == 0xC2
    records = [host.read(31) for _ in range(10)]
    for rec in records:
        assert_frame(rec, 0xC2, 31)
    first = gaps([reply, records[0]])[0]
    assert 0 < first <= period_ticks + TICKS_PER_S / 1000 + 1
    assert gaps(records) == pytest.approx([period_ticks] * 9, abs=1)

    host.send(STOP)
    for rec in split_replies(host.listen(0.1), {0xC2: 31}):
        assert_frame(rec, 0xC2, 31)
    assert host.listen(0.1) == b""
    assert host.ask(mode(0), 4) == framed(b"\xd4\x01")
    assert host.ask(continuous_preset(0), 4) == framed(b"\xd6\x00"), "0xC4 changed the preset"


def test_set_continuous_zero_stops_the_stream(host: Host) -> None:
    host.send(set_continuous(0xC2))
    assert_frame(host.read(8), 0xC4, 8)
    assert_frame(host.read(31), 0xC2, 31)
    host.send(set_continuous(0))
    replies = split_replies(host.listen(0.15), {0xC2: 31, 0xC4: 8})
    assert replies and replies[-1][0] == 0xC4
    for reply in replies:
        assert_frame(reply, reply[0], len(reply))
    assert host.listen(0.1) == b""


def test_mode_continuous_replies_before_the_first_record(transport: str) -> None:
    with serve(transport) as host:
        assert host.ask(mode(2), 4) == framed(b"\xd4\x01"), "factory preset 0: no action"
        assert host.listen(0.05) == b""
        assert host.ask(continuous_preset(0xC2), 4) == framed(b"\xd6\xc2")
        period_ticks = host.sampling().decimation * TICKS_PER_S / 1000
        host.send(mode(2))
        assert host.read(4) == framed(b"\xd4\x02")
        records = [host.read(31) for _ in range(5)]
        for rec in records:
            assert_frame(rec, 0xC2, 31)
        assert gaps(records) == pytest.approx([period_ticks] * 4, abs=1)
        host.send(STOP)
        host.drain()
        assert host.ask(mode(0), 4) == framed(b"\xd4\x01")


# --- settings -------------------------------------------------------------------------------
def test_bias_corrections_are_echoed_and_subtracted(host: Host) -> None:
    accel_bias = (0.125, -0.25, 0.0625)
    gyro_bias = (0.015625, -0.0078125, 0.03125)
    before, _ = host.record(0xC2)
    try:
        reply = host.ask(write_accel_bias(accel_bias), 19)
        assert_frame(reply, 0xC9, 19)
        assert reply[1:13] == struct.pack(">3f", *accel_bias)
        reply = host.ask(write_gyro_bias(gyro_bias), 19)
        assert_frame(reply, 0xCA, 19)
        assert reply[1:13] == struct.pack(">3f", *gyro_bias)
        after, _ = host.record(0xC2)
        assert after[:3] == pytest.approx(before[:3] - accel_bias, abs=1e-6)
        assert after[3:] == pytest.approx(before[3:] - gyro_bias, abs=1e-6)
    finally:
        host.ask(write_accel_bias((0.0, 0.0, 0.0)), 19)
        host.ask(write_gyro_bias((0.0, 0.0, 0.0)), 19)
    restored, _ = host.record(0xC2)
    assert restored == pytest.approx(before, abs=1e-6)


def test_capture_gyro_bias_reports_the_true_bias_after_sampling(transport: str) -> None:
    true_bias = (0.004, -0.003, 0.002)
    config = replace(CONFIG, motion=replace(CONFIG.motion, gyro_bias_rad_s=true_bias))
    with serve(transport, config) as host:
        rates, _ = host.record(0xC2)
        assert rates[3:] == pytest.approx(true_bias, abs=1e-7)
        _, start, _ = host.timer()
        sent = time.monotonic()
        host.send(capture_gyro_bias(200))
        reply = host.read(19, timeout=15.0)
        waited = time.monotonic() - sent
        assert_frame(reply, 0xCD, 19)
        assert waited >= 0.2
        assert struct.unpack_from(">3f", reply, 1) == pytest.approx(true_bias, abs=1e-8)
        assert (timer_of(reply) - start) % WRAP >= 0.2 * TICKS_PER_S
        rates, _ = host.record(0xC2)
        assert np.abs(rates[3:]).max() < 1e-7


def test_transfer_to_nonvolatile_survives_a_reset(transport: str) -> None:
    accel_bias = (0.5, 0.0, -0.25)
    gyro_bias = (0.0, 0.0625, 0.0)
    with serve(transport) as host:
        before, _ = host.record(0xC2)
        host.ask(write_accel_bias(accel_bias), 19)
        host.ask(write_gyro_bias(gyro_bias), 19)
        for quantity in (1, 2, 3):
            reply = host.ask(transfer(quantity), 9)
            assert_frame(reply, 0xD0, 9)
            expected = quantity if quantity in (1, 2) else 0xFFFF
            assert struct.unpack_from(">H", reply, 1)[0] == expected
        host.send(RESET)
        time.sleep(0.1)
        assert_frame(host.ask_settled(timer(0), 7), 0xD7, 7)
        after, _ = host.record(0xC2)
        assert after[:3] == pytest.approx(before[:3] - accel_bias, abs=1e-6)
        assert after[3:] == pytest.approx(before[3:] - gyro_bias, abs=1e-6)


def test_mode_read_idle_active_and_ignored(host: Host) -> None:
    """Idle returns NaN for calculated floats; a mode outside the set changes nothing."""
    assert host.ask(mode(0), 4) == framed(b"\xd4\x01")
    try:
        assert host.ask(mode(3), 4) == framed(b"\xd4\x03")
        assert host.ask(mode(0), 4) == framed(b"\xd4\x03")
        for code in (0xC2, 0xC5, 0xC7, 0xCE):
            values, _ = host.record(code)
            assert np.isnan(values).all(), hexid(code)
        assert host.ask(mode(9), 4) == framed(b"\xd4\x03")
    finally:
        assert host.ask(mode(1), 4) == framed(b"\xd4\x01")
    assert host.ask(mode(9), 4) == framed(b"\xd4\x01")
    values, _ = host.record(0xC2)
    assert np.isfinite(values).all()


def test_sleep_modes_wake_on_any_byte(transport: str) -> None:
    """Sleep wakes into the preset mode; deep sleep also restarts, so the timer restarts."""
    with serve(transport) as host:
        assert host.ask(mode(4), 4) == framed(b"\xd4\x04")
        assert host.listen(0.05) == b""
        host.send(b"\x00")
        time.sleep(0.1)
        assert host.ask_settled(mode(0), 4) == framed(b"\xd4\x01")
        host.ask(timer(1, 0x8000_0000), 7)
        assert host.ask(mode(5), 4) == framed(b"\xd4\x05")
        woke = time.monotonic()
        host.send(b"\x00")
        time.sleep(0.1)
        reply = host.ask_settled(timer(0), 7)
        after = time.monotonic()
        assert_frame(reply, 0xD7, 7)
        assert timer_of(reply) <= (after - woke) * TICKS_PER_S + 1
        assert host.ask(mode(0), 4) == framed(b"\xd4\x01")


def test_mode_preset_read_set_and_ignored(transport: str) -> None:
    with serve(transport) as host:
        assert host.ask(mode_preset(0), 4) == framed(b"\xd5\x01")
        assert host.ask(mode_preset(3), 4) == framed(b"\xd5\x03")
        assert host.ask(mode_preset(7), 4) == framed(b"\xd5\x03")
        assert host.ask(mode_preset(0), 4) == framed(b"\xd5\x03")


def test_continuous_preset_read_set_and_invalid(transport: str) -> None:
    """0 or a value that is not a data command stores nothing and returns the stored value."""
    with serve(transport) as host:
        assert host.ask(continuous_preset(0), 4) == framed(b"\xd6\x00")
        assert host.ask(continuous_preset(0xCB), 4) == framed(b"\xd6\xcb")
        for invalid in (0x01, 0xC4, 0xE9, 0xFF):
            assert host.ask(continuous_preset(invalid), 4) == framed(b"\xd6\xcb"), hexid(invalid)
        assert host.ask(continuous_preset(0), 4) == framed(b"\xd6\xcb")


def test_timer_set_restarts_it_at_the_value(host: Host) -> None:
    """Set close to the rollover: it reads back later having wrapped through 0, unsigned."""
    value = 0xFFFF_F000
    sent = time.monotonic()
    assert host.ask(timer(1, value), 7) == framed(b"\xd7" + struct.pack(">I", value))
    time.sleep(0.2)
    _, stamp, after = host.timer()
    assert stamp < value
    assert 0.2 * TICKS_PER_S <= (stamp - value) % WRAP <= (after - sent) * TICKS_PER_S + 2


def test_comms_settings_read(host: Host) -> None:
    reply = host.ask(comms(0, 0), 10)
    assert_frame(reply, 0xD9, 10)
    assert reply[1:7] == b"\x01" + struct.pack(">I", 115_200) + b"\x02"


@pytest.mark.parametrize("function", [1, 2])
def test_comms_settings_ignore_an_unsupported_baud(host: Host, function: int) -> None:
    reply = host.ask(comms(function, 9600), 10)
    assert_frame(reply, 0xD9, 10)
    assert struct.unpack_from(">I", reply, 2)[0] == 115_200
    assert host.ask(FIRMWARE_VERSION, 7) == FIRMWARE_REPLY


def test_baud_change_reply_arrives_at_the_old_rate(transport: str) -> None:
    """"The response is always given at the current settings": a host at 115200 reads it."""
    with serve(transport) as host:
        host.send(comms(1, 921_600))
        assert host.read(10) == framed(b"\xd9\x01" + struct.pack(">I", 921_600) + b"\x02\x00")


def test_baud_change_moves_the_line_to_the_new_rate() -> None:
    """After 0xD9 921600 a host left at 115200 reads garbage; one at 921600 reads records."""
    with serve("pty") as host:
        period_ticks = host.sampling().decimation * TICKS_PER_S / 1000
        host.send(set_continuous(0xC2))
        assert_frame(host.read(8), 0xC4, 8)
        for _ in range(3):
            assert_frame(host.read(31), 0xC2, 31)
        host.send(comms(1, 921_600))
        deadline = time.monotonic() + 2.0
        while find_records(host.listen(0.1), 0xC2, 31) and time.monotonic() < deadline:
            pass
        garbage = host.listen(0.2)
        assert garbage, "the unit should still be streaming"
        assert not find_records(garbage, 0xC2, 31)
        host.port.baudrate = 921_600
        host.drain()
        records = find_records(host.listen(0.2), 0xC2, 31)
        assert len(records) >= 10
        assert gaps(records) == pytest.approx([period_ticks] * (len(records) - 1), abs=1)
        host.send(STOP)
        host.drain()
        assert host.ask(FIRMWARE_VERSION, 7) == FIRMWARE_REPLY
        host.send(RESET)
        time.sleep(0.1)
        host.port.baudrate = 115_200
        assert host.ask_settled(FIRMWARE_VERSION, 7) == FIRMWARE_REPLY, "function 1 is temporary"


def test_stationary_test_flags_of_an_awake_unit(host: Host) -> None:
    """Bit 0 (3 V supply) and bit 3 (system tick) are the flags the manual names."""
    reply = host.ask(STATIONARY_TEST, 7)
    assert_frame(reply, 0xDA, 7)
    flags = struct.unpack_from(">I", reply, 1)[0]
    assert flags & 0b1001 == 0b1001


def test_stationary_test_in_idle_keeps_3v_and_tick_flags(host: Host) -> None:
    """Only the 5 V flag drops in idle; the 3 V supply and the system tick still run."""
    try:
        assert host.ask(mode(3), 4) == framed(b"\xd4\x03")
        reply = host.ask(STATIONARY_TEST, 7)
        assert_frame(reply, 0xDA, 7)
        assert struct.unpack_from(">I", reply, 1)[0] & 0b1001 == 0b1001
    finally:
        host.ask(mode(1), 4)


def test_sampling_settings_read_gives_manual_defaults(host: Host) -> None:
    settings = host.sampling()
    assert 1 <= settings.decimation <= 1000
    assert replace(settings, decimation=10) == Sampling(10, 0x0003, 15, 17, 10, 10)


def test_sampling_settings_set_and_read_back(host: Host) -> None:
    wanted = Sampling(20, 0x0003, 8, 9, 30, 40)
    with host.sampling_kept() as saved:
        assert host.sampling(1, wanted) == wanted
        assert host.sampling() == wanted
    assert host.sampling() == saved


@pytest.mark.parametrize(("sent", "clamped"), [
    (Sampling(0, 0x0002, 0, 0, 0, 0), Sampling(1, 0x0002, 1, 1, 1, 1)),
    (Sampling(5000, 0x0003, 99, 200, 5000, 65535), Sampling(1000, 0x0003, 32, 32, 1000, 1000)),
], ids=["below", "above"])
def test_sampling_settings_are_clamped_into_range(host: Host, sent: Sampling,
                                                  clamped: Sampling) -> None:
    with host.sampling_kept():
        assert host.sampling(1, sent) == clamped
        assert host.sampling() == clamped


def test_sampling_settings_function_3_is_silent_but_applies(host: Host) -> None:
    with host.sampling_kept() as saved:
        host.send(replace(saved, decimation=25).command(3))
        assert host.listen(0.1) == b""
        assert host.sampling().decimation == 25


def test_magnetometer_off_gives_nan(host: Host) -> None:
    with host.sampling_kept() as saved:
        host.sampling(1, replace(saved, flags=saved.flags | DISABLE_MAG_BIT))
        for code in (0xC7, 0xCB):
            values, _ = host.record(code)
            assert np.isnan(values[-3:]).all(), hexid(code)


def test_realign_replies_with_function_0_only(host: Host) -> None:
    assert_frame(host.ask(realign(0), 7), 0xDD, 7)
    host.send(realign(3))
    assert host.listen(0.1) == b""
    assert host.ask(FIRMWARE_VERSION, 7) == FIRMWARE_REPLY


def test_eeprom_user_words_are_written_and_others_ignored(host: Host) -> None:
    for address, value in ((0x0010, 0xBEEF), (0x0420, 0x1234)):
        assert host.ask(write_word(address, value), 5) == framed(b"\xe4" + struct.pack(">H", value))
        assert host.ask(read_word(address), 5) == framed(b"\xe5" + struct.pack(">H", value))
    for address in (0x00F0, 0x0430, 0x0800):
        reply = host.ask(write_word(address, 0xDEAD), 5)
        assert_frame(reply, 0xE4, 5)
        assert reply[1:3] != b"\xde\xad"
        reply = host.ask(read_word(address), 5)
        assert_frame(reply, 0xE5, 5)
        assert reply[1:3] != b"\xde\xad"


def test_firmware_version(host: Host) -> None:
    assert host.ask(FIRMWARE_VERSION, 7) == FIRMWARE_REPLY


@pytest.mark.parametrize("selector", range(5))
def test_device_id_strings(host: Host, selector: int) -> None:
    reply = host.ask(device_id(selector), 20)
    assert_frame(reply, 0xEA, 20)
    assert reply[1] == selector
    text = reply[2:18]
    assert all(0x20 <= b < 0x7F or b == 0 for b in text)
    assert text.decode("ascii").strip(" \x00") == ID_STRINGS[selector]


def test_stop_and_firmware_update_send_nothing(host: Host) -> None:
    """0xFA and 0xFD are "(no reply)"; the unit keeps answering afterwards."""
    host.send(STOP)
    host.send(b"\xfd")
    assert host.listen(0.1) == b""
    assert host.ask(FIRMWARE_VERSION, 7) == FIRMWARE_REPLY


def test_device_reset_keeps_stored_settings_only(transport: str) -> None:
    """0xFE: no reply; after settling the timer restarts and volatile settings are gone."""
    stored = Sampling(20, 0x0003, 15, 17, 10, 10)
    volatile = Sampling(50, 0x0003, 8, 9, 30, 40)
    with serve(transport) as host:
        assert host.sampling(2, stored) == stored
        assert host.sampling(1, volatile) == volatile
        assert host.ask(mode_preset(3), 4) == framed(b"\xd5\x03")
        assert host.ask(continuous_preset(0xCB), 4) == framed(b"\xd6\xcb")
        before, _ = host.record(0xC2)
        host.ask(write_accel_bias((0.5, 0.5, 0.5)), 19)
        host.ask(timer(1, 3_000_000_000), 7)
        sent = time.monotonic()
        host.send(RESET)
        assert host.listen(0.05) == b""
        time.sleep(0.05)
        reply = host.ask_settled(timer(0), 7)
        after = time.monotonic()
        assert_frame(reply, 0xD7, 7)
        assert timer_of(reply) <= (after - sent) * TICKS_PER_S + 1
        assert host.sampling() == stored
        assert host.ask(mode_preset(0), 4) == framed(b"\xd5\x03")
        assert host.ask(continuous_preset(0), 4) == framed(b"\xd6\xcb")
        assert host.ask(mode(0), 4) == framed(b"\xd4\x03"), "wakes in the preset mode"
        assert host.ask(mode(1), 4) == framed(b"\xd4\x01")
        after_reset, _ = host.record(0xC2)
        assert after_reset == pytest.approx(before, abs=1e-6), "volatile accel bias survived"


CONFIRMED: dict[str, bytes] = {
    "0xC4": set_continuous(0xC2),
    "0xC9": write_accel_bias((0.5, 0.5, 0.5)),
    "0xCA": write_gyro_bias((0.5, 0.5, 0.5)),
    "0xCD": capture_gyro_bias(100),
    "0xD0": transfer(1),
    "0xD4": mode(3),
    "0xD5": mode_preset(3),
    "0xD6": continuous_preset(0xCB),
    "0xD7": timer(1, 12_345),
    "0xD9": comms(1, 921_600),
    "0xDB": Sampling(20, 0x0003, 8, 9, 30, 40).command(1),
    "0xDD": realign(0),
    "0xE4": write_word(0x0020, 0x5555),
    "0xFA": STOP,
    "0xFE": RESET,
}


@pytest.mark.parametrize("position", [1, 2], ids=["byte2", "byte3"])
@pytest.mark.parametrize("name", sorted(CONFIRMED))
def test_wrong_confirmation_gets_the_error_reply_only(host: Host, name: str,
                                                      position: int) -> None:
    """Exactly 21 00 21, nothing changes: the next command is answered at once, as before."""
    bad = bytearray(CONFIRMED[name])
    bad[position] ^= 0xFF
    host.send(bytes(bad) + FIRMWARE_VERSION)
    assert host.read(len(ERROR_REPLY) + len(FIRMWARE_REPLY)) == ERROR_REPLY + FIRMWARE_REPLY
    assert host.listen(0.02) == b""
