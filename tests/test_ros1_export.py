"""`gx3 export --format ros1`: a ROS 1 bag read back with rosbags' ROS 1 reader and type
store (Noetic's), message for message the ROS 2 bag of the same export; and the noise
guide's Kalibr recipe, run as written up to Kalibr itself."""

from __future__ import annotations

import json
import re
import shlex
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.rosbag1 import Reader, Writer
from rosbags.typesys import Stores, get_typestore
from ruamel.yaml import YAML

from bridge.archive.writer import ArchiveWriter
from bridge.protocol.convert import STANDARD_GRAVITY
from bridge.ros2 import messages
from bridge.ros2.noise import sample_variance
from bridge.sim.archived import archive_samples
from bridge.sim.motion import Motion, MotionConfig, SignalChain
from tests.helpers.noise import ACCEL_DENSITY, GYRO_DENSITY, WALL_NS, kalibr_yaml
from tests.helpers.processes import GX3, gx3

GUIDE = Path(__file__).parents[1] / "docs" / "guides" / "noise.md"
NOETIC = get_typestore(Stores.ROS1_NOETIC)
HUMBLE = get_typestore(Stores.ROS2_HUMBLE)
RATE = 100.0
CAMERA_TOPIC = "/cam0/image_raw"
STILL = MotionConfig(seed=3, static=True, accelerometer_noise_density=2e-3,
                     gyroscope_noise_density=1e-4)


@dataclass
class Bag1:
    topics: dict[str, str]  # topic -> message type
    raw: dict[str, list[bytes]]
    stamps: dict[str, list[int]]  # the bag's own time of each message


def read_bag1(path: Path) -> Bag1:
    bag = Bag1({}, {}, {})
    with Reader(path) as reader:
        for c in reader.connections:
            bag.topics[c.topic] = c.msgtype
        for connection, stamp, data in reader.messages():
            bag.raw.setdefault(connection.topic, []).append(bytes(data))
            bag.stamps.setdefault(connection.topic, []).append(stamp)
    return bag


def _seconds(start: float, end: float) -> np.ndarray:
    return np.arange(round(start * RATE), round(end * RATE)) / RATE


