"""Imperfection in the simulator: localisation error, belief-relative continuous motion, LiDAR noise and
the SPAD photon budgets; all of it off by default, where the world is what it was (the legacy episodes of
tests/test_onboard.py hold it to that)."""

import json
import math

import numpy as np
import pytest

from superex_deploy.cli import main
from superex_deploy.commands.options import noise_options, parse_lidar_noise, parse_pose_noise
from superex_deploy.maps import OccupancyGrid, load_map, start_poses
from superex_deploy.messages import Command, Pose2D
from superex_deploy.onboard.nlos.los import estimate_los
from superex_deploy.onboard.planning.planners import make_planner
from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
from superex_deploy.onboard.nlos.processing import scan_from_frame
from superex_deploy.evaluation.episodes import run_episode
from superex_deploy.sim.exploration import ExplorationConfig
from superex_deploy.sim.kinematics import first_blocked
from superex_deploy.sim.noise.lidar import LidarNoise, noisy_ranges
from superex_deploy.sim.noise.model import NOISE_PRESETS, SimNoise
from superex_deploy.sim.noise.pose import PoseErrorModel, PoseNoise
from superex_deploy.evaluation.metrics import MAP_ERROR_KEYS
from superex_deploy.evaluation.summary import summary_markdown, summary_table
from superex_deploy.sim.spad import simulate_scan
from superex_deploy.sim.world import World, WorldConfig
from superex_deploy.spad_types import SPAD_PRESETS, SpadConfig, spad_preset

_EXACT = PoseNoise()  # continuous motion, belief = truth: the belief is then set by hand


def _command(world: World, cells) -> Command:
    cells = np.asarray(cells, np.int64)
    return Command(0.0, None, None, world.frame.centres_xy(cells), cells, False, False)


def _north_of(cell, n):
    return [(cell[0] - k, cell[1]) for k in range(n + 1)]


# Belief-relative motion on hand-built grids.

def test_a_belief_one_cell_off_drives_the_robot_one_cell_off_the_path(walled_box):
    world = World(walled_box(), (10, 5), WorldConfig(noise=SimNoise(pose=_EXACT)))
    truth = world.observe().pose
    assert (truth.x, truth.y, truth.yaw) == pytest.approx((0.55, 0.95, 0.0))
    world.belief = Pose2D(truth.x + 0.1, truth.y, 0.0)  # the robot believes it is one cell east
    metres = world.apply(_command(world, _north_of((10, 6), 4)))  # its path runs north along column 6
    assert metres == pytest.approx(0.3) and world.driven_m == pytest.approx(0.3)
    assert world.pose_rc == (7, 5)  # three cells north, still in column 5: one cell west of the path
    assert (world.pose.x, world.pose.y) == pytest.approx((0.55, 1.25))
    assert world.pose.yaw == pytest.approx(math.pi / 2)  # heading along the direction of travel
    assert world.collisions == 0


def test_a_wall_stops_the_robot_at_the_last_free_position_and_counts(walled_box):
    world = World(walled_box(walls=[(8, 5)]), (10, 5), WorldConfig(noise=SimNoise(pose=_EXACT)))
    truth = world.observe().pose
    world.belief = Pose2D(truth.x + 0.1, truth.y, 0.0)
    metres = world.apply(_command(world, _north_of((10, 6), 4)))  # column 6 is free, column 5 is not
    assert world.collisions == 1
    assert metres == pytest.approx(0.15, abs=1e-5)  # from the centre of row 10 to the face of row 8
    assert world.pose_rc == (9, 5) and world.grid.is_free(world.pose_rc)
    world.belief = world.observe().pose  # exact again: a path straight into the wall stops at once
    assert world.apply(_command(world, _north_of((9, 5), 3))) == pytest.approx(0.0, abs=1e-5)
    assert world.collisions == 2 and world.pose_rc == (9, 5)


def test_a_yaw_error_turns_the_displacement(walled_box):
    world = World(walled_box(), (10, 10), WorldConfig(noise=SimNoise(pose=_EXACT)))
    truth = world.observe().pose
    world.belief = Pose2D(truth.x, truth.y, math.pi / 2)  # believes it faces north, faces east
    world.apply(_command(world, _north_of((10, 10), 3)))  # three cells ahead, as the robot sees it
    assert (world.pose.x - truth.x, world.pose.y - truth.y) == pytest.approx((0.3, 0.0), abs=1e-12)
    assert world.pose_rc == (10, 13)  # straight ahead, as it really faces: east


