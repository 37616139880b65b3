"""``superex offline`` on logs as a robot writes them (the acceptance test of the bag reader): a SICK LMS-style
scanner (180 degrees, 361 rays, ``range_max`` 80 m, no echo coded as 81.83 m) driven through a bundled building
floor, its scans stamped at another phase than the 20 Hz /tf, written with ``rosbags``.

The scans are cast with the simulator's ray caster (:func:`superex_deploy.geometry.cast_rays`) on the floor of a
:class:`~superex_deploy.sim.world.World` whose :class:`~superex_deploy.sim.world.LidarConfig` is the SICK's range;
a ray that meets no wall within it reads the scanner's no-echo code. Each ray may have its own pose (a scanner's
mirror turns while the robot drives: ``time_increment``), which the de-skew test uses. Maps are compared in the
floor's grid, wall IoU within a cell (a wall one cell off, diagonals included, counts:
:func:`~superex_deploy.evaluation.metrics.wall_iou_tolerant` at 1.5 cells).

Helpers here serve ``tests/test_bags_*.py`` too."""

import math

import numpy as np
import pytest

pytest.importorskip("rosbags")

from superex_deploy.cli import main  # noqa: E402
from superex_deploy.geometry import cast_rays  # noqa: E402
from superex_deploy.maps import load_map, start_poses  # noqa: E402
from superex_deploy.messages import grid_angles  # noqa: E402
from superex_deploy.evaluation.metrics import wall_iou_tolerant  # noqa: E402
from superex_deploy.sim.world import LidarConfig, World, WorldConfig, _float32_at_least  # noqa: E402
from tests.test_bags import T, T0, _header, _write_items  # noqa: E402

SICK_RAYS = 361
SICK_RANGE_MAX = 80.0
NO_ECHO = 81.83
FLOOR = "50045230"  # the smallest bundled floor: 23.5 m x 46.9 m
WITHIN_A_CELL = 1.5
SICK_DROPOUT = 0.02
"""The share of returns a SICK loses (no echo from a dark or glossy surface, read as the no-echo code)."""
SICK_NOISE_M = 0.01
"""The SICK's range noise (standard deviation, metres). A noise-free range ends exactly on a wall cell's face,
where the float32 angles of an upside-down scanner's mirrored scan (1e-7 rad off the upright one's) would put
the return in the cell before or behind it: a test of mounts would measure float32 rounding."""


def sick_world(name: str = FLOOR) -> World:
    """The floor with the SICK's LiDAR range (the world's start: its first start pose), its outer walls glazed:
    :func:`windows`."""
    grid = load_map(name)
    return World(grid, start_poses(name)[0], WorldConfig(lidar=LidarConfig(n_rays=720, range_m=SICK_RANGE_MAX)))


def windows(world: World) -> np.ndarray:
    """bool ``[H, W]``: the floor's glass, 2 m windows every 4 m along the top and bottom outer walls (the first and
    last three rows). A laser passes through glass without an echo: a ray through a window meets nothing within
    80 m (the floor ends there) and reads the no-echo code."""
    glass = np.zeros(world.grid.shape, bool)
    columns = (np.arange(glass.shape[1]) // 20) % 2 == 0
    glass[:3, columns] = glass[-3:, columns] = True
    glass[:, :3] = glass[:, -3:] = False  # the corners stay walls
    return glass & world.grid.occupied


def floor_path(world: World, length_m: float, clearance_m: float = 0.8) -> np.ndarray:
    """float ``[N, 2]`` map-frame points, 0.1 m apart, of a drive from the world's start along the shortest path
    (8-connected, at least ``clearance_m`` from every wall) to the farthest reachable cell, cut at ``length_m``
    and smoothed (a robot turns through its corners)."""
    from collections import deque

    from scipy import ndimage

    grid = world.grid
    room = ndimage.distance_transform_edt(~grid.occupied) * grid.resolution_m >= clearance_m
    start = world.pose_rc
    assert room[start], "the start must be clear of the walls"
    parent = {start: None}
    queue = deque([start])
    while queue:
        cell = queue.popleft()
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                nxt = (cell[0] + dr, cell[1] + dc)
                if nxt not in parent and 0 <= nxt[0] < grid.shape[0] and 0 <= nxt[1] < grid.shape[1] and room[nxt]:
                    parent[nxt] = cell
                    queue.append(nxt)
    cells, cell = [], cell
    while cell is not None:
        cells.append(cell)
        cell = parent[cell]
    points = world.frame.centres_xy(np.asarray(cells[::-1]))
    kernel = np.ones(15) / 15.0
    padded = np.pad(points, ((7, 7), (0, 0)), mode="edge")
    smooth = np.stack([np.convolve(padded[:, k], kernel, mode="valid") for k in range(2)], axis=1)
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(smooth, axis=0).T))])
    along = np.arange(0.0, min(length_m, arc[-1]), 0.1)
    return np.stack([np.interp(along, arc, smooth[:, 0]), np.interp(along, arc, smooth[:, 1])], axis=1)


