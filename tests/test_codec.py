"""Range checks, command parsing and encode/decode round trips of the codec."""

from __future__ import annotations

import math
import string
import struct
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bridge.exceptions import ProtocolError
from bridge.protocol.codec import (
    command_length,
    decode_block,
    encode_command,
    encode_replies,
    encode_reply,
    parse_command,
    plausible,
    plausible_rows,
)
from bridge.protocol.table import COMMANDS, DATA_CODES, REPLIES, Field

FAST = settings(max_examples=60, deadline=None)
BITS = {"u8": 8, "u16": 16, "u32": 32}
DOCUMENTED = sorted(code for code, cmd in COMMANDS.items() if cmd.documented)
REPLY_CODES = sorted(REPLIES)


def _inside_f32(bound: float) -> float:
    """The float32 nearest ``bound`` on the zero side, as Hypothesis needs exact bounds."""
    x = np.float32(bound)
    if abs(float(x)) > abs(bound):
        x = np.nextafter(x, np.float32(0))
    return float(x)


def field_values(f: Field) -> st.SearchStrategy[Any]:
    """Values a unit could send (reply fields: inside the domain) or take (parameters:
    inside the rules it clamps to), float32-exact."""
    if f.kind == "f32":
        bound = None if f.domain is None else _inside_f32(f.domain[1])
        element = st.floats(None if bound is None else -bound, bound, width=32,
                            allow_nan=False, allow_infinity=False)
        shape = f.shape
        return st.lists(element, min_size=f.count, max_size=f.count).map(
            lambda v: np.array(v, np.float32).reshape(shape))
    if f.kind == "ascii":
        return st.text(string.ascii_letters + string.digits + "-_.", max_size=16)
    values = f.allowed if f.allowed is not None else f.domain_values
    if values is not None:
        return st.sampled_from(sorted(values))
    lo, hi = (f.lo, f.hi) if f.lo is not None else f.domain or (None, None)
    low = 0 if lo is None else int(lo)
    high = (1 << BITS[f.kind]) - 1 if hi is None else int(hi)
    if f.shape:
        return st.lists(st.integers(low, high), min_size=f.count, max_size=f.count)
    return st.integers(low, high)


def reply_values(code: int) -> st.SearchStrategy[dict[str, Any]]:
    return st.fixed_dictionaries(
        {f.name: field_values(f) for f in REPLIES[code].fields if not f.is_pad})


def command_params(code: int) -> st.SearchStrategy[dict[str, Any]]:
    params = {}
    for f in COMMANDS[code].params:
        if f.is_pad:
            continue
        if f.kind == "f32":
            params[f.name] = field_values(f).map(lambda a: a.tolist())
        else:
            params[f.name] = field_values(f)
    return st.fixed_dictionaries(params)


# ---------------------------------------------------------------- range checks

# (command, parameters, the parameter the message must name, the allowed values it must list)
DB_OK = {"function": 1, "decimation": 10, "flags": 3, "filter_width": 15, "mag_filter_width": 17,
         "up_compensation": 10, "north_compensation": 10}
D9_OK = {"port": 1, "function": 1, "baud": 115_200, "config": 2}
OUT_OF_RANGE = [
    (0xDB, {**DB_OK, "decimation": 0}, "decimation=0", "1..1000"),
    (0xDB, {**DB_OK, "decimation": 1001}, "decimation=1001", "1..1000"),
    (0xDB, {**DB_OK, "filter_width": 33}, "filter_width=33", "1..32"),
    (0xDB, {**DB_OK, "mag_filter_width": 0}, "mag_filter_width=0", "1..32"),
    (0xDB, {**DB_OK, "up_compensation": 1001}, "up_compensation=1001", "1..1000"),
    # Older firmware reports 0 (a plausible reply), but a unit clamps a setting of 0 to 1.
    (0xDB, {**DB_OK, "north_compensation": 0}, "north_compensation=0", "1..1000"),
    (0xDB, {**DB_OK, "function": 4}, "function=4", "0, 1, 2, 3"),
    (0xD4, {"mode": 6}, "mode=6", "0, 1, 2, 3, 4, 5"),
    (0xD5, {"mode_preset": 4}, "mode_preset=4", "0, 1, 2, 3"),
    (0xD9, {**D9_OK, "baud": 9600}, "baud=9600", "115200, 230400, 460800, 921600"),
    (0xD9, {**D9_OK, "port": 0}, "port=0", "1, 2, 3"),
    (0xEA, {"selector": 5}, "selector=5", "0, 1, 2, 3, 4"),
    (0xD0, {"quantity": 3}, "quantity=3", "1, 2"),
    (0xD7, {"function": 3, "value": 0}, "function=3", "0, 1, 2"),
    (0xDD, {"function": 1, "up_realign": 10, "north_realign": 10}, "function=1", "0, 3"),
    (0xDD, {"function": 0, "up_realign": 101, "north_realign": 10}, "up_realign=101", "100, 255"),
    (0xC4, {"command": 0xC4}, "command=196", "0, 193"),
    (0xD6, {"continuous_preset": 0xFA}, "continuous_preset=250", "0, 193"),
]


