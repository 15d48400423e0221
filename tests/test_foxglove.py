"""The archive as Foxglove and Rerun see it: a REP-103 frame tree that puts every unit the
right way up, a marker they draw in each unit's frame, and the events on a Log channel.

Messages are decoded with mcap's own protobuf decoder and with Rerun's MCAP reader, not
ours; attitudes are checked against the emulator's true motion.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from bridge.archive.walk import read_archive
from bridge.archive.writer import ArchiveWriter
from bridge.bus.codec import encode_batch
from bridge.bus.gx3_pb2 import Event, Info
from bridge.ingest.replay import replay
from bridge.protocol.codec import Batch, encode_reply
from bridge.protocol.convert import euler_to_m
from bridge.protocol.table import REPLIES
from bridge.sim.motion import Motion, MotionConfig
from tests.helpers.archives import write_capture
from tests.helpers.mcap_order import order_problems
from tests.helpers.records import T0
from tests.helpers.rotations import rotation

PERIOD_S = 0.01
#: NED vectors in ENU: north is y, east is x, down is -z.
NED_TO_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def emulated(motion: Motion, code: int, n: int) -> tuple[Batch, np.ndarray, dict[str, np.ndarray]]:
    """n records of ``code`` of the emulator's ``motion`` at 100 Hz, their times and truth."""
    t = np.arange(n) * PERIOD_S
    truth = motion.sample(t, PERIOD_S)
    columns = {f.name: (np.arange(n, dtype=np.uint32) * 625 if f.name == "timer"
                        else truth[f.name].astype(np.float32))
               for f in REPLIES[code].fields}
    batch = Batch(code, columns, np.arange(n), np.zeros(n, np.int64), False)
    return batch, T0 + np.round(t * 1e9).astype(np.int64), truth


def decoded(path: Path) -> list[tuple[str, int, Any]]:
    """(topic, log time, message) of every Foxglove message, in file order, by mcap's
    protobuf decoder from the schemas in the file."""
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [(c.topic, m.log_time, msg) for s, c, m, msg
                in reader.iter_decoded_messages(log_time_order=False)
                if s is not None and s.name.startswith("foxglove.")]


def stamp(msg: Any) -> int:
    return int(msg.timestamp.seconds) * 1_000_000_000 + int(msg.timestamp.nanos)


Pose = tuple[np.ndarray, np.ndarray]  # rotation (3, 3), translation (3,)


def tree(messages: list[tuple[str, int, Any]]) -> Callable[[str, int], tuple[str, Pose]]:
    """Look a frame up as Foxglove's transform tree does: follow parent after parent, each
    transform the latest stamped at or before the time; (root, pose of the frame in it)."""
    history: dict[str, list[tuple[int, str, Pose]]] = {}
    for _, _, msg in messages:
        if type(msg).__name__ != "FrameTransform":
            continue
        q = np.array([msg.rotation.x, msg.rotation.y, msg.rotation.z, msg.rotation.w])
        p = np.array([msg.translation.x, msg.translation.y, msg.translation.z])
        history.setdefault(msg.child_frame_id, []).append(
            (stamp(msg), msg.parent_frame_id, (rotation(q), p)))

    def lookup(frame: str, at: int) -> tuple[str, Pose]:
        r, p = np.eye(3), np.zeros(3)
        while frame in history:
            stamped = [h for h in history[frame] if h[0] <= at]
            assert stamped, f"{frame} has no transform at or before {at}"
            _, parent, (r_parent, p_parent) = max(stamped, key=lambda h: h[0])
            r, p = r_parent @ r, r_parent @ p + p_parent
            frame = parent
        return frame, (r, p)
    return lookup


def write_units(path: Path, units: dict[str, tuple[Batch, np.ndarray]]) -> None:
    with ArchiveWriter(path, frame_rate_hz=None) as writer:
        for unit, (batch, times) in units.items():
            n = len(times)
            writer.write_many(f"gx3/{unit}/imu", encode_batch(unit, batch, np.arange(n), times,
                                                              times), times + 3_000_000)


