"""`gx3 export --format ros2`: a ROS 2 bag of emulated units, read with decoders that are not
ours (mcap-ros2-support, rosbags, Rerun) and checked with physics: specific force in the
world frame is +g up, orientations are the emulated motion's true attitudes in ENU/FLU,
the field is the earth's in tesla, stamps are the table export's time_ns."""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.typesys import Stores, get_typestore

from bridge.archive.rawcapture import RawCaptureWriter
from bridge.archive.walk import read_archive
from bridge.export import bags
from bridge.export.ros2_bag import write_ros2
from bridge.export.tables import sample_table
from bridge.ingest.replay import replay
from bridge.protocol.convert import STANDARD_GRAVITY, quaternion_to_m
from bridge.ros2 import messages
from bridge.sim.capture import streaming_config, synthesize
from bridge.sim.motion import MotionConfig
from bridge.sim.unit import UnitConfig
from bridge.sim.usb import UsbDelivery
from tests.helpers.mcap_order import header, order_problems
from tests.helpers.noise import ACCEL_DENSITY, FILE_RATE_HZ, GYRO_DENSITY, kalibr_yaml
from tests.helpers.processes import gx3
from tests.helpers.rotations import rotation

#: unit -> record type: u0 has M and a magnetometer, u1 no attitude, u2 Euler angles only
#: with its rate (no accel).
UNITS = {"u0": 0xCC, "u1": 0xC2, "u2": 0xCF}
UNIT_RATE_HZ = 100.0  # decimation 10
ORIENTATION_STDDEV = 0.02  # rad
EARTH_FIELD_GAUSS = (0.2, 0.0, 0.45)  # north-east-down
#: The ROS world (ENU) of a GX3 earth (NED) vector, and the ROS body (FLU) of a GX3 body
#: (FRD) vector, written out here rather than taken from the code under test.
ENU_OF_NED = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1]], float)
FLU_OF_FRD = np.diag([1.0, -1.0, -1.0])


@dataclass
class Fleet:
    archive: Path
    truth: dict[str, dict[str, np.ndarray]]  # unit -> the emulator's truth per record


@dataclass
class Bag:
    profile: str
    metadata: dict[str, dict[str, str]]  # MCAP metadata records by name
    channels: dict[str, tuple[str, str, str, bytes]]  # topic -> encodings, schema name, data
    log_time: list[int]  # every message in file order
    topics: list[str]
    decoded: dict[str, list[Any]]  # topic -> messages, by mcap-ros2-support
    raw: dict[str, list[bytes]]
    sequence: dict[str, list[int]]


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Fleet:
    """Ten seconds of three emulated units at 100 Hz (no linear acceleration, so the
    specific force is gravity alone), captured over USB and replayed into one archive."""
    folder = tmp_path_factory.mktemp("ros2")
    captures, truth = [], {}
    for i, (unit, code) in enumerate(UNITS.items()):
        motion = MotionConfig(seed=i + 3, linear_accel_amplitude_g=0.0,
                              earth_field_gauss=EARTH_FIELD_GAUSS)
        cap = synthesize(streaming_config(UnitConfig(motion=motion), code=code, decimation=10),
                         UsbDelivery(seed=i), seconds=10.0)
        meta = {"unit": unit, "record": hex(code), "decimation": "10", "filter_width": "15",
                "baud": "115200", "transport": "usb"}
        writer = RawCaptureWriter(folder / f"{unit}.raw.mcap", "gx3", unit, meta)
        for rx, data in zip(cap.rx_ns.tolist(), cap.data, strict=True):
            writer.write(data, rx)
        writer.close()
        captures.append(folder / f"{unit}.raw.mcap")
        truth[unit] = cap.truth
    replay(captures, folder / "fleet.mcap")
    return Fleet(folder / "fleet.mcap", truth)


def read_bag(path: Path) -> Bag:
    bag = Bag("", {}, {}, [], [], {}, {}, {})
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        bag.profile = reader.get_header().profile
        bag.metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        summary = reader.get_summary()
        assert summary is not None
        for c in summary.channels.values():
            s = summary.schemas[c.schema_id]
            bag.channels[c.topic] = (c.message_encoding, s.encoding, s.name, s.data)
            assert c.metadata == {"offered_qos_profiles": "[]"}  # required by the ros2 profile
        for _, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
            assert message.publish_time == message.log_time
            bag.log_time.append(message.log_time)
            bag.topics.append(channel.topic)
            bag.decoded.setdefault(channel.topic, []).append(decoded)
            bag.raw.setdefault(channel.topic, []).append(message.data)
            bag.sequence.setdefault(channel.topic, []).append(message.sequence)
    return bag


