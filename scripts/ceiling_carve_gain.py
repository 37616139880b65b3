"""The ceiling of an NLOS-aware goal choice (would a planner that asks what the SPAD will carve explore faster?):
the SuperEx planner given the TRUE carve gain of each frontier (from the simulator) against today's planner, the
``superex`` pipeline paired by scenario on train floors.

Today's planner scores a frontier by the unknown cells it expects to see in line of sight along the path to it
(:class:`~superex_deploy.onboard.planning.planners.superex.SuperexPlanner`): a goal beside a long wall that would
carve a whole hidden room scores like any other. The ceiling planner (:class:`TrueCarveGainPlanner`) adds to each
frontier's gain ``--weight`` times the number of cells the onboard carving would carve from the frontier's goal cell
that are unknown in the explorer's current map (carved cells are FREE in it already, so they are not counted
twice): a noise-free SPAD scan simulated there on the true grid (:func:`superex_deploy.sim.spad.simulate_scan`,
the episode's :class:`~superex_deploy.spad_types.SpadConfig`) and carved as the robot carves
(:func:`~superex_deploy.onboard.nlos.estimate_los` and :func:`~superex_deploy.onboard.nlos.carve`, the episode's
:class:`~superex_deploy.onboard.nlos.NlosConfig`). The simulator's truth is allowed here: it is a ceiling, never
onboard code. A cell both seen and carved from the goal counts in both terms (the gains are added, not united).

The carved set of a cell reads neither the map nor the step (the scan is noise-free, the carving reads no known
cells, the pose is exact), so it is computed once per goal cell and episode and only its intersection with the
unknown cells is counted at each choice. ``--top-k K`` adds the carve gain to the K frontiers of largest
line-of-sight gain only (0: every frontier).

Both arms run the ``superex`` pipeline as it ships (:data:`superex_deploy.pipeline.PIPELINES`: LaMa-BP, SPAD
carving and Pix2Pix evidence, its profile on the simulated clock), the same seed, on the held-out train floors
(:func:`superex_deploy.evaluation.heldout_scenarios`: ``train_scenarios`` of the buildings the learned models never
trained on; never ``eval/``); the IoU evaluation is off (not measured here). The measure is the first-half AUC of
coverage counting carved cells, paired by scenario
(:func:`superex_deploy.evaluation.summary.paired_summary`, bootstrap 95 % interval). One JSON per episode in
``OUT/episodes/`` (a rerun skips those already there); ``OUT/ceiling.md`` and ``OUT/ceiling.json`` are written
from the pairs finished so far (``--report`` writes them without running anything).

    NUMBA_NUM_THREADS=1 PYTHONPATH=. .venv/bin/python scripts/ceiling_carve_gain.py --scenarios 6 --steps 400 \\
        --out benchmarks/carve_gain_ceiling

``--arm today`` / ``--arm second`` run one arm (two processes on one ``--out``). The planner given its **onboard
estimate** of the carve gain instead of the truth (second arm ``estimate``, ``OUT/episodes/estimate/``) ran at commit
5ef5f36 (``--estimate``; the estimate was slower on train and left the package); ``--report --estimate`` rewrites
those folders' reports from their episodes.
"""

from __future__ import annotations

import argparse
import time
from collections import OrderedDict
from pathlib import Path
from typing import Optional

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PIPELINE = "superex"
ARMS = ("today", "ceiling")
"""The two arms: today's planner, and the planner given the true carve gain."""
ESTIMATE = "estimate"
"""The second arm of the onboard estimate's runs (commit :data:`ESTIMATE_COMMIT`): the shipped planner with an
onboard estimate of the NLOS gain in place of the true one; only reported now."""
ESTIMATE_COMMIT = "5ef5f36"
"""The commit whose ``--estimate`` ran the estimate arm (``benchmarks/carve_gain_ceiling/estimate*/``)."""
VIEWPOINTS = ("goal", "path")
"""Where the carve gain is carved from: the frontier's goal cell, or the pathwise gain's viewpoints."""