class Drive:
    """A robot following ``points`` at ``speed`` m/s, heading along its path (the heading smoothed over
    ``turn_m``), from stamp ``T0``: :meth:`pose` at any stamp."""

    def __init__(self, points: np.ndarray, speed: float = 1.0, turn_m: float = 1.0):
        self.points, self.speed = points, speed
        step = np.diff(points, axis=0)
        heading = np.unwrap(np.arctan2(step[:, 1], step[:, 0]))
        width = max(1, int(round(turn_m / 0.1)))
        padded = np.pad(np.append(heading, heading[-1]), (width, width), mode="edge")
        self.heading = np.convolve(padded, np.ones(2 * width + 1) / (2 * width + 1), mode="valid")
        self.arc = np.arange(len(points)) * 0.1
        self.duration = self.arc[-1] / speed

    def pose(self, t: float) -> tuple[float, float, float]:
        s = (t - T0) * self.speed
        return (float(np.interp(s, self.arc, self.points[:, 0])), float(np.interp(s, self.arc, self.points[:, 1])),
                float(np.interp(s, self.arc, self.heading)))


def sick_angles() -> np.ndarray:
    """The SICK's ray angles as its messages carry them (float32 fields: ``angle_min + i * angle_increment``)."""
    return float(np.float32(-math.pi / 2)) + np.arange(SICK_RAYS) * float(np.float32(math.pi / (SICK_RAYS - 1)))


def sick_ranges(world: World, drive, stamp: float, time_increment: float = 0.0, group: int = 1,
                noise_m: float = SICK_NOISE_M, dropout: float = SICK_DROPOUT):
    """The SICK's 361 ranges (float32, rays from -90 to +90 degrees, counter-clockwise) taken from ``drive``'s pose
    at ``stamp + i * time_increment`` for ray ``i`` (``group`` rays share one pose) through the floor's walls but
    its :func:`windows`, no echo coded as :data:`NO_ECHO`, each return with the range noise ``noise_m`` and lost
    (no echo) with probability ``dropout`` (the draws seeded by the stamp: every bag of one drive has the same);
    and the wall cells the rays hit (bool, the floor's grid)."""
    angles = sick_angles()
    ranges = np.empty(SICK_RAYS, np.float32)
    seen = np.zeros(world.grid.shape, bool)
    walls = world.grid.occupied & ~windows(world)
    resolution = world.grid.resolution_m
    group = group if time_increment else SICK_RAYS
    for first in range(0, SICK_RAYS, group):
        rays = slice(first, min(first + group, SICK_RAYS))
        x, y, yaw = drive.pose(stamp + (first + 0.5 * (group - 1)) * time_increment)
        origin, _ = world.frame.locate(x, y)
        hits = cast_rays(walls, origin, grid_angles(yaw, angles[rays]), SICK_RANGE_MAX / resolution)
        # float32 rounded up, as the simulator's scans are: a return never falls short of the wall's face
        ranges[rays] = np.where(hits.hit_mask, _float32_at_least(hits.distance_cells * resolution), NO_ECHO)
        seen[hits.hit_rc[hits.hit_mask, 0], hits.hit_rc[hits.hit_mask, 1]] = True
    returns = ranges != np.float32(NO_ECHO)
    draw = np.random.default_rng(int(round(stamp * 1e3)))
    noise, lost = draw.normal(0.0, noise_m, SICK_RAYS), draw.random(SICK_RAYS) < dropout
    ranges[returns] = (ranges + noise)[returns]
    ranges[returns & lost] = NO_ECHO
    return ranges, seen


