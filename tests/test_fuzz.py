"""Random bad input at the package's edges: only the documented ValueError, never a crash, hang or NaN."""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from superex_deploy.geometry import cast_rays, line_of_sight, mark_ranges
from superex_deploy.maps import OccupancyGrid, load_map
from superex_deploy.messages import LaserScan, MapFrame, Pose2D
from superex_deploy.recording import read_recording

FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
ANY_FLOAT = st.floats(allow_nan=True, allow_infinity=True, width=64)
YAML_VALUE = st.one_of(st.none(), st.booleans(), st.integers(-10, 10), ANY_FLOAT, st.text(max_size=8),
                       st.lists(st.integers(), max_size=2), st.dictionaries(st.text(max_size=3), st.integers(),
                                                                             max_size=2))


@FUZZ
@given(data=st.binary(max_size=400), suffix=st.sampled_from([".png", ".pgm", ".yaml", ".jpg", ".bmp"]))
def test_the_map_loader_refuses_random_bytes_with_a_value_error(tmp_path, data, suffix):
    path = tmp_path / f"map{suffix}"
    path.write_bytes(data)
    try:
        grid = load_map(path)
    except ValueError:
        return
    assert isinstance(grid, OccupancyGrid) and grid.occupied.dtype == np.bool_


@FUZZ
@given(resolution=YAML_VALUE, threshold=YAML_VALUE, negate=YAML_VALUE, image=st.sampled_from(["ok.png", "none.png"]))
@example(resolution=0.1, threshold=0.5, negate=[1], image="ok.png")
@example(resolution=0.1, threshold=0.5, negate="yes", image="ok.png")
@example(resolution=0.1, threshold=0.5, negate={"a": 1}, image="ok.png")
@example(resolution="0.1", threshold=None, negate=None, image="ok.png")
def test_ros_yaml_fields_of_any_type_give_a_value_error_or_a_grid(tmp_path, resolution, threshold, negate, image):
    import yaml
    from PIL import Image

    Image.fromarray(np.full((4, 5), 255, np.uint8)).save(tmp_path / "ok.png")
    spec = {"image": image, "resolution": resolution, "occupied_thresh": threshold, "negate": negate}
    (tmp_path / "map.yaml").write_text(yaml.safe_dump(spec))
    try:
        grid = load_map(tmp_path / "map.yaml")
    except ValueError:
        return
    assert grid.resolution_m > 0 and math.isfinite(grid.resolution_m) and grid.shape == (4, 5)


@FUZZ
@given(shape=st.tuples(st.integers(1, 12), st.integers(1, 12)), y=ANY_FLOAT, x=ANY_FLOAT,
       angles=st.lists(ANY_FLOAT, min_size=0, max_size=6), max_range=ANY_FLOAT, seed=st.integers(0, 2 ** 16))
def test_the_ray_kernels_take_any_origin_angles_and_range(shape, y, x, angles, max_range, seed):
    occupied = np.random.default_rng(seed).random(shape) < 0.3
    try:
        hits = cast_rays(occupied, (y, x), angles, max_range)
    except ValueError:
        return
    assert np.all(np.isfinite(hits.distance_cells)) and np.all(hits.distance_cells >= 0)
    assert np.all(hits.distance_cells <= max_range + 1e-9)
    ranges = np.where(hits.hit_mask, hits.distance_cells, np.inf)
    free, hit = np.zeros(shape, bool), np.zeros(shape, bool)
    mark_ranges((y, x), angles, ranges, max_range, free, hit)
    assert not np.any(hit & occupied ^ hit)  # every return lies on a wall


@FUZZ
@given(shape=st.tuples(st.integers(1, 10), st.integers(1, 10)),
       a=st.tuples(st.integers(-3, 12), st.integers(-3, 12)), b=st.tuples(st.integers(-3, 12), st.integers(-3, 12)))
def test_line_of_sight_takes_any_cells(shape, a, b):
    blocked = np.zeros(shape, bool)
    try:
        seen = line_of_sight(blocked, a, b)
    except ValueError:
        return
    assert seen  # nothing blocks in an empty grid


@FUZZ
@given(angle_min=ANY_FLOAT, increment=ANY_FLOAT, range_min=ANY_FLOAT, range_max=ANY_FLOAT,
       ranges=st.lists(ANY_FLOAT, min_size=0, max_size=5), x=ANY_FLOAT, y=ANY_FLOAT)
def test_scan_and_pose_messages_take_any_numbers(angle_min, increment, range_min, range_max, ranges, x, y):
    try:
        scan = LaserScan(angle_min, increment, range_min, range_max, np.asarray(ranges, np.float64))
        pose = Pose2D(x, y, 0.0)
    except ValueError:
        return
    assert scan.angle_increment > 0 and np.all(np.isfinite(scan.angles()))
    assert math.isfinite(pose.x) and math.isfinite(pose.y)
    frame = MapFrame((5, 5), 0.1)
    from superex_deploy.onboard.mapping.mapper import Mapper

    try:
        Mapper(frame.shape).integrate_scan(frame, pose, scan)
    except ValueError:
        pass


@FUZZ
@given(data=st.binary(max_size=600))
def test_a_recording_of_random_bytes_is_refused(tmp_path, data):
    path = tmp_path / "x.mcap"
    path.write_bytes(b"\x89MCAP0\r\n" + data)
    with pytest.raises(ValueError):
        read_recording(path)
