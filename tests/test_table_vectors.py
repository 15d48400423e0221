"""Byte vectors transcribed by hand from the manual's Command Reference.

Every expected byte string here is built with ``struct`` from the manual's byte
tables and a checksum summed in the test, never with the codec's encoder, so a
wrong layout in ``table.py`` cannot agree with itself.
"""

from __future__ import annotations

import struct
from typing import Any

import numpy as np
import pytest

from bridge.exceptions import ProtocolError
from bridge.protocol.codec import checksum, decode_block, encode_command, encode_reply
from bridge.protocol.framer import Framer
from bridge.protocol.table import (
    COMMANDS,
    DATA_CODES,
    ERROR_CODE,
    ERROR_REPLY,
    REPLIES,
    Flag,
    Mode,
)


def frame(code: int, payload: bytes) -> bytes:
    """Echo byte, payload, then the manual's checksum: 16-bit sum of all bytes, big-endian."""
    body = bytes((code,)) + payload
    return body + struct.pack(">H", sum(body) % 65536)


def decode_one(raw: bytes, little_endian: bool = False) -> dict[str, Any]:
    """Decode one reply through the columnar decoder and the per-record dict view."""
    block = np.frombuffer(raw, np.uint8).reshape(1, -1)
    columns = decode_block(raw[0], block, little_endian)
    return {name: col[0] for name, col in columns.items()}


# The Command Set Summary (Table 2) of the manual.
MANUAL_COMMANDS = {
    0xC1, 0xC2, 0xC3, 0xC4, 0xC5, 0xC6, 0xC7, 0xC8, 0xC9, 0xCA, 0xCB, 0xCC, 0xCD, 0xCE, 0xCF,
    0xD0, 0xD1, 0xD2, 0xD3, 0xD4, 0xD5, 0xD6, 0xD7, 0xD9, 0xDA, 0xDB, 0xDD, 0xDF,
    0xE4, 0xE5, 0xE9, 0xEA, 0xFA, 0xFD, 0xFE,
}

MANUAL_DATA_CODES = {
    0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC8, 0xCB, 0xCC, 0xCE, 0xCF, 0xD1, 0xD2, 0xD3, 0xDF,
}

# Reply lengths read off the last "Bytes n-m Checksum" row of each reply table.
MANUAL_REPLY_LENGTHS = {
    0xC1: 31, 0xC2: 31, 0xC3: 31, 0xC4: 8, 0xC5: 43, 0xC6: 43, 0xC7: 19, 0xC8: 67,
    0xC9: 19, 0xCA: 19, 0xCB: 43, 0xCC: 79, 0xCD: 19, 0xCE: 19, 0xCF: 31, 0xD0: 9,
    0xD1: 15, 0xD2: 43, 0xD3: 43, 0xD4: 4, 0xD5: 4, 0xD6: 4, 0xD7: 7, 0xD9: 10,
    0xDA: 7, 0xDB: 19, 0xDD: 7, 0xDF: 23, 0xE4: 5, 0xE5: 5, 0xE9: 7, 0xEA: 20,
    ERROR_CODE: 3,
}

F1 = (0.5, -1.25, 2.0)
F2 = (-0.125, 0.0625, 3.5)
F3 = (0.25, -0.75, 0.375)
M9 = tuple(k / 16 for k in range(1, 10))  # m11, m12, ..., m33 in wire order