class TrueCarveGain:
    """The cells the onboard carving would carve from a viewpoint cell, from a scan simulated on the true grid.

    Args:
        grid: the true :class:`~superex_deploy.maps.OccupancyGrid` (the world's).
        spad: the episode's :class:`~superex_deploy.spad_types.SpadConfig` (noise, if on, seeded by the cell).
        nlos_cfg: the episode's :class:`~superex_deploy.onboard.nlos.NlosConfig`.
        cache_size: carved sets kept (least recently used dropped first).

    Attributes:
        scans: scans simulated and carved so far; ``seconds``: time spent on them.
    """

    def __init__(self, grid, spad, nlos_cfg, cache_size: int = 4096):
        self.grid, self.spad, self.nlos_cfg = grid, spad, nlos_cfg
        self.cache_size = int(cache_size)
        self._cache: OrderedDict = OrderedDict()
        self.scans, self.seconds = 0, 0.0

    def carved_flat(self, cell_rc) -> np.ndarray:
        """int64 ``[M]`` flat indices of the cells carved from ``cell_rc`` (empty for a cell in a true wall)."""
        from superex_deploy.onboard.nlos import carve, estimate_los
        from superex_deploy.sim.spad import simulate_scan

        key = (int(cell_rc[0]), int(cell_rc[1]))
        if key in self._cache:
            self._cache.move_to_end(key)
            return self._cache[key]
        clock = time.perf_counter()
        if self.grid.occupied[key] or not self.grid.valid[key]:
            flat = np.zeros(0, np.int64)
        else:
            rng = np.random.default_rng(key[0] * self.grid.shape[1] + key[1]) if self.spad.noise.enabled else None
            scan = simulate_scan(self.grid, key, self.spad, rng=rng)
            flat = np.flatnonzero(carve(scan, estimate_los(scan, self.nlos_cfg), self.nlos_cfg)).astype(np.int64)
        self.scans += 1
        self.seconds += time.perf_counter() - clock
        self._cache[key] = flat
        if len(self._cache) > self.cache_size:
            self._cache.popitem(last=False)
        return flat

    def gains(self, observed: np.ndarray, cells_rc, offsets=None) -> np.ndarray:
        """float64 ``[N]``: for each cell of int ``[V, 2]`` ``cells_rc`` (each group ``cells_rc[offsets[i]:offsets[i +
        1]]`` with ``offsets`` int ``[N + 1]``: the union of the group's carved sets), the cells carved from it that
        are UNKNOWN in int8 ``observed`` (the explorer's map, carved cells FREE in it).

        Raises:
            ValueError: a map of another shape than the true grid (the planner's grid must be the world's).
        """
        from superex_deploy.onboard.types import UNKNOWN

        if observed.shape != self.grid.shape:
            raise ValueError(f"the planner's map is {observed.shape}, the true grid {self.grid.shape}: the ceiling "
                             f"needs the planning grid to be the world's (one cell per block, no growth)")
        flat_unknown = (observed == UNKNOWN).ravel()
        carved = [self.carved_flat(cell) for cell in cells_rc]
        if offsets is None:
            return np.array([np.count_nonzero(flat_unknown[flat]) for flat in carved], float)
        groups = [np.unique(np.concatenate(carved[a:b] or [np.zeros(0, np.int64)]))
                  for a, b in zip(offsets[:-1], offsets[1:])]
        return np.array([np.count_nonzero(flat_unknown[flat]) for flat in groups], float)


def ceiling_planner(carve_gain: TrueCarveGain, weight: float = 1.0, top_k: int = 0, viewpoints: str = "goal"):
    """The SuperEx planner (its shipped config) whose gain adds ``weight`` x the true carve gain of each frontier
    (of the ``top_k`` frontiers of largest line-of-sight gain; 0: all): carved from its goal cell
    (``viewpoints="goal"``), or the union of what is carved from the viewpoints of the pathwise gain (``"path"``:
    every ``sense_every_m`` along the least-cost path, and the goal cell). Its ``stats`` count the choices, the
    frontiers scored and the mean line-of-sight and carve gains."""
    from superex_deploy.onboard.planning.planners import SuperexPlanner
    from superex_deploy.onboard.planning.planners.superex import path_viewpoints

    if viewpoints not in VIEWPOINTS:
        raise ValueError(f"viewpoints must be one of {VIEWPOINTS}, got {viewpoints!r}")

    class TrueCarveGainPlanner(SuperexPlanner):
        name = "superex_true_carve"

        def __init__(self):
            super().__init__()
            self.stats = {"calls": 0, "frontiers": 0, "scored": 0, "los_gain": 0.0, "carve_gain": 0.0}

        def gains(self, ctx, prediction, frontiers) -> np.ndarray:
            base = np.asarray(super().gains(ctx, prediction, frontiers), float)
            picked = np.argsort(-base, kind="stable")
            if top_k:
                picked = picked[:top_k]
            cells = [frontiers[i].cell_rc for i in picked]
            if viewpoints == "goal":
                extra = carve_gain.gains(np.asarray(ctx.observed), cells)
            else:
                every = max(1, int(round(self.cfg.sense_every_m / ctx.resolution_m)))
                path_cells, offsets = path_viewpoints(ctx.travel_cost, np.array(cells, np.int64).reshape(-1, 2),
                                                      every)
                extra = carve_gain.gains(np.asarray(ctx.observed), [tuple(c) for c in path_cells.tolist()],
                                         offsets)
            out = base.copy()
            out[picked] += weight * extra
            s = self.stats
            s["calls"] += 1
            s["frontiers"] += len(frontiers)
            s["scored"] += len(picked)
            s["los_gain"] += float(base[picked].sum())
            s["carve_gain"] += float(extra.sum())
            return out

    return TrueCarveGainPlanner()


