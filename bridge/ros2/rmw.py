"""ROS 2 on Zenoh as ``rmw_zenoh_cpp`` speaks it, so ROS 2 nodes see the bridge's topics.

Followed: ``docs/design.md`` of ros2/rmw_zenoh at commit
99a6a2bd10b949052f4f12c5854825dc005e95a5 (key expressions, liveliness tokens, the
attachment), with ``liveliness_utils.cpp`` (token layout, ``%`` mangling,
``qos_to_keyexpr``), ``qos.cpp`` (the defaults a QoS is written against) and
``rmw_publisher_data.cpp`` (sequence numbers from 1, DROP congestion control for a
KEEP_LAST publisher, no encoding) of the same tree.

- data: ``<domain>/<topic without leading '/'>/<dds type>/<RIHS01 hash>``, a CDR
  payload, and a 33-byte attachment: int64 LE sequence number, int64 LE source
  timestamp (ns since the epoch, at publication), one byte 16, the 16-byte GID;
- graph: a liveliness token for the node
  ``@ros2_lv/<domain>/<zid>/<nid>/<nid>/NN/<enclave>/<namespace>/<node>`` and one per
  publisher ``@ros2_lv/<domain>/<zid>/<nid>/<eid>/MP/<enclave>/<namespace>/<node>/
  <topic>/<dds type>/<hash>/<qos>``, names mangled ('/' -> '%');
- a publisher's GID is the XXH3-128 of its token (low 64 bits, then high, little-endian),
  which is what every rmw_zenoh node computes for it from the token.

Humble: ``docs/design.md`` of rmw_zenoh's humble branch (release 0.1.9, upstream commit
d60045d71ca16efcc7b98ac9bd076426b9e8340e of ros2-gbp/rmw_zenoh-release) gives the same
keys and tokens with the constant ``TypeHashNotSupported`` where the hash goes (Humble's
type support has no type hash; ``rmw_publisher_data.cpp`` "leave[s] it in place as a
constant"); the attachment, the GID, the QoS chunk and its defaults are the same code.
A Humble subscriber's key never matches a Jazzy publisher's, so the distribution is
chosen per node.
"""

from __future__ import annotations

import functools
import logging
import struct
import threading
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
import zenoh

from bridge.bus.codec import RecordBatch, record_quantities
from bridge.device import clock
from bridge.ros2.messages import (
    ATTITUDE,
    DEFAULT_DISTRO,
    IMU,
    MAGNETIC_FIELD,
    MAGNETOMETER,
    check_distro,
    frame_id,
    has_mag,
    imu_cdr_batch,
    mag_cdr_batch,
    ros_token,
    ros_topic,
    type_hash,
)
from bridge.ros2.noise import ImuCovariance, ImuNoise, imu_covariance
from bridge.ros2.xxh3 import xxh3_128_bytes

_log = logging.getLogger(__name__)
ADMIN_SPACE = "@ros2_lv"
#: What Humble's rmw_zenoh writes where Jazzy's writes the RIHS01 type hash.
HUMBLE_TYPE_HASH = "TypeHashNotSupported"
MAX_DOMAIN = 232  # the highest ROS_DOMAIN_ID ROS 2 documents
GID_SIZE = 16
_ATTACHMENT = struct.Struct(f"<qqB{GID_SIZE}s")

# rmw_qos_profile_t enum values (rmw/types.h)
RELIABLE, BEST_EFFORT = 1, 2
TRANSIENT_LOCAL, VOLATILE = 1, 2
KEEP_LAST, KEEP_ALL = 1, 2
AUTOMATIC = 1


@dataclass(frozen=True)
class Qos:
    """The QoS a token announces; the deadline, lifespan and lease stay infinite.

    Attributes:
        reliability: ``RELIABLE`` or ``BEST_EFFORT``.
        durability: ``TRANSIENT_LOCAL`` or ``VOLATILE``.
        history: ``KEEP_LAST`` or ``KEEP_ALL``.
        depth: Messages kept, with ``KEEP_LAST``.
        liveliness: ``AUTOMATIC``.
    """

    reliability: int = RELIABLE
    durability: int = VOLATILE
    history: int = KEEP_LAST
    depth: int = 10
    liveliness: int = AUTOMATIC