@pytest.mark.parametrize(("code", "params", "named", "allowed"), OUT_OF_RANGE,
                         ids=[n for _, _, n, _ in OUT_OF_RANGE])
def test_out_of_range_names_parameter_and_allowed_values(
    code: int, params: dict[str, Any], named: str, allowed: str
) -> None:
    with pytest.raises(ProtocolError) as caught:
        encode_command(code, **params)
    message = str(caught.value)
    assert f"0x{code:02X}" in message
    assert named in message
    assert allowed in message


@pytest.mark.parametrize(("code", "params", "named", "allowed"), OUT_OF_RANGE,
                         ids=[n for _, _, n, _ in OUT_OF_RANGE])
def test_non_strict_passes_values_that_fit(
    code: int, params: dict[str, Any], named: str, allowed: str
) -> None:
    wire = encode_command(code, strict=False, **params)
    assert len(wire) == COMMANDS[code].length
    assert parse_command(wire).params == params


def test_non_strict_bytes_are_the_raw_values() -> None:
    wire = encode_command(0xDB, strict=False, **{**DB_OK, "decimation": 0, "filter_width": 33})
    assert wire[4:6] == b"\x00\x00"
    assert wire[8] == 33
    wire = encode_command(0xD9, strict=False, **{**D9_OK, "baud": 9600})
    assert wire[5:9] == struct.pack(">I", 9600)


@pytest.mark.parametrize(("code", "params", "fragment"), [
    (0xDB, {**DB_OK, "decimation": 65_536}, "decimation=65536 does not fit 16 bits"),
    (0xD4, {"mode": -1}, "mode=-1 does not fit 8 bits"),
    (0xD7, {"function": 1, "value": 1 << 32}, "does not fit 32 bits"),
])
@pytest.mark.parametrize("strict", [True, False])
def test_values_that_do_not_fit_are_refused_even_when_not_strict(
    code: int, params: dict[str, Any], fragment: str, strict: bool
) -> None:
    with pytest.raises(ProtocolError, match=fragment):
        encode_command(code, strict=strict, **params)


@pytest.mark.parametrize(("code", "params", "fragments"), [
    (0xD4, {}, ("takes mode", "missing mode")),
    (0xD4, {"mode": 1, "speed": 3}, ("takes mode", "unknown speed")),
    (0xDB, {"function": 1}, ("missing decimation, flags",)),
    (0xD9, {"port": 1, "function": 2, "baud": 115_200}, ("missing config",)),
    (0xC2, {"mode": 1}, ("takes no parameters", "unknown mode")),
    (0xD4, {"mode": 1.5}, ("mode must be an integer",)),
    (0xD4, {"mode": True}, ("mode must be an integer",)),
    (0xC9, {"accel_bias": [1.0, 2.0]}, ("accel_bias needs 3 numbers",)),
])
def test_missing_unknown_and_mistyped_parameters(
    code: int, params: dict[str, Any], fragments: tuple[str, ...]
) -> None:
    with pytest.raises(ProtocolError) as caught:
        encode_command(code, **params)
    for fragment in fragments:
        assert fragment in str(caught.value)


def test_unknown_command_lists_the_known_ones() -> None:
    with pytest.raises(KeyError, match="0xC1 raw_accel_ang_rate"):
        encode_command(0x99)
    with pytest.raises(KeyError, match="'warp_drive'"):
        encode_command("warp_drive")


def test_firmware_update_is_refused() -> None:
    with pytest.raises(ProtocolError, match="0xFD"):
        encode_command(0xFD)
    with pytest.raises(ProtocolError, match="0xFD"):
        encode_command("firmware_update", strict=False)


# ------------------------------------------------------------ command parsing


@pytest.mark.parametrize("code", DOCUMENTED, ids=lambda c: f"0x{c:02X}")
@settings(max_examples=15, deadline=None)
@given(data=st.data())
def test_parse_command_round_trips(code: int, data: st.DataObject) -> None:
    params = data.draw(command_params(code))
    wire = encode_command(code, **params)
    assert command_length(code) == len(wire)  # what a unit reads before parsing
    parsed = parse_command(wire)
    assert parsed.command is COMMANDS[code]
    assert parsed.confirmed
    assert parsed.params == params


