"""Where the SuperEx pipeline's gain comes from (the paper's Fig. 6 question): the ablation rows of the paper suite
paired by scenario with the full pipeline and with MapEx on LaMa-LOS, one plot per measure; and the paper's planner
rows paired with each other (:data:`PAIRS`: what the SPAD adds under the same planner, the planner under the same
predictor, the true-map ceiling, each row against its previous defaults).

The ablation rows (``superex benchmark --suite paper --rows no_carving,carving_only,no_lama,no_pix2pix --steps 500
--out benchmarks/eval_paper/ablations``) run the first 500 steps of the paper's 1000-step episodes: the episodes are
deterministic, so their measures over steps 1-500 (first-half AUC, IoU below 30 % coverage) are the paper
protocol's, and they pair with the 1000-step rows of ``benchmarks/eval_paper/rows`` cut to the same steps. Writes
``OUT/ablations.md``, ``OUT/ablations.json`` and ``OUT/ablation_<measure>.png`` (mean paired difference against the
full pipeline with its bootstrap 95 % interval, one bar per row), and ``pairs.md`` / ``pairs.json`` beside ``--rows``
(the rows of the previous defaults read from ``benchmarks/history/eval_paper_previous_defaults/rows``).

    PYTHONPATH=. .venv/bin/python scripts/paper_ablations.py --out benchmarks/eval_paper/ablations
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from superex_deploy.evaluation import markdown_table, read_json, save_figure, write_json, write_text
from superex_deploy.evaluation.reports import pyplot
from superex_deploy.pipeline import PIPELINES
from superex_deploy.evaluation.summary import paired_summary, row_summary

ROOT = Path(__file__).resolve().parents[1]
# The paper rows as measured with the previous (0.1) defaults, which this version cannot re-run.
PREVIOUS_ROWS = ROOT / "benchmarks" / "history" / "eval_paper_previous_defaults" / "rows"
MEASURES = {"auc_first_half": ("first-half AUC, carved cells counted (points)", 100.0),
            "los_auc_first_half": ("first-half AUC, line of sight only (points)", 100.0),
            "iou_bin_0.0_0.1": ("wall IoU at 0-10 % coverage", 1.0),
            "iou@0.10": ("wall IoU at 10 % coverage", 1.0)}
"""Measure -> (its label, the factor it is shown with)."""
FULL, REFERENCE = "superex", "mapex_lama_los"
ORDER = ("no_pix2pix", "no_lama", "no_carving", "carving_only")
PREVIOUS = "@previous"
PAIRS = (("superex", "superex_lama_los", "what the SPAD adds (same planner, LaMa-BP + SPAD vs LaMa-LOS)"),
         ("superex", "superex_observed", "the learned map and the SPAD against neither (same planner)"),
         ("superex_lama_los", "superex_observed", "LaMa-LOS against no prediction (same planner)"),
         ("superex_lama_los", "mapex_lama_los", "the planner (same predictor, LaMa-LOS)"),
         ("superex_observed", "mapex_lama_los", "the planner on the observed map against MapEx on LaMa-LOS"),
         ("superex_oracle", "mapex_observed", "the ceiling: the true map against MapEx on the observed map"),
         ("superex_oracle", "superex_observed", "the true map against no prediction (same planner)"),
         ("superex_oracle", "superex", "the true map against the SuperEx pipeline (same planner)"),
         ("superex", "superex" + PREVIOUS, "the shipped defaults against the previous ones"),
         ("superex_observed", "superex_observed" + PREVIOUS, "the planner's new default gain, observed map"),
         ("superex_lama_los", "superex_lama_los" + PREVIOUS, "the planner's new default gain, LaMa-LOS"),
         ("superex_oracle", "superex_oracle" + PREVIOUS, "the planner's new default gain, true map"))
"""(candidate, reference, what the pair measures); ``NAME@previous``: the row of the previous defaults."""


def _episodes(path: Path) -> list[dict]:
    return read_json(path)["episodes"]


def _compare(candidate: list[dict], reference: list[dict], steps: int) -> dict:
    """Measure -> the paired difference of :func:`~superex_deploy.evaluation.summary.paired_summary` (scaled for the
    table) with the candidate's mean (:func:`~superex_deploy.evaluation.summary.row_summary`) beside it."""
    summary, means = paired_summary(reference, candidate, steps), row_summary(candidate, steps)
    out = {}
    for measure, (_, scale) in MEASURES.items():
        p = summary[measure]
        out[measure] = {"scenarios": p["n"], "mean": means[measure] * scale,
                        "difference": p["mean"] * scale, "interval": [p["low"] * scale, p["high"] * scale],
                        "ratio": p["ratio"], "better": p["better"], "worse": p["worse"]}
    return out