#: rmw_zenoh's defaults (qos.cpp): a token spells only what differs from them.
DEFAULT_QOS = Qos(depth=42)
#: What the bridge's publishers announce: ROS 2's default profile (reliable, volatile,
#: keep last 10), which ``ros2 topic echo`` and most subscriptions match.
SENSOR_QOS = Qos()


def qos_keyexpr(qos: Qos) -> str:
    """rmw_zenoh's compact QoS chunk, e.g. ``::,10:,:,:,,`` for keep last 10."""
    def differs(value: int, default: int) -> str:
        return "" if value == default else str(value)

    d = DEFAULT_QOS
    return (f"{differs(qos.reliability, d.reliability)}:{differs(qos.durability, d.durability)}:"
            f"{differs(qos.history, d.history)},{differs(qos.depth, d.depth)}:,:,:"
            f"{differs(qos.liveliness, d.liveliness)},,")


def _mangle(name: str) -> str:
    """A ROS name as one key chunk: each '/' becomes '%' (so '/' alone is '%')."""
    return name.replace("/", "%")


def dds_type(msgtype: str) -> str:
    """The type name in keys and tokens, as CDR names it in DDS.

    ``sensor_msgs/msg/Imu`` -> ``sensor_msgs::msg::dds_::Imu_``.
    """
    package, kind, name = msgtype.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def key_type_hash(msgtype: str, distro: str = DEFAULT_DISTRO) -> str:
    """The type hash chunk of a topic's key and tokens, as the distribution's rmw_zenoh writes it.

    Args:
        msgtype: The message type, e.g. ``sensor_msgs/msg/Imu``.
        distro: ``jazzy`` (its RIHS01 hash) or ``humble`` (``TypeHashNotSupported``).

    Returns:
        The chunk.

    Raises:
        ValueError: Another distribution.
    """
    return HUMBLE_TYPE_HASH if check_distro(distro) == "humble" else type_hash(msgtype)


def topic_key(domain: int, topic: str, type_name: str, type_hash: str) -> str:
    """The key a topic's samples travel on.

    E.g. ``0/chatter/std_msgs::msg::dds_::String_/RIHS01_df66…``.
    """
    return f"{domain}/{topic.strip('/')}/{type_name}/{type_hash}"


@dataclass(frozen=True)
class NodeName:
    """Where a node sits in the ROS graph."""

    domain: int
    zid: str
    node_id: int
    name: str
    namespace: str = "/"
    enclave: str = "/"

    def _head(self, entity_id: int, kind: str) -> str:
        return (f"{ADMIN_SPACE}/{self.domain}/{self.zid}/{self.node_id}/{entity_id}/{kind}/"
                f"{_mangle(self.enclave)}/{_mangle(self.namespace)}/{self.name}")

    def node_token(self) -> str:
        """The node's liveliness token."""
        return self._head(self.node_id, "NN")

    def publisher_token(self, entity_id: int, topic: str, type_name: str, type_hash: str,
                        qos: Qos) -> str:
        """The liveliness token of one of the node's publishers."""
        return (f"{self._head(entity_id, 'MP')}/{_mangle(topic)}/{type_name}/{type_hash}/"
                f"{qos_keyexpr(qos)}")


def gid(token: str) -> bytes:
    """An entity's 16-byte GID, from its liveliness token as rmw_zenoh makes it."""
    return xxh3_128_bytes(token.encode())


def attachment(sequence: int, source_ns: int, source_gid: bytes) -> bytes:
    """The 33 bytes that go with every put: what ROS 2's message info reports."""
    return _ATTACHMENT.pack(sequence, source_ns, GID_SIZE, source_gid)


def parse_attachment(data: bytes) -> tuple[int, int, bytes]:
    """``(sequence, source_ns, gid)`` of an attachment; ValueError if it is not one."""
    if len(data) != _ATTACHMENT.size:
        raise ValueError(f"an rmw_zenoh attachment has {_ATTACHMENT.size} bytes, not {len(data)}")
    sequence, source_ns, size, source_gid = _ATTACHMENT.unpack(data)
    if size != GID_SIZE:
        raise ValueError(f"an rmw_zenoh attachment's GID has {GID_SIZE} bytes, not {size}")
    return sequence, source_ns, source_gid


