"""``superex robot-sim``: a simulated ROS 2 robot on DDS (:mod:`superex_deploy.sim.robot_node`) for a closed loop on
one machine: a bundled floor plan, its LiDAR (and SPAD with ``--spad``), a SLAM stand-in publishing ``/map`` every
``--map-period`` seconds, tf at ``--tf-rate``, a goal follower on ``/goal_pose`` as Nav2's navigator, and ``/clock``.
Start it in one terminal and ``superex node`` in another::

    superex robot-sim --map 50052750 --start 0
    superex node -p planner:=superex

With ``--out DIR`` it writes ``DIR/run.json``: coverage per scan, goals (and how many lay in a wall), the node's
status changes, when it said ``finished`` and when the last reachable frontier went.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from superex_deploy.commands.options import add_noise_options, non_negative_int


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--map", required=True, help="bundled map name or an image / ROS YAML path")
    parser.add_argument("--start", type=non_negative_int, default=0, help="index of the map's start pose (0-3)")
    parser.add_argument("--pose", type=int, nargs=2, metavar=("ROW", "COL"), help="start cell instead of --start")
    parser.add_argument("--resolution", type=float, default=None, metavar="METRES",
                        help="the floor's cell size: a bundled floor (0.1 m) at 0.1 / K (K = 2..4: upsampled, a SLAM "
                             "grid), an image at this many metres per pixel (default: the map's own)")
    parser.add_argument("--duration", type=float, default=600.0, metavar="SECONDS",
                        help="seconds of simulated time to run (default: 600)")
    parser.add_argument("--rate", type=float, default=1.0,
                        help="simulated time per wall second (default: 1, real time; at another rate give the node "
                             "-p use_sim_time:=true)")
    parser.add_argument("--map-period", type=float, default=5.0, metavar="SECONDS",
                        help="the SLAM stand-in publishes /map every this many seconds (default: 5)")
    parser.add_argument("--tf-rate", type=float, default=20.0, metavar="HZ", help="transforms per second (default 20)")
    parser.add_argument("--scan-rate", type=float, default=10.0, metavar="HZ", help="scans per second (default 10)")
    parser.add_argument("--speed", type=float, default=0.5, metavar="M_PER_S", help="the follower's speed (default 0.5)")
    parser.add_argument("--goal-failure-rate", type=float, default=0.0,
                        help="the chance that the follower aborts a goal (default 0)")
    parser.add_argument("--spad", action="store_true", help="also publish SPAD frames on /spad")
    parser.add_argument("--finish-frontier", type=float, default=0.5, metavar="METRES",
                        help="the frontier size the node's finished is judged against (its min_frontier_size)")
    parser.add_argument("--judge-every", type=float, default=0.5, metavar="SECONDS",
                        help="how often the run's log checks whether a reachable frontier is left (a search over the "
                             "floor, for judging the node's finished; 0: never)")
    parser.add_argument("--keep-running", action="store_true",
                        help="go on after the node says finished (default: stop a second after)")
    parser.add_argument("--namespace", default="", help="the ROS namespace")
    parser.add_argument("--domain-id", type=int, default=None, help="the DDS domain (default: ROS_DOMAIN_ID, else 0)")
    parser.add_argument("--loopback", action="store_true", help="keep DDS on 127.0.0.1 (see superex node)")
    parser.add_argument("--wait-for-node", type=float, default=60.0, metavar="SECONDS",
                        help="wait this long for a node to subscribe before starting the clock (0: do not wait)")
    parser.add_argument("--seed", type=non_negative_int, default=0)
    parser.add_argument("--out", type=Path, default=None, help="write run.json here")
    add_noise_options(parser)


def run(args: argparse.Namespace) -> int:
    from superex_deploy.commands.options import check_output_folder, load_floor, noise_options
    from superex_deploy.sim.robot import RobotSimConfig
    from superex_deploy.spad_types import SpadConfig, spad_preset

    grid, start = load_floor(args.map, args.resolution, args.start, args.pose, seed=args.seed,
                             command="superex robot-sim")
    noise = noise_options(args).seeded(args.seed)
    spad = None
    if args.spad:
        spad = SpadConfig() if noise.spad == "off" else spad_preset(noise.spad, SpadConfig())
    cfg = RobotSimConfig(scan_hz=args.scan_rate, tf_hz=args.tf_rate, map_period_s=args.map_period,
                         speed_m_s=args.speed, goal_failure_rate=args.goal_failure_rate, spad=spad, seed=args.seed,
                         noise=noise)
    if not (math.isfinite(args.judge_every) and args.judge_every >= 0):
        raise ValueError(f"--judge-every must be a number of seconds >= 0, got {args.judge_every}")
    out = None if args.out is None else check_output_folder(args.out)
    try:
        from superex_deploy.ros.dds import loopback_config
        from superex_deploy.sim.robot_node import SimulatedRobotNode
    except ModuleNotFoundError as error:
        raise ModuleNotFoundError(f"superex robot-sim needs {error.name}: pip install 'superex[ros2]'",
                                  name=error.name) from error
    with SimulatedRobotNode(grid, start, cfg, args.finish_frontier, args.namespace, args.domain_id,
                            config=loopback_config() if args.loopback else None,
                            judge_every_s=args.judge_every) as robot:
        print(f"superex robot-sim: {grid.name} from cell {start}, domain {robot.participant.domain_id}; waiting for "
              f"a node on /scan and /goal_pose", flush=True)
        if args.wait_for_node and not robot.wait_for_node(args.wait_for_node):
            raise ValueError(f"no node subscribed to /scan and published /goal_pose within {args.wait_for_node:g} s "
                             f"(start `superex node`, on the same ROS_DOMAIN_ID)")
        result = None
        try:
            result = robot.run(args.duration, args.rate, stop_when_finished=not args.keep_running)
        except KeyboardInterrupt as stop:
            result = robot.log.result()
            stop.kept = "" if out is None else f"wrote {out / 'run.json'}"
            raise
        finally:
            if out is not None and result is not None:
                out.mkdir(parents=True, exist_ok=True)
                (out / "run.json").write_text(json.dumps(result.to_json(), indent=1) + "\n")
    print(f"superex robot-sim: {len(result.stamps_s)} scans, coverage {result.coverage[-1]:.1%}, goals "
          f"{len(result.goals)} ({result.goals_in_walls} in walls), finished at "
          f"{'-' if result.finished_s is None else f'{result.finished_s:.1f} s'}", flush=True)
    return 0
