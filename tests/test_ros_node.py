"""The exploration node (``superex node``): its parameters, its core on a simulated robot in one process (the
reference of the node over DDS), the inputs a robot gives it (tf at the scan's stamp, a rolled or tilted laser,
stamps of 0 or going backwards, a missing transform), the operator's commands, and the two processes over DDS on
the loopback (``superex robot-sim`` + ``superex node``)."""

import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from superex_deploy.maps import OccupancyGrid
from superex_deploy.messages import LaserScan
from superex_deploy.ros.core import ExplorationCore
from superex_deploy.ros.node_status import PAUSED, WAITING_FOR_INPUT
from superex_deploy.ros.params import NodeParams, load_params
from superex_deploy.ros.rigid import Transform
from superex_deploy.sim.robot import RobotSimConfig, SimulatedRobot, TfSample, run_in_process
from superex_deploy.sim.world import LidarConfig

NEAREST = dict(planner="nearest", predictor="observed")


def _rooms() -> OccupancyGrid:
    walls = np.zeros((80, 80), bool)
    walls[[0, -1], :] = walls[:, [0, -1]] = True
    walls[:, 40] = True
    walls[35:45, 40] = False
    return OccupancyGrid(walls, ~walls, 0.1, "two rooms")


# Parameters


def test_a_params_file_gives_the_node_section_over_every_node_and_refuses_unknown_names(tmp_path):
    path = tmp_path / "superex.yaml"
    path.write_text("/**:\n  ros__parameters:\n    planner: mapex\n    progress_timeout: 10\n"
                    "superex:\n  ros__parameters:\n    planner: nearest\n    bounds: [0, 0, 10, 0, 10, 8]\n")
    params = load_params(path, "superex", finish_after=2.0)
    assert (params.planner, params.progress_timeout, params.finish_after) == ("nearest", 10.0, 2.0)
    assert params.bounds == ((0.0, 0.0), (10.0, 0.0), (10.0, 8.0))
    assert params.explorer.goal_policy.no_progress_s == 10.0 and params.explorer.bounds is not None
    again = tmp_path / "again.yaml"
    again.write_text(params.to_yaml("superex"))
    assert load_params(again, "superex") == params
    with pytest.raises(ValueError, match="unknown parameter plannerr; the node takes"):
        load_params(None, "superex", plannerr="nearest")
    with pytest.raises(ValueError, match="no section for the node 'other'"):
        load_params(_only(tmp_path, "superex"), "other")
    with pytest.raises(ValueError, match="parameter bounds must hold pairs of numbers"):
        NodeParams(bounds=[0, 0, 1])
    with pytest.raises(ValueError, match="parameter min_frontier_size must"):
        NodeParams(min_frontier_size=-1.0)


def _only(folder: Path, name: str) -> Path:
    path = folder / "only.yaml"
    path.write_text(f"{name}:\n  ros__parameters:\n    planner: nearest\n")
    return path


def test_command_line_overrides_are_read_as_yaml_values():
    from superex_deploy.commands.node import parse_overrides

    assert parse_overrides(["planner:=nearest", "finish_after:=2", "bounds:=[0,0,1,0,1,1]", "record:="]) == {
        "planner": "nearest", "finish_after": 2, "bounds": [0, 0, 1, 0, 1, 1], "record": ""}
    with pytest.raises(ValueError, match="-p takes NAME:=VALUE"):
        parse_overrides(["planner=nearest"])


def test_a_predictor_that_reads_the_spad_needs_its_topic():
    with pytest.raises(ValueError, match="the lama_bp predictor reads the SPAD evidence: set spad_topic"):
        ExplorationCore(NodeParams(planner="nearest", predictor="lama_bp"))
    assert NodeParams().predictor_name == "lama_los" and NodeParams(spad_topic="/spad").predictor_name == "lama_bp"


# The core on a simulated robot, in one process


def test_the_core_explores_a_simulated_robot_and_finishes_when_nothing_is_left():
    core = ExplorationCore(NodeParams(**NEAREST))
    run = run_in_process(_rooms(), (20, 10), core, RobotSimConfig(lidar=LidarConfig(range_m=10.0)), duration_s=300)
    assert run.finished_s is not None and run.frontier_gone_s is not None
    assert 0.0 <= run.finished_s - run.frontier_gone_s <= 10.0  # the map period (5 s) and the finish delay (5 s)
    assert run.coverage[-1] > 0.95 and run.goals_in_walls == 0 and run.collisions == 0
    assert run.statuses[-1][1:] == ("done", "no frontier left")


def _core_with_tf(**params) -> ExplorationCore:
    core = ExplorationCore(NodeParams(costmap_topic="", **NEAREST, **params))
    core.add_transform("base_link", "laser", 0.0, Transform(), static=True)
    core.add_transform("map", "odom", 0.0, Transform(), static=True)
    return core


