"""Issue #23, the rows of the hostile pass: every bad input gets one clear error where it enters, never a silent
wrong result, a crash deep inside, or a warning."""


import math
import threading
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from superex_deploy.messages import LaserScan, MapFrame, Observation, Pose2D
from superex_deploy.onboard import Explorer
from superex_deploy.onboard.mapper import Mapper
from superex_deploy.onboard.planners import make_planner
from superex_deploy.onboard.prediction import ObservedAsPrediction
from superex_deploy.onboard.types import Planner

FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
ANY_FLOAT = st.floats(allow_nan=True, allow_infinity=True, width=64)
RAYS = 72
INCREMENT = 2 * math.pi / RAYS


def _scan(ranges, range_min=0.1, range_max=5.0) -> LaserScan:
    return LaserScan(0.0, INCREMENT, range_min, range_max, np.asarray(ranges, np.float64))


def _observation(ranges, stamp=0.0, pose=Pose2D(10.0, 10.0)) -> Observation:
    return Observation(stamp, pose, _scan(ranges))


# Row 1: a scan with no valid reading leaves the map untouched and never reports `finished`.

INVALID = st.one_of(st.just(math.nan), st.just(-math.inf), st.floats(-1e300, 0.0999, allow_nan=False))


@FUZZ
@given(ranges=st.lists(INVALID, min_size=RAYS, max_size=RAYS))
@example(ranges=[math.nan] * RAYS)
@example(ranges=[-math.inf] * RAYS)
@example(ranges=[0.05] * RAYS)
def test_a_scan_without_valid_readings_changes_nothing_and_is_not_finished(ranges):
    explorer = Explorer(MapFrame((200, 200), 0.1), make_planner("nearest"), ObservedAsPrediction())
    for step in range(3):
        command = explorer.step(_observation(ranges, stamp=float(step)))
        assert not command.finished and command.goal_rc is None and command.step == step
        assert not explorer.mapper.known().any()
    # The loop of the README goes on; the first valid scan (no return on any ray: free up to 5 m) gives a goal.
    command = explorer.step(_observation(np.full(RAYS, np.inf), stamp=3.0))
    assert command.goal_rc is not None and not command.finished and explorer.mapper.known().any()


def test_finished_means_a_known_map_without_a_reachable_frontier():
    # A 2 m square frame seen whole by one dense scan of no returns: everything is known free, nothing is left.
    explorer = Explorer(MapFrame((20, 20), 0.1), make_planner("nearest"), ObservedAsPrediction())
    scan = LaserScan(0.0, 2 * math.pi / 1440, 0.1, 20.0, np.full(1440, np.inf, np.float32))
    command = explorer.step(Observation(0.0, Pose2D(1.0, 1.0), scan))
    assert command.finished and command.goal_rc is None and explorer.mapper.known().all()


