"""Seams of the cropped predictions: the real-time profile's crops, written back with hard
edges or feathered, against a whole-map prediction of the same map and evidence.

Every scenario is one episode of the ``lama_bp`` pipeline with the SPAD (``superex`` planner) under the chosen
profile (``realtime``: crops with 6.4 m of context, one LaMa member). The episode's own prediction requests (every
``schedule.every_steps`` steps, on that step's map and evidence) are replayed, as they happen, into shadow
:class:`~superex_deploy.onboard.prediction.reuse.ReusingPredictor` s that share the profile's reuse settings and
differ only in the feathering (``feather_m`` x ``feather_ramp``; ``hard`` is ``feather_m = 0``). They see the same
requests and cut the same crops, so the network runs once per request (the answer is shared). At the sample steps
the same one-member predictor also predicts the whole map, and each shadow's prediction is compared with it on
the unknown cells (known cells are the map's in both):

* ``mae``: mean absolute error of the wall probability (the prediction's mean) over every unknown cell;
* ``mae_band``: the same over the *seam band*: unknown cells within ``--band-m`` (default: half the crop margin,
  the width of the context band a feather can use) of a seam, a line between two cells last written (with hard
  edges) by different predictions (or by none);
* ``step``: the mean absolute difference between the two cells of a seam line (both unknown): what the eye sees
  as an edge; ``step_whole`` is the same pairs in the whole-map prediction;
* ``blend_ms``: the shadow's time per request beyond the network (change detection, merge, blend).

Choose the feather width on the held-out train floors (``--split train``, the 12 scenarios of
``scripts/bench_realtime.py --error train``, or the first ``--scenarios`` of them), report it on a few eval scenarios
(``--split eval``: start 0 of ``--scenarios`` eval maps, the README's map first), never the other way round:

    NUMBA_NUM_THREADS=1 python scripts/bench_seams.py --split train --out benchmarks/seams   # 12 scenarios, ~5 min
    NUMBA_NUM_THREADS=1 python scripts/bench_seams.py --split eval --out benchmarks/seams    # 4 scenarios, ~5 min

Episodes are journaled (``OUT/seams_SPLIT.episodes.jsonl``: a rerun resumes); writes ``OUT/seams_SPLIT.json`` and
``OUT/seams.md`` (one table per split found in the folder).
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from superex_deploy.evaluation import markdown_table

ROOT = Path(__file__).resolve().parents[1]

EVAL_MAPS = ("50052750", "50010539", "50045230", "50015847", "50010535_PLAN1", "50052749")
"""Eval maps for reporting, in order (start 0 of each): the README's map first, then others of every size."""
HARD = "hard"


class SharedAnswer:
    """A predictor that answers a map it has just answered from its last answer (the shadows cut the same crop:
    the network runs once); everything else it forwards."""

    def __init__(self, predictor):
        self.predictor = predictor
        self.name = getattr(predictor, "name", type(predictor).__name__)
        self.accepts_crops = getattr(predictor, "accepts_crops", False)
        self.size_multiple = getattr(predictor, "size_multiple", 1)
        self._last = None

    def predict(self, observed, extra=None):
        if self._last is not None:
            last_observed, last_extra, answer = self._last
            if np.array_equal(last_observed, observed) and (
                    (extra is None and last_extra is None)
                    or (extra is not None and last_extra is not None and np.array_equal(last_extra, extra))):
                return answer
        answer = self.predictor.predict(observed, extra)
        self._last = (observed.copy(), None if extra is None else extra.copy(), answer)
        return answer


def config_name(ramp: str, feather_m: float) -> str:
    return HARD if feather_m == 0 else f"{ramp}_{feather_m:g}m"


def seam_band(labels: np.ndarray, band_cells: int) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """The seam band of int ``[H, W]`` ``labels`` (which prediction last wrote a cell): bool ``[H, W]``, the cells
    within ``band_cells`` (chessboard distance) of a cell that has a 4-neighbour with another label; and the seam
    lines' neighbour pairs as two flat index arrays (``first``, ``second``)."""
    from scipy.ndimage import distance_transform_cdt

    flat = np.arange(labels.size).reshape(labels.shape)
    down = labels[1:, :] != labels[:-1, :]
    right = labels[:, 1:] != labels[:, :-1]
    first = np.concatenate([flat[:-1, :][down], flat[:, :-1][right]])
    second = np.concatenate([flat[1:, :][down], flat[:, 1:][right]])
    seam = np.zeros(labels.shape, bool)
    seam.flat[first] = True
    seam.flat[second] = True
    if not seam.any():
        return seam, (first, second)
    return distance_transform_cdt(~seam, metric="chessboard") <= band_cells, (first, second)