def test_with_pose_noise_no_command_is_refused_and_without_it_the_old_rules_hold(walled_box):
    noisy = World(walled_box(), (10, 5), WorldConfig(noise=SimNoise(pose=PoseNoise.from_sigmas(0.05, 1.0))))
    noisy.observe()
    noisy.apply(_command(noisy, [(3, 3), (3, 4), (3, 6)]))  # elsewhere, and not 8-connected: still driven
    exact = World(walled_box(), (10, 5))
    with pytest.raises(ValueError, match="starts at cell"):
        exact.apply(_command(exact, [(3, 3), (3, 4)]))
    assert exact.observe().pose_covariance is None


def test_first_blocked_finds_the_first_wall_a_segment_enters():
    rng = np.random.default_rng(5)
    for _ in range(300):
        grid = OccupancyGrid(rng.random((12, 12)) < 0.25, np.ones((12, 12), bool), 0.1, "random")
        free = np.argwhere(~grid.occupied)
        r, c = free[rng.integers(len(free))]
        start = ((c + rng.random()) * 0.1, (11 - r + rng.random()) * 0.1)
        end = (start[0] + rng.uniform(-0.4, 0.4), start[1] + rng.uniform(-0.4, 0.4))
        blocked = first_blocked(grid, start, end)
        samples = np.linspace(0.0, 1.0, 4001)
        points = np.outer(1 - samples, start) + np.outer(samples, end)
        rows = 11 - np.floor(points[:, 1] / 0.1).astype(int)
        cols = np.floor(points[:, 0] / 0.1).astype(int)
        inside = (rows >= 0) & (rows < 12) & (cols >= 0) & (cols < 12)
        free_at = inside & ~grid.occupied[np.clip(rows, 0, 11), np.clip(cols, 0, 11)]
        first = samples[np.argmin(free_at)] if not free_at.all() else None
        if first is None:  # a sampled segment that stays free may still clip a wall corner between samples
            assert blocked is None or free_at[samples >= blocked].all()
        else:
            assert blocked is not None and blocked <= first + 1e-9
            assert free_at[samples < blocked - 1e-6].all()


# The localisation error.

def test_jitter_has_zero_mean_and_the_configured_sigma():
    model = PoseErrorModel(PoseNoise(sigma_xy_m=0.05, sigma_yaw_deg=2.0, seed=3))
    truth = Pose2D(3.0, 4.0, 0.5)
    errors = np.array([(b.x - 3.0, b.y - 4.0, b.yaw - 0.5) for b in (model.believe(truth) for _ in range(20000))])
    sigmas = np.array([0.05, 0.05, math.radians(2.0)])
    np.testing.assert_array_less(np.abs(errors.mean(axis=0)), 4 * sigmas / math.sqrt(len(errors)))
    np.testing.assert_allclose(errors.std(axis=0), sigmas, rtol=0.03)
    np.testing.assert_allclose(np.diag(model.covariance().matrix), sigmas ** 2)  # no distance driven: no drift


def test_drift_grows_with_the_distance_driven():
    noise = PoseNoise(drift_xy_per_m=0.01, drift_yaw_deg_per_m=0.5, max_drift_xy_m=math.inf,
                      max_drift_yaw_deg=math.inf)
    biases = {4: [], 16: []}
    for seed in range(3000):
        model = PoseErrorModel(PoseNoise(**{**noise.__dict__, "seed": seed}))
        for metres in (4, 16):
            while model.distance_m < metres - 1e-9:
                model.drive(0.3 if metres - model.distance_m > 0.3 else metres - model.distance_m)
            biases[metres].append((*model.bias_xy_m, model.bias_yaw_rad))
    for metres, values in biases.items():
        values = np.array(values)
        expected = np.array([0.01, 0.01, math.radians(0.5)]) * math.sqrt(metres)
        np.testing.assert_allclose(values.std(axis=0), expected, rtol=0.06)
        assert np.all(np.abs(values.mean(axis=0)) < 4 * expected / math.sqrt(len(values)))
        xy, yaw = noise.drift_variance(metres)
        assert (xy, yaw) == pytest.approx(tuple(expected[1:] ** 2))