@FUZZ
@given(value=ANY_FLOAT)
@example(value=1e300)
@example(value=-1e300)
@example(value=3.4e38)
def test_every_range_is_a_return_no_return_or_skipped_without_warnings(value):
    """REP 117: [range_min, range_max] a return; +inf or above range_max no return (free up to range_max); NaN,
    -inf or below range_min invalid (skipped). float64 ranges beyond float32 become +-inf, without a warning."""
    frame, pose = MapFrame((120, 120), 0.1), Pose2D(6.0, 6.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scan = _scan(np.full(RAYS, value), range_min=0.1, range_max=5.0)
        mapper = Mapper(frame.shape)
        mapper.integrate_scan(frame, pose, scan)
    stored = float(scan.ranges[0])
    if math.isnan(stored) or stored < scan.range_min:
        assert not mapper.known().any()
        return
    returned = stored <= scan.range_max
    equivalent = Mapper(frame.shape)
    equivalent.integrate_scan(frame, pose, _scan(np.full(RAYS, stored if returned else np.inf)))
    assert np.array_equal(mapper.known(), equivalent.known()) and mapper.known().any()
    assert mapper.seen_wall.any() == returned


# Row 12: one caller at a time.

class _BlockingPlanner(Planner):
    """The nearest-frontier choice, held inside the step until the test lets it go."""

    name = "blocking"

    def __init__(self):
        self.entered, self.release = threading.Event(), threading.Event()

    def choose_goal(self, ctx):
        self.entered.set()
        assert self.release.wait(30), "the test never released the step"
        return make_planner("nearest").choose_goal(ctx)


def test_a_second_concurrent_step_raises_instead_of_repeating_a_step_number():
    planner = _BlockingPlanner()
    explorer = Explorer(MapFrame((200, 200), 0.1), planner, ObservedAsPrediction())
    results: list = []
    first = threading.Thread(target=lambda: results.append(explorer.step(_observation(np.full(RAYS, np.inf)))))
    first.start()
    try:
        assert planner.entered.wait(60)  # the first step is inside the planner now
        with pytest.raises(RuntimeError, match="one caller at a time"):
            explorer.step(_observation(np.full(RAYS, np.inf), stamp=1.0))
    finally:
        planner.release.set()
        first.join(60)
    assert [c.step for c in results] == [0] and explorer.steps == 1
    assert explorer.step(_observation(np.full(RAYS, np.inf), stamp=2.0)).step == 1  # the lock was released


def test_a_step_that_raises_releases_the_lock():
    explorer = Explorer(MapFrame((200, 200), 0.1), make_planner("nearest"), ObservedAsPrediction())
    with pytest.raises(ValueError, match="outside the map"):
        explorer.step(_observation(np.full(RAYS, np.inf), pose=Pose2D(100.0, 100.0)))
    assert explorer.step(_observation(np.full(RAYS, np.inf))).step == 0


# Rows 3, 4, 5: planner options are checked when the planner is built.

@pytest.mark.parametrize("planner, field, value", [
    ("mapex", "visibility", 3), ("hector", "visibility", "none"), ("upen", "rrt_samples", math.inf),
    ("superex", "n_rays", math.inf), ("hector", "wall_threshold", -3), ("hector", "wall_threshold", math.nan),
    ("hector", "wall_threshold", "x"), ("mapex", "min_distance_cells", math.inf),
    ("upen", "min_goal_distance_m", math.inf), ("upen", "rrt_samples", 10 ** 400), ("upen", "expand_cells", "x"),
    ("hector", "info_gain_weight", None), ("superex", "rollout_cell_m", 1e12), ("superex", "gain", ["path"]),
    ("mapex", "distance", 3), ("superex", "candidates", True), ("upen", "reach_horizon", 2.5),
])
def test_a_bad_planner_option_is_refused_when_the_planner_is_built(planner, field, value):
    with pytest.raises(ValueError, match=f"bad configuration for planner '{planner}': {field}"):
        make_planner(planner, **{field: value})


NUMERIC_FIELDS = [("hector", "info_gain_weight"), ("hector", "wall_threshold"), ("mapex", "min_distance_cells"),
                  ("upen", "rrt_samples"), ("upen", "expand_cells"), ("upen", "reach_horizon"),
                  ("upen", "min_goal_distance_m"), ("superex", "wall_threshold"), ("superex", "sense_every_m"),
                  ("superex", "range_m"), ("superex", "n_rays"), ("superex", "drop_resolved_m"),
                  ("superex", "candidates"), ("superex", "rollout_goals"), ("superex", "horizon_m"),
                  ("superex", "rollout_cell_m"), ("superex", "rollout_frontier_cells"), ("superex", "tour_frontiers")]
OPTION_VALUE = st.one_of(ANY_FLOAT, st.integers(-10 ** 20, 10 ** 20), st.booleans(), st.none(), st.text(max_size=5),
                         st.lists(st.integers(), max_size=2))


@FUZZ
@given(case=st.sampled_from(NUMERIC_FIELDS), value=OPTION_VALUE)
def test_numeric_planner_options_are_finite_numbers_of_their_type_or_refused(case, value):
    planner_name, field = case
    try:
        planner = make_planner(planner_name, **{field: value})
    except ValueError as error:
        assert field in str(error)
        return
    stored = getattr(planner.cfg, field)
    if stored is None:
        assert field == "drop_resolved_m" and value is None
        return
    assert type(stored) in (int, float) and math.isfinite(stored) and float(stored) == float(value)


@pytest.mark.parametrize("text", ["x", "nan", "inf", "-inf", "none", "1e400"])
@pytest.mark.parametrize("planner, field", [("hector", "wall_threshold"), ("mapex", "min_distance_cells"),
                                            ("upen", "rrt_samples"), ("superex", "n_rays"),
                                            ("mapex", "visibility")])
def test_command_line_option_strings_give_one_clear_error(planner, field, text):
    from superex_deploy.commands.explore import planner_options

    with pytest.raises(ValueError, match=f"{field} must"):
        make_planner(planner, **planner_options([f"{field}={text}"]))


def test_a_planner_refuses_a_config_of_another_planner():
    from superex_deploy.onboard.planners import MapexConfig, UpenPlanner

    with pytest.raises(ValueError, match="cfg must be a UpenConfig"):
        UpenPlanner(MapexConfig())
