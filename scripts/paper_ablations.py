"""Where the SuperEx pipeline's gain comes from (the paper's Fig. 6 question): the ablation rows of the paper suite
paired by scenario with the full pipeline and with MapEx on LaMa-LOS, one plot per measure.

The ablation rows (``superex benchmark --suite paper --rows no_carving,carving_only,no_lama,no_pix2pix --steps 500
--out benchmarks/eval_paper/ablations``) run the first 500 steps of the paper's 1000-step episodes: the episodes are
deterministic, so their measures over steps 1-500 (first-half AUC, IoU below 30 % coverage) are the paper
protocol's, and they pair with the 1000-step rows of ``benchmarks/eval_paper/rows`` cut to the same steps. Writes
``OUT/ablations.md``, ``OUT/ablations.json`` and ``OUT/ablation_<measure>.png`` (mean paired difference against the
full pipeline with its bootstrap 95 % interval, one bar per row).

    PYTHONPATH=. .venv/bin/python scripts/paper_ablations.py --out benchmarks/eval_paper/ablations
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from superex_deploy.evaluation import (bootstrap_interval, markdown_table, save_figure, scenario_key,
                                       scenario_metrics, write_json, write_text)
from superex_deploy.evaluation.reports import pyplot
from superex_deploy.sim.suite import PAPER_ROWS

ROOT = Path(__file__).resolve().parents[1]
MEASURES = {"auc_first_half": ("first-half AUC, carved cells counted (points)", 100.0),
            "los_auc_first_half": ("first-half AUC, line of sight only (points)", 100.0),
            "iou_bin_0.0_0.1": ("wall IoU at 0-10 % coverage", 1.0),
            "iou@0.10": ("wall IoU at 10 % coverage", 1.0)}
"""Measure -> (its label, the factor it is shown with)."""
FULL, REFERENCE = "superex", "mapex_lama_los"
ORDER = ("no_pix2pix", "no_lama", "no_carving", "carving_only")


def _row(path: Path) -> dict:
    return {scenario_key(e): e for e in json.loads(path.read_text())["episodes"]}


def _metrics(row: dict, steps: int) -> dict:
    return {key: scenario_metrics(episode, steps) for key, episode in row.items()}


def _paired(new: dict, old: dict, measure: str, scale: float) -> dict:
    keys = sorted(set(new) & set(old))
    a = np.array([new[k][measure] for k in keys], float)
    b = np.array([old[k][measure] for k in keys], float)
    keep = np.isfinite(a) & np.isfinite(b)
    diff = (a[keep] - b[keep]) * scale
    low, high = bootstrap_interval(diff)
    return {"scenarios": int(keep.sum()), "mean": float(a[keep].mean() * scale), "against": float(b[keep].mean() * scale),
            "difference": float(diff.mean()), "interval": [float(low), float(high)],
            "ratio": float(a[keep].mean() / b[keep].mean() - 1.0), "better": int((diff > 0).sum()),
            "worse": int((diff < 0).sum())}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=Path, default=ROOT / "benchmarks" / "eval_paper" / "rows",
                        help="the paper suite's 1000-step rows (the full pipeline and the reference)")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "eval_paper" / "ablations",
                        help="the ablations' run folder (its rows/ are read; the tables and plots written there)")
    args = parser.parse_args(argv)
    steps = 1000  # the paper protocol's: first half = steps 1-500
    full = _metrics(_row(args.rows / f"{FULL}.json"), steps)
    reference = _metrics(_row(args.rows / f"{REFERENCE}.json"), steps)
    names = [n for n in ORDER if (args.out / "rows" / f"{n}.json").is_file()]
    if not names:
        raise SystemExit(f"no ablation row in {args.out / 'rows'}")
    ablations = {n: _metrics(_row(args.out / "rows" / f"{n}.json"), steps) for n in names}
    result = {n: {m: {"vs_full": _paired(ablations[n], full, m, s), "vs_reference": _paired(ablations[n], reference, m, s)}
                  for m, (_, s) in MEASURES.items()} for n in names}
    result[FULL] = {m: {"vs_reference": _paired(full, reference, m, s)} for m, (_, s) in MEASURES.items()}

    def cell(p: dict) -> str:
        return (f"{p['difference']:+.2f} [{p['interval'][0]:+.2f}, {p['interval'][1]:+.2f}] {p['ratio']:+.1%} "
                f"{p['better']}/{p['worse']}" if abs(p["against"]) >= 1 else
                f"{p['difference']:+.3f} [{p['interval'][0]:+.3f}, {p['interval'][1]:+.3f}] {p['ratio']:+.1%} "
                f"{p['better']}/{p['worse']}")

    lines = [f"Ablations of the SuperEx pipeline (40 eval scenarios, steps 1-500 of the paper's episodes), paired by "
             f"scenario: mean, and the mean difference [bootstrap 95 %], ratio of means - 1, better / worse; "
             f"against the full pipeline (`{FULL}`) and against MapEx on LaMa-LOS (`{REFERENCE}`).", ""]
    for measure, (label, scale) in MEASURES.items():
        lines += [f"**{label}**", ""]
        rows = [[f"{FULL}: {PAPER_ROWS[FULL].label}", f"{result[FULL][measure]['vs_reference']['mean']:.3f}", "-",
                 cell(result[FULL][measure]["vs_reference"])]]
        rows += [[f"{n}: {PAPER_ROWS[n].label}", f"{result[n][measure]['vs_full']['mean']:.3f}",
                  cell(result[n][measure]["vs_full"]), cell(result[n][measure]["vs_reference"])] for n in names]
        lines += markdown_table(["row", "mean", f"vs {FULL}", f"vs {REFERENCE}"], rows, ["-", "---:", "-", "-"]) + [""]
        plt = pyplot()
        fig, ax = plt.subplots(figsize=(6, 3))
        pairs = [result[n][measure]["vs_full"] for n in names]
        ax.bar(range(len(names)), [p["difference"] for p in pairs],
               yerr=np.abs(np.array([p["interval"] for p in pairs]).T - [p["difference"] for p in pairs]),
               color="tab:gray", capsize=4)
        ax.axhline(0.0, color="black", linewidth=0.8)
        ax.set_xticks(range(len(names)), names)
        ax.set_ylabel(f"difference to {FULL}")
        ax.set_title(label, fontsize=10)
        fig.tight_layout()
        save_figure(fig, args.out / f"ablation_{measure.replace('@', '_at_')}.png")
    write_text(args.out / "ablations.md", "\n".join(lines))
    write_json(args.out / "ablations.json", result)
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