def test_the_default_drift_is_bounded_and_the_covariance_follows_it():
    noise = PoseNoise.from_sigmas(0.05, 1.0)
    assert noise.drift_xy_per_m == pytest.approx(0.01) and noise.drift_bound_xy_m == pytest.approx(0.05 * math.sqrt(3))
    bias = []
    for seed in range(1500):
        model = PoseErrorModel(PoseNoise(**{**noise.__dict__, "seed": seed}))
        model.drive(2000.0)  # far beyond the correlation length (150 m): stationary
        bias.append(model.bias_xy_m.copy())
    assert np.std(bias) == pytest.approx(0.05 * math.sqrt(3), rel=0.06)
    episode = PoseErrorModel(noise)
    for _ in range(500):
        episode.drive(0.3)
    sigma_xy = math.sqrt(episode.covariance().matrix[0, 0])
    assert 1.85 * 0.05 < sigma_xy < 2.0 * 0.05  # a 500-step episode stays within two jitter sigmas
    assert episode.covariance().sigma_yaw_rad < 2.0 * math.radians(1.0)


def test_pose_noise_is_deterministic_per_seed():
    def trajectory(seed):
        world = World(load_map("50052750"), start_poses("50052750")[0],
                      WorldConfig(noise=SimNoise(pose=PoseNoise.from_sigmas(0.05, 1.0, seed=seed),
                                                 lidar=LidarNoise.from_sigma(0.02, seed=seed))))
        out = []
        for _ in range(3):
            observation = world.observe()
            out.append((observation.pose, observation.scan.ranges.copy()))
            world.apply(_command(world, [world.frame.cell_of(observation.pose.x, observation.pose.y)]))
        return out

    a, b, c = trajectory(1), trajectory(1), trajectory(2)
    assert [p for p, _ in a] == [p for p, _ in b] and [p for p, _ in a] != [p for p, _ in c]
    assert all(np.array_equal(x, y, equal_nan=True) for (_, x), (_, y) in zip(a, b))


# LiDAR noise.

def test_lidar_noise_has_the_configured_rates():
    noise = LidarNoise(sigma_m=0.02, dropout_prob=0.05, spurious_prob=0.02, seed=4)
    exact = np.where(np.arange(200_000) % 4 == 0, np.inf, np.random.default_rng(0).uniform(1.0, 15.0, 200_000))
    ranges = noisy_ranges(exact, noise, 20.0, noise.generator()).astype(np.float64)
    dropped = np.isnan(ranges)
    assert dropped.mean() == pytest.approx(0.05, abs=0.003)
    returned = np.isfinite(exact) & ~dropped
    residual = ranges[returned] - exact[returned]
    spurious = residual < -0.1  # five sigmas short: a spurious return
    assert spurious.mean() == pytest.approx(0.02, abs=0.002)
    assert residual[~spurious].std() == pytest.approx(0.02, rel=0.02)
    assert abs(residual[~spurious].mean()) < 2e-4
    no_return = ~np.isfinite(exact) & ~dropped
    short = np.isfinite(ranges[no_return])
    assert short.mean() == pytest.approx(0.02, abs=0.003)
    assert np.all((ranges[no_return][short] >= 0.05) & (ranges[no_return][short] < 20.0))
    again = noisy_ranges(exact, noise, 20.0, noise.generator())
    np.testing.assert_array_equal(again, ranges.astype(np.float32))  # deterministic per seed


def test_the_world_sends_noisy_scans_with_a_minimum_range(walled_box):
    world = World(walled_box(), (10, 10), WorldConfig(noise=SimNoise(lidar=LidarNoise.from_sigma(0.02, seed=1))))
    scan = world.observe().scan
    assert scan.range_min == pytest.approx(0.05) and np.isnan(scan.ranges).any()
    clean = World(walled_box(), (10, 10)).observe().scan
    valid = ~np.isnan(scan.ranges) & (np.abs(scan.ranges - clean.ranges) < 0.1)
    assert valid.mean() > 0.95
    assert np.std(scan.ranges[valid] - clean.ranges[valid]) == pytest.approx(0.02, rel=0.25)


