"""Where a bag's scans were taken (``superex offline``, :mod:`superex_deploy.recording.bag_poses`): a laser mounted
upside down, a tilted one, /tf and pose topics interpolated at the scans' stamps, a scan just past the newest
transform, stamps that do not advance, and the de-skew of a scan taken while the robot turns."""

import json
import math

import numpy as np
import pytest

pytest.importorskip("rosbags")

from superex_deploy.cli import main  # noqa: E402
from superex_deploy.geometry import cast_rays  # noqa: E402
from superex_deploy.messages import LaserScan, grid_angles  # noqa: E402
from superex_deploy.recording.bags import BagTopics, read_bag  # noqa: E402
from superex_deploy.sim.world import World, WorldConfig, _float32_at_least  # noqa: E402
from tests.test_bags import (LASER_OFFSET, T, T0, _header, _laser_mount, _pose_message, _scan_message,  # noqa: E402
                             _tf, _two_rooms, _write_items)
from tests.test_bags_real_logs import tf_message, transform_message  # noqa: E402

# A scanner whose float32 angles mirror exactly (-3.125 + i / 64 rad, 401 rays): an upside-down one reports the
# very rays of an upright one, so their maps must be equal cell for cell.
STEP = 2.0 ** -6
RAYS = 401
ANGLES = -0.5 * (RAYS - 1) * STEP + np.arange(RAYS) * STEP


def _ranges(world, x, y, yaw, angles=ANGLES):
    origin, _ = world.frame.locate(x, y)
    hits = cast_rays(world.grid.occupied, origin, grid_angles(yaw, angles), 100.0)
    return np.where(hits.hit_mask, _float32_at_least(hits.distance_cells * world.grid.resolution_m), np.inf)


def _scan(t, ranges):
    return _scan_message(t, LaserScan(float(ANGLES[0]), STEP, 0.0, 20.0, np.asarray(ranges, np.float32)))


def _mount_bag(path, roll, pose_source="tf", pitch=0.0, steps=8):
    """A drive through the two rooms, turning, with the laser 10 cm ahead of base_link, rolled by ``roll`` (pi:
    upside down, its scans the upright one's reversed) and pitched by ``pitch``."""
    world = World(_two_rooms(), (20, 10), WorldConfig())
    items = [("/tf_static", T0, tf_message(transform_message(T0, "base_link", "laser", *LASER_OFFSET, 0.0, roll=roll,
                                                              pitch=pitch)))]
    for k in range(steps):
        t = T0 + 0.1 * k
        x, y = world.frame.centre_xy((20, 10 + 4 * k))
        yaw = 0.4 * k
        ranges = _ranges(world, x + LASER_OFFSET[0] * math.cos(yaw), y + LASER_OFFSET[0] * math.sin(yaw), yaw)
        if pose_source == "tf":
            items.append(("/tf", t, _tf(t, ("map", "base_link", x, y, yaw))))
        else:
            items.append(("/amcl_pose", t, _pose_message(t, x, y, yaw, sigma=0.0)))
        items.append(("/scan", t, _scan(t, ranges[::-1] if abs(roll) == math.pi else ranges)))
    return _write_items(path, items)


@pytest.mark.parametrize("pose_source", ["tf", "/amcl_pose"])
def test_a_laser_mounted_upside_down_gives_the_map_of_an_upright_one(tmp_path, pose_source):
    # Its roll was dropped (the yaw of the quaternion (1, 0, 0, 0) is 0): every scan was drawn mirrored.
    maps = {}
    for name, roll in (("upright", 0.0), ("rolled", math.pi)):
        bag = _mount_bag(tmp_path / name, roll, pose_source)
        assert main(["offline", str(bag), "--out", str(tmp_path / f"out-{name}"), "--finish-after", "0"]) == 0
        maps[name] = np.load(tmp_path / f"out-{name}" / "map.npz")
        summary = json.loads((tmp_path / f"out-{name}" / "summary.json").read_text())
        assert summary["mirrored_scans"] == (8 if name == "rolled" else 0) and summary["steps"] == 8
    assert np.array_equal(maps["upright"]["origin_xy"], maps["rolled"]["origin_xy"])
    assert np.array_equal(maps["upright"]["observed"], maps["rolled"]["observed"])
    assert np.count_nonzero(maps["upright"]["observed"] == 1) > 100


