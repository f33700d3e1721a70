"""Where ROS 2 topics appear on Zenoh, for the two ways of getting them there.

ros2dds   zenoh-bridge-ros2dds (eclipse-zenoh/zenoh-plugin-ros2dds, ``ros2_name_to_key_expr``):
          topic ``/ns/topic`` is key ``ns/topic``; a bridge configured with ``namespace: /bot1``
          puts it on ``bot1/ns/topic``. The payload is the DDS sample: CDR with its
          4-byte encapsulation header. No attachment.
rmw_zenoh ROS 2 nodes on rmw_zenoh_cpp (ros2/rmw_zenoh docs/design.md): key
          ``<domain_id>/<topic without its slashes at the ends>/<DDS type name>/<type hash>``,
          e.g. ``0/perception/object_recognition/tracking/objects/
          autoware_perception_msgs::msg::dds_::TrackedObjects_/RIHS01_3559...``. The payload
          is CDR as above; every sample carries a 33-byte attachment (``attachment``), without
          which an rmw_zenoh subscription drops it. Publishers and subscriptions also declare
          liveliness tokens under ``@ros2_lv`` so that they show in the ROS graph
          (``graph_tokens``); data flows without them.

A fused vehicle's bridge (``fused_keys``) has one input key per sensor, built from each
input's topic the same way, and one output key.
"""

from __future__ import annotations

import hashlib
import re
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum

from simpletrack.ros2.messages import DETECTED_OBJECTS, TRACKED_OBJECTS
from simpletrack.ros2.typehash import dds_type_name, type_hash

DEFAULT_TOPIC = "/perception/object_recognition/detection/objects"
DEFAULT_OUT_TOPIC = "/perception/object_recognition/tracking/objects"
GID_SIZE = 16
# rmw's default profile (reliable, volatile, keep last) but a depth of 10, in rmw_zenoh's
# qos_to_keyexpr form: empty components are the defaults.
QOS_DEPTH_10 = "::,10:,:,:,,"
NODE_NAME = "simpletrack_bridge"

_TOPIC = re.compile(r"^/?[A-Za-z_~{][A-Za-z0-9_/{}~]*$")


class Layout(StrEnum):
    ROS2DDS = "ros2dds"
    RMW_ZENOH = "rmw_zenoh"


def check_topic(topic: str) -> str:
    """A ROS 2 topic name usable in a key: letters, digits, '_' and '/' separators."""
    if not _TOPIC.fullmatch(topic) or "//" in topic or topic.strip("/") == "":
        raise ValueError(
            f"topic {topic!r} must be a ROS 2 name such as /perception/object_recognition/"
            "detection/objects (letters, digits, '_', '/' separators)"
        )
    return topic


def check_namespace(namespace: str) -> str:
    if namespace not in ("", "/"):
        check_topic(namespace)
    return namespace


def ros2dds_key(topic: str, namespace: str = "") -> str:
    """The key zenoh-bridge-ros2dds routes ``topic`` to (bridge ``namespace`` optional)."""
    parts = [p.strip("/") for p in (namespace, topic) if p.strip("/")]
    return "/".join(parts)


def rmw_zenoh_key(topic: str, type_name: str, domain: int = 0) -> str:
    return f"{domain}/{topic.strip('/')}/{dds_type_name(type_name)}/{type_hash(type_name)}"


@dataclass(frozen=True, slots=True)
class TopicKeys:
    """The bridge's input (DetectedObjects) and output (TrackedObjects) keys."""

    layout: Layout
    in_key: str
    out_key: str
    in_topic: str
    out_topic: str
    domain: int = 0


def _layout_key(layout: Layout, full: str, type_name: str, domain: int) -> str:
    return full if layout is Layout.ROS2DDS else rmw_zenoh_key(full, type_name, domain)


def _check_domain(domain: int) -> None:
    if not 0 <= domain <= 232:  # the DDS domain ids ROS 2 can use
        raise ValueError(f"domain {domain} must be a ROS_DOMAIN_ID between 0 and 232")


def topic_keys(
    layout: Layout,
    topic: str = DEFAULT_TOPIC,
    out_topic: str = DEFAULT_OUT_TOPIC,
    *,
    domain: int = 0,
    namespace: str = "",
    in_key: str | None = None,
    out_key: str | None = None,
) -> TopicKeys:
    """Default keys of the layout from the topics; ``in_key``/``out_key`` replace them."""
    check_topic(topic)
    check_topic(out_topic)
    check_namespace(namespace)
    _check_domain(domain)
    full_in = ros2dds_key(topic, namespace)
    full_out = ros2dds_key(out_topic, namespace)
    return TopicKeys(
        layout,
        in_key or _layout_key(layout, full_in, DETECTED_OBJECTS, domain),
        out_key or _layout_key(layout, full_out, TRACKED_OBJECTS, domain),
        "/" + full_in,
        "/" + full_out,
        domain,
    )