@pytest.fixture(scope="module")
def exported(fleet: Fleet, tmp_path_factory: pytest.TempPathFactory) -> tuple[Bag, dict[
        str, np.ndarray], Path]:
    """The whole fleet as a ROS 2 bag, and as the Parquet table with the same options."""
    folder = tmp_path_factory.mktemp("ros2out")
    out = folder / "fleet.ros2.mcap"
    done = gx3("export", fleet.archive, "-o", out, "--format", "ros2")
    assert done.returncode == 0, done.stderr
    assert "Imu and" in done.stderr and "MagneticField messages" in done.stderr
    table = folder / "fleet.parquet"
    done = gx3("export", fleet.archive, "-o", table)
    assert done.returncode == 0, done.stderr
    cols = {k: np.asarray(v) for k, v in pq.read_table(table).to_pydict().items()}
    return read_bag(out), cols, out


def stamps(decoded: list[Any]) -> np.ndarray:
    return np.array([m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
                     for m in decoded], np.int64)


def vectors(decoded: list[Any], field: str) -> np.ndarray:
    return np.array([[getattr(getattr(m, field), a) for a in "xyz"] for m in decoded])


def orientations(decoded: list[Any]) -> np.ndarray:
    return np.array([[getattr(m.orientation, a) for a in "xyzw"]
                     for m in decoded])


def test_the_bag_is_what_rosbag2_writes(exported: tuple[Bag, dict[str, np.ndarray], Path]) -> None:
    bag, _, path = exported
    assert bag.profile == "ros2" and header(path).profile == "ros2"
    assert set(bag.channels) == {"/gx3/u0/imu", "/gx3/u0/mag", "/gx3/u1/imu", "/gx3/u2/imu"}
    for topic, (message_encoding, schema_encoding, name, data) in bag.channels.items():
        assert (message_encoding, schema_encoding) == ("cdr", "ros2msg")
        assert name == ("sensor_msgs/msg/MagneticField" if topic.endswith("/mag")
                        else "sensor_msgs/msg/Imu")
        text = data.decode()
        assert text == messages.message_definition(name)
        assert "\nMSG: std_msgs/Header\n" in text and "\nMSG: builtin_interfaces/Time\n" in text
    assert not order_problems(path)
    assert bag.log_time == sorted(bag.log_time)
    for topic, decoded in bag.decoded.items():
        unit = topic.split("/")[2]
        assert {m.header.frame_id for m in decoded} == {f"gx3_{unit}"}
        assert np.array_equal(stamps(decoded), [t for t, k in zip(bag.log_time, bag.topics,
                                                                  strict=True) if k == topic])
        assert bag.sequence[topic] == list(range(len(decoded)))


