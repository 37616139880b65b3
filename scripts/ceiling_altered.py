"""Oracle ceiling on altered train floors: does knowing the true map pay where an
obstruction hidden behind a turn turns a corridor or a room into a dead end?

Scenarios: the train floors of at least ``--min-area`` valid cells, every k-th of them to take ``--maps``, and
``--starts`` start cells each, drawn by :func:`superex_deploy.maps.random_start` (0.5 m from walls) from a generator
seeded with the map's name; a start is kept when the robot reaches at least ``--min-reach`` of the floor's valid
cells from it and :func:`superex_deploy.sim.alterations.alter_floor_with_record` (seeded with a CRC of the map's
name and the start) makes at least one dead end there; else the next draw is tried (at most 20 per map).
Every scenario runs on the altered floor and on the *unaltered* one (no obstruction, the same recomputed valid
area: what the robot reaches), ``--steps`` steps, each row of RUNS; every row is paired by scenario with MapEx on
the observed map. The first-half AUC is the mean coverage over steps 1..steps/2.

Dead-end entries (altered floors only, :func:`superex_deploy.sim.dead_ends.dead_end_entries`): runs of poses
inside a dead end reaching 1 m deep, the metres driven from entering to the deepest pose of each (before turning
back), and the metres driven inside dead ends in all.

The altered floors are cached under ``--work`` (with the journal: a killed run resumes where it stopped).

    PYTHONPATH=. .venv/bin/python scripts/ceiling_altered.py --maps 18 --starts 1 --steps 500 --jobs 1
"""

from __future__ import annotations

import argparse
import json
import time
import zlib
from pathlib import Path

import numpy as np

from superex_deploy.evaluation import (bootstrap_interval, coverage_auc, coverage_curve, first_half_auc,
                                       markdown_table, run_benchmark_episode, write_json, write_text)

RUNS = {"mapex_observed": ("mapex", "observed"), "superex_oracle": ("superex", "oracle"),
        "superex_observed": ("superex", "observed")}
"""Row name -> (planner, predictor)."""
BASELINE = "mapex_observed"
VARIANTS = ("altered", "unaltered")


def _floor_file(work: Path, name: str, start, cfg) -> Path:
    """The cached floor of a scenario under one generator configuration."""
    from dataclasses import asdict

    tag = zlib.crc32(json.dumps(asdict(cfg), sort_keys=True).encode())
    return work / "floors" / f"{name}_{start[0]}_{start[1]}_{tag:08x}.npz"


def _save_floor(path: Path, record) -> None:
    """The altered grid, the unaltered floor's recomputed valid area, and the dead ends, as one ``.npz``."""
    from superex_deploy.sim.alterations import AlterationConfig, alter_floor
    from superex_deploy.sim.altered_floors import record_arrays

    unaltered_valid = alter_floor(record.original, record.start_rc, 0, AlterationConfig(alterations=0)).valid
    arrays, meta = record_arrays(record)
    arrays.update(original_occupied=record.original.occupied, unaltered_valid=unaltered_valid)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, meta=json.dumps({"name": record.grid.name, "resolution_m": record.grid.resolution_m,
                                               "seed": record.seed, "kept_fraction": record.kept_fraction,
                                               "alterations": meta}), **arrays)


def _load_floor(path: Path, variant: str):
    """``(grid, dead ends, meta)`` of a cached floor; the unaltered variant has the original walls."""
    from superex_deploy.maps import OccupancyGrid
    from superex_deploy.sim.dead_ends import DeadEnd

    data = np.load(path)
    meta = json.loads(str(data["meta"]))
    if variant == "altered":
        grid = OccupancyGrid(occupied=data["occupied"], valid=data["valid"], resolution_m=meta["resolution_m"],
                             name=meta["name"])
    else:
        grid = OccupancyGrid(occupied=data["original_occupied"], valid=data["unaltered_valid"],
                             resolution_m=meta["resolution_m"], name=meta["name"])
    dead_ends = [DeadEnd(pocket=data[f"pocket_{i}"], depth_m=data[f"depth_{i}"], mouth=data[f"mouth_{i}"],
                         face=data[f"face_{i}"], length_m=m["length_m"], hidden_m=m["hidden_m"], area_m2=m["area_m2"])
                 for i, m in enumerate(meta["alterations"])]
    return grid, dead_ends, meta


