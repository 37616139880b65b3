"""What makes a DDS endpoint a ROS 2 one beyond its topic and QoS: the type hash every reader and writer carries
(:func:`type_hash`) and the ROS graph's discovery messages (:class:`ParticipantEntitiesInfo` on
:data:`DISCOVERY_TOPIC`), which :class:`~superex_deploy.ros.dds.RosParticipant` puts on the wire.

* **type hash**: every reader and writer carries ``typehash=RIHS01_<64 hex>;`` in its USER_DATA QoS, exactly as
  ``rmw_cyclonedds_cpp``'s ``create_readwrite_qos`` puts it there (``rmw_dds_common::
  encode_type_hash_for_user_data_qos``: ``"typehash=" + rosidl_stringify_type_hash(hash) + ";"``, read back by
  ``parse_type_hash_from_user_data`` as the key-value pair ``typehash``). The hash is rosbags'
  ``Typestore.hash_rihs01`` over the Jazzy store with the ``superex_msgs`` types registered (equal to ROS 2's: the
  published hashes of ``std_msgs/msg/String`` and ``sensor_msgs/msg/LaserScan`` match).
* **the ROS graph**: ``ros2 node list`` shows nodes from the ``ros_discovery_info`` topic (no ``rt/`` prefix: rmw
  creates it with ``avoid_ros_namespace_conventions``), type ``rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_``,
  reliable, transient local, keep last 1. A participant publishes there its GUID and one node (name, namespace, the
  GUIDs of its readers and writers) after every change. The ``Gid`` is ``char[16]`` since Iron (``rmw_dds_common``
  "Change Gid.msg to be 16 bytes"), ``char[24]`` in Humble: this targets Iron and later; a Humble graph does not parse
  it. The type hash of ParticipantEntitiesInfo is computed with ``char`` as ``uint8``, as ``rosidl_adapter`` converts
  it (rosbags' own store hashes it as a char and would differ).
"""

import threading
from dataclasses import field

from cyclonedds.idl import types

from superex_deploy.ros.idl import (EXPLORER_STATUS_MSG, MESSAGE_TYPES, SPAD_FRAME_MSG, RosMessage, ros_message,
                                    ros_name)

__all__ = ["type_hash", "Gid", "NodeEntitiesInfo", "ParticipantEntitiesInfo", "DISCOVERY_TOPIC"]

DISCOVERY_TOPIC = "ros_discovery_info"


@ros_message
class Gid(RosMessage, typename="rmw_dds_common::msg::dds_::Gid_"):
    data: types.array[types.uint8, 16] = field(default_factory=lambda: bytes(16))  # a DDS GUID (Iron and later)


@ros_message
class NodeEntitiesInfo(RosMessage, typename="rmw_dds_common::msg::dds_::NodeEntitiesInfo_"):
    node_namespace: types.bounded_str[256] = ""
    node_name: types.bounded_str[256] = ""
    reader_gid_seq: types.sequence[Gid] = field(default_factory=list)
    writer_gid_seq: types.sequence[Gid] = field(default_factory=list)


@ros_message
class ParticipantEntitiesInfo(RosMessage, typename="rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_"):
    gid: Gid = field(default_factory=Gid)
    node_entities_info_seq: types.sequence[NodeEntitiesInfo] = field(default_factory=list)


_DISCOVERY_MSGS = {"rmw_dds_common/msg/Gid": "uint8[16] data",  # char[16] in the .msg; rosidl_adapter: uint8
                   "rmw_dds_common/msg/NodeEntitiesInfo": "string<=256 node_namespace\nstring<=256 node_name\n"
                                                          "Gid[] reader_gid_seq\nGid[] writer_gid_seq\n",
                   "rmw_dds_common/msg/ParticipantEntitiesInfo": "Gid gid\nNodeEntitiesInfo[] node_entities_info_seq\n"}
_HASHES: dict = {}
_HASH_LOCK = threading.Lock()


def type_hash(msg_type) -> str:
    """The ROS 2 type hash ``RIHS01_<64 hex>`` of a message class (of :data:`MESSAGE_TYPES` or the discovery types).

    Raises:
        ValueError: not a message class of this package.
    """
    name = ros_name(msg_type)
    with _HASH_LOCK:
        if not _HASHES:
            from rosbags.typesys import Stores, get_types_from_msg, get_typestore
            store = get_typestore(Stores.ROS2_JAZZY)
            store.register(get_types_from_msg(SPAD_FRAME_MSG, "superex_msgs/msg/SpadFrame"))
            store.register(get_types_from_msg(EXPLORER_STATUS_MSG, "superex_msgs/msg/ExplorerStatus"))
            discovery = get_typestore(Stores.EMPTY)
            for ros, text in _DISCOVERY_MSGS.items():
                discovery.register(get_types_from_msg(text, ros))
            _HASHES.update({ros: store.hash_rihs01(ros) for ros in MESSAGE_TYPES})
            _HASHES.update({ros: discovery.hash_rihs01(ros) for ros in _DISCOVERY_MSGS})
    if name not in _HASHES or msg_type not in (*MESSAGE_TYPES.values(), Gid, NodeEntitiesInfo,
                                               ParticipantEntitiesInfo):
        raise ValueError(f"not a message class of this package: {msg_type!r}")
    return _HASHES[name]
