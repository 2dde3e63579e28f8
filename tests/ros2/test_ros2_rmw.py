"""rmw_zenoh's layout: key expressions, liveliness tokens and attachments.

Checked against rmw_zenoh's documented layout (ros2/rmw_zenoh: ``liveliness_utils.hpp``'s
comment, and ``Entity::make(keyexpr)`` / ``keyexpr_to_qos`` in ``liveliness_utils.cpp``, whose
parsing rules :func:`parse_token` restates), against zenoh-ros2-sdk's own builders of the same
strings (an independent implementation), and, for the attachment, against Zenoh's
deserializer and the SDK's parser.
"""

from __future__ import annotations

import struct

import xxhash
import zenoh
from zenoh.ext import Int64, z_deserialize
from zenoh_ros2_sdk.entity import EndpointEntity, EntityKind, NodeEntity
from zenoh_ros2_sdk.keyexpr import (endpoint_liveliness_keyexpr, node_liveliness_keyexpr,
                                    topic_keyexpr)

from tactiled_service.ros2 import messages, rmw

ZID = "3bdb143648cbf52442f567f6103229cd"
NODE = rmw.NodeInfo(domain_id=7, zid=ZID, node_id=0, namespace="/tactiled", name="tactiled")


def parse_token(token: str) -> dict[str, object]:
    """A liveliness key expression read the way rmw_zenoh's graph cache reads it: '/'-split
    parts, none empty, admin space ``@ros2_lv``, entity NN/MP/MS/SS/SC, at least 9 parts
    (through the node name), 13 for an entity with a topic, names demangled ('%' -> '/'), and
    the QoS in 6 ':'-separated fields (history ',' depth; deadline, lifespan: 's,ns';
    liveliness 'kind,s,ns'), numbers or empty for the default."""
    parts = token.split("/")
    assert len(parts) >= 9 and all(parts), token
    assert parts[0] == "@ros2_lv"
    entity = parts[5]
    assert entity in ("NN", "MP", "MS", "SS", "SC")
    out: dict[str, object] = {
        "domain_id": int(parts[1]), "zid": parts[2], "nid": parts[3], "id": parts[4],
        "entity": entity, "enclave": parts[6].replace("%", "/"),
        "namespace": parts[7].replace("%", "/"), "node": parts[8].replace("%", "/")}
    if entity == "NN":
        assert len(parts) == 9 and parts[3] == parts[4], "a node's id is its node id"
        return out
    assert len(parts) == 13, token
    qos = parts[12].split(":")
    assert len(qos) == 6
    assert [len(q.split(",")) for q in qos] == [1, 1, 2, 2, 2, 3]
    for field in ",".join(qos).split(","):
        assert field == "" or field.isdigit()
    out.update(topic=parts[9].replace("%", "/"), type=parts[10], type_hash=parts[11],
               qos=parts[12])
    return out


def test_node_token_follows_the_documented_layout() -> None:
    token = NODE.token()
    assert parse_token(token) == {
        "domain_id": 7, "zid": ZID, "nid": "0", "id": "0", "entity": "NN", "enclave": "/",
        "namespace": "/tactiled", "node": "tactiled"}
    sdk = NodeEntity(domain_id=7, session_id=ZID, node_id=0, node_name="tactiled",
                     namespace="/tactiled")
    assert token == node_liveliness_keyexpr(sdk)


def test_publisher_token_and_topic_key_follow_the_documented_layout() -> None:
    typename = messages.TYPES["wrench"]
    type_hash = messages.type_hash(typename)
    topic = messages.topic("/tactiled", "finger0", "wrench")
    token = NODE.publisher_token(3, topic, typename, type_hash)
    parsed = parse_token(token)
    assert parsed["entity"] == "MP" and parsed["id"] == "3" and parsed["nid"] == "0"
    assert parsed["topic"] == "/tactiled/finger0/wrench"
    assert parsed["type"] == "geometry_msgs::msg::dds_::WrenchStamped_"
    assert parsed["type_hash"] == type_hash
    assert parsed["qos"] == "::,10:,:,:,,"  # reliable, volatile, keep last 10
    sdk_node = NodeEntity(domain_id=7, session_id=ZID, node_id=0, node_name="tactiled",
                          namespace="/tactiled")
    sdk_ep = EndpointEntity(node=sdk_node, entity_id=3, kind=EntityKind.PUBLISHER, name=topic,
                            dds_type_name="geometry_msgs::msg::dds_::WrenchStamped_",
                            type_hash=type_hash, qos=rmw.QOS)
    assert token == endpoint_liveliness_keyexpr(sdk_ep)
    key = rmw.topic_key(7, topic, typename, type_hash)
    assert key == f"7/tactiled/finger0/wrench/geometry_msgs::msg::dds_::WrenchStamped_/{type_hash}"
    assert key == topic_keyexpr(7, topic, "geometry_msgs::msg::dds_::WrenchStamped_", type_hash)
    zenoh.KeyExpr(key)  # a valid key expression
    zenoh.KeyExpr(token)


def test_gid_is_xxh3_128_of_the_token_low_half_first() -> None:
    token = NODE.publisher_token(1, "/tactiled/finger0/contact", messages.CONTACT_TYPE, "RIHS01_0")
    digest = xxhash.xxh3_128(token.encode()).digest()  # big-endian: high 64 bits first
    high, low = struct.unpack(">QQ", digest)
    assert rmw.gid(token) == struct.pack("<QQ", low, high)


def test_attachment_is_zenoh_serialised_seq_timestamp_gid() -> None:
    gid = bytes(range(100, 116))
    data = rmw.attachment(42, 1_795_309_645_250_000_123, gid)
    assert z_deserialize(tuple[Int64, Int64, bytes], zenoh.ZBytes(data)) == (
        42, 1_795_309_645_250_000_123, gid)
    # The SDK's own reading of rmw_zenoh attachments: u64, u64, u8 length, the GID.
    seq, stamp, n = struct.unpack_from("<QQB", data)
    assert (seq, stamp, n, data[17:]) == (42, 1_795_309_645_250_000_123, 16, gid)
    assert len(data) == 33


def test_humble_has_no_type_hash_in_keys_nor_tokens() -> None:
    """Humble's rmw_zenoh writes ``TypeHashNotSupported`` where the hash goes (ros2/rmw_zenoh
    pull request 388); Jazzy, Kilted and Rolling the RIHS01 hash."""
    typename = "geometry_msgs/msg/WrenchStamped"
    real = messages.type_hash(typename)
    for distro in ("jazzy", "kilted", "rolling"):
        assert rmw.distro_hash(real, distro) == real
    humble = rmw.distro_hash(real, "humble")
    assert humble == "TypeHashNotSupported"
    assert rmw.topic_key(0, "/tactiled/finger0/wrench", typename, humble) == (
        "0/tactiled/finger0/wrench/geometry_msgs::msg::dds_::WrenchStamped_/"
        "TypeHashNotSupported")
    token = parse_token(NODE.publisher_token(1, "/tactiled/finger0/wrench", typename, humble))
    assert (token["type"], token["type_hash"]) == (
        "geometry_msgs::msg::dds_::WrenchStamped_", "TypeHashNotSupported")
    from tactiled_service.ros2.reader import parse_key
    assert parse_key(rmw.topic_key(0, "/tactiled/finger0/wrench", typename, humble)) == (
        "/tactiled/finger0/wrench", typename, "TypeHashNotSupported")
    import pytest
    with pytest.raises(ValueError, match="unknown ROS 2 distro"):
        rmw.distro_hash(real, "iron")
