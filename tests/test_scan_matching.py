"""Correlative scan-to-map matching (onboard.scan_matching): the scoring kernel against its slow twin, a scan taken at
a known pose and reported shifted / turned by a known error matched back on a hand-built room and on train floors,
the acceptance rule, and nothing changed without a pose covariance (the explorer included)."""

import math
from dataclasses import replace

import numpy as np
import pytest

from superex_deploy.geometry import cast_rays
from superex_deploy.maps import OccupancyGrid, list_maps, load_map, random_start
from superex_deploy.messages import MapFrame, Observation, Pose2D, PoseCovariance, grid_angles
from superex_deploy.onboard.explorer import Explorer, ExplorerConfig
from superex_deploy.onboard.mapping.mapper import Mapper
from superex_deploy.onboard.planning.planners import make_planner
from superex_deploy.onboard.prediction.registry import make_onboard_predictor
from superex_deploy.onboard.mapping.scan_matching import (ScanMatcher, ScanMatchingConfig, likelihood_field,
                                                  score_poses)
from superex_deploy.sim.world import laser_scan_from_distances
from tests.naive import naive_score_poses

N_RAYS, RANGE_M = 2500, 20.0


def scan_at(grid: OccupancyGrid, frame: MapFrame, pose: Pose2D):
    """The noise-free scan of ``grid`` from the continuous ``pose`` (robot-frame angles from 0, a full turn)."""
    increment = 2.0 * math.pi / N_RAYS
    origin, _ = frame.locate(pose.x, pose.y)
    hits = cast_rays(grid.occupied, origin, grid_angles(pose.yaw, np.arange(N_RAYS) * increment),
                     RANGE_M / grid.resolution_m)
    return laser_scan_from_distances(hits.distance_cells, hits.hit_mask, grid.resolution_m, 0.0, increment, RANGE_M)


def frame_of(grid: OccupancyGrid) -> MapFrame:
    return MapFrame(grid.shape, grid.resolution_m, (0.0, 0.0))


def mapped_walls(grid: OccupancyGrid, frame: MapFrame, poses) -> np.ndarray:
    """The walls a log-odds map holds after noise-free scans from ``poses``."""
    mapper = Mapper(grid.shape)
    for pose in poses:
        mapper.integrate_scan(frame, pose, scan_at(grid, frame, pose))
    return mapper.seen_wall


def room() -> OccupancyGrid:
    """An L-shaped room with a pillar and a doorway: every pose offset changes the fit."""
    walls = np.zeros((60, 80), bool)
    walls[[0, -1], :] = True
    walls[:, [0, -1]] = True
    walls[35:, 45:] = True          # the L's missing corner
    walls[15:19, 20:23] = True      # a pillar
    walls[35, 10:30] = True         # a wall with a doorway at columns 30..44
    return OccupancyGrid(walls, ~walls, 0.1, "room")


def angle_error_deg(a: float, b: float) -> float:
    return abs(math.degrees(math.remainder(a - b, 2.0 * math.pi)))


def test_the_scoring_kernel_matches_its_naive_twin():
    rng = np.random.default_rng(24)
    for _ in range(20):
        shape = tuple(int(n) for n in rng.integers(4, 40, 2))
        field = rng.random(shape)
        n = int(rng.integers(1, 30))
        rho, angles = rng.uniform(0, 25, n), rng.uniform(-math.pi, math.pi, n)
        y0, x0, yaw = rng.uniform(0, shape[0]), rng.uniform(0, shape[1]), rng.uniform(-math.pi, math.pi)
        offsets = np.column_stack([rng.uniform(-3, 3, 15), rng.uniform(-3, 3, 15), rng.uniform(-0.2, 0.2, 15)])
        fast = score_poses(field, rho, angles, (y0, x0), yaw, offsets)
        slow = naive_score_poses(field, rho, angles, y0, x0, yaw, offsets)
        np.testing.assert_allclose(fast, slow, rtol=1e-12, atol=1e-12)


def test_score_poses_rejects_bad_inputs():
    field = np.zeros((5, 5))
    with pytest.raises(ValueError, match="offsets"):
        score_poses(field, np.ones(3), np.zeros(3), (2, 2), 0.0, np.zeros((4, 2)))
    with pytest.raises(ValueError, match="one length"):
        score_poses(field, np.ones(3), np.zeros(2), (2, 2), 0.0, np.zeros((1, 3)))
    with pytest.raises(ValueError, match="field"):
        score_poses(np.zeros(5), np.ones(3), np.zeros(3), (2, 2), 0.0, np.zeros((1, 3)))
    with pytest.raises(ValueError, match="finite"):
        score_poses(field, np.array([1.0, np.nan]), np.zeros(2), (2, 2), 0.0, np.zeros((1, 3)))