@dataclass(frozen=True, slots=True)
class InputKey:
    """One sensor's DetectedObjects input of a fused vehicle's bridge."""

    sensor: str
    topic: str  # the full ROS name, namespace included
    key: str


@dataclass(frozen=True, slots=True)
class FusedKeys:
    """A fused vehicle's bridge: one input per sensor, one TrackedObjects output."""

    layout: Layout
    inputs: tuple[InputKey, ...]
    out_key: str
    out_topic: str
    domain: int = 0


def fused_keys(
    layout: Layout,
    inputs: Sequence[tuple[str, str]],
    out_topic: str = DEFAULT_OUT_TOPIC,
    *,
    domain: int = 0,
    namespace: str = "",
    out_key: str | None = None,
) -> FusedKeys:
    """Keys of (sensor, topic) inputs and the output topic, as ``topic_keys`` builds them.
    Each sensor and each topic once; no input on the output topic."""
    if not inputs:
        raise ValueError("a fused vehicle's bridge needs at least one input")
    check_topic(out_topic)
    check_namespace(namespace)
    _check_domain(domain)
    full_out = ros2dds_key(out_topic, namespace)
    built: list[InputKey] = []
    for sensor, topic in inputs:
        check_topic(topic)
        full = ros2dds_key(topic, namespace)
        for other in built:
            if other.sensor == sensor:
                raise ValueError(f"sensor {sensor!r} is given two inputs")
            if other.topic == "/" + full:
                raise ValueError(
                    f"sensors {other.sensor!r} and {sensor!r} are both on topic /{full}: each "
                    "message would be published twice"
                )
        if full == full_out:
            raise ValueError(f"input {sensor!r} is on the output topic /{full}")
        built.append(
            InputKey(sensor, "/" + full, _layout_key(layout, full, DETECTED_OBJECTS, domain))
        )
    return FusedKeys(
        layout,
        tuple(built),
        out_key or _layout_key(layout, full_out, TRACKED_OBJECTS, domain),
        "/" + full_out,
        domain,
    )


def publisher_gid(out_key: str, instance: str) -> bytes:
    """A stable 16-byte publisher GID for the attachment (rmw_zenoh hashes its liveliness
    token into one; any 16 bytes unique to the publisher will do)."""
    return hashlib.blake2b(f"{instance}|{out_key}".encode(), digest_size=GID_SIZE).digest()


def attachment(sequence_number: int, source_timestamp_ns: int, gid: bytes) -> bytes:
    """rmw_zenoh's sample attachment: int64 LE sequence number (from 1), int64 LE source
    timestamp (ns since the epoch), the GID length (one byte, 16) and the 16 GID bytes."""
    if len(gid) != GID_SIZE:
        raise ValueError(f"gid has {len(gid)} bytes, rmw_zenoh's have 16")
    return struct.pack("<qqB", sequence_number, source_timestamp_ns, GID_SIZE) + gid


def parse_attachment(raw: bytes) -> tuple[int, int, bytes]:
    """(sequence number, source timestamp ns, gid) of an rmw_zenoh attachment."""
    if len(raw) != 17 + GID_SIZE or raw[16] != GID_SIZE:
        raise ValueError(f"an rmw_zenoh attachment has 33 bytes, this one {len(raw)}")
    seq, stamp = struct.unpack_from("<qq", raw)
    return int(seq), int(stamp), raw[17:]


def _mangle(name: str) -> str:
    return name.replace("/", "%") or "%"


def graph_tokens(keys: TopicKeys | FusedKeys, zid: str, node: str = NODE_NAME) -> list[str]:
    """rmw_zenoh liveliness tokens of the bridge as a ROS node with a subscription to each
    input topic and a publisher on the output topic (design.md, "Graph Cache"): the node,
    the subscriptions (entity ids from 1), then the publisher."""
    head = f"@ros2_lv/{keys.domain}/{zid}/0"
    tail = f"%/%/{node}"
    node_token = f"{head}/0/NN/{tail}"

    def entity(eid: int, kind: str, topic: str, type_name: str) -> str:
        return (
            f"{head}/{eid}/{kind}/{tail}/{_mangle(topic)}/{dds_type_name(type_name)}/"
            f"{type_hash(type_name)}/{QOS_DEPTH_10}"
        )

    topics = [keys.in_topic] if isinstance(keys, TopicKeys) else [i.topic for i in keys.inputs]
    subscriptions = [
        entity(eid, "MS", topic, DETECTED_OBJECTS) for eid, topic in enumerate(topics, 1)
    ]
    publisher = entity(len(topics) + 1, "MP", keys.out_topic, TRACKED_OBJECTS)
    return [node_token, *subscriptions, publisher]
