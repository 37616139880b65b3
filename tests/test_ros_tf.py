"""The transform buffer of :mod:`superex_deploy.ros.tf` and its transforms (:mod:`superex_deploy.ros.rigid`): tf2's
semantics (interpolation, common ancestors, the latest common time, its errors), checked analytically, against the
slow twins of ``tests/naive.py`` (4 x 4 matrices, Rodrigues' rotations, an axis-angle slerp) on random trees, on a
turning robot's /tf, and for 2-D LiDAR mounts."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from superex_deploy.ros.rigid import Transform, planar
from superex_deploy.ros.tf import (ConnectivityError, ExtrapolationError, LoopError, TfBuffer, TransformError,
                                   UnknownFrameError, stamp_of, stamp_seconds)
from tests.naive import naive_lookup

T0 = 1_700_000_000.0  # an epoch stamp: the precision of float seconds there is 0.24 us


def _close(a: Transform, b: Transform, tolerance: float = 1e-12) -> bool:
    return bool(np.abs(a.matrix() - b.matrix()).max() <= tolerance)


def _yaw(transform: Transform) -> float:
    return math.atan2(transform.matrix()[1, 0], transform.matrix()[0, 0])


def _angle(a: float, b: float) -> float:
    return abs(math.remainder(a - b, 2.0 * math.pi))


# --- Transform ---


def test_transform_composes_inverts_and_applies_as_matrices():
    a = Transform((1.0, -2.0, 0.5), (0.1, 0.7, -0.2, 0.6))
    b = Transform((0.3, 0.4, -1.0), (-0.5, 0.1, 0.3, 0.8))
    np.testing.assert_allclose(a.compose(b).matrix(), a.matrix() @ b.matrix(), atol=1e-12)
    np.testing.assert_allclose(a.inverse().matrix(), np.linalg.inv(a.matrix()), atol=1e-12)
    points = np.random.default_rng(0).normal(size=(5, 3))
    np.testing.assert_allclose(a.compose(b).apply(points), a.apply(b.apply(points)), atol=1e-12)
    np.testing.assert_allclose(a.apply(points[0]), (a.matrix() @ np.append(points[0], 1.0))[:3], atol=1e-12)
    assert _close(a.compose(a.inverse()), Transform())
    np.testing.assert_allclose(Transform((0, 0, 0), (0, 0, 0, 2)).rotation, [0, 0, 0, 1])  # normalised
    pose = Transform.from_planar(1.0, 2.0, math.pi / 2)
    np.testing.assert_allclose(pose.apply([1.0, 0.0, 0.0]), [1.0, 3.0, 0.0], atol=1e-15)
    with pytest.raises(ValueError, match="points must be"):
        pose.apply(np.zeros((2, 2)))
    with pytest.raises(Exception):  # frozen
        pose.translation[0] = 5.0


@pytest.mark.parametrize("translation, rotation", [((0, 0, 0), (0, 0, 0, 0)), ((0, 0, 0), (0, 0, math.nan, 1)),
                                                   ((math.inf, 0, 0), (0, 0, 0, 1)), ((0, 0), (0, 0, 0, 1)),
                                                   ((0, 0, 0), (0, 0, 1e-300, 0)), ((0, 0, 0), "xyzw")])
def test_transform_refuses_bad_values(translation, rotation):
    with pytest.raises(ValueError, match="a transform needs"):
        Transform(translation, rotation)


def test_interpolation_takes_the_shorter_arc_and_lerps_the_translation():
    a = Transform.from_planar(0.0, 0.0, math.radians(170))
    b = Transform.from_planar(2.0, -4.0, math.radians(-170))
    half = a.interpolate(b, 0.5)
    assert _angle(_yaw(half), math.pi) < 1e-12  # through 180, not through 0
    np.testing.assert_allclose(half.translation, [1.0, -2.0, 0.0])
    assert _angle(_yaw(a.interpolate(b, 0.25)), math.radians(175)) < 1e-12
    flipped = Transform(b.translation, -b.rotation)  # the same rotation, the other sign: the same arc
    assert _close(a.interpolate(flipped, 0.25), a.interpolate(b, 0.25))
    assert _close(a.interpolate(b, 0.0), a) and _close(a.interpolate(b, 1.0), b)
    assert _close(a.interpolate(a, 0.3), a)


# --- the buffer: analytic cases ---


def _robot(buffer: TfBuffer, stamps, pose_at, mount=Transform((0.2, 0.0, 0.3))) -> None:
    """map -> odom (static offset), odom -> base_link at ``pose_at(t)`` (x, y, yaw), base_link -> laser (static)."""
    buffer.add("map", "odom", 0.0, Transform.from_planar(1.0, -1.0, 0.5), static=True)
    for t in stamps:
        buffer.add("odom", "base_link", t, Transform.from_planar(*pose_at(t)))
    buffer.add("base_link", "laser", 0.0, mount, static=True)


def test_a_chain_with_a_static_mount():
    buffer = TfBuffer()
    _robot(buffer, [T0 + 1.0, T0 + 2.0], lambda t: (t - T0, 0.0, (t - T0) * 0.4))
    got = buffer.lookup("map", "laser", T0 + 1.5)
    expected = (Transform.from_planar(1.0, -1.0, 0.5).compose(Transform.from_planar(1.5, 0.0, 0.6))
                .compose(Transform((0.2, 0.0, 0.3))))
    assert _close(got, expected, 1e-6)  # 1e-6: the stamps' float precision at T0 times 1 m/s
    assert _close(buffer.lookup("/map", "/laser", T0 + 2.0), buffer.lookup("map", "laser", T0 + 2.0))
    assert _close(buffer.lookup("laser", "map", T0 + 1.5), got.inverse())
    assert _close(buffer.lookup("ghost", "ghost", 3.0), Transform())  # tf2: the identity, even for unknown frames
    assert buffer.frames() == {"map", "odom", "base_link", "laser"}
    assert buffer.newest_stamp("base_link") == T0 + 2.0 and buffer.newest_stamp("laser") == math.inf
    assert buffer.newest_stamp("map") is None and buffer.newest_stamp("nowhere") is None
    assert buffer.can_transform("map", "laser", T0 + 1.5) and not buffer.can_transform("map", "laser", T0 + 3.0)


def test_common_ancestor_lookups_read_no_link_above_it():
    buffer = TfBuffer()
    _robot(buffer, [1.0, 2.0], lambda t: (t, 0.5 * t, 0.3 * t))
    dock = Transform((3.0, 1.0, 0.0), (0.0, 0.0, 0.6, 0.8))
    buffer.add("odom", "dock", 0.0, dock, static=True)  # a sibling of base_link under odom
    buffer.add("world", "map", 50.0, Transform.from_planar(5.0, 5.0, 1.0))  # a link above, with no data at 1.5
    got = buffer.lookup("dock", "laser", 1.5)
    expected = dock.inverse().compose(Transform.from_planar(1.5, 0.75, 0.45)).compose(Transform((0.2, 0.0, 0.3)))
    assert _close(got, expected)
    assert _close(buffer.lookup("laser", "dock", 1.5), got.inverse())
    with pytest.raises(ExtrapolationError, match="world -> map"):  # only through the link above
        buffer.lookup("world", "laser", 1.5)


def test_stamp_zero_is_the_latest_common_time():
    buffer = TfBuffer()
    for t in (1.0, 2.0, 3.0):
        buffer.add("map", "odom", t, Transform.from_planar(t, 0.0, 0.0))
    for t in (1.0, 1.5, 2.5):
        buffer.add("odom", "base_link", t, Transform.from_planar(0.0, t, 0.0))
    buffer.add("base_link", "laser", 7.0, Transform(), static=True)
    assert buffer.latest_common_time("map", "laser") == 2.5
    assert buffer.latest_common_time("odom", "map") == 3.0
    assert _close(buffer.lookup("map", "laser", 0.0), buffer.lookup("map", "laser", 2.5))
    np.testing.assert_allclose(buffer.lookup("map", "laser", 0.0).translation, [2.5, 2.5, 0.0])
    assert buffer.latest_common_time("base_link", "laser") == 0.0  # all static: any time
    assert buffer.latest_common_time("odom", "odom") == 3.0  # a frame with itself: its newest (tf2)
    assert _close(buffer.lookup("laser", "base_link", 0.0), Transform())


def test_out_of_order_inserts_pruning_and_repeated_stamps():
    in_order, shuffled = TfBuffer(), TfBuffer()
    stamps = np.arange(0.0, 2.0, 0.1)
    for t in stamps:
        in_order.add("odom", "base", float(t), Transform.from_planar(t, t * t, t))
    for t in np.random.default_rng(1).permutation(stamps):
        shuffled.add("odom", "base", float(t), Transform.from_planar(t, t * t, t))
    for t in np.linspace(0.0, 1.9, 37)[1:]:
        assert _close(in_order.lookup("odom", "base", t), shuffled.lookup("odom", "base", t))
    assert not in_order.add("odom", "base", 1.0, Transform.from_planar(9.0, 9.0, 0.0))  # repeated: the first kept
    np.testing.assert_allclose(in_order.lookup("odom", "base", 1.0).translation, [1.0, 1.0, 0.0], atol=1e-12)
    buffer = TfBuffer(cache_s=1.0)
    for t in range(10):
        assert buffer.add("odom", "base", float(t) * 0.5, Transform.from_planar(t, 0.0, 0.0))
    assert not buffer.add("odom", "base", 2.0, Transform())  # older than 1 s behind the newest (4.5): ignored
    with pytest.raises(ExtrapolationError, match="into the past.*earliest data is at time 3.500000"):
        buffer.lookup("odom", "base", 3.2)


def test_a_new_parent_holds_from_its_stamp_on():
    buffer = TfBuffer()
    buffer.add("map", "table", 0.0, Transform((1.0, 0.0, 0.0)), static=True)
    buffer.add("map", "gripper", 0.0, Transform((0.0, 5.0, 0.0)), static=True)
    buffer.add("table", "cup", 1.0, Transform((0.1, 0.0, 0.0)))
    buffer.add("table", "cup", 2.0, Transform((0.2, 0.0, 0.0)))
    buffer.add("gripper", "cup", 3.0, Transform((0.0, 0.0, 0.1)))  # picked up
    buffer.add("gripper", "cup", 4.0, Transform((0.0, 0.0, 0.2)))
    np.testing.assert_allclose(buffer.lookup("map", "cup", 1.5).translation, [1.15, 0.0, 0.0])
    np.testing.assert_allclose(buffer.lookup("map", "cup", 2.5).translation, [1.2, 0.0, 0.0])  # older, held
    np.testing.assert_allclose(buffer.lookup("map", "cup", 3.5).translation, [0.0, 5.0, 0.15])
    np.testing.assert_allclose(buffer.lookup("map", "cup", 0.0).translation, [0.0, 5.0, 0.2])
    np.testing.assert_allclose(buffer.lookup("table", "cup", 1.5).translation, [0.15, 0.0, 0.0])


def test_static_and_dynamic_replace_each_other():
    buffer = TfBuffer()
    buffer.add("base", "laser", 1.0, Transform((1.0, 0.0, 0.0)))
    buffer.add("base", "laser", 2.0, Transform((2.0, 0.0, 0.0)))
    buffer.add("base", "laser", 0.0, Transform((5.0, 0.0, 0.0)), static=True)
    np.testing.assert_allclose(buffer.lookup("base", "laser", 123.0).translation, [5.0, 0.0, 0.0])
    buffer.add("base", "laser", 0.0, Transform((6.0, 0.0, 0.0)), static=True)
    np.testing.assert_allclose(buffer.lookup("base", "laser", 1.5).translation, [6.0, 0.0, 0.0])
    buffer.add("base", "laser", 10.0, Transform((7.0, 0.0, 0.0)))
    with pytest.raises(ExtrapolationError, match="only time 10.000000 is in the buffer"):
        buffer.lookup("base", "laser", 1.5)


# --- errors ---


def test_unknown_frames_and_unconnected_trees():
    buffer = TfBuffer()
    buffer.add("map", "odom", 1.0, Transform())
    buffer.add("world", "robot2", 1.0, Transform())
    with pytest.raises(UnknownFrameError, match=r'"lasr" passed to lookup argument source does not exist; the buffer '
                                                r"holds the frames map \(root\), odom \(parent map\), robot2"):
        buffer.lookup("map", "lasr", 1.0)
    with pytest.raises(UnknownFrameError, match="an empty frame id passed to lookup argument target"):
        buffer.lookup("", "odom", 1.0)
    with pytest.raises(ConnectivityError, match="between 'map' and 'robot2' because they are not part of the same "
                                                r"tree.*world \(root\)"):
        buffer.lookup("map", "robot2", 1.0)
    with pytest.raises(ConnectivityError):  # not an extrapolation, though no link has data at 5
        buffer.lookup("map", "robot2", 5.0)
    with pytest.raises(ConnectivityError):
        buffer.lookup("robot2", "odom", 0.0)
    assert issubclass(ConnectivityError, TransformError) and issubclass(TransformError, LookupError)
    with pytest.raises(ValueError, match="finite stamp"):
        buffer.lookup("map", "odom", math.nan)


def test_extrapolation_names_the_link_and_the_stamps_and_holds_within_the_limit():
    for limit in (0.0, 0.05):
        buffer = TfBuffer(max_extrapolation_s=limit)
        buffer.add("map", "odom", 0.0, Transform(), static=True)
        buffer.add("odom", "base_link", 10.0, Transform.from_planar(0.0, 0.0, 0.0))
        buffer.add("odom", "base_link", 10.5, Transform.from_planar(1.0, 0.0, 0.0))
        with pytest.raises(ExtrapolationError, match=r"extrapolation into the future.  Requested time 10.600000 but "
                                                     r"the latest data is at time 10.500000.*the link odom -> "
                                                     r"base_link \(data from 10.000000 to 10.500000\).*frame "
                                                     r"\[base_link\] to frame \[map\]"):
            buffer.lookup("map", "base_link", 10.6)
        with pytest.raises(ExtrapolationError, match="into the past.  Requested time 9.900000 but the earliest data "
                                                     "is at time 10.000000"):
            buffer.lookup("map", "base_link", 9.9)
        held = [10.54, 9.96]
        if limit:
            np.testing.assert_allclose(buffer.lookup("map", "base_link", held[0]).translation, [1.0, 0.0, 0.0])
            np.testing.assert_allclose(buffer.lookup("base_link", "map", held[1]).translation, [0.0, 0.0, 0.0])
        else:
            for t in held:
                assert not buffer.can_transform("map", "base_link", t)


def test_a_loop_is_named():
    buffer = TfBuffer()
    buffer.add("a", "b", 1.0, Transform())
    buffer.add("b", "a", 1.0, Transform())
    buffer.add("a", "c", 1.0, Transform())
    with pytest.raises(LoopError, match="contains a loop: a -> b -> a"):
        buffer.lookup("c", "a", 1.0)
    with pytest.raises(LoopError, match="contains a loop"):
        buffer.lookup("c", "a", 0.0)
    buffer.add("x", "y", 1.0, Transform())
    with pytest.raises(LoopError, match="contains a loop: a -> b -> a"):  # found walking up from the target
        buffer.lookup("c", "y", 1.0)


@pytest.mark.parametrize("parent, child, stamp, match", [("map", "map", 1.0, "'map' to itself"),
                                                         ("/map", "map", 1.0, "'map' to itself"),
                                                         ("", "odom", 1.0, "non-empty parent and child"),
                                                         ("map", "/", 1.0, "non-empty parent and child"),
                                                         ("map", "odom", math.nan, "finite stamp")])
def test_add_refuses_bad_transforms(parent, child, stamp, match):
    buffer = TfBuffer()
    with pytest.raises(ValueError, match=match):
        buffer.add(parent, child, stamp, Transform())
    assert buffer.frames() == set()
    with pytest.raises(ValueError, match="a transform needs a finite translation and a finite non-zero quaternion"):
        buffer.add("map", "odom", 1.0, Transform((0, 0, 0), (0, 0, 0, 0)))


def _ros_transform(parent, child, t, xyz=(0.0, 0.0, 0.0), xyzw=(0.0, 0.0, 0.0, 1.0)):
    """A geometry_msgs/TransformStamped as a plain object with the ROS field names."""
    sec, nanosec = stamp_of(t)
    return SimpleNamespace(header=SimpleNamespace(frame_id=parent, stamp=SimpleNamespace(sec=sec, nanosec=nanosec)),
                           child_frame_id=child, transform=SimpleNamespace(
                               translation=SimpleNamespace(x=xyz[0], y=xyz[1], z=xyz[2]),
                               rotation=SimpleNamespace(x=xyzw[0], y=xyzw[1], z=xyzw[2], w=xyzw[3])))


def test_add_message_skips_and_counts_bad_transforms():
    buffer = TfBuffer()
    good = [_ros_transform("/odom", "base_link", T0 + 1.0, (1.0, 0.0, 0.0)),
            _ros_transform("odom", "/base_link", T0 + 2.0, (2.0, 0.0, 0.0))]
    bad = [_ros_transform("odom", "base_link", T0 + 1.5, (math.nan, 0.0, 0.0)),
           _ros_transform("odom", "base_link", T0 + 1.6, xyzw=(0.0, 0.0, 0.0, 0.0)),
           _ros_transform("odom", "base_link", T0 + 1.7, xyzw=(0.0, 0.0, 0.5, 0.5)),  # |q|^2 = 0.5: tf2 refuses
           _ros_transform("odom", "odom", T0 + 1.8), _ros_transform("", "base_link", T0 + 1.9),
           SimpleNamespace(child_frame_id="base_link")]
    assert buffer.add_message(SimpleNamespace(transforms=[good[0], *bad, good[1]]), static=False) == 2
    assert buffer.rejected == len(bad) and buffer.last_rejection.startswith("transform '?' -> 'base_link' skipped")
    np.testing.assert_allclose(buffer.lookup("odom", "base_link", T0 + 1.5).translation, [1.5, 0.0, 0.0], atol=1e-6)
    assert buffer.frames() == {"odom", "base_link"}
    assert buffer.add_message(SimpleNamespace(transforms=[good[0]]), static=False) == 0  # repeated: ignored
    assert buffer.rejected == len(bad)


def test_add_message_reads_rosbags_messages():
    typesys = pytest.importorskip("rosbags.typesys")
    types = typesys.get_typestore(typesys.Stores.ROS2_HUMBLE).types

    def stamped(parent, child, t, x, yaw):
        sec, nanosec = stamp_of(t)
        return types["geometry_msgs/msg/TransformStamped"](
            header=types["std_msgs/msg/Header"](stamp=types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec),
                                                frame_id=parent), child_frame_id=child,
            transform=types["geometry_msgs/msg/Transform"](
                translation=types["geometry_msgs/msg/Vector3"](x=x, y=0.0, z=0.0),
                rotation=types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))))

    message = types["tf2_msgs/msg/TFMessage"]
    buffer = TfBuffer()
    buffer.add_message(message(transforms=[stamped("base_link", "laser", T0, 0.1, math.pi)]), static=True)
    buffer.add_message(message(transforms=[stamped("odom", "base_link", T0 + 0.05 * k, 0.05 * k, 0.0)
                                           for k in range(3)]), static=False)
    got = buffer.lookup("odom", "laser", stamp_seconds(types["builtin_interfaces/msg/Time"](*stamp_of(T0 + 0.075))))
    np.testing.assert_allclose(got.translation, [0.175, 0.0, 0.0], atol=1e-6)
    assert buffer.rejected == 0 and buffer.newest_stamp("base_link") == stamp_seconds(
        types["builtin_interfaces/msg/Time"](*stamp_of(T0 + 0.1)))


def test_stamps_round_trip_to_the_nanosecond():
    assert stamp_of(1.5) == (1, 500_000_000) and stamp_of(2.0000000004) == (2, 0)
    assert stamp_of(-0.5) == (-1, 500_000_000)
    sec, nanosec = stamp_of(T0 + 0.123456789)
    assert abs(stamp_seconds(SimpleNamespace(sec=sec, nanosec=nanosec)) - (T0 + 0.123456789)) < 3e-7


# --- against the slow twin ---


_QUATERNIONS = st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4).filter(lambda q: sum(v * v for v in q) > 0.01)
_TRANSLATIONS = st.lists(st.floats(-5.0, 5.0), min_size=3, max_size=3)


@st.composite
def _trees(draw):
    """``(links, records)``: each frame ``f1..fn``'s parent and samples (naive_lookup's form), and the same as
    ``TfBuffer.add`` arguments in a random order (some frame ids with a leading ``/``)."""
    links, records = {}, []
    for i in range(1, draw(st.integers(2, 7))):
        parent, static = f"f{draw(st.integers(0, i - 1))}", draw(st.booleans())
        stamps = [draw(st.floats(0.0, 10.0))] if static else sorted(
            {1.0, 9.0, *draw(st.lists(st.floats(1.0, 9.0), max_size=4))})
        samples = [(t, draw(_TRANSLATIONS), draw(_QUATERNIONS)) for t in stamps]
        links[f"f{i}"] = (parent, samples)
        slash = draw(st.booleans())
        records += [(("/" if slash else "") + parent, f"f{i}", t, Transform(p, q), static) for t, p, q in samples]
    return links, draw(st.permutations(records))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(tree=_trees(), data=st.data())
def test_lookups_match_the_slow_twin(tree, data):
    links, records = tree
    buffer = TfBuffer()
    for record in records:
        assert buffer.add(*record)
    frames = sorted(buffer.frames())
    for _ in range(4):
        target, source = data.draw(st.sampled_from(frames)), data.draw(st.sampled_from(frames))
        stamp = data.draw(st.floats(1.0, 9.0) | st.sampled_from([0.0, 1.0, 9.0]))
        expected = naive_lookup(links, target, source, 9.0 if stamp == 0.0 else stamp)
        got = buffer.lookup(target, source, stamp)
        assert np.abs(got.matrix() - expected).max() <= 1e-9
        assert np.abs(buffer.lookup(source, target, stamp).inverse().matrix() - expected).max() <= 1e-9


# --- a turning robot: interpolation against the newest pose at or before a scan ---


def test_interpolated_poses_of_a_turning_robot():
    """v = 1 m/s, omega = 1 rad/s (a circle of radius 1 m), /tf at 20 Hz, a laser 0.2 m ahead: lerp + slerp is off
    the arc by at most its sagitta R (1 - cos(omega dt / 2)) = 0.31 mm (the rotation is exact); the newest pose at
    or before the scan (the old rule) is up to 5 cm and 2.9 deg off."""
    v, omega, dt, mount = 1.0, 1.0, 0.05, (0.2, 0.0)

    def exact(t):  # the laser's (x, y, yaw) in odom at T0 + t
        yaw = omega * t
        x, y = v / omega * math.sin(yaw), v / omega * (1.0 - math.cos(yaw))
        return x + mount[0] * math.cos(yaw), y + mount[0] * math.sin(yaw), yaw

    buffer = TfBuffer()
    for k in range(41):
        t = k * dt
        buffer.add("odom", "base_link", T0 + t, Transform.from_planar(v / omega * math.sin(omega * t),
                                                                      v / omega * (1 - math.cos(omega * t)), omega * t))
    buffer.add("base_link", "laser", T0, Transform((*mount, 0.25)), static=True)
    sagitta = v / omega * (1.0 - math.cos(omega * dt / 2.0))
    assert 3.1e-4 < sagitta < 3.2e-4
    errors, old_errors = [], []
    for t in np.random.default_rng(2).uniform(0.0, 2.0, 400):
        x, y, yaw = exact(t)
        got_x, got_y, got_yaw, mirrored = buffer.lookup("odom", "laser", T0 + t).planar("laser")
        errors.append((math.hypot(got_x - x, got_y - y), _angle(got_yaw, yaw)))
        old = T0 + math.floor(t / dt + 1e-9) * dt  # the newest sample at or before the scan
        old_x, old_y, old_yaw, _ = buffer.lookup("odom", "laser", old).planar("laser")
        old_errors.append((math.hypot(old_x - x, old_y - y), _angle(old_yaw, yaw)))
        assert not mirrored
    errors, old_errors = np.array(errors), np.array(old_errors)
    assert errors[:, 0].max() <= sagitta + 1e-5  # 1e-5: float seconds at T0 (0.24 us) times the speed
    assert errors[:, 0].max() > 0.5 * sagitta and errors[:, 0].max() < 1e-3
    assert errors[:, 1].max() < math.radians(0.01)
    assert 0.045 < old_errors[:, 0].max() < 0.052 and math.radians(2.5) < old_errors[:, 1].max() < math.radians(2.9)


def test_holding_versus_linear_extrapolation():
    """What the hold window costs and what extrapolating would: 50 ms past the newest of 20 Hz samples of a constant
    twist (1 m/s, 1 rad/s) holding is 5 cm off and linear extrapolation 2.5 mm; after a 5 cm localisation correction
    between 10 Hz samples (or a robot that stopped), extrapolating invents 2.5 cm (5 cm) that holding does not."""
    buffer = TfBuffer(max_extrapolation_s=0.05)
    pose = lambda t: Transform.from_planar(math.sin(t), 1.0 - math.cos(t), t)  # noqa: E731
    for k in range(21):
        buffer.add("odom", "base_link", k * 0.05, pose(k * 0.05))
    linear = pose(0.95).interpolate(pose(1.0), 2.0)
    hold_error = np.linalg.norm(buffer.lookup("odom", "base_link", 1.05).translation - pose(1.05).translation)
    linear_error = np.linalg.norm(linear.translation - pose(1.05).translation)
    assert 0.049 < hold_error < 0.051 and 0.002 < linear_error < 0.003
    buffer.add("map", "odom", 0.9, Transform())
    buffer.add("map", "odom", 1.0, Transform((0.05, 0.0, 0.0)))  # the correction: 0.05 m, held until corrected again
    truth = Transform((0.05, 0.0, 0.0))
    linear = Transform().interpolate(truth, (1.05 - 0.9) / 0.1)
    assert np.linalg.norm(buffer.lookup("map", "odom", 1.05).translation - truth.translation) == 0.0
    assert abs(np.linalg.norm(linear.translation - truth.translation) - 0.025) < 1e-12
    buffer.add("odom", "robot", 0.95, Transform((0.95, 0.0, 0.0)))
    buffer.add("odom", "robot", 1.0, Transform((1.0, 0.0, 0.0)))  # stopped there
    linear = Transform((0.95, 0.0, 0.0)).interpolate(Transform((1.0, 0.0, 0.0)), 2.0)
    assert buffer.lookup("odom", "robot", 1.05).translation[0] == 1.0 and abs(linear.translation[0] - 1.05) < 1e-12


# --- 2-D LiDAR mounts ---


def _scan_points(ranges, angles):
    return np.stack([ranges * np.cos(angles), ranges * np.sin(angles), np.zeros_like(angles)], axis=1)


@pytest.mark.parametrize("mount, mirrored, yaw_offset", [
    ((0.0, 0.0, 0.0, 1.0), False, 0.0),  # upright
    ((1.0, 0.0, 0.0, 0.0), True, 0.0),  # roll = pi: upside down, x still forwards
    ((0.0, 1.0, 0.0, 0.0), True, math.pi),  # pitch = pi: upside down, x backwards
    ((0.0, 0.0, math.sin(0.3), math.cos(0.3)), False, 0.6),  # turned 0.6 rad on the robot
    ((math.sin(0.015), 0.0, 0.0, math.cos(0.015)), False, 0.0)])  # rolled 1.7 deg: within the tolerance
def test_planar_projects_scan_points_as_3d_points_land(mount, mirrored, yaw_offset):
    base = Transform((2.0, -1.0, 0.0), (0.0, 0.0, math.sin(0.35), math.cos(0.35)))  # yaw 0.7
    laser = base.compose(Transform((0.3, 0.1, 0.4), mount))
    x, y, yaw, got_mirrored = planar(laser, "laser")
    assert got_mirrored is mirrored and _angle(yaw, 0.7 + yaw_offset) < 1e-12
    angles = np.linspace(-2.0, 2.0, 9)
    ranges = np.linspace(0.5, 4.0, 9)
    landed = laser.apply(_scan_points(ranges, angles))
    turn = yaw - angles if mirrored else yaw + angles
    tolerance = 1e-12 if mount[0] in (0.0, 1.0) else 4.0 * (1.0 - math.cos(0.03))  # tilted: its cone's shortening
    np.testing.assert_allclose(landed[:, 0], x + ranges * np.cos(turn), atol=tolerance)
    np.testing.assert_allclose(landed[:, 1], y + ranges * np.sin(turn), atol=tolerance)
    assert (x, y, yaw, mirrored) == laser.planar("laser")


@pytest.mark.parametrize("roll", [0.1, math.pi - 0.1, math.pi / 2])
def test_planar_refuses_a_tilted_sensor(roll):
    laser = Transform((0.0, 0.0, 0.3), (math.sin(roll / 2), 0.0, 0.0, math.cos(roll / 2)))
    tilt = math.degrees(min(roll, math.pi - roll))
    with pytest.raises(ValueError, match=rf"'front_laser' is tilted {tilt:.2f} deg from the vertical.*non-planar "
                                         "mount cannot be used by a 2-D explorer"):
        planar(laser, "front_laser")
    assert planar(laser, "front_laser", tilt_tolerance_rad=math.pi / 2)[3] is (roll > math.pi / 2)
