"""A robot's recording as input (``superex offline``, :mod:`superex_deploy.recording.bags`): small ROS 1 and ROS 2
bags written with ``rosbags`` itself from a simulated floor, read back into the observations the simulator made.
The poses are stamped at the scans' stamps (the reader interpolates between poses, so a pose stamped earlier would
give another one); ``tests/test_bags_*.py`` use the helpers here."""

import json
import math

import numpy as np
import pytest

rosbags = pytest.importorskip("rosbags")

from rosbags.typesys import Stores, get_typestore  # noqa: E402

from superex_deploy.cli import main  # noqa: E402
from superex_deploy.maps import OccupancyGrid  # noqa: E402
from superex_deploy.messages import STATUSES, OccupancyGridMessage  # noqa: E402
from superex_deploy.recording.bags import BagTopics, read_bag  # noqa: E402
from superex_deploy.sim.world import World, WorldConfig  # noqa: E402

TYPES = get_typestore(Stores.ROS2_HUMBLE)
T = TYPES.types
LASER_OFFSET = (0.1, 0.0)  # the scanner sits 10 cm ahead of base_link
T0 = 1_700_000_000.0


def _two_rooms() -> OccupancyGrid:
    occupied = np.zeros((40, 70), bool)
    occupied[[0, -1], :] = occupied[:, [0, -1]] = True
    occupied[:, 35] = True
    occupied[17:23, 35] = False  # the door
    return OccupancyGrid(occupied, ~occupied, 0.1, "two-rooms")


def _time(t):
    sec = int(math.floor(t))
    return T["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((t - sec) * 1e9)))


def _header(t, frame):
    return T["std_msgs/msg/Header"](stamp=_time(t), frame_id=frame)


def _quaternion(yaw):
    return T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))


def _transform(t, parent, child, x, y, yaw):
    return T["geometry_msgs/msg/TransformStamped"](
        header=_header(t, parent), child_frame_id=child,
        transform=T["geometry_msgs/msg/Transform"](translation=T["geometry_msgs/msg/Vector3"](x=x, y=y, z=0.0),
                                                   rotation=_quaternion(yaw)))


def _scan_message(t, scan):
    return T["sensor_msgs/msg/LaserScan"](
        header=_header(t, "laser"), angle_min=scan.angle_min, angle_max=scan.angle_max,
        angle_increment=scan.angle_increment, time_increment=0.0, scan_time=0.1, range_min=scan.range_min,
        range_max=scan.range_max, ranges=np.asarray(scan.ranges, np.float32), intensities=np.zeros(0, np.float32))


def _pose_message(t, x, y, yaw, sigma=0.0):
    covariance = np.zeros(36)
    covariance[[0, 7]], covariance[35] = sigma ** 2, (sigma / 10) ** 2
    return T["geometry_msgs/msg/PoseWithCovarianceStamped"](
        header=_header(t, "map"), pose=T["geometry_msgs/msg/PoseWithCovariance"](
            pose=T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
                                             orientation=_quaternion(yaw)), covariance=covariance))


def _grid_message(t, message: OccupancyGridMessage):
    info = T["nav_msgs/msg/MapMetaData"](
        map_load_time=_time(t), resolution=message.resolution_m, width=message.width, height=message.height,
        origin=T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=message.origin_xy[0],
                                                                                y=message.origin_xy[1], z=0.0),
                                           orientation=_quaternion(0.0)))
    return T["nav_msgs/msg/OccupancyGrid"](header=_header(t, "map"), info=info, data=message.data)


def _drive(steps=12):
    """A simulated drive through the two rooms: per step the stamp, the laser's pose, the base's pose, the scan."""
    world = World(_two_rooms(), (20, 10), WorldConfig())
    cells = [(20, 10 + 4 * k) for k in range(steps)]
    out = []
    for k, cell in enumerate(cells):
        world.pose_rc = cell
        observation = world.observe()
        laser = observation.pose
        base = (laser.x - LASER_OFFSET[0], laser.y - LASER_OFFSET[1], laser.yaw)
        out.append((T0 + 0.1 * k, laser, base, observation.scan))
    return world, out