def _episode_path(out: Path, arm: str, scenario) -> Path:
    return out / "episodes" / arm / f"{scenario.map_name}_{scenario.start_index}.json"


def run_arm(scenario, arm: str, steps: int, weight: float, top_k: int, viewpoints: str = "goal", seed: int = 0
            ) -> dict:
    """One episode of the ``superex`` pipeline on ``scenario``, with today's planner or the ceiling's; its JSON
    summary (no poses, no per-step stage times) with ``start_index``, ``arm``, ``seconds`` and, for the ceiling,
    ``carve_gain`` (the planner's counts and the time its scans took)."""
    from superex_deploy.evaluation import run_benchmark_episode
    from superex_deploy.maps import load_map
    from superex_deploy.onboard.planning.planners import make_planner
    from superex_deploy.pipeline import PIPELINES, PROFILES, make_sensing

    pipeline = PIPELINES[PIPELINE]
    profile = PROFILES[pipeline.profile]
    grid = load_map(scenario.map_name)
    sensing = make_sensing(pipeline.predictor, pipeline.spad, seed, profile=profile)
    carve_gain = None
    if arm == "today":
        planner = make_planner(pipeline.planner)
    else:
        carve_gain = TrueCarveGain(grid, sensing.spad, sensing.nlos_cfg)
        planner = ceiling_planner(carve_gain, weight, top_k, viewpoints)
    run = run_benchmark_episode(grid, scenario.start_rc, planner, pipeline.predictor, steps=steps, seed=seed,
                                cfg=profile.episode_config(iou_every=0), profile=profile, sensing=sensing)
    summary = run.result.to_json()
    for key in ("poses", "timings_s", "evaluation_s", "simulation_s"):
        summary.pop(key)
    summary.update(start_index=scenario.start_index, arm=arm, seconds=run.seconds, pipeline=PIPELINE)
    if carve_gain is not None:
        summary["carve_gain"] = {**planner.stats, "scans": carve_gain.scans, "scan_seconds": carve_gain.seconds,
                                 "weight": weight, "top_k": top_k, "viewpoints": viewpoints}
    return summary


def _first_other_goal(today: dict, ceiling: dict) -> Optional[int]:
    """The step of the first goal choice where the two episodes differ (step or cell), None if none did."""
    goals = [list(zip(e["goals"]["steps"], map(tuple, e["goals"]["cells"]))) for e in (today, ceiling)]
    for a, b in zip(*goals):
        if a != b:
            return int(min(a[0], b[0]))
    if len(goals[0]) != len(goals[1]):
        shorter = min(goals, key=len)
        return int(max(goals, key=len)[len(shorter)][0])
    return None