CONFIRMED = sorted(code for code, cmd in COMMANDS.items() if cmd.confirm and cmd.documented)


@pytest.mark.parametrize("code", CONFIRMED, ids=lambda c: f"0x{c:02X}")
def test_wrong_confirmation_byte_is_unconfirmed(code: int) -> None:
    cmd = COMMANDS[code]
    wire = encode_command(code, strict=False, **{
        f.name: [0.0] * f.count if f.kind == "f32" else 0 for f in cmd.params if not f.is_pad})
    for i in range(1, 1 + len(cmd.confirm)):
        bad = bytearray(wire)
        bad[i] ^= 0x01
        assert not parse_command(bytes(bad)).confirmed


def test_parse_command_checks_length() -> None:
    with pytest.raises(ProtocolError, match="0xD4 mode is 4 bytes, got 3"):
        parse_command(b"\xd4\xa3\x47")


def test_command_length_of_a_byte_the_unit_ignores() -> None:
    assert command_length(0x00) is None
    assert command_length(0x21) is None


# ------------------------------------------------------------ reply round trip


@pytest.mark.parametrize("code", REPLY_CODES, ids=lambda c: f"0x{c:02X}")
@pytest.mark.parametrize("little_endian", [False, True], ids=["big", "little"])
@settings(max_examples=20, deadline=None)
@given(data=st.data())
def test_reply_round_trip(code: int, little_endian: bool, data: st.DataObject) -> None:
    values = data.draw(reply_values(code))
    raw = encode_reply(code, little_endian, **values)
    assert len(raw) == REPLIES[code].length
    assert raw[0] == code
    assert int.from_bytes(raw[-2:], "big") == sum(raw[:-2]) % 65_536
    assert plausible(code, raw, little_endian)
    decoded = decode_block(code, np.frombuffer(raw, np.uint8).reshape(1, -1), little_endian)
    assert sorted(decoded) == sorted(values)
    for name, value in values.items():
        got = decoded[name][0]
        if isinstance(value, str):
            assert got.decode("ascii").rstrip() == value
        else:
            np.testing.assert_array_equal(got, value)
    if "timer" in values:
        assert int(decoded["timer"][0]) == values["timer"] >= 0


@st.composite
def reply_columns(draw: st.DrawFn) -> tuple[int, int, bool, dict[str, Any]]:
    code = draw(st.sampled_from(sorted(DATA_CODES)))
    n = draw(st.integers(1, 6))
    rows = [draw(reply_values(code)) for _ in range(n)]
    columns = {name: np.array([row[name] for row in rows]) for name in rows[0]}
    return code, n, draw(st.booleans()), columns


@FAST
@given(reply_columns())
def test_many_replies_round_trip_as_columns(case: tuple[int, int, bool, dict[str, Any]]) -> None:
    code, n, little_endian, columns = case
    raw = encode_replies(code, columns, n, little_endian)
    size = REPLIES[code].length
    assert len(raw) == n * size
    block = np.frombuffer(raw, np.uint8).reshape(n, size)
    decoded = decode_block(code, block, little_endian)
    for name, column in columns.items():
        np.testing.assert_array_equal(decoded[name], column)
    for i in range(n):  # every record stands alone: its own checksum, its own row
        record = raw[i * size : (i + 1) * size]
        assert int.from_bytes(record[-2:], "big") == sum(record[:-2]) % 65_536
        alone = decode_block(code, np.frombuffer(record, np.uint8).reshape(1, -1), little_endian)
        for name, column in columns.items():
            np.testing.assert_array_equal(alone[name][0], column[i])


def test_timer_column_is_unsigned() -> None:
    raw = encode_replies(0xC7, {"mag": [0, 0, 0], "timer": [0xFFFFFFF0, 0x7FFFFFFF]}, 2)
    timer = decode_block(0xC7, np.frombuffer(raw, np.uint8).reshape(2, -1))["timer"]
    assert timer.dtype == np.uint32
    assert timer.tolist() == [4_294_967_280, 2_147_483_647]


# ---------------------------------------------------------------- plausibility


