"""rmw_zenoh's layout on Zenoh: key expressions, liveliness tokens, attachments (no I/O).

Builds exactly the strings and bytes ROS 2's Zenoh middleware (https://github.com/ros2/rmw_zenoh,
``rmw_zenoh_cpp``) uses for topics, discovery and GIDs, so ``ros2 topic list`` sees the daemon.
:func:`distro_hash` gives the type-hash field of a distribution (Humble has none).
"""
# Sources: the design document https://github.com/ros2/rmw_zenoh/blob/rolling/docs/design.md,
# and in rmw_zenoh_cpp/src/detail/: liveliness_utils.{hpp,cpp}, attachment_helpers.cpp,
# rmw_publisher_data.cpp, qos.cpp.
# * data of a topic goes on <domain_id>/<topic name without its leading '/'>/<type>/<hash>,
#   <type> the DDS-style name (geometry_msgs::msg::dds_::WrenchStamped_) and <hash> the RIHS01
#   type hash (RIHS01_<64 hex>); the payload is the CDR message with its encapsulation header;
# * each sample carries an attachment, Zenoh-serialised: the publisher's sequence number (int64,
#   from 1), the source timestamp (int64, ns since the Unix epoch) and the publisher's 16-byte
#   GID (a sequence: its length 16 as a LEB128 varint, then the bytes);
# * discovery is by liveliness tokens @ros2_lv/<domain_id>/<zid>/<node id>/<entity id>/<kind>/
#   <enclave>/<namespace>/<node name> for a node (kind NN, entity id = node id), with
#   /<topic>/<type>/<hash>/<qos> appended for a publisher (kind MP); every / inside a name
#   becomes % (the root enclave / is %, the namespace /tactiled is %tactiled);
# * an entity's GID is the XXH3-128 hash of its liveliness key expression, its low 64 bits then
#   its high 64 bits, little-endian.
# Distributions: Jazzy, Kilted and Rolling lay these out alike.  Humble has no type hashes: its
# rmw_zenoh (the humble branch, from https://github.com/ros2/rmw_zenoh/pull/388 "Updates to
# compile against Humble": "Humble does not support type hashes ... we just remove the code that
# computes it, and instead set it to a constant string") puts TypeHashNotSupported wherever the
# hash goes, in the data key expression and the liveliness token alike; the rest (16-byte GID,
# attachment, QoS string) is the same.

from __future__ import annotations

from dataclasses import dataclass

import xxhash
from zenoh.ext import Int64, z_serialize

ADMIN_SPACE = "@ros2_lv"
NODE, PUBLISHER = "NN", "MP"
#: The QoS of every tactiled publisher in rmw_zenoh's compact form: reliable, volatile,
#: keep-last with depth 10 (rclcpp's default); only what differs from rmw_zenoh's defaults
#: (reliable, volatile, keep-last 42, infinite deadline/lifespan/lease, automatic liveliness)
#: is written, so this is the depth alone.
QOS = "::,10:,:,:,,"
GID_SIZE = 16


#: The hash field of Humble's rmw_zenoh, which has no type hashes.
NO_TYPE_HASH = "TypeHashNotSupported"
DISTROS = ("humble", "jazzy", "kilted", "rolling")


def distro_hash(type_hash: str, distro: str) -> str:
    """The type-hash field of ``distro``'s rmw_zenoh: ``type_hash`` (``RIHS01_...``), or
    :data:`NO_TYPE_HASH` on Humble."""
    if distro not in DISTROS:
        raise ValueError(f"unknown ROS 2 distro {distro!r} (known: {', '.join(DISTROS)})")
    return NO_TYPE_HASH if distro == "humble" else type_hash


def mangle(name: str) -> str:
    """A ROS name as one key expression chunk: every ``/`` becomes ``%``."""
    return name.replace("/", "%")


def dds_type(typename: str) -> str:
    """``pkg/msg/Name`` -> ``pkg::msg::dds_::Name_`` (the type string rmw_zenoh puts in keys)."""
    pkg, kind, name = typename.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def topic_key(domain_id: int, topic: str, typename: str, type_hash: str) -> str:
    """The key expression of a topic's data (``0/tactiled/finger0/wrench/geometry_msgs::msg::
    dds_::WrenchStamped_/RIHS01_...``); ``topic`` fully qualified."""
    return f"{domain_id}/{topic.strip('/')}/{dds_type(typename)}/{type_hash}"


@dataclass(frozen=True)
class NodeInfo:
    """A ROS node as rmw_zenoh announces it: its domain, the Zenoh session's id (as Zenoh
    prints it), its id in that session, namespace, name and enclave."""

    domain_id: int
    zid: str
    node_id: int
    namespace: str
    name: str
    enclave: str = "/"

    def _prefix(self, entity_id: int, kind: str) -> str:
        return (f"{ADMIN_SPACE}/{self.domain_id}/{self.zid}/{self.node_id}/{entity_id}/{kind}/"
                f"{mangle(self.enclave)}/{mangle(self.namespace)}/{mangle(self.name)}")

    def token(self) -> str:
        """The node's liveliness key expression (kind ``NN``)."""
        return self._prefix(self.node_id, NODE)

    def publisher_token(self, entity_id: int, topic: str, typename: str, type_hash: str,
                        qos: str = QOS) -> str:
        """A publisher's liveliness key expression (kind ``MP``); ``topic`` fully qualified."""
        return (f"{self._prefix(entity_id, PUBLISHER)}/{mangle(topic)}/"
                f"{mangle(dds_type(typename))}/{mangle(type_hash)}/{qos}")


def gid(token: str) -> bytes:
    """The 16-byte GID rmw_zenoh derives from an entity's liveliness key expression."""
    return xxhash.xxh3_128_intdigest(token.encode()).to_bytes(GID_SIZE, "little")


def attachment(sequence_number: int, source_timestamp_ns: int, source_gid: bytes) -> bytes:
    """A sample's attachment, serialised by Zenoh's own serializer (``zenoh.ext``)."""
    if len(source_gid) != GID_SIZE:
        raise ValueError(f"a GID has {GID_SIZE} bytes, got {len(source_gid)}")
    return z_serialize((Int64(sequence_number), Int64(source_timestamp_ns),
                        bytes(source_gid))).to_bytes()
