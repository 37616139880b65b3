"""ROS 2 on the wire without a ROS install: DDS topics ``rt/<topic>`` through Cyclone DDS (the DDS under ROS 2's
``rmw_cyclonedds_cpp``).

:mod:`superex_deploy.ros.idl` holds the messages (byte-identical to ROS 2's CDR), :mod:`superex_deploy.ros.qos` the
QoS profiles of the ROS 2 publishers we talk to, and :mod:`superex_deploy.ros.dds` a minimal ROS-2-like participant
(name resolution, publishers and subscriptions that carry the ROS 2 type hash, a wait set, ``ros_discovery_info``).
They need the ``ros2`` extra (``cyclonedds``, ``rosbags``); importing this package imports none of them.
"""