def test_the_fit_is_one_on_the_walls_and_falls_off_the_walls():
    walls = np.zeros((20, 20), bool)
    walls[:, 10] = True
    field = likelihood_field(walls, 1.0)
    assert field[:, 10].min() == 1.0 and field[5, 13] == pytest.approx(math.exp(-4.5))
    assert not likelihood_field(np.zeros((4, 4), bool), 1.0).any()


@pytest.mark.parametrize("bad", [dict(window_sigmas=0.0), dict(field_sigma_m=-1.0), dict(min_gain=-0.1),
                                 dict(max_points=0), dict(min_points=500, max_points=400), dict(enabled=1),
                                 dict(starts=0), dict(max_window_deg=float("inf"))])
def test_the_config_rejects_bad_values(bad):
    with pytest.raises(ValueError, match="ScanMatchingConfig"):
        ScanMatchingConfig(**bad)


ERRORS = [(0.15, -0.10, 2.0), (-0.20, 0.05, -3.0), (0.07, 0.12, 0.6), (-0.12, -0.18, -1.5), (0.25, 0.0, 0.0)]


@pytest.mark.parametrize("error", ERRORS)
def test_a_known_error_is_matched_back_in_a_hand_built_room(error):
    grid = room()
    frame = frame_of(grid)
    truth = Pose2D(3.05, 3.57, math.radians(20.0))
    walls = mapped_walls(grid, frame, [Pose2D(2.55, 4.05, 0.0), Pose2D(5.55, 1.55, 0.0)])
    believed = Pose2D(truth.x + error[0], truth.y + error[1], truth.yaw + math.radians(error[2]))
    match = ScanMatcher().match(
        frame, walls, believed, PoseCovariance.from_sigmas(0.1, math.radians(2.0)), scan_at(grid, frame, truth))
    assert match.accepted and match.fit > match.believed_fit
    assert math.hypot(match.pose.x - truth.x, match.pose.y - truth.y) < grid.resolution_m
    assert angle_error_deg(match.pose.yaw, truth.yaw) < 0.5


def test_known_errors_are_matched_back_on_train_floors():
    """The default search finds the true pose within a cell and half a degree; a prior five times stronger (the
    an earlier default, which held the map closer to the belief) still removes most of the error."""
    rng = np.random.default_rng(7)
    weak, default = ScanMatcher(), ScanMatcher(ScanMatchingConfig(prior_weight=0.05))
    covariance = PoseCovariance.from_sigmas(0.1, math.radians(2.0))
    errors = {"belief": [], "default": []}
    for name in list_maps("train")[2::12][:4]:
        grid = load_map(name)
        frame = frame_of(grid)
        start = random_start(grid, rng, 1.0)
        mapped_from = Pose2D(*frame.centre_xy(start), 0.0)
        walls = mapped_walls(grid, frame, [mapped_from])
        for _ in range(4):
            # The truth a few decimetres from where the map was scanned, the belief off by N(0, sigma).
            truth = Pose2D(mapped_from.x + rng.uniform(-0.3, 0.3), mapped_from.y + rng.uniform(-0.3, 0.3),
                           rng.uniform(-math.pi, math.pi))
            if not grid.is_free(frame.cell_of(truth.x, truth.y)):
                continue
            believed = Pose2D(truth.x + rng.normal(0.0, 0.1), truth.y + rng.normal(0.0, 0.1),
                              truth.yaw + math.radians(rng.normal(0.0, 2.0)))
            scan = scan_at(grid, frame, truth)
            match = weak.match(frame, walls, believed, covariance, scan)
            assert match.accepted, (name, match.reason)
            assert math.hypot(match.pose.x - truth.x, match.pose.y - truth.y) < grid.resolution_m, name
            assert angle_error_deg(match.pose.yaw, truth.yaw) < 0.5, name
            for key, pose in (("belief", believed), ("default", default.match(frame, walls, believed, covariance,
                                                                              scan).pose)):
                errors[key].append((math.hypot(pose.x - truth.x, pose.y - truth.y),
                                    angle_error_deg(pose.yaw, truth.yaw)))
    belief, matched = np.mean(errors["belief"], axis=0), np.mean(errors["default"], axis=0)
    assert len(errors["belief"]) >= 10
    assert matched[0] < 0.5 * belief[0] and matched[1] < 0.5 * belief[1], (belief, matched)