def test_plausible_rejects_values_outside_the_domain() -> None:
    m = np.eye(3, dtype=np.float32)
    assert plausible(0xC5, encode_reply(0xC5, m=m, timer=1))
    assert not plausible(0xC5, encode_reply(0xC5, m=2 * m, timer=1))
    assert not plausible(0xD4, encode_reply(0xD4, mode=9))
    assert not plausible(0xD1, encode_reply(0xD1, temperature=[0, 0, 0, 4096], timer=0))
    assert not plausible(0xD9, encode_reply(0xD9, port=1, baud=9600, config=2))
    assert not plausible(0xDB, encode_reply(0xDB, decimation=10, flags=3, filter_width=33,
                                            mag_filter_width=17, up_compensation=0,
                                            north_compensation=0))


FLOAT_FIELDS = [(code, f) for code in REPLY_CODES for f in REPLIES[code].fields
                if f.kind == "f32"]


@pytest.mark.parametrize(("code", "f"), FLOAT_FIELDS,
                         ids=[f"0x{c:02X}-{f.name}" for c, f in FLOAT_FIELDS])
@pytest.mark.parametrize("special", [math.nan, math.inf, -math.inf], ids=["nan", "inf", "-inf"])
def test_non_finite_floats_are_plausible_in_every_float_field(
    code: int, f: Field, special: float
) -> None:
    """A unit sends NaN (idle mode, orientation off) unless suppressed; infinities are
    floats it can produce too. Both the scanner and the fast path must take them."""
    values = {g.name: np.zeros(g.shape) if g.kind == "f32" else 1
              for g in REPLIES[code].fields if not g.is_pad}
    values[f.name] = np.array([special] + [0.5] * (f.count - 1)).reshape(f.shape)
    for little_endian in (False, True):
        raw = encode_reply(code, little_endian, **values)
        block = np.frombuffer(raw * 2, np.uint8).reshape(2, -1)
        assert plausible(code, raw, little_endian)
        assert plausible_rows(code, block, little_endian).all()


def test_idle_mode_raw_codes_are_plausible() -> None:
    """Raw A/D codes are "undetermined" in idle mode: any finite value within the loose
    physical bound passes, negative or beyond 17 bits included."""
    raw = encode_reply(0xC1, raw_accel=[-3.5, 2e5, 0.0], raw_ang_rate=[9.9e5, -1.0, 131_072],
                       timer=5)
    assert plausible(0xC1, raw)
    assert not plausible(0xC1, encode_reply(0xC1, raw_accel=[2e6, 0, 0], raw_ang_rate=[0, 0, 0],
                                            timer=5))


@FAST
@given(code=st.sampled_from(REPLY_CODES), little_endian=st.booleans(), data=st.data())
def test_plausible_rows_agrees_with_plausible(code: int, little_endian: bool,
                                              data: st.DataObject) -> None:
    """The framer's fast path uses the array form, its scanner the scalar one: they must
    accept exactly the same records. Rows mix valid replies with random bytes."""
    size = REPLIES[code].length
    rows = data.draw(st.lists(st.one_of(
        reply_values(code).map(lambda v: encode_reply(code, little_endian, **v)),
        st.binary(min_size=size - 1, max_size=size - 1).map(lambda b: bytes((code,)) + b),
    ), min_size=1, max_size=8))
    block = np.frombuffer(b"".join(rows), np.uint8).reshape(len(rows), size)
    expected = [plausible(code, row, little_endian) for row in rows]
    assert plausible_rows(code, block, little_endian).tolist() == expected


def _around(bound: float) -> list[float]:
    """float32 values on both sides of ``bound``, and on it when it is representable."""
    x = np.float32(bound)
    return [float(v) for v in (np.nextafter(x, np.float32(-np.inf)), x,
                               np.nextafter(x, np.float32(np.inf)))]


@pytest.mark.parametrize(("code", "f"), FLOAT_FIELDS,
                         ids=[f"0x{c:02X}-{f.name}" for c, f in FLOAT_FIELDS])
@pytest.mark.parametrize("little_endian", [False, True], ids=["big", "little"])
def test_plausible_rows_agrees_at_every_float_bound(code: int, f: Field,
                                                    little_endian: bool) -> None:
    """Bounds such as 1.001 are not float32 values; both forms must draw the line alike."""
    rows = []
    assert f.domain is not None
    for value in [*_around(f.domain[0]), *_around(f.domain[1])]:
        values = {g.name: np.zeros(g.shape) if g.kind == "f32" else 1
                  for g in REPLIES[code].fields if not g.is_pad}
        values[f.name] = np.full(f.shape, value)
        rows.append(encode_reply(code, little_endian, **values))
    block = np.frombuffer(b"".join(rows), np.uint8).reshape(len(rows), -1)
    expected = [plausible(code, row, little_endian) for row in rows]
    assert expected.count(False) >= 2
    assert plausible_rows(code, block, little_endian).tolist() == expected
