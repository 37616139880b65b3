"""Exploration episodes in the simulator (superex_deploy.evaluation.episodes): whole episodes on hand-built and
bundled maps, their determinism, the goal tiers, the IoU log and the checks of their inputs."""

import json

import numpy as np
import pytest

from superex_deploy.maps import OccupancyGrid, load_map, start_poses
from superex_deploy.messages import SpadFrame
from superex_deploy.onboard import SpadProcessing
from superex_deploy.onboard.nlos import NlosConfig
from superex_deploy.onboard.explorer import ExplorerConfig
from superex_deploy.onboard.planning.frontiers import find_frontiers
from superex_deploy.onboard.planning.goal_choice import choose_goal as _choose
from superex_deploy.onboard.planning.goal_choice import goal_reached as _reached
from superex_deploy.onboard.planning.goal_choice import near_visited_goal as _near_visited
from superex_deploy.onboard.planning.motion import MotionConfig
from superex_deploy.onboard.planning.planners import MapexPlanner, NearestFrontier, make_planner
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.onboard.types import FREE, OCCUPIED, Planner, Prediction
from superex_deploy.evaluation.episodes import STAGES, run_episode
from superex_deploy.sim.exploration import ExplorationConfig
from superex_deploy.evaluation.summary import summary_table
from superex_deploy.sim.oracle import OraclePredictor
from superex_deploy.sim.sensing import SpadSensing
from superex_deploy.spad_types import SpadConfig

_SMALL_SPAD = SpadConfig(n_rays=100, range_m=3.0)


class _Closest(Planner):
    """The frontier with the lowest cost-to-go (the engine's tests do not depend on planners.py)."""

    name = "closest"

    def choose_goal(self, ctx):
        reachable = [f for f in ctx.frontiers if np.isfinite(ctx.travel_cost[f.cell_rc])]
        if not reachable:
            return None
        return min(reachable, key=lambda f: (ctx.travel_cost[f.cell_rc], f.cell_rc)).cell_rc


class _AsksForPrediction(_Closest):
    name = "asks"

    def choose_goal(self, ctx):
        assert ctx.predict() is ctx.predict()  # cached within a step
        return super().choose_goal(ctx)


class _CountingPredictor:
    """Unknown cells predicted free; records every call and the evidence it was given."""

    name = "counting"

    def __init__(self):
        self.calls = 0
        self.extras = []

    def predict(self, observed, extra=None):
        self.calls += 1
        self.extras.append(extra)
        mean = (observed == OCCUPIED).astype(np.float32)
        return Prediction(mean=mean, variance=np.zeros_like(mean))


class _CarveRightRoom(SpadProcessing):
    """A stand-in for the onboard SPAD processing: reveals a 5 x 5 block of the hidden room from the first step on."""

    def __init__(self, shape):
        super().__init__(sensor=_SMALL_SPAD, nlos_cfg=NlosConfig(normals_from_map=True))  # asks for the map's walls
        self.carved = np.zeros(shape, bool)
        self.carved[5:10, 30:35] = True
        self.fixed_evidence = np.full(shape, 0.25, np.float32)
        self.calls = 0

    def __call__(self, frame, map_frame, pose, known, pose_covariance=None, map_walls=None):
        self.calls += 1
        assert isinstance(frame, SpadFrame) and known.dtype == np.bool_ and known.shape == map_frame.shape
        # The explorer hands over its map's walls (they support the carving's normals): walls it knows.
        assert map_walls.dtype == np.bool_ and map_walls.shape == map_frame.shape and not np.any(map_walls & ~known)
        assert map_walls.any()
        self._evidence = self.fixed_evidence
        return self.carved, self._evidence


class _SensingWith(SpadSensing):
    """SPAD sensing whose onboard processing is the given stand-in (the world still simulates real frames)."""

    def __init__(self, processing):
        super().__init__(spad=_SMALL_SPAD)
        self.stand_in = processing

    def processing(self):
        self._processing = self.stand_in
        return self.stand_in


