"""ROS 2, live: what `gx3 bridge --ros2` puts on Zenoh, checked as rmw_zenoh_cpp reads it.

No ROS 2 runs here, so every string and byte is checked against the examples of
ros2/rmw_zenoh's docs/design.md (commit 99a6a2bd10b949052f4f12c5854825dc005e95a5,
quoted below), the type hash against rosbags' REP-2011 implementation (which must
reproduce the design doc's std_msgs/String hash first), the attachment against
Zenoh's own serializer, and payloads with rosbags' CDR decoder and mcap-ros2-support's.
"""

from __future__ import annotations

import json
import re
import signal
import subprocess
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh
from mcap_ros2._dynamic import generate_dynamic
from rosbags.typesys import Stores, get_typestore
from zenoh.ext import Int64, UInt8, z_serialize

from bridge.bus.session import open_session
from bridge.protocol.codec import Batch
from bridge.protocol.convert import euler_to_m
from bridge.ros2.messages import (
    IMU,
    MAGNETIC_FIELD,
    message_definition,
    ros_token,
    ros_topic,
    type_hash,
)
from bridge.ros2.noise import read_noise
from bridge.ros2.rmw import (
    NodeName,
    Qos,
    Ros2Node,
    UnitTopics,
    attachment,
    dds_type,
    gid,
    key_type_hash,
    parse_attachment,
    qos_keyexpr,
    topic_key,
)
from bridge.ros2.xxh3 import xxh3_128, xxh3_128_bytes
from tests.helpers.noise import ACCEL_DENSITY, GYRO_DENSITY, kalibr_yaml
from tests.helpers.processes import GX3, bridge_process
from tests.helpers.waiting import free_port, wait_for

# Examples quoted from the design doc.
STRING_TYPE = "std_msgs::msg::dds_::String_"
STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
ADD_TYPE = "example_interfaces::srv::dds_::AddTwoInts_"
ADD_HASH = "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a"
DOC_KEYS = {
    (0, "/chatter", STRING_TYPE, STRING_HASH): f"0/chatter/{STRING_TYPE}/{STRING_HASH}",
    (0, "/robot1/chatter", STRING_TYPE, STRING_HASH):
        f"0/robot1/chatter/{STRING_TYPE}/{STRING_HASH}",
    (2, "/add_two_ints", ADD_TYPE, ADD_HASH): f"2/add_two_ints/{ADD_TYPE}/{ADD_HASH}",
}
DOC_LISTENER_NODE = "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
DOC_TALKER_PUB = ("@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
                  f"{STRING_TYPE}/{STRING_HASH}/::,7:,:,:,,")
DOC_LISTENER_QOS = "::,10:,:,:,,"
IMU_TYPE = "sensor_msgs::msg::dds_::Imu_"
IMU_HASH = type_hash(IMU)


@pytest.mark.parametrize(("args", "expected"), list(DOC_KEYS.items()))
def test_topic_keys_are_the_design_docs(args: tuple[int, str, str, str], expected: str) -> None:
    assert topic_key(*args) == expected


def test_liveliness_tokens_are_the_design_docs() -> None:
    listener = NodeName(2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, "listener")
    assert listener.node_token() == DOC_LISTENER_NODE
    talker = NodeName(2, "8b20917502ee955ac4476e0266340d5c", 0, "talker")
    assert talker.publisher_token(10, "/chatter", STRING_TYPE, STRING_HASH,
                                  Qos(depth=7)) == DOC_TALKER_PUB
    # the listener's keep-last-10 subscription: the QoS the bridge announces
    assert qos_keyexpr(Qos()) == DOC_LISTENER_QOS
    # what differs from rmw_zenoh's defaults is spelled with rmw's enum values
    assert qos_keyexpr(Qos(reliability=2, durability=1, history=2, depth=42)) == "2:1:2,:,:,:,,"