def _open_scan(n: int = 360) -> LaserScan:
    return LaserScan(0.0, 2 * math.pi / n, 0.05, 4.0, np.full(n, np.inf, np.float32))


def test_a_scan_takes_the_pose_interpolated_at_its_stamp_and_waits_for_its_transform():
    core = _core_with_tf()
    core.add_planar_transform(TfSample(10.0, "odom", "base_link", 1.0, 2.0, 0.0))
    core.add_scan(10.05, "laser", _open_scan())
    assert core.step(10.06) is None  # the transform at 10.05 s has not come yet: waited for
    core.add_planar_transform(TfSample(10.1, "odom", "base_link", 2.0, 2.0, 0.2))
    step = core.step(10.11)
    assert step is not None and step.state == "exploring"
    pose = step.observation.pose
    assert (pose.x, pose.y) == pytest.approx((1.5, 2.0)) and pose.yaw == pytest.approx(0.1)
    core.add_scan(10.3, "laser", _open_scan())
    assert core.step(10.4) is None  # waited for within transform_tolerance (0.3 s)
    assert core.step(10.61) is None and core.status(10.61).state == WAITING_FOR_INPUT
    assert "no transform map -> laser at the scan's stamp" in core.status(10.61).reason


def test_scans_stamped_zero_or_backwards_are_refused_and_counted():
    core = _core_with_tf()
    core.add_planar_transform(TfSample(5.0, "odom", "base_link", 1.0, 1.0, 0.0))
    assert not core.add_scan(0.0, "laser", _open_scan())
    assert "scans stamped 0" in core.status(5.0).reason and core.refused == {"stamp 0": 1}
    assert core.add_scan(5.0, "laser", _open_scan()) and core.step(5.0) is not None
    assert not core.add_scan(4.0, "laser", _open_scan())
    assert "before the latest step's" in core.status(5.0).reason and core.scans_dropped == 2


def test_a_laser_mounted_upside_down_gives_the_upright_lasers_map_and_a_tilted_one_is_refused():
    from superex_deploy.sim.world import World, WorldConfig

    world = World(_rooms(), (20, 10), WorldConfig(lidar=LidarConfig(n_rays=720, range_m=10.0)))
    exact = world.observe().scan  # angle_min 0, a full turn; returns end on the walls' faces, on cell edges
    upright = LaserScan(0.0, exact.angle_increment, exact.range_min, exact.range_max,
                        exact.ranges + np.float32(0.01))  # 1 cm into the wall: not on an edge either way rounds
    n = upright.n_rays
    rolled = LaserScan(0.0, upright.angle_increment, upright.range_min, upright.range_max,
                       upright.ranges[(n - np.arange(n)) % n])  # the same rays seen from the sensor flipped over
    x, y = world.pose.x, world.pose.y
    maps = []
    for ranges, rotation in ((upright, (0.0, 0.0, 0.0, 1.0)), (rolled, (1.0, 0.0, 0.0, 0.0))):
        core = ExplorationCore(NodeParams(costmap_topic="", **NEAREST))
        core.add_transform("base_link", "laser", 0.0, Transform(rotation=rotation), static=True)
        core.add_transform("map", "base_link", 0.0, Transform.from_planar(x, y, 0.0), static=True)
        core.add_scan(1.0, "laser", ranges)
        assert core.step(1.0) is not None
        maps.append(core.explorer.observed.copy())
    known = (maps[0] != -1) | (maps[1] != -1)
    assert known.sum() > 1000 and np.array_equal(maps[0], maps[1])
    tilted = ExplorationCore(NodeParams(costmap_topic="", **NEAREST))
    tilted.add_transform("base_link", "laser", 0.0, Transform(rotation=(math.sin(0.15), 0.0, 0.0, math.cos(0.15))),
                         static=True)
    tilted.add_transform("map", "base_link", 0.0, Transform.from_planar(x, y, 0.0), static=True)
    tilted.add_scan(1.0, "laser", upright)
    assert tilted.step(1.0) is None
    assert "laser" in tilted.status(1.0).reason and "non-planar" in tilted.status(1.0).reason


def test_pause_resume_return_and_bounds_from_the_operator():
    core = _core_with_tf()
    for t in (1.0, 1.1, 1.2, 1.3):
        core.add_planar_transform(TfSample(t, "odom", "base_link", 1.0, 1.0, 0.0))
    core.add_scan(1.0, "laser", _open_scan())
    assert core.step(1.0).state == "exploring"
    core.pause()
    core.add_scan(1.1, "laser", _open_scan())
    assert core.step(1.1) is None and core.status(1.1).state == PAUSED
    core.resume()
    with pytest.raises(ValueError, match="smaller than the robot"):
        core.set_bounds([(0.9, 0.9), (1.1, 0.9), (1.1, 1.1)])
    with pytest.raises(ValueError, match="must contain the robot's start pose"):
        core.set_bounds([(5.0, 5.0), (8.0, 5.0), (8.0, 8.0)])
    core.return_to_start()
    core.add_scan(1.2, "laser", _open_scan())
    step = core.step(1.2)
    assert step.state == "done" and step.reason == "back at the start"