def test_two_rooms_are_explored_completely(two_rooms):
    grid = two_rooms()
    result = run_episode(grid, (5, 5), _Closest(), _CountingPredictor(), steps=300, seed=0)
    assert result.finished and result.steps < 300
    # It stops when no frontier is left at all: the small pockets beside the door were visited too.
    assert find_frontiers(result.final_observed, min_cells=1) == () and result.coverage[-1] > 0.98
    assert np.all(np.diff(result.coverage) >= 0)
    assert result.poses[:, 1].max() >= 20  # drove into the door
    assert not grid.occupied[result.poses[:, 0], result.poses[:, 1]].any()
    steps = np.diff(result.poses, axis=0)
    assert np.abs(steps).max() <= 3  # at most step_m = 0.3 m, 3 cells, per step
    driven = np.diff(result.path_length_m)  # along the 8-connected path: at least the displacement
    assert np.all(driven >= 0.1 * np.hypot(steps[:, 0], steps[:, 1]) - 1e-9)
    assert np.all(driven <= 0.3 * np.sqrt(2) + 1e-9)
    assert result.path_length_m[0] == 0.0


def test_a_door_seen_edge_on_is_followed_though_its_frontier_is_small():
    """A room whose only exit, a 0.6 m door in its bottom wall far from the robot, shows fewer frontier cells
    than the minimum region size at the first scan (a corridor runs right behind it): the small regions are the
    fallback, so the robot goes through instead of stopping (2 of the 40 benchmark scenarios did)."""
    walls = np.zeros((50, 70), bool)
    walls[[0, -1], :] = walls[:, [0, -1]] = True
    walls[30, :] = True
    walls[30, 30:36] = False  # the door
    walls[39:, :] = True  # the corridor behind it: rows 31-38
    walls[:30, 40] = True
    grid = OccupancyGrid(walls, ~walls, 0.1, "edge-on door")
    first = {}

    def on_step(state):
        first.setdefault("observed", state.observed.copy())

    result = run_episode(grid, (3, 3), _Closest(), _CountingPredictor(), steps=300, seed=0, on_step=on_step)
    assert find_frontiers(first["observed"], min_cells=10) == ()  # only small regions at the first scan
    assert len(find_frontiers(first["observed"], min_cells=1)) > 0
    assert result.poses[:, 0].max() > 30  # through the door
    assert result.coverage[-1] > result.coverage[0] + 0.15
    assert result.finished and find_frontiers(result.final_observed, min_cells=1) == ()
    # With the minimum at one cell there is no fallback to make: the same episode.
    same = run_episode(grid, (3, 3), _Closest(), _CountingPredictor(), steps=300, seed=0,
                       cfg=ExplorationConfig(explorer=ExplorerConfig(frontier_min_m=0.1)))
    assert same.poses[:, 0].max() > 30


def test_the_onboard_nlos_processing_feeds_carving_and_evidence(two_rooms):
    grid = two_rooms()
    hook = _CarveRightRoom(grid.shape)
    predictor = _CountingPredictor()
    result = run_episode(grid, (5, 5), _AsksForPrediction(), predictor, steps=40, seed=0, sensing=_SensingWith(hook),
                         cfg=ExplorationConfig(iou_every=0))
    assert hook.calls == result.steps
    assert np.all(result.coverage_with_carving >= result.coverage)
    extra = 25 / grid.valid.sum()
    assert result.coverage_with_carving[0] == pytest.approx(result.coverage[0] + extra)
    assert result.final_carved[5:10, 30:35].all() and result.final_observed[7, 32] == FREE
    assert all(e is hook.evidence for e in predictor.extras) and predictor.calls > 0
    # Computed once per step at most (the planner asks twice), and only on steps where a goal was chosen.
    asked = np.flatnonzero(result.timings_s["prediction"] > 0)
    assert predictor.calls == len(asked) and set(result.goal_steps) <= set(asked.tolist())