def test_the_imu_type_hash_is_rep_2011s() -> None:
    """rosbags computes REP-2011 hashes from the type descriptions; it reproduces the
    design doc's std_msgs/String hash, so its sensor_msgs/Imu hash is the one to use."""
    for store in (Stores.ROS2_HUMBLE, Stores.ROS2_JAZZY, Stores.LATEST):
        types = get_typestore(store)
        assert types.hash_rihs01("std_msgs/msg/String") == STRING_HASH
        assert types.hash_rihs01("sensor_msgs/msg/Imu") == IMU_HASH
    assert IMU_HASH.startswith("RIHS01_7d9a")  # the example
    assert dds_type("std_msgs/msg/String") == STRING_TYPE
    assert dds_type("example_interfaces/srv/AddTwoInts") == ADD_TYPE
    assert dds_type(IMU) == IMU_TYPE


def test_the_attachment_is_zenohs_serialization_of_seq_stamp_gid() -> None:
    """design.md: int64 LE sequence, int64 LE ns timestamp, 1 byte GID length (16), the GID;
    exactly what zenoh-cpp's ext::Serializer makes of (int64, int64, array<uint8, 16>)."""
    gid = bytes(range(200, 216))
    data = attachment(7, 1_764_000_000_123_456_789, gid)
    assert len(data) == 33
    expected = z_serialize((Int64(7), Int64(1_764_000_000_123_456_789),
                            [UInt8(b) for b in gid])).to_bytes()
    assert data == expected
    assert data[:8] == (7).to_bytes(8, "little") and data[16] == 16 and data[17:] == gid
    assert parse_attachment(data) == (7, 1_764_000_000_123_456_789, gid)
    with pytest.raises(ValueError, match="33 bytes"):
        parse_attachment(data[:-1])


# xxHash's sanity-check vectors (cli/xsum_sanity_check.c): XXH3-128, seed 0, of the
# first n bytes of its pseudo-random test buffer, as (low64, high64)
XXH128_VECTORS = {
    24: (0x1E7044D28B1B901D, 0x0CE966E4678D3761), 48: (0xF942219AED80F67B, 0xA002AC4E5478227E),
    81: (0x5E8BAFB9F95FB803, 0x4952F58181AB0042), 222: (0xF1AEBD597CEC6B3A, 0x337E09641B948717),
    403: (0xCDEB804D65C6DEA4, 0x1B6DE21E332DD73D), 512: (0x617E49599013CB6B, 0x18D2D110DCC9BCA1),
    2048: (0xDD59E2C3A5F038E0, 0xF736557FD47073A5),
    2240: (0x6E73A90539CF2948, 0xCCB134FBFA7CE49D),
    2367: (0xCB37AEB9E5D361ED, 0xE89C0F6FF369B427)}


def _xxh_test_buffer(n: int) -> bytes:
    byte_gen, out = 2654435761, bytearray()
    for _ in range(n):
        out.append(byte_gen >> 56)
        byte_gen = (byte_gen * 11400714785074694797) % 2**64
    return bytes(out)


@pytest.mark.parametrize("n", sorted(XXH128_VECTORS))
def test_gids_are_xxh3_128_of_the_token_as_rmw_zenohs(n: int) -> None:
    """Every length class of XXH3-128 (17-128, 129-240, one and several 1 KiB blocks)."""
    data = _xxh_test_buffer(n)
    assert xxh3_128(data) == XXH128_VECTORS[n]
    low, high = XXH128_VECTORS[n]
    assert xxh3_128_bytes(data) == low.to_bytes(8, "little") + high.to_bytes(8, "little")


def test_a_gid_is_the_hash_of_the_token() -> None:
    token = DOC_TALKER_PUB
    assert gid(token) == xxh3_128_bytes(token.encode()) and len(gid(token)) == 16
    with pytest.raises(ValueError, match="more than 16 bytes"):
        xxh3_128(b"@ros2_lv")


@pytest.mark.parametrize(("name", "token"), [
    ("imu1", "imu1"), ("imu-1", "imu_1"), ("lab.gx3--a", "lab_gx3_a"),
    ("6234.12345", "u6234_12345"), ("gx3", "gx3"), ("_x_", "x"), ("--", "unit")])
def test_unit_names_become_ros_name_tokens(name: str, token: str) -> None:
    assert ros_token(name) == token
    assert ros_topic("lab/gx3", name, "imu") == f"/lab/gx3/{token}/imu"


@pytest.fixture
def sessions() -> Iterator[tuple[zenoh.Session, zenoh.Session]]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with open_session(listen=[endpoint], multicast_scouting=False) as there, \
            open_session(connect=[endpoint], multicast_scouting=False) as here:
        yield there, here