def sick_message(t: float, ranges, frame: str = "laser", mirrored: bool = False, time_increment: float = 0.0):
    """The ``sensor_msgs/LaserScan`` of the SICK's ranges; ``mirrored``: as an upside-down SICK reports the same rays
    (its counter-clockwise order is the upright one's clockwise: the ranges reversed)."""
    increment = np.float32(math.pi / (SICK_RAYS - 1))
    return T["sensor_msgs/msg/LaserScan"](
        header=_header(t, frame), angle_min=float(np.float32(-math.pi / 2)), angle_max=float(np.float32(math.pi / 2)),
        angle_increment=float(increment), time_increment=time_increment, scan_time=0.04, range_min=0.05,
        range_max=SICK_RANGE_MAX, ranges=np.ascontiguousarray(ranges[::-1] if mirrored else ranges, np.float32),
        intensities=np.zeros(0, np.float32))


def transform_message(t, parent, child, x, y, yaw, roll=0.0, pitch=0.0):
    """A ``geometry_msgs/TransformStamped`` of a pose turned by ``roll``, ``pitch`` then ``yaw`` (ZYX)."""
    cr, sr, cp, sp = math.cos(roll / 2), math.sin(roll / 2), math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    rotation = T["geometry_msgs/msg/Quaternion"](x=sr * cp * cy - cr * sp * sy, y=cr * sp * cy + sr * cp * sy,
                                                 z=cr * cp * sy - sr * sp * cy, w=cr * cp * cy + sr * sp * sy)
    return T["geometry_msgs/msg/TransformStamped"](
        header=_header(t, parent), child_frame_id=child,
        transform=T["geometry_msgs/msg/Transform"](translation=T["geometry_msgs/msg/Vector3"](x=x, y=y, z=0.3),
                                                   rotation=rotation))


def tf_message(*transforms):
    return T["tf2_msgs/msg/TFMessage"](transforms=list(transforms))


def sick_bag(path, world, drive, scan_times, tf_times, mirrored=False, no_echo=NO_ECHO, time_increment=0.0,
             group=1, version=2):
    """A bag of the drive: ``/tf_static`` base_link -> laser (upright, or rolled by pi: ``mirrored``), ``/tf``
    map -> base_link at ``tf_times``, the SICK's scans at ``scan_times`` (no echo read as ``no_echo``: the code,
    or NaN for a bag with those readings removed). Returns the bag and the wall cells the scans hit."""
    items = [("/tf_static", T0, tf_message(transform_message(T0, "base_link", "laser", 0.0, 0.0, 0.0,
                                                              roll=math.pi if mirrored else 0.0)))]
    events = [(t, "/tf") for t in tf_times] + [(t, "/scan") for t in scan_times]
    seen = np.zeros(world.grid.shape, bool)
    for t, topic in sorted(events):
        if topic == "/tf":
            items.append(("/tf", t, tf_message(transform_message(t, "map", "base_link", *drive.pose(t)))))
            continue
        ranges, hit = sick_ranges(world, drive, t, time_increment, group)
        seen |= hit
        ranges[ranges == NO_ECHO] = no_echo
        items.append(("/scan", t, sick_message(t, ranges, mirrored=mirrored, time_increment=time_increment)))
    return _write_items(path, items, version=version), seen


def map_in_floor(out, world) -> np.ndarray:
    """``superex offline``'s map (``OUT/map.npz``) pasted into the floor's grid (int8, -1 where it holds nothing)."""
    saved = np.load(out / "map.npz")
    observed, (x0, y0), resolution = saved["observed"], saved["origin_xy"], float(saved["resolution_m"])
    assert resolution == pytest.approx(world.grid.resolution_m)
    rows, cols = world.grid.shape
    col0 = int(round(x0 / resolution))
    row0 = rows - observed.shape[0] - int(round(y0 / resolution))
    placed = np.full((rows, cols), -1, np.int8)
    r = np.arange(observed.shape[0]) + row0
    c = np.arange(observed.shape[1]) + col0
    keep_r, keep_c = (r >= 0) & (r < rows), (c >= 0) & (c < cols)
    placed[np.ix_(r[keep_r], c[keep_c])] = observed[np.ix_(keep_r, keep_c)]
    return placed


