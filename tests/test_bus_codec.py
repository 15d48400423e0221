"""Bulk ImuSample encoding gives protobuf's bytes, one length per record type, and decodes back."""

from __future__ import annotations

import numpy as np
import pytest

from bridge.bus.codec import (
    HEADER,
    LEGACY_HEADERS,
    decode_batch,
    encode_batch,
    encode_records,
    layout,
    peek,
    record_quantities,
    units_agree,
)
from bridge.bus.gx3_pb2 import ImuSample
from bridge.protocol.codec import Batch, encode_replies
from bridge.protocol.framer import Framer
from bridge.protocol.table import DATA_CODES, REPLIES
from tests.helpers.records import wire_batch, wire_times

CODES = sorted(DATA_CODES)


def reference(unit: str, batch: Batch, i: int, ticks: np.ndarray, time_ns: np.ndarray,
              rx_ns: np.ndarray, mono: np.ndarray | None = None,
              part: tuple[np.ndarray, np.ndarray] | None = None) -> ImuSample:
    """The message built field by field with the protobuf library (``mono``: the raw-clock
    receive times; a bridge that knows none writes 0; ``part``: the partial reads, not
    recorded: 0)."""
    return ImuSample(unit=unit, command=batch.code, timer=int(batch["timer"][i]),
                     ticks=int(ticks[i]), time_ns=int(time_ns[i]), rx_ns=int(rx_ns[i]),
                     rx_mono_raw_ns=0 if mono is None else int(mono[i]),
                     part_rx_mono_raw_ns=0 if part is None else int(part[0][i]),
                     part_lead_ns=0 if part is None else int(part[1][i]),
                     **{q: batch[q][i].reshape(-1).tolist() for q in record_quantities(batch.code)})


@pytest.mark.parametrize("code", CODES, ids=lambda c: f"0x{c:02X}")
def test_bulk_encoding_is_byte_identical_to_protobuf(code: int) -> None:
    batch = wire_batch(code, 6, code)
    ticks, time_ns, rx_ns = wire_times(6)
    mono = rx_ns - 1_700_000_000_000_000_000
    part = (mono - np.array([0, 5, 900_000, 1, 0, 7]), np.array([0, 0, 86_806, 347_222, 0, 1]))
    encoded = encode_batch("imu-0.a", batch, ticks, time_ns, rx_ns, mono, part)
    assert len(encoded) == 6
    for i, payload in enumerate(encoded):
        assert payload == reference("imu-0.a", batch, i, ticks, time_ns, rx_ns,
                                    mono, part).SerializeToString()
        assert peek(payload) == ("imu-0.a", code)


@pytest.mark.parametrize("little_endian", [False, True], ids=["big-endian", "little-endian"])
@pytest.mark.parametrize("code", CODES, ids=lambda c: f"0x{c:02X}")
def test_records_off_the_wire_encode_from_their_bytes_as_from_their_columns(
        code: int, little_endian: bool) -> None:
    """The framer's batches carry their wire bytes, which the encoder moves without
    decoding; the messages must be the very ones the decoded columns give."""
    columns = {name: col / 10 if col.dtype.kind == "f" else col  # inside every domain
               for name, col in wire_batch(code, 7, code + 2).columns.items()}
    raw = encode_replies(code, columns, 7, little_endian)
    framer = Framer(expect=[code], little_endian=little_endian)
    [framed] = framer.feed(raw, 5)
    assert framed.block is not None
    decoded = Batch(code, {k: np.array(v) for k, v in framed.columns.items()}, framed.offsets,
                    framed.rx_ns, little_endian)
    ticks, time_ns, rx_ns = wire_times(7)
    from_bytes = encode_batch("u-9", framed, ticks, time_ns, rx_ns)
    assert from_bytes == encode_batch("u-9", decoded, ticks, time_ns, rx_ns)
    assert from_bytes[3] == reference("u-9", decoded, 3, ticks, time_ns, rx_ns).SerializeToString()
    for i in range(7):  # a live read mostly holds one record: the same message alone
        one = framed.select(np.arange(7) == i)
        assert one.block is not None
        assert encode_batch("u-9", one, ticks[i : i + 1], time_ns[i : i + 1],
                            rx_ns[i : i + 1]) == [from_bytes[i]]