def test_a_long_export_is_encoded_in_slices_to_the_same_bag(
        fleet: Fleet, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    table = sample_table(read_archive(fleet.archive), re_estimate=None)
    write_ros2(table, tmp_path / "whole.mcap")
    monkeypatch.setattr(bags, "SLICE", 97)
    write_ros2(table, tmp_path / "sliced.mcap")
    whole, sliced = read_bag(tmp_path / "whole.mcap"), read_bag(tmp_path / "sliced.mcap")
    assert sliced.raw == whole.raw and sliced.sequence == whole.sequence
    assert sliced.log_time == whole.log_time
    assert len(whole.log_time) == len(table["time_ns"]) + (table["unit"] == "u0").sum()


def test_stamps_are_the_table_exports_time_ns(
        exported: tuple[Bag, dict[str, np.ndarray], Path]) -> None:
    bag, table, _ = exported
    for unit in UNITS:
        mine = table["unit"] == unit
        assert mine.sum() > 900
        np.testing.assert_array_equal(stamps(bag.decoded[f"/gx3/{unit}/imu"]),
                                      table["time_ns"][mine])
    np.testing.assert_array_equal(stamps(bag.decoded["/gx3/u0/mag"]),
                                  table["time_ns"][table["unit"] == "u0"])


def test_the_same_options_as_the_table_export(fleet: Fleet, tmp_path: Path) -> None:
    options = ["--unit", "u0", "--unit", "u2", "--start", "2.5", "--end", "6"]
    assert gx3("export", fleet.archive, "-o", tmp_path / "b.mcap", "--format", "ros2",
               *options).returncode == 0
    assert gx3("export", fleet.archive, "-o", tmp_path / "t.parquet", *options).returncode == 0
    table = pq.read_table(tmp_path / "t.parquet").to_pydict()
    bag = read_bag(tmp_path / "b.mcap")
    assert set(bag.channels) == {"/gx3/u0/imu", "/gx3/u0/mag", "/gx3/u2/imu"}
    both = np.concatenate([stamps(bag.decoded["/gx3/u0/imu"]),
                           stamps(bag.decoded["/gx3/u2/imu"])])
    assert 600 < len(both) < 800
    np.testing.assert_array_equal(np.sort(both), np.sort(table["time_ns"]))


def test_specific_force_in_the_world_frame_is_g_up(
        exported: tuple[Bag, dict[str, np.ndarray], Path]) -> None:
    """The unit turns and tilts but does not accelerate: rotating each linear
    acceleration into the world by its orientation gives (0, 0, +9.81) m/s²."""
    bag, _, _ = exported
    decoded = bag.decoded["/gx3/u0/imu"]
    accel, q = vectors(decoded, "linear_acceleration"), orientations(decoded)
    world = np.array([rotation(qi) @ ai for qi, ai in zip(q, accel, strict=True)])
    assert np.ptp(accel[:, 2]) > 1.0, "the unit should tilt"
    np.testing.assert_allclose(world, np.tile([0.0, 0.0, STANDARD_GRAVITY], (len(world), 1)),
                               atol=1e-5)


def test_orientations_are_the_true_attitudes_in_enu_and_flu(
        fleet: Fleet, exported: tuple[Bag, dict[str, np.ndarray], Path]) -> None:
    """The emulator's true quaternion (the manual's, earth to sensor) as a body-to-world
    rotation, NED and FRD turned into ENU and FLU, for M (u0) and Euler (u2) records."""
    bag, table, _ = exported
    for unit in ("u0", "u2"):
        truth = fleet.truth[unit]
        by_timer = dict(zip(truth["timer"].tolist(), range(len(truth["timer"])), strict=True))
        timers = table["timer"][table["unit"] == unit]
        true_m = quaternion_to_m(truth["quaternion"][[by_timer[t] for t in timers.tolist()]])
        expected = ENU_OF_NED @ true_m.transpose(0, 2, 1) @ FLU_OF_FRD.T
        q = orientations(bag.decoded[f"/gx3/{unit}/imu"])
        got = np.array([rotation(qi) for qi in q])
        np.testing.assert_allclose(got, expected, atol=2e-5)
        assert np.ptp(np.degrees(np.arctan2(got[:, 1, 0], got[:, 0, 0]))) > 20, "it should turn"
        for m in bag.decoded[f"/gx3/{unit}/imu"]:
            assert m.orientation_covariance[0] == 0.0


def test_a_record_without_a_quantity_marks_its_covariance(
        exported: tuple[Bag, dict[str, np.ndarray], Path]) -> None:
    bag, table, _ = exported
    no_attitude = bag.decoded["/gx3/u1/imu"]
    for m in no_attitude:
        assert m.orientation_covariance[0] == -1.0
        assert m.linear_acceleration_covariance[0] == 0.0
    mine = table["unit"] == "u1"
    frd = np.stack([table[f"accel_{a}"][mine] for a in "xyz"], axis=1).astype(np.float64)
    np.testing.assert_allclose(vectors(no_attitude, "linear_acceleration"),
                               frd * [1, -1, -1] * STANDARD_GRAVITY, rtol=1e-12)
    frd = np.stack([table[f"ang_rate_{a}"][mine] for a in "xyz"], axis=1).astype(np.float64)
    np.testing.assert_allclose(vectors(no_attitude, "angular_velocity"), frd * [1, -1, -1],
                               rtol=1e-12)
    for m in bag.decoded["/gx3/u2/imu"]:  # Euler and rate: no accelerometer
        assert m.linear_acceleration_covariance[0] == -1.0
        assert m.angular_velocity_covariance[0] == 0.0


def test_the_field_is_the_earths_in_tesla(
        exported: tuple[Bag, dict[str, np.ndarray], Path]) -> None:
    """Body field rotated into the world by the Imu orientation of the same sample: the
    emulated earth field (0.2 G north, 0.45 G down) as ENU tesla."""
    bag, _, _ = exported
    field = vectors(bag.decoded["/gx3/u0/mag"], "magnetic_field")
    q = orientations(bag.decoded["/gx3/u0/imu"])
    world = np.array([rotation(qi) @ fi for qi, fi in zip(q, field, strict=True)])
    north, down = EARTH_FIELD_GAUSS[0] * 1e-4, EARTH_FIELD_GAUSS[2] * 1e-4
    np.testing.assert_allclose(world, np.tile([0.0, north, -down], (len(world), 1)), atol=5e-7)


@pytest.mark.parametrize("frame", ["u", "gx3_u1", "gx3_u12", "gx3_abcdefgh", "a" * 13])
def test_messages_are_byte_for_byte_what_rosbags_serializes(frame: str) -> None:
    """Each frame id length puts the doubles after a different padding."""
    store = get_typestore(messages.DISTROS[messages.DEFAULT_DISTRO])
    rng = np.random.default_rng(len(frame))
    n = 5
    columns = {"accel": rng.normal(size=(n, 3)), "ang_rate": rng.normal(size=(n, 3)),
               "m": quaternion_to_m(rng.normal(size=(n, 4))), "mag": rng.normal(size=(n, 3))}
    columns["accel"][1] = np.nan
    columns["m"][2] = np.nan
    t = 1_763_000_000_000_000_000 + rng.integers(0, 10**12, n)
    for msgtype, batch in ((messages.IMU, messages.imu_cdr_batch),
                           (messages.MAGNETIC_FIELD, messages.mag_cdr_batch)):
        for k, data in enumerate(batch(t, frame, columns)):
            decoded: Any = store.deserialize_cdr(data, msgtype)
            assert decoded.header.frame_id == frame
            assert decoded.header.stamp.sec * 10**9 + decoded.header.stamp.nanosec == t[k]
            assert bytes(store.serialize_cdr(decoded, msgtype)) == data
    one = messages.imu_cdr(int(t[0]), frame, {k: v[0] for k, v in columns.items()})
    assert one == messages.imu_cdr_batch(t, frame, columns)[0]


def test_rerun_plots_the_imu_topics_as_time_series(
        exported: tuple[Bag, dict[str, np.ndarray], Path]) -> None:
    """Rerun's own MCAP reader turns each Imu topic into Scalars (gyro xyz, accel xyz)
    on a ros2_timestamp timeline at the stamps: plots with no configuration."""
    from rerun.chunk import McapReader

    bag, _, path = exported
    series: dict[str, list[np.ndarray]] = {}
    times: dict[str, list[int]] = {}
    names: dict[str, list[str]] = {}
    for chunk in McapReader(path, include_topic_regex=[".*/imu"]).stream():
        batch = chunk.to_record_batch()
        if "SeriesLines:names" in batch.schema.names:
            names[chunk.entity_path] = batch.column("SeriesLines:names")[0].as_py()
        if "Scalars:scalars" in batch.schema.names:
            series.setdefault(chunk.entity_path, []).extend(
                np.array(v) for v in batch.column("Scalars:scalars").to_pylist())
            times.setdefault(chunk.entity_path, []).extend(
                batch.column("ros2_timestamp").cast("int64").to_pylist())
    assert set(series) == {f"/gx3/{u}/imu" for u in UNITS}
    for entity, values in series.items():
        assert names[entity] == [f"{s}/{a}" for s in ("gyroscope", "accelerometer")
                                 for a in "xyz"]
        decoded = bag.decoded[entity]
        order = np.argsort(times[entity], kind="stable")
        np.testing.assert_array_equal(np.array(times[entity])[order], stamps(decoded))
        expected = np.concatenate([vectors(decoded, "angular_velocity"),
                                   vectors(decoded, "linear_acceleration")], axis=1)
        np.testing.assert_array_equal(np.array(values)[order], expected)


@pytest.mark.parametrize(("args", "says"), [
    (["-o", "{d}/b.parquet", "--format", "ros2"], "--format ros2 writes a .mcap file"),
    (["-o", "{d}/b.mcap", "--format", "hdf5"], "--format hdf5: give parquet, csv, ros2, ros1"),
    (["-o", "{d}/b.mcap", "--align", "100"], "--align makes a table"),
])
def test_a_bad_ros2_request_is_a_one_line_error(fleet: Fleet, tmp_path: Path, args: list[str],
                                                says: str) -> None:
    done = gx3("export", fleet.archive, *[a.format(d=tmp_path) for a in args])
    assert done.returncode == 2
    assert says in done.stderr and "Traceback" not in done.stderr
    assert not list(tmp_path.iterdir())


def test_an_existing_bag_is_kept_without_force(fleet: Fleet, tmp_path: Path) -> None:
    out = tmp_path / "b.mcap"
    out.write_bytes(b"mine")
    done = gx3("export", fleet.archive, "-o", out)
    assert done.returncode == 2 and "exists" in done.stderr
    assert out.read_bytes() == b"mine"
    assert gx3("export", fleet.archive, "-o", out, "--force").returncode == 0
    assert read_bag(out).profile == "ros2"


@pytest.fixture(scope="module")
def noisy(fleet: Fleet, tmp_path_factory: pytest.TempPathFactory) -> tuple[Bag, str, Path]:
    """The fleet as a ROS 2 bag with a noise file measured at 200 Hz (the units run at
    100 Hz) and an orientation standard deviation, and what gx3 export said."""
    folder = tmp_path_factory.mktemp("noisy")
    noise = kalibr_yaml(folder / "imu.yaml", extra="allan_fit: {tau: [0.1, 1.0]}\n")
    out = folder / "fleet.ros2.mcap"
    done = gx3("export", fleet.archive, "-o", out, "--noise", noise,
               "--orientation-stddev", str(ORIENTATION_STDDEV))
    assert done.returncode == 0, done.stderr
    return read_bag(out), done.stderr, noise


def _diagonal(variance: float) -> list[float]:
    return [variance, 0, 0, 0, variance, 0, 0, 0, variance]


def test_noise_gives_variances_of_density_squared_times_the_units_rate(
        exported: tuple[Bag, dict[str, np.ndarray], Path],
        noisy: tuple[Bag, str, Path]) -> None:
    """Read back by mcap-ros2-support: σ² = N² · 100 Hz (the units' rate from their Info,
    not the file's 200 Hz; their decimation, 10, is under their filter width, 15) on the
    diagonal of every quantity a record carries, 0 off it; the orientation's variance
    given where a record carries one (u0's M, u2's Euler angles), and -1 in element 0
    for a quantity a record lacks (u1's orientation, u2's accel). Every value but the
    covariances is the noise-less bag's."""
    plain, _, _ = exported
    bag, stderr, _ = noisy
    gyro = _diagonal(GYRO_DENSITY**2 * UNIT_RATE_HZ)
    accel = _diagonal(ACCEL_DENSITY**2 * UNIT_RATE_HZ)
    assert gyro[0] == pytest.approx(3.6e-7) and accel[0] == pytest.approx(6.4e-5)
    orientation = _diagonal(ORIENTATION_STDDEV**2)
    lacks = [-1.0] + [0.0] * 8
    carries = {"u0": ("orientation", "accel", "rate"), "u1": ("accel", "rate"),
               "u2": ("orientation", "rate")}
    for unit, has in carries.items():
        decoded = bag.decoded[f"/gx3/{unit}/imu"]
        assert len(decoded) > 900
        for m in decoded:
            assert list(m.orientation_covariance) == (orientation if "orientation" in has
                                                      else lacks)
            assert list(m.angular_velocity_covariance) == (gyro if "rate" in has else lacks)
            assert list(m.linear_acceleration_covariance) == (accel if "accel" in has
                                                              else lacks)
        before = plain.decoded[f"/gx3/{unit}/imu"]
        np.testing.assert_array_equal(stamps(decoded), stamps(before))
        np.testing.assert_array_equal(orientations(decoded), orientations(before))
        for field in ("angular_velocity", "linear_acceleration"):
            np.testing.assert_array_equal(vectors(decoded, field), vectors(before, field))
    assert bag.raw["/gx3/u0/mag"] == plain.raw["/gx3/u0/mag"]
    for unit in UNITS:
        assert (f"unit {unit}: its covariances use its output rate, 100 Hz, and filter width, "
                f"15 (its Info), not imu.yaml's update_rate, {FILE_RATE_HZ:g} Hz") in stderr


def test_without_noise_an_orientation_is_unknown_not_absent(
        exported: tuple[Bag, dict[str, np.ndarray], Path]) -> None:
    """REP-145: a covariance nobody measured is all 0; -1 in element 0 says the message
    has no orientation at all, and robot_localization would then drop it."""
    bag = exported[0]
    for unit, has in (("u0", True), ("u1", False), ("u2", True)):
        for m in bag.decoded[f"/gx3/{unit}/imu"]:
            assert list(m.orientation_covariance) == [0.0 if has else -1.0] + [0.0] * 8


def test_the_bag_names_the_noise_file_it_used(noisy: tuple[Bag, str, Path]) -> None:
    bag, _, noise = noisy
    record = bag.metadata["gx3.noise"]
    assert record["file"] == str(noise)
    assert record["sha256"] == hashlib.sha256(noise.read_bytes()).hexdigest()
    assert float(record["gyroscope_noise_density"]) == GYRO_DENSITY
    assert float(record["update_rate"]) == FILE_RATE_HZ
    assert "allan_fit" not in record
    units = json.loads(record["units"])
    assert sorted(units) == sorted(UNITS)
    assert units["u1"]["rate_hz"] == UNIT_RATE_HZ and units["u1"]["filter_width"] == 15
    assert units["u1"]["angular_velocity_covariance"][4] == GYRO_DENSITY**2 * UNIT_RATE_HZ
    assert float(record["orientation_stddev"]) == ORIENTATION_STDDEV


def test_without_noise_the_bag_has_no_noise_record(
        exported: tuple[Bag, dict[str, np.ndarray], Path]) -> None:
    assert exported[0].metadata == {}


def test_a_humble_bag_is_the_jazzy_bag(fleet: Fleet, tmp_path: Path,
                                       noisy: tuple[Bag, str, Path]) -> None:
    """Humble's definitions of Imu, MagneticField and the types they use are Jazzy's text,
    so the bag for Humble is the same bytes; Humble's type store decodes it."""
    for msgtype in (messages.IMU, messages.MAGNETIC_FIELD):
        assert (messages.message_definition(msgtype, "humble")
                == messages.message_definition(msgtype, "jazzy"))
    options: list[str | Path] = ["--unit", "u0", "--end", "3", "--noise", noisy[2]]
    assert gx3("export", fleet.archive, "-o", tmp_path / "j.mcap", *options).returncode == 0
    done = gx3("export", fleet.archive, "-o", tmp_path / "h.mcap", "--ros2-distro", "HUMBLE",
               *options)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "h.mcap").read_bytes() == (tmp_path / "j.mcap").read_bytes()
    humble = get_typestore(Stores.ROS2_HUMBLE)
    bag = read_bag(tmp_path / "h.mcap")
    for topic, raw in bag.raw.items():
        msgtype = bag.channels[topic][2]
        assert bag.channels[topic][3].decode() == humble.generate_msgdef(msgtype,
                                                                         ros_version=2)[0]
        for data, m in zip(raw, bag.decoded[topic], strict=True):
            again: Any = humble.deserialize_cdr(data, msgtype)
            assert again.header.stamp.sec == m.header.stamp.sec
    first: Any = humble.deserialize_cdr(bag.raw["/gx3/u0/imu"][0], messages.IMU)
    assert first.angular_velocity_covariance[0] == GYRO_DENSITY**2 * UNIT_RATE_HZ