@pytest.mark.parametrize("code", [0xC8, 0xDF, 0xCE], ids=["m", "quaternion", "euler"])
def test_each_unit_stands_the_right_way_up_in_the_enu_root(tmp_path: Path, code: int) -> None:
    """Through the frames as Foxglove chains them: a level unit's z axis points down in
    gx3_world (ENU), its x axis along its heading (north = +y); a moving unit's body
    frame is its true attitude; and (records with accel) the specific force, turned
    into gx3_world, is the motion's acceleration plus 1 g up."""
    level = Motion(MotionConfig(seed=3, static=True, attitude_amplitude_rad=0.0))
    moving = Motion(MotionConfig(seed=5))
    units = {"level": emulated(level, code, 40), "moving": emulated(moving, code, 40)}
    path = tmp_path / "fleet.mcap"
    write_units(path, {u: (b, t) for u, (b, t, _) in units.items()})
    assert order_problems(path) == []
    lookup = tree(decoded(path))
    truth_fields = [f.name for f in REPLIES[code].fields]
    for unit, (_, times, truth) in units.items():
        for i, at in enumerate(times.tolist()):
            root, (r, _) = lookup(f"gx3_{unit}_frd", at)
            assert root == "gx3_world"
            np.testing.assert_allclose(r, NED_TO_ENU @ euler_to_m(truth["euler"][i]).T,
                                       atol=2e-6)
            if unit == "level":
                yaw = truth["euler"][i][2]
                np.testing.assert_allclose(r[:, 2], [0.0, 0.0, -1.0], atol=1e-6)
                np.testing.assert_allclose(r[:, 0], [np.sin(yaw), np.cos(yaw), 0.0], atol=2e-6)
            if "accel" in truth_fields:
                lin = moving.linear_accel_earth(at / 1e9 - T0 / 1e9) if unit == "moving" else 0
                np.testing.assert_allclose(r @ truth["accel"][i],
                                           NED_TO_ENU @ (lin - np.array([0.0, 0.0, 1.0])),
                                           atol=1e-5)


def test_a_unit_heading_north_points_along_y_and_east_along_x(tmp_path: Path) -> None:
    """Euler records, level, yaw 0 and 90°: body x is the ENU root's +y, then +x."""
    units = {}
    for unit, yaw in (("north", 0.0), ("east", np.pi / 2)):
        euler = np.tile(np.array([0.0, 0.0, yaw], np.float32), (5, 1))
        batch = Batch(0xCE, {"euler": euler, "timer": np.arange(5, dtype=np.uint32) * 625},
                      np.arange(5), np.zeros(5, np.int64), False)
        units[unit] = (batch, T0 + np.arange(5, dtype=np.int64) * 10_000_000)
    path = tmp_path / "compass.mcap"
    write_units(path, units)
    lookup = tree(decoded(path))
    for unit, axis in (("north", [0.0, 1.0, 0.0]), ("east", [1.0, 0.0, 0.0])):
        _, (r, _) = lookup(f"gx3_{unit}_frd", T0 + 40_000_000)
        np.testing.assert_allclose(r[:, 0], axis, atol=1e-6)
        np.testing.assert_allclose(r[:, 2], [0.0, 0.0, -1.0], atol=1e-6)
    east_of = {u: lookup(f"gx3_{u}_frd", T0)[1][1][0] for u in units}
    assert east_of["east"] - east_of["north"] == pytest.approx(0.5)  # side by side, eastwards


def test_the_axes_marker_is_drawn_in_the_unit_frame_with_every_frame(tmp_path: Path) -> None:
    """The PointCloud a viewer draws: in the unit's body frame, stamped as its frames; seen
    from gx3_world, a level unit's blue (z) dots hang below it and its red (x) dots lie
    level, along its heading."""
    level = Motion(MotionConfig(seed=3, static=True, attitude_amplitude_rad=0.0))
    batch, times, truth = emulated(level, 0xC8, 10)
    path = tmp_path / "axes.mcap"
    write_units(path, {"u1": (batch, times)})
    messages = decoded(path)
    lookup = tree(messages)
    clouds = [msg for topic, _, msg in messages if topic == "gx3/u1/axes"]
    frames = [msg for topic, _, msg in messages if topic == "gx3/u1/frame"]
    assert [stamp(c) for c in clouds] == [stamp(f) for f in frames] == times.tolist()
    yaw = truth["euler"][0][2]
    for cloud in clouds:
        assert cloud.frame_id == "gx3_u1_frd"
        names = [f.name for f in cloud.fields]
        points = np.frombuffer(cloud.data, np.dtype({
            "names": names, "offsets": [f.offset for f in cloud.fields],
            "formats": ["<f4" if f.type == f.FLOAT32 else "u1" for f in cloud.fields],
            "itemsize": cloud.point_stride}))
        _, (r, p) = lookup(cloud.frame_id, stamp(cloud))
        seen = (r @ np.stack([points["x"], points["y"], points["z"]]).astype(float)).T + p
        blue = (points["blue"] == 255) & (points["red"] == 0)
        red = (points["red"] == 255) & (points["blue"] == 0)
        assert blue.sum() >= 3 and red.sum() >= 3
        assert (seen[blue, 2] < p[2] - 0.01).all()
        np.testing.assert_allclose(seen[red, 2], p[2], atol=1e-6)
        heading = (seen[red] - p) / np.linalg.norm(seen[red] - p, axis=1)[:, None]
        np.testing.assert_allclose(heading, np.tile([np.sin(yaw), np.cos(yaw), 0.0],
                                                    (red.sum(), 1)), atol=1e-5)


