"""QoS profiles that match the ROS 2 publishers and subscribers SuperEx talks to, as Cyclone DDS QoS.

A DDS reader receives from a writer only when their QoS are compatible ("requested / offered"); otherwise the two
never match and **the reader silently gets nothing** (DDS reports it only as an incompatible-QoS status:
``Subscription.incompatible_qos()`` in :mod:`superex_deploy.ros.dds`). The two rules that matter here:

* reliability: a **reliable reader does not match a best-effort writer** (a best-effort reader matches both). LiDAR
  drivers and Gazebo publish ``/scan`` with ``SensorDataQoS`` (best effort), so our scan subscription is
  :data:`SENSOR_DATA` (best effort): it then also receives from a reliable ``/scan`` writer.
* durability: a **transient-local reader does not match a volatile writer** (a volatile reader matches both, but
  then gets no history). slam_toolbox, map_server and Cartographer publish ``/map`` transient local, so :data:`MAP`
  is transient local: a subscriber that starts after the map was published still receives the newest one.

Depth is not part of matching; a writer's depth is how many samples it keeps (for a late transient-local reader, how
many old ones it replays), a reader's how many it queues before dropping the oldest.

Sources (read in their repositories): ``rclcpp/include/rclcpp/qos.hpp`` and ``rclcpp/src/rclcpp/qos.cpp``
(``SensorDataQoS`` = ``rmw_qos_profile_sensor_data``: keep last 5, best effort, volatile; ``ClockQoS`` = the same
profile at depth 1; ``rclcpp::QoS(depth)``: reliable, volatile), ``tf2_ros/include/tf2_ros/qos.hpp``
(``DynamicBroadcasterQoS`` / ``DynamicListenerQoS``: ``QoS(100)``; ``StaticBroadcasterQoS``: ``QoS(1)`` transient
local; ``StaticListenerQoS``: ``QoS(100)`` transient local), slam_toolbox ``src/slam_toolbox_common.cpp``
(``/map``: ``QoS(KeepLast(1)).transient_local().reliable()``), nav2 map_server (the same), cartographer_ros (ROS 2
port) ``occupancy_grid_node_main.cc`` (``QoS(10).transient_local()``), and ``rmw_cyclonedds_cpp``'s
``create_readwrite_qos`` (what each ROS profile becomes in DDS: see :meth:`RosQos.to_dds`).
"""

from dataclasses import dataclass

__all__ = ["RosQos", "SENSOR_DATA", "MAP", "DEFAULT", "TF", "TF_STATIC", "TF_STATIC_LISTENER", "CLOCK",
           "DISCOVERY_INFO", "RELIABILITIES", "DURABILITIES"]

RELIABILITIES = ("reliable", "best_effort")
DURABILITIES = ("volatile", "transient_local")


@dataclass(frozen=True)
class RosQos:
    """A ROS 2 QoS profile: history keep-last ``depth`` (samples), ``reliability``, ``durability``.

    Raises:
        ValueError: a reliability or durability not in :data:`RELIABILITIES` / :data:`DURABILITIES`, or a depth that
            is not an integer in ``1..2**31 - 1``.
    """

    reliability: str
    durability: str
    depth: int

    def __post_init__(self):
        if self.reliability not in RELIABILITIES:
            raise ValueError(f"reliability must be one of {RELIABILITIES}, got {self.reliability!r}")
        if self.durability not in DURABILITIES:
            raise ValueError(f"durability must be one of {DURABILITIES}, got {self.durability!r}")
        if isinstance(self.depth, bool) or not isinstance(self.depth, int) or not 1 <= self.depth < 2 ** 31:
            raise ValueError(f"depth must be an integer in 1..2**31 - 1, got {self.depth!r}")

    def matches(self, writer: "RosQos") -> bool:
        """Whether a reader with this profile receives from a writer with ``writer``'s (the DDS rules above)."""
        return ((self.reliability == "best_effort" or writer.reliability == "reliable")
                and (self.durability == "volatile" or writer.durability == "transient_local"))

    def to_dds(self, user_data: bytes = b""):
        """The cyclonedds ``Qos`` for a reader or writer, as ``rmw_cyclonedds_cpp`` builds it.

        Keep last ``depth``; reliable with an infinite max blocking time, or best effort; volatile, or transient local
        with a durability service keeping the same history (so that a late reader gets the last ``depth`` samples);
        automatic liveliness with an infinite lease; ``autodispose`` off (rmw's ``writer_data_lifecycle(false)``);
        XCDR1 data representation, which ROS 2 readers accept; ``user_data`` in USER_DATA (the type hash).
        """
        from cyclonedds.core import Policy, Qos
        from cyclonedds.util import duration

        history = Policy.History.KeepLast(self.depth)
        policies = [history, Policy.Liveliness.Automatic(lease_duration=duration(infinite=True)),
                    Policy.WriterDataLifecycle(autodispose=False),
                    Policy.DataRepresentation(use_cdrv0_representation=True)]
        if self.reliability == "reliable":
            policies.append(Policy.Reliability.Reliable(max_blocking_time=duration(infinite=True)))
        else:
            policies.append(Policy.Reliability.BestEffort)
        if self.durability == "transient_local":
            policies += [Policy.Durability.TransientLocal,
                         Policy.DurabilityService(cleanup_delay=0, history=history, max_samples=-1,
                                                  max_instances=-1, max_samples_per_instance=-1)]
        else:
            policies.append(Policy.Durability.Volatile)
        if user_data:
            policies.append(Policy.Userdata(data=bytes(user_data)))
        return Qos(*policies)


SENSOR_DATA = RosQos("best_effort", "volatile", 5)
"""``rclcpp::SensorDataQoS`` (``rmw_qos_profile_sensor_data``): LiDAR drivers' and Gazebo's ``/scan``; as a reader it
matches reliable and best-effort writers alike."""

MAP = RosQos("reliable", "transient_local", 1)
"""``/map`` of slam_toolbox and nav2 map_server (``QoS(KeepLast(1)).transient_local().reliable()``) and Cartographer's
occupancy grid node (transient local, depth 10): a late reader still gets the newest map."""

DEFAULT = RosQos("reliable", "volatile", 10)
"""``rclcpp::QoS(10)``, the default of ``create_publisher(topic, 10)``: poses, odometry, goals, paths, markers."""

TF = RosQos("reliable", "volatile", 100)
"""``tf2_ros::DynamicBroadcasterQoS`` / ``DynamicListenerQoS`` (``QoS(100)``): ``/tf``."""

TF_STATIC = RosQos("reliable", "transient_local", 1)
"""``tf2_ros::StaticBroadcasterQoS`` (``QoS(1).transient_local()``): a ``/tf_static`` writer."""

TF_STATIC_LISTENER = RosQos("reliable", "transient_local", 100)
"""``tf2_ros::StaticListenerQoS`` (``QoS(100).transient_local()``): a ``/tf_static`` reader. ``/tf_static`` is one
keyless topic with a writer per static broadcaster, each replaying its last message to a late reader: a reader of
depth 1 could keep only one of them."""

CLOCK = RosQos("best_effort", "volatile", 1)
"""``rclcpp::ClockQoS`` (``rmw_qos_profile_sensor_data`` at depth 1): ``/clock`` of a simulator."""

DISCOVERY_INFO = RosQos("reliable", "transient_local", 1)
"""``ros_discovery_info``, as ``rmw_cyclonedds_cpp`` writes it (``rmw_create_node``: keep last 1, transient local,
reliable)."""