def _write(path, version, drive, pose="tf", slam=None, extra_scan_topic=False):
    """Write ``drive`` into a bag: ROS 2 (``version`` 2, SQLite; ``"mcap"``: MCAP storage) or ROS 1 (1)."""
    if version == 1:
        from rosbags.rosbag1 import Writer

        writer, serialize = Writer(path), lambda m, k: TYPES.serialize_ros1(m, k)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.MCAP if version == "mcap" else StoragePlugin.SQLITE3
        writer, serialize = Writer(path, version=9, storage_plugin=plugin), lambda m, k: TYPES.serialize_cdr(m, k)
    kinds = {"/scan": "sensor_msgs/msg/LaserScan", "/tf": "tf2_msgs/msg/TFMessage",
             "/tf_static": "tf2_msgs/msg/TFMessage", "/amcl_pose": "geometry_msgs/msg/PoseWithCovarianceStamped",
             "/map": "nav_msgs/msg/OccupancyGrid", "/scan2": "sensor_msgs/msg/LaserScan"}
    with writer:
        connections = {topic: writer.add_connection(topic, kind, typestore=TYPES) for topic, kind in kinds.items()}

        def put(topic, t, message):
            writer.write(connections[topic], int(t * 1e9), serialize(message, kinds[topic]))

        put("/tf_static", T0, T["tf2_msgs/msg/TFMessage"](
            transforms=[_transform(T0, "base_link", "laser", *LASER_OFFSET, 0.0)]))
        if slam is not None:
            put("/map", T0, _grid_message(T0, slam))
        for t, _, base, scan in drive:
            if pose == "tf":
                put("/tf", t, T["tf2_msgs/msg/TFMessage"](transforms=[
                    _transform(t, "map", "odom", 0.0, 0.0, 0.0),
                    _transform(t, "odom", "base_link", *base)]))
            else:
                put("/amcl_pose", t, _pose_message(t, *base, sigma=0.02))
            put("/scan", t, _scan_message(t, scan))
            if extra_scan_topic:
                put("/scan2", t, _scan_message(t, scan))
    return path


@pytest.mark.parametrize("version, pose", [(2, "tf"), ("mcap", "tf"), (1, "pose")])
def test_a_bag_gives_back_the_observations_the_simulator_made(tmp_path, version, pose):
    _, drive = _drive()
    path = _write(tmp_path / ("drive.bag" if version == 1 else "drive"), version, drive, pose=pose)
    reading, observations = read_bag(path)
    observations = list(observations)
    assert reading.scan_topic == "/scan" and reading.scans == len(drive) == len(observations)
    assert reading.pose_source == ("tf" if pose == "tf" else "/amcl_pose")
    for observation, (t, laser, _, scan) in zip(observations, drive):
        assert observation.stamp_s == pytest.approx(t - T0, abs=1e-6)
        assert (observation.pose.x, observation.pose.y) == pytest.approx((laser.x, laser.y), abs=1e-6)
        assert np.array_equal(observation.scan.ranges, scan.ranges)
        assert (observation.pose_covariance is None) == (pose == "tf")
    x0, y0, x1, y1 = reading.extent_xy
    assert x0 >= 0.1 - 1e-6 and y0 >= 0.1 - 1e-6 and x1 <= 6.9 + 1e-6 and y1 <= 3.9 + 1e-6  # inside the walls' faces


def test_superex_offline_maps_the_floor_and_writes_its_outputs(tmp_path):
    world, drive = _drive()
    bag = _write(tmp_path / "drive", 2, drive)
    assert main(["offline", str(bag), "--out", str(tmp_path / "out"), "--finish-after", "0.5"]) == 0
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["steps"] == len(drive) and summary["pose_source"] == "tf" and not summary["interrupted"]
    saved = np.load(tmp_path / "out" / "map.npz")
    observed, origin = saved["observed"], saved["origin_xy"]
    # The explorer's walls lie on the floor's walls (within a cell), in the map frame the bag's poses are in.
    rows, cols = np.nonzero(observed == 1)
    xs, ys = origin[0] + (cols + 0.5) * 0.1, origin[1] + (observed.shape[0] - rows - 0.5) * 0.1
    truth_rows = (world.grid.shape[0] - 1 - np.floor(ys / 0.1)).astype(int)
    truth_cols = np.floor(xs / 0.1).astype(int)
    from scipy import ndimage

    near_wall = ndimage.binary_dilation(world.grid.occupied, iterations=1)
    assert len(rows) > 100 and near_wall[truth_rows, truth_cols].mean() > 0.98
    lines = (tmp_path / "out" / "commands.csv").read_text().splitlines()
    assert lines[0].startswith("stamp_s,step,goal_x_m,goal_y_m,finished") and len(lines) == len(drive) + 1
    assert lines[0].endswith(",step_ms,status,reason") and lines[1].endswith(",exploring,")
    assert summary["status"] in STATUSES and isinstance(summary["reason"], str)
    assert (tmp_path / "out" / "map.png").stat().st_size > 0


