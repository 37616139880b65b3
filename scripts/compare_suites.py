"""The standard and the altered suite side by side: the same rows, scenarios and step budget.

The standard suite's rows (``benchmarks/eval_paper/rows``, 1000 steps) are cut to the altered run's budget: its
episodes are deterministic, so the first N steps of a 1000-step episode are the N-step episode. For each row and
each of the two baselines (MapEx on LaMa-LOS; MapEx on the observed map), on the scenarios both rows hold:
first-half AUC on each suite, the paired difference to the baseline on each (bootstrap 95 %), and how the
alteration changes that difference scenario by scenario (altered minus standard), over every scenario and over
those whose floor holds a dead end. Coverage is of each floor's valid area (the altered floors': what the robot
reaches), so the two suites' absolute values differ a little even where no alteration was made.

    PYTHONPATH=. .venv/bin/python scripts/compare_suites.py --altered benchmarks/eval_altered --steps 300
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from superex_deploy.evaluation import bootstrap_interval, markdown_table, scenario_metrics, write_json, write_text
from superex_deploy.pipeline import PIPELINES

BASELINES = ("mapex_lama_los", "mapex_observed")


def _rows(folder: Path) -> dict[str, dict]:
    """Row name -> {(map, start index): episode} of every row file under ``folder/rows``."""
    out = {}
    for path in sorted((folder / "rows").glob("*.json")):
        if path.name.endswith(".setting.json"):
            continue
        done = json.loads(path.read_text())
        out[done["row"]] = {(e["map"], int(e["start_index"])): e for e in done["episodes"]}
    return out


def _auc(episode: dict, steps: int) -> float:
    return scenario_metrics(episode, steps)["auc_first_half"]


def _interval(values: np.ndarray) -> dict:
    low, high = bootstrap_interval(values)
    return {"n": int(len(values)), "mean": float(np.mean(values)), "low": low, "high": high,
            "larger": int((values > 1e-9).sum()), "smaller": int((values < -1e-9).sum())}


def compare(standard: dict, altered: dict, steps: int) -> list[dict]:
    """One entry per (row, baseline) present in both suites (see the module docstring)."""
    out = []
    for baseline in BASELINES:
        if baseline not in altered or baseline not in standard:
            continue
        for row in altered:
            if row == baseline or row not in standard:
                continue
            keys = sorted(set(altered[row]) & set(altered[baseline]) & set(standard[row]) & set(standard[baseline]))
            if not keys:
                continue
            std = np.array([_auc(standard[row][k], steps) - _auc(standard[baseline][k], steps) for k in keys])
            alt = np.array([_auc(altered[row][k], steps) - _auc(altered[baseline][k], steps) for k in keys])
            dead = np.array([altered[row][k].get("alteration", {}).get("dead_ends", 0) > 0 for k in keys])
            entry = {"row": row, "baseline": baseline, "scenarios": len(keys), "with_dead_ends": int(dead.sum()),
                     "standard_auc": float(np.mean([_auc(standard[row][k], steps) for k in keys])),
                     "altered_auc": float(np.mean([_auc(altered[row][k], steps) for k in keys])),
                     "standard_paired": _interval(std), "altered_paired": _interval(alt),
                     "change": _interval(alt - std)}
            if dead.any():
                entry["change_with_dead_ends"] = _interval((alt - std)[dead])
                metres = np.array([altered[row][k]["dead_ends"]["metres_inside"]
                                   - altered[baseline][k]["dead_ends"]["metres_inside"] for k in keys])
                entry["metres_inside_paired"] = _interval(metres[dead])
            out.append(entry)
    return out


def _cell(d: dict, scale: float = 100.0, digits: int = 2) -> str:
    return (f"{d['mean'] * scale:+.{digits}f} [{d['low'] * scale:+.{digits}f}, {d['high'] * scale:+.{digits}f}] "
            f"{d['larger']}/{d['smaller']}")


def markdown(entries: list[dict], steps: int) -> str:
    lines = [f"First-half AUC (mean coverage over steps 1-{steps // 2}, points), {steps} steps, paired by scenario "
             f"(mean [bootstrap 95 %] larger/smaller).", ""]
    for baseline in BASELINES:
        mine = [e for e in entries if e["baseline"] == baseline]
        if not mine:
            continue
        cells = []
        for e in mine:
            dead = e.get("change_with_dead_ends")
            metres = e.get("metres_inside_paired")
            cells.append([e["row"], f"{e['scenarios']} ({e['with_dead_ends']})", f"{100 * e['standard_auc']:.1f}",
                          f"{100 * e['altered_auc']:.1f}", _cell(e["standard_paired"]), _cell(e["altered_paired"]),
                          _cell(e["change"]), _cell(dead) if dead else "-", _cell(metres, 1.0, 1) if metres else "-"])
        lines += [f"Against {baseline} ({PIPELINES[baseline].label}):", ""] + markdown_table(
            ["row", "scenarios (with dead ends)", "standard AUC", "altered AUC", "standard: row - baseline",
             "altered: row - baseline", "change (altered - standard)", "change, scenarios with dead ends",
             "m inside dead ends, row - baseline"], cells, ["-"] + ["---:"] * 8)
        lines.append("")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--standard", type=Path, default=Path("benchmarks/eval_paper"))
    parser.add_argument("--altered", type=Path, default=Path("benchmarks/eval_altered"))
    parser.add_argument("--steps", type=int, required=True, help="the altered run's step budget")
    args = parser.parse_args()
    entries = compare(_rows(args.standard), _rows(args.altered), args.steps)
    text = markdown(entries, args.steps)
    print(text)
    write_text(args.altered / "side_by_side.md", text)
    write_json(args.altered / "side_by_side.json", {"steps": args.steps, "entries": entries})


if __name__ == "__main__":
    main()
