"""Reading archives cut short anywhere, damaged or not MCAP at all, and raw captures."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader

from bridge.archive.mcap_writer import MAGIC
from bridge.archive.rawcapture import RawCaptureWriter
from bridge.archive.reader import ArchiveReader
from bridge.archive.repair import repair
from bridge.archive.walk import read_archive, sample_span
from bridge.archive.writer import ArchiveWriter
from bridge.bus.codec import HEADER, encode_batch, record_quantities
from bridge.bus.gx3_pb2 import Event, ImuSample, Info, Status
from bridge.exceptions import ArchiveReadError
from tests.helpers.archives import FLEET, LATENCY, PERIOD, write_fleet
from tests.helpers.records import T0, synthetic_batch


def record_ends(data: bytes) -> list[int]:
    """Byte offsets where each top-level MCAP record ends (an independent walk)."""
    ends, off = [], len(MAGIC)
    while off + 9 <= len(data):
        (length,) = struct.unpack_from("<Q", data, off + 1)
        off += 9 + length
        ends.append(off)
    return ends


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("read") / "fleet.mcap"
    write_fleet(path, chunk_size=6_000)
    return path


def test_a_cut_archive_reads_exactly_its_complete_chunks_at_any_cut(
        fleet: Path, tmp_path: Path) -> None:
    data = fleet.read_bytes()
    full = read_archive(fleet)
    with fleet.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    chunks = [(ci.chunk_start_offset, ci.chunk_start_offset + ci.chunk_length)
              for ci in summary.chunk_indexes]
    assert len(chunks) >= 8
    ends = record_ends(data)
    by_chunk = full.blocks  # one block per chunk, in file order
    assert len(by_chunk) == len(chunks)
    rng = np.random.default_rng(7)
    cuts = {9, 17, 30, len(data) - 1, len(data) - 8, *rng.integers(8, len(data), 25).tolist()}
    for start, end in chunks[:: max(1, len(chunks) // 6)]:
        cuts |= {start, start + 1, end - 1, end, end + 1, (start + end) // 2}
    cut_file = tmp_path / "cut.mcap"
    for cut in sorted(cuts):
        cut_file.write_bytes(data[:cut])
        archive = read_archive(cut_file)  # never raises
        complete = [i for i, (_, end) in enumerate(chunks) if end <= cut]
        expected = sum(len(by_chunk[i]) for i in complete)
        assert archive.message_count == expected, cut
        assert archive.chunks == len(complete), cut
        kept = max([e for e in ends if e <= cut], default=len(MAGIC))
        if cut < len(data):
            assert not archive.complete
            assert archive.dropped_bytes == cut - kept, cut
        topic = "gx3/u1/imu"
        got = archive.messages(topic).payloads
        assert got == full.messages(topic).payloads[: len(got)], cut


def test_truncated_samples_decode_and_repair_gives_an_indexed_file(
        fleet: Path, tmp_path: Path) -> None:
    data = fleet.read_bytes()
    with fleet.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    middle = summary.chunk_indexes[len(summary.chunk_indexes) // 2]
    cut_file = tmp_path / "cut.mcap"
    cut_file.write_bytes(data[: middle.chunk_start_offset + middle.chunk_length // 2])
    archive = read_archive(cut_file)
    samples = {s.unit: s for s in archive.samples()}
    assert 0 < len(samples["u1"]) < FLEET["u1"][1]
    assert np.all(np.diff(samples["u1"].columns["time_ns"]) > 0)
    report = repair(cut_file)
    assert report.output == tmp_path / "cut.repaired.mcap"
    assert report.messages == archive.message_count and not report.was_complete
    assert report.dropped_bytes == archive.dropped_bytes > 0
    with report.output.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == archive.message_count
        assert summary.chunk_indexes
        assert {c.topic for c in summary.channels.values()} == set(archive.topics())
        names = {s.name for s in summary.schemas.values()}
        assert names == {s.name for s in archive.schemas.values()} >= {"gx3.v1.ImuSample"}
    repaired = read_archive(report.output)
    assert repaired.complete
    for topic in archive.topics():
        assert repaired.messages(topic).payloads == archive.messages(topic).payloads
    assert [m.metadata for m in repaired.metadata] == [m.metadata for m in archive.metadata]


def test_repair_refuses_to_overwrite_its_input(fleet: Path) -> None:
    with pytest.raises(ArchiveReadError, match="overwrite"):
        repair(fleet, fleet)


def test_files_that_are_not_archives_get_one_line_errors(tmp_path: Path) -> None:
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    text = tmp_path / "notes.mcap"
    text.write_text("hello\n")
    for path, says in ((empty, "empty file"), (text, "not an MCAP file"),
                       (tmp_path / "nope.mcap", "no such file"), (tmp_path, "is a directory")):
        with pytest.raises(ArchiveReadError) as info:
            read_archive(path)
        assert says in str(info.value) and "\n" not in str(info.value)


def test_garbage_after_the_magic_reads_as_nothing_with_the_reason(tmp_path: Path) -> None:
    path = tmp_path / "garbage.mcap"
    path.write_bytes(MAGIC + np.random.default_rng(1).bytes(5000))
    archive = read_archive(path)
    assert archive.message_count == 0 and not archive.complete
    assert archive.dropped_bytes > 0 and archive.problem


def test_a_corrupt_chunk_of_a_file_cut_short_keeps_the_chunks_before_it(
        fleet: Path, tmp_path: Path) -> None:
    """No summary, so no index to find the next chunk by: the reading stops there."""
    data = bytearray(fleet.read_bytes())
    with fleet.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    third, sixth = summary.chunk_indexes[3], summary.chunk_indexes[6]
    middle = third.chunk_start_offset + third.chunk_length // 2
    data[middle : middle + 16] = bytes(16)
    path = tmp_path / "corrupt.mcap"
    path.write_bytes(bytes(data[: sixth.chunk_start_offset]))
    archive = read_archive(path)
    assert archive.chunks == 3 and not archive.complete and not archive.damage
    assert archive.problem and "corrupt record" in archive.problem
    assert archive.dropped_bytes == sixth.chunk_start_offset - third.chunk_start_offset


def test_raw_captures_read_with_their_receive_times(tmp_path: Path) -> None:
    path = tmp_path / "raw.mcap"
    capture = RawCaptureWriter(path, "gx3", "u7", {"port": "/dev/ttyUSB0"})
    reads = [(bytes([i]) * (i + 1), 1_000 + i * 7) for i in range(50)]
    for data, rx in reads:
        capture.write(data, rx)
    capture.close()
    archive = read_archive(path)
    assert archive.topics() == ["gx3/u7/raw"] and archive.units() == ["u7"]
    got = archive.messages("gx3/u7/raw")
    assert got.kind == "raw"
    assert got.payloads == [d for d, _ in reads]
    assert got.log_time.tolist() == [rx for _, rx in reads]


def test_messages_of_all_topics_come_in_log_time_order(fleet: Path) -> None:
    archive = read_archive(fleet)
    records = list(archive.iter_messages())
    assert len(records) == archive.message_count
    times = [r.log_time for r in records]
    assert times == sorted(times)
    u2 = list(archive.iter_messages(units=["u2"]))
    assert {r.topic for r in u2} == {"gx3/u2/imu", "gx3/u2/status", "gx3/u2/event",
                                     "gx3/u2/info", "gx3/u2/frame", "gx3/u2/axes"}
    assert u2 == [r for r in records if r.topic.startswith("gx3/u2/")]
    summary = archive.summary()
    for unit, (code, n, _) in FLEET.items():
        assert f"{unit} 0x{code:02X}: {n} samples" in summary


# -- the bulk reader against the MCAP library, message by message ----------------------

#: unit -> record types it sends, in turn (a unit that switches types mid-run, names of
#: several lengths, one without attitude)
MIXED = {"u1": (0xCC, 0xC2), "imu-long-2": (0xDF,), "u3": (0xC2,)}


#: A raw read whose last bytes look like a whole message record of its own.
FAKE_RECORD = b"\x05" + struct.pack("<Q", 22) + bytes(22)
RAW = b"\xcc\x00\x01raw bytes" + FAKE_RECORD


def _reordered(payload: bytes) -> bytes:
    """The same ImuSample with its unit field moved to the end: as long as the bulk
    layout, valid protobuf, but not the layout."""
    end = 2 + payload[1]
    return payload[end:] + payload[:end]


def write_mixed(path: Path) -> None:
    """Three units, two record types for one, status, events, info, a raw read, and two
    samples in another encoding: one reordered, one with an unknown field appended."""
    feed: list[tuple[int, str, bytes]] = []
    for k, (unit, codes) in enumerate(MIXED.items()):
        for j, code in enumerate(codes):
            n = 120
            time_ns = T0 + (j * n + np.arange(n, dtype=np.int64)) * PERIOD + k * 1000
            euler = np.stack([np.linspace(0, 1, n)] * 3, axis=1)
            payloads = encode_batch(unit, synthetic_batch(code, n, 10 * k + j, euler),
                                    (j * n + np.arange(n, dtype=np.int64)) * 625, time_ns,
                                    time_ns + LATENCY)
            if unit == "u3":
                payloads[50] = _reordered(payloads[50])
            if code == 0xCC:
                payloads[70] += bytes([0xC0, 0x3E, 0x01])  # field 1000, varint 1
            feed += [(int(t) + LATENCY, f"gx3/{unit}/imu", p)
                     for t, p in zip(time_ns, payloads, strict=True)]
            for s in range(0, n, 40):
                t = int(time_ns[s])
                feed.append((t + 1, f"gx3/{unit}/status",
                             Status(unit=unit, time_ns=t, samples=s).SerializeToString()))
            feed.append((int(time_ns[n // 2]) + 2, f"gx3/{unit}/event", Event(
                unit=unit, time_ns=int(time_ns[n // 2]), kind=Event.GAP, count=j + 1,
                detail=f"{unit} {j}").SerializeToString()))
        feed.append((T0 - 4 + k, f"gx3/{unit}/info",
                     Info(unit=unit, bring_up_time_ns=T0 - 5).SerializeToString()))
    feed.append((T0 + 7, "gx3/u1/raw", RAW))
    feed.sort(key=lambda f: f[0])
    with ArchiveWriter(path, chunk_size=5_000) as writer:
        for receive_ns, key, payload in feed:
            writer.write(key, payload, receive_ns)


def top_records(data: bytes) -> list[tuple[int, int, int]]:
    """(opcode, start, end) of each whole top-level record (an independent walk)."""
    out, off = [], len(MAGIC)
    while off + 9 <= len(data):
        opcode, length = struct.unpack_from("<BQ", data, off)
        if off + 9 + length > len(data):
            break
        out.append((opcode, off, off + 9 + length))
        off += 9 + length
    return out


def reference(path: Path) -> tuple[dict[int, Channel], list[Message]]:
    """Channels and messages as the MCAP library reads them, one object each, up to where
    it stops (the end, or a record cut short)."""
    channels: dict[int, Channel] = {}
    messages: list[Message] = []
    with path.open("rb") as f:
        try:
            for record in StreamReader(f).records:
                if isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Message):
                    messages.append(record)
        except Exception:  # the library stops at a cut-off record, as it should
            pass
    return channels, messages


def by_log_time(messages: list[Message]) -> list[Message]:
    return sorted(messages, key=lambda m: m.log_time)  # stable: file order among equals


def assert_reads_like_the_library(path: Path) -> None:
    channels, messages = reference(path)
    archive = read_archive(path)
    assert archive.message_count == len(messages)
    topics = sorted({channels[m.channel_id].topic for m in messages})
    assert [t for t in archive.topics() if len(archive.messages(t))] == topics
    for topic in topics:
        want = by_log_time([m for m in messages if channels[m.channel_id].topic == topic])
        got = archive.messages(topic)
        assert got.payloads == [m.data for m in want], topic
        assert got.log_time.tolist() == [m.log_time for m in want], topic
        assert got.publish_time.tolist() == [m.publish_time for m in want], topic
        assert got.sequence.tolist() == [m.sequence for m in want], topic
    imu = by_log_time([m for m in messages if channels[m.channel_id].topic.endswith("/imu")])
    parsed = [(ImuSample.FromString(m.data), m.publish_time) for m in imu]
    samples = archive.samples()
    assert sorted((s.unit, s.code) for s in samples) == sorted(
        {(p.unit, p.command) for p, _ in parsed})
    for s in samples:
        mine = [(p, rx) for p, rx in parsed if (p.unit, p.command) == (s.unit, s.code)]
        assert s.receive_ns.tolist() == [rx for _, rx in mine]
        for name in HEADER:
            assert s.columns[name].tolist() == [getattr(p, name) for p, _ in mine], name
        for q in record_quantities(s.code):
            want_q = np.array([list(getattr(p, q)) for p, _ in mine], np.float64)
            np.testing.assert_array_equal(s.columns[q].reshape(len(mine), -1), want_q, q)
    events = by_log_time([m for m in messages if channels[m.channel_id].topic.endswith("/event")])
    assert [(u, e.SerializeToString()) for u, e in archive.events()] == [
        (Event.FromString(m.data).unit, m.data) for m in events]


def test_bulk_reading_gives_what_the_mcap_library_reads(tmp_path: Path) -> None:
    path = tmp_path / "mixed.mcap"
    write_mixed(path)
    data = path.read_bytes()
    records = top_records(data)
    chunks = [(start, end) for op, start, end in records if op == Opcode.CHUNK]
    indexes = [(start, end) for op, start, end in records if op == Opcode.MESSAGE_INDEX]
    assert len(chunks) >= 6 and indexes
    archive = read_archive(path)
    assert {(s.unit, s.code) for s in archive.samples()} == {
        (u, c) for u, codes in MIXED.items() for c in codes}
    assert archive.topics("status") and archive.topics("info") and archive.topics("raw")
    variants = {"whole": data,
                "cut in a chunk": data[: (chunks[-2][0] + chunks[-2][1]) // 2],
                "cut in the indexes after a chunk": data[: chunks[-3][1] + 20]}
    # message indexes that lie: one lists nothing, one points one byte off, and the raw
    # read's points at the message record look-alike inside it
    lying = bytearray(data)
    start, _ = indexes[0]
    lying[start + 9 + 2 : start + 9 + 6] = bytes(4)
    start, end = indexes[len(indexes) // 2]
    assert end - start >= 9 + 6 + 16
    (offset,) = struct.unpack_from("<Q", lying, start + 9 + 6 + 8)
    struct.pack_into("<Q", lying, start + 9 + 6 + 8, offset + 1)
    (raw_id,) = (c.id for c in archive.channels.values() if c.kind == "raw")
    (start, _), = ((s, e) for s, e in indexes
                   if struct.unpack_from("<H", data, s + 9)[0] == raw_id)
    (offset,) = struct.unpack_from("<Q", lying, start + 9 + 6 + 8)
    struct.pack_into("<Q", lying, start + 9 + 6 + 8,
                     offset + 9 + 22 + len(RAW) - len(FAKE_RECORD))
    variants["lying indexes"] = bytes(lying)
    for name, content in variants.items():
        cut = tmp_path / f"{name.replace(' ', '_')}.mcap"
        cut.write_bytes(content)
        assert_reads_like_the_library(cut)


def test_a_window_reads_only_its_chunks_and_all_of_its_messages(fleet: Path) -> None:
    """Of a finished file, the chunks that can hold messages logged in the window, no
    other; every message logged in it is among what is read, on the channels of the
    summary (those registered in chunks left unread too)."""
    full = read_archive(fleet)
    with fleet.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    lo, hi = T0 + 1_000_000_000, T0 + 1_500_000_000
    window = read_archive(fleet, between=(lo, hi))
    overlapping = [c for c in summary.chunk_indexes
                   if c.message_end_time >= lo and c.message_start_time < hi]
    assert 0 < window.chunks == len(overlapping) < full.chunks
    assert window.topics() == full.topics()
    for topic in full.topics():
        every, some = full.messages(topic), window.messages(topic)
        inside = (every.log_time >= lo) & (every.log_time < hi)
        kept = np.isin(some.log_time, every.log_time[inside])
        assert [p for p, k in zip(some.payloads, kept, strict=True) if k] == [
            p for p, i in zip(every.payloads, inside, strict=True) if i], topic
    assert read_archive(fleet, between=(None, T0 - 10**9)).chunks == 0
    assert read_archive(fleet, between=(T0 + 10**12, None)).chunks == 0


def test_the_span_of_samples_from_the_summary_or_by_reading(fleet: Path,
                                                            tmp_path: Path) -> None:
    """Units, counts and the first sample's time from a finished file's summary and the
    chunks that can hold it; a file cut short is read through for the same."""
    full = read_archive(fleet)
    last = max(int(b.columns["time_ns"].max()) for b in full.samples())
    span = sample_span(fleet)
    assert span.counts == samples_per_unit(full) == {u: n for u, (_, n, _) in FLEET.items()}
    assert span.first_ns == full.first_sample_ns()
    assert span.last_ns is not None and last <= span.last_ns <= last + 10**9
    data = fleet.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    read = read_archive(cut)
    span = sample_span(cut)
    assert span.counts == samples_per_unit(read)
    assert span.first_ns == read.first_sample_ns()
    assert span.last_ns == max(int(b.columns["time_ns"].max()) for b in read.samples())


def samples_per_unit(archive: ArchiveReader) -> dict[str, int]:
    counts: dict[str, int] = {}
    for block in archive.samples():
        counts[block.unit] = counts.get(block.unit, 0) + len(block)
    return counts
