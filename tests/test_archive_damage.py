"""A finished archive with a flipped byte, or with messages that are not what their topic
says: every reader skips only what is damaged, says what, and reads the rest."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk, ChunkIndex, Message
from mcap.stream_reader import breakup_chunk
from mcap.summary import Summary

from bridge.archive.reader import ArchiveReader
from bridge.archive.walk import read_archive
from bridge.archive.writer import ArchiveWriter
from bridge.bus.codec import encode_batch
from bridge.bus.gx3_pb2 import Event, ImuSample, Status
from tests.helpers.archives import PERIOD
from tests.helpers.processes import GX3
from tests.helpers.records import T0, synthetic_batch

UNITS = ("u1", "u2")
SAMPLES = 3_000  # per unit, 100 Hz: 30 s


@pytest.fixture(scope="module")
def archive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two units of 0xCC samples with status and events, in 16 kB chunks."""
    path = tmp_path_factory.mktemp("damage") / "two.mcap"
    with ArchiveWriter(path, chunk_size=16_000) as writer:
        for k, unit in enumerate(UNITS):
            t = T0 + np.arange(SAMPLES, dtype=np.int64) * PERIOD + k * 1_000
            payloads = encode_batch(unit, synthetic_batch(0xCC, SAMPLES, k + 1),
                                    np.arange(SAMPLES, dtype=np.int64) * 625, t, t + 3)
            for lo in range(0, SAMPLES, 100):  # a second at a time, as a recorder does
                writer.write_many(f"gx3/{unit}/imu", payloads[lo : lo + 100], t[lo : lo + 100] + 5)
                status = Status(unit=unit, time_ns=int(t[lo]), samples=lo).SerializeToString()
                writer.write_many(f"gx3/{unit}/status", [status], int(t[lo]) + 5)
            event = Event(unit=unit, time_ns=int(t[100]), kind=Event.GAP, count=1)
            writer.write_many(f"gx3/{unit}/event", [event.SerializeToString()], int(t[100]) + 5)
    return path


def summary_of(path: Path) -> Summary:
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    return summary


def flipped(source: Path, out: Path, offset: int) -> Path:
    data = bytearray(source.read_bytes())
    data[offset] ^= 0xFF
    out.write_bytes(bytes(data))
    return out


def imu_count(archive: ArchiveReader) -> int:
    return sum(len(s) for s in archive.samples())


def test_a_flipped_byte_loses_one_chunk_and_says_which(archive: Path, tmp_path: Path) -> None:
    """A byte flipped a quarter into the file: that chunk's CRC fails; the chunks after it
    are read, and the warning gives the span and the messages lost, per topic, from the
    chunk index and its message indexes (on main: 23 % of the samples, "not finished")."""
    at = a_quarter_in(archive)
    hit, lost = chunk_at(archive, at)
    warned: list[str] = []
    damaged = read_archive(flipped(archive, tmp_path / "flip.mcap", at), warn=warned.append)
    full = read_archive(archive)
    assert damaged.complete and len(damaged.damage) == 1 and len(warned) == 1
    d = damaged.damage[0]
    assert (d.offset, d.start_ns, d.end_ns) == (hit.chunk_start_offset,
                                                hit.message_start_time, hit.message_end_time)
    assert d.lost == lost and sum(lost.values()) > 0
    assert damaged.message_count == full.message_count - sum(lost.values())
    imu_lost = sum(n for t, n in lost.items() if t.endswith("/imu"))
    assert imu_count(damaged) == imu_count(full) - imu_lost
    # zstd's own check or the chunk's CRC, whichever the flipped byte trips first
    assert str(sum(lost.values())) in warned[0]
    assert "CRC" in warned[0].upper() or "CORRUPTION" in warned[0].upper()