def test_predictions_are_lazy_and_iou_is_logged_every_k_steps(two_rooms):
    grid = two_rooms()
    predictor = _CountingPredictor()
    result = run_episode(grid, (5, 5), _Closest(), predictor, steps=60, seed=0, cfg=ExplorationConfig(iou_every=0))
    assert predictor.calls == 0 and result.iou == [] and result.final_prediction is None
    predictor = _CountingPredictor()
    result = run_episode(grid, (5, 5), _Closest(), predictor, steps=60, seed=0, cfg=ExplorationConfig(iou_every=10))
    expected_steps = sorted(set(range(0, result.steps, 10)) | {result.steps - 1})
    assert result.iou_steps == expected_steps and predictor.calls == len(expected_steps)
    assert all(0.0 <= v <= 1.0 for v in result.iou)
    assert result.iou_coverage == [pytest.approx(result.coverage_with_carving[t]) for t in expected_steps]
    assert result.iou[-1] > result.iou[0]  # observed walls are predicted walls: IoU grows with coverage


def test_on_step_sees_every_step_and_the_log_is_json_ready(two_rooms):
    grid = two_rooms()
    seen = []
    result = run_episode(grid, (5, 5), _Closest(), _CountingPredictor(), steps=25,
                         on_step=lambda state: seen.append((state.step, state.pose, state.coverage)))
    assert [s for s, _, _ in seen] == list(range(result.steps))
    assert [p for _, p, _ in seen] == [tuple(p) for p in result.poses.tolist()]
    assert [c for _, _, c in seen] == result.coverage.tolist()
    log = json.loads(json.dumps(result.to_json()))
    assert set(log["timings_s"]) == set(STAGES) and all(len(v) == result.steps for v in log["timings_s"].values())
    assert log["steps"] == result.steps == len(log["coverage"]) == len(log["path_length_m"])
    assert log["config"]["explorer"]["motion"]["step_m"] == 0.3 and log["config"]["lidar"]["n_rays"] == 2500


def test_episodes_are_deterministic_on_a_bundled_map():
    grid = load_map("50052750")
    start = start_poses("50052750")[3]
    a, b = (run_episode(grid, start, _Closest(), _CountingPredictor(), steps=60, seed=7) for _ in range(2))
    np.testing.assert_array_equal(a.poses, b.poses)
    np.testing.assert_array_equal(a.coverage, b.coverage)
    assert a.goals == b.goals and a.iou == b.iou


def test_the_episode_builds_its_explorer_with_build_explorer_and_its_checks(two_rooms):
    """An evidence predictor without SPAD sensing is refused by pipeline.build_explorer, which builds the episode's
    explorer; the planner and predictor objects are the explorer's, as given."""
    grid = two_rooms()

    class _ReadsEvidence(_CountingPredictor):
        name = "evidence"

    with pytest.raises(ValueError, match="reads the SPAD evidence"):
        run_episode(grid, (5, 5), _Closest(), _ReadsEvidence(), steps=2)
    planner, predictor = _Closest(), _CountingPredictor()
    seen = []
    run_episode(grid, (5, 5), planner, predictor, steps=2, on_observation=lambda o, c, e: seen.append(e))
    assert seen[0].planner is planner and seen[0].predictor is predictor


