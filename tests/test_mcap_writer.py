"""The bulk MCAP writer against the specification, checked with mcap's own record parsers:
every chunk's message index points at its messages, the summary counts what is there, the
footer's CRC covers the summary, and mcap's readers agree with what was written."""

from __future__ import annotations

import io
import itertools
import struct
import zlib
from pathlib import Path

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.reader import NonSeekingReader, make_reader
from mcap.records import Chunk, Footer, MessageIndex
from mcap.stream_reader import get_chunk_data_stream

from bridge.archive.mcap_writer import MAGIC, McapWriter
from tests.helpers.records import T0

Written = list[tuple[int, int, int, int, bytes]]  # channel, sequence, log, publish, data


def write(path: Path, chunk_size: int = 2_000) -> Written:
    """Three channels: fixed-size payloads in bulk, payloads of every size (and empty ones)
    a few at a time, log times out of order within a call. Returned in the order the
    file holds them: by log time, messages of one time in the order added."""
    rng = np.random.default_rng(5)
    out: Written = []
    with path.open("wb") as stream:
        w = McapWriter(stream, chunk_size)
        w.start("test", "bridge")
        schema = w.register_schema("s", "protobuf", b"\x01\x02")
        ids = [w.register_channel(f"t/{k}", "protobuf", schema, {"k": str(k)})
               for k in range(2)]
        w.add_metadata("meta", {"a": "b"})
        sequence = {1: 0, 2: 0, 3: 0}
        for step in range(40):
            if step == 10:
                ids.append(w.register_channel("t/late", "octet", 0, {}))
            channel = ids[step % len(ids)]
            n = int(rng.integers(1, 60))
            if channel == 1:
                payloads = [rng.bytes(24) for _ in range(n)]
            else:
                payloads = [rng.bytes(int(k)) for k in rng.integers(0, 90, n)]
            log = T0 + step * 10**9 + rng.integers(0, 10**9, n)
            pub = log + 5
            w.add(channel, sequence[channel], log, pub, payloads)
            out += [(channel, sequence[channel] + i, int(log[i]), int(pub[i]), payloads[i])
                    for i in range(n)]
            sequence[channel] += n
            if step % 13 == 12:
                w.release(T0 + step * 10**9 + 5 * 10**8)
                w.flush()
        w.finish()
    assert w.late == 0
    return sorted(out, key=lambda m: m[2])