# Two processes over DDS


def _floor_png(folder: Path) -> Path:
    grid = _rooms()
    path = folder / "rooms.png"
    Image.fromarray(np.where(grid.occupied, 0, 255).astype(np.uint8)).save(path)
    return path


@pytest.mark.slow
def test_the_node_and_the_simulated_robot_explore_over_dds_in_two_processes(tmp_path):
    pytest.importorskip("cyclonedds")
    env = dict(os.environ, ROS_DOMAIN_ID=str(100 + os.getpid() % 100))
    superex = [sys.executable, "-m", "superex_deploy.cli"]
    robot = subprocess.Popen(superex + ["robot-sim", "--map", str(_floor_png(tmp_path)), "--pose", "20", "10",
                                        "--loopback", "--duration", "120", "--rate", "3", "--speed", "1.0",
                                        "--out", str(tmp_path / "robot")], env=env, stdout=subprocess.PIPE,
                             stderr=subprocess.STDOUT, text=True)
    try:
        node = subprocess.run(superex + ["node", "--loopback", "-p", "planner:=nearest", "-p", "predictor:=observed",
                                         "-p", "use_sim_time:=true", "--duration", "90", "--exit-when-finished",
                                         "--out", str(tmp_path / "node")], env=env, capture_output=True, text=True,
                              timeout=150)
        robot_out, _ = robot.communicate(timeout=150)
    finally:
        robot.kill()
    assert node.returncode == 0, node.stdout + node.stderr
    assert robot.returncode == 0, robot_out
    run = json.loads((tmp_path / "robot" / "run.json").read_text())
    summary = json.loads((tmp_path / "node" / "summary.json").read_text())
    assert run["finished_s"] is not None and run["goals_in_walls"] == 0 and run["coverage"][-1] > 0.95
    assert run["frontier_gone_s"] is not None and 0.0 <= run["finished_s"] - run["frontier_gone_s"] <= 10.0
    assert summary["steps"] > 50 and summary["goals_sent"] >= 1 and summary["latency_ms"]["p99"] < 1000
    assert summary["states"][-1][1] == "done"


@pytest.mark.slow
def test_the_node_on_dds_answers_a_robot_and_its_operator_and_records_a_replayable_run(tmp_path):
    pytest.importorskip("cyclonedds")
    from superex_deploy.cli import main
    from superex_deploy.messages import MapFrame, OccupancyGridMessage
    from superex_deploy.ros import idl, outputs, qos
    from superex_deploy.ros.dds import RosParticipant, loopback_config
    from superex_deploy.ros.node import ExplorationNode
    from superex_deploy.sim.robot import TfSample

    domain = 20 + os.getpid() % 80
    record = tmp_path / "node.mcap"
    frame = MapFrame((80, 80), 0.1, (0.0, 0.0))
    slam = np.full(frame.shape, -1, np.int8)
    slam[36:45, 10:71] = 0
    slam[35, 9:72] = slam[45, 9:72] = slam[36:45, 10] = 100  # a corridor open to the east
    node = ExplorationNode(NodeParams(**NEAREST, record=str(record), status_period=0.2), domain_id=domain,
                           config=loopback_config())
    robot = RosParticipant("robot", domain_id=domain, config=loopback_config())
    try:
        node.start()
        publish = {name: robot.publisher(topic, kind, profile) for name, topic, kind, profile in (
            ("map", "/map", idl.OccupancyGrid, qos.MAP), ("scan", "/scan", idl.LaserScan, qos.SENSOR_DATA),
            ("tf", "/tf", idl.TFMessage, qos.TF), ("static", "/tf_static", idl.TFMessage, qos.TF_STATIC),
            ("pause", "/superex/pause", idl.Empty, qos.DEFAULT), ("resume", "/superex/resume", idl.Empty, qos.DEFAULT),
            ("bounds", "/superex/bounds", idl.PolygonStamped, qos.DEFAULT))}
        goals = robot.subscription("/goal_pose", idl.PoseStamped, qos.DEFAULT)
        status = robot.subscription("/superex/status", idl.ExplorerStatus, qos.DEFAULT)
        x, y = frame.centre_xy((40, 30))
        t0 = time.time()
        publish["static"].publish(outputs.tf_message([TfSample(t0, "base_link", "laser", 0.0, 0.0, 0.0)]))
        grid = OccupancyGridMessage.from_frame_grid(frame, slam)
        publish["map"].publish(outputs.grid_message(OccupancyGridMessage(
            grid.resolution_m, grid.width, grid.height, grid.origin_xy, grid.data, stamp_s=t0), "map"))
        scan = LaserScan(0.0, 2 * math.pi / 360, 0.05, 4.0, np.full(360, np.inf, np.float32))

        def drive(seconds, until):
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                now = time.time()
                publish["tf"].publish(outputs.tf_message([TfSample(now, "map", "odom", 0.0, 0.0, 0.0),
                                                          TfSample(now, "odom", "base_link", x, y, 0.0)]))
                publish["scan"].publish(outputs.scan_message(scan, now, "laser"))
                time.sleep(0.1)
                got = [m for m, _ in status.take()] + [m for m, _ in goals.take()]
                if any(until(m) for m in got):
                    return True
            return False

        assert drive(20.0, lambda m: isinstance(m, idl.PoseStamped) and m.pose.position.x > 6.5)  # the east end
        publish["pause"].publish(idl.Empty())
        assert drive(10.0, lambda m: isinstance(m, idl.ExplorerStatus) and m.state == "paused")
        publish["resume"].publish(idl.Empty())
        assert drive(10.0, lambda m: isinstance(m, idl.ExplorerStatus) and m.state == "exploring")
        tiny = idl.PolygonStamped(header=outputs.header(time.time(), "map"), polygon=idl.Polygon(points=[
            idl.Point32(x=x, y=y, z=0.0), idl.Point32(x=x + 0.1, y=y, z=0.0), idl.Point32(x=x, y=y + 0.1, z=0.0)]))
        publish["bounds"].publish(tiny)
        assert drive(10.0, lambda m: isinstance(m, idl.ExplorerStatus) and "smaller than the robot" in m.reason)
    finally:
        robot.close()
        node.close()
    assert node.steps >= 3 and node.goals_sent >= 1 and record.exists(), node.summary()
    assert main(["replay", str(record), "--out", str(tmp_path / "replay")]) == 0