def test_the_scan_turns_with_the_robot(walled_box):
    world = World(walled_box(), (10, 5), WorldConfig(noise=SimNoise(pose=_EXACT)))
    world.observe()
    world.apply(_command(world, _north_of((10, 5), 3)))  # heading north now, at the centre of (7, 5)
    scan = world.observe().scan
    assert world.pose.yaw == pytest.approx(math.pi / 2)
    # Ray 0 looks along the heading: from y = 1.25 m to the face of row 0 (y = 1.9 m).
    assert scan.ranges[0] == pytest.approx(0.65, abs=1e-5)
    quarter = scan.n_rays // 4  # 90 degrees counter-clockwise: west, to the face of column 0 (x = 0.1 m)
    assert scan.ranges[quarter] == pytest.approx(0.45, abs=1e-3)


# The SPAD: from the true pose, and its photon budgets.

def test_the_spad_scan_is_cast_from_the_true_continuous_pose(walled_box):
    small = SpadConfig(n_rays=90, range_m=2.0, n_secondary=16)
    grid = walled_box()
    centre = simulate_scan(grid, (10, 10), small)
    same = simulate_scan(grid, (10, 10), small, origin_yx=(10.5, 10.5))
    np.testing.assert_array_equal(centre.histograms, same.histograms)
    with pytest.raises(ValueError, match="outside the robot cell"):
        simulate_scan(grid, (10, 10), small, origin_yx=(11.2, 10.5))
    world = World(grid, (10, 5), WorldConfig(spad=small, noise=SimNoise(pose=_EXACT)))
    world.observe()
    world.apply(_command(world, [(10, 5), (9, 6), (8, 7), (7, 8)]))  # 0.3 m diagonally: off the centres, turned
    assert world.pose.yaw == pytest.approx(math.pi / 4) and world.pose_rc == (8, 7)
    observation = world.observe()
    truth = world.pose
    assert world.last_spad_scan.origin_yx == pytest.approx(world.frame.locate(truth.x, truth.y)[0])
    rebuilt = scan_from_frame(observation.spad, world.frame, observation.pose, small)
    turn = np.angle(np.exp(1j * (rebuilt.angles - world.last_spad_scan.angles)))
    np.testing.assert_allclose(turn, 0.0, atol=1e-9)  # the robot-frame angles turn back to the grid's


def test_the_photon_budgets_set_the_noise_and_the_onboard_threshold(walled_box):
    assert set(SPAD_PRESETS) == {"off", "realistic", "low"}
    small = SpadConfig(n_rays=60, range_m=3.0, n_secondary=16)
    assert spad_preset("off", small) is small and spad_preset("off") == SpadConfig()
    realistic, low = spad_preset("realistic", small), spad_preset("low", small)
    assert realistic.noise.enabled and low.noise.enabled
    assert low.noise.background_per_bin > realistic.noise.background_per_bin > 0.0
    assert small.direct_counts > realistic.direct_counts > low.direct_counts
    assert realistic.n_bins == small.n_bins and realistic.bin_width_s == small.bin_width_s  # same histograms
    rng = np.random.default_rng(0)
    thresholds = [estimate_los(simulate_scan(walled_box(), (10, 10), config, rng=rng)).late_threshold
                  for config in (small, realistic, low)]
    assert thresholds[0] == 0.0 < thresholds[1] < thresholds[2]
    with pytest.raises(ValueError, match="unknown SPAD noise preset"):
        spad_preset("dim")


# Episodes, the command line and the results.

def _short_noisy_episode(noise=SimNoise()):
    grid = load_map("50052750")
    return run_episode(grid, start_poses("50052750")[0], make_planner("nearest"), ObservedAsPrediction(), steps=50,
                       seed=0, cfg=ExplorationConfig(noise=noise))