def _tokens(session: zenoh.Session, key: str) -> list[str]:
    return sorted(str(r.ok.key_expr) for r in session.liveliness().get(key, timeout=5)
                  if r.ok is not None)


def test_a_node_publishes_with_attachments_and_announces_itself(
        sessions: tuple[zenoh.Session, zenoh.Session]) -> None:
    there, here = sessions
    received: list[zenoh.Sample] = []
    sub = here.declare_subscriber("0/gx3/imu1/imu/**", received.append)
    node = Ros2Node(there, 0, "gx3_bridge_imu1")
    try:
        pub = node.publisher("/gx3/imu1/imu", IMU)
        assert pub.key == f"0/gx3/imu1/imu/{IMU_TYPE}/{IMU_HASH}"
        zid = str(there.info.zid())
        expected = [f"@ros2_lv/0/{zid}/0/0/NN/%/%/gx3_bridge_imu1",
                    f"@ros2_lv/0/{zid}/0/1/MP/%/%/gx3_bridge_imu1/%gx3%imu1%imu/{IMU_TYPE}/"
                    f"{IMU_HASH}/{DOC_LISTENER_QOS}"]
        wait_for(lambda: _tokens(here, "@ros2_lv/0/**") == expected, 20, "both tokens")
        wait_for(lambda: pub.matched, 20, "the subscriber to match")
        pub.put_all([b"a", b"b"])
        pub.put_all([b"c"])
        wait_for(lambda: len(received) == 3, 20, "three samples")
        parsed = [parse_attachment(s.attachment.to_bytes()) for s in received
                  if s.attachment is not None]
        assert [s.payload.to_bytes() for s in received] == [b"a", b"b", b"c"]
        assert [p[0] for p in parsed] == [1, 2, 3]
        assert {p[2] for p in parsed} == {pub.gid}
        assert parsed[0][1] <= parsed[2][1]
    finally:
        node.close()
        node.close()
        sub.undeclare()
    wait_for(lambda: _tokens(here, "@ros2_lv/0/**") == [], 20, "the tokens to go")


def test_a_domain_out_of_range_is_refused(sessions: tuple[zenoh.Session, zenoh.Session]) -> None:
    with pytest.raises(ValueError, match="use 0 to 232"):
        Ros2Node(sessions[0], 233, "n")


