"""Compare two ``superex benchmark`` runs scenario by scenario (paired by map, start pose and planner).

Prints, per checkpoint, the median and mean difference in coverage points (candidate minus baseline) and how
many scenarios the candidate explores better / worse / equally, next to each run's mean; the same for the final
map IoU. Writes JSON. Example (the SuperEx pipeline against MapEx on the line-of-sight ensemble):

    .venv/bin/python scripts/compare_benchmarks.py runs/bench_los/results.json runs/bench_bp/results.json \\
        --candidate-series coverage_with_carving --out benchmarks/compare.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from superex_deploy.evaluation import write_json
from superex_deploy.evaluation.summary import paired_differences


def _load(path: Path) -> list[dict]:
    if not path.is_file():
        raise SystemExit(f"no benchmark results at {path} (run `superex benchmark ... --out DIR` first)")
    return json.loads(path.read_text())["episodes"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("baseline", type=Path, help="results.json of the baseline run")
    parser.add_argument("candidate", type=Path, help="results.json of the candidate run")
    parser.add_argument("--checkpoints", default="100,250,500", help="comma-separated step counts")
    parser.add_argument("--baseline-series", default="coverage", choices=("coverage", "coverage_with_carving"))
    parser.add_argument("--candidate-series", default="coverage", choices=("coverage", "coverage_with_carving"))
    parser.add_argument("--out", type=Path, default=None, help="JSON output")
    args = parser.parse_args()
    baseline, candidate = _load(args.baseline), _load(args.candidate)
    checkpoints = [int(s) for s in args.checkpoints.split(",") if s.strip()]
    paired = paired_differences(baseline, candidate, checkpoints, series=args.candidate_series,
                                baseline_series=args.baseline_series)
    print(f"baseline {args.baseline} ({args.baseline_series}) vs candidate {args.candidate} "
          f"({args.candidate_series}), {next(iter(paired.values()))['n']} paired scenarios\n")
    print("| metric | baseline mean | candidate mean | paired median | paired mean | better / worse / tied |")
    print("|---|---:|---:|---:|---:|---|")
    for metric, row in paired.items():
        scale, digits = (100.0, 1) if metric.startswith("coverage") else (1.0, 3)
        print(f"| {metric} | {row['baseline_mean'] * scale:.{digits}f} | {row['candidate_mean'] * scale:.{digits}f} "
              f"| {row['median'] * scale:+.{digits}f} | {row['mean'] * scale:+.{digits}f} "
              f"| {row['better']} / {row['worse']} / {row['tied']} |")
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        write_json(args.out, {"baseline": str(args.baseline), "candidate": str(args.candidate),
                              "baseline_series": args.baseline_series, "candidate_series": args.candidate_series,
                              "paired": paired})
        print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