def test_a_slam_map_in_the_bag_is_given_to_the_explorer(tmp_path):
    _, drive = _drive(4)
    known = np.full((40, 70), -1, np.int8)
    known[1:39, 1:35] = 0
    known[0, :35] = known[39, :35] = known[:, 0] = 100
    slam = OccupancyGridMessage(resolution_m=float(np.float32(0.1)), width=70, height=40, origin_xy=(0.0, 0.0),
                                data=np.ascontiguousarray(known[::-1]).reshape(-1))
    bag = _write(tmp_path / "drive", 2, drive, slam=slam)
    reading, observations = read_bag(bag)
    first = next(observations)
    assert reading.map_topic == "/map" and first.occupancy_grid is not None and first.scan is None
    assert next(observations).occupancy_grid is None


def test_a_bag_without_what_is_needed_gets_one_error_naming_it(tmp_path):
    _, drive = _drive(3)
    with pytest.raises(ValueError, match="several sensor_msgs/msg/LaserScan topics .*--scan-topic"):
        read_bag(_write(tmp_path / "two", 2, drive, extra_scan_topic=True))
    bag = _write(tmp_path / "one", 2, drive)
    with pytest.raises(ValueError, match="no sensor_msgs/msg/LaserScan topic '/lidar'"):
        read_bag(bag, BagTopics(scan_topic="/lidar"))
    with pytest.raises(ValueError, match="pose source '/odom' is not a"):
        read_bag(bag, BagTopics(pose_source="/odom"))
    with pytest.raises(ValueError, match="no scan on /scan has a pose from tf"):
        read_bag(bag, BagTopics(map_frame="world"))
    with pytest.raises(ValueError, match="cannot read .* as a ROS 1 bag"):
        (tmp_path / "junk.bag").write_bytes(b"not a bag")
        read_bag(tmp_path / "junk.bag")
    assert main(["offline", str(tmp_path / "missing"), "--out", str(tmp_path / "o")]) == 2


def test_an_interrupted_offline_run_writes_the_steps_it_did(tmp_path, monkeypatch, capsys):
    from superex_deploy.onboard import Explorer

    _, drive = _drive()
    bag = _write(tmp_path / "drive", 2, drive)
    step = Explorer.step

    def step_then_stop(self, observation):
        if self.steps == 5:
            raise KeyboardInterrupt
        return step(self, observation)

    monkeypatch.setattr(Explorer, "step", step_then_stop)
    assert main(["offline", str(bag), "--out", str(tmp_path / "out")]) == 130
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["interrupted"] and summary["steps"] == 5
    assert "wrote the 5 steps done" in capsys.readouterr().err
    assert not list((tmp_path / "out").glob("*.part"))


KINDS = {"/scan": "sensor_msgs/msg/LaserScan", "/tf": "tf2_msgs/msg/TFMessage",
         "/tf_static": "tf2_msgs/msg/TFMessage", "/map": "nav_msgs/msg/OccupancyGrid",
         "/amcl_pose": "geometry_msgs/msg/PoseWithCovarianceStamped", "/odom": "nav_msgs/msg/Odometry"}


def _write_items(path, items, version=2, chunk_bytes=None):
    """A bag of ``(topic, stamp_s, message)`` items (types by topic name, :data:`KINDS`; a message given as bytes
    is written as it is, garbled): a ROS 2 bag (SQLite), ``version=1`` a ROS 1 bag (chunks of about
    ``chunk_bytes``), ``"mcap"`` a ROS 2 bag stored as MCAP."""
    if version == 1:
        from rosbags.rosbag1 import Writer

        writer, serialize = Writer(path), TYPES.serialize_ros1
        if chunk_bytes is not None:
            writer.chunk_threshold = chunk_bytes
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.MCAP if version == "mcap" else StoragePlugin.SQLITE3
        writer, serialize = Writer(path, version=9, storage_plugin=plugin), TYPES.serialize_cdr
    with writer:
        connections = {topic: writer.add_connection(topic, KINDS[topic], typestore=TYPES)
                       for topic in dict.fromkeys(topic for topic, _, _ in items)}
        for topic, t, message in items:
            raw = message if isinstance(message, bytes) else serialize(message, KINDS[topic])
            writer.write(connections[topic], int(round(t * 1e9)), raw)
    return path


