"""Framer properties: exact records out, whatever the chunking and whatever the damage."""

from __future__ import annotations

import struct
from collections import Counter
from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bridge.protocol.codec import Batch, encode_reply
from bridge.protocol.framer import Framer
from bridge.protocol.table import DATA_CODES, REPLIES, Field

DATA = sorted(DATA_CODES)
PROPERTY = settings(max_examples=60, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

# A decoded record as a comparable value: its code and the bytes of every column entry
# (bytes, so that NaN compares equal to itself).
Record = tuple[int, tuple[tuple[str, bytes], ...]]


def _inside_f32(bound: float) -> float:
    x = np.float32(bound)
    return float(np.nextafter(x, np.float32(0)) if abs(float(x)) > abs(bound) else x)


def _values(f: Field) -> st.SearchStrategy[object]:
    """Values a unit sends: inside the field's domain (the framer rejects any other, as
    garbage), NaN included as in idle mode."""
    if f.kind == "f32":
        element = st.floats(_inside_f32(f.lo), _inside_f32(f.hi), width=32,
                            allow_infinity=False) | st.just(float("nan"))
        return st.lists(element, min_size=f.count, max_size=f.count).map(
            lambda v, shape=f.shape: np.array(v, np.float32).reshape(shape))
    if f.name == "timer":
        return st.integers(0, 0xFFFFFFFF)
    return st.lists(st.integers(int(f.lo), int(f.hi)), min_size=f.count, max_size=f.count)


def data_record(codes: list[int]) -> st.SearchStrategy[bytes]:
    """One data record of one of ``codes`` with random in-domain values."""
    return st.sampled_from(codes).flatmap(lambda code: st.fixed_dictionaries(
        {f.name: _values(f) for f in REPLIES[code].fields}).map(
        lambda values, code=code: encode_reply(code, **values)))


def as_records(batches: list[Batch]) -> list[Record]:
    out = []
    for batch in batches:
        for i in range(len(batch)):
            out.append((batch.code, tuple(
                (name, np.ascontiguousarray(col[i]).tobytes())
                for name, col in batch.columns.items())))
    return out


def offsets(batches: list[Batch]) -> list[int]:
    return [int(o) for batch in batches for o in batch.offsets]


def record_of(raw: bytes) -> Record:
    """The framer's view of one intact record, used as the expected value."""
    return as_records(Framer([raw[0]]).feed(raw))[0]


def run(framer: Framer, stream: bytes, cuts: list[int]) -> list[Batch]:
    """Feed ``stream`` cut at ``cuts`` (sorted positions), then flush."""
    out: list[Batch] = []
    start = 0
    for cut in [*cuts, len(stream)]:
        out += framer.feed(stream[start:cut])
        start = cut
    return out + framer.flush()


def chunkings(size: int) -> st.SearchStrategy[list[int]]:
    """Cut positions: from every byte on its own to one piece, and anything between."""
    every_byte = st.just(list(range(1, size)))
    random_cuts = st.lists(st.integers(1, max(1, size - 1)), max_size=40).map(
        lambda cs: sorted(set(cs) & set(range(1, size))))
    return st.one_of(st.just([]), every_byte, random_cuts)


MIXED = st.just(DATA)
ONE_TYPE = st.sampled_from(DATA).map(lambda c: [c])


@PROPERTY
@given(data=st.data(), continuous=st.booleans())
def test_clean_stream_yields_exactly_the_records_sent(
    data: st.DataObject, continuous: bool
) -> None:
    codes = data.draw(ONE_TYPE if continuous else MIXED, label="codes")
    # Continuous mode streams one type; a long run lets the NumPy fast path take over.
    raws = data.draw(st.lists(data_record(codes), min_size=1,
                              max_size=60 if continuous else 30), label="records")
    stream = b"".join(raws)
    expect = codes if continuous else None
    whole = run(Framer(expect), stream, [])
    cuts = data.draw(chunkings(len(stream)), label="cuts")
    chunked = run(Framer(expect), stream, cuts)
    assert as_records(whole) == [record_of(r) for r in raws]
    assert as_records(chunked) == as_records(whole)
    assert offsets(chunked) == offsets(whole) == list(np.cumsum([0, *map(len, raws)])[:-1])


def test_fast_path_and_byte_scanner_agree_on_a_long_run(monkeypatch: pytest.MonkeyPatch) -> None:
    """One piece takes the NumPy fast path, one byte at a time never can; same records out."""
    rng = np.random.default_rng(7)
    n = 500
    records = [
        encode_reply(0xC8, accel=a, ang_rate=w, m=np.eye(3), timer=int(t))
        for a, w, t in zip(rng.normal(size=(n, 3)), rng.normal(size=(n, 3)),
                           rng.integers(0, 1 << 32, n), strict=True)]
    damaged = bytearray(records[300])
    damaged[20] ^= 0x10
    raw = b"".join(records[:300]) + bytes(damaged) + b"".join(records[301:])
    fast_records = []
    original = Framer._fast

    def spy(self: Framer, *args: object) -> tuple[int, bool]:
        good, whole = original(self, *args)
        fast_records.append(good)
        return good, whole

    monkeypatch.setattr(Framer, "_fast", spy)
    whole = run(Framer([0xC8]), raw, [])
    assert sum(fast_records) > 400
    fast_records.clear()
    chunked = run(Framer([0xC8]), raw, list(range(1, len(raw))))
    assert fast_records == []
    assert as_records(whole) == [record_of(r) for i, r in enumerate(records) if i != 300]
    assert as_records(chunked) == as_records(whole)


@dataclass(frozen=True)
class Damaged:
    """A stream after damage, and what an ideal framer must still find in it."""

    stream: bytes
    intact: list[Record]
    intact_offsets: list[int]


# At most one corruption per record. Two flipped bits in one record are excluded on
# purpose: a 16-bit additive checksum cannot detect compensating flips (+1 in one byte,
# -1 in another leaves the sum unchanged), so no framer could reject that record.
KINDS = ("none", "none", "flip", "drop", "garbage", "cut")


@st.composite
def damaged_streams(draw: st.DrawFn, codes: list[int]) -> Damaged:
    raws = draw(st.lists(data_record(codes), min_size=1, max_size=25), label="records")
    stream = bytearray()
    intact: list[Record] = []
    intact_offsets: list[int] = []
    for raw in raws:
        kind = draw(st.sampled_from(KINDS))
        size = len(raw)
        if kind == "flip":
            bit = draw(st.integers(0, 8 * size - 1))
            damaged = bytearray(raw)
            damaged[bit // 8] ^= 1 << (bit % 8)
            stream += damaged
        elif kind == "drop":
            # Interior bytes only: dropping the first or last byte can give the very same
            # stream as dropping the neighbouring record's last or first byte.
            i = draw(st.integers(1, size - 2))
            stream += raw[:i] + raw[i + 1 :]
        elif kind == "cut":
            stream += raw[: size // 2]
        else:
            intact_offsets.append(len(stream))
            intact.append(record_of(raw))
            stream += raw
            if kind == "garbage":
                stream += draw(st.binary(min_size=1, max_size=40))
    return Damaged(bytes(stream), intact, intact_offsets)


# Deterministic on purpose: misaligned bytes still match a 16-bit checksum by chance (about
# one window in 65,536, more often on the all-zero records Hypothesis favours) and, rarely,
# look plausible too; a randomised run would then fail once in a long while.
@settings(PROPERTY, derandomize=True)
@given(data=st.data(), continuous=st.booleans())
def test_damage_loses_only_the_damaged_records(data: st.DataObject, continuous: bool) -> None:
    codes = data.draw(ONE_TYPE if continuous else MIXED, label="codes")
    case = data.draw(damaged_streams(codes), label="stream")
    cuts = data.draw(chunkings(len(case.stream)), label="cuts")
    expect = codes if continuous else None
    whole = run(Framer(expect), case.stream, [])
    chunked = run(Framer(expect), case.stream, cuts)
    # Never a record that was not sent, every untouched one, in order, where it was.
    assert as_records(whole) == case.intact
    assert offsets(whole) == case.intact_offsets
    assert as_records(chunked) == as_records(whole)


@PROPERTY
@given(st.binary(max_size=400), st.lists(st.integers(1, 400), max_size=10))
def test_garbage_never_raises(garbage: bytes, cuts: list[int]) -> None:
    framer = Framer()
    run(framer, garbage, sorted(c for c in set(cuts) if c < len(garbage)))
    stats = framer.stats
    assert stats.bytes_fed == len(garbage)
    assert framer.pending == 0
    assert stats.bytes_skipped + sum(REPLIES[c].length * n for c, n in stats.records.items()) \
        == len(garbage)


def frame(code: int, payload: bytes) -> bytes:
    body = bytes((code,)) + payload
    return body + struct.pack(">H", sum(body) % 65_536)


def test_stats_on_a_hand_made_stream() -> None:
    good_c2 = frame(0xC2, struct.pack(">6fI", 1.0, 0, 0, 0, 0, 0.5, 0x100))
    good_c7 = frame(0xC7, struct.pack(">3fI", 0, 0.25, 0, 0x200))
    bad_c2 = bytearray(good_c2)
    bad_c2[-2:] = b"\x00\x00"  # wrong checksum
    prefix, gap = b"\x00\x01\x02", b"\x55\xaa"
    # None of the skipped bytes may look like a record start, so every count is exact.
    assert not set(prefix + bytes(bad_c2[1:]) + gap) & DATA_CODES
    stream = prefix + bytes(bad_c2) + good_c2 + good_c7 + gap + good_c2 + good_c2

    framer = Framer()
    batches = framer.feed(stream) + framer.flush()

    assert [(b.code, len(b)) for b in batches] == [(0xC2, 1), (0xC7, 1), (0xC2, 2)]
    stats = framer.stats
    assert stats.records == Counter({0xC2: 3, 0xC7: 1})
    assert stats.checksum_failures == 1
    assert stats.bytes_skipped == len(prefix) + len(bad_c2) + len(gap)
    assert stats.bytes_fed == len(stream)
    assert stats.resyncs == 1  # the gap after a locked run; the start was never in step
    assert offsets(batches) == [34, 65, 86, 117]
    assert "0xC2×3, 0xC7×1" in stats.summary()
    assert "checksum failures: 1" in stats.summary()


def test_partial_record_waits_for_more_bytes_then_flush_skips_it() -> None:
    raw = frame(0xC7, struct.pack(">3fI", 0, 0, 1.0, 9))
    framer = Framer()
    assert framer.feed(raw[:10]) == []
    assert framer.pending == 10
    (batch,) = framer.feed(raw[10:] + raw[:5])
    assert batch["timer"].tolist() == [9]
    assert framer.flush() == []
    assert framer.stats.bytes_skipped == 5
    assert framer.pending == 0


def test_expect_limits_the_codes_and_rejects_unknown_ones() -> None:
    d4 = frame(0xD4, b"\x01")
    c7 = frame(0xC7, struct.pack(">3fI", 0, 0, 1.0, 9))
    framer = Framer([0xC7])
    assert [b.code for b in framer.feed(c7 + d4)] == [0xC7]
    framer.expect([0xD4, 0x21])
    assert framer.expected == {0xD4, 0x21}
    assert [b.code for b in framer.feed(d4 + b"\x21\x00\x21")] == [0xD4, 0x21]
    with pytest.raises(ValueError, match="0x99"):
        Framer([0x99])


def test_record_cut_short_in_step_is_not_trusted_on_its_checksum_alone() -> None:
    """Found by the damage property: in step after four all-zero 0xD1 records, the fifth
    is cut to 7 bytes and the sixth loses a byte; the 15 bytes from the fifth's start sum
    to 0x0319 and the next two bytes happen to be 03 19. Only the domain check (a 12-bit
    temperature cannot be 53504) tells this window from a record."""
    zero = frame(0xD1, bytes(12))
    fifth_cut, sixth_short = "d1 00 00 00 76 02 ff", "d1 00 00 00 00 00 03 19 00 00 00 00 00 ed"
    stream = zero * 4 + bytes.fromhex(fifth_cut + sixth_short)
    window = stream[60:75]
    assert sum(window[:-2]) == int.from_bytes(window[-2:], "big")
    framer = Framer([0xD1])
    batches = framer.feed(stream) + framer.flush()
    assert offsets(batches) == [0, 15, 30, 45]
    assert framer.stats.bytes_skipped == len(stream) - 60


def test_short_reply_needs_plausible_values_while_resynchronising() -> None:
    # A checksum-correct 0xD4 reply with mode 9 does not exist; after garbage it is refused.
    bogus = frame(0xD4, b"\x09")
    framer = Framer([0xD4])
    assert framer.feed(b"\x00" + bogus + frame(0xD4, b"\x02")) != []
    assert framer.stats.records == Counter({0xD4: 1})