@pytest.mark.parametrize("little_endian", [False, True], ids=["big-endian", "little-endian"])
@pytest.mark.parametrize("code", CODES, ids=lambda c: f"0x{c:02X}")
def test_one_record_at_a_time_encodes_to_the_bulk_bytes(code: int, little_endian: bool) -> None:
    """A live bridge encodes each record from its own bytes with structs, not arrays:
    the messages must be the bulk encoder's, whatever the bytes hold (random bytes: NaN
    payloads, infinities, every bit pattern) and for either float byte order."""
    n = 9
    rng = np.random.default_rng(code + little_endian)
    block = rng.integers(0, 256, (n, REPLIES[code].length), dtype=np.uint8)
    batch = Batch.from_block(code, block, np.arange(n), np.zeros(n, np.int64), little_endian)
    ticks = rng.integers(-(2**62), 2**62, n)
    time_ns = rng.integers(-(2**62), 2**62, n)
    rx_ns = rng.integers(0, 2**62, n)
    mono = rng.integers(0, 2**62, n)
    part = (rng.integers(-1, 2**40, n), rng.integers(0, 10**6, n))
    bulk = encode_batch("imu-0.a", batch, ticks, time_ns, rx_ns, mono, part)
    assert encode_records("imu-0.a", code, little_endian, [bytes(r) for r in block],
                          [c.tolist() for c in (ticks, time_ns, rx_ns, mono, *part)]) == bulk


@pytest.mark.parametrize("code", CODES, ids=lambda c: f"0x{c:02X}")
def test_round_trip_through_protobuf_gives_the_columns_back(code: int) -> None:
    batch = wire_batch(code, 5, code + 1)
    ticks, time_ns, rx_ns = wire_times(5)
    encoded = encode_batch("u1", batch, ticks, time_ns, rx_ns)
    parsed = [ImuSample.FromString(p) for p in encoded]
    assert [m.command for m in parsed] == [code] * 5
    assert [m.ticks for m in parsed] == ticks.tolist()
    assert [m.rx_ns for m in parsed] == rx_ns.tolist()
    filled = {f.name for f, _ in parsed[0].ListFields()}
    assert filled == {"unit", *HEADER, *record_quantities(code)}, "a record fills what it has"
    columns = decode_batch("u1", code, encoded)
    expected = {"command": np.full(5, code), "timer": batch["timer"], "ticks": ticks,
                "time_ns": time_ns, "rx_ns": rx_ns}
    for name, want in expected.items():
        np.testing.assert_array_equal(columns[name], want, err_msg=name)
    for q in record_quantities(code):
        assert columns[q].shape == batch[q].shape, q
        np.testing.assert_array_equal(columns[q], batch[q], err_msg=q)  # NaN == NaN here


@pytest.mark.parametrize("code", CODES, ids=lambda c: f"0x{c:02X}")
def test_every_message_of_one_record_type_has_one_length(code: int) -> None:
    lengths = set()
    for seed in range(3):
        batch = wire_batch(code, 4, seed)
        ticks, time_ns, rx_ns = wire_times(4)
        lengths |= {len(p) for p in encode_batch("imu0", batch, ticks * seed, time_ns * seed,
                                                 rx_ns)}
        zeros = Batch(code, {k: np.zeros_like(v) for k, v in batch.columns.items()},
                      batch.offsets, batch.rx_ns, False)
        lengths |= {len(p) for p in encode_batch("imu0", zeros, ticks * 0, time_ns * 0,
                                                 rx_ns * 0)}
    assert lengths == {layout(code, "imu0").size}


def test_other_valid_encodings_of_the_same_message_decode_alike() -> None:
    """A producer that writes fields in another order (here: quantities first) is still read."""
    code = 0xC8
    batch = wire_batch(code, 3, 7)
    ticks, time_ns, rx_ns = wire_times(3)
    ours = encode_batch("imu0", batch, ticks, time_ns, rx_ns)
    theirs = []
    for i in range(3):
        full = reference("imu0", batch, i, ticks, time_ns, rx_ns)
        head = ImuSample(unit="imu0", command=code, timer=full.timer, ticks=full.ticks,
                         time_ns=full.time_ns, rx_ns=full.rx_ns, rx_mono_raw_ns=0,
                         part_rx_mono_raw_ns=0, part_lead_ns=0)
        body = ImuSample(accel=full.accel, ang_rate=full.ang_rate, m=full.m)
        theirs.append(body.SerializeToString() + head.SerializeToString())  # protobuf merges
    assert [len(p) for p in theirs] == [len(p) for p in ours] and theirs != ours
    assert peek(theirs[0]) == ("imu0", code)
    mixed = decode_batch("imu0", code, [ours[0], theirs[1], ours[2]])
    reference_columns = decode_batch("imu0", code, ours)
    for name, col in reference_columns.items():
        np.testing.assert_array_equal(mixed[name], col, err_msg=name)