EVENTS = [  # unit, kind, count, detail, ms after T0
    ("u1", Event.GAP, 254, "", 300),
    ("u2", Event.RESET, 3, "", 100),
    ("u1", Event.DISCONNECT, 1, "port closed", 500),
    ("u1", Event.RECONNECT, 1, "back after 1.8 s", 2300),
    ("u2", Event.ROLLOVER, 1, "", 900),
    ("u2", Event.SHED, 40, "", 1200),
]


def write_events(path: Path, one_by_one: bool) -> None:
    with ArchiveWriter(path) as writer:
        for unit in ("u1", "u2"):
            info = Info(unit=unit, output_rate_hz=100.0, bring_up_time_ns=T0)
            writer.write_many(f"gx3/{unit}/info", [info.SerializeToString()], T0)
        for unit, kind, count, detail, ms in EVENTS:
            at = T0 + ms * 1_000_000
            end = at + 390_000_000 if kind == Event.SHED else 0  # 40 samples at 100 Hz
            payload = Event(unit=unit, time_ns=at, kind=kind, count=count, detail=detail,
                            leaf="imu" * (kind == Event.SHED),
                            end_time_ns=end).SerializeToString()
            if one_by_one:
                writer.write(f"gx3/{unit}/event", payload, at + 5_000_000)
            else:
                writer.write_many(f"gx3/{unit}/event", [payload], at + 5_000_000)


@pytest.mark.parametrize("one_by_one", [False, True], ids=["write_many", "write"])
def test_events_are_foxglove_logs_in_log_time_order(tmp_path: Path, one_by_one: bool) -> None:
    """One fleet channel: name = unit, lost records or messages warn with their count and
    span, a disconnect is an error, the rest inform; stamped and logged at the event's
    time, in log-time order whatever order they were written in."""
    path = tmp_path / "events.mcap"
    write_events(path, one_by_one)
    assert order_problems(path) == []
    logs = [(t, msg) for topic, t, msg in decoded(path) if topic == "gx3/log"]
    times = [t for t, _ in logs]
    assert times == sorted(times) == sorted(T0 + ms * 1_000_000 for *_, ms in EVENTS)
    assert all(stamp(msg) == t for t, msg in logs)
    got = {(msg.name, msg.level, msg.message) for _, msg in logs}
    warning, error, info = 3, 4, 2  # foxglove.Log.Level
    assert got == {("u1", warning, "u1 GAP (254 records, 2.54 s)"),
                   ("u2", warning, "u2 RESET (3 records, 0.03 s)"),
                   ("u1", error, "u1 DISCONNECT: port closed"),
                   ("u1", info, "u1 RECONNECT: back after 1.8 s"),
                   ("u2", info, "u2 ROLLOVER"),
                   ("u2", warning, "u2 SHED (40 imu messages, 0.39 s)")}
    archive = read_archive(path)  # our reader: the fleet channel belongs to no unit
    assert archive.units() == ["u1", "u2"]
    assert [(u, e.kind) for u, e in archive.events()] == [
        (u, k) for u, k, *_ in sorted(EVENTS, key=lambda e: e[4])]