def test_bad_inputs_raise_value_error(two_rooms):
    grid = two_rooms()
    planner, predictor = _Closest(), _CountingPredictor()
    with pytest.raises(ValueError, match="inside a wall"):
        run_episode(grid, (0, 0), planner, predictor)
    with pytest.raises(ValueError, match="outside"):
        run_episode(grid, (30, 5), planner, predictor)
    with pytest.raises(ValueError, match="OccupancyGrid"):
        run_episode(grid.occupied, (5, 5), planner, predictor)
    with pytest.raises(ValueError, match="Planner"):
        run_episode(grid, (5, 5), "nearest", predictor)
    with pytest.raises(ValueError, match="predict"):
        run_episode(grid, (5, 5), planner, object())
    with pytest.raises(ValueError, match="steps"):
        run_episode(grid, (5, 5), planner, predictor, steps=2.5)
    with pytest.raises(ValueError, match="sensing must be a SpadSensing"):
        run_episode(grid, (5, 5), planner, predictor, sensing="spad")
    with pytest.raises(ValueError, match="sensing must be a SpadSensing"):
        run_episode(grid, (5, 5), planner, predictor, sensing=lambda g, p, o: (np.zeros((3, 3), bool), None))
    with pytest.raises(ValueError, match="frontier_min_m must be positive"):
        ExplorerConfig(frontier_min_m=0)


def _two_side_rooms():
    """A 2.5 m square: a corridor on the left (cols 1-8) and two rooms on the right whose doors open from it,
    each door flanked by a two-cell-thick jamb. The rooms' far corners lie within 1 m of corridor cells from
    which the jamb hides them: the geometry of eval map 50010539, where every planner used to shuttle between
    two such corners for 900 steps (a frontier counted as reached by distance alone)."""
    walls = np.zeros((25, 25), bool)
    walls[[0, -1], :] = walls[:, [0, -1]] = True
    walls[1:7, 9:11] = True  # thick jamb above room A's door
    walls[11:14, 9:] = True  # the wall between the rooms
    walls[18:24, 9:11] = True  # thick jamb below room B's door
    return OccupancyGrid(walls, ~walls, 0.1, "two side rooms")


def test_a_frontier_hidden_behind_a_door_jamb_is_not_reached_from_the_corridor():
    grid = _two_side_rooms()
    result = run_episode(grid, (12, 3), _Closest(), _CountingPredictor(), steps=300, seed=0,
                         cfg=ExplorationConfig(iou_every=0))
    assert result.finished and result.steps < 40
    assert result.coverage[-1] == 1.0
    assert len(set(result.goals)) == len(result.goals)  # no goal chosen twice
    # A goal cell within the tolerance but behind the jamb does not count as reached; seen, it does.
    not_free = result.final_observed != FREE
    assert np.hypot(3 - 9, 11 - 4) < 10.0 and not _reached(not_free, (9, 4), (3, 11), reach_cells=10.0)
    assert _reached(not_free, (12, 3), (12, 8), reach_cells=10.0)
    assert not _reached(not_free, (12, 3), (12, 20), reach_cells=10.0)  # in sight but too far


def test_goal_tiers_skip_visited_goals_and_fall_back_on_close_ones():
    """_choose offers far regions first, never a region whose goal cell was reached before, and, when only
    regions in sight within the tolerance are left, one of those with tolerance 0 (drive onto it)."""
    observed = np.full((20, 40), -1, np.int8)
    observed[7:14, 2:38] = OCCUPIED
    observed[8:13, 2:38] = FREE  # a known corridor, open (unknown) at both ends
    frontiers = find_frontiers(observed, 3)
    assert sorted(f.cell_rc for f in frontiers) == [(10, 2), (10, 37)]
    offered = []

    def offer(regions):
        offered.append({f.cell_rc for f in regions})
        return regions[0].cell_rc if regions else None

    not_free = observed != FREE
    pose = (10, 8)  # the left end is in sight 0.6 m away, the right end 2.9 m away
    assert _choose(offer, observed, frontiers, 3, not_free, pose, 10.0, set()) == ((10, 37), 10.0)
    assert offered == [{(10, 37)}]
    # The far end visited before (or a neighbour of its goal cell): only the close end is left, to be driven onto.
    offered.clear()
    assert _choose(offer, observed, frontiers, 3, not_free, pose, 10.0, {(9, 36)}) == ((10, 2), 0.0)
    assert offered == [set(), {(10, 2)}]
    # Both visited: nothing is left, the episode ends.
    offered.clear()
    assert _choose(offer, observed, frontiers, 3, not_free, pose, 10.0, {(9, 36), (10, 2)}) == (None, 0.0)
    assert _near_visited((3, 3), {(4, 4)}) and not _near_visited((3, 3), {(5, 4)})