def _camera_bag(path: Path, start_s: float, seconds: float) -> None:
    """A ROS 1 camera's bag: tiny mono images at 20 Hz, stamped on the host's clock."""
    image = NOETIC.types["sensor_msgs/msg/Image"]
    header = NOETIC.types["std_msgs/msg/Header"]
    stamp = NOETIC.types["builtin_interfaces/msg/Time"]
    writer = Writer(path)
    writer.open()
    connection = writer.add_connection(CAMERA_TOPIC, "sensor_msgs/msg/Image", typestore=NOETIC)
    for i, at in enumerate(np.arange(start_s, start_s + seconds, 0.05).tolist()):
        ns = WALL_NS + round(at * 1e9)
        msg = image(header=header(seq=i, stamp=stamp(sec=ns // 10**9, nanosec=ns % 10**9),
                                  frame_id="cam0"),
                    height=4, width=4, encoding="mono8", is_bigendian=0, step=4,
                    data=np.full(16, i % 256, np.uint8))
        writer.write(connection, ns, NOETIC.serialize_ros1(msg, "sensor_msgs/msg/Image"))
    writer.close()


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """What the guide's recipe starts from: still.mcap (the unit standing still),
    calib.mcap (it moving in front of the camera) and camera.bag (the camera's images)."""
    folder = tmp_path_factory.mktemp("kalibr")
    with ArchiveWriter(folder / "still.mcap") as writer:
        archive_samples(writer, "imu1", Motion(STILL), _seconds(0, 300), 1 / RATE)
    with ArchiveWriter(folder / "calib.mcap") as writer:
        archive_samples(writer, "imu1", Motion(MotionConfig(seed=5)), _seconds(400, 430),
                        1 / RATE)
    _camera_bag(folder / "camera.bag", 401.0, 28.0)
    return folder


def _recipe() -> list[list[str]]:
    """The commands of the guide's Kalibr recipe, as a shell would split them."""
    text = GUIDE.read_text()
    block = re.search(r"<!-- the Kalibr recipe.*?-->\n```sh\n(.*?)```", text, re.S)
    assert block, "the guide's Kalibr recipe is not where the test looks for it"
    return [shlex.split(line) for line in block.group(1).replace("\\\n", " ").splitlines()]


def test_the_guides_kalibr_recipe_gives_kalibr_what_it_reads(folder: Path) -> None:
    """Every gx3 line of the guide, run as written in the folder; then what its Kalibr
    line names: an imu.yaml whose rostopic is a sensor_msgs/Imu topic of the bag at the
    file's update_rate, beside the camera's images, copied unchanged."""
    commands = _recipe()
    assert [c[0] for c in commands] == ["gx3", "gx3", "rosrun"]
    for command in commands[:-1]:
        done = subprocess.run([GX3, *command[1:]], cwd=folder, capture_output=True,
                              text=True, timeout=300)
        assert done.returncode == 0, (command, done.stderr)
    kalibr = commands[-1]
    assert kalibr[1:3] == ["kalibr", "kalibr_calibrate_imu_camera"]
    given = dict(zip(kalibr[3::2], kalibr[4::2], strict=True))
    imu = YAML(typ="safe").load((folder / given["--imu"]).read_text())
    bag = read_bag1(folder / given["--bag"])
    topic = imu["rostopic"]
    assert bag.topics == {topic: "sensor_msgs/msg/Imu", CAMERA_TOPIC: "sensor_msgs/msg/Image"}
    assert len(bag.raw[topic]) == 30 * RATE and imu["update_rate"] == RATE
    decoded: list[Any] = [NOETIC.deserialize_ros1(d, "sensor_msgs/msg/Imu")
                          for d in bag.raw[topic]]
    stamps = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in decoded])
    assert np.array_equal(stamps, bag.stamps[topic])
    assert np.diff(stamps).mean() == pytest.approx(1e9 / RATE, rel=1e-4)
    assert [m.header.seq for m in decoded] == list(range(len(decoded)))
    assert {m.header.frame_id for m in decoded} == {"gx3_imu1"}
    assert bag.raw[CAMERA_TOPIC] == read_bag1(folder / "camera.bag").raw[CAMERA_TOPIC]
    # the moving unit, with gravity: specific force about 1 g, turning at up to 1 rad/s
    force = np.array([[m.linear_acceleration.x, m.linear_acceleration.y,
                       m.linear_acceleration.z] for m in decoded])
    assert np.linalg.norm(force, axis=1).mean() == pytest.approx(STANDARD_GRAVITY, rel=0.2)
    assert 0.1 < np.abs([m.angular_velocity.x for m in decoded]).max() < 3