def _episode(task: tuple) -> dict:
    """One scenario in a worker: ``(map, start index, start cell, profile, steps, samples, feathers, ramps, band_m)``."""
    from superex_deploy.evaluation import run_benchmark_episode
    from superex_deploy.maps import load_map
    from superex_deploy.onboard.prediction.reuse import ReusingPredictor
    from superex_deploy.onboard.types import UNKNOWN
    from superex_deploy.pipeline import PIPELINES, PROFILES, make_predictor

    map_name, start_index, start, profile_name, steps, samples, feathers, ramps, band_m = task
    pipeline = PIPELINES["superex"]
    grid = load_map(map_name)
    profile = PROFILES[profile_name]
    if profile.reuse.crop_margin_m is None:
        raise ValueError(f"the {profile_name} profile predicts no crops: nothing to measure")
    every = profile.explorer_config("simulated").prediction.every_steps or 1  # the benchmarks' (simulated) clock
    resolution = grid.resolution_m
    margin = int(np.ceil(profile.reuse.crop_margin_m / resolution - 1e-9))
    band_cells = int(round((margin - margin // 2) if band_m is None else band_m / resolution))
    network = SharedAnswer(make_predictor(pipeline.predictor, grid, profile=profile))
    configs = {config_name(ramp, f): replace(profile.reuse, feather_m=f, feather_ramp=ramp)
               for f in feathers for ramp in (ramps if f else ramps[:1])}
    # The primer runs the network (its time is not a shadow's) and keeps the hard edges' labels.
    primer = ReusingPredictor(network, replace(profile.reuse, feather_m=0.0), resolution)
    shadows = {name: ReusingPredictor(network, cfg, resolution) for name, cfg in configs.items()}
    labels = np.zeros(grid.shape, np.int32)
    sums = {name: dict.fromkeys(("abs", "abs_band", "step"), 0.0) for name in configs}
    counts = {"unknown": 0, "band": 0, "pairs": 0, "step_whole": 0.0, "requests": 0, "crops": 0, "crop_cells": 0,
              "whole_s": 0.0, "samples": 0}
    blend_s = dict.fromkeys(configs, 0.0)
    per_sample = []

    def on_observation(observation, command, explorer):
        t = command.step
        if t % every:
            return
        observed = explorer.observed.copy()
        evidence = None if explorer.evidence is None else explorer.evidence.copy()
        runs = primer.runs
        primer.predict(observed, evidence)
        counts["requests"] += 1
        if primer.runs > runs:
            if primer.last_crop is None:
                labels[:] = primer.runs
            else:
                outer, inner = primer.last_crop
                labels[inner[0]:inner[2], inner[1]:inner[3]] = primer.runs
                counts["crops"] += 1
                counts["crop_cells"] += (outer[2] - outer[0]) * (outer[3] - outer[1])
        answers = {}
        names = list(shadows)
        first = counts["requests"] % len(names)  # rotated: no configuration is always the first to touch the arrays
        for name in names[first:] + names[:first]:
            clock = time.perf_counter()
            answers[name] = shadows[name].predict(observed, evidence)
            blend_s[name] += time.perf_counter() - clock
        if t not in samples:
            return
        clock = time.perf_counter()
        whole = network.predictor.predict(observed, evidence).mean
        counts["whole_s"] += time.perf_counter() - clock
        unknown = observed == UNKNOWN
        band, (first, second) = seam_band(labels, band_cells)
        band &= unknown
        pairs = unknown.flat[first] & unknown.flat[second]
        first, second = first[pairs], second[pairs]
        counts["samples"] += 1
        counts["unknown"] += int(unknown.sum())
        counts["band"] += int(band.sum())
        counts["pairs"] += int(first.size)
        counts["step_whole"] += float(np.abs(whole.flat[first] - whole.flat[second]).sum())
        row = {"step": t, "unknown": int(unknown.sum()), "band": int(band.sum())}
        for name in names:
            answer = answers[name]
            error = np.abs(answer.mean.astype(np.float64) - whole)
            sums[name]["abs"] += float(error[unknown].sum())
            sums[name]["abs_band"] += float(error[band].sum())
            sums[name]["step"] += float(np.abs(answer.mean.flat[first].astype(np.float64)
                                               - answer.mean.flat[second]).sum())
            row[name] = {"mae": float(error[unknown].mean()) if unknown.any() else 0.0,
                         "mae_band": float(error[band].mean()) if band.any() else 0.0}
        per_sample.append(row)

    clock = time.perf_counter()
    run_benchmark_episode(grid, start, pipeline.planner, pipeline.predictor, steps=steps, seed=0,
                          cfg=profile.episode_config(iou_every=0), profile=profile, spad=pipeline.spad,
                          on_observation=on_observation)
    return {"map": map_name, "start_index": start_index, "start": list(start), "profile": profile_name,
            "band_cells": band_cells, "counts": counts, "sums": sums,
            "blend_ms": {name: 1e3 * s / max(counts["requests"], 1) for name, s in blend_s.items()},
            "samples": per_sample, "seconds": time.perf_counter() - clock}


def scenarios(split: str, n: int) -> list[tuple[str, int, tuple[int, int]]]:
    """``(map, start index, start cell)``: the held-out train floors of ``bench_realtime.py --error train`` or
    start 0 of :data:`EVAL_MAPS`; the first ``n``."""
    from superex_deploy.evaluation import eval_scenarios, heldout_scenarios

    places = heldout_scenarios(12) if split == "train" else eval_scenarios(starts=1, maps=EVAL_MAPS)
    return places[:n]


def summarise(episodes: list[dict]) -> dict:
    """Pooled over the episodes' samples: per configuration ``mae``, ``mae_band``, ``step`` (see the module
    docstring), ``blend_ms``; and ``step_whole``, the sample counts."""
    totals = {key: sum(e["counts"][key] for e in episodes) for key in episodes[0]["counts"]}
    names = list(episodes[0]["sums"])
    rows = {}
    for name in names:
        sums = {key: sum(e["sums"][name][key] for e in episodes) for key in ("abs", "abs_band", "step")}
        rows[name] = {"mae": sums["abs"] / max(totals["unknown"], 1),
                      "mae_band": sums["abs_band"] / max(totals["band"], 1),
                      "step": sums["step"] / max(totals["pairs"], 1),
                      "blend_ms": float(np.mean([e["blend_ms"][name] for e in episodes])),
                      "mae_per_episode": [e["sums"][name]["abs"] / max(e["counts"]["unknown"], 1) for e in episodes],
                      "mae_band_per_episode": [e["sums"][name]["abs_band"] / max(e["counts"]["band"], 1)
                                               for e in episodes]}
    return {"configs": rows, "step_whole": totals["step_whole"] / max(totals["pairs"], 1), "totals": totals,
            "episodes": [{k: e[k] for k in ("map", "start_index", "start", "seconds")} for e in episodes]}


def best_config(summary: dict) -> str:
    """The configuration whose seam-band MAE, relative to ``hard`` and averaged over the episodes, is lowest."""
    hard = np.asarray(summary["configs"][HARD]["mae_band_per_episode"])
    return min(summary["configs"], key=lambda name: float(np.mean(
        np.asarray(summary["configs"][name]["mae_band_per_episode"]) / np.maximum(hard, 1e-12))))


def markdown(out: Path) -> str:
    lines = ["# Seams of the cropped predictions", "",
             "Written by `scripts/bench_seams.py` (see its docstring): the real-time profile's crops written back "
             "with hard edges or feathered, against a one-member whole-map prediction of the same map and evidence. "
             "MAE of the wall probability over the unknown cells, all and in the seam band (within the band width "
             "of a line between cells written by different predictions); *step*: mean absolute difference across "
             "those lines (the whole-map prediction's own in the heading); *blend ms*: per request, beyond the "
             "network. Paired against `hard` by episode: the band MAE's relative change (mean over the episodes, and the "
             "worst episode) and how many episodes it lowers. MAE and step are pooled over every sample's cells.",
             ""]
    for split in ("train", "eval"):
        path = out / f"seams_{split}.json"
        if not path.is_file():
            continue
        data = json.loads(path.read_text())
        summary, totals = data["summary"], data["summary"]["totals"]
        lines += [f"## {split} ({len(summary['episodes'])} episodes x {data['steps']} steps, profile "
                  f"`{data['profile']}`, {totals['samples']} samples, {totals['requests']} requests of which "
                  f"{totals['crops']} crops; band {data['band_cells']} cells; step of the whole-map prediction "
                  f"{summary['step_whole']:.4f})", ""]
        hard = np.asarray(summary["configs"][HARD]["mae_band_per_episode"])
        cells = []
        for name, row in summary["configs"].items():
            band = np.asarray(row["mae_band_per_episode"])
            relative = band / np.maximum(hard, 1e-12) - 1.0
            mark = " (default)" if name == data.get("default") else ""
            cells.append([f"{name}{mark}", f"{row['mae']:.4f}", f"{row['mae_band']:.4f}", f"{row['step']:.4f}",
                          f"{100 * relative.mean():+.1f} % / {100 * relative.max():+.1f} %",
                          f"{int((band < hard).sum())}/{band.size}", f"{row['blend_ms']:.2f}"])
        lines += markdown_table(["configuration", "MAE", "MAE seam band", "step",
                                 "band MAE vs hard, per episode: mean / worst", "band MAE better than hard",
                                 "blend ms"], cells, ["-"] + ["---:"] * 6)
        if split == "train":
            lines += ["", f"Lowest band MAE on these floors (relative to `hard`, mean per episode): "
                          f"`{best_config(summary)}`: the width to choose."]
        lines += ["", "Episodes: " + ", ".join(f"{e['map']} start {e['start_index']}" for e in summary["episodes"]),
                  ""]
    if (out / "final_prediction_hard_edges.png").is_file() and (out / "final_prediction_feathered.png").is_file():
        lines += ["## The README's first command", "",
                  "The prediction panel of `final.png` of `superex explore --map 50052750 --start 0 --planner superex "
                  "--predictor lama_bp --spad --steps 300` (default profile), before (hard edges) and after "
                  "(feathered): the rectangular patches are gone; the faint straight lines left are the network's "
                  "own guesses (a whole-map prediction of the same map shows them too).", "",
                  "| hard edges | feathered |", "|---|---|",
                  "| ![hard edges](final_prediction_hard_edges.png) | ![feathered](final_prediction_feathered.png) |",
                  ""]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    parser.add_argument("--split", choices=("train", "eval"), default="train",
                        help="train: choose the width (held-out train floors); eval: report only")
    parser.add_argument("--scenarios", type=int, default=None,
                        help="how many scenarios of the split (default: 12 train, 4 eval)")
    parser.add_argument("--steps", type=int, default=300, help="steps per episode")
    parser.add_argument("--sample-every", type=int, default=50, help="compare with the whole map every this many "
                        "steps (from this step on; rounded to the profile's request steps)")
    parser.add_argument("--feathers", default="0,0.4,0.8,1.6,2.4,3.2,6.4",
                        help="comma-separated feather widths in metres (0: hard edges)")
    parser.add_argument("--ramps", default="linear,cosine", help="comma-separated ramps")
    parser.add_argument("--band-m", type=float, default=None,
                        help="seam band half-width in metres (default: half the profile's crop margin)")
    parser.add_argument("--profile", default="realtime", help="the profile whose reuse settings are measured")
    parser.add_argument("--default", default=None, help="the configuration to mark as the default in the table")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "seams")
    args = parser.parse_args()

    from superex_deploy.evaluation import write_json, write_text
    from superex_deploy.onboard.prediction.reuse import RAMPS
    from superex_deploy.parallel import run_tasks
    from superex_deploy.pipeline import PROFILES

    feathers = sorted({float(v) for v in args.feathers.split(",") if v.strip()})
    ramps = [r.strip() for r in args.ramps.split(",") if r.strip()]
    if 0.0 not in feathers:
        feathers = [0.0] + feathers  # hard edges: the reference
    if any(r not in RAMPS for r in ramps) or not ramps:
        parser.error(f"--ramps: choose from {', '.join(RAMPS)}")
    if args.profile not in PROFILES:
        parser.error(f"--profile: choose from {', '.join(PROFILES)}")
    every = PROFILES[args.profile].explorer_config("simulated").prediction.every_steps or 1
    samples = tuple(t - t % every for t in range(args.sample_every, args.steps, args.sample_every))
    places = scenarios(args.split, args.scenarios or (12 if args.split == "train" else 4))
    args.out.mkdir(parents=True, exist_ok=True)
    settings = (args.profile, args.steps, samples, tuple(feathers), tuple(ramps), args.band_m)
    tasks = [(m, k, start, *settings[:2], samples, tuple(feathers), tuple(ramps), args.band_m)
             for m, k, start in places]
    keys = [json.dumps([m, k, *settings]) for m, k, _ in places]
    episodes = run_tasks(_episode, tasks, keys, args.jobs, args.out / f"seams_{args.split}.episodes.jsonl",
                         progress=f"seams {args.split}")
    summary = summarise(episodes)
    reuse = PROFILES[args.profile].reuse
    default = args.default or config_name(reuse.feather_ramp, reuse.feather_m)
    data = {"split": args.split, "profile": args.profile, "steps": args.steps, "samples": list(samples),
            "feathers_m": feathers, "ramps": ramps, "band_cells": episodes[0]["band_cells"], "default": default,
            "summary": summary, "episodes": episodes}
    write_json(args.out / f"seams_{args.split}.json", data)
    table = markdown(args.out)
    write_text(args.out / "seams.md", table)
    print(table)


if __name__ == "__main__":
    main()