class Ros2Publisher:
    """One topic: a Zenoh publisher on its key and its liveliness token.

    Args:
        session: The Zenoh session.
        node: The node it belongs to.
        entity_id: Its id in the node (from 1).
        topic: The ROS topic, e.g. ``/gx3/imu1/imu``.
        type_name: The DDS type name (``dds_type``).
        type_hash: The RIHS01 type hash.
        qos: What its token announces; a reliable keep-all publisher blocks when
            congested, any other drops.
    """

    def __init__(self, session: zenoh.Session, node: NodeName, entity_id: int, topic: str,
                 type_name: str, type_hash: str, qos: Qos) -> None:
        self.topic = topic
        self.key = topic_key(node.domain, topic, type_name, type_hash)
        self.token_key = node.publisher_token(entity_id, topic, type_name, type_hash, qos)
        self.gid = gid(self.token_key)
        self.sequence = 0  # the last one sent; rmw_zenoh's first is 1
        block = qos.reliability == RELIABLE and qos.history == KEEP_ALL
        self._pub = session.declare_publisher(
            self.key, congestion_control=zenoh.CongestionControl.BLOCK if block
            else zenoh.CongestionControl.DROP,
            reliability=zenoh.Reliability.RELIABLE if qos.reliability == RELIABLE
            else zenoh.Reliability.BEST_EFFORT)
        try:
            self._token = session.liveliness().declare_token(self.token_key)
        except BaseException:
            self._pub.undeclare()
            raise

    @property
    def matched(self) -> bool:
        """Whether a subscriber (a ROS 2 node, ``ros2 topic echo``) listens now."""
        status: Any = self._pub.matching_status  # the stub says bool; it is a MatchingStatus
        return bool(status.matching)

    def put_all(self, payloads: Iterable[bytes]) -> None:
        """Publish CDR messages, each with the next sequence number.

        The source timestamp is the publication time, as rmw_zenoh's.

        Args:
            payloads: The messages, CDR with encapsulation header.
        """
        put, source_gid = self._pub.put, self.gid
        sequence, now = self.sequence, clock.realtime_ns()
        for payload in payloads:
            sequence += 1
            put(payload, attachment=attachment(sequence, now, source_gid))
        self.sequence = sequence

    def close(self) -> None:
        """The token goes first, as rmw_zenoh undeclares it."""
        self._token.undeclare()
        self._pub.undeclare()


class Ros2Node:
    """A ROS 2 node on a Zenoh session: its token, and publishers declared on it.

    Args:
        session: The Zenoh session.
        domain: The ROS domain id (``ROS_DOMAIN_ID``).
        name: The node's name.
        namespace: The node's namespace.
        distro: The ROS 2 distribution whose rmw_zenoh its subscribers run: ``jazzy``
            or ``humble`` (whose keys carry no type hash).

    Raises:
        ValueError: The domain is outside 0 to ``MAX_DOMAIN``, or the distribution is
            not one of ``DISTROS``.
    """

    def __init__(self, session: zenoh.Session, domain: int, name: str,
                 namespace: str = "/", distro: str = DEFAULT_DISTRO) -> None:
        if not 0 <= domain <= MAX_DOMAIN:
            raise ValueError(f"ROS domain {domain}: use 0 to {MAX_DOMAIN}")
        self.distro = check_distro(distro)
        self.session = session
        self.name = NodeName(domain, str(session.info.zid()), 0, name, namespace)
        self._token: Any = session.liveliness().declare_token(self.name.node_token())
        self._publishers: list[Ros2Publisher] = []
        self._lock = threading.Lock()

    def publisher(self, topic: str, msgtype: str, qos: Qos = SENSOR_QOS) -> Ros2Publisher:
        """Declare a publisher on the node.

        Args:
            topic: The ROS topic, e.g. ``/gx3/imu1/imu``.
            msgtype: Its message type, e.g. ``sensor_msgs/msg/Imu``.
            qos: What it announces.

        Returns:
            The publisher; the node closes it.
        """
        with self._lock:
            pub = Ros2Publisher(self.session, self.name, len(self._publishers) + 1, topic,
                                dds_type(msgtype), key_type_hash(msgtype, self.distro), qos)
            self._publishers.append(pub)
        return pub

    def close(self) -> None:
        """Undeclare the publishers, then the node; safe to call twice."""
        with self._lock:
            publishers, self._publishers = self._publishers, []
            token, self._token = self._token, None
        for pub in publishers:
            pub.close()
        if token is not None:
            token.undeclare()