def test_a_slam_map_at_a_resolution_the_models_do_not_serve_gets_the_nearest_they_do():
    # A real SLAM map of 0.0504 m: 0.2.0's lama_bp refused it ("won't serve"); the node runs at 0.05 m and
    # resamples the map onto its cells.
    from superex_deploy.messages import MapFrame, OccupancyGridMessage
    from superex_deploy.onboard.prediction.scale import servable_resolution

    frame = MapFrame((100, 100), 0.0504, (-2.52, -2.52))
    slam = np.full(frame.shape, -1, np.int8)
    slam[30:70, 30:70] = 0
    grid = OccupancyGridMessage.from_frame_grid(frame, slam)
    core = ExplorationCore(NodeParams(costmap_topic="/map", planner="nearest", predictor="lama_los"))
    core.add_transform("base_link", "laser", 0.0, Transform(), static=True)
    core.add_transform("map", "base_link", 0.0, Transform(), static=True)
    core.add_map(OccupancyGridMessage(grid.resolution_m, grid.width, grid.height, grid.origin_xy, grid.data,
                                      stamp_s=1.0))
    core.add_scan(1.0, "laser", _open_scan())
    step = core.step(1.0)
    assert step is not None and core.explorer.frame.resolution_m == 0.05 == servable_resolution(0.0504)
    assert step.command.goal_xy is not None
    core.explorer.close()


def test_a_spad_frame_is_stepped_with_the_scan_of_its_stamp():
    from superex_deploy.sim.world import World, WorldConfig
    from superex_deploy.spad_types import SpadConfig

    world = World(_rooms(), (20, 10), WorldConfig(spad=SpadConfig()))
    observation = world.observe()
    core = ExplorationCore(NodeParams(costmap_topic="", spad_topic="/spad", planner="nearest", predictor="lama_bp"))
    core.add_transform("base_link", "laser", 0.0, Transform(), static=True)
    core.add_transform("map", "base_link", 0.0, Transform.from_planar(observation.pose.x, observation.pose.y, 0.0),
                       static=True)
    core.add_spad(1.0 + 0.01, observation.spad)  # within spad_sync (0.05 s) of the scan
    core.add_scan(1.0, "laser", observation.scan)
    step = core.step(1.0)
    assert step.observation.spad is observation.spad
    assert core.explorer.spad_processing.evidence is not None and core.explorer.mapper.carved.any()
    core.add_spad(2.2, observation.spad)  # too far from the next scan's stamp: that scan steps alone
    core.add_scan(2.0, "laser", observation.scan)
    assert core.step(2.0).observation.spad is None
    core.explorer.close()