# (command, parameters, bytes the manual says go on the wire).
COMMAND_VECTORS: list[tuple[int, dict[str, Any], bytes]] = [
    *((code, {}, bytes((code,))) for code in sorted(MANUAL_DATA_CODES)),
    (0xC4, {"command": 0xC8}, b"\xc4\xc1\x29\xc8"),
    (0xC9, {"accel_bias": list(F1)}, b"\xc9\xb7\x44" + struct.pack(">3f", *F1)),
    (0xCA, {"gyro_bias": list(F2)}, b"\xca\x12\xa5" + struct.pack(">3f", *F2)),
    (0xCD, {"sampling_time_ms": 10_000}, b"\xcd\xc1\x29\x27\x10"),
    (0xD0, {"quantity": 2}, b"\xd0\xc1\x29\x00\x02"),
    (0xD4, {"mode": Mode.CONTINUOUS}, b"\xd4\xa3\x47\x02"),
    (0xD5, {"mode_preset": 3}, b"\xd5\xba\x89\x03"),
    (0xD6, {"continuous_preset": 0xC2}, b"\xd6\xc6\x6b\xc2"),
    (0xD7, {"function": 1, "value": 0x12345678}, b"\xd7\xc1\x29\x01\x12\x34\x56\x78"),
    (0xD9, {"port": 1, "function": 1, "baud": 460_800, "config": 0x02},
     b"\xd9\xc3\x55\x01\x01" + struct.pack(">I", 460_800) + b"\x02\x00"),
    # Reads: the manual says the unit ignores the other values, so they may be left out.
    (0xD7, {"function": 0}, b"\xd7\xc1\x29\x00" + bytes(4)),
    (0xD9, {"port": 1, "function": 0}, b"\xd9\xc3\x55\x01\x00" + bytes(6)),
    (0xDB, {"function": 0}, b"\xdb\xa8\xb9\x00" + bytes(16)),
    (0xDA, {}, b"\xda"),
    (0xDB, {"function": 1, "decimation": 10, "flags": 0x1003, "filter_width": 15,
            "mag_filter_width": 17, "up_compensation": 10, "north_compensation": 1000},
     b"\xdb\xa8\xb9\x01" + b"\x00\x0a" + b"\x10\x03" + b"\x0f\x11" + b"\x00\x0a" + b"\x03\xe8"
     + bytes(6)),
    (0xDD, {"function": 0, "up_realign": 10, "north_realign": 255},
     b"\xdd\x54\x4c\x00\x0a\xff" + bytes(4)),
    (0xE4, {"address": 0x0010, "value": 0xBEEF}, b"\xe4\xc1\x29\x00\x00\x10\xbe\xef"),
    (0xE5, {"address": 0x0400}, b"\xe5\x00\x04\x00"),
    (0xE9, {}, b"\xe9"),
    (0xEA, {"selector": 1}, b"\xea\x01"),
    (0xFA, {}, b"\xfa\x75\xb4"),
    (0xFE, {}, b"\xfe\x9e\x3a"),
]

# Manual byte lengths of every command sent (the last "Byte n" row).
MANUAL_COMMAND_LENGTHS = {
    **dict.fromkeys(MANUAL_DATA_CODES, 1),
    0xC4: 4, 0xC9: 15, 0xCA: 15, 0xCD: 5, 0xD0: 5, 0xD4: 4, 0xD5: 4, 0xD6: 4, 0xD7: 8,
    0xD9: 11, 0xDA: 1, 0xDB: 20, 0xDD: 10, 0xE4: 8, 0xE5: 4, 0xE9: 1, 0xEA: 2, 0xFA: 3,
    0xFE: 3,
}


def test_table_lists_exactly_the_manual_commands() -> None:
    assert set(COMMANDS) == MANUAL_COMMANDS
    assert set(DATA_CODES) == MANUAL_DATA_CODES
    assert {code for code, _, _ in COMMAND_VECTORS} == MANUAL_COMMANDS - {0xFD}


@pytest.mark.parametrize(("code", "params", "wire"), COMMAND_VECTORS,
                         ids=[f"0x{c:02X}" for c, _, _ in COMMAND_VECTORS])
def test_command_bytes(code: int, params: dict[str, Any], wire: bytes) -> None:
    assert len(wire) == MANUAL_COMMAND_LENGTHS[code]
    assert encode_command(code, **params) == wire
    assert COMMANDS[code].length == len(wire)
    assert encode_command(COMMANDS[code].name, **params) == wire


def test_firmware_update_has_no_layout_and_is_refused() -> None:
    with pytest.raises(ProtocolError, match="no byte layout"):
        encode_command(0xFD)
    assert COMMANDS[0xFD].reply is None


