"""The onboard explorer fed only messages, as on a robot: LaserScan, the odometry pose and now and then a SLAM map in,
a goal out.

A small simulated robot (``superex_deploy.sim.robot.SimulatedRobot``: a LiDAR, a SLAM stand-in and a goal follower
on a generated 20 m x 14 m floor) publishes what a robot's drivers publish; the explorer (built with
``superex_deploy.pipeline.build_explorer``) gets those messages alone, on a small frame around its start that grows
as it sees more, and never the floor itself. The simulator's coverage, printed beside the explorer's own map, is
judged on the truth, outside the explorer. By default it runs until the explorer says ``finished`` (about 450 scans).

    python examples/explore_on_messages.py [--steps 500] [--every 50] [--planner nearest]
"""

import argparse
from itertools import chain

import numpy as np

from superex_deploy.maps import largest_region_start
from superex_deploy.messages import MapFrame, Observation, Pose2D
from superex_deploy.onboard import ExplorerConfig
from superex_deploy.onboard.mapping.growth import MapGrowth
from superex_deploy.pipeline import build_explorer
from superex_deploy.sim.generated_floors import FloorLayout, generate_floor
from superex_deploy.sim.robot import BASE_FRAME, RobotSimConfig, SimulatedRobot


def messages(robot: SimulatedRobot):
    """What the robot publishes, one scan at a time: (stamp, odometry pose, LaserScan, a SLAM map or None)."""
    while True:
        tick = robot.tick()  # 20 Hz transforms, a scan on every 2nd tick, a SLAM map every 5 s
        if tick.scan is not None:
            odom = next(t for t in tick.transforms if t.child == BASE_FRAME)  # map -> odom is the identity here
            yield tick.stamp_s, Pose2D(odom.x, odom.y, odom.yaw), tick.scan, tick.slam_map


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=500, help="at most this many scans (10 a second)")
    parser.add_argument("--every", type=int, default=50, help="print a line every this many scans")
    parser.add_argument("--planner", default="nearest", help="a planner's name (nearest, superex, ...)")
    args = parser.parse_args(argv)
    if args.steps < 1 or args.every < 1:
        parser.error("--steps and --every must be >= 1")

    floor = generate_floor(FloorLayout(width_m=20, height_m=14, room_depth_m=(3, 5), cross_corridors=1), seed=1)
    start = largest_region_start(floor, np.random.default_rng(0), min_clearance_m=0.5)  # a free cell, 0.5 m clear
    robot = SimulatedRobot(floor, start, RobotSimConfig(speed_m_s=1.0))  # the robot's side: it holds the truth
    published = messages(robot)
    first = next(published)
    frame = MapFrame.around(first[1].x, first[1].y, resolution_m=0.1, size_m=10.0)  # grows with what is seen
    coverage = []
    with build_explorer(frame, args.planner, "observed", cfg=ExplorerConfig(growth=MapGrowth())) as explorer:
        for step, (stamp, pose, scan, slam_map) in enumerate(chain([first], published), start=1):
            command = explorer.step(Observation(stamp_s=stamp, pose=pose, scan=scan, occupancy_grid=slam_map))
            if command.new_goal:
                robot.follower.set_goal(*command.goal_xy)  # as Nav2 takes /goal_pose
            coverage.append(robot.coverage())  # judged on the truth, on the robot's side
            if step % args.every == 0 or command.finished:
                known_m2 = np.count_nonzero(explorer.observed != -1) * explorer.frame.resolution_m ** 2
                print(f"scan {step:4d}  t {stamp:5.1f} s  {command.status:22s} grid {explorer.frame.shape[0]}x"
                      f"{explorer.frame.shape[1]}  known {known_m2:6.1f} m2  coverage {coverage[-1]:.1%}")
            if command.finished or step == args.steps:
                break
    print(f"final: {command.status} ({command.reason or 'goal set'}), {step} scans, coverage {coverage[-1]:.1%}, "
          f"finished {command.finished}")
    return {"coverage": coverage, "status": command.status, "finished": command.finished}


if __name__ == "__main__":
    main()