def test_a_ros1_bag_holds_what_the_ros2_bag_holds(folder: Path, tmp_path: Path) -> None:
    """The same export as ROS 1 and ROS 2 bags: every message the same values, stamps,
    frames and covariances, decoded by rosbags' Noetic and Humble type stores; the noise
    record the ROS 2 bag keeps as metadata on the ROS 1 bag's latched gx3_noise topic."""
    from mcap.reader import make_reader

    noise = kalibr_yaml(tmp_path / "imu.yaml")
    options: list[str | Path] = ["--noise", noise, "--orientation-stddev", "0.01"]
    for out in (tmp_path / "a.bag", tmp_path / "a.mcap"):
        done = gx3("export", folder / "calib.mcap", "-o", out, *options)
        assert done.returncode == 0, done.stderr
    one = read_bag1(tmp_path / "a.bag")
    with (tmp_path / "a.mcap").open("rb") as f:
        reader = make_reader(f)
        two: dict[str, list[bytes]] = {}
        for _, channel, message in reader.iter_messages():
            two.setdefault(channel.topic, []).append(message.data)
        record = {m.name: dict(m.metadata) for m in reader.iter_metadata()}["gx3.noise"]
    assert sorted(one.topics) == ["/gx3/gx3_noise", "/gx3/imu1/imu"] and list(two) == [
        "/gx3/imu1/imu"]
    fields = ("orientation", "orientation_covariance", "angular_velocity",
              "angular_velocity_covariance", "linear_acceleration",
              "linear_acceleration_covariance")
    assert len(one.raw["/gx3/imu1/imu"]) == len(two["/gx3/imu1/imu"]) == 30 * RATE
    for a, b in zip(one.raw["/gx3/imu1/imu"], two["/gx3/imu1/imu"], strict=True):
        m1: Any = NOETIC.deserialize_ros1(a, messages.IMU)
        m2: Any = HUMBLE.deserialize_cdr(b, messages.IMU)
        assert (m1.header.stamp.sec, m1.header.stamp.nanosec, m1.header.frame_id) == (
            m2.header.stamp.sec, m2.header.stamp.nanosec, m2.header.frame_id)
        for name in fields:
            assert str(getattr(m1, name)) == str(getattr(m2, name)), name
    latched: Any = NOETIC.deserialize_ros1(one.raw["/gx3/gx3_noise"][0], "std_msgs/msg/String")
    noted = json.loads(latched.data)
    assert sorted(noted) == sorted(record)
    for key, value in record.items():  # the ROS 2 bag's metadata values are text
        assert noted[key] == (value if isinstance(noted[key], str) else json.loads(value))
    assert noted["units"]["imu1"]["orientation_covariance"][0] == pytest.approx(1e-4)


def test_a_unit_whose_decimation_passes_its_width_gets_its_samples_own_variance(
        tmp_path: Path) -> None:
    """A unit at 100 Hz averaging 4 cycles (D = 10 > M = 4, from its Info): its samples
    are independent, each of variance N² · 1000 Hz / 4, and that is the covariance, not
    N² · 100 Hz."""
    archive = tmp_path / "narrow.mcap"
    with ArchiveWriter(archive) as writer:
        archive_samples(writer, "imu1", Motion(STILL), _seconds(0, 10), 1 / RATE,
                        chain=SignalChain(4, 17, True))
    done = gx3("export", archive, "-o", tmp_path / "n.bag", "--noise",
               kalibr_yaml(tmp_path / "imu.yaml"))
    assert done.returncode == 0, done.stderr
    first: Any = NOETIC.deserialize_ros1(read_bag1(tmp_path / "n.bag").raw["/gx3/imu1/imu"][0],
                                         messages.IMU)
    assert first.angular_velocity_covariance[0] == pytest.approx(GYRO_DENSITY**2 * 250.0)
    assert first.linear_acceleration_covariance[8] == pytest.approx(
        sample_variance(ACCEL_DENSITY, RATE, 4))
    assert list(first.orientation_covariance) == [-1.0] + [0.0] * 8  # 0xC2: none


def test_a_bag_to_merge_is_checked_before_anything_is_written(folder: Path,
                                                              tmp_path: Path) -> None:
    """Not a ROS 1 bag, one that already has the unit's topic, one given with another
    format, or the output itself: one line each, nothing written, the camera's bag as
    it was."""
    (tmp_path / "notes.bag").write_text("not a bag\n")
    clash = tmp_path / "clash.bag"
    assert gx3("export", folder / "calib.mcap", "-o", clash).returncode == 0
    before = clash.read_bytes()
    cases: list[tuple[list[str | Path], str]] = [
        (["--merge", tmp_path / "notes.bag", "-o", tmp_path / "o.bag"],
         "cannot read it as a ROS 1 bag"),
        (["--merge", clash, "-o", tmp_path / "o.bag"],
         "already has the topic /gx3/imu1/imu, which the export writes"),
        (["--merge", folder / "camera.bag", "-o", tmp_path / "o.mcap"],
         "copies a ROS 1 bag into a ROS 1 bag"),
        (["--merge", clash, "-o", clash, "--force"], "is the input"),
    ]
    for args, says in cases:
        done = gx3("export", folder / "calib.mcap", *args)
        assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
        assert says in done.stderr, done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clash.bag", "notes.bag"]
    assert clash.read_bytes() == before