def test_reply_lengths_match_the_manual() -> None:
    assert set(REPLIES) == set(MANUAL_REPLY_LENGTHS)
    for code, length in MANUAL_REPLY_LENGTHS.items():
        assert REPLIES[code].length == length, f"0x{code:02X}"
        if code != ERROR_CODE:
            assert COMMANDS[code].reply_length == length, f"0x{code:02X}"
    for code in (0xFA, 0xFD, 0xFE):
        assert COMMANDS[code].reply_length is None


# Data records: the fields of each manual table in wire order, as (name, count, struct code).
DATA_LAYOUTS: dict[int, tuple[tuple[str, int, str], ...]] = {
    0xC1: (("raw_accel", 3, "f"), ("raw_ang_rate", 3, "f")),
    0xC2: (("accel", 3, "f"), ("ang_rate", 3, "f")),
    0xC3: (("delta_ang", 3, "f"), ("delta_vel", 3, "f")),
    0xC5: (("m", 9, "f"),),
    0xC6: (("c", 9, "f"),),
    0xC7: (("mag", 3, "f"),),
    0xC8: (("accel", 3, "f"), ("ang_rate", 3, "f"), ("m", 9, "f")),
    0xCB: (("accel", 3, "f"), ("ang_rate", 3, "f"), ("mag", 3, "f")),
    0xCC: (("accel", 3, "f"), ("ang_rate", 3, "f"), ("mag", 3, "f"), ("m", 9, "f")),
    0xCE: (("euler", 3, "f"),),
    0xCF: (("euler", 3, "f"), ("ang_rate", 3, "f")),
    0xD1: (("temperature", 4, "H"),),
    0xD2: (("stab_accel", 3, "f"), ("ang_rate", 3, "f"), ("stab_mag", 3, "f")),
    0xD3: (("delta_ang", 3, "f"), ("delta_vel", 3, "f"), ("mag", 3, "f")),
    0xDF: (("quaternion", 4, "f"),),
}
SAMPLE = {
    "raw_accel": (65_536.5, 70_000.0, 1_024.25), "raw_ang_rate": (60_000.0, 131_071.0, 0.0),
    "accel": F1, "ang_rate": F2, "delta_ang": F3, "delta_vel": F1, "mag": F2,
    "stab_accel": F3, "stab_mag": F1, "m": M9, "c": tuple(-v for v in M9), "euler": F3,
    "quaternion": (0.5, -0.5, 0.5, -0.5), "temperature": (0x0ABC, 2000, 2100, 4095),
}
SHAPES = {"m": (3, 3), "c": (3, 3)}


def data_record(code: int, timer: int, little_endian: bool = False) -> bytes:
    """A data record from DATA_LAYOUTS; floats in the chosen order, the timer always big-endian."""
    order = "<" if little_endian else ">"
    payload = b"".join(
        struct.pack((order if kind == "f" else ">") + f"{count}{kind}", *SAMPLE[name])
        for name, count, kind in DATA_LAYOUTS[code]
    )
    return frame(code, payload + struct.pack(">I", timer))


@pytest.mark.parametrize("code", sorted(DATA_LAYOUTS), ids=lambda c: f"0x{c:02X}")
def test_data_record(code: int) -> None:
    raw = data_record(code, 0xFFFFFFF0)
    assert len(raw) == MANUAL_REPLY_LENGTHS[code]
    decoded = decode_one(raw)
    names = [name for name, _, _ in DATA_LAYOUTS[code]]
    assert list(decoded) == [*names, "timer"]
    for name, _, kind in DATA_LAYOUTS[code]:
        want = np.array(SAMPLE[name]).reshape(SHAPES.get(name, (-1,)))
        assert decoded[name].shape == want.shape
        assert decoded[name].dtype == (np.float32 if kind == "f" else np.uint16)
        np.testing.assert_array_equal(decoded[name], want)
    assert int(decoded["timer"]) == 4_294_967_280
    values = {name: SAMPLE[name] for name in names}
    columns: dict[str, Any] = {n: np.reshape(v, SHAPES.get(n, (-1,))) for n, v in values.items()}
    assert encode_reply(code, timer=0xFFFFFFF0, **columns) == raw


