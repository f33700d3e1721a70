"""Where the bridge listens and publishes: the two key layouts, the type hashes in the
rmw_zenoh keys, the rmw_zenoh attachment and graph tokens."""

from __future__ import annotations

import struct

import pytest

from simpletrack.ros2.layout import (
    Layout,
    attachment,
    graph_tokens,
    parse_attachment,
    publisher_gid,
    topic_keys,
)
from simpletrack.ros2.typehash import dds_type_name, definitions, parse_msg, type_hash
from tests.ros2 import rosmsgs as R


def test_our_type_hashes_equal_rosbags_for_every_definition() -> None:
    store = R.typestore()
    assert len(definitions()) == 22
    for name in definitions():
        assert type_hash(name) == store.hash_rihs01(name), name


def test_the_hash_of_std_msgs_string_is_the_one_rmw_zenoh_documents() -> None:
    # ros2/rmw_zenoh docs/design.md: 0/chatter/std_msgs::msg::dds_::String_/RIHS01_df66...
    import hashlib
    import json

    fields = [f.as_json() for f in parse_msg("string data\n", "std_msgs/msg/String")]
    doc = {
        "type_description": {"type_name": "std_msgs/msg/String", "fields": fields},
        "referenced_type_descriptions": [],
    }
    digest = hashlib.sha256(json.dumps(doc).encode()).hexdigest()
    assert digest == "df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"


def test_ros2dds_keys_are_the_topics_without_the_leading_slash() -> None:
    keys = topic_keys(Layout.ROS2DDS)
    assert keys.in_key == "perception/object_recognition/detection/objects"
    assert keys.out_key == "perception/object_recognition/tracking/objects"
    ns = topic_keys(Layout.ROS2DDS, "/objects", "tracks", namespace="/bot1")
    assert (ns.in_key, ns.out_key) == ("bot1/objects", "bot1/tracks")


def test_rmw_zenoh_keys_carry_domain_type_and_hash() -> None:
    keys = topic_keys(Layout.RMW_ZENOH, "/det", "/trk", domain=3)
    assert keys.in_key == (
        "3/det/autoware_perception_msgs::msg::dds_::DetectedObjects_/"
        + type_hash("autoware_perception_msgs/msg/DetectedObjects")
    )
    assert keys.out_key.startswith("3/trk/autoware_perception_msgs::msg::dds_::TrackedObjects_/")
    assert keys.out_key.endswith(R.typestore().hash_rihs01(R.TRACKED))
    assert dds_type_name("std_msgs/msg/String") == "std_msgs::msg::dds_::String_"


def test_explicit_keys_replace_the_layout_s() -> None:
    keys = topic_keys(Layout.RMW_ZENOH, in_key="robot/in", out_key="robot/out")
    assert (keys.in_key, keys.out_key) == ("robot/in", "robot/out")


@pytest.mark.parametrize("topic", ["", "/", "a b", "a//b", "a/*", "a/**/b"])
def test_bad_topics_are_refused_with_the_value(topic: str) -> None:
    with pytest.raises(ValueError, match="topic"):
        topic_keys(Layout.ROS2DDS, topic)


def test_a_domain_outside_ros_range_is_refused() -> None:
    with pytest.raises(ValueError, match="domain 300"):
        topic_keys(Layout.RMW_ZENOH, domain=300)


def test_the_attachment_is_rmw_zenoh_s_33_bytes() -> None:
    gid = publisher_gid("0/trk/x/y", "bridge-a")
    raw = attachment(5, 1_700_000_000_123_456_789, gid)
    assert len(raw) == 33
    assert struct.unpack_from("<qq", raw) == (5, 1_700_000_000_123_456_789)
    assert raw[16] == 16 and raw[17:] == gid
    assert parse_attachment(raw) == (5, 1_700_000_000_123_456_789, gid)
    assert publisher_gid("0/trk/x/y", "bridge-b") != gid


def test_graph_tokens_name_the_node_and_both_entities() -> None:
    keys = topic_keys(Layout.RMW_ZENOH, "/perception/det", "/perception/trk")
    node, sub, pub = graph_tokens(keys, "aac3178e146ba6f1fc6e6a4085e77f21")
    assert node == "@ros2_lv/0/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/simpletrack_bridge"
    assert sub.split("/")[5:10] == [
        "MS",
        "%",
        "%",
        "simpletrack_bridge",
        "%perception%det",
    ]
    assert pub.split("/")[10:] == [
        "autoware_perception_msgs::msg::dds_::TrackedObjects_",
        type_hash("autoware_perception_msgs/msg/TrackedObjects"),
        "::,10:,:,:,,",
    ]
