"""The archive writer: Zenoh bytes per key, sample-time log times, schemas a standard decoder
reads, per-unit FrameTransforms with the true attitude, numbered splits, clear write errors."""

from __future__ import annotations

import itertools
import json
import signal
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.exceptions import EndOfFile
from mcap.reader import NonSeekingReader, make_reader

from bridge.archive.frames import frame_picks
from bridge.archive.repair import repair
from bridge.archive.walk import read_archive
from bridge.archive.writer import ArchiveWriter, numbered
from bridge.bus.codec import encode_batch
from bridge.bus.gx3_pb2 import ImuSample, Info, Status
from bridge.exceptions import ArchiveError
from bridge.protocol.convert import euler_to_m
from tests.helpers.archives import FLEET, LATENCY, PERIOD, Feed, fleet_feed, write_fleet
from tests.helpers.records import T0, synthetic_batch
from tests.helpers.rotations import rotation


def in_bursts(feed: Feed) -> Feed:
    """The feed as a recorder draining its queue every 250 ms takes it: key by key."""
    return sorted(feed, key=lambda f: (f[0] // 250_000_000, f[1], f[0]))


def write_bulk(path: Path, feed: Feed, **options: object) -> None:
    """``feed`` through write_many, one call per run of one key."""
    with ArchiveWriter(path, **options) as writer:  # type: ignore[arg-type]
        for key, run in itertools.groupby(feed, key=lambda f: f[1]):
            burst = list(run)
            writer.write_many(key, [f[2] for f in burst], np.array([f[0] for f in burst]))


def test_data_channels_hold_the_zenoh_bytes_logged_at_sample_time(tmp_path: Path) -> None:
    path = tmp_path / "fleet.mcap"
    written = write_fleet(path)
    archive = read_archive(path)
    assert archive.complete and archive.dropped_bytes == 0
    assert archive.units() == ["u1", "u2", "u3"]
    for topic, expected in written.messages.items():
        got = archive.messages(topic)
        order = sorted(range(len(expected)), key=lambda i: expected[i][0])
        assert got.payloads == [expected[i][2] for i in order], topic
        assert got.log_time.tolist() == [expected[i][0] for i in order], topic
        assert got.publish_time.tolist() == [expected[i][1] for i in order], topic
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.chunk_indexes and summary.statistics
        schemas = {s.id: s for s in summary.schemas.values()}
        for ch in summary.channels.values():
            kind = ch.topic.rsplit("/", 1)[1]
            if kind == "raw":
                assert ch.schema_id == 0
                assert ch.message_encoding == "application/octet-stream"
                continue
            assert ch.message_encoding == "protobuf"
            assert schemas[ch.schema_id].encoding == "protobuf"
            assert schemas[ch.schema_id].name == {
                "imu": "gx3.v1.ImuSample", "status": "gx3.v1.Status", "event": "gx3.v1.Event",
                "info": "gx3.v1.Info", "frame": "foxglove.FrameTransform",
                "axes": "foxglove.PointCloud", "log": "foxglove.Log"}[kind]
        assert sum(1 for _ in reader.iter_messages()) == summary.statistics.message_count


_STANDARD_DECODE = """
import json, sys
from mcap.reader import NonSeekingReader, make_reader
from mcap.exceptions import EndOfFile
from mcap_protobuf.decoder import DecoderFactory
out = {}
with open(sys.argv[1], "rb") as f:
    reader = make_reader(f, decoder_factories=[DecoderFactory()])
    topics = [c.topic for c in reader.get_summary().channels.values()
              if c.message_encoding == "protobuf"]
    for schema, channel, message, decoded in reader.iter_decoded_messages(topics=topics):
        row = out.setdefault(channel.topic, [])
        if schema.name == "gx3.v1.ImuSample":
            row.append([decoded.unit, decoded.command, decoded.time_ns, message.log_time,
                        list(decoded.accel) or list(decoded.quaternion)])
        elif schema.name == "foxglove.FrameTransform":
            row.append([decoded.child_frame_id, decoded.parent_frame_id])
        elif schema.name == "foxglove.PointCloud":
            row.append([decoded.frame_id, len(decoded.data) // decoded.point_stride])
        elif schema.name == "foxglove.Log":
            row.append([decoded.name, decoded.level, decoded.message])
        else:
            row.append([decoded.unit, schema.name])
leaked = sorted(m for m in sys.modules if m == "bridge" or m.startswith("bridge."))
print(json.dumps({"topics": out, "leaked": leaked}))
"""


def test_a_standard_protobuf_decoder_reads_the_archive_from_its_embedded_schemas(
        tmp_path: Path) -> None:
    path = tmp_path / "fleet.mcap"
    written = write_fleet(path)
    result = subprocess.run([sys.executable, "-c", _STANDARD_DECODE, str(path)],
                            capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    decoded = json.loads(result.stdout)
    assert decoded["leaked"] == []
    topics = decoded["topics"]
    for unit, (code, n, _) in FLEET.items():
        rows = topics[f"gx3/{unit}/imu"]
        assert len(rows) == n
        assert all(r[0] == unit and r[1] == code and r[2] == r[3] for r in rows)
        assert [r[2] for r in rows] == written.times[unit].tolist()
        first = "quaternion" if code == 0xDF else "accel"
        np.testing.assert_array_equal(np.array([r[4] for r in rows], np.float32),
                                      written.batches[unit][first])
        assert topics[f"gx3/{unit}/status"][0] == [unit, "gx3.v1.Status"]
        assert topics[f"gx3/{unit}/info"] == [[unit, "gx3.v1.Info"]]
    assert {r[0] for r in topics["gx3/u1/frame"]} == {"gx3_u1_frd"}
    assert {r[1] for r in topics["gx3/u2/frame"]} == {"gx3_world_ned"}
    assert topics["gx3/frame"] == [["gx3_world_ned", "gx3_world"]]
    assert {tuple(r) for r in topics["gx3/u1/axes"]} == {("gx3_u1_frd", 17)}
    assert len(topics["gx3/u1/axes"]) == len(topics["gx3/u1/frame"])
    assert "gx3/u3/frame" not in topics  # 0xC2 carries no attitude


# roll +90° (right side down), pitch +30° (nose up), yaw +90° (nose east): each a rotation
# about one axis, so a transposed matrix or a wxyz/xyzw mix-up cannot pass.
ATTITUDES = {
    "roll": ([np.pi / 2, 0.0, 0.0], {1: [0.0, 0.0, 1.0], 0: [1.0, 0.0, 0.0]}),
    "pitch": ([0.0, np.pi / 6, 0.0], {0: [np.cos(np.pi / 6), 0.0, -np.sin(np.pi / 6)]}),
    "yaw": ([0.0, 0.0, np.pi / 2], {0: [0.0, 1.0, 0.0], 1: [-1.0, 0.0, 0.0]}),
}


def write_attitudes(path: Path, code: int) -> None:
    """Three units, one rotated about each axis; a frame for every sample."""
    with ArchiveWriter(path, frame_rate_hz=None) as writer:
        for k, (name, (euler, _)) in enumerate(ATTITUDES.items()):
            batch = synthetic_batch(code, 5, k, np.tile(euler, (5, 1)))
            t = T0 + np.arange(5, dtype=np.int64) * PERIOD
            for i, p in enumerate(encode_batch(name, batch, np.arange(5), t, t)):
                writer.write(f"gx3/{name}/imu", p, int(t[i]) + LATENCY)


@pytest.mark.parametrize("code", [0xC5, 0xDF, 0xCE], ids=["m", "quaternion", "euler"])
def test_frame_transform_rotates_sensor_axes_into_ned(tmp_path: Path, code: int) -> None:
    path = tmp_path / "attitude.mcap"
    write_attitudes(path, code)
    archive = read_archive(path)
    for slot, (unit, (euler, axes)) in enumerate(ATTITUDES.items()):
        frames = archive.messages(f"gx3/{unit}/frame")
        assert len(frames) == 5
        for payload in frames.payloads:
            msg = FrameTransform.FromString(payload)
            assert (msg.parent_frame_id, msg.child_frame_id) == ("gx3_world_ned",
                                                                 f"gx3_{unit}_frd")
            assert (msg.translation.x, msg.translation.y, msg.translation.z) == (0, 0.5 * slot, 0)
            r = rotation(np.array([msg.rotation.x, msg.rotation.y, msg.rotation.z,
                                   msg.rotation.w]))
            np.testing.assert_allclose(r, euler_to_m(euler).T, atol=1e-6)
            for axis, ned in axes.items():  # the sensor axis, seen in north-east-down
                np.testing.assert_allclose(r[:, axis], ned, atol=1e-6)
        assert frames.log_time.tolist() == (T0 + np.arange(5) * PERIOD).tolist()


def test_rerun_reads_the_frames_as_the_true_attitude(tmp_path: Path) -> None:
    from rerun.chunk import McapReader

    path = tmp_path / "attitude.mcap"
    write_attitudes(path, 0xC5)
    seen = set()
    for chunk in McapReader(path, include_topic_regex=[".*/frame"]).stream():
        batch = chunk.to_record_batch()
        if "Transform3D:quaternion" not in batch.schema.names:
            continue
        child = batch.column("Transform3D:child_frame")[0].as_py()[0]
        if child == "gx3_world_ned":
            continue
        unit = child.removeprefix("gx3_").removesuffix("_frd")
        euler = ATTITUDES[unit][0]
        for q in batch.column("Transform3D:quaternion").to_pylist():
            np.testing.assert_allclose(rotation(np.array(q[0])), euler_to_m(euler).T,
                                       atol=1e-6)
        seen.add(unit)
    assert seen == set(ATTITUDES)


def test_frames_are_decimated_to_the_frame_rate(tmp_path: Path) -> None:
    path = tmp_path / "fast.mcap"
    with ArchiveWriter(path, frame_rate_hz=50) as writer:
        batch = synthetic_batch(0xC8, 1000, 3)
        t = T0 + np.arange(1000, dtype=np.int64) * 1_000_000  # 1 kHz for 1 s
        for p, ti in zip(encode_batch("u", batch, np.arange(1000), t, t), t.tolist(),
                         strict=True):
            writer.write("gx3/u/imu", p, ti)
    frames = read_archive(path).messages("gx3/u/frame")
    assert len(frames) == 50
    assert set(np.diff(frames.log_time).tolist()) == {20_000_000}


def test_split_by_size_gives_numbered_files_that_each_open(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    written = write_fleet(path, split_bytes=30_000, chunk_size=8_000)
    files = sorted(tmp_path.glob("run_*.mcap"))
    assert len(files) >= 3 and files[0] == numbered(path, 1) and not path.exists()
    topics: dict[str, list[bytes]] = {}
    for f in files:
        archive = read_archive(f)
        assert archive.complete
        for topic in archive.topics():
            topics.setdefault(topic, []).extend(archive.messages(topic).payloads)
        with f.open("rb") as stream:
            assert make_reader(stream).get_summary() is not None
    for topic, expected in written.messages.items():
        assert sorted(topics[topic]) == sorted(p for _, _, p in expected)
    slots = {FrameTransform.FromString(p).translation.y for f in files
             for p in read_archive(f).messages("gx3/u2/frame").payloads}
    assert slots == {1.0}  # u2 is the third unit seen, and keeps its place across files


def test_split_by_duration_of_receive_time(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    write_fleet(path, split_seconds=1.0)
    # the feed spans 2.6 s of receive time
    files = sorted(tmp_path.glob("run_*.mcap"))
    assert [f.name for f in files] == ["run_0001.mcap", "run_0002.mcap", "run_0003.mcap"]
    for f in files:  # a file's age counts from its first message, the one that opened it
        received = np.concatenate([m.publish_time for t in read_archive(f).topics()
                                   if (m := read_archive(f).messages(t))])
        assert received.max() - received.min() < 1_000_000_000, f.name


def test_a_new_file_is_as_old_as_the_message_that_opened_it(tmp_path: Path) -> None:
    raw = "gx3/u1/raw"
    with ArchiveWriter(tmp_path / "run.mcap", split_seconds=1.0) as writer:
        for at in (0.0, 0.5, 1.0, 1.6, 2.0, 2.1):
            writer.write(raw, b"x", T0 + int(at * 1e9))
    held = [read_archive(f).messages(raw).log_time.tolist()
            for f in sorted(tmp_path.glob("run_*.mcap"))]
    assert held == [[T0, T0 + 500_000_000], [T0 + 1_000_000_000, T0 + 1_600_000_000],
                    [T0 + 2_000_000_000, T0 + 2_100_000_000]]


def test_unwritable_path_is_a_one_line_error(tmp_path: Path) -> None:
    for bad in (tmp_path / "missing" / "a.mcap", tmp_path):
        with pytest.raises(ArchiveError) as info:
            ArchiveWriter(bad)
        assert str(bad) in str(info.value) and "\n" not in str(info.value)


def test_unknown_keys_and_bad_payloads_are_refused(tmp_path: Path) -> None:
    with ArchiveWriter(tmp_path / "a.mcap") as writer:
        with pytest.raises(ValueError, match="no archive channel for 'command'"):
            writer.write("gx3/u1/command", b"x", 1)
        with pytest.raises(ValueError, match="not of the form"):
            writer.write("other/u1/imu", b"x", 1)
        with pytest.raises(ValueError, match=r"not a gx3\.v1\.Status"):
            writer.write("gx3/u1/status", b"\xff\xff\xff", 1)
    with pytest.raises(ArchiveError, match="closed"):
        writer.write("gx3/u1/raw", b"x", 1)


_FULL_DISK = """
import sys
import numpy as np
from pathlib import Path
from bridge.bus.codec import encode_batch
from bridge.archive.writer import ArchiveWriter
from bridge.exceptions import ArchiveError
from tests.helpers.records import T0, synthetic_batch
batch = synthetic_batch(0xCC, 20000, 1)
t = T0 + np.arange(20000, dtype=np.int64) * 1_000_000
payloads = encode_batch("u1", batch, np.arange(20000), t, t)
writer = ArchiveWriter(Path(sys.argv[1]), chunk_size=16_000)
n = 0
try:
    for p, ti in zip(payloads, t.tolist()):
        writer.write("gx3/u1/imu", p, ti)
        n += 1
        if n % 500 == 0:
            writer.flush()
except ArchiveError as exc:
    print(n, exc)
writer.close()
"""


def _limit_file_size() -> None:
    import resource

    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (300_000, 300_000))


def test_a_full_disk_stops_the_archive_with_one_line_and_keeps_it_readable(
        tmp_path: Path) -> None:
    path = tmp_path / "full.mcap"
    result = subprocess.run([sys.executable, "-c", _FULL_DISK, str(path)], capture_output=True,
                            text=True, timeout=120, preexec_fn=_limit_file_size,
                            cwd=Path(__file__).parent.parent)
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr
    written, message = result.stdout.strip().split(" ", 1)
    assert message.startswith(f"{path}: File too large; the archive stops here")
    assert "\n" not in message
    archive = read_archive(path)
    assert not archive.complete
    got = archive.messages("gx3/u1/imu")
    assert 1000 <= len(got) <= int(written)
    assert got.log_time.tolist() == (T0 + np.arange(len(got)) * 1_000_000).tolist()


def test_tick_flushes_a_second_after_the_last_flush_while_messages_pause(
        tmp_path: Path) -> None:
    now = [0.0]
    path = tmp_path / "idle.mcap"
    writer = ArchiveWriter(path, clock=lambda: now[0])
    batch = synthetic_batch(0xC2, 3, 1)
    t = T0 + np.arange(3, dtype=np.int64) * PERIOD
    for p, ti in zip(encode_batch("u1", batch, np.arange(3), t, t), t.tolist(), strict=True):
        writer.write("gx3/u1/imu", p, ti)
    now[0] = 0.9
    writer.tick()
    assert read_archive(path).message_count == 0  # still in the open chunk
    now[0] = 1.0
    writer.tick()
    on_disk = read_archive(path)
    assert on_disk.message_count == 3 and not on_disk.complete
    writer.close()
    writer.close()
    assert read_archive(path).complete


@pytest.mark.parametrize("bulk", [False, True], ids=["write", "write_many"])
def test_samples_of_other_encodings_or_names_are_archived_and_framed(tmp_path: Path,
                                                                     bulk: bool) -> None:
    m = euler_to_m(np.array([0.0, 0.0, 0.3])).reshape(-1).tolist()
    # m before the header fields (another producer's order), a unit name unlike the key's
    head = ImuSample(unit="other", command=0xC5, timer=1, ticks=1, time_ns=T0 + 5, rx_ns=T0 + 9)
    reordered = ImuSample(m=m).SerializeToString() + head.SerializeToString()
    # the bulk header, then an m field cut short: archived, but it gets no frame
    cut = ImuSample(unit="u1", command=0xC5, timer=2, ticks=2, time_ns=T0 + 6,
                    rx_ns=T0 + 9).SerializeToString() + b"\x82\x01\x24" + bytes(10)
    path = tmp_path / "odd.mcap"
    with ArchiveWriter(path, frame_rate_hz=None) as writer:
        if bulk:
            writer.write_many("gx3/u1/imu", [reordered, cut], np.array([T0 + 10, T0 + 11]))
            with pytest.raises(ValueError, match=r"not a gx3\.v1\.ImuSample"):
                writer.write_many("gx3/u1/imu", [cut, b"\xff" * 8], T0 + 12)
            with pytest.raises(ValueError, match="2 payloads but 3 receive times"):
                writer.write_many("gx3/u1/imu", [cut, cut], np.zeros(3, np.int64))
        else:
            writer.write("gx3/u1/imu", reordered, T0 + 10)
            writer.write("gx3/u1/imu", cut, T0 + 11)
            with pytest.raises(ValueError, match=r"not a gx3\.v1\.ImuSample"):
                writer.write("gx3/u1/imu", b"\xff" * 8, T0 + 12)
    archive = read_archive(path)
    imu = archive.messages("gx3/u1/imu")
    assert imu.payloads == [reordered, cut] and imu.log_time.tolist() == [T0 + 5, T0 + 6]
    frames = archive.messages("gx3/u1/frame")
    assert len(frames) == 1 and frames.log_time[0] == T0 + 5
    frame = FrameTransform.FromString(frames.payloads[0])
    assert frame.child_frame_id == "gx3_u1_frd"
    q = np.array([frame.rotation.x, frame.rotation.y, frame.rotation.z, frame.rotation.w])
    np.testing.assert_allclose(rotation(q), np.reshape(m, (3, 3)).T, atol=1e-6)


def _never() -> float:
    """A clock that stands still: no flush by the wall clock, so chunks depend on the data."""
    return 0.0


def standard_read(path: Path) -> tuple[list[tuple[str, int, int, int, bytes]], dict[str, int]]:
    """Every message (topic, log time, publish time, sequence, data) in file order, and the
    summary's count per topic, as mcap's own reader gives them."""
    with path.open("rb") as f:
        reader = make_reader(f, validate_crcs=True)
        messages = [(c.topic, m.log_time, m.publish_time, m.sequence, m.data)
                    for _, c, m in reader.iter_messages(log_time_order=False)]
        summary = reader.get_summary()
    assert summary is not None and summary.statistics is not None
    counts = {summary.channels[c].topic: n
              for c, n in summary.statistics.channel_message_counts.items()}
    return messages, counts


@pytest.mark.parametrize("options", [
    {}, {"chunk_size": 3_000}, {"split_bytes": 30_000, "chunk_size": 8_000},
    {"split_seconds": 1.0, "frame_rate_hz": None}], ids=["plain", "small chunks",
                                                        "split by size", "split by age"])
def test_write_many_archives_what_write_archives_message_by_message(
        tmp_path: Path, options: dict[str, object]) -> None:
    """The same messages, times, sequence numbers and channels, read by mcap's reader;
    split by age, where ``write`` keeps the order of the calls, the very same bytes."""
    written, feed = fleet_feed()
    feed = in_bursts(feed)
    (tmp_path / "one").mkdir()
    (tmp_path / "bulk").mkdir()
    with ArchiveWriter(tmp_path / "one" / "a.mcap", clock=_never,
                       **options) as writer:  # type: ignore[arg-type]
        for receive_ns, key, payload, _ in feed:
            writer.write(key, payload, receive_ns)
    write_bulk(tmp_path / "bulk" / "a.mcap", feed, clock=_never, **options)
    archives: dict[str, list[tuple[str, int, int, int, bytes]]] = {}
    for way in ("one", "bulk"):
        files = sorted((tmp_path / way).iterdir())
        if any(k.startswith("split") for k in options):
            assert [f.name for f in files] == [f"a_{i:04d}.mcap" for i in
                                               range(1, len(files) + 1)] and len(files) > 1
        archives[way] = []
        for f in files:
            messages, counts = standard_read(f)
            assert sum(counts.values()) == len(messages) > 0
            frames = [t for top, t, *_ in messages if top.endswith("/frame")]
            roots = [t for top, t, *_ in messages if top == "gx3/frame"]
            assert roots == ([min(frames)] if frames else []), f  # one, at the first frame
            archives[way] += messages
    if "split_bytes" in options:  # where a file ends depends on the batches: so do roots
        for way in archives:
            archives[way] = [m for m in archives[way] if m[0] != "gx3/frame"]
    assert sorted(archives["one"]) == sorted(archives["bulk"])
    if "split_seconds" in options:
        for f in (tmp_path / "one").iterdir():
            assert f.read_bytes() == (tmp_path / "bulk" / f.name).read_bytes()
    for topic, expected in written.messages.items():  # and it is what was fed, in order
        got = [(t, r, p) for top, t, r, _, p in archives["bulk"] if top == topic]
        assert sorted(got) == sorted(expected), topic
        sequences = sorted((r, q) for top, _, r, q, _ in archives["one"] if top == topic)
        assert [q for _, q in sequences] == list(range(len(expected))), topic
    assert any(topic.endswith("/frame") for topic, *_ in archives["bulk"])


def test_a_write_many_archive_cut_anywhere_reads_and_repairs_up_to_its_last_chunk(
        tmp_path: Path) -> None:
    """A killed recorder leaves the file cut at any byte: every chunk written before the
    cut is read back (by reader.py and by mcap's streaming reader alike) and repaired into
    a finished, indexed archive."""
    path = tmp_path / "whole.mcap"
    write_bulk(path, in_bursts(fleet_feed()[1]), chunk_size=4_000, clock=_never)
    data = path.read_bytes()
    whole, _ = standard_read(path)
    with path.open("rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes  # type: ignore[union-attr]
    assert len(chunks) > 8
    ends = [c.chunk_start_offset + c.chunk_length for c in chunks]
    cuts = [chunks[2].chunk_start_offset + chunks[2].chunk_length // 2,  # inside a chunk
            ends[4] + 12,  # inside the message index after a chunk
            chunks[6].chunk_start_offset,  # right before a chunk
            ends[-1] + 3]  # after the last chunk, before the summary
    cut = tmp_path / "cut.mcap"
    counts = []
    for at in cuts:
        cut.write_bytes(data[:at])
        archive = read_archive(cut)
        assert not archive.complete
        streamed = []
        # mcap's streaming reader stops at the cut (inside an index: struct.error)
        with cut.open("rb") as f, pytest.raises((EndOfFile, struct.error)):
            for _, c, m in NonSeekingReader(f).iter_messages(log_time_order=False):
                streamed.append((c.topic, m.log_time, m.publish_time, m.sequence, m.data))
        assert archive.chunks == sum(1 for e in ends if e <= at)
        assert archive.message_count == len(streamed) > 0
        assert streamed == whole[: len(streamed)]
        report = repair(cut, tmp_path / "repaired.mcap")
        assert report.messages == len(streamed)
        repaired, counts_by_topic = standard_read(tmp_path / "repaired.mcap")
        assert sorted(repaired) == sorted(streamed)
        assert sum(counts_by_topic.values()) == len(streamed)
        counts.append(len(streamed))
    assert counts == sorted(counts) and counts[0] < counts[-1]


def test_frames_built_in_bulk_are_the_bytes_protobuf_serializes() -> None:
    """Times before and after 1970, whole seconds, rotations with +0.0 (left out) and
    -0.0 (kept), a long unit name: byte for byte what FrameTransform.SerializeToString
    gives, so any protobuf reader sees the same message."""
    from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
    from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
    from google.protobuf.timestamp_pb2 import Timestamp

    from bridge.archive.frames import frame_messages

    rng = np.random.default_rng(11)
    times = np.concatenate([rng.integers(-(1 << 62), 1 << 62, 300),
                            [0, 1, -1, 10**9, -(10**9), 999_999_999, T0]]).astype(np.int64)
    xyzw = rng.normal(size=(len(times), 4))
    xyzw[rng.random(xyzw.shape) < 0.2] = 0.0
    xyzw[rng.random(xyzw.shape) < 0.05] = -0.0
    for unit, slot in (("u1", 0), ("a-unit-with-a-long-name" * 7, 3)):
        expected = [FrameTransform(
            timestamp=Timestamp(seconds=t // 10**9, nanos=t % 10**9),
            parent_frame_id="gx3_world_ned", child_frame_id=f"gx3_{unit}_frd",
            translation=Vector3(x=0.0, y=slot * 0.5, z=0.0),
            rotation=Quaternion(x=x, y=y, z=z, w=w)).SerializeToString()
            for t, (x, y, z, w) in zip(times.tolist(), xyzw.tolist(), strict=True)]
        assert frame_messages(unit, slot, times, xyzw, 0.5) == expected
    assert frame_messages("u1", 0, np.zeros(0, np.int64), np.zeros((0, 4)), 0.5) == []


def test_frames_are_one_a_tick_of_a_grid_and_start_again_on_a_reset() -> None:
    """The jump from frame to frame (times in order) picks what looking at every sample
    picks: the first sample at or after each tick of a grid one period apart, from the
    first sample; a sample more than two periods before the due tick starts again."""

    def every_sample(times: list[int], due: int | None,
                     period: int) -> tuple[list[int], int | None]:
        picks = []
        for i, t in enumerate(times):
            if due is None or t < due - 2 * period:
                due = t
            if t >= due:
                picks.append(i)
                while due <= t:
                    due += period
        return picks, due

    rng = np.random.default_rng(5)
    for _ in range(300):
        n, period = int(rng.integers(0, 60)), int(rng.choice([7, 40, 100]))
        times = np.cumsum(rng.integers(0, 30, n)) + 1_000
        if rng.random() < 0.3 and n > 2:  # a reset: time goes back
            times[n // 2 :] -= int(rng.integers(0, 2_000))
        due = None if rng.random() < 0.2 else int(rng.integers(0, 2_500))
        assert frame_picks(times, due, period) == every_sample(times.tolist(), due, period)


def _picks_in_bursts(times: np.ndarray, burst: int, period: int) -> list[int]:
    """Frames of ``times`` fed ``burst`` samples at a time, as a recorder takes them."""
    picks: list[int] = []
    due = None
    for lo in range(0, len(times), burst):
        found, due = frame_picks(times[lo : lo + burst], due, period)
        picks += [lo + i for i in found]
    return picks


@pytest.mark.parametrize("ppm", [42.0, -27.0, 0.0])
def test_frames_come_at_the_display_rate_whatever_the_units_drift(ppm: float) -> None:
    """100 Hz samples of a unit whose clock runs ``ppm`` fast or slow: 25 frames a second
    (a grid restarted at each pick gave 20 Hz at +42 ppm)."""
    period = int(1e9 / 25)
    times = T0 + np.round(np.arange(10_000) * 1e7 / (1 + ppm * 1e-6)).astype(np.int64)
    picks = _picks_in_bursts(times, 37, period)
    assert abs(len(picks) - 1 - (times[-1] - times[0]) / period) <= 1
    steps = np.diff(times[picks])
    assert steps.min() > period - 10_000_000 and steps.max() < period + 10_000_000


@settings(max_examples=200, deadline=None)
@given(st.floats(-500, 500), st.integers(2, 400), st.sampled_from([5, 10, 20, 40]),
       st.integers(1, 50))
def test_frame_rate_is_the_display_rate_for_any_drift_sample_rate_and_burst(
        ppm: float, n: int, sample_ms: int, burst: int) -> None:
    """Over any span the frames number the span over the period (within one), as long as
    samples come at least as often as frames; picks are a period apart less than one
    sample step, never two in one period."""
    period = 40_000_000
    step = sample_ms * 1e6 / (1 + ppm * 1e-6)
    times = T0 + np.round(np.arange(n) * step).astype(np.int64)
    picks = _picks_in_bursts(times, burst, period)
    assert picks[0] == 0
    assert abs(len(picks) - 1 - (times[-1] - times[0]) / period) <= 1
    assert (np.diff(times[picks]) > period - step - 1).all()


@pytest.mark.parametrize("bulk", [False, True], ids=["write", "write_many"])
def test_the_file_is_in_log_time_order_with_no_overlapping_chunks(tmp_path: Path,
                                                                  bulk: bool) -> None:
    """Three units, status, events, info, raw and frames, taken key by key every 250 ms
    as a recorder does, in small chunks: log time never goes back in file order, chunks
    never overlap, nothing comes later than the reorder window (on main 40 % of the
    messages came out of order). Profile and library as the registry asks."""
    from tests.helpers.mcap_order import header, order_problems

    written, feed = fleet_feed()
    path = tmp_path / "a.mcap"
    if bulk:
        write_bulk(path, in_bursts(feed), chunk_size=3_000)
    else:
        with ArchiveWriter(path, chunk_size=3_000) as writer:
            for receive_ns, key, payload, _ in in_bursts(feed):
                writer.write(key, payload, receive_ns)
            assert writer.late == 0
    assert order_problems(path) == []
    assert (header(path).profile, header(path).library) == ("", "gx3-bridge 0.1.0")
    archive = read_archive(path)
    assert not [m for m in archive.metadata if m.name == "gx3.order"]
    for topic, expected in written.messages.items():  # every message at its own time
        got = archive.messages(topic)
        assert sorted(got.log_time.tolist()) == sorted(t for t, _, _ in expected), topic


def test_a_message_later_than_the_reorder_window_keeps_the_order_and_is_counted(
        tmp_path: Path) -> None:
    """An Info whose bring-up was long ago (as a recorder gets it when it finds a unit
    already running): logged at the last time written, counted in ``late`` and the
    ``gx3.order`` metadata; its own time stays in its payload."""
    from tests.helpers.mcap_order import order_problems

    path = tmp_path / "a.mcap"
    now = [0.0]
    with ArchiveWriter(path, clock=lambda: now[0]) as writer:
        for k in range(30):
            status = Status(unit="u1", time_ns=T0 + k * 10**8).SerializeToString()
            writer.write("gx3/u1/status", status, T0 + k * 10**8 + 1)
            now[0] += 0.1
        info = Info(unit="u1", bring_up_time_ns=T0 - 60 * 10**9).SerializeToString()
        writer.write("gx3/u1/info", info, T0 + 3 * 10**9)
    assert writer.late == 1 and order_problems(path) == []
    archive = read_archive(path)
    logged = archive.messages("gx3/u1/info")
    assert T0 < logged.log_time[0] <= T0 + 3 * 10**9 and logged.payloads == [info]
    order = next(m for m in archive.metadata if m.name == "gx3.order")
    assert order.metadata["late_messages"] == "1"