def test_a_short_noisy_episode_runs_and_is_deterministic():
    noisy = SimNoise(pose=PoseNoise.from_sigmas(0.05, 1.0), lidar=LidarNoise.from_sigma(0.02))
    a, b = _short_noisy_episode(noisy), _short_noisy_episode(noisy)
    assert a.steps >= 1 and np.array_equal(a.true_poses, b.true_poses) and a.goals == b.goals
    np.testing.assert_array_equal(a.coverage, b.coverage)
    error = np.hypot(*(a.true_poses[:, :2] - a.believed_poses[:, :2]).T)
    assert 0.0 < error.mean() < 0.2
    log = json.loads(json.dumps(a.to_json()))
    assert {"collisions", "true_walls_held_free", "true_walls_carved", "map_iou"} <= set(log)
    noise = log["config"]["noise"]
    assert noise["pose"]["sigma_xy_m"] == 0.05 and noise["lidar"]["sigma_m"] == 0.02 and noise["spad"] == "off"
    exact = _short_noisy_episode()
    assert "noise" not in exact.to_json()["config"]
    np.testing.assert_array_equal(exact.believed_poses, exact.true_poses)  # no noise: the truth is observed
    assert 0.0 < exact.explorer_map_iou <= 1.0 and exact.true_walls_held_free == 0 and exact.collisions == 0
    rows = summary_table([dict(exact.to_json(), start_index=0), dict(a.to_json(), start_index=0)], 50,
                         extra=MAP_ERROR_KEYS)
    ious = sorted([exact.explorer_map_iou, a.explorer_map_iou])
    assert rows[0]["map_iou"]["mean"] == pytest.approx(np.mean(ious))
    assert ious[0] <= rows[0]["map_iou"]["low"] <= rows[0]["map_iou"]["high"] <= ious[1]
    assert "| collisions |" in summary_markdown(rows, ["auc", *MAP_ERROR_KEYS])
    assert "map_iou" not in summary_table([exact.to_json()], 50)[0]


def test_the_noise_flags_are_parsed_and_checked():
    assert parse_pose_noise("0.05,1") == (0.05, 1.0) and parse_pose_noise("0,0") is None
    assert parse_lidar_noise("0.02") == (0.02, 0.01, 0.001) and parse_lidar_noise("0") is None
    assert parse_lidar_noise("0,0.1,0") == (0.0, 0.1, 0.0)
    for text, message in [("0.05", "SIGMA_M,SIGMA_DEG"), ("a,1", "SIGMA_M,SIGMA_DEG"), ("nan,1", "SIGMA_M,SIGMA_DEG"),
                          ("-0.1,1", "SIGMA_M must lie in"), ("0.1,90", "SIGMA_DEG must lie in")]:
        with pytest.raises(ValueError, match=message):
            parse_pose_noise(text)
    for text, message in [("0.02,0.1", "SIGMA_M or SIGMA_M,DROPOUT,SPURIOUS"), ("5", "SIGMA_M must lie in"),
                          ("0.02,1,0", "DROPOUT is a probability"), ("0.02,0,-1", "SPURIOUS is a probability")]:
        with pytest.raises(ValueError, match=message):
            parse_lidar_noise(text)
    from argparse import Namespace

    with pytest.raises(ValueError, match="add --spad"):
        noise_options(Namespace(pose_noise=None, lidar_noise=None, spad_noise="low", spad=False))
    # One noise object: what the flags ask for, recorded as before, seeded per episode.
    noise = noise_options(Namespace(pose_noise="0.05,1", lidar_noise="0.02", spad_noise="low", spad=True))
    assert noise == SimNoise.from_sigmas((0.05, 1.0), (0.02, 0.01, 0.001), "low")
    assert noise.settings() == {"pose_noise": [0.05, 1.0], "lidar_noise": [0.02, 0.01, 0.001], "spad_noise": "low"}
    assert noise.seeded(7).pose.seed == noise.seeded(7).lidar.seed == 7 and noise.pose.seed == 0
    assert SimNoise().settings() == {} and not SimNoise().on and NOISE_PRESETS["off"] == SimNoise()
    assert NOISE_PRESETS["robot"].settings()["spad_noise"] == "realistic"


def test_noise_models_refuse_bad_values_naming_the_field():
    for bad, message in [({"sigma_m": -1.0}, "LidarNoise.sigma_m must be finite and >= 0"),
                         ({"dropout_prob": 1.0}, r"LidarNoise.dropout_prob must lie in \[0, 1\)"),
                         ({"seed": -1}, "LidarNoise.seed must be an integer >= 0"),
                         ({"range_min_m": float("nan")}, "LidarNoise.range_min_m")]:
        with pytest.raises(ValueError, match=message):
            LidarNoise(**bad)
    for bad, message in [({"sigma_xy_m": -0.1}, "PoseNoise.sigma_xy_m must be finite and >= 0"),
                         ({"sigma_yaw_deg": True}, "PoseNoise.sigma_yaw_deg"),
                         ({"max_drift_xy_m": -1.0}, "PoseNoise.max_drift_xy_m"),
                         ({"seed": 1.5}, "PoseNoise.seed must be an integer >= 0")]:
        with pytest.raises(ValueError, match=message):
            PoseNoise(**bad)
    assert PoseNoise(max_drift_xy_m=float("inf")).drift_bound_xy_m == math.inf  # an unbounded walk
    with pytest.raises(ValueError, match="spad must be 'off'"):
        SimNoise(spad="dim")
    with pytest.raises(ValueError, match="pose must be a PoseNoise or None"):
        SimNoise(pose=(0.05, 1.0))
    with pytest.raises(ValueError, match="noise must be a SimNoise"):
        ExplorationConfig(noise=None)
    with pytest.raises(ValueError, match="noise must be a SimNoise"):
        WorldConfig(noise={"pose": None})