@pytest.mark.parametrize("roll, pitch", [(0.3, 0.0), (0.0, 0.2), (math.pi, 0.2)])
def test_a_tilted_laser_is_refused_naming_its_frame_before_any_scan_runs(tmp_path, capsys, roll, pitch):
    bag = _mount_bag(tmp_path / "tilted", roll, pitch=pitch, steps=3)
    assert main(["offline", str(bag), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("superex offline: error: the scans on /scan: the frame 'laser' is "
                                               "tilted") and "non-planar mount" in err[0]
    assert not (tmp_path / "out").exists()


def _moving(t):
    """A robot driving at 1 m/s along x while turning at 1 rad/s (its pose at stamp ``t``)."""
    return 1.0 + (t - T0), 2.0, -3.0 + (t - T0)


def test_tf_poses_are_interpolated_between_the_transforms_around_each_scan(tmp_path):
    # /tf at 20 Hz, the scans at another phase: each scan took the newest transform before it (up to 5 cm and
    # 0.05 rad off at 1 m/s and 1 rad/s).
    scan = np.full(RAYS, 1.5, np.float32)
    items = [_laser_mount()]
    stamps = T0 + 0.013 + 0.1 * np.arange(10)
    for t in T0 + 0.05 * np.arange(22):
        items.append(("/tf", t, _tf(t, ("map", "base_link", *_moving(t)))))
    for t in stamps:
        items.append(("/scan", t, _scan(t, scan)))
    reading, observations = read_bag(_write_items(tmp_path / "tf20", sorted(items, key=lambda item: item[1])))
    observations = list(observations)
    assert len(observations) == 10 and reading.expected_scans == 10
    for observation, t in zip(observations, stamps):
        x, y, yaw = _moving(t)
        expected = (x + LASER_OFFSET[0] * math.cos(yaw), y + LASER_OFFSET[0] * math.sin(yaw))
        assert (observation.pose.x, observation.pose.y) == pytest.approx(expected, abs=1e-6)
        assert math.remainder(observation.pose.yaw - yaw, 2 * math.pi) == pytest.approx(0.0, abs=1e-6)


def test_a_scan_just_after_the_newest_transform_holds_it_within_the_extrapolation_limit(tmp_path):
    # The last scan of a bag is often stamped after the last /tf: it was refused, or took a pose 0.5 s old.
    scan = np.full(RAYS, 1.5, np.float32)
    items = [_laser_mount()]
    for t in T0 + 0.05 * np.arange(5):  # /tf up to T0 + 0.2
        items.append(("/tf", t, _tf(t, ("map", "base_link", *_moving(t)))))
    for t in (T0 + 0.1, T0 + 0.25, T0 + 0.45):  # inside, 50 ms after the newest /tf, 250 ms after
        items.append(("/scan", t, _scan(t, scan)))
    bag = _write_items(tmp_path / "late", sorted(items, key=lambda item: item[1]))
    reading, observations = read_bag(bag)
    held = list(observations)
    assert len(held) == 2 and reading.skipped["no_pose"] == 1
    assert held[1].pose.x == pytest.approx(_moving(T0 + 0.2)[0] + LASER_OFFSET[0] * math.cos(_moving(T0 + 0.2)[2]))
    reading, observations = read_bag(bag, BagTopics(max_extrapolation_s=0.0))  # tf2's rule
    assert len(list(observations)) == 1 and reading.skipped["no_pose"] == 2
    assert main(["offline", str(bag), "--out", str(tmp_path / "out"), "--max-extrapolation", "0.3"]) == 0
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["steps"] == 3 and summary["max_extrapolation_s"] == 0.3
    assert main(["offline", str(bag), "--out", str(tmp_path / "o2"), "--max-extrapolation", "-1"]) == 2


def test_a_pose_topic_is_interpolated_between_the_two_pose_messages_around_a_scan(tmp_path):
    # The newest pose before the scan was taken (and with it its covariance), up to 0.5 s old.
    scan = np.full(RAYS, 1.5, np.float32)
    items = [_laser_mount(),
             ("/amcl_pose", T0, _pose_message(T0, 1.0, 2.0, 3.0, sigma=0.1)),
             ("/amcl_pose", T0 + 0.4, _pose_message(T0 + 0.4, 1.4, 2.2, -3.0, sigma=0.2)),
             ("/amcl_pose", T0 + 1.4, _pose_message(T0 + 1.4, 5.0, 5.0, 0.0, sigma=0.3))]
    for t in (T0 + 0.1, T0 + 0.3, T0 + 0.85):
        items.append(("/scan", t, _scan(t, scan)))
    reading, observations = read_bag(_write_items(tmp_path / "amcl", sorted(items, key=lambda item: item[1])))
    first, second, third = list(observations)
    yaw = 3.0 + 0.75 * (2 * math.pi - 6.0)  # along the shorter arc, through pi
    base = (1.3, 2.15)
    assert (second.pose.x, second.pose.y) == pytest.approx((base[0] + 0.1 * math.cos(yaw),
                                                            base[1] + 0.1 * math.sin(yaw)), abs=1e-6)
    assert math.remainder(second.pose.yaw - yaw, 2 * math.pi) == pytest.approx(0.0, abs=1e-6)
    # The covariance is the nearer message's; the third scan is 0.55 s from the next pose (beyond 0.5 s): it holds
    # the previous one, 0.45 s old.
    assert first.pose_covariance.sigma_xy_m == pytest.approx(0.1)
    assert second.pose_covariance.sigma_xy_m == pytest.approx(0.2)
    assert third.pose.x == pytest.approx(1.4 + 0.1 * math.cos(-3.0)) and third.pose_covariance.sigma_xy_m == \
        pytest.approx(0.2)


def _unclocked_bag(path, stamp_of=lambda t: 0.0):
    """Scans whose driver stamps them ``stamp_of(t)``, /tf stamped right, all received at ``t``."""
    scan = np.full(RAYS, 1.5, np.float32)
    items = [_laser_mount()]
    for k in range(6):
        t = T0 + 0.1 * k
        items.append(("/tf", t, _tf(t, ("map", "base_link", *_moving(t)))))
        message = _scan(t, scan)
        stamp = stamp_of(t)
        sec = int(math.floor(stamp))
        message.header = _header(0.0, "laser")
        message.header.stamp = T["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((stamp - sec) * 1e9)))
        items.append(("/scan", t + 0.002, message))
    items.append(("/tf", T0 + 0.6, _tf(T0 + 0.6, ("map", "base_link", *_moving(T0 + 0.6)))))
    return _write_items(path, items)


def test_scans_stamped_zero_are_refused_unless_the_receive_times_are_used(tmp_path, capsys):
    # A driver without a clock: every scan at 0. The lookups at 0 took tf2's "latest" transform for every scan.
    bag = _unclocked_bag(tmp_path / "unclocked")
    assert main(["offline", str(bag), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "the header stamps of the 6 scans on /scan do not advance (all 0.000000000 s" in err[0]
    assert "--stamps arrival" in err[0] and not (tmp_path / "out").exists()
    assert main(["offline", str(bag), "--out", str(tmp_path / "out"), "--stamps", "arrival"]) == 0
    captured = capsys.readouterr()
    assert "warning: --stamps arrival" in captured.err
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["stamps"] == "arrival" and summary["steps"] == 6 and summary["first_stamp_s"] == \
        pytest.approx(T0 + 0.002)
    reading, observations = read_bag(bag, BagTopics(stamps="arrival"))
    for k, observation in enumerate(observations):  # each at the pose of its receive time, 2 ms after its /tf
        x, _, yaw = _moving(T0 + 0.1 * k + 0.002)
        assert observation.pose.x == pytest.approx(x + LASER_OFFSET[0] * math.cos(yaw), abs=1e-6)
    # Some scans stamped 0 among stamped ones: those are skipped and counted.
    bag = _unclocked_bag(tmp_path / "glitches", lambda t: 0.0 if round((t - T0) * 10) in (2, 4) else t)
    reading, observations = read_bag(bag)
    assert len(list(observations)) == 4 and reading.skipped["no_stamp"] == 2


def test_deskew_places_each_return_from_its_own_rays_pose(tmp_path):
    # A robot spinning at 2 rad/s under a 10 Hz scanner whose 401 rays take 0.1 s: the last ray is 0.2 rad turned
    # from the first. Without de-skew every return is drawn from the first ray's pose.
    world = World(_two_rooms(), (20, 15), WorldConfig())
    x, y = world.frame.centre_xy((20, 15))
    spin, increment = 2.0, 0.1 / RAYS
    items, truth = [_laser_mount()], []
    for t in T0 + 0.005 * np.arange(50):
        items.append(("/tf", t, _tf(t, ("map", "base_link", x, y, spin * (t - T0)))))
    for t in (T0 + 0.0, T0 + 0.1):
        ranges = np.empty(RAYS)
        for i in range(RAYS):
            yaw = spin * (t + i * increment - T0)
            ranges[i] = _ranges(world, x + LASER_OFFSET[0] * math.cos(yaw), y + LASER_OFFSET[0] * math.sin(yaw), yaw,
                                ANGLES[i:i + 1])[0]
            truth.append((x + LASER_OFFSET[0] * math.cos(yaw) + ranges[i] * math.cos(yaw + ANGLES[i]),
                          y + LASER_OFFSET[0] * math.sin(yaw) + ranges[i] * math.sin(yaw + ANGLES[i])))
        message = _scan(t, ranges)
        message.time_increment = increment
        items.append(("/scan", t, message))
    bag = _write_items(tmp_path / "spin", sorted(items, key=lambda item: item[1]))
    from scipy.spatial import cKDTree

    truth = cKDTree(np.asarray(truth))
    errors = {}
    for deskew in (False, True):
        reading, observations = read_bag(bag, BagTopics(deskew=deskew))
        points, bound = [], []
        for observation in observations:
            scan, pose = observation.scan, observation.pose
            ranges = scan.ranges.astype(np.float64)
            keep = np.isfinite(ranges)
            angles = pose.yaw + scan.angles()[keep]
            points.append(np.stack([pose.x + ranges[keep] * np.cos(angles), pose.y + ranges[keep] * np.sin(angles)], 1))
            bound.append(0.5 * STEP * ranges[keep] + 1e-6)  # re-binned: at most half an increment off
        assert reading.deskewed == (2 if deskew else 0)
        errors[deskew] = (truth.query(np.concatenate(points))[0], np.concatenate(bound))
    assert np.all(errors[True][0] <= errors[True][1])
    assert np.median(errors[False][0]) > 0.05 and np.median(errors[True][0]) < 0.01