def summarise(out: Path, scenarios, steps: int, weight: float, top_k: int, viewpoints: str = "goal",
              starts: int = 1, first_half_only: bool = False, second: str = "ceiling"
              ) -> Optional[tuple[dict, str]]:
    """``(ceiling.json's dict, ceiling.md's text)`` of the pairs finished in ``OUT/episodes`` (both arms of a
    scenario), in the order of ``scenarios``; None if none. ``starts`` (seeded starts per floor) and
    ``first_half_only`` (the episodes ran ``steps // 2`` steps, all the first-half AUC of a ``steps`` budget
    reads) are recorded in the JSON (``starts``, ``steps_run``) and the text when not 1 / False. ``second``: the
    arm paired with today's, ``"ceiling"`` or :data:`ESTIMATE` (its keys and words then say so).

    Raises:
        ValueError: an episode ran with other settings, or fewer steps than the measure reads.
    """
    from superex_deploy.evaluation import markdown_table, read_json
    from superex_deploy.evaluation.metrics import scenario_metrics
    from superex_deploy.evaluation.summary import paired_summary

    arms = ("today", second)
    pairs = [(s, [read_json(_episode_path(out, arm, s)) for arm in arms]) for s in scenarios
             if all(_episode_path(out, arm, s).is_file() for arm in arms)]
    if not pairs:
        return None
    rows, per = [], []
    for s, (today, ceiling) in pairs:
        for e in (today, ceiling):
            if len(e["coverage_with_carving"]) < steps // 2 and not e["finished"]:
                raise ValueError(f"{s.map_name} #{s.start_index} {e['arm']}: "
                                 f"{len(e['coverage_with_carving'])} steps run, the first half of {steps} reads "
                                 f"{steps // 2}")
        a, b = (scenario_metrics(e, steps)["auc_first_half"] for e in (today, ceiling))
        stats = ceiling["carve_gain"]
        ran = (stats["weight"], stats["top_k"], stats.get("viewpoints", "goal"))  # "goal" before the option
        if ran != (weight, top_k, viewpoints):
            raise ValueError(f"{_episode_path(out, second, s)} ran with (weight, top-k, viewpoints) {ran}, not "
                             f"{(weight, top_k, viewpoints)}: give its settings or another --out")
        per.append({"map": s.map_name, "start_index": s.start_index, "start_rc": list(s.start_rc),
                    "auc_today": a, f"auc_{second}": b, "difference": b - a,
                    "first_other_goal_step": _first_other_goal(today, ceiling),
                    "goals_today": len(today["goals"]["steps"]), f"goals_{second}": len(ceiling["goals"]["steps"]),
                    "mean_los_gain": stats["los_gain"] / max(stats["scored"], 1),
                    "mean_carve_gain": stats["carve_gain"] / max(stats["scored"], 1),
                    "choices": stats["calls"], "scans": stats["scans"], "scan_seconds": stats["scan_seconds"],
                    "seconds": [today["seconds"], ceiling["seconds"]]})
        other = per[-1]["first_other_goal_step"]
        rows.append([f"{s.map_name} #{s.start_index}", f"{100 * a:.2f}", f"{100 * b:.2f}", f"{100 * (b - a):+.2f}",
                     "-" if other is None else other, f"{per[-1]['mean_los_gain']:.0f}",
                     f"{per[-1]['mean_carve_gain']:.0f}"])
    paired = paired_summary([e for _, (e, _) in pairs], [e for _, (_, e) in pairs], steps)["auc_first_half"]
    result = {"pipeline": PIPELINE, **({"second_arm": second} if second != "ceiling" else {}), "steps": steps,
              "weight": weight, "top_k": top_k, "viewpoints": viewpoints,
              "seed": 0, **({"starts": starts} if starts != 1 else {}),
              **({"steps_run": steps // 2} if first_half_only else {}),
              "scenarios_planned": len(scenarios), "scenarios_finished": len(pairs),
              "complete": len(pairs) == len(scenarios),
              "auc_first_half": {"today": float(np.mean([p["auc_today"] for p in per])),
                                 second: float(np.mean([p[f"auc_{second}"] for p in per])),
                                 "difference": paired["mean"], "interval": [paired["low"], paired["high"]],
                                 "relative": paired["ratio"], "better": paired["better"], "worse": paired["worse"],
                                 "tied": paired["tied"]},
              "per_scenario": per}
    status = ("" if result["complete"] else
              f" **Partial: {len(pairs)} of {len(scenarios)} planned scenarios finished.**")
    scored = "every frontier" if not top_k else f"the {top_k} frontiers of largest line-of-sight gain"
    scored += ", carved from the goal cell" if viewpoints == "goal" else ", carved along the path (pathwise viewpoints)"
    floors = "held-out train floors" + (f" ({starts} seeded starts per floor)" if starts != 1 else "")
    budget = (f"a {steps}-step budget of which the episodes ran the first {steps // 2} steps, all the measure "
              f"reads (an episode does not depend on its budget)" if first_half_only else f"{steps} steps")
    given, gain = (("given the true carve gain", "true carve gains") if second == "ceiling" else
                   ("with its onboard estimate of the carve gain", "estimated carve gains"))
    lines = [f"The SuperEx planner {given} (weight {weight:g}, {scored}) against today's, the "
             f"`{PIPELINE}` pipeline on {floors}, {budget}, seed 0, paired by scenario. "
             f"First-half AUC counting carved cells (steps 1-{steps // 2}, percent); the step of the first goal "
             f"the two arms chose differently (- : none); the mean line-of-sight and {gain} of the "
             f"frontiers the {second} scored (cells).{status}", ""]
    lines += markdown_table(["scenario", "AUC today", f"AUC {second}", "difference", "first other goal (step)",
                             "LOS gain", "carve gain"], rows, ["-", "---:", "---:", "---:", "---:", "---:", "---:"])
    d = result["auc_first_half"]
    lines += ["", f"Paired mean difference ({second} - today): **{100 * d['difference']:+.2f} points** "
                  f"[{100 * d['interval'][0]:+.2f}, {100 * d['interval'][1]:+.2f}] (bootstrap 95 %), "
                  f"**{100 * d['relative']:+.1f} %** relative (AUC {100 * d['today']:.2f} -> "
                  f"{100 * d[second]:.2f}); "
                  f"better / worse / tied: {d['better']} / {d['worse']} / {d['tied']} of {len(pairs)}."]
    return result, "\n".join(lines) + "\n"


def report(out: Path, scenarios, steps: int, weight: float, top_k: int, viewpoints: str = "goal",
           starts: int = 1, first_half_only: bool = False, second: str = "ceiling") -> Optional[dict]:
    """Write ``OUT/ceiling.md`` and ``OUT/ceiling.json`` (:func:`summarise`) and print the table; None (nothing
    written) if no pair is finished."""
    from superex_deploy.evaluation import write_json, write_text

    summary = summarise(out, scenarios, steps, weight, top_k, viewpoints, starts, first_half_only, second)
    if summary is None:
        return None
    result, text = summary
    write_text(out / "ceiling.md", text)
    write_json(out / "ceiling.json", result, newline=True)
    print(text, end="")
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", type=int, default=6,
                        help="held-out train floors (heldout_scenarios(N, STARTS): STARTS seeded starts on each)")
    parser.add_argument("--starts", type=int, default=1, help="seeded starts per floor (the k-th: start index k)")
    parser.add_argument("--steps", type=int, default=400, help="step budget of each episode")
    parser.add_argument("--weight", type=float, default=1.0,
                        help="weight of a carved cell in the gain (1: a carved cell counts like a seen one)")
    parser.add_argument("--top-k", type=int, default=0,
                        help="add the carve gain to the K frontiers of largest line-of-sight gain only (0: all)")
    parser.add_argument("--viewpoints", choices=VIEWPOINTS, default="goal",
                        help="carve from the frontier's goal cell, or from the pathwise gain's viewpoints (union)")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "carve_gain_ceiling",
                        help="folder of the per-episode JSON (episodes/) and the report")
    parser.add_argument("--first-half-only", action="store_true",
                        help="run each episode STEPS // 2 steps: all the first-half AUC of a STEPS budget reads")
    parser.add_argument("--report", action="store_true", help="only write the report from the episodes there")
    parser.add_argument("--estimate", action="store_true",
                        help="with --report: the folder's second arm is the onboard estimate's (its runs: "
                             f"{ESTIMATE_COMMIT}:scripts/ceiling_carve_gain.py --estimate)")
    parser.add_argument("--arm", choices=("both", "today", "second"), default="both",
                        help="run only today's arm or only the second one (two processes on one --out)")
    args = parser.parse_args(argv)
    if (args.scenarios < 1 or args.starts < 1 or args.steps < 2 or args.top_k < 0
            or not np.isfinite(args.weight)):
        parser.error("--scenarios >= 1, --starts >= 1, --steps >= 2, --top-k >= 0 and a finite --weight")

    from tqdm import tqdm

    from superex_deploy.evaluation import first_half_auc, heldout_scenarios, write_json

    scenarios = heldout_scenarios(args.scenarios, args.starts)
    run_steps = args.steps // 2 if args.first_half_only else args.steps
    second = ESTIMATE if args.estimate else "ceiling"
    if args.estimate and not args.report:
        parser.error(f"--estimate only reports: the estimate left the package ({ESTIMATE_COMMIT} ran it)")
    options = (args.steps, args.weight, args.top_k, args.viewpoints, args.starts, args.first_half_only, second)
    arms = {"both": ("today", second), "today": ("today",), "second": (second,)}[args.arm]
    if not args.report:
        todo = [(s, arm) for s in scenarios for arm in arms if not _episode_path(args.out, arm, s).is_file()]
        for s, arm in tqdm(todo, desc="episodes", unit="episode"):
            summary = run_arm(s, arm, run_steps, args.weight, args.top_k, args.viewpoints)
            write_json(_episode_path(args.out, arm, s), summary)
            auc = first_half_auc(summary["coverage_with_carving"], args.steps)
            tqdm.write(f"{s.map_name} #{s.start_index} {arm}: first-half AUC {100 * auc:.2f} %, "
                       f"{summary['seconds']:.0f} s")
            report(args.out, scenarios, *options)
    if report(args.out, scenarios, *options) is None:
        print("no finished pair yet")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