def test_orientation_matrix_is_row_major() -> None:
    m = decode_one(data_record(0xC8, 1))["m"]
    assert m[0].tolist() == [1 / 16, 2 / 16, 3 / 16]  # m11 m12 m13
    assert m[1, 0] == 4 / 16  # m21 is the 4th float on the wire
    assert m[2, 1] == 8 / 16  # m32


def test_unsigned_timer_through_the_record_view() -> None:
    framer = Framer()
    (batch,) = framer.feed(data_record(0xC2, 0xFFFFFFF0))
    (record,) = batch.records()
    assert record["timer"] == 4_294_967_280
    assert record["command"] == 0xC2
    assert record["accel"] == list(F1)


def test_manual_checksum_example() -> None:
    # 0xC2 reply, 31 bytes: accel (0, 0, -1 g), ang_rate 0, timer 62,500 (one second).
    # Sum of bytes 1-29: 0xC2 + 0xBF + 0x80 + 0xF4 + 0x24 = 793 = 0x0319, sent MSB first.
    raw = bytes.fromhex(
        "c2" "00000000" "00000000" "bf800000" "00000000" "00000000" "00000000" "0000f424" "0319"
    )
    assert len(raw) == 31
    t_chksum = 0
    for tix in range(len(raw) - 2):  # the manual's C loop, verbatim in spirit
        t_chksum = (t_chksum + raw[tix]) & 0xFFFF
    assert t_chksum == (raw[29] << 8) + raw[30] == 0x0319
    assert checksum(raw[:29]) == 0x0319
    assert encode_reply(0xC2, accel=[0, 0, -1], ang_rate=[0, 0, 0], timer=62_500) == raw
    decoded = decode_one(raw)
    assert decoded["accel"].tolist() == [0.0, 0.0, -1.0]
    assert int(decoded["timer"]) == 62_500


def test_checksum_rolls_over_from_65535_to_0() -> None:
    assert checksum(b"\xff" * 300) == (300 * 255) - 65_536
    assert checksum(b"\xff" * 257 + b"\x01") == (257 * 255 + 1) % 65_536
    assert checksum(b"") == 0


def test_little_endian_floats_keep_timer_and_checksum_big_endian() -> None:
    raw = data_record(0xC2, 0x01020304, little_endian=True)
    assert raw[1:5] == struct.pack("<f", F1[0])
    assert raw[25:29] == b"\x01\x02\x03\x04"
    assert raw[29:31] == struct.pack(">H", sum(raw[:29]))
    decoded = decode_one(raw, little_endian=True)
    assert decoded["accel"].tolist() == list(F1)
    assert decoded["ang_rate"].tolist() == list(F2)
    assert int(decoded["timer"]) == 0x01020304
    assert encode_reply(0xC2, little_endian=True, accel=F1, ang_rate=F2, timer=0x01020304) == raw
    (batch,) = Framer([0xC2], little_endian=True).feed(raw)
    assert batch["accel"][0].tolist() == list(F1)


def test_little_endian_leaves_integer_replies_alone() -> None:
    raw = data_record(0xD1, 7, little_endian=True)
    assert raw == data_record(0xD1, 7)
    assert decode_one(raw, little_endian=True)["temperature"].tolist() == [0x0ABC, 2000, 2100, 4095]