def test_iou_is_evaluated_densely_only_below_the_coverage_threshold():
    grid = load_map("50052750")
    start = start_poses("50052750")[0]
    dense = run_episode(grid, start, _Closest(), _CountingPredictor(), steps=45, seed=0,
                        cfg=ExplorationConfig(iou_every=2))
    assert dense.steps == 45 and dense.iou_steps == list(range(0, 45, 2))  # 44: the last step, too
    # Above the threshold (here from the first step on) only every 10 * iou_every steps, and at the last step.
    sparse = run_episode(grid, start, _Closest(), _CountingPredictor(), steps=45, seed=0,
                         cfg=ExplorationConfig(iou_every=2, iou_dense_until=0.0))
    assert sparse.iou_steps == [0, 20, 40, 44]
    # Below a threshold the coverage passes at step k, densely up to k and sparsely after.
    threshold = float(dense.coverage_with_carving[10])
    mixed = run_episode(grid, start, _Closest(), _CountingPredictor(), steps=45, seed=0,
                        cfg=ExplorationConfig(iou_every=2, iou_dense_until=threshold))
    passed = int(np.argmax(dense.coverage_with_carving > threshold))
    assert [s for s in mixed.iou_steps if s < passed] == list(range(0, passed, 2))
    assert all(s % 20 == 0 for s in mixed.iou_steps[:-1] if s >= passed)


@pytest.mark.parametrize("value", [-1, 2.5, True])
def test_the_episode_config_refuses_a_bad_iou_interval(value):
    from superex_deploy.sim.exploration import ExplorationConfig

    with pytest.raises(ValueError, match="iou_every must be an integer >= 0"):
        ExplorationConfig(iou_every=value)


@pytest.fixture(scope="module")
def small_map():
    return load_map("50052750")


def test_episode_coverage_never_decreases_and_is_deterministic(small_map):
    start = start_poses("50052750")[1]
    runs = [run_episode(small_map, start, make_planner("nearest"), ObservedAsPrediction(), steps=80, seed=3)
            for _ in range(2)]
    a, b = runs
    assert np.all(np.diff(a.coverage) >= 0) and np.all(np.diff(a.coverage_with_carving) >= 0)
    assert np.all(np.diff(a.path_length_m) >= 0) and a.path_length_m[-1] > 5.0
    np.testing.assert_array_equal(a.poses, b.poses)
    np.testing.assert_array_equal(a.coverage, b.coverage)
    assert a.goals == b.goals
    assert not small_map.occupied[a.poses[:, 0], a.poses[:, 1]].any()
    # Each step moves at most step_m (0.3 m along 8-connected cells).
    assert np.all(np.diff(np.r_[0.0, a.path_length_m]) <= 3 * np.sqrt(2) * 0.1 + 1e-9)


def test_mapex_with_the_oracle_covers_more_than_nearest_frontier(small_map):
    start = start_poses("50052750")[0]
    oracle = OraclePredictor(small_map)
    nearest = run_episode(small_map, start, NearestFrontier(), oracle, steps=150, seed=0)
    mapex = run_episode(small_map, start, MapexPlanner(), oracle, steps=150, seed=0)
    assert mapex.coverage[-1] > nearest.coverage[-1]
    assert mapex.coverage.sum() > nearest.coverage.sum()  # area under the coverage curve


def test_episode_finishes_when_everything_is_known(walled_box):
    grid = walled_box(12, 12)
    result = run_episode(grid, (6, 6), NearestFrontier(), ObservedAsPrediction(), steps=50)
    assert result.finished and result.coverage[-1] == 1.0
    summary = summary_table([result.to_json()], 100)
    assert summary[0]["planner"] == "nearest" and summary[0]["episodes"] == 1
    assert summary[0]["coverage@100"] == {"mean": 1.0, "low": 1.0, "high": 1.0}  # an early end keeps its value


