"""The exploration node over DDS against the same pipeline in one process, and the node's latency.

* ``--loop``: eval floors x starts, each explored twice by the node's defaults (``superex`` planner, LaMa-LOS, the
  realtime profile) on the simulated robot (``superex_deploy.sim.robot``: SLAM map every 5 s, tf at 20 Hz, scans at
  10 Hz, the Nav2-like follower at ``--speed``): once **in one process** (``run_in_process``: the node's core stepped
  on every scan, the robot waiting for it) and once as **two processes over DDS** (``superex robot-sim`` paced at
  ``--rate`` times real time + ``superex node``, on the loopback). Per run: first-half coverage (mean coverage of the
  truth over the first half of ``--duration`` seconds; a finished run keeps its last coverage), when ``finished``
  came against when the SLAM stand-in's exact map last held a frontier the node's finish rule counts
  (``RobotRun.frontier_gone_s``), the largest reachable part of the floor still unseen then (the truth: a passage
  too narrow for the robot is known only once seen), goals in walls, collisions, and the node's latency (scan
  received -> goal published). Paired difference DDS - in-process
  with a bootstrap interval.
* ``--latency``: the largest eval floor upsampled x2 (0.05 m), ``--latency-seconds`` of simulated time, the node's
  defaults paced at 10 Hz: the in-process core's step times (paced at the scan rate by the wall clock) beside the DDS
  node's latency.

Results go to ``--out`` (``node.json`` / ``node.md``; every run in ``runs/NAME.json``, so a killed run resumes).
Times are this machine's (2 cores; the two processes and the LaMa worker share them).

    python scripts/bench_node.py --loop --latency --out benchmarks/node
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from superex_deploy.evaluation import bootstrap_interval, markdown_table, read_json, write_json, write_text

FLOORS = ("50045230", "50052750", "50010539")
LATENCY_MAP = "50015847"


def first_half(stamps, coverage, duration_s: float) -> float:
    """Mean coverage over ``[0, duration_s / 2]`` on the scan clock, a run that ended earlier holding its last."""
    stamps, coverage = np.asarray(stamps, float), np.asarray(coverage, float)
    grid = np.arange(0.0, duration_s / 2.0 + 1e-9, 0.1)
    if not len(stamps):
        return 0.0
    index = np.clip(np.searchsorted(stamps, grid, side="right") - 1, 0, len(stamps) - 1)
    return float(coverage[index].mean())


def _summary(run: dict, duration_s: float) -> dict:
    lag = None if run["finished_s"] is None or run["frontier_gone_s"] is None else \
        run["finished_s"] - run["frontier_gone_s"]
    return {"first_half": first_half(run["stamps_s"], run["coverage"], duration_s),
            "final": run["coverage"][-1] if run["coverage"] else 0.0, "finished_s": run["finished_s"],
            "gone_s": run["frontier_gone_s"], "finish_lag_s": lag, "unseen_at_finish_m2": run["unseen_at_finish_m2"],
            "goals": len(run["goals"]),
            "goals_in_walls": run["goals_in_walls"], "collisions": run["collisions"], "follower": run["follower"]}


def in_process(map_name: str, start: int, duration_s: float, speed: float, upsample: int = 1,
               pace_hz: float = 0.0, judge: bool = True) -> dict:
    """One run of the node's core and the simulated robot in this process; its :class:`RobotRun` as JSON plus the
    core's step times (ms)."""
    from superex_deploy.maps import load_map, start_poses
    from superex_deploy.ros.core import ExplorationCore
    from superex_deploy.ros.params import NodeParams
    from superex_deploy.sim.generated_floors import upsampled
    from superex_deploy.sim.robot import RobotSimConfig, run_in_process

    grid, cell = load_map(map_name), start_poses(map_name)[start]
    if upsample > 1:
        grid, cell = upsampled(grid, upsample), (cell[0] * upsample + upsample // 2, cell[1] * upsample + upsample // 2)
    core = ExplorationCore(NodeParams())
    steps, clock = [], [time.perf_counter()]

    def on_tick(robot, tick, outputs):
        if outputs is not None:
            steps.append(1e3 * sum(outputs.command.timings_s.values()))
        if pace_hz:
            clock[0] += 1.0 / pace_hz
            time.sleep(max(0.0, clock[0] - time.perf_counter()))

    wall = time.perf_counter()
    run = run_in_process(grid, cell, core, RobotSimConfig(speed_m_s=speed), duration_s=duration_s, on_tick=on_tick,
                         judge_every_s=0.5 if judge else 0.0)
    core.explorer.close()
    return {**run.to_json(), "step_ms": steps, "wall_s": time.perf_counter() - wall}


def over_dds(map_name: str, start: int, duration_s: float, speed: float, rate: float, upsample: int = 1,
             stop_when_finished: bool = True, judge: bool = True) -> dict:
    """One run of ``superex robot-sim`` and ``superex node`` as two processes on the loopback; the robot's run JSON
    plus the node's summary (latency, steps, states)."""
    superex = [sys.executable, "-m", "superex_deploy.cli"]
    env = dict(os.environ, ROS_DOMAIN_ID=str(150 + os.getpid() % 80))
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        robot = subprocess.Popen(
            superex + ["robot-sim", "--map", map_name, "--start", str(start), "--loopback", "--duration",
                       str(duration_s), "--rate", str(rate), "--speed", str(speed), "--resolution", str(0.1 / upsample),
                       "--out", str(folder / "robot"), "--judge-every", "0.5" if judge else "0"]
            + ([] if stop_when_finished else ["--keep-running"]),
            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        wall = time.perf_counter()
        node = subprocess.run(
            superex + ["node", "--loopback", "-p", "use_sim_time:=true", "--duration", str(duration_s / rate + 90),
                       "--out", str(folder / "node")] + (["--exit-when-finished"] if stop_when_finished else []),
            env=env, capture_output=True, text=True)
        robot_log, _ = robot.communicate(timeout=120)
        if node.returncode or robot.returncode:
            raise RuntimeError(f"the node ({node.returncode}) or the robot ({robot.returncode}) failed:\n"
                               f"{node.stdout}{node.stderr}\n{robot_log}")
        run = json.loads((folder / "robot" / "run.json").read_text())
        node_summary = json.loads((folder / "node" / "summary.json").read_text())
    latency = node_summary.pop("latency_ms")
    return {**run, "node": {k: node_summary[k] for k in ("steps", "goals_sent", "scans_received", "scans_dropped",
                                                         "steps_skipped")},
            "latency_ms": latency, "wall_s": time.perf_counter() - wall}


def _cached(path: Path, make):
    if path.exists():
        return read_json(path)
    result = make()
    write_json(path, result)
    return result


def _percentiles(values_ms) -> dict:
    values = np.asarray(values_ms, float)
    return {"mean": float(values.mean()), "p50": float(np.percentile(values, 50)),
            "p99": float(np.percentile(values, 99)), "max": float(values.max())} if len(values) else {}


def loop_part(out: Path, duration_s: float, speed: float, rate: float, floors) -> dict:
    rows = []
    for name in floors:
        for start in (0, 1):
            label = f"{name}_{start}"
            print(f"loop {label}: in process", flush=True)
            local = _cached(out / "runs" / f"{label}_inprocess.json",
                            lambda: in_process(name, start, duration_s, speed))
            print(f"loop {label}: over DDS", flush=True)
            remote = _cached(out / "runs" / f"{label}_dds.json",
                             lambda: over_dds(name, start, duration_s, speed, rate))
            rows.append({"scenario": label, "in_process": _summary(local, duration_s),
                         "dds": _summary(remote, duration_s), "dds_latency_ms": remote["latency_ms"],
                         "dds_node": remote["node"], "in_process_step_ms": _percentiles(local["step_ms"])})
    differences = [r["dds"]["first_half"] - r["in_process"]["first_half"] for r in rows]
    relative = [d / r["in_process"]["first_half"] for d, r in zip(differences, rows)]
    return {"rows": rows, "first_half_difference": float(np.mean(differences)),
            "first_half_difference_interval": list(bootstrap_interval(differences)),
            "first_half_relative": float(np.mean(relative)), "worst_relative": float(max(relative, key=abs)),
            "duration_s": duration_s, "speed_m_s": speed, "rate": rate}


def latency_part(out: Path, seconds: float, speed: float) -> dict:
    print("latency: in process at 0.05 m", flush=True)
    local = _cached(out / "runs" / "latency_inprocess.json",
                    lambda: in_process(LATENCY_MAP, 0, seconds, speed, upsample=2, pace_hz=10.0, judge=False))
    print("latency: over DDS at 0.05 m", flush=True)
    remote = _cached(out / "runs" / "latency_dds.json",
                     lambda: over_dds(LATENCY_MAP, 0, seconds, speed, 1.0, upsample=2, stop_when_finished=False,
                                      judge=False))
    return {"map": f"{LATENCY_MAP}@x2 (0.05 m)", "seconds": seconds, "in_process_step_ms": _percentiles(
        local["step_ms"]), "dds_latency_ms": remote["latency_ms"], "dds_node": remote["node"],
        "coverage": {"in_process": local["coverage"][-1], "dds": remote["coverage"][-1]}}


def _area(summary: dict) -> str:
    value = summary.get("unseen_at_finish_m2")
    return "-" if value is None else f"{value:.2f}"


def _report(result: dict) -> list[str]:
    lines = ["# The exploration node over DDS against the same pipeline in one process", ""]
    loop = result.get("loop")
    if loop:
        lines += [f"Node defaults (superex, LaMa-LOS, realtime profile), simulated robot at {loop['speed_m_s']} m/s, "
                  f"SLAM map every 5 s, tf 20 Hz, scans 10 Hz, {loop['duration_s']:.0f} s; DDS paced at "
                  f"{loop['rate']:g}x real time. First half: mean coverage over the first "
                  f"{loop['duration_s'] / 2:.0f} s.", ""]
        table = []
        for row in loop["rows"]:
            a, b = row["in_process"], row["dds"]
            lag = lambda s: "-" if s["finish_lag_s"] is None else f"{s['finish_lag_s']:+.1f}"
            when = lambda s: "-" if s["finished_s"] is None else f"{s['finished_s']:.1f}"
            table.append([row["scenario"], f"{a['first_half']:.3f}", f"{b['first_half']:.3f}",
                          f"{100 * (b['first_half'] - a['first_half']) / a['first_half']:+.1f}%",
                          f"{a['final']:.3f} / {b['final']:.3f}",
                          f"{when(a)} / {when(b)}", f"{lag(a)} / {lag(b)}",
                          f"{_area(a)} / {_area(b)}", f"{a['goals_in_walls']} / {b['goals_in_walls']}",
                          f"{row['dds_latency_ms'].get('p99', float('nan')):.1f}",
                          f"{row['dds_node']['scans_dropped'] / max(row['dds_node']['scans_received'], 1):.0%}"])
        lines += markdown_table(["scenario", "first half, in process", "over DDS", "DDS - in process",
                                 "final coverage", "finished (s)", "finished - no frontier left (s)",
                                 "unseen reachable at finish (m2)", "goals in walls",
                                 "node latency p99 (ms)", "scans the node dropped (busy)"], table)
        low, high = loop["first_half_difference_interval"]
        lines += ["", f"DDS - in process, first half: {loop['first_half_difference']:+.4f} [{low:+.4f}, {high:+.4f}] "
                      f"({100 * loop['first_half_relative']:+.1f} % on average, worst {100 * loop['worst_relative']:+.1f} %)",
                  ""]
    latency = result.get("latency")
    if latency:
        a, b = latency["in_process_step_ms"], latency["dds_latency_ms"]
        lines += [f"## Latency at 0.05 m ({latency['map']}, {latency['seconds']:.0f} s, node defaults, paced at 10 Hz)",
                  ""] + markdown_table(["", "mean (ms)", "p50", "p99", "max"], [
                      ["in process: the core's step", *(f"{a[k]:.1f}" for k in ("mean", "p50", "p99", "max"))],
                      ["over DDS: scan received -> goal published", *(f"{b[k]:.1f}" for k in ("mean", "p50", "p99",
                                                                                                "max"))]])
        lines += ["", f"Scans received / dropped by the node: {latency['dds_node']['scans_received']} / "
                      f"{latency['dds_node']['scans_dropped']}.", ""]
    return lines


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--loop", action="store_true")
    parser.add_argument("--latency", action="store_true")
    parser.add_argument("--floors", nargs="+", default=list(FLOORS))
    parser.add_argument("--duration", type=float, default=900.0)
    parser.add_argument("--speed", type=float, default=1.0)
    parser.add_argument("--rate", type=float, default=1.0)
    parser.add_argument("--latency-seconds", type=float, default=300.0)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/node"))
    args = parser.parse_args(argv)
    result = read_json(args.out / "node.json") if (args.out / "node.json").exists() else {}
    if args.loop:
        result["loop"] = loop_part(args.out, args.duration, args.speed, args.rate, args.floors)
    if args.latency:
        result["latency"] = latency_part(args.out, args.latency_seconds, args.speed)
    result["machine"] = "this project's 2-core sandbox"
    write_json(args.out / "node.json", result)
    write_text(args.out / "node.md", "\n".join(_report(result)) + "\n")
    print("\n".join(_report(result)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
