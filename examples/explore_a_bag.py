"""A robot's recording, open-loop: write a small ROS 2 bag of a simulated drive, then run ``superex offline`` on it.

A simulated robot (``superex_deploy.sim.World``) drives through two rooms joined by a door; its LiDAR scans
(``/scan``, frame ``laser``) and its pose (``/tf``: ``map -> odom -> base_link``; ``/tf_static``: ``base_link ->
laser``) are written with ``rosbags``, as a robot's ``ros2 bag record`` would hold them. ``superex offline`` (called
through ``superex_deploy.cli.main``, as the ``superex`` command does) reads the bag back, feeds the scans to the
explorer and writes ``commands.csv``, ``map.npz`` / ``map.png`` and ``summary.json``. Needs the ``bag`` extra.

    python examples/explore_a_bag.py --scans 30 [--out runs/bag_example]
"""

import argparse
import json
import math
import tempfile
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Writer
from rosbags.typesys import Stores, get_typestore

from superex_deploy.cli import main as superex
from superex_deploy.maps import OccupancyGrid
from superex_deploy.sim import World, WorldConfig

TYPES = get_typestore(Stores.ROS2_HUMBLE)
T = TYPES.types
KINDS = {"/scan": "sensor_msgs/msg/LaserScan", "/tf": "tf2_msgs/msg/TFMessage", "/tf_static": "tf2_msgs/msg/TFMessage"}


def header(ns: int, frame: str):
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9),
                                    frame_id=frame)


def tf(ns: int, parent: str, child: str, x: float, y: float, yaw: float):
    """A ``geometry_msgs/TransformStamped``: ``child``'s planar pose in ``parent``."""
    translation = T["geometry_msgs/msg/Vector3"](x=float(x), y=float(y), z=0.0)
    rotation = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))
    transform = T["geometry_msgs/msg/Transform"](translation=translation, rotation=rotation)
    return T["geometry_msgs/msg/TransformStamped"](header=header(ns, parent), child_frame_id=child, transform=transform)


def write_bag(path: Path, scans: int, t0_ns: int = 1_700_000_000 * 10**9) -> None:
    """``scans`` scans at 10 Hz of a robot driving 0.3 m per scan from one room through the door into the other."""
    occupied = np.zeros((40, 70), bool)  # 4 m x 7 m at 0.1 m: two rooms, a wall at x = 3.5 m, a door in it
    occupied[[0, -1], :] = occupied[:, [0, -1]] = True
    occupied[:, 35], occupied[17:23, 35] = True, False
    world = World(OccupancyGrid(occupied, ~occupied, 0.1, "two-rooms"), (20, 5), WorldConfig())
    with Writer(path, version=9) as writer:
        links = {topic: writer.add_connection(topic, kind, typestore=TYPES) for topic, kind in KINDS.items()}

        def put(topic, ns, message):
            writer.write(links[topic], ns, TYPES.serialize_cdr(message, KINDS[topic]))

        put("/tf_static", t0_ns, T["tf2_msgs/msg/TFMessage"](transforms=[tf(t0_ns, "base_link", "laser", 0, 0, 0)]))
        for k in range(scans):
            ns, observation = t0_ns + k * 100_000_000, world.observe()  # a scan from the true pose every 0.1 s
            pose, scan = observation.pose, observation.scan
            put("/tf", ns, T["tf2_msgs/msg/TFMessage"](transforms=[
                tf(ns, "map", "odom", 0, 0, 0), tf(ns, "odom", "base_link", pose.x, pose.y, pose.yaw)]))
            put("/scan", ns, T["sensor_msgs/msg/LaserScan"](
                header=header(ns, "laser"), angle_min=scan.angle_min, angle_max=scan.angle_max,
                angle_increment=scan.angle_increment, time_increment=0.0, scan_time=0.1, range_min=scan.range_min,
                range_max=scan.range_max, ranges=scan.ranges, intensities=np.zeros(0, np.float32)))
            world.drive([[pose.x, pose.y], [6.5, 2.0]], 0.3)  # along the rooms' middle, through the door


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, default=30, help="scans in the bag (10 a second)")
    parser.add_argument("--out", type=Path, default=None, help="keep the bag and the outputs in this folder "
                                                              "(default: a temporary one, removed at the end)")
    args = parser.parse_args(argv)
    if args.scans < 1 or (args.out is not None and (args.out / "drive").exists()):
        parser.error("--scans must be >= 1, and --out a folder without a bag called drive")
    with tempfile.TemporaryDirectory() as scratch:
        folder = args.out or Path(scratch)
        folder.mkdir(parents=True, exist_ok=True)
        write_bag(folder / "drive", args.scans)
        code = superex(["offline", str(folder / "drive"), "--out", str(folder / "offline"), "--finish-after", "0.5"])
        summary = json.loads((folder / "offline" / "summary.json").read_text())
    skipped = sum(summary["scans_skipped"].values())
    print(f"exit {code}: {summary['steps']} of {summary['expected_scans']} scans stepped (skipped {skipped}), pose "
          f"from {summary['pose_source']}, grid {summary['frame']['shape']}, status {summary['status']}, finished "
          f"{summary['finished']}, step p99 {summary['step_ms']['p99']:.1f} ms")
    return summary


if __name__ == "__main__":
    main()