def scenarios(n_maps: int, starts: int, min_area: int, min_reach: float, work: Path, cfg) -> list[dict]:
    """The scenarios (see the module docstring), their floors altered with ``cfg`` cached under ``work``."""
    from superex_deploy.maps import list_maps, load_map, random_start
    from superex_deploy.sim.alterations import alter_floor_with_record
    from superex_deploy.sim.dead_ends import robot_cells

    names = [n for n in list_maps("train") if int(load_map(n).valid.sum()) >= min_area]
    names = names[::max(1, len(names) // n_maps)][:n_maps]
    out = []
    for name in names:
        grid = load_map(name)
        rng = np.random.default_rng(zlib.crc32(name.encode()))
        found = 0
        for _ in range(20):
            if found == starts:
                break
            start = random_start(grid, rng, 0.5)
            reach = robot_cells(grid.occupied, start, cfg.robot_radius_m / grid.resolution_m)
            if reach.sum() < min_reach * grid.valid.sum():
                continue
            seed = zlib.crc32(f"{name}:{start[0]}:{start[1]}".encode())
            path = _floor_file(work, name, start, cfg)
            nothing = path.with_suffix(".none")  # a start where no dead end qualified, kept so that reruns skip it
            if nothing.is_file():
                continue
            if not path.is_file():
                clock = time.perf_counter()
                record = alter_floor_with_record(grid, start, seed, cfg)
                if not record.alterations:
                    nothing.parent.mkdir(parents=True, exist_ok=True)
                    nothing.touch()
                    continue
                _save_floor(path, record)
                print(f"{name} {start}: {len(record.alterations)} dead ends "
                      f"({time.perf_counter() - clock:.1f} s)", flush=True)
            out.append({"map": name, "start": [int(start[0]), int(start[1])], "seed": seed, "floor": str(path)})
            found += 1
    return out


def _episode(task: dict) -> dict:
    from superex_deploy.pipeline import PROFILES
    from superex_deploy.sim.dead_ends import dead_end_entries
    from superex_deploy.sim.exploration import ExplorationConfig

    grid, dead_ends, _ = _load_floor(Path(task["floor"]), task["variant"])
    planner, predictor = RUNS[task["run"]]
    clock = time.perf_counter()
    result = run_benchmark_episode(grid, task["start"], planner, predictor, steps=task["steps"],
                                   cfg=ExplorationConfig(iou_every=0), profile=PROFILES["full"]).result
    at = coverage_curve(list(result.coverage), task["steps"])
    summary = {key: task[key] for key in ("map", "start", "variant", "run")}
    summary.update(auc_first_half=first_half_auc(at, task["steps"]), auc=coverage_auc(at, 1, task["steps"]),
                   final=float(at[-1]), path_m=float(result.path_length_m[-1]), seconds=time.perf_counter() - clock)
    if task["variant"] == "altered":
        summary["dead_ends"] = dead_end_entries(dead_ends, result.poses, result.path_length_m).to_json()
    return summary


def _bootstrap(values: np.ndarray, statistic) -> tuple[float, float]:
    """Percentile bootstrap 95 % interval of ``statistic`` over ``values`` (10,000 resamples, seed 0, quantiles
    0.025 / 0.975 as committed)."""
    return bootstrap_interval(values, statistic=statistic, levels=(0.025, 0.975))


def summarise(results: list[dict], runs: list[str]) -> list[dict]:
    """One row per (variant, run): mean first-half AUC and its paired difference to the baseline (mean and median,
    bootstrap 95 % intervals), and the dead-end entries."""
    rows = []
    for variant in VARIANTS:
        base = {(r["map"], tuple(r["start"])): r for r in results if (r["variant"], r["run"]) == (variant, BASELINE)}
        for run in runs:
            mine = [r for r in results if (r["variant"], r["run"]) == (variant, run)
                    and (r["map"], tuple(r["start"])) in base]
            if not mine:
                continue
            diff = np.array([r["auc_first_half"] - base[(r["map"], tuple(r["start"]))]["auc_first_half"]
                             for r in mine])
            mean_auc = float(np.mean([r["auc_first_half"] for r in mine]))
            base_auc = float(np.mean([base[(r["map"], tuple(r["start"]))]["auc_first_half"] for r in mine]))
            row = {"variant": variant, "run": run, "scenarios": len(mine), "auc_first_half": mean_auc,
                   "ratio": mean_auc / base_auc - 1.0, "paired_mean": float(diff.mean()),
                   "paired_mean_ci": _bootstrap(diff, np.mean), "paired_median": float(np.median(diff)),
                   "paired_median_ci": _bootstrap(diff, np.median), "better": int((diff > 1e-9).sum()),
                   "worse": int((diff < -1e-9).sum()), "final": float(np.mean([r["final"] for r in mine]))}
            if variant == "altered":
                inside = np.array([r["dead_ends"]["metres_inside"] - base[(r["map"], tuple(r["start"]))]["dead_ends"][
                    "metres_inside"] for r in mine])
                row["dead_end_metres_inside_paired"] = {"mean": float(inside.mean()),
                                                        "ci": _bootstrap(inside, np.mean)}
                entries = [r["dead_ends"] for r in mine]
                row["dead_end"] = {
                    "entries_per_scenario": float(np.mean([e["entries"] for e in entries])),
                    "scenarios_entered": int(sum(e["entries"] > 0 for e in entries)),
                    "metres_in_per_scenario": float(np.mean([e["metres_in"] for e in entries])),
                    "metres_inside_per_scenario": float(np.mean([e["metres_inside"] for e in entries])),
                    "reached_end": int(sum(e["reached_end"] for e in entries))}
            rows.append(row)
    return rows


def gap_changes(results: list[dict], runs: list[str]) -> list[dict]:
    """Per row: how the alteration changes its paired first-half AUC difference to the baseline, scenario by
    scenario (``(row - baseline) on the altered floor - (row - baseline) on the unaltered floor``)."""
    auc = {(r["map"], tuple(r["start"]), r["variant"], r["run"]): r["auc_first_half"] for r in results}
    places = sorted({(r["map"], tuple(r["start"])) for r in results})
    out = []
    for run in runs:
        if run == BASELINE:
            continue
        keys = [p for p in places if all((*p, v, r) in auc for v in VARIANTS for r in (run, BASELINE))]
        if not keys:
            continue
        change = np.array([(auc[(*p, "altered", run)] - auc[(*p, "altered", BASELINE)])
                           - (auc[(*p, "unaltered", run)] - auc[(*p, "unaltered", BASELINE)]) for p in keys])
        out.append({"run": run, "scenarios": len(keys), "mean": float(change.mean()), "ci": _bootstrap(change, np.mean),
                    "median": float(np.median(change)), "median_ci": _bootstrap(change, np.median),
                    "larger": int((change > 1e-9).sum()), "smaller": int((change < -1e-9).sum())})
    return out


def markdown(rows: list[dict], scenario_list: list[dict], steps: int, gaps: list[dict]) -> str:
    """The rows as a markdown table (AUC in coverage points)."""
    header = ["floor", "row", "first-half AUC", "vs MapEx", "paired mean [95 %]", "paired median [95 %]",
              "better / worse", "final", "dead-end entries / scenario (scenarios entered)",
              "m in before turning back / scenario", "m inside dead ends / scenario", "reached the obstruction"]
    cells = []
    for row in rows:
        dead = row.get("dead_end")
        dead_cells = [f"{dead['entries_per_scenario']:.2f} ({dead['scenarios_entered']})",
                      f"{dead['metres_in_per_scenario']:.1f}", f"{dead['metres_inside_per_scenario']:.1f}",
                      f"{dead['reached_end']}"] if dead else ["-"] * 4
        mean_low, mean_high = row["paired_mean_ci"]
        median_low, median_high = row["paired_median_ci"]
        cells.append([row["variant"], row["run"], f"{100 * row['auc_first_half']:.1f}", f"{row['ratio']:+.1%}",
                      f"{100 * row['paired_mean']:+.2f} [{100 * mean_low:+.2f}, {100 * mean_high:+.2f}]",
                      f"{100 * row['paired_median']:+.2f} [{100 * median_low:+.2f}, {100 * median_high:+.2f}]",
                      f"{row['better']} / {row['worse']}", f"{100 * row['final']:.1f}", *dead_cells])
    lines = [f"{len(scenario_list)} scenarios on {len({s['map'] for s in scenario_list})} train floors, {steps} steps; "
             f"paired by scenario with MapEx on the observed map of the same floor variant.", ""]
    lines += markdown_table(header, cells, ["-", "-"] + ["---:"] * 4 + ["-"] + ["---:"] * 5)
    lines += ["", "The alteration's effect on each row's paired difference to MapEx (first-half AUC points, "
              "per scenario: altered minus unaltered):", ""]
    lines += markdown_table(
        ["row", "mean [95 %]", "median [95 %]", "larger / smaller"],
        [[gap["run"], f"{100 * gap['mean']:+.2f} [{100 * gap['ci'][0]:+.2f}, {100 * gap['ci'][1]:+.2f}]",
          f"{100 * gap['median']:+.2f} [{100 * gap['median_ci'][0]:+.2f}, {100 * gap['median_ci'][1]:+.2f}]",
          f"{gap['larger']} / {gap['smaller']}"] for gap in gaps], ["-", "---:", "---:", "-"])
    lines += ["", "Metres inside dead ends, paired with MapEx (altered floors; mean [95 %]):", ""]
    lines += [f"- {row['run']}: {row['dead_end_metres_inside_paired']['mean']:+.1f} m "
              f"[{row['dead_end_metres_inside_paired']['ci'][0]:+.1f}, "
              f"{row['dead_end_metres_inside_paired']['ci'][1]:+.1f}]"
              for row in rows if row["variant"] == "altered" and row["run"] != BASELINE]
    return "\n".join(lines) + "\n"


def _config(options: list[str]):
    """The generator's configuration: the defaults with ``NAME=VALUE`` overrides."""
    from superex_deploy.sim.alterations import AlterationConfig

    fields = AlterationConfig.__dataclass_fields__
    values = {}
    for option in options:
        name, _, value = option.partition("=")
        if name not in fields:
            raise SystemExit(f"--alter-option: unknown field {name!r}; fields: {', '.join(fields)}")
        values[name] = int(value) if fields[name].type in ("int", int) else float(value)
    try:
        return AlterationConfig(**values)
    except ValueError as error:
        raise SystemExit(f"--alter-option: {error}") from None


def main() -> None:
    from dataclasses import asdict

    from superex_deploy.parallel import run_tasks

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--maps", type=int, default=18, help="train floors")
    parser.add_argument("--starts", type=int, default=1, help="start cells per floor")
    parser.add_argument("--min-area", type=int, default=40000, help="smallest floor (valid cells)")
    parser.add_argument("--min-reach", type=float, default=0.5,
                        help="smallest share of the valid cells the robot must reach from a start")
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--runs", default="all", help=f"comma-separated rows of {list(RUNS)}, or 'all'")
    parser.add_argument("--alter-option", action="append", default=[], metavar="NAME=VALUE",
                        help="override an AlterationConfig field (tuning on the train floors only)")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes (the machine is shared: keep 1)")
    parser.add_argument("--work", type=Path, default=Path("runs/altered_ceiling"),
                        help="cached floors and the journal (a rerun resumes)")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/altered_ceiling"),
                        help="folder for ceiling.md and ceiling.json")
    args = parser.parse_args()
    runs = list(RUNS) if args.runs == "all" else [r.strip() for r in args.runs.split(",")]
    if any(r not in RUNS for r in runs) or BASELINE not in runs:
        raise SystemExit(f"--runs: choose from {list(RUNS)}, {BASELINE} included")
    cfg = _config(args.alter_option)
    args.work.mkdir(parents=True, exist_ok=True)
    places = scenarios(args.maps, args.starts, args.min_area, args.min_reach, args.work, cfg)
    tasks = [dict(place, variant=variant, run=run, steps=args.steps) for place in places for variant in VARIANTS
             for run in runs]
    keys = [f"{Path(t['floor']).stem}:{t['variant']}:{t['run']}:{t['steps']}" for t in tasks]
    print(f"{len(places)} scenarios, {len(tasks)} episodes", flush=True)
    results = run_tasks(_episode, tasks, keys, args.jobs, args.work / "journal.jsonl", progress="episodes")
    rows, gaps = summarise(results, runs), gap_changes(results, runs)
    floors = []
    for place in places:
        _, _, meta = _load_floor(Path(place["floor"]), "altered")
        floors.append({key: place[key] for key in ("map", "start", "seed")} | {
            "kept_fraction": meta["kept_fraction"], "alterations": meta["alterations"]})
    table = markdown(rows, places, args.steps, gaps)
    print("\n" + table)
    write_text(args.out / "ceiling.md", table)
    write_json(args.out / "ceiling.json", {"steps": args.steps, "baseline": BASELINE, "rows": rows,
                                           "gap_changes": gaps, "config": asdict(cfg), "scenarios": floors,
                                           "episodes": results})
    print(f"wrote {args.out}/ceiling.md and ceiling.json")


if __name__ == "__main__":
    main()