def test_standard_readers_give_back_every_message_with_its_times(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    written = write(path)
    with path.open("rb") as f:
        reader = make_reader(f, validate_crcs=True)
        got = [(c.id, m.sequence, m.log_time, m.publish_time, m.data)
               for _, c, m in reader.iter_messages(log_time_order=False)]
        summary = reader.get_summary()
        assert summary is not None
        by_time = [m.log_time for _, _, m in reader.iter_messages()]
        assert [m.name for m in reader.iter_metadata()] == ["meta"]
    assert got == written
    assert by_time == sorted(w[2] for w in written)
    stats = summary.statistics
    assert stats is not None
    assert stats.message_count == len(written)
    assert (stats.message_start_time, stats.message_end_time) == (
        min(w[2] for w in written), max(w[2] for w in written))
    assert dict(stats.channel_message_counts) == {
        c: sum(1 for w in written if w[0] == c) for c in (1, 2, 3)}
    assert (stats.schema_count, stats.channel_count, stats.metadata_count) == (1, 3, 1)
    assert stats.chunk_count == len(summary.chunk_indexes) > 10
    assert {c.id: (c.topic, c.metadata) for c in summary.channels.values()} == {
        1: ("t/0", {"k": "0"}), 2: ("t/1", {"k": "1"}), 3: ("t/late", {})}
    with path.open("rb") as f:
        streamed = [(c.id, m.sequence, m.log_time, m.publish_time, m.data)
                    for _, c, m in NonSeekingReader(f).iter_messages(log_time_order=False)]
    assert streamed == written


def _record(data: bytes, at: int, opcode: int) -> ReadDataStream:
    op, length = struct.unpack_from("<BQ", data, at)
    assert op == opcode
    return ReadDataStream(io.BytesIO(data[at + 9 : at + 9 + length]))


def test_chunk_and_message_indexes_point_at_every_message(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    written = write(path)
    data = path.read_bytes()
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    seen = []
    for ci in summary.chunk_indexes:
        chunk = Chunk.read(_record(data, ci.chunk_start_offset, 0x06))
        assert ci.chunk_length == 9 + struct.unpack_from("<Q", data, ci.chunk_start_offset + 1)[0]
        assert (ci.compression, ci.compressed_size, ci.uncompressed_size) == (
            "zstd", len(chunk.data), chunk.uncompressed_size)
        assert (ci.message_start_time, ci.message_end_time) == (
            chunk.message_start_time, chunk.message_end_time)
        stream, size = get_chunk_data_stream(chunk, validate_crc=True)
        records = stream.read(size)
        messages = {}
        at = 0
        while at < len(records):  # every record of the chunk, messages by offset
            opcode, length = struct.unpack_from("<BQ", records, at)
            if opcode == 0x05:
                messages[at] = struct.unpack_from("<HIQ", records, at + 9)
            at += 9 + length
        indexed = {}
        assert ci.message_index_offsets  # one index record per channel, right after the chunk
        assert min(ci.message_index_offsets.values()) == ci.chunk_start_offset + ci.chunk_length
        for channel, offset in ci.message_index_offsets.items():
            index = MessageIndex.read(_record(data, offset, 0x07))
            assert index.channel_id == channel
            for log_time, where in index.records:
                channel_id, _, logged = messages[where]
                assert (channel_id, logged) == (channel, log_time)
                indexed[where] = log_time
        assert indexed.keys() == messages.keys()
        times = [t for _, _, t in messages.values()]
        assert (min(times), max(times)) == (chunk.message_start_time, chunk.message_end_time)
        seen += [messages[k] for k in sorted(messages)]
    assert [(c, s, t) for c, s, t, _, _ in written] == seen


def test_footer_crc_covers_the_summary_and_summary_offsets_name_their_groups(
        tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    write(path)
    data = path.read_bytes()
    assert data.startswith(MAGIC) and data.endswith(MAGIC)
    footer_at = len(data) - len(MAGIC) - 9 - 20
    footer = Footer.read(_record(data, footer_at, 0x02))
    assert footer.summary_crc == zlib.crc32(data[footer.summary_start : footer_at + 9 + 16])
    offsets = footer.summary_offset_start
    groups = {}
    while offsets < footer_at:
        opcode, group_start, group_length = struct.unpack_from("<BQQ", data, offsets + 9)
        assert data[offsets] == 0x0E
        groups[opcode] = (group_start, group_length)
        assert data[group_start] == opcode
        offsets += 9 + 17
    assert set(groups) == {0x03, 0x04, 0x0B, 0x08, 0x0D}


def test_a_chunk_closes_after_the_message_that_passes_its_size(tmp_path: Path) -> None:
    """As mcap's writer does: records past ``chunk_size`` by the last message written."""
    path = tmp_path / "a.mcap"
    with path.open("wb") as stream:
        w = McapWriter(stream, chunk_size=1_000)
        w.start("", "")
        channel = w.register_channel("t", "octet", 0, {})
        for i in range(25):
            w.add(channel, i, np.array([T0 + i]), np.array([T0]), [bytes(100)])
            w.release()
        w.add(channel, 25, np.full(30, T0 + 30), np.full(30, T0), [bytes(100)] * 30)
        w.finish()
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    # the channel record (31 bytes) and 131-byte messages: 8 messages pass 1,000 bytes,
    # and 8 more each chunk after it
    assert [ci.uncompressed_size for ci in summary.chunk_indexes] == [
        31 + 8 * 131, 8 * 131, 8 * 131, 8 * 131, 8 * 131, 8 * 131, 7 * 131]


def test_messages_are_written_in_log_time_order_and_chunks_never_overlap(
        tmp_path: Path) -> None:
    """Held messages go out sorted up to each release; one added behind what is written
    is written at the time of the last one written, and counted."""
    path = tmp_path / "a.mcap"
    rng = np.random.default_rng(2)
    with path.open("wb") as stream:
        w = McapWriter(stream, chunk_size=500)
        w.start("", "")
        channels = [w.register_channel(f"t/{k}", "octet", 0, {}) for k in range(3)]
        sequence = dict.fromkeys(channels, 0)
        for step in range(30):
            for c in channels:
                log = T0 + step * 1000 + np.sort(rng.integers(-1500, 1000, 7))
                w.add(c, sequence[c], log, log, [bytes(20)] * 7)
                sequence[c] += 7
            w.release(T0 + step * 1000 - 1000)
        late = T0 + 10
        w.add(channels[0], sequence[channels[0]], np.array([late]), np.array([late]), [b"x"])
        w.finish()
        assert w.late == 1
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        logs = [m.log_time for _, _, m in reader.iter_messages(log_time_order=False)]
        last = [(m.log_time, m.publish_time, m.data) for _, _, m in reader.iter_messages(
            log_time_order=False) if m.data == b"x"]
    assert summary is not None
    assert logs == sorted(logs) and len(logs) == 30 * 3 * 7 + 1
    spans = [(ci.message_start_time, ci.message_end_time) for ci in summary.chunk_indexes]
    assert len(spans) > 10 and all(a[1] <= b[0] for a, b in itertools.pairwise(spans))
    # at the time of the last message the last release wrote (up to T0 + 28,000)
    assert last == [(max(t for t in logs if t <= T0 + 28_000), late, b"x")]


def test_a_file_sorted_whole_spills_sorted_runs_and_merges_them(tmp_path: Path) -> None:
    """Held past ``spill_bytes``, messages go to sorted runs in an unnamed file beside the
    output; at the end the runs are merged: the same file as sorted in memory, and the
    writer's memory stays near ``spill_bytes``."""
    rng = np.random.default_rng(9)
    batches = []
    for unit in range(4):  # a replay: unit after unit, each over the same hour
        log = T0 + np.sort(rng.integers(0, 3600 * 10**9, 3_000))
        payloads = [rng.bytes(int(k)) for k in rng.integers(10, 60, len(log))]
        batches += [(unit + 1, lo, log[lo : lo + 500], payloads[lo : lo + 500])
                    for lo in range(0, len(log), 500)]
    log[:7] = log[0]  # messages of one time keep the order they were added in
    files = {}
    for spill in (1 << 30, 20_000):
        path = tmp_path / f"{spill}.mcap"
        with path.open("wb") as stream:
            w = McapWriter(stream, chunk_size=4_000, spill_bytes=spill, spill_dir=tmp_path)
            w.start("", "")
            for c in range(4):
                w.register_channel(f"u{c}", "octet", 0, {})
            for channel, lo, t, p in batches:
                w.add(channel, lo, t, t, p)
                assert w.held_bytes <= spill + 500 * 100
            w.finish()
        files[spill] = path.read_bytes()
        assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
            f"{s}.mcap" for s in files)  # the spill file has no name
    assert files[20_000] == files[1 << 30]
    with (tmp_path / "20000.mcap").open("rb") as f:
        got = [(c.id, m.sequence, m.log_time) for _, c, m in
               make_reader(f).iter_messages(log_time_order=False)]
    expected = sorted(((ch, lo + i, int(t[i])) for ch, lo, t, _ in batches
                       for i in range(len(t))), key=lambda m: m[2])
    assert got == expected