def test_nothing_is_corrected_without_a_covariance_walls_or_a_clear_gain():
    grid = room()
    frame = frame_of(grid)
    truth = Pose2D(3.05, 3.57, 0.3)
    scan = scan_at(grid, frame, truth)
    walls = mapped_walls(grid, frame, [truth])
    believed = Pose2D(truth.x + 0.2, truth.y, truth.yaw)
    covariance = PoseCovariance.from_sigmas(0.1, math.radians(2.0))
    for match, reason in [(ScanMatcher().match(frame, walls, believed, None, scan), "no covariance"),
                          (ScanMatcher(ScanMatchingConfig(enabled=False)).match(frame, walls, believed, covariance,
                                                                                 scan), "disabled"),
                          (ScanMatcher().match(frame, np.zeros_like(walls), believed, covariance, scan),
                           "too few walls"),
                          (ScanMatcher(ScanMatchingConfig(min_fit=1.0)).match(frame, walls, believed, covariance,
                                                                               scan), "min_fit")]:
        assert not match.accepted and match.pose == believed and reason in match.reason
    # At the true pose there is nothing clearly better to find.
    exact = ScanMatcher().match(frame, walls, truth, covariance, scan)
    assert not exact.accepted and exact.pose == truth and "min_gain" in exact.reason


def explorer_for(frame: MapFrame, cfg: ExplorerConfig = ExplorerConfig()) -> Explorer:
    return Explorer(frame, make_planner("nearest"), make_onboard_predictor("observed"), cfg=cfg)


def test_the_explorer_is_unchanged_without_a_covariance():
    grid = room()
    frame = frame_of(grid)
    poses = [Pose2D(2.55, 4.05, 0.0), Pose2D(2.75, 3.85, 0.0), Pose2D(5.55, 1.55, 0.0)]
    with_matching, without = explorer_for(frame), explorer_for(
        frame, ExplorerConfig(scan_matching=ScanMatchingConfig(enabled=False)))
    for t, pose in enumerate(poses):
        observation = Observation(stamp_s=float(t), pose=pose, scan=scan_at(grid, frame, pose))
        a, b = with_matching.step(observation), without.step(observation)
        assert with_matching.scan_match is None and with_matching.pose_estimate == pose
        assert a.goal_rc == b.goal_rc and np.array_equal(a.path_rc, b.path_rc)
        assert np.array_equal(with_matching.mapper.log_odds, without.mapper.log_odds)


def test_the_explorer_integrates_and_plans_from_the_corrected_pose():
    grid = room()
    frame = frame_of(grid)
    covariance = PoseCovariance.from_sigmas(0.1, math.radians(2.0))
    explorer = explorer_for(frame)
    first = Pose2D(2.55, 4.05, 0.0)
    explorer.step(Observation(stamp_s=0.0, pose=first, scan=scan_at(grid, frame, first), pose_covariance=covariance))
    assert explorer.scan_match is not None and not explorer.scan_match.accepted  # an empty map: nothing to match
    truth = Pose2D(3.05, 3.55, 0.2)
    believed = Pose2D(truth.x + 0.22, truth.y - 0.14, truth.yaw + math.radians(2.5))
    command = explorer.step(Observation(stamp_s=1.0, pose=believed, scan=scan_at(grid, frame, truth),
                                        pose_covariance=covariance))
    assert explorer.scan_match.accepted
    estimate = explorer.pose_estimate
    assert math.hypot(estimate.x - truth.x, estimate.y - truth.y) < grid.resolution_m
    assert frame.cell_of(estimate.x, estimate.y) != frame.cell_of(believed.x, believed.y)
    assert tuple(command.path_rc[0]) == frame.cell_of(estimate.x, estimate.y)
    # The scan's rays no longer cross the walls they return from: far fewer true walls held free than from the belief.
    raw = explorer_for(frame, ExplorerConfig(scan_matching=ScanMatchingConfig(enabled=False)))
    for t, (pose, reported) in enumerate([(first, first), (truth, believed)]):
        raw.step(Observation(stamp_s=float(t), pose=reported, scan=scan_at(grid, frame, pose),
                             pose_covariance=covariance))
    assert np.count_nonzero(grid.occupied & explorer.mapper.seen_free) * 4 < np.count_nonzero(
        grid.occupied & raw.mapper.seen_free)


def test_a_recordings_config_dict_is_accepted():
    cfg = ExplorerConfig(scan_matching=dict(min_gain=0.05))
    assert cfg.scan_matching == replace(ScanMatchingConfig(), min_gain=0.05)
    with pytest.raises(ValueError, match="scan_matching"):
        ExplorerConfig(scan_matching=3)