def walls_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Wall IoU of two maps (or a map and a bool wall mask) within a cell."""
    a = a if a.dtype == bool else a == 1
    b = b if b.dtype == bool else b == 1
    return wall_iou_tolerant(a, b, WITHIN_A_CELL)


def offline(bag, out, *options) -> int:
    return main(["offline", str(bag), "--out", str(out), "--finish-after", "1000", *options])


@pytest.mark.slow
def test_a_sick_log_as_logged_maps_the_floor_as_the_log_without_its_no_echo_readings(tmp_path):
    # The acceptance test: no echo coded above range_max (81.83 m of a SICK LMS), /tf at 20 Hz with the scans at
    # another phase, and the same drive with a scanner mounted upside down: all give the map of the same drive with
    # /tf at every scan's stamp (measured: wall IoU within a cell 1.000 for each; on the reader before, the
    # rolled scanner's map scored 0.124 and the 20 Hz /tf's 0.990).
    world = sick_world()
    drive = Drive(floor_path(world, 30.0, clearance_m=0.4))
    scans = T0 + 0.013 + np.arange(0.0, drive.duration - 0.05, 0.1)  # 10 Hz, between the /tf samples
    tf = T0 + np.arange(0.0, drive.duration + 0.05, 0.05)  # 20 Hz
    logged, seen = sick_bag(tmp_path / "logged", world, drive, scans, tf)
    cleaned, _ = sick_bag(tmp_path / "cleaned", world, drive, scans, tf, no_echo=float("nan"))
    rolled, _ = sick_bag(tmp_path / "rolled", world, drive, scans, tf, mirrored=True)
    exact, _ = sick_bag(tmp_path / "exact", world, drive, scans, scans)  # /tf at every scan's stamp
    maps = {}
    for name, bag in (("logged", logged), ("cleaned", cleaned), ("rolled", rolled), ("exact", exact)):
        assert offline(bag, tmp_path / name) == 0
        maps[name] = map_in_floor(tmp_path / name, world)
    # The log holds what made the maps go wrong: readings without an echo (through the windows, and lost returns).
    from superex_deploy.recording.bags import read_bag

    _, observations = read_bag(logged)
    assert sum(np.count_nonzero(o.scan.ranges == np.float32(NO_ECHO)) for o in observations) > 5000
    truth = walls_iou(maps["exact"], seen)  # measured 0.999
    assert truth > 0.98, f"the exact poses' map against the walls the scans hit: {truth:.3f}"
    for name in ("cleaned", "rolled", "logged"):
        iou = walls_iou(maps[name], maps["exact"])
        assert iou >= 0.99, f"{name}: wall IoU within a cell against the exact poses' map {iou:.4f}"
    assert walls_iou(maps["logged"], maps["cleaned"]) >= 0.99
    assert walls_iou(maps["rolled"], maps["logged"]) >= 0.99


class Spin:
    """A robot turning in place at ``rate`` rad/s at ``(x, y)`` from stamp ``T0`` for ``duration`` seconds."""

    def __init__(self, x: float, y: float, rate: float, duration: float):
        self.x, self.y, self.rate, self.duration = x, y, rate, duration

    def pose(self, t: float) -> tuple[float, float, float]:
        return self.x, self.y, self.rate * (t - T0)


@pytest.mark.slow
@pytest.mark.parametrize("motion", ["drive", "spin"])
def test_deskew_measured_on_a_turning_robot(tmp_path, motion):
    # A 10 Hz SICK (its 361 rays take 50 ms: time_increment 0.1 s / 720) on a robot turning through its corners
    # at up to 1.1 rad/s, or spinning in place at 1 rad/s: the wall IoU within a cell of the map against the walls
    # the rays hit, with and without --deskew. Measured: drive 0.964 as logged, 0.999 de-skewed; spin 0.895 and
    # 1.000 (docs of superex_deploy.recording.bag_poses). At 25 Hz the skew is 2.5 times smaller and both maps
    # score alike (0.9996 driving).
    world = sick_world()
    if motion == "drive":
        drive = Drive(floor_path(world, 30.0, clearance_m=0.4), speed=1.0, turn_m=0.5)
    else:
        drive = Spin(*world.frame.centre_xy((190, 60)), rate=1.0, duration=2 * math.pi)
    scans = T0 + 0.013 + np.arange(0.0, drive.duration - 0.1, 0.1)
    tf = T0 + np.arange(0.0, drive.duration + 0.05, 0.05)
    bag, seen = sick_bag(tmp_path / "turning", world, drive, scans, tf, time_increment=0.1 / 720, group=4)
    iou = {}
    for name, options in (("as logged", []), ("deskewed", ["--deskew"])):
        assert offline(bag, tmp_path / name, *options) == 0
        iou[name] = walls_iou(map_in_floor(tmp_path / name, world), seen)
    print(motion, {name: round(value, 4) for name, value in iou.items()})
    assert iou["deskewed"] >= 0.99 and iou["as logged"] <= iou["deskewed"] - 0.02, iou