def _quat_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion x, y, z, w (body -> world)."""
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


@contextmanager
def _still_unit_behind_router(tmp_path: Path, serial: str
                              ) -> Iterator[tuple[str, Path, zenoh.Session]]:
    """A still emulated unit (0xCC at 100 Hz) on a pty and a `gx3 router`: the pty, a
    client config for a bridge, and a client session of our own; all stopped after."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    client = tmp_path / "client.json5"
    client.write_text(json.dumps({"mode": "client", "connect": {"endpoints": [endpoint]},
                                  "scouting": {"multicast": {"enabled": False}}}))
    router = subprocess.Popen([GX3, "router", "--listen", endpoint],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    sim = subprocess.Popen([GX3, "sim", "--pty", "--static", "--serial", serial,
                            "--decimation", "10", "--mode-preset", "2",
                            "--continuous-preset", "0xCC"],
                           stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE)
    try:
        assert router.stdout is not None and router.stdout.readline().strip() == b"READY"
        assert sim.stdout is not None
        pty = sim.stdout.readline().decode().strip()
        with open_session(connect=[endpoint], mode="client",
                          multicast_scouting=False) as here:
            yield pty, client, here
    finally:
        for proc in (sim, router):
            proc.send_signal(signal.SIGINT)
            proc.communicate(timeout=30)


def test_gx3_bridge_ros2_is_seen_as_rmw_zenoh_publishes(tmp_path: Path) -> None:
    """A still emulated unit on a pty, `gx3 bridge --ros2` and a plain Zenoh subscriber
    through a `gx3 router`, as ROS 2 nodes meet: rmw_zenoh's keys, CDR that rosbags
    decodes to the physics of a still unit (specific force +g up in the world frame),
    attachments in sequence, and the graph's tokens."""
    types = get_typestore(Stores.ROS2_JAZZY)
    received: dict[str, list[tuple[bytes, bytes]]] = {"imu": [], "mag": []}

    def keep(sample: zenoh.Sample) -> None:
        leaf = str(sample.key_expr).split("/")[3]
        attached = sample.attachment.to_bytes() if sample.attachment is not None else b""
        received[leaf].append((sample.payload.to_bytes(), attached))

    with _still_unit_behind_router(tmp_path, "ROS0001") as (pty, client, here):
        subs = [here.declare_subscriber(f"0/gx3/imu_1/{leaf}/**", keep)
                for leaf in ("imu", "mag")]
        with bridge_process(pty, client, "--unit", "imu-1", "--ros2") as bridge:
            wait_for(lambda: len(received["imu"]) >= 50 and len(received["mag"]) >= 50,
                     60, "ROS 2 samples")
            tokens = _tokens(here, "@ros2_lv/0/**")
        assert bridge.returncode == 0, bridge.stderr.read() if bridge.stderr else ""
        for sub in subs:
            sub.undeclare()
        wait_for(lambda: _tokens(here, "@ros2_lv/0/**") == [], 20, "the tokens to go")

    zid = tokens[0].split("/")[2]
    node = "gx3_bridge_imu_1"
    qos = DOC_LISTENER_QOS
    mag_type, mag_hash = dds_type(MAGNETIC_FIELD), type_hash(MAGNETIC_FIELD)
    imu_token = (f"@ros2_lv/0/{zid}/0/1/MP/%/%/{node}/%gx3%imu_1%imu/{IMU_TYPE}/{IMU_HASH}/"
                 f"{qos}")
    assert re.fullmatch(r"[0-9a-f]{1,32}", zid)
    assert tokens == sorted([
        f"@ros2_lv/0/{zid}/0/0/NN/%/%/{node}", imu_token,
        f"@ros2_lv/0/{zid}/0/2/MP/%/%/{node}/%gx3%imu_1%mag/{mag_type}/{mag_hash}/{qos}"])

    imu: list[Any] = [types.deserialize_cdr(payload, IMU) for payload, _ in received["imu"]]
    attached = [parse_attachment(a) for _, a in received["imu"]]
    sequence = [a[0] for a in attached]
    assert sequence == sorted(set(sequence)) and sequence[0] >= 1
    assert all(a[2] == gid(imu_token) for a in attached)
    sources = [a[1] for a in attached]
    stamps = [m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec for m in imu]
    assert sources == sorted(sources) and stamps == sorted(stamps)
    now = time.time_ns()
    assert now - 120e9 < stamps[0] < now and now - 120e9 < sources[0] < now
    for m in imu:
        assert m.header.frame_id == "gx3_imu-1"
        q = np.array([m.orientation.x, m.orientation.y, m.orientation.z, m.orientation.w])
        assert abs(np.linalg.norm(q) - 1) < 1e-4
        force = np.array([m.linear_acceleration.x, m.linear_acceleration.y,
                          m.linear_acceleration.z])
        assert _quat_matrix(q) @ force == pytest.approx([0, 0, 9.80665], abs=0.05)
        rate = m.angular_velocity
        assert np.abs([rate.x, rate.y, rate.z]).max() < 0.01
        assert m.orientation_covariance[0] == 0 and m.linear_acceleration_covariance[0] == 0
    # a second decoder, from the text definition rosbag2 embeds, reads the same values
    second = generate_dynamic(IMU, message_definition(IMU))[IMU]
    for (payload, _), m in zip(received["imu"], imu, strict=True):
        other: Any = second(payload)
        assert other.header.frame_id == m.header.frame_id
        assert other.header.stamp.nanosec == m.header.stamp.nanosec
        assert [other.orientation.w, other.linear_acceleration.z, other.angular_velocity.x] \
            == [m.orientation.w, m.linear_acceleration.z, m.angular_velocity.x]
    mag: list[Any] = [types.deserialize_cdr(payload, MAGNETIC_FIELD)
                      for payload, _ in received["mag"]]
    for m in mag:
        field = np.array([m.magnetic_field.x, m.magnetic_field.y, m.magnetic_field.z])
        assert 10e-6 < np.linalg.norm(field) < 100e-6  # the Earth's field is 25-65 µT
    assert [parse_attachment(a)[0] for _, a in received["mag"]][:1] >= [1]


def test_ros2_domain_needs_ros2() -> None:
    done = subprocess.run([GX3, "bridge", "--port", "/dev/null", "--ros2-domain", "3"],
                          capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 2 and "add --ros2" in done.stderr


def test_a_units_topics_follow_the_domain_prefix_and_leave_out_records_without_a_field(
        sessions: tuple[zenoh.Session, zenoh.Session]) -> None:
    """0xCC records (accel, ang_rate, mag, M) in domain 7 under prefix lab/gx3: every
    record an Imu, only those with a field a MagneticField, on ROS-legal names."""
    there, here = sessions
    received: list[zenoh.Sample] = []
    sub = here.declare_subscriber("7/lab/gx3/u6234_1/**", received.append)
    n = 4
    mag = np.tile(np.array([0.2, 0.0, 0.4], np.float32), (n, 1))
    mag[1] = np.nan
    columns = {"accel": np.tile(np.array([0, 0, -1], np.float32), (n, 1)),
               "ang_rate": np.zeros((n, 3), np.float32), "mag": mag,
               "m": euler_to_m(np.zeros((n, 3))).astype(np.float32),
               "timer": np.arange(n, dtype=np.uint32)}
    stamps = time.time_ns() + np.arange(n, dtype=np.int64) * 10_000_000
    topics = UnitTopics(there, 7, "lab/gx3", "6234.1")
    try:
        wait_for(lambda: topics.imu.matched and topics.mag.matched, 20, "the subscriber")
        topics.publish(Batch(0xCC, columns, np.arange(n), np.zeros(n, np.int64), False), stamps)
        wait_for(lambda: len(received) == n + n - 1, 20, "4 Imu and 3 MagneticField")
    finally:
        topics.close()
        sub.undeclare()
    types = get_typestore(Stores.ROS2_JAZZY)
    by_key: dict[str, list[Any]] = {}
    for s in received:
        by_key.setdefault(str(s.key_expr), []).append(s)
    assert sorted(by_key) == [f"7/lab/gx3/u6234_1/imu/{IMU_TYPE}/{IMU_HASH}",
                              f"7/lab/gx3/u6234_1/mag/{dds_type(MAGNETIC_FIELD)}/"
                              f"{type_hash(MAGNETIC_FIELD)}"]
    imu, fields = by_key.values()
    decoded: list[Any] = [types.deserialize_cdr(s.payload.to_bytes(), MAGNETIC_FIELD)
                          for s in fields]
    assert [m.header.stamp.nanosec for m in decoded] == [int(t % 10**9) for t in stamps[[0, 2, 3]]]
    assert decoded[0].magnetic_field.z == pytest.approx(-0.4e-4)  # gauss down -> tesla up
    assert [parse_attachment(s.attachment.to_bytes())[0] for s in imu] == [1, 2, 3, 4]
    assert [parse_attachment(s.attachment.to_bytes())[0] for s in fields] == [1, 2, 3]


# Humble: docs/design.md of rmw_zenoh's humble branch (release 0.1.9; upstream commit
# d60045d71ca16efcc7b98ac9bd076426b9e8340e of ros2-gbp/rmw_zenoh-release).
HUMBLE_KEY_FORMAT = "<domain_id>/<fully_qualified_name>/<type_name>/TypeHashNotSupported"
HUMBLE_TOKEN_FORMAT = ("@ros2_lv/<domain_id>/<session_id>/<node_id>/<entity_id>/<entity_kind>/"
                       "<mangled_enclave>/<mangled_namespace>/<node_name>/"
                       "<mangled_qualified_name>/<type_name>/TypeHashNotSupported/<qos>")


def _fill(form: str, **chunks: str) -> str:
    for name, value in chunks.items():
        form = form.replace(f"<{name}>", value)
    assert "<" not in form, form
    return form


def test_humble_keys_and_tokens_are_the_humble_design_docs() -> None:
    """The humble branch's design.md:

        The format of key expressions for topics and services is:
        `<domain_id>/<fully_qualified_name>/<type_name>/TypeHashNotSupported`

        The format of a liveliness token for a publisher, subscription, service server,
        or service client:
        @ros2_lv/<domain_id>/<session_id>/<node_id>/<entity_id>/<entity_kind>/
        <mangled_enclave>/<mangled_namespace>/<node_name>/<mangled_qualified_name>/
        <type_name>/TypeHashNotSupported/<qos>

    (its examples still show Jazzy's RIHS01 hashes; rmw_publisher_data.cpp of the same
    release writes the constant "TypeHashNotSupported" where the hash goes). The node's
    token has no type, so it is Jazzy's; the QoS chunk is the same code."""
    hashed = key_type_hash("std_msgs/msg/String", "humble")
    assert hashed == "TypeHashNotSupported"
    assert key_type_hash("std_msgs/msg/String", "jazzy") == STRING_HASH
    assert topic_key(0, "/chatter", STRING_TYPE, hashed) == _fill(
        HUMBLE_KEY_FORMAT, domain_id="0", fully_qualified_name="chatter",
        type_name=STRING_TYPE) == "0/chatter/std_msgs::msg::dds_::String_/TypeHashNotSupported"
    assert topic_key(0, "/robot1/chatter", STRING_TYPE, hashed) == (
        "0/robot1/chatter/std_msgs::msg::dds_::String_/TypeHashNotSupported")
    talker = NodeName(2, "8b20917502ee955ac4476e0266340d5c", 0, "talker")
    token = talker.publisher_token(10, "/chatter", STRING_TYPE, hashed, Qos(depth=7))
    assert token == _fill(
        HUMBLE_TOKEN_FORMAT, domain_id="2", session_id="8b20917502ee955ac4476e0266340d5c",
        node_id="0", entity_id="10", entity_kind="MP", mangled_enclave="%",
        mangled_namespace="%", node_name="talker", mangled_qualified_name="%chatter",
        type_name=STRING_TYPE, qos="::,7:,:,:,,")
    assert token == ("@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
                     "std_msgs::msg::dds_::String_/TypeHashNotSupported/::,7:,:,:,,")
    with pytest.raises(ValueError, match="give humble or jazzy"):
        key_type_hash(IMU, "iron")


def test_a_humble_subscriber_gets_the_units_imu_with_its_covariances(
        sessions: tuple[zenoh.Session, zenoh.Session], tmp_path: Path) -> None:
    """A subscriber on the exact key a Humble node declares receives every Imu, and the
    Humble node's graph sees TypeHashNotSupported tokens; nothing goes out on Jazzy's key.
    Decoded with rosbags' Humble types: σ² = N² · the rate given (250 Hz: decimation 4,
    under the filter width 15), the orientation (M) 0, unknown; a record without accel:
    -1 in element 0 there."""
    there, here = sessions
    humble_key = "0/gx3/imu1/imu/sensor_msgs::msg::dds_::Imu_/TypeHashNotSupported"
    jazzy_key = f"0/gx3/imu1/imu/{IMU_TYPE}/{IMU_HASH}"
    received: list[zenoh.Sample] = []
    on_jazzy: list[zenoh.Sample] = []
    sub = here.declare_subscriber(humble_key, received.append)
    other = here.declare_subscriber(jazzy_key, on_jazzy.append)
    n = 5
    accel = np.tile(np.array([0, 0, -1], np.float32), (n, 1))
    accel[3] = np.nan
    columns = {"accel": accel, "ang_rate": np.full((n, 3), 0.01, np.float32),
               "mag": np.tile(np.array([0.2, 0.0, 0.4], np.float32), (n, 1)),
               "m": euler_to_m(np.zeros((n, 3))).astype(np.float32),
               "timer": np.arange(n, dtype=np.uint32)}
    stamps = time.time_ns() + np.arange(n, dtype=np.int64) * 4_000_000
    noise = read_noise(kalibr_yaml(tmp_path / "imu.yaml"))
    topics = UnitTopics(there, 0, "gx3", "imu1", "humble", noise)
    try:
        topics.use_settings(250.0, 15)
        assert topics.imu.key == humble_key
        wait_for(lambda: topics.imu.matched, 20, "the Humble subscriber")
        zid = str(there.info.zid())
        node = "gx3_bridge_imu1"
        expected = sorted([
            f"@ros2_lv/0/{zid}/0/0/NN/%/%/{node}",
            f"@ros2_lv/0/{zid}/0/1/MP/%/%/{node}/%gx3%imu1%imu/{IMU_TYPE}/"
            f"TypeHashNotSupported/{DOC_LISTENER_QOS}",
            f"@ros2_lv/0/{zid}/0/2/MP/%/%/{node}/%gx3%imu1%mag/{dds_type(MAGNETIC_FIELD)}/"
            f"TypeHashNotSupported/{DOC_LISTENER_QOS}"])
        wait_for(lambda: _tokens(here, "@ros2_lv/0/**") == expected, 20, "Humble tokens")
        topics.publish(Batch(0xCC, columns, np.arange(n), np.zeros(n, np.int64), False), stamps)
        wait_for(lambda: len(received) == n, 20, "5 Imu messages")
    finally:
        topics.close()
        sub.undeclare()
        other.undeclare()
    assert on_jazzy == []
    types = get_typestore(Stores.ROS2_HUMBLE)
    decoded: list[Any] = [types.deserialize_cdr(s.payload.to_bytes(), IMU) for s in received]
    gyro_var, accel_var = GYRO_DENSITY**2 * 250.0, ACCEL_DENSITY**2 * 250.0
    for k, m in enumerate(decoded):
        assert m.header.stamp.nanosec == int(stamps[k] % 10**9)
        assert list(m.orientation_covariance) == [0.0] * 9
        assert list(m.angular_velocity_covariance) == [gyro_var, 0, 0, 0, gyro_var, 0, 0, 0,
                                                       gyro_var]
        accel_cov = ([-1.0] + [0.0] * 8 if k == 3
                     else [accel_var, 0, 0, 0, accel_var, 0, 0, 0, accel_var])
        assert list(m.linear_acceleration_covariance) == accel_cov
    assert [parse_attachment(s.attachment.to_bytes())[0] for s in received
            if s.attachment is not None] == [1, 2, 3, 4, 5]


def test_gx3_bridge_ros2_humble_with_noise(tmp_path: Path) -> None:
    """`gx3 bridge --ros2 --ros2-distro humble --noise imu.yaml --orientation-stddev 0.05`
    on an emulated unit at 100 Hz (its decimation 10, under its filter width 15): a
    Humble subscriber's key gets Imu messages whose covariances are N² · 100 Hz, the
    unit's rate, not the file's 200 Hz, and 0.05² on its orientation's diagonal."""
    noise = kalibr_yaml(tmp_path / "imu.yaml")
    received: list[bytes] = []
    with _still_unit_behind_router(tmp_path, "ROS0002") as (pty, client, here):
        sub = here.declare_subscriber(
            "0/gx3/imu_2/imu/sensor_msgs::msg::dds_::Imu_/TypeHashNotSupported",
            lambda s: received.append(s.payload.to_bytes()))
        with bridge_process(pty, client, "--unit", "imu-2", "--ros2", "--ros2-distro",
                            "humble", "--noise", str(noise), "--orientation-stddev",
                            "0.05") as bridge:
            wait_for(lambda: len(received) >= 20, 60, "Humble Imu messages")
        assert bridge.returncode == 0, bridge.stderr.read() if bridge.stderr else ""
        sub.undeclare()
    types = get_typestore(Stores.ROS2_HUMBLE)
    gyro_var, accel_var = GYRO_DENSITY**2 * 100.0, ACCEL_DENSITY**2 * 100.0
    for payload in received:
        m: Any = types.deserialize_cdr(payload, IMU)
        assert m.header.frame_id == "gx3_imu-2"
        assert list(m.angular_velocity_covariance) == [gyro_var, 0, 0, 0, gyro_var, 0, 0, 0,
                                                       gyro_var]
        assert list(m.linear_acceleration_covariance) == [accel_var, 0, 0, 0, accel_var, 0,
                                                          0, 0, accel_var]
        assert list(m.orientation_covariance) == pytest.approx([0.0025, 0, 0, 0, 0.0025, 0,
                                                                0, 0, 0.0025])
        force = [m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z]
        assert np.linalg.norm(force) == pytest.approx(9.80665, abs=0.05)  # still: g alone