# Settings and status replies: (code, hand-built bytes, decoded values).
ID_TEXT = b"6225-4220".ljust(16)
SETTINGS_VECTORS: list[tuple[int, bytes, dict[str, Any]]] = [
    (0xC4, frame(0xC4, struct.pack(">BI", 0xC8, 0xFFFFFFF0)),
     {"command": 0xC8, "timer": 4_294_967_280}),
    (0xC9, frame(0xC9, struct.pack(">3fI", *F1, 5)), {"accel_bias": list(F1), "timer": 5}),
    (0xCA, frame(0xCA, struct.pack(">3fI", *F2, 6)), {"gyro_bias": list(F2), "timer": 6}),
    (0xCD, frame(0xCD, struct.pack(">3fI", *F3, 7)), {"gyro_bias": list(F3), "timer": 7}),
    (0xD0, frame(0xD0, struct.pack(">HI", 0xFFFF, 8)), {"quantity": 0xFFFF, "timer": 8}),
    (0xD4, frame(0xD4, struct.pack(">B", 3)), {"mode": Mode.IDLE}),
    (0xD5, frame(0xD5, struct.pack(">B", 2)), {"mode_preset": 2}),
    (0xD6, frame(0xD6, struct.pack(">B", 0xCC)), {"continuous_preset": 0xCC}),
    (0xD7, frame(0xD7, struct.pack(">I", 0xFFFFFFF0)), {"timer": 4_294_967_280}),
    (0xD9, frame(0xD9, struct.pack(">BIBx", 1, 921_600, 0x02)),
     {"port": 1, "baud": 921_600, "config": 2}),
    # Ports 2 and 3 are unused on the GX3-25: their settings read back as baud 0.
    (0xD9, frame(0xD9, struct.pack(">BIBx", 3, 0, 0)), {"port": 3, "baud": 0, "config": 0}),
    (0xDA, frame(0xDA, struct.pack(">I", 0x8000_00FF)), {"test_result": 0x8000_00FF}),
    # Firmware before 1.1.27 has no up/north compensation and reports 0 for both.
    (0xDB, frame(0xDB, struct.pack(">HHBBHH6x", 10, 3, 15, 17, 0, 0)),
     {"decimation": 10, "flags": 3, "filter_width": 15, "mag_filter_width": 17,
      "up_compensation": 0, "north_compensation": 0}),
    (0xDB, frame(0xDB, struct.pack(">HHBBHH6x", 4, Flag.ORIENTATION | Flag.QUATERNION, 15, 17,
                                    10, 1000)),
     {"decimation": 4, "flags": 0x1001, "filter_width": 15, "mag_filter_width": 17,
      "up_compensation": 10, "north_compensation": 1000}),
    (0xDD, frame(0xDD, bytes(4)), {}),
    (0xE4, frame(0xE4, struct.pack(">H", 0xBEEF)), {"word": 0xBEEF}),
    (0xE5, frame(0xE5, struct.pack(">H", 0x0102)), {"word": 0x0102}),
    (0xE9, frame(0xE9, bytes((0x00, 0x00, 0x04, 0x67))), {"firmware": 1127}),
    (0xEA, frame(0xEA, b"\x01" + ID_TEXT), {"selector": 1, "text": "6225-4220"}),
    (ERROR_CODE, b"\x21\x00\x21", {}),
]


@pytest.mark.parametrize(("code", "raw", "values"), SETTINGS_VECTORS,
                         ids=[f"0x{c:02X}" for c, _, _ in SETTINGS_VECTORS])
def test_settings_reply(code: int, raw: bytes, values: dict[str, Any]) -> None:
    assert len(raw) == MANUAL_REPLY_LENGTHS[code]
    (batch,) = Framer([code]).feed(raw)
    (record,) = batch.records()
    assert record == {"command": code, **values}
    assert not any(isinstance(v, np.generic) for v in record.values())
    assert encode_reply(code, **{
        k: v.ljust(16) if k == "text" else v for k, v in values.items()}) == raw


def test_error_reply_is_the_fixed_three_bytes() -> None:
    assert ERROR_REPLY == b"\x21\x00\x21"
    assert encode_reply(ERROR_CODE) == ERROR_REPLY
    framer = Framer([0xD4, ERROR_CODE])
    batches = framer.feed(ERROR_REPLY + frame(0xD4, b"\x01"))
    assert [(b.code, len(b)) for b in batches] == [(ERROR_CODE, 1), (0xD4, 1)]


def test_realign_reply_reserved_bytes_are_not_decoded() -> None:
    raw = frame(0xDD, b"\xde\xad\xbe\xef")
    (batch,) = Framer([0xDD]).feed(raw)
    assert batch.columns == {}
    assert len(batch) == 1