def test_bad_inputs(small_map):
    with pytest.raises(ValueError, match="inside a wall"):
        run_episode(small_map, tuple(np.argwhere(small_map.occupied)[0]), NearestFrontier(), ObservedAsPrediction())
    with pytest.raises(ValueError, match="outside"):
        run_episode(small_map, (-1, 0), NearestFrontier(), ObservedAsPrediction())
    with pytest.raises(ValueError, match="Planner"):
        run_episode(small_map, start_poses("50052750")[0], "nearest", ObservedAsPrediction())
    with pytest.raises(ValueError, match="steps"):
        run_episode(small_map, start_poses("50052750")[0], NearestFrontier(), ObservedAsPrediction(), steps=0)
    with pytest.raises(ValueError, match="min_cells"):
        find_frontiers(np.zeros((3, 3), np.int8), min_cells=0)
    with pytest.raises(ValueError, match="MotionConfig"):
        MotionConfig(step_m=0)
    with pytest.raises(ValueError, match="unknown planner"):
        make_planner("frontier")


def _episode_digest(result) -> str:
    """sha256 of an episode's per-step series (coverage, with carving, metres driven, poses), goals and IoU log."""
    import hashlib

    digest = hashlib.sha256()
    for series in (result.coverage, result.coverage_with_carving, result.path_length_m, result.poses):
        digest.update(np.ascontiguousarray(series).tobytes())
    digest.update(json.dumps([list(map(int, goal)) for goal in result.goals]).encode())
    digest.update(json.dumps(result.goal_steps).encode())
    digest.update(json.dumps([float(value) for value in result.iou]).encode())
    return digest.hexdigest()


def test_a_short_episode_is_the_one_recorded_before_the_explorer_came_from_build_explorer(small_map):
    """run_episode builds its explorer with pipeline.build_explorer (since 0.3; before, it called Explorer(...)
    itself): the series and goals of two 40-step episodes, one with SPAD sensing, recorded before that change."""
    nearest = run_episode(small_map, start_poses("50052750")[0], make_planner("nearest"), ObservedAsPrediction(),
                          steps=40, seed=0)
    assert [list(goal) for goal in nearest.goals] == [[43, 132], [83, 51]] and nearest.goal_steps == [0, 36]
    assert float(nearest.coverage.sum()) == 3.11948469251138
    assert _episode_digest(nearest) == "94465e5e0d043e35f6f5ccabff46bc2b9d46773876c5e5ac17324f73d837122b"
    spad = run_episode(small_map, start_poses("50052750")[1], make_planner("superex"), OraclePredictor(small_map),
                       steps=40, seed=0, sensing=SpadSensing(spad=_SMALL_SPAD))
    assert [list(goal) for goal in spad.goals] == [[44, 349], [63, 336], [55, 169], [62, 138]]
    assert spad.goal_steps == [0, 10, 18, 21] and float(spad.coverage_with_carving.sum()) == 2.3618458242837166
    assert _episode_digest(spad) == "363317a46c78a26595b8065cabde0c771a687c59b0d66558c034c537dfc2dcb3"
    # With the carving's normals supported by the map (NlosConfig.normals_from_map, 0.3): the same goals here, and
    # every step's carving reaches at least as far.
    mapped = run_episode(small_map, start_poses("50052750")[1], make_planner("superex"), OraclePredictor(small_map),
                         steps=40, seed=0, sensing=SpadSensing(spad=_SMALL_SPAD,
                                                               nlos_cfg=NlosConfig(normals_from_map=True)))
    assert mapped.goals == spad.goals and np.array_equal(mapped.coverage, spad.coverage)
    assert np.all(mapped.coverage_with_carving >= spad.coverage_with_carving)
    assert mapped.coverage_with_carving.sum() > spad.coverage_with_carving.sum()
