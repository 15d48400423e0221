"""Reading archives cut short anywhere, damaged or not MCAP at all, and raw captures."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from bridge.recorder.rawcapture import RawCaptureWriter
from bridge.recorder.read import MAGIC, ArchiveReadError, read_archive
from bridge.recorder.repair import repair
from tests.test_archive_writer import FLEET, write_fleet


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


def test_a_corrupt_chunk_keeps_the_chunks_before_it(fleet: Path, tmp_path: Path) -> None:
    data = bytearray(fleet.read_bytes())
    with fleet.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    third = summary.chunk_indexes[3]
    middle = third.chunk_start_offset + third.chunk_length // 2
    data[middle : middle + 16] = bytes(16)
    path = tmp_path / "corrupt.mcap"
    path.write_bytes(bytes(data))
    archive = read_archive(path)
    assert archive.chunks == 3 and not archive.complete
    assert archive.problem and "corrupt record" in archive.problem
    assert archive.dropped_bytes == len(data) - third.chunk_start_offset


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
                                     "gx3/u2/info", "gx3/u2/frame"}
    assert u2 == [r for r in records if r.topic.startswith("gx3/u2/")]
    summary = archive.summary()
    for unit, (code, n, _) in FLEET.items():
        assert f"{unit} 0x{code:02X}: {n} samples" in summary