def test_a_sample_of_another_unit_or_garbage_is_a_clear_error() -> None:
    payload = encode_batch("imu0", wire_batch(0xC2, 3, 0), *wire_times(3))[0]
    with pytest.raises(ValueError, match="is from 'imu0' 0xC2, not 'imu1' 0xC2"):
        decode_batch("imu1", 0xC2, [payload])
    with pytest.raises(ValueError, match=r"not a gx3.v1.ImuSample \(3 bytes\)"):
        peek(b"\xff\xff\xff")
    with pytest.raises(ValueError, match="0xD4 is not a data record"):
        record_quantities(0xD4)


def test_units_agree_reads_the_unit_as_a_protobuf_parser_does() -> None:
    n = 20
    payloads = encode_batch("a", wire_batch(0xC8, n, 3), np.arange(n), np.arange(n),
                            np.arange(n))
    assert units_agree("a", payloads) == [True] * n
    assert units_agree("b", payloads) == [False] * n
    # a second unit field wins in every parser, though the bulk header names "a"
    relabelled = payloads[4] + ImuSample(unit="b").SerializeToString()
    damaged = payloads[5][:-3]
    mixed = [*payloads[:4], relabelled, damaged, *payloads[6:]]
    assert units_agree("a", mixed) == [True] * 4 + [False, False] + [True] * (n - 6)
    assert units_agree("b", [relabelled]) == [True]


@pytest.mark.parametrize("cleared", [("part_rx_mono_raw_ns", "part_lead_ns"),
                                     ("part_rx_mono_raw_ns", "part_lead_ns", "rx_mono_raw_ns")],
                         ids=["no partial read", "no raw stamp"])
@pytest.mark.parametrize("code", [0xC2, 0xCC, 0xDF], ids=lambda c: f"0x{c:02X}")
def test_an_older_bridges_samples_decode_in_bulk(code: int, cleared: tuple[str, ...]) -> None:
    """Samples from older bridges lack the partial read (``part_rx_mono_raw_ns`` reads 0), and
    those older still the raw-clock stamp (``rx_mono_raw_ns`` reads 0): each has a bulk
    layout of its own, read as fast."""
    batch = wire_batch(code, 5, code)
    ticks, time_ns, rx_ns = wire_times(5)
    part = (rx_ns - 7 - np.arange(5) * 1000, np.arange(5) * 87)
    old = []
    for i in range(5):
        message = reference("u1", batch, i, ticks, time_ns, rx_ns, rx_ns - 7, part)
        for name in cleared:
            message.ClearField(name)
        old.append(message.SerializeToString())
    assert {len(p) for p in old} == {layout(code, "u1", LEGACY_HEADERS[len(cleared) - 2]).size}
    new = encode_batch("u1", batch, ticks, time_ns, rx_ns, rx_ns - 7, part)
    want = decode_batch("u1", code, new)
    np.testing.assert_array_equal(want["rx_mono_raw_ns"], rx_ns - 7)
    absent = {"rx_mono_raw_ns": 0, "part_rx_mono_raw_ns": 0, "part_lead_ns": 0}
    rows = np.frombuffer(b"".join(old), np.uint8).reshape(5, -1)
    mixed = [old[0], new[1], old[2], new[3], old[4]]
    for got, fresh in ((decode_batch("u1", code, old), []),
                       (decode_batch("u1", code, rows), []),
                       (decode_batch("u1", code, mixed), [1, 3])):
        for name, column in want.items():
            expected = column.copy()
            if name in cleared:
                expected[[i for i in range(5) if i not in fresh]] = absent[name]
            np.testing.assert_array_equal(got[name], expected, err_msg=name)
