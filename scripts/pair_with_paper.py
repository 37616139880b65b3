"""One new row paired by scenario with the committed paper rows (a planner variant decided on train floors,
reported on the eval floors without re-running the paper table).

The paper rows (``benchmarks/eval_paper/rows``, 1000 steps) are deterministic, so their first N steps are the N-step
episodes: a row of N steps holds the first half of a 2N-step episode, so its first-half AUC (steps 1..N) is the
2N-step protocol's (the paper's 1000 steps for N = 500); IoU at a coverage level counts where both rows reached it. The new row is a
``superex benchmark`` output folder (``episodes.jsonl``). Writes ``OUT/pairing.md`` and ``OUT/pairing.json``.

    PYTHONPATH=. .venv/bin/python scripts/pair_with_paper.py --row runs/expcorr --name superex_expected_correlated \\
        --against superex,mapex_lama_los,superex_observed --out benchmarks/eval_expected_correlated
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from superex_deploy.parallel import read_journal
from superex_deploy.evaluation import bootstrap_interval, scenario_key, scenario_metrics, write_json, write_text

ROOT = Path(__file__).resolve().parents[1]
METRICS = ("auc_first_half", "iou@0.10", "iou@0.20", "iou@0.30")


def _paper_row(name: str) -> dict:
    path = ROOT / "benchmarks" / "eval_paper" / "rows" / f"{name}.json"
    if not path.is_file():
        raise SystemExit(f"no committed paper row {name!r} ({path})")
    return {scenario_key(e): e for e in json.loads(path.read_text())["episodes"]}


def _new_row(path: Path) -> dict:
    """The episodes of a `superex benchmark` output folder (its ``episodes.jsonl``), of one journal file (a suite's
    ``rows/ROW.episodes.jsonl``) or of a finished suite row (``rows/ROW.json``)."""
    if path.suffix == ".json" and path.is_file():
        return {scenario_key(e): e for e in json.loads(path.read_text())["episodes"]}
    journal = path if path.suffix == ".jsonl" else path / "episodes.jsonl"
    if not journal.is_file():
        raise SystemExit(f"{journal} does not exist: give a `superex benchmark` output folder, a .jsonl journal or "
                         "a suite's row .json")
    return {scenario_key(e): e for e in read_journal(journal).values()}


def _row(name: str) -> dict:
    """A committed paper row by name, or a new row (a path ending in .jsonl or .json)."""
    return _new_row(Path(name)) if name.endswith((".jsonl", ".json")) else _paper_row(name)


def pair(new: dict, old: dict, steps: int) -> dict:
    """Paired differences (new - old) of :data:`METRICS` on the scenarios both rows hold; ``steps``: the new row's
    budget, the first half of a ``2 steps`` episode."""
    shared = sorted(set(new) & set(old))
    out = {"scenarios": len(shared)}
    for metric in METRICS:
        a = np.array([scenario_metrics(new[k], 2 * steps)[metric] for k in shared], float)
        b = np.array([scenario_metrics(old[k], 2 * steps)[metric] for k in shared], float)
        ok = np.isfinite(a) & np.isfinite(b)
        diff = (a - b)[ok]
        low, high = bootstrap_interval(diff)
        out[metric] = {"new": float(a[ok].mean()), "old": float(b[ok].mean()), "mean_diff": float(diff.mean()),
                       "ci95": [low, high], "better": int((diff > 0).sum()), "worse": int((diff < 0).sum()),
                       "n": int(ok.sum())}
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--row", type=Path, required=True,
                        help="a `superex benchmark` output folder, or a suite row's journal (.jsonl) or file (.json)")
    parser.add_argument("--name", required=True, help="the new row's name in the table")
    parser.add_argument("--against", default="superex,mapex_lama_los,superex_observed",
                        help="comma-separated committed paper rows, or new rows' journals (.jsonl) or files (.json)")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--protocol-steps", type=int, default=0,
                        help="the episodes' protocol budget, whose first half the AUC reads (0: twice the new row's "
                             "steps, the paper's 1000 for a 500-step row; the altered suite's 500 for its own rows)")
    args = parser.parse_args(argv)
    if args.protocol_steps < 0 or args.protocol_steps % 2:
        parser.error("--protocol-steps must be an even number >= 0")
    new = _new_row(args.row)
    if not new:
        raise SystemExit(f"{args.row} holds no finished episode")
    steps = min(int(e["steps"]) for e in new.values())
    if args.protocol_steps:
        if args.protocol_steps > steps:
            parser.error(f"--protocol-steps {args.protocol_steps} is longer than the row's {steps} steps")
        steps = args.protocol_steps // 2  # the first half the AUC reads
    results = {"row": args.name, "steps": steps, "pairs": {}}
    lines = [f"`{args.name}` ({len(new)} eval scenarios, {steps} steps) paired by scenario with the committed paper "
             f"rows; first-half AUC of {2 * steps}-step episodes in points (steps 1-{steps}), IoU at 10 / 20 / 30 % "
             "coverage; mean difference [bootstrap 95 %], better / worse.", "",
             "| against | scenarios | AUC new | AUC old | relative | AUC diff | IoU@10% diff | IoU@20% diff | IoU@30% diff |",
             "|---|---:|---:|---:|---:|---|---|---|---|"]
    for name in [s.strip() for s in args.against.split(",") if s.strip()]:
        result = pair(new, _row(name), steps)
        results["pairs"][name] = result
        auc = result["auc_first_half"]
        cells = [f"{100 * auc['mean_diff']:+.2f} [{100 * auc['ci95'][0]:+.2f}, {100 * auc['ci95'][1]:+.2f}] "
                 f"{auc['better']}/{auc['worse']}"]
        for metric in METRICS[1:]:
            m = result[metric]
            cells.append(f"{m['mean_diff']:+.3f} [{m['ci95'][0]:+.3f}, {m['ci95'][1]:+.3f}] {m['better']}/{m['worse']}")
        lines.append(f"| {name} | {result['scenarios']} | {100 * auc['new']:.2f} | {100 * auc['old']:.2f} | "
                     f"{auc['new'] / auc['old'] - 1:+.1%} | " + " | ".join(cells) + " |")
    args.out.mkdir(parents=True, exist_ok=True)
    write_json(args.out / "pairing.json", results)
    write_text(args.out / "pairing.md", "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