def test_a_replayed_capture_logs_its_gap(tmp_path: Path) -> None:
    """gx3 replay archives the events it finds, and their Logs, like the live recorder."""
    reads = [(T0 + i * 10_000_000, encode_reply(0xC2, accel=[0.0, 0.0, -1.0],
                                                ang_rate=[0.0, 0.0, 0.0], timer=1000 + i * 625))
             for i in range(300) if i not in range(120, 125)]
    meta = {"unit": "u1", "record": "0xC2", "decimation": "10", "filter_width": "15",
            "baud": "115200", "transport": "uart"}
    path = write_capture(tmp_path / "raw.mcap", reads, meta)
    replay([path], tmp_path / "out.mcap")
    ((_, gap),) = read_archive(tmp_path / "out.mcap").events()
    logs = [(t, msg) for topic, t, msg in decoded(tmp_path / "out.mcap") if topic == "gx3/log"]
    assert [(t, msg.name, msg.level, msg.message) for t, msg in logs] == [
        (gap.time_ns, "u1", 3, "u1 GAP (5 records, 0.05 s)")]


def test_under_a_prefix_of_two_levels_frames_and_fleet_channels_follow_it(
        tmp_path: Path) -> None:
    """``site/gx3/log`` is the fleet's, not a unit called gx3's; frame names take the
    prefix as the ROS 2 export does (site_gx3_<unit> is its FLU body frame)."""
    path = tmp_path / "site.mcap"
    batch, times, _ = emulated(Motion(MotionConfig(seed=3)), 0xCE, 3)
    with ArchiveWriter(path, prefix="site/gx3", frame_rate_hz=None) as writer:
        writer.write_many("site/gx3/u1/imu", encode_batch("u1", batch, np.arange(3), times,
                                                          times), times)
        event = Event(unit="u1", time_ns=T0, kind=Event.GAP, count=2)
        writer.write_many("site/gx3/u1/event", [event.SerializeToString()], T0)
    archive = read_archive(path)
    assert archive.topics() == ["site/gx3/frame", "site/gx3/log", "site/gx3/u1/axes",
                                "site/gx3/u1/event", "site/gx3/u1/frame", "site/gx3/u1/imu"]
    assert archive.units() == ["u1"]
    root, _ = tree(decoded(path))("site_gx3_u1_frd", int(times[-1]))
    assert root == "site_gx3_world"


def test_rerun_reads_a_frame_tree_a_3d_marker_and_a_text_log(tmp_path: Path) -> None:
    """What `rerun ARCHIVE.mcap` builds, by Rerun's own MCAP reader: the transforms with
    their frame names, Points3D in each unit's frame (which makes a 3-D view) and the
    events as TextLog with their levels."""
    from rerun.chunk import McapReader

    level = Motion(MotionConfig(seed=3, static=True, attitude_amplitude_rad=0.0))
    batch, times, _ = emulated(level, 0xC8, 10)
    path = tmp_path / "rerun.mcap"
    with ArchiveWriter(path, frame_rate_hz=None) as writer:
        writer.write_many("gx3/u1/imu", encode_batch("u1", batch, np.arange(10), times, times),
                          times)
        event = Event(unit="u1", time_ns=int(times[5]), kind=Event.GAP, count=2)
        writer.write_many("gx3/u1/event", [event.SerializeToString()], int(times[5]))
    columns: dict[tuple[str, str], list[Any]] = {}
    for chunk in McapReader(path).stream():
        batch_ = chunk.to_record_batch()
        for name in batch_.schema.names:
            if name.split(":")[0] in ("Transform3D", "Points3D", "CoordinateFrame", "TextLog"):
                columns.setdefault((chunk.entity_path, name), []).extend(
                    batch_.column(name).to_pylist())
    assert columns[("/gx3/frame", "Transform3D:parent_frame")] == [["gx3_world"]]
    assert columns[("/gx3/frame", "Transform3D:child_frame")] == [["gx3_world_ned"]]
    assert {c[0] for c in columns[("/gx3/u1/frame", "Transform3D:parent_frame")]} == {
        "gx3_world_ned"}
    assert {c[0] for c in columns[("/gx3/u1/axes", "CoordinateFrame:frame")]} == {"gx3_u1_frd"}
    assert len(columns[("/gx3/u1/axes", "Points3D:positions")]) == 10
    assert columns[("/gx3/log", "TextLog:text")] == [["u1 GAP (2 records)"]]  # no Info: no span
    assert columns[("/gx3/log", "TextLog:level")] == [["WARN"]]
