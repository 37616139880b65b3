"""``superex node``: the exploration node a ROS 2 robot runs (:mod:`superex_deploy.ros.node`), on DDS, with no ROS
install: the SLAM map, the scans and tf in, Nav2 goals out, a status topic, operator commands.

Parameters come from a ROS 2 params file (``--params-file``, the node's section or ``/**``) and ``-p NAME:=VALUE``
overrides, as ``ros2 run`` takes them (:class:`~superex_deploy.ros.params.NodeParams`; ``--print-params`` writes a
file with every one and its meaning). It runs until Ctrl-C / SIGTERM (or ``--duration`` seconds, or with
``--exit-when-finished`` once the exploration is done); with ``--out DIR`` it writes ``DIR/summary.json``: steps,
goals, the latency per step (scan received -> goal published: mean, p50, p99, max in ms), scans received and
dropped, the states the status went through and when ``finished`` first held.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--params-file", type=Path, default=None, help="a ROS 2 params file (YAML)")
    parser.add_argument("-p", "--param", action="append", default=[], metavar="NAME:=VALUE",
                        help="set one parameter (YAML value: -p planner:=nearest -p bounds:=[0,0,10,0,10,8])")
    parser.add_argument("--node-name", default="superex", help="the ROS node name (default: superex)")
    parser.add_argument("--namespace", default="", help="the ROS namespace (topics resolve under it)")
    parser.add_argument("--domain-id", type=int, default=None, help="the DDS domain (default: ROS_DOMAIN_ID, else 0)")
    parser.add_argument("--loopback", action="store_true",
                        help="keep DDS on 127.0.0.1 (one machine, no network; a ROS 2 node there needs "
                             "ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST)")
    parser.add_argument("--models", type=Path, default=None, help="folder of exported models (default: installed)")
    parser.add_argument("--duration", type=float, default=None, metavar="SECONDS",
                        help="stop after this many seconds of wall time (default: run until stopped)")
    parser.add_argument("--exit-when-finished", action="store_true",
                        help="stop once the exploration is finished (the status says done)")
    parser.add_argument("--out", type=Path, default=None, help="write summary.json here when the node stops")
    parser.add_argument("--print-params", action="store_true",
                        help="print a params file with every parameter (after --params-file and -p) and exit")


def parse_overrides(pairs: list[str]) -> dict:
    """``NAME:=VALUE`` pairs as a dict, each value read as YAML (numbers, true/false, lists, strings).

    Raises:
        ValueError: a pair without ``:=``, or a name given twice.
    """
    import yaml

    values = {}
    for pair in pairs:
        name, sep, text = pair.partition(":=")
        if not sep or not name:
            raise ValueError(f"-p takes NAME:=VALUE (as ros2 run's -p), got {pair!r}")
        if name in values:
            raise ValueError(f"-p {name} is given twice")
        try:
            values[name] = yaml.safe_load(text) if text else ""
        except yaml.YAMLError as error:
            raise ValueError(f"-p {name}:={text}: not a YAML value ({error})") from None
        if values[name] is None:
            values[name] = ""
    return values


def run(args: argparse.Namespace) -> int:
    from superex_deploy.ros.params import load_params

    params = load_params(args.params_file, args.node_name, **parse_overrides(args.param))
    if args.print_params:
        sys.stdout.write(params.to_yaml(args.node_name))
        return 0
    if args.duration is not None and not args.duration > 0:
        raise ValueError(f"--duration must be a positive number of seconds, got {args.duration}")
    if args.out is not None:
        from superex_deploy.commands.options import check_output_folder

        args.out = check_output_folder(args.out)
    try:
        from superex_deploy.ros.dds import loopback_config
        from superex_deploy.ros.node import ExplorationNode
    except ModuleNotFoundError as error:
        raise ModuleNotFoundError(f"superex node needs {error.name}: pip install 'superex[ros2]'",
                                  name=error.name) from error
    node = ExplorationNode(params, args.node_name, args.namespace, args.domain_id,
                           config=loopback_config() if args.loopback else None, models=args.models)
    print(f"superex node: /{args.node_name.lstrip('/')} on domain {node.participant.domain_id}: "
          f"{params.planner} / {params.predictor_name}, scans {params.scan_topic}, map {params.costmap_topic or '-'},"
          f" goals {params.goal_topic}", flush=True)
    stop = None
    try:
        end = float("inf") if args.duration is None else time.monotonic() + args.duration
        node.start()
        while time.monotonic() < end:
            time.sleep(0.1)
            if node.error is not None:
                break
            if args.exit_when_finished and node.finished_at_s is not None and node.states and \
                    node.states[-1][1] == "done":
                break
    except KeyboardInterrupt as interrupted:
        stop = interrupted
    finally:
        try:
            node.close()
        finally:
            if args.out is not None:
                args.out.mkdir(parents=True, exist_ok=True)
                node.write_summary(args.out / "summary.json")
    summary = node.summary()
    latency = summary["latency_ms"]
    print(f"superex node: {summary['steps']} steps, {summary['goals_sent']} goals, latency p99 "
          f"{latency.get('p99', float('nan')):.1f} ms, last state {summary['states'][-1][1] if summary['states'] else '-'}",
          flush=True)
    if stop is not None:
        stop.kept = "the node was closed" + (f"; wrote {args.out / 'summary.json'}" if args.out else "")
        raise stop
    return 0