def _cell(p: dict) -> str:
    digits = 2 if abs(p["mean"]) >= 1 else 3
    return (f"{p['difference']:+.{digits}f} [{p['interval'][0]:+.{digits}f}, {p['interval'][1]:+.{digits}f}] "
            f"{p['ratio']:+.1%} {p['better']}/{p['worse']}")


def _pairs(rows_dir: Path, steps: int) -> tuple[list[str], dict]:
    """:data:`PAIRS` whose two rows are in ``rows_dir`` (a row of the previous defaults in :data:`PREVIOUS_ROWS`):
    the table's lines and ``"candidate - reference"`` -> measure -> the paired difference."""
    def path(name: str) -> Path:
        if name.endswith(PREVIOUS):
            return PREVIOUS_ROWS / f"{name[:-len(PREVIOUS)]}.json"
        return rows_dir / f"{name}.json"

    result, table = {}, []
    for candidate, reference, what in PAIRS:
        if not (path(candidate).is_file() and path(reference).is_file()):
            continue
        pair = _compare(_episodes(path(candidate)), _episodes(path(reference)), steps)
        result[f"{candidate} - {reference}"] = {"what": what, **pair}
        table.append([f"{candidate} - {reference}", what] + [_cell(pair[m]) for m in MEASURES])
    lines = ["The paper's planner rows paired by scenario (40 eval scenarios, 1000 steps; measures over steps 1-500 "
             "and below 30 % coverage): mean difference [bootstrap 95 %], ratio of means - 1, better / worse; "
             f"`NAME{PREVIOUS}`: the row with the previous defaults "
             "(`benchmarks/history/eval_paper_previous_defaults/rows/`).", ""]
    lines += markdown_table(["pair", "what it measures"] + [MEASURES[m][0] for m in MEASURES], table,
                            ["-", "-"] + ["-"] * len(MEASURES))
    return lines, result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=Path, default=ROOT / "benchmarks" / "eval_paper" / "rows",
                        help="the paper suite's 1000-step rows (the full pipeline and the reference)")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "eval_paper" / "ablations",
                        help="the ablations' run folder (its rows/ are read; the tables and plots written there)")
    args = parser.parse_args(argv)
    steps = 1000  # the paper protocol's: first half = steps 1-500
    full = _episodes(args.rows / f"{FULL}.json")
    reference = _episodes(args.rows / f"{REFERENCE}.json")
    names = [n for n in ORDER if (args.out / "rows" / f"{n}.json").is_file()]
    if not names:
        raise SystemExit(f"no ablation row in {args.out / 'rows'}")
    result = {}
    for n in names:
        rows = _episodes(args.out / "rows" / f"{n}.json")
        vs_full, vs_reference = _compare(rows, full, steps), _compare(rows, reference, steps)
        result[n] = {m: {"vs_full": vs_full[m], "vs_reference": vs_reference[m]} for m in MEASURES}
    result[FULL] = {m: {"vs_reference": p} for m, p in _compare(full, reference, steps).items()}

    lines = [f"Ablations of the SuperEx pipeline (40 eval scenarios, steps 1-500 of the paper's episodes), paired by "
             f"scenario: mean, and the mean difference [bootstrap 95 %], ratio of means - 1, better / worse; "
             f"against the full pipeline (`{FULL}`) and against MapEx on LaMa-LOS (`{REFERENCE}`).", ""]
    for measure, (label, scale) in MEASURES.items():
        lines += [f"**{label}**", ""]
        rows = [[f"{FULL}: {PIPELINES[FULL].label}", f"{result[FULL][measure]['vs_reference']['mean']:.3f}", "-",
                 _cell(result[FULL][measure]["vs_reference"])]]
        rows += [[f"{n}: {PIPELINES[n].label}", f"{result[n][measure]['vs_full']['mean']:.3f}",
                  _cell(result[n][measure]["vs_full"]), _cell(result[n][measure]["vs_reference"])] for n in names]
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
    pair_lines, pairs = _pairs(args.rows, steps)
    write_text(args.rows.parent / "pairs.md", "\n".join(pair_lines))
    write_json(args.rows.parent / "pairs.json", pairs)
    print("\n" + "\n".join(pair_lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