class UnitTopics:
    """One unit on ROS 2: a node publishing its samples as ``sensor_msgs`` messages.

    The node ``<prefix>_bridge_<unit>`` publishes ``sensor_msgs/Imu`` on
    ``/<prefix>/<unit>/imu`` and, for records with a magnetometer,
    ``sensor_msgs/MagneticField`` on ``/<prefix>/<unit>/mag``, in the frame the archive's
    ROS 2 export uses. With the unit's measured noise, each Imu carries the covariances
    it gives at the unit's output rate and filter width (``use_settings``, at each
    bring-up); with an orientation standard deviation, those that carry an orientation
    its variance.

    Args:
        session: The Zenoh session.
        domain: The ROS domain id.
        prefix: The key prefix (``gx3``).
        unit: The unit's name.
        distro: The ROS 2 distribution of the subscribers (``jazzy``, ``humble``).
        noise: The unit's measured noise; None: angular velocity and linear
            acceleration covariances 0 (unknown).
        orientation_stddev: The orientation's standard deviation about each axis, rad;
            None: its covariance 0 (unknown).

    Raises:
        ValueError: The domain is outside 0 to ``MAX_DOMAIN``, or the distribution is
            not one of ``DISTROS``.
    """

    def __init__(self, session: zenoh.Session, domain: int, prefix: str, unit: str,
                 distro: str = DEFAULT_DISTRO, noise: ImuNoise | None = None,
                 orientation_stddev: float | None = None) -> None:
        self.frame = frame_id(unit, prefix)
        self.noise = noise
        self.orientation_stddev = orientation_stddev
        self.covariance: ImuCovariance | None = None
        self.node = Ros2Node(session, domain,
                             f"{ros_token(prefix)}_bridge_{ros_token(unit)}", distro=distro)
        try:
            self.imu = self.node.publisher(ros_topic(prefix, unit, "imu"), IMU)
            self.mag = self.node.publisher(ros_topic(prefix, unit, "mag"), MAGNETIC_FIELD)
        except BaseException:
            self.node.close()
            raise

    def use_settings(self, rate_hz: float, filter_width: int) -> None:
        """Give the Imu messages their covariances at the unit's rate and filter width.

        Args:
            rate_hz: The unit's output rate (1000 Hz / decimation), as brought up.
            filter_width: Its filter width M, as brought up.

        Raises:
            ValueError: The rate or the width is not a positive number.
        """
        if self.noise is None and self.orientation_stddev is None:
            return
        self.covariance = imu_covariance(self.noise, rate_hz, filter_width,
                                         self.orientation_stddev)
        if self.noise is not None and abs(rate_hz - self.noise.update_rate_hz) > 1e-6 * rate_hz:
            _log.info("%s: the Imu covariances use the unit's output rate, %g Hz, and filter "
                      "width, %d, not %s's update_rate, %g Hz", self.frame, rate_hz,
                      filter_width, self.noise.path.name, self.noise.update_rate_hz)

    def publish(self, batch: RecordBatch, time_ns: np.ndarray) -> None:
        """Publish the records of a batch.

        Args:
            batch: The records.
            time_ns: Their instants, host ns: each message's stamp.
        """
        names, imu, mag = _contents(batch.code)
        columns = {name: batch[name] for name in names}
        if imu:  # every record: a NaN quantity is told by its covariance (-1)
            self.imu.put_all(imu_cdr_batch(time_ns, self.frame, columns, self.covariance))
        if mag:
            rows = has_mag(columns, len(time_ns))
            if rows.all():
                self.mag.put_all(mag_cdr_batch(time_ns, self.frame, columns))
            elif rows.any():
                self.mag.put_all(mag_cdr_batch(time_ns[rows], self.frame,
                                               {k: v[rows] for k, v in columns.items()}))

    def close(self) -> None:
        """Undeclare the node and its publishers."""
        self.node.close()


@functools.cache
def _contents(code: int) -> tuple[tuple[str, ...], bool, bool]:
    """A record's quantities, and whether it makes an Imu and a MagneticField message."""
    names = record_quantities(code)
    return (names, not {*ATTITUDE, "ang_rate", "accel"}.isdisjoint(names),
            not set(MAGNETOMETER).isdisjoint(names))