def a_quarter_in(path: Path) -> int:
    """A byte about a quarter into the file, in the middle of a chunk's messages."""
    quarter = path.stat().st_size // 4
    chunk = min(summary_of(path).chunk_indexes,
                key=lambda c: abs(c.chunk_start_offset + c.chunk_length // 2 - quarter))
    return chunk.chunk_start_offset + chunk.chunk_length // 2


def chunk_at(path: Path, at: int) -> tuple[ChunkIndex, dict[str, int]]:
    """The chunk of the intact file that holds byte ``at`` (past its head), and its
    messages per topic, read with mcap's own parsers."""
    summary = summary_of(path)
    chunk = next(c for c in summary.chunk_indexes
                 if c.chunk_start_offset + 40 < at < c.chunk_start_offset + c.chunk_length)
    with path.open("rb") as f:
        f.seek(chunk.chunk_start_offset + 9)
        record = Chunk.read(ReadDataStream(f))
    counts: dict[str, int] = {}
    for r in breakup_chunk(record, validate_crc=True):
        if isinstance(r, Message):
            topic = summary.channels[r.channel_id].topic
            counts[topic] = counts.get(topic, 0) + 1
    return chunk, counts


def test_a_flipped_byte_in_the_first_chunk_keeps_its_channels(archive: Path,
                                                              tmp_path: Path) -> None:
    """Offset 300 is in the first chunk, which holds the schemas and channels: the
    summary's copies stand in for them (on main: nothing readable)."""
    first = summary_of(archive).chunk_indexes[0]
    assert first.chunk_start_offset < 300 < first.chunk_start_offset + first.chunk_length
    _, lost = chunk_at(archive, 300)
    damaged = read_archive(flipped(archive, tmp_path / "flip.mcap", 300))
    assert damaged.units() == list(UNITS) and len(damaged.damage) == 1
    assert imu_count(damaged) == 2 * SAMPLES - sum(n for t, n in lost.items()
                                                   if t.endswith("/imu"))


def run(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([GX3, *map(str, args)], capture_output=True, text=True, timeout=120,
                          check=False)


def test_export_rrd_and_repair_of_a_damaged_archive(archive: Path, tmp_path: Path) -> None:
    at = a_quarter_in(archive)
    damaged = flipped(archive, tmp_path / "flip.mcap", at)
    _, lost = chunk_at(archive, at)
    imu_lost = sum(n for t, n in lost.items() if t.endswith("/imu"))
    done = run("export", damaged, "-o", tmp_path / "out.parquet")
    assert done.returncode == 0, done.stderr
    assert pq.read_table(tmp_path / "out.parquet").num_rows == 2 * SAMPLES - imu_lost
    assert done.stderr.count("corrupt chunk") == 1 and "Traceback" not in done.stderr
    done = run("rrd", damaged, "-o", tmp_path / "out.rrd")
    assert done.returncode == 0 and "corrupt chunk" in done.stderr, done.stderr
    done = run("repair", damaged, "-o", tmp_path / "fixed.mcap")
    assert done.returncode == 0, done.stderr
    fixed = read_archive(tmp_path / "fixed.mcap")
    assert fixed.complete and not fixed.damage
    assert imu_count(fixed) == 2 * SAMPLES - imu_lost


def test_repair_that_recovers_nothing_fails_in_one_line(tmp_path: Path) -> None:
    """An archive whose only chunk is damaged (on main: "success" with 0 messages)."""
    path = tmp_path / "one.mcap"
    with ArchiveWriter(path) as writer:
        writer.write_many("gx3/u1/status", [Status(unit="u1", time_ns=T0).SerializeToString()],
                          T0)
    chunk = summary_of(path).chunk_indexes[0]
    end = chunk.chunk_start_offset + chunk.chunk_length
    damaged = flipped(path, tmp_path / "flip.mcap", end - 3)
    done = run("repair", damaged, "-o", tmp_path / "fixed.mcap")
    assert done.returncode == 2 and not (tmp_path / "fixed.mcap").exists()
    assert len(done.stderr.strip().splitlines()) == 1 and "no message" in done.stderr


def test_readers_skip_a_forged_sample_and_count_it(tmp_path: Path) -> None:
    """A sample whose unit disagrees with its topic, and bytes that are no sample at all,
    in an archive from another writer: export and rrd leave them out with one warning
    (on main: export refuses the file, rrd prints a traceback)."""
    path = tmp_path / "forged.mcap"
    t = T0 + np.arange(200, dtype=np.int64) * PERIOD
    good = encode_batch("u1", synthetic_batch(0xCC, 200, 1), np.arange(200), t, t)
    forged = encode_batch("u2", synthetic_batch(0xCC, 1, 2), np.arange(1), t[:1] + 5, t[:1])
    with ArchiveWriter(path) as writer:
        f = writer._current()  # another writer's file: what our own writer would refuse
        writer.write_many("gx3/u1/imu", good[:100], t[:100])
        writer.write_many("gx3/u1/status", [Status(unit="u1", time_ns=T0).SerializeToString()],
                          T0)
        cid = f.channels["gx3/u1/imu"]
        f.writer.add(cid, 100, t[:1] + 5, t[:1], forged)
        f.writer.add(cid, 101, t[:1] + 6, t[:1], [b"\xff\xff not a sample"])
        f.writer.add(f.channels["gx3/u1/status"], 1, t[:1] + 7, t[:1], [b"\xff\xff"])
        writer.write_many("gx3/u1/imu", good[100:], t[100:])
    assert ImuSample.FromString(forged[0]).unit == "u2"
    done = run("export", path, "-o", tmp_path / "out.csv")
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "out.csv").read_text().count("\n") == 201
    assert done.stderr.count("gx3/u1/imu: skipped 1 message(s)") == 2  # one per reason
    assert "Traceback" not in done.stderr
    done = run("rrd", path, "-o", tmp_path / "out.rrd")
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
    assert "gx3/u1/status: skipped 1 message(s)" in done.stderr  # it does not parse