def _tf(t, *transforms):
    return T["tf2_msgs/msg/TFMessage"](transforms=[_transform(t, *link) for link in transforms])


def _laser_mount():
    return ("/tf_static", T0, _tf(T0, ("base_link", "laser", *LASER_OFFSET, 0.0)))


def test_a_tf_tree_with_a_loop_is_no_pose_not_a_hang(tmp_path):
    # odom -> base_link, and a second publisher's inverted base_link -> odom: looking the laser up in map looped
    # for ever (laser -> base_link -> odom -> base_link ...).
    _, drive = _drive(3)
    items = [_laser_mount()]
    for t, _, base, scan in drive:
        items += [("/tf", t, _tf(t, ("base_link", "odom", 0.0, 0.0, 0.0), ("odom", "base_link", *base))),
                  ("/scan", t, _scan_message(t, scan))]
    bag = _write_items(tmp_path / "loop", items)
    outcome = []

    def read():  # in a thread, so that a hang fails the test instead of stopping the suite
        try:
            read_bag(bag, BagTopics(pose_source="tf"))
        except ValueError as error:
            outcome.append(str(error))

    import threading

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    reader.join(timeout=30)
    assert not reader.is_alive(), "read_bag looped on the tf tree"
    assert outcome and "no scan on /scan has a pose from tf" in outcome[0]


def test_a_malformed_scan_is_skipped_and_counted(tmp_path):
    # A driver's glitch (a scan with no ranges) stopped the whole reading with LaserScan's ValueError.
    _, drive = _drive(5)
    items = [_laser_mount()]
    for k, (t, _, base, scan) in enumerate(drive):
        message = _scan_message(t, scan)
        if k == 2:
            message.ranges = np.zeros(0, np.float32)
        items += [("/tf", t, _tf(t, ("map", "base_link", *base))), ("/scan", t, message)]
    reading, observations = read_bag(_write_items(tmp_path / "glitch", items))
    stamps = [observation.stamp_s for observation in observations]
    assert reading.skipped["invalid"] == 1 and reading.scans == 4
    assert stamps == pytest.approx([0.0, 0.1, 0.3, 0.4])


def test_a_slam_map_the_explorer_cannot_take_is_refused_when_the_bag_opens(tmp_path):
    # A rotated origin in the bag's fourth map: refused by read_bag, not in the middle of the run.
    _, drive = _drive(5)
    slam = OccupancyGridMessage(0.1, 70, 40, (0.0, 0.0), np.zeros(70 * 40, np.int8))
    items = [_laser_mount()]
    for k, (t, _, base, scan) in enumerate(drive):
        items += [("/tf", t, _tf(t, ("map", "base_link", *base))), ("/scan", t, _scan_message(t, scan))]
        grid = _grid_message(t, slam)
        if k == 3:
            grid.info.origin.orientation = _quaternion(0.4)
        items.append(("/map", t + 0.01, grid))
    with pytest.raises(ValueError, match=r"the SLAM map on /map stamped .*rotated origin"):
        read_bag(_write_items(tmp_path / "rotated", items))


def test_offline_resamples_a_slam_map_of_another_resolution(tmp_path):
    # A 0.1 m SLAM map for an explorer at 0.05 m (and the map's own 0.1 m): both run, and the finer map holds the
    # SLAM map's free area (it stopped with the explorer's resolution error before).
    _, drive = _drive(4)
    slam = OccupancyGridMessage(float(np.float32(0.1)), 70, 40, (0.0, 0.0), np.zeros(70 * 40, np.int8))
    bag = _write(tmp_path / "slam", 2, drive, slam=slam)
    free = {}
    for resolution in ("0.05", "0.1"):
        out = tmp_path / f"out{resolution}"
        assert main(["offline", str(bag), "--out", str(out), "--resolution", resolution, "--finish-after", "0"]) == 0
        saved = np.load(out / "map.npz")
        free[resolution] = np.count_nonzero(saved["observed"] == 0) * float(resolution) ** 2
    assert free["0.05"] == pytest.approx(free["0.1"], rel=0.05) and free["0.1"] >= 0.9 * 7.0 * 4.0