@pytest.mark.parametrize("argv, message", [
    (["explore", "--map", "50052750", "--steps", "5", "--pose-noise", "0.05"], "--pose-noise takes SIGMA_M,SIGMA_DEG"),
    (["explore", "--map", "50052750", "--steps", "5", "--lidar-noise", "2"], "--lidar-noise: SIGMA_M must lie"),
    (["explore", "--pipeline", "nearest", "--map", "50052750", "--steps", "5", "--spad-noise", "realistic"],
      "add --spad"),
    (["benchmark", "--maps", "50052750", "--steps", "5", "--pose-noise", "x,y"], "--pose-noise takes"),
    (["benchmark", "--suite", "paper", "--pose-noise", "0.05,1"], "noise-free protocol"),
])
def test_bad_noise_flags_fail_with_a_clear_message(tmp_path, capsys, argv, message):
    assert main(argv + ["--out", str(tmp_path / "out")]) == 2
    assert message in capsys.readouterr().err


@pytest.mark.slow
def test_explore_and_benchmark_run_with_noise(tmp_path, capsys):
    out = tmp_path / "explore"
    assert main(["explore", "--pipeline", "nearest", "--map", "50052750", "--steps", "50", "--pose-noise", "0.05,1",
                 "--lidar-noise", "0.02", "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["pose_noise"] == [0.05, 1.0] and metrics["lidar_noise"] == [0.02, 0.01, 0.001]
    assert {"collisions", "true_walls_held_free", "true_walls_carved", "map_iou"} <= set(metrics)
    assert "collisions" in capsys.readouterr().out
    bench = tmp_path / "bench"
    assert main(["benchmark", "--maps", "50052750", "--planners", "nearest", "--steps", "10", "--jobs", "1",
                 "--pose-noise", "0.02,0.5", "--spad", "--spad-noise", "realistic", "--out", str(bench)]) == 0
    results = json.loads((bench / "results.json").read_text())
    assert len(results["episodes"]) == 4 and "true_walls_carved" in results["summary"][0]
    assert json.loads((bench / "settings.json").read_text())["spad_noise"] == "realistic"
    assert "pose_noise [0.02, 0.5], spad_noise realistic" in (bench / "results.md").read_text()


def test_map_errors_tell_a_wall_held_one_cell_off_from_a_missing_one():
    from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN
    from superex_deploy.evaluation.metrics import explorer_map_errors

    occupied = np.zeros((10, 12), bool)
    occupied[:, 6] = True  # one true wall, a column
    grid = OccupancyGrid(occupied, np.ones_like(occupied), 0.1, "column")
    observed = np.full(occupied.shape, FREE, np.int8)
    observed[:, 8:] = UNKNOWN
    observed[:5, 7] = OCCUPIED  # rows 0-4: the wall held one cell off (its true cells free)
    observed[5:, 6] = FREE      # rows 5-9: the wall not held at all
    errors = explorer_map_errors(observed, grid, np.ones_like(occupied))
    assert errors.held_free == 10 and errors.seen == 10
    # Rows 0-5 have a map wall within one cell (row 5 touches row 4's diagonally); rows 6-9 do not.
    assert errors.missing == 4
    assert errors.map_iou == 0.0
    # Within a cell the 5 map walls all count, and the true cells of rows 0-5 are found: 5 / (5 + 4).
    assert errors.map_iou_within_cell == pytest.approx(5 / 9)
    exact = observed.copy()
    exact[:, 6], exact[:, 7] = OCCUPIED, FREE
    assert explorer_map_errors(exact, grid, np.ones_like(occupied)) == (0, 1.0, 10, 0, 1.0)