def test_a_parquet_table_records_the_noise_file_and_keeps_its_samples(
        fleet: Fleet, tmp_path: Path, noisy: tuple[Bag, str, Path]) -> None:
    """--noise on a table is provenance: the samples are the same; the gx3.noise metadata
    names the file and the covariances a bag would carry."""
    noise = noisy[2]
    options = ["--unit", "u1", "--end", "2"]
    assert gx3("export", fleet.archive, "-o", tmp_path / "a.parquet", *options).returncode == 0
    done = gx3("export", fleet.archive, "-o", tmp_path / "b.parquet", "--noise", noise,
               *options)
    assert done.returncode == 0, done.stderr
    plain, noted = pq.read_table(tmp_path / "a.parquet"), pq.read_table(tmp_path / "b.parquet")
    assert noted.equals(plain)
    meta = noted.schema.metadata
    assert b"gx3.noise" not in plain.schema.metadata
    record = json.loads(meta[b"gx3.noise"])
    assert record["file"] == str(noise) and record["gyroscope_noise_density"] == GYRO_DENSITY
    assert record["units"]["u1"]["linear_acceleration_covariance"][8] == (
        ACCEL_DENSITY**2 * UNIT_RATE_HZ)
    assert record["units"]["u1"]["orientation_covariance"] == _diagonal(0.0)