@pytest.mark.parametrize("option, value", [("--resolution", "0"), ("--resolution", "-0.1"), ("--margin-m", "-1")])
def test_offline_refuses_a_bad_resolution_or_margin_before_reading_the_bag(tmp_path, option, value):
    # --resolution 0 ran at the default resolution (0 read as "not given"); -0.1 with a SLAM map got the SLAM map's
    # resolution error; neither named the option's own rule.
    from superex_deploy.cli import build_parser
    from superex_deploy.commands import offline

    args = build_parser().parse_args(["offline", str(tmp_path / "no-bag"), "--out", str(tmp_path / "out"), option,
                                      value])
    with pytest.raises(ValueError, match=f"{option} must be"):
        offline.run(args)
    assert not (tmp_path / "out").exists()


def test_auto_takes_the_odometry_when_the_tf_tree_has_no_map_frame(tmp_path):
    # A robot without localisation: /odom, and /tf with odom -> base_link only. auto chose tf (the bag has /tf)
    # and refused the bag: "no scan on /scan has a pose from tf".
    from rosbags.rosbag2 import Writer

    _, drive = _drive(4)
    kinds = {"/scan": "sensor_msgs/msg/LaserScan", "/tf": "tf2_msgs/msg/TFMessage",
             "/tf_static": "tf2_msgs/msg/TFMessage", "/odom": "nav_msgs/msg/Odometry"}
    vector = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    with Writer(tmp_path / "odom", version=9) as writer:
        connections = {topic: writer.add_connection(topic, kind, typestore=TYPES) for topic, kind in kinds.items()}

        def put(topic, t, message):
            writer.write(connections[topic], int(t * 1e9), TYPES.serialize_cdr(message, kinds[topic]))

        put("/tf_static", T0, _tf(T0, ("base_link", "laser", *LASER_OFFSET, 0.0)))
        for t, _, base, scan in drive:
            put("/tf", t, _tf(t, ("odom", "base_link", *base)))
            put("/odom", t, T["nav_msgs/msg/Odometry"](
                header=_header(t, "odom"), child_frame_id="base_link",
                pose=_pose_message(t, *base).pose,
                twist=T["geometry_msgs/msg/TwistWithCovariance"](
                    twist=T["geometry_msgs/msg/Twist"](linear=vector, angular=vector), covariance=np.zeros(36))))
            put("/scan", t, _scan_message(t, scan))
    reading, observations = read_bag(tmp_path / "odom")
    observations = list(observations)
    assert reading.pose_source == "/odom" and len(observations) == len(drive)
    for observation, (_, laser, _, _) in zip(observations, drive):  # the base's odometry plus the laser's mount
        assert (observation.pose.x, observation.pose.y) == pytest.approx((laser.x, laser.y), abs=1e-6)
    with pytest.raises(ValueError, match="no scan on /scan has a pose from tf"):  # asked for: still refused
        read_bag(tmp_path / "odom", BagTopics(pose_source="tf"))


def test_a_pose_topics_scans_without_the_scanners_mount_have_no_pose(tmp_path):
    # A bag recorded without /tf_static: the scans in 'laser' were drawn from base_link, 10 cm off (a scanner
    # mounted turned round: every scan mirrored), silently.
    _, drive = _drive(3)
    items = []
    for t, _, base, scan in drive:
        items += [("/amcl_pose", t, _pose_message(t, *base, sigma=0.02)),
                  ("/scan", t, _scan_message(t, scan))]
    from rosbags.rosbag2 import Writer

    kinds = {"/scan": "sensor_msgs/msg/LaserScan", "/amcl_pose": "geometry_msgs/msg/PoseWithCovarianceStamped"}
    with Writer(tmp_path / "no-mount", version=9) as writer:
        connections = {topic: writer.add_connection(topic, kind, typestore=TYPES) for topic, kind in kinds.items()}
        for topic, t, message in items:
            writer.write(connections[topic], int(t * 1e9), TYPES.serialize_cdr(message, kinds[topic]))
    with pytest.raises(ValueError, match=r"no scan on /scan has a pose from /amcl_pose .*--base-frame 'base_link'"):
        read_bag(tmp_path / "no-mount")
    reading, observations = read_bag(tmp_path / "no-mount", BagTopics(base_frame="laser"))  # the pose is the laser's
    observations = list(observations)
    assert reading.scans == len(observations) == len(drive)
    assert (observations[0].pose.x, observations[0].pose.y) == pytest.approx(drive[0][2][:2])
