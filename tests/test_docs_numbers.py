"""The headline numbers of the README and of the benchmark pages, read against the committed benchmark files.

Every claim below is one phrase of a page, written as the page prints it with ``{}`` where a number stands, and the
file under ``benchmarks/`` the number comes from. The test finds the phrase in the page (once, in the table row or
section named), reads its numbers and compares them, as printed, with the file's values rounded the way the page
rounds them. A rerun of a benchmark that moves a headline number therefore fails here until the page says the new
number, and a page edited by hand fails until it matches its file again. To add a claim: copy the sentence from the
page, put ``{}`` where its numbers are, and say how each is read from the file (the helpers below format them).
"""

from __future__ import annotations

import fnmatch
import itertools
import json
import math
import re
import statistics
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Callable

import pytest

ROOT = Path(__file__).resolve().parents[1]

# A number as the pages print it: an optional sign, digits with optional thousands commas, optional decimals.
NUMBER = r"[+-]?\d[\d,]*(?:\.\d+)?"


# ---------------------------------------------------------------------------------------------------------------
# Reading the pages


def _template_pattern(template: str) -> re.Pattern:
    """A template's regular expression: literal text (any run of whitespace matching any whitespace, so a phrase may
    wrap onto the next line of the markdown source) with a captured number at each ``{}``."""
    parts = []
    for piece in re.split(r"(\{\}|\s+)", template):
        if piece == "{}":
            parts.append(f"({NUMBER})")
        elif piece and piece.isspace():
            parts.append(r"\s+")
        elif piece:
            parts.append(re.escape(piece))
    # A number must not run on from a digit or a sign just before the placeholder, nor into one after it.
    pattern = "".join(parts)
    pattern = pattern.replace(f"({NUMBER})", f"(?<![\\d.])({NUMBER})(?![\\d])")
    return re.compile(pattern)


@lru_cache(maxsize=None)
def _page(path: str) -> str:
    return (ROOT / path).read_text(encoding="utf-8")


def _scope(text: str, where: str) -> str:
    """The part of a page a claim is read from: ``""`` the whole page; ``"| start"`` the one table row that starts
    so; ``"## Heading"`` (any level) the section under that heading, up to the next heading of its level or above."""
    if not where:
        return text
    if where.startswith("|"):
        rows = [line for line in text.splitlines() if line.startswith(where)]
        assert len(rows) == 1, f"expected one table row starting {where!r}, found {len(rows)}"
        return rows[0]
    level = len(where) - len(where.lstrip("#"))
    lines = text.splitlines()
    starts = [i for i, line in enumerate(lines) if line.strip() == where]
    assert len(starts) == 1, f"expected one heading {where!r}, found {len(starts)}"
    end = len(lines)
    for i in range(starts[0] + 1, len(lines)):
        match = re.match(r"^(#+) ", lines[i])
        if match and len(match.group(1)) <= level:
            end = i
            break
    return "\n".join(lines[starts[0]:end])


def read_numbers(text: str, template: str) -> list[str]:
    """The numbers at the ``{}`` of the template's one occurrence in the text, as printed (thousands commas
    dropped)."""
    matches = list(_template_pattern(template).finditer(text))
    assert len(matches) == 1, f"expected the phrase once, found it {len(matches)} times: {template!r}"
    return [number.replace(",", "") for number in matches[0].groups()]


# ---------------------------------------------------------------------------------------------------------------
# Reading the files, and printing their numbers as the pages do


@lru_cache(maxsize=None)
def _json(path: str):
    return json.loads((ROOT / path).read_text(encoding="utf-8"))


def read(path: str):
    """A committed benchmark file (JSON), parsed once."""
    return _json(path)


def fixed(value: float, decimals: int) -> str:
    """``12.1``: the value with this many decimals."""
    return f"{value:.{decimals}f}"


def signed(value: float, decimals: int) -> str:
    """``+0.96``, ``-0.46``: with its sign."""
    return f"{value:+.{decimals}f}"


def percent(ratio: float, decimals: int = 1) -> str:
    """``+2.3``: a ratio - 1 (0.023) as a signed percentage."""
    return signed(100.0 * ratio, decimals)


def points(fraction: float, decimals: int = 2) -> str:
    """``+0.96``: a difference of coverage fractions (0.0096) in signed percentage points."""
    return signed(100.0 * fraction, decimals)


def count(value: float) -> str:
    """``26``: a count (or a whole number of steps, scenarios)."""
    return str(int(round(value)))


def interval(pair, scale: float = 1.0, decimals: int = 2) -> list[str]:
    """``[-0.46, +2.71]``'s two numbers."""
    return [signed(scale * pair[0], decimals), signed(scale * pair[1], decimals)]


def paired(entry: dict, scale: float = 100.0, decimals: int = 2) -> list[str]:
    """A paired difference of ``results.json`` (``mean``, ``low``, ``high`` as fractions) in signed points."""
    return [signed(scale * entry["mean"], decimals), signed(scale * entry["low"], decimals),
            signed(scale * entry["high"], decimals)]


def _pairs_entry(entry: dict) -> list[str]:
    """A paired difference of ``pairs.json`` / ``ablations.json`` (``difference`` and ``interval`` in points)."""
    return [signed(entry["difference"], 2), *interval(entry["interval"])]


# ---------------------------------------------------------------------------------------------------------------
# The files the claims read

PAPER = "benchmarks/eval_paper/results.json"
PAIRS = "benchmarks/eval_paper/pairs.json"
PREVIOUS = "benchmarks/history/eval_paper_previous_defaults/results.json"
ABLATIONS = "benchmarks/eval_paper/ablations/ablations.json"
ALTERED = "benchmarks/eval_altered/defaults34/results.json"
ALTERED_NOW = "benchmarks/eval_altered/shipped44/results.json"
SIDE_BY_SIDE = "benchmarks/eval_altered/side_by_side.json"
CEILING = "benchmarks/ceiling_study/ceiling_study_1000.json"
CARVE_CEILINGS = {"goal": "benchmarks/carve_gain_ceiling/ceiling.json",
                  "path": "benchmarks/carve_gain_ceiling/path/ceiling.json",
                  "weight3": "benchmarks/carve_gain_ceiling/weight3/ceiling.json",
                  "path_weight3": "benchmarks/carve_gain_ceiling/path_weight3/ceiling.json",
                  "confirm": "benchmarks/carve_gain_ceiling/confirm/ceiling.json"}
FRAME = "benchmarks/frame_budget/realtime.json"
FRAME_NOW = "benchmarks/frame_budget/shipped44/realtime.json"
FRAME_34 = "benchmarks/frame_budget/defaults34/realtime.json"
LATTICE_TIMING = "benchmarks/lattice/timing/realtime.json"
FINE = "benchmarks/realtime/fine/realtime.json"
MODELS = "benchmarks/eval_models/eval_models.json"
MODELS_PREVIOUS = "benchmarks/history/eval_models_previous/eval_models_previous.json"
MODEL_SPEED = "benchmarks/model_speed/bench_models.json"
ROBUSTNESS = "benchmarks/robustness/robustness.json"
RESOLUTION = "benchmarks/resolution/resolution.json"
GROWTH = "benchmarks/growth/growth.json"
SPAD = "benchmarks/spad/bench_spad.json"
EXPLORE = "benchmarks/explore/bench_explore.json"

ROBOT_POINT = "pose0.05m1deg_spad-realistic_lidar0.02m"  # the robustness targets' point: 5 cm / 1 deg, LiDAR 2 cm


def superex_vs_mapex_lama_los(metric: str) -> dict:
    """The shipped SuperEx row paired with MapEx on LaMa-LOS by scenario (the paper table's headline)."""
    return read(PAPER)["paired_vs_reference"]["superex"][metric]


def ceiling_row(idea: str, predictor: str) -> dict:
    return next(row for row in read(CEILING)["rows"] if row["idea"] == idea and row["predictor"] == predictor)


def pathwise_ceiling_on_eval() -> float:
    """The superex planner with the true map over MapEx on the observed map, ratio of the means - 1, as measured
    with the previous defaults (the pathwise gain)."""
    summary = read(PREVIOUS)["summary"]
    return summary["superex_oracle"]["auc_first_half"] / summary["mapex_observed"]["auc_first_half"] - 1.0


def timing(path: str, setting: str) -> dict:
    return read(path)["timing"][setting]


def unpaced_over_mapex(path: str, setting: str) -> float:
    walls = read(path)["timing"]
    return walls[setting]["episode_wall_s"] / walls["mapex_observed"]["episode_wall_s"]


def realtime_vs_full(metric: str) -> dict:
    return read(FRAME)["error"]["eval"]["paired"]["realtime"][metric]


def unknown_iou_ratio(path: str, coverage_bin: str) -> float:
    entry = read(path)["predictors"]["bins"][coverage_bin]
    return entry["lama_bp_unknown_iou"] / entry["lama_los_unknown_iou"]


def unknown_iou(path: str, coverage_bin: str, ensemble: str) -> float:
    return read(path)["predictors"]["bins"][coverage_bin][f"{ensemble}_unknown_iou"]


FAR_BINS = ("5-10 m", ">10 m")  # farther than 5 m from known space


def far(ensemble: str, key: str) -> float:
    """A measure pooled over the cells farther than 5 m from known space (the bins weighted by their cells)."""
    pooled = read(MODELS)["predictors"]["distance"]["pooled"][ensemble]
    cells = sum(pooled[name]["cells"] for name in FAR_BINS)
    return sum(pooled[name][key] * pooled[name]["cells"] for name in FAR_BINS) / cells


def far_ece(ensemble: str) -> float:
    """The calibration error far out: the worse of the two far bins."""
    pooled = read(MODELS)["predictors"]["distance"]["pooled"][ensemble]
    return max(pooled[name]["ece"] for name in FAR_BINS)


def distance_row(name: str) -> list[str]:
    pooled = read(MODELS)["predictors"]["distance"]["pooled"]
    bp, los = pooled["lama_bp"][name], pooled["lama_los"][name]
    return [fixed(bp["wall_share"], 3), fixed(bp["mean_p"], 3), fixed(bp["ece"], 3), fixed(los["mean_p"], 3),
            fixed(los["ece"], 3)]


def robot(key: str, setting: str = ROBOT_POINT):
    return read(ROBUSTNESS)["settings"][setting][key]


def resolution(measure: str) -> dict:
    return read(RESOLUTION)[measure]


def fine_to_coarse(measure: str) -> float:
    entry = resolution(measure)
    return entry["mean_0.05m"] / entry["mean_0.1m"] - 1.0


def growth(grid: str) -> dict:
    return next(row for row in read(GROWTH)["rows"] if row["grid"] == grid)


def spad_episodes(numerator: str, denominator: str) -> float:
    """A ratio of the SPAD benchmark's episode medians (medians over steps, then over maps)."""
    episodes = read(SPAD)["episodes"]
    return episodes[f"median_{numerator}_ms"] / episodes[f"median_{denominator}_ms"]


def altered_ceiling_change() -> dict:
    """The oracle's lead over MapEx on the observed map, altered floors minus standard ones (300 steps)."""
    entries = read(SIDE_BY_SIDE)["entries"]
    return next(e for e in entries if e["row"] == "superex_oracle" and e["baseline"] == "mapex_observed")["change"]


def carve_ceiling(variant: str) -> dict:
    """The true carve gain's ceiling (``carve_gain_ceiling``) of one variant: the paired first-half AUC."""
    return read(CARVE_CEILINGS[variant])["auc_first_half"]


def carve_ceiling_row(variant: str) -> list[str]:
    """A row of the carve gain ceiling's table: scenarios, AUC today and ceiling, the paired difference [95 %],
    the relative gain, better / worse / tied."""
    entry = carve_ceiling(variant)
    return [count(read(CARVE_CEILINGS[variant])["scenarios_finished"]), fixed(100 * entry["today"], 2),
            fixed(100 * entry["ceiling"], 2), points(entry["difference"]), *interval(entry["interval"], 100.0),
            percent(entry["relative"]), *[count(entry[k]) for k in ("better", "worse", "tied")]]


def onnx_median_speedup() -> float:
    return statistics.median(model["torch_over_ort"] for model in read(MODEL_SPEED)["models"])


# ---------------------------------------------------------------------------------------------------------------
# The claims


@dataclass(frozen=True)
class Claim:
    page: str                         # the page, from the repository root
    where: str                        # "" the whole page, "| row start" one table row, "## Heading" one section
    template: str                     # the page's words, "{}" at each number
    files: tuple[str, ...]            # the benchmark files the numbers come from
    key: str                          # where in the files, for the reader of a failure
    values: Callable[[], list[str]]   # the numbers as the page prints them, read from the files

    @property
    def id(self) -> str:
        return f"{self.page}: {self.template[:60]}"


README = "README.md"
INDEX = "docs/benchmarks/index.md"
REALTIME = "docs/benchmarks/realtime.md"
MODELS_PAGE = "docs/benchmarks/models.md"
BETTER_MAP = "docs/benchmarks/better-map.md"
SPAD_PAGE = "docs/benchmarks/spad.md"
RESOLUTION_PAGE = "docs/benchmarks/resolution.md"
ROBOT_PAGE = "docs/on-a-robot.md"

ROW_PAPER = "| Does the SuperEx pipeline explore faster than MapEx on LaMa-LOS?"
ROW_MAPS = "| Are its maps better?"
ROW_CEILING = "| How much could a perfect map give?"
ROW_FRAME = "| Does a step fit in the SPAD's 100 ms frame?"
ROW_FILTER = "| Does the learned filter beat the classic one?"
ROW_PREDICTOR = "| Does the SPAD evidence make a better map predictor?"
ROW_ROBOT = "| Does it survive a robot's data?"
ROW_SLAM = "| Does it work on a SLAM grid?"
ROW_GROWTH = "| Does a step cost what the robot explored, not the frame?"
ROW_SPAD = "| What does a SPAD scan cost?"

INDEX_BETTER = "| [Does a better map make exploration faster](better-map.md)"
INDEX_REALTIME = "| [Real time](realtime.md)"
INDEX_ONBOARD = "| [Onboard step cost](onboard.md)"
INDEX_SPAD = "| [SPAD simulator and NLOS processing](spad.md)"
INDEX_EXPLORE = "| [Exploration loop and baseline planners](exploration.md)"
INDEX_MODELS = "| [Model accuracy and speed](models.md)"

FRAME_NOW_SECTION = "## The frame budget with the shipped defaults"
FRAME_SECTION = "## The default today: never waiting"
SHIPPED_MODELS_SECTION = "## The shipped models, retrained for 256-ray scans"
PAPER_SECTION = "### With the shipped defaults"
CARVE_SECTION = "## The NLOS gain's ceiling: the planner given the true carve gain"


CLAIMS = [
    # --- README: the headline results -----------------------------------------------------------------------
    Claim(README, ROW_PAPER, "| {} % ({} points [{}, {}], {} better / {} worse;",
          (PAPER,), "paired_vs_reference.superex.auc_first_half: ratio, mean [low, high], better, worse",
          lambda: [percent(superex_vs_mapex_lama_los("auc_first_half")["ratio"]),
                   *paired(superex_vs_mapex_lama_los("auc_first_half")),
                   count(superex_vs_mapex_lama_los("auc_first_half")["better"]),
                   count(superex_vs_mapex_lama_los("auc_first_half")["worse"])]),
    Claim(README, ROW_PAPER, "previous defaults {} %)", (PREVIOUS,),
          "paired_vs_reference.superex.auc_first_half.ratio",
          lambda: [percent(read(PREVIOUS)["paired_vs_reference"]["superex"]["auc_first_half"]["ratio"])]),
    Claim(README, ROW_PAPER, "line of sight only {} %", (PAPER,),
          "paired_vs_reference.superex.los_auc_first_half.ratio",
          lambda: [percent(superex_vs_mapex_lama_los("los_auc_first_half")["ratio"])]),
    Claim(README, ROW_PAPER, "{} % ({} [{}, {}]) against the same planner on the observed map", (PAIRS,),
          "'superex - superex_observed'.auc_first_half: ratio, difference, interval",
          lambda: [percent(read(PAIRS)["superex - superex_observed"]["auc_first_half"]["ratio"]),
                   *_pairs_entry(read(PAIRS)["superex - superex_observed"]["auc_first_half"])]),
    Claim(README, ROW_PAPER, "carving alone on the observed map {} % ({} [{}, {}])", (ABLATIONS,),
          "carving_only.auc_first_half.vs_reference: ratio, difference, interval",
          lambda: [percent(read(ABLATIONS)["carving_only"]["auc_first_half"]["vs_reference"]["ratio"]),
                   *_pairs_entry(read(ABLATIONS)["carving_only"]["auc_first_half"]["vs_reference"])]),
    Claim(README, ROW_PAPER, "altered with hidden dead ends ({} scenarios, {} steps) {} % ({} [{}, {}])", (ALTERED,),
          "paired_vs_reference.superex.auc_first_half: n, setting.steps, ratio, mean [low, high]",
          lambda: [count(read(ALTERED)["paired_vs_reference"]["superex"]["auc_first_half"]["n"]),
                   count(read(ALTERED)["setting"]["steps"]),
                   percent(read(ALTERED)["paired_vs_reference"]["superex"]["auc_first_half"]["ratio"]),
                   *paired(read(ALTERED)["paired_vs_reference"]["superex"]["auc_first_half"])]),
    Claim(README, ROW_MAPS, "| {} % / {} %, 0-10 %: {} % |", (PAPER,),
          "paired_vs_reference.superex: iou@0.10, iou@0.20, iou_bin_0.0_0.1 ratios",
          lambda: [percent(superex_vs_mapex_lama_los("iou@0.10")["ratio"], 0),
                   percent(superex_vs_mapex_lama_los("iou@0.20")["ratio"], 0),
                   percent(superex_vs_mapex_lama_los("iou_bin_0.0_0.1")["ratio"], 0)]),
    Claim(README, ROW_CEILING, "| {} % on the train floors", (CEILING,), "rows[superex, oracle].ratio",
          lambda: [percent(ceiling_row("superex", "oracle")["ratio"])]),
    Claim(README, ROW_CEILING, "on the train floors, {} % on eval (pathwise gain)", (PREVIOUS,),
          "summary: superex_oracle / mapex_observed auc_first_half - 1",
          lambda: [percent(pathwise_ceiling_on_eval())]),
    Claim(README, ROW_CEILING, "with the shipped expected gain {} % on eval ({} points [{}, {}])", (PAIRS,),
          "'superex_oracle - mapex_observed'.auc_first_half: ratio, difference, interval",
          lambda: [percent(read(PAIRS)["superex_oracle - mapex_observed"]["auc_first_half"]["ratio"]),
                   *_pairs_entry(read(PAIRS)["superex_oracle - mapex_observed"]["auc_first_half"])]),
    Claim(README, ROW_FRAME,
          "shipped defaults (256-ray carving, expected gain, lattice filter): p99 {} ms, mean {} ms, prediction wait "
          "p99 {} ms; one core held by another process: p99 {} ms; unpaced {}x MapEx", (FRAME_NOW,),
          "timing.realtime: p99_ms, mean_ms, wait_p99_ms; timing['realtime (1 core held)'].p99_ms; "
          "episode_wall_s over mapex_observed's",
          lambda: [fixed(timing(FRAME_NOW, "realtime")["p99_ms"], 0),
                   fixed(timing(FRAME_NOW, "realtime")["mean_ms"], 1),
                   fixed(timing(FRAME_NOW, "realtime")["wait_p99_ms"], 2),
                   fixed(timing(FRAME_NOW, "realtime (1 core held)")["p99_ms"], 0),
                   fixed(unpaced_over_mapex(FRAME_NOW, "realtime"), 1)]),
    Claim(README, ROW_FRAME, "loaded p99 150 ms: not met in one run ({} ms), met in another ({} ms, the lattice filter "
          "timed against itself off: {} ms)", (FRAME_NOW, LATTICE_TIMING),
          "timing['realtime (1 core held)'].p99_ms of each; timing['realtime_no_lattice_filter (1 core held)'].p99_ms",
          lambda: [fixed(timing(FRAME_NOW, "realtime (1 core held)")["p99_ms"], 0),
                   fixed(timing(LATTICE_TIMING, "realtime (1 core held)")["p99_ms"], 0),
                   fixed(timing(LATTICE_TIMING, "realtime_no_lattice_filter (1 core held)")["p99_ms"], 0)]),
    Claim(README, ROW_FRAME, "(before the lattice filter: p99 {} ms, mean {} ms, loaded p99 {} ms, {}x;", (FRAME_34,),
          "timing.realtime: p99_ms, mean_ms; timing['realtime (1 core held)'].p99_ms; wall over MapEx",
          lambda: [fixed(timing(FRAME_34, "realtime")["p99_ms"], 0),
                   fixed(timing(FRAME_34, "realtime")["mean_ms"], 1),
                   fixed(timing(FRAME_34, "realtime (1 core held)")["p99_ms"], 0),
                   fixed(unpaced_over_mapex(FRAME_34, "realtime"), 1)]),
    Claim(README, ROW_FRAME, "previous defaults: p99 {} ms, mean {} ms, loaded p99 {} ms, {}x)", (FRAME,),
          "timing.realtime: p99_ms, mean_ms; timing['realtime (1 core held)'].p99_ms; wall over MapEx",
          lambda: [fixed(timing(FRAME, "realtime")["p99_ms"], 0), fixed(timing(FRAME, "realtime")["mean_ms"], 1),
                   fixed(timing(FRAME, "realtime (1 core held)")["p99_ms"], 0),
                   fixed(unpaced_over_mapex(FRAME, "realtime"), 1)]),
    Claim(README, ROW_FRAME,
          "against `full` ({} eval scenarios, {} steps): first-half AUC {} %, wall IoU {} / {} / {} % at 10 / 20 / 30 "
          "% coverage", (FRAME,),
          "error.eval: scenarios, steps; paired.realtime: auc_first_half, iou@0.10 / 0.20 / 0.30 ratios",
          lambda: [count(read(FRAME)["error"]["eval"]["scenarios"]), count(read(FRAME)["error"]["eval"]["steps"]),
                   percent(realtime_vs_full("auc_first_half")["ratio"]),
                   *[percent(realtime_vs_full(f"iou@{c}")["ratio"]) for c in ("0.10", "0.20", "0.30")]]),
    Claim(README, ROW_FILTER, "| Pix2Pix {} ({} at its best threshold), Laplacian {} (", (MODELS,),
          "filter: pix2pix_iou@0.5, pix2pix_best[1], laplacian_iou@0.5",
          lambda: [fixed(read(MODELS)["filter"]["pix2pix_iou@0.5"], 3),
                   fixed(read(MODELS)["filter"]["pix2pix_best"][1], 3),
                   fixed(read(MODELS)["filter"]["laplacian_iou@0.5"], 3)]),
    Claim(README, ROW_FILTER, "the 64-ray filter {})", (MODELS_PREVIOUS,), "filter.pix2pix_iou@0.5",
          lambda: [fixed(read(MODELS_PREVIOUS)["filter"]["pix2pix_iou@0.5"], 3)]),
    Claim(README, ROW_PREDICTOR, "| {}x / {}x / {}x at 0-10 / 10-20 / 20-30 % coverage", (MODELS,),
          "predictors.bins[BIN]: lama_bp_unknown_iou / lama_los_unknown_iou",
          lambda: [fixed(unknown_iou_ratio(MODELS, b), 2) for b in ("0%-10%", "10%-20%", "20%-30%")]),
    Claim(README, ROW_PREDICTOR,
          "calibrated far out within ECE {} (LaMa-LOS {}), both over-predict walls > 5 m from known space (mean p {} "
          "/ {} where {} are walls)", (MODELS,),
          "predictors.distance.pooled[ENSEMBLE]['5-10 m', '>10 m']: worst ece; mean_p and wall_share weighted by cells",
          lambda: [fixed(far_ece("lama_bp"), 2), fixed(far_ece("lama_los"), 2), fixed(far("lama_bp", "mean_p"), 2),
                   fixed(far("lama_los", "mean_p"), 2), fixed(far("lama_bp", "wall_share"), 2)]),
    Claim(README, ROW_ROBOT,
          "(pose noise {} cm / {} deg, LiDAR {} cm, realistic SPAD; nearest, {} eval scenarios, {} steps)",
          (ROBUSTNESS,), f"settings['{ROBOT_POINT}']: pose, lidar_m, episodes; steps",
          lambda: [fixed(100 * robot("pose")[0], 0), fixed(robot("pose")[1], 0), fixed(100 * robot("lidar_m"), 0),
                   count(robot("episodes")), count(read(ROBUSTNESS)["steps"])]),
    Claim(README, ROW_ROBOT, "| {} collisions and {} true walls carved (up to {} cm / {} deg)", (ROBUSTNESS,),
          "settings[*]: the most collisions and true_walls_carved, the largest pose noise",
          lambda: [count(max(s["collisions"] for s in read(ROBUSTNESS)["settings"].values())),
                   count(max(s["true_walls_carved"] for s in read(ROBUSTNESS)["settings"].values())),
                   fixed(100 * max(s["pose"][0] for s in read(ROBUSTNESS)["settings"].values()), 0),
                   fixed(max(s["pose"][1] for s in read(ROBUSTNESS)["settings"].values()), 0)]),
    Claim(README, ROW_ROBOT, "map wall IoU {} of noise-free, first-half AUC {} % ({} points [{}, {}])",
          (ROBUSTNESS,), f"settings['{ROBOT_POINT}']: map_iou_vs_noise_free, auc_vs_noise_free[0], "
                         "auc_points_vs_noise_free",
          lambda: [fixed(robot("map_iou_vs_noise_free"), 2), percent(robot("auc_vs_noise_free")[0]),
                   *[signed(v, 2) for v in robot("auc_points_vs_noise_free")]]),
    Claim(README, ROW_ROBOT, "SuperEx keeps {} of its IoU gain over LaMa-LOS ({} scenarios)", (ROBUSTNESS,),
          f"superex['{ROBOT_POINT}']: kept@10%, episodes",
          lambda: [fixed(read(ROBUSTNESS)["superex"][ROBOT_POINT]["kept@10%"], 2),
                   count(read(ROBUSTNESS)["superex"][ROBOT_POINT]["episodes"])]),
    Claim(README, ROW_ROBOT, "{} true walls held free per 1,000 seen, {} of them with no map wall within a cell",
          (ROBUSTNESS,), f"settings['{ROBOT_POINT}']: held_free_per_1000_seen, missing_per_1000_seen",
          lambda: [fixed(robot("held_free_per_1000_seen"), 0), fixed(robot("missing_per_1000_seen"), 0)]),
    Claim(README, ROW_SLAM,
          "| first-half AUC {} % ({} points [{}, {}]), path {} %, wall IoU {} / {} / {} % at 10 / 20 / 30 % coverage "
          "(the metric alone loses {} % at 0.05 m)", (RESOLUTION,),
          "the 0.05 m mean over the 0.1 m mean - 1 per measure; 'first-half AUC (%)': difference, interval; "
          "interpolation: bilinear / 0.1m - 1",
          lambda: [percent(fine_to_coarse("first-half AUC (%)")),
                   signed(resolution("first-half AUC (%)")["difference"], 2),
                   *interval(resolution("first-half AUC (%)")["interval"]),
                   percent(fine_to_coarse("path (m)")),
                   *[percent(fine_to_coarse(f"IoU @{c} %")) for c in (10, 20, 30)],
                   fixed(100 * (1 - read(RESOLUTION)["interpolation"]["bilinear"]
                                / read(RESOLUTION)["interpolation"]["0.1m"]), 1)]),
    Claim(README, ROW_SLAM,
          "p99 {} ms, mean {} ms on the largest eval floor at 0.05 m, p99 {} ms, mean {} ms on a generated", (FINE,),
          "timing['realtime@50015847@x2'], timing['realtime@generated@0.05']: p99_ms, mean_ms",
          lambda: [fixed(timing(FINE, "realtime@50015847@x2")["p99_ms"], 0),
                   fixed(timing(FINE, "realtime@50015847@x2")["mean_ms"], 1),
                   fixed(timing(FINE, "realtime@generated@0.05")["p99_ms"], 0),
                   fixed(timing(FINE, "realtime@generated@0.05")["mean_ms"], 1)]),
    Claim(README, ROW_GROWTH,
          "| growing map {}x the floor's own frame; a frame of {} M cells {}x, of {} M cells {}x |", (GROWTH,),
          "rows[grid]: median_ratio_to_floor, cells_mean",
          lambda: [fixed(growth("growing from 10 m")["median_ratio_to_floor"], 2),
                   fixed(growth("padded 4 M")["cells_mean"] / 1e6, 0),
                   fixed(growth("padded 4 M")["median_ratio_to_floor"], 0),
                   fixed(growth("padded 25 M")["cells_mean"] / 1e6, 0),
                   fixed(growth("padded 25 M")["median_ratio_to_floor"], 0)]),
    Claim(README, ROW_SPAD, "| {}x in episodes, a grid's first scan ~{}x; NLOS processing {}x the scan |", (SPAD,),
          "episodes: median_spad_ms / median_los_ms, median_nlos_ms / median_spad_ms; "
          "single_scans.median_ratios.cold_spad_over_los",
          lambda: [fixed(spad_episodes("spad", "los"), 1),
                   fixed(read(SPAD)["single_scans"]["median_ratios"]["cold_spad_over_los"], 1),
                   fixed(spad_episodes("nlos", "spad"), 1)]),

    # --- docs/benchmarks/index.md: the headline column ------------------------------------------------------
    Claim(INDEX, INDEX_BETTER,
          "the SuperEx pipeline with the shipped defaults {} % first-half AUC over MapEx on LaMa-LOS", (PAPER,),
          "paired_vs_reference.superex.auc_first_half.ratio",
          lambda: [percent(superex_vs_mapex_lama_los("auc_first_half")["ratio"])]),
    Claim(INDEX, INDEX_BETTER, "(previous defaults {} %)", (PREVIOUS,),
          "paired_vs_reference.superex.auc_first_half.ratio",
          lambda: [percent(read(PREVIOUS)["paired_vs_reference"]["superex"]["auc_first_half"]["ratio"])]),
    Claim(INDEX, INDEX_BETTER, "maps {} % wall IoU at 10 % coverage", (PAPER,),
          "paired_vs_reference.superex['iou@0.10'].ratio",
          lambda: [percent(superex_vs_mapex_lama_los("iou@0.10")["ratio"], 0)]),
    Claim(INDEX, INDEX_BETTER, "carving alone on the observed map {} %, carving left out {} %", (ABLATIONS,),
          "carving_only.auc_first_half.vs_reference.ratio, no_carving.auc_first_half.vs_full.ratio",
          lambda: [percent(read(ABLATIONS)["carving_only"]["auc_first_half"]["vs_reference"]["ratio"]),
                   percent(read(ABLATIONS)["no_carving"]["auc_first_half"]["vs_full"]["ratio"])]),
    Claim(INDEX, INDEX_BETTER, "the planner's ceiling with the true map {} % (train)", (CEILING,),
          "rows[superex, oracle].ratio", lambda: [percent(ceiling_row("superex", "oracle")["ratio"])]),
    Claim(INDEX, INDEX_BETTER, "/ {} % (eval) with the pathwise gain", (PREVIOUS,),
          "summary: superex_oracle / mapex_observed auc_first_half - 1", lambda: [percent(pathwise_ceiling_on_eval())]),
    Claim(INDEX, INDEX_BETTER, "{} % (eval) with the shipped expected gain", (PAIRS,),
          "'superex_oracle - mapex_observed'.auc_first_half.ratio",
          lambda: [percent(read(PAIRS)["superex_oracle - mapex_observed"]["auc_first_half"]["ratio"])]),
    Claim(INDEX, INDEX_BETTER, "the same planner on LaMa-LOS {} % from the new gain", (PAIRS,),
          "'superex_lama_los - superex_lama_los@previous'.auc_first_half.ratio",
          lambda: [percent(read(PAIRS)["superex_lama_los - superex_lama_los@previous"]["auc_first_half"]["ratio"])]),
    Claim(INDEX, INDEX_BETTER, "the ceiling does not grow ({} points, {} steps)", (SIDE_BY_SIDE,),
          "entries[superex_oracle vs mapex_observed].change.mean, steps",
          lambda: [points(altered_ceiling_change()["mean"]), count(read(SIDE_BY_SIDE)["steps"])]),
    Claim(INDEX, INDEX_BETTER, "given the true carve gain the planner is no faster ({} %, {} points [{}, {}], train)",
          (CARVE_CEILINGS["goal"],), "auc_first_half: relative, difference [interval]",
          lambda: [percent(carve_ceiling("goal")["relative"]), points(carve_ceiling("goal")["difference"]),
                   *interval(carve_ceiling("goal")["interval"], 100.0)]),
    Claim(INDEX, INDEX_BETTER, "{} % at best (carved along the path, weight 3;", (CARVE_CEILINGS["path_weight3"],),
          "auc_first_half.relative", lambda: [percent(carve_ceiling("path_weight3")["relative"])]),
    Claim(INDEX, INDEX_REALTIME,
          "with the shipped defaults p99 {} ms, mean {} ms ({} ms with a core held), {}x MapEx unpaced", (FRAME_NOW,),
          "timing.realtime: p99_ms, mean_ms; timing['realtime (1 core held)'].p99_ms; wall over MapEx",
          lambda: [fixed(timing(FRAME_NOW, "realtime")["p99_ms"], 0),
                   fixed(timing(FRAME_NOW, "realtime")["mean_ms"], 1),
                   fixed(timing(FRAME_NOW, "realtime (1 core held)")["p99_ms"], 0),
                   fixed(unpaced_over_mapex(FRAME_NOW, "realtime"), 1)]),
    Claim(INDEX, INDEX_REALTIME,
          "the previous defaults: p99 {} ms, {}x); first-half AUC {} % of `full`, IoU at 10 % coverage {} %",
          (FRAME,), "timing.realtime.p99_ms, wall over MapEx; error.eval.paired.realtime: auc_first_half, iou@0.10",
          lambda: [fixed(timing(FRAME, "realtime")["p99_ms"], 0), fixed(unpaced_over_mapex(FRAME, "realtime"), 1),
                   percent(realtime_vs_full("auc_first_half")["ratio"]),
                   percent(realtime_vs_full("iou@0.10")["ratio"])]),
    Claim(INDEX, INDEX_ONBOARD,
          "a map that grows costs {}x a step on the floor's own frame, a frame of {} M cells {}x", (GROWTH,),
          "rows[grid]: median_ratio_to_floor, cells_mean",
          lambda: [fixed(growth("growing from 10 m")["median_ratio_to_floor"], 2),
                   fixed(growth("padded 25 M")["cells_mean"] / 1e6, 0),
                   fixed(growth("padded 25 M")["median_ratio_to_floor"], 0)]),
    Claim(INDEX, INDEX_SPAD,
          "SPAD scan {}x the LOS scan in episodes, a grid's first scan ~{}x; NLOS processing {}x the scan in episodes",
          (SPAD,), "episodes medians; single_scans.median_ratios.cold_spad_over_los",
          lambda: [fixed(spad_episodes("spad", "los"), 1),
                   fixed(read(SPAD)["single_scans"]["median_ratios"]["cold_spad_over_los"], 1),
                   fixed(spad_episodes("nlos", "spad"), 1)]),
    Claim(INDEX, INDEX_EXPLORE, "a {}-step episode in under {} s", (EXPLORE,),
          "steps; rows[*].episode_s (the slowest, rounded up)",
          lambda: [count(read(EXPLORE)["steps"]),
                   str(math.ceil(max(row["episode_s"] for row in read(EXPLORE)["rows"])))]),
    Claim(INDEX, INDEX_MODELS, "Pix2Pix held-out wall IoU {} (Laplacian {};", (MODELS,),
          "filter: pix2pix_iou@0.5, laplacian_iou@0.5",
          lambda: [fixed(read(MODELS)["filter"]["pix2pix_iou@0.5"], 3),
                   fixed(read(MODELS)["filter"]["laplacian_iou@0.5"], 3)]),
    Claim(INDEX, INDEX_MODELS, "the previous 64-ray models {},", (MODELS_PREVIOUS,), "filter.pix2pix_iou@0.5",
          lambda: [fixed(read(MODELS_PREVIOUS)["filter"]["pix2pix_iou@0.5"], 3)]),
    Claim(INDEX, INDEX_MODELS, "beyond 5 m LaMa-BP predicts {}x the true wall share, LaMa-LOS {}x", (MODELS,),
          "predictors.distance.pooled: mean_p / wall_share beyond 5 m, weighted by cells",
          lambda: [fixed(far("lama_bp", "mean_p") / far("lama_bp", "wall_share"), 1),
                   fixed(far("lama_los", "mean_p") / far("lama_los", "wall_share"), 1)]),
    Claim(INDEX, INDEX_MODELS, "ONNX Runtime median {}x torch", (MODEL_SPEED,), "median of models[*].torch_over_ort",
          lambda: [fixed(onnx_median_speedup(), 2)]),

    # --- docs/benchmarks/realtime.md --------------------------------------------------------------------------
    Claim(REALTIME, FRAME_NOW_SECTION, "| realtime | {} | {} | {} | {} | {} | {} | {} | {} ({}) | {} |", (FRAME_NOW,),
          "timing.realtime: p50, p90, p99, max, mean, first step, stages map_update, wait p99 (max), wall",
          lambda: [*[fixed(timing(FRAME_NOW, "realtime")[k], 1) for k in ("p50_ms", "p90_ms", "p99_ms")],
                   fixed(timing(FRAME_NOW, "realtime")["max_ms"], 0),
                   fixed(timing(FRAME_NOW, "realtime")["mean_ms"], 1),
                   fixed(timing(FRAME_NOW, "realtime")["first_step_ms"], 1),
                   fixed(timing(FRAME_NOW, "realtime")["stages_mean_ms"]["map_update"], 1),
                   fixed(timing(FRAME_NOW, "realtime")["wait_p99_ms"], 2),
                   fixed(timing(FRAME_NOW, "realtime")["wait_max_ms"], 1),
                   fixed(timing(FRAME_NOW, "realtime")["episode_wall_s"], 0)]),
    Claim(REALTIME, FRAME_NOW_SECTION, "| realtime (1 core held) | {} | {} | {} | {} | {} |", (FRAME_NOW,),
          "timing['realtime (1 core held)']: p50, p90, p99, max, mean",
          lambda: [*[fixed(timing(FRAME_NOW, "realtime (1 core held)")[k], 1)
                     for k in ("p50_ms", "p90_ms", "p99_ms")],
                   fixed(timing(FRAME_NOW, "realtime (1 core held)")["max_ms"], 0),
                   fixed(timing(FRAME_NOW, "realtime (1 core held)")["mean_ms"], 1)]),
    Claim(REALTIME, FRAME_NOW_SECTION, "full {} s ({}x), realtime {} s ({}x), MapEx {} s.", (FRAME_NOW,),
          "timing[*].episode_wall_s and their ratios to mapex_observed's",
          lambda: [fixed(timing(FRAME_NOW, "full")["episode_wall_s"], 0),
                   fixed(unpaced_over_mapex(FRAME_NOW, "full"), 1),
                   fixed(timing(FRAME_NOW, "realtime")["episode_wall_s"], 0),
                   fixed(unpaced_over_mapex(FRAME_NOW, "realtime"), 1),
                   fixed(timing(FRAME_NOW, "mapex_observed")["episode_wall_s"], 0)]),
    Claim(REALTIME, FRAME_NOW_SECTION, "**met**, the p99 with {} ms to spare; loaded p99 <= 150 ms: **not met**, {} ms "
          "over", (FRAME_NOW,), "100 ms - timing.realtime.p99_ms; timing['realtime (1 core held)'].p99_ms - 150 ms",
          lambda: [fixed(100.0 - timing(FRAME_NOW, "realtime")["p99_ms"], 0),
                   fixed(timing(FRAME_NOW, "realtime (1 core held)")["p99_ms"] - 150.0, 0)]),
    Claim(REALTIME, FRAME_NOW_SECTION, "p99 {} ms, mean {} ms, loaded p99 {}\nms, {}x MapEx", (FRAME_34,),
          "timing.realtime: p99_ms, mean_ms; timing['realtime (1 core held)'].p99_ms; wall over MapEx",
          lambda: [fixed(timing(FRAME_34, "realtime")["p99_ms"], 0), fixed(timing(FRAME_34, "realtime")["mean_ms"], 1),
                   fixed(timing(FRAME_34, "realtime (1 core held)")["p99_ms"], 0),
                   fixed(unpaced_over_mapex(FRAME_34, "realtime"), 1)]),
    Claim(REALTIME, FRAME_NOW_SECTION, "| realtime (lattice filter on, as shipped) | {} | {} | {} | {} | {} | {} |",
          (LATTICE_TIMING,), "timing.realtime: p50, p90, p99, mean; timing['realtime (1 core held)']: p99, mean",
          lambda: [*[fixed(timing(LATTICE_TIMING, "realtime")[k], 1) for k in ("p50_ms", "p90_ms", "p99_ms", "mean_ms")],
                   *[fixed(timing(LATTICE_TIMING, "realtime (1 core held)")[k], 1) for k in ("p99_ms", "mean_ms")]]),
    Claim(REALTIME, FRAME_NOW_SECTION, "| realtime, lattice filter off | {} | {} | {} | {} | {} | {} |",
          (LATTICE_TIMING,), "timing.realtime_no_lattice_filter (and held): p50, p90, p99, mean; p99, mean",
          lambda: [*[fixed(timing(LATTICE_TIMING, "realtime_no_lattice_filter")[k], 1)
                     for k in ("p50_ms", "p90_ms", "p99_ms", "mean_ms")],
                   *[fixed(timing(LATTICE_TIMING, "realtime_no_lattice_filter (1 core held)")[k], 1)
                     for k in ("p99_ms", "mean_ms")]]),
    Claim(REALTIME, FRAME_NOW_SECTION, "loaded p99 is {} ms in the run above and {} ms in this one", (FRAME_NOW, LATTICE_TIMING),
          "timing['realtime (1 core held)'].p99_ms of each",
          lambda: [fixed(timing(FRAME_NOW, "realtime (1 core held)")["p99_ms"], 1),
                   fixed(timing(LATTICE_TIMING, "realtime (1 core held)")["p99_ms"], 1)]),
    Claim(REALTIME, FRAME_NOW_SECTION, "hold in both ({} and {} ms; {} and {} ms)", (LATTICE_TIMING, FRAME_NOW),
          "timing.realtime: p99_ms, mean_ms of each",
          lambda: [fixed(timing(LATTICE_TIMING, "realtime")["p99_ms"], 1),
                   fixed(timing(FRAME_NOW, "realtime")["p99_ms"], 1),
                   fixed(timing(LATTICE_TIMING, "realtime")["mean_ms"], 1),
                   fixed(timing(FRAME_NOW, "realtime")["mean_ms"], 1)]),
    Claim(REALTIME, FRAME_NOW_SECTION, "the previous defaults: p99 {} ms, mean {} ms, loaded p99 {} ms, {}x.",
          (FRAME,), "timing.realtime: p99_ms, mean_ms; timing['realtime (1 core held)'].p99_ms; wall over MapEx",
          lambda: [fixed(timing(FRAME, "realtime")["p99_ms"], 0), fixed(timing(FRAME, "realtime")["mean_ms"], 1),
                   fixed(timing(FRAME, "realtime (1 core held)")["p99_ms"], 0),
                   fixed(unpaced_over_mapex(FRAME, "realtime"), 1)]),
    Claim(REALTIME, FRAME_SECTION, "| realtime | {} | {} | {} | {} | {} | {} |", (FRAME,),
          "timing.realtime: p50, p90, p99, max, mean, first step",
          lambda: [*[fixed(timing(FRAME, "realtime")[k], 1) for k in ("p50_ms", "p90_ms", "p99_ms")],
                   fixed(timing(FRAME, "realtime")["max_ms"], 0), fixed(timing(FRAME, "realtime")["mean_ms"], 1),
                   fixed(timing(FRAME, "realtime")["first_step_ms"], 1)]),
    Claim(REALTIME, FRAME_SECTION,
          "p99 <= 100 ms and mean <= 25 ms: **met** ({} ms, {} ms); p99 <= 150 ms with one core held: **met** ({} ms); "
          "the 1000-step unpaced episode <= 3x MapEx: **met** ({}x)", (FRAME,),
          "timing.realtime: p99_ms, mean_ms; timing['realtime (1 core held)'].p99_ms; wall over MapEx",
          lambda: [fixed(timing(FRAME, "realtime")["p99_ms"], 1), fixed(timing(FRAME, "realtime")["mean_ms"], 1),
                   fixed(timing(FRAME, "realtime (1 core held)")["p99_ms"], 1),
                   fixed(unpaced_over_mapex(FRAME, "realtime"), 1)]),
    Claim(REALTIME, FRAME_SECTION, "| realtime | {} | {} [{}, {}] ({} %) | {} % | {} % | {} % | {} / {} / {} |",
          (FRAME,), "error.eval: summary.realtime.auc_first_half; paired.realtime: auc_first_half, iou@0.10 / "
                    "0.20 / 0.30, better / worse / tied",
          lambda: [fixed(100 * read(FRAME)["error"]["eval"]["summary"]["realtime"]["auc_first_half"], 1),
                   *paired(realtime_vs_full("auc_first_half")),
                   percent(realtime_vs_full("auc_first_half")["ratio"]),
                   *[percent(realtime_vs_full(f"iou@{c}")["ratio"]) for c in ("0.10", "0.20", "0.30")],
                   *[count(realtime_vs_full("auc_first_half")[k]) for k in ("better", "worse", "tied")]]),

    # --- docs/benchmarks/models.md ----------------------------------------------------------------------------
    Claim(MODELS_PAGE, "| Pix2Pix wall IoU at 0.5", "| Pix2Pix wall IoU at 0.5 ({} windows) | {} |",
          (MODELS_PREVIOUS,), "filter: samples, pix2pix_iou@0.5",
          lambda: [count(read(MODELS_PREVIOUS)["filter"]["samples"]),
                   fixed(read(MODELS_PREVIOUS)["filter"]["pix2pix_iou@0.5"], 3)]),
    Claim(MODELS_PAGE, "| Pix2Pix wall IoU at 0.5", "| **{}** ({} at {}) |", (MODELS,),
          "filter: pix2pix_iou@0.5, pix2pix_best (IoU, threshold)",
          lambda: [fixed(read(MODELS)["filter"]["pix2pix_iou@0.5"], 3),
                   fixed(read(MODELS)["filter"]["pix2pix_best"][1], 3),
                   fixed(read(MODELS)["filter"]["pix2pix_best"][0], 1)]),
    Claim(MODELS_PAGE, "| Laplacian baseline at 0.5", "| Laplacian baseline at 0.5 | {} | {} |",
          (MODELS_PREVIOUS, MODELS), "filter.laplacian_iou@0.5 of each file",
          lambda: [fixed(read(MODELS_PREVIOUS)["filter"]["laplacian_iou@0.5"], 3),
                   fixed(read(MODELS)["filter"]["laplacian_iou@0.5"], 3)]),
    *[Claim(MODELS_PAGE, row, "| {} / {} ({}x) | {} / {} (**{}x**) |" if bold else "| {} / {} ({}x) | {} / {} ({}x) |",
            (MODELS_PREVIOUS, MODELS),
            f"predictors.bins['{coverage_bin}']: lama_bp_unknown_iou, lama_los_unknown_iou of each file",
            lambda coverage_bin=coverage_bin: [
                *[value for path in (MODELS_PREVIOUS, MODELS) for value in (
                    fixed(unknown_iou(path, coverage_bin, "lama_bp"), 3),
                    fixed(unknown_iou(path, coverage_bin, "lama_los"), 3),
                    fixed(unknown_iou_ratio(path, coverage_bin), 2))]])
      for row, coverage_bin, bold in (("| LaMa-BP / LaMa-LOS IoU on unknown cells, 0-10 % coverage", "0%-10%", True),
                                      ("| same, 10-20 %", "10%-20%", False),
                                      ("| same, 20-30 %", "20%-30%", False))],
    Claim(MODELS_PAGE, "| Pix2Pix |", "| Pix2Pix | **{}** | {} ({}) |", (MODELS_PREVIOUS,),
          "filter: pix2pix_iou@0.5, pix2pix_best (threshold, IoU)",
          lambda: [fixed(read(MODELS_PREVIOUS)["filter"]["pix2pix_iou@0.5"], 3),
                   fixed(read(MODELS_PREVIOUS)["filter"]["pix2pix_best"][1], 3),
                   fixed(read(MODELS_PREVIOUS)["filter"]["pix2pix_best"][0], 2)]),
    Claim(MODELS_PAGE, "| Laplacian-filtered BP |", "| Laplacian-filtered BP | {} | {} ({}) |", (MODELS_PREVIOUS,),
          "filter: laplacian_iou@0.5, laplacian_best (threshold, IoU)",
          lambda: [fixed(read(MODELS_PREVIOUS)["filter"]["laplacian_iou@0.5"], 3),
                   fixed(read(MODELS_PREVIOUS)["filter"]["laplacian_best"][1], 3),
                   fixed(read(MODELS_PREVIOUS)["filter"]["laplacian_best"][0], 1)]),
    *[Claim(MODELS_PAGE, SHIPPED_MODELS_SECTION, f"| {label} | {{}} | {{}} | {{}} | {{}} | {{}} |", (MODELS,),
            f"predictors.distance.pooled[lama_bp, lama_los]['{name}']: wall_share, mean_p, ece",
            lambda name=name: distance_row(name))
      for label, name in (("0-2 m", "0-2 m"), ("2-5 m", "2-5 m"), ("5-10 m", "5-10 m"), ("> 10 m", ">10 m"))],

    # --- docs/benchmarks/better-map.md ------------------------------------------------------------------------
    Claim(BETTER_MAP, "| **superex**: SuperEx, LaMa-BP + SPAD (shipped defaults)",
          "| **{}** | {} | {} | {} | {} | {} |", (PAPER,),
          "summary.superex: auc_first_half, los_auc_first_half, coverage@1000, iou@0.10, iou_bin_0.0_0.1, "
          "scoring_ms_per_goal",
          lambda: [fixed(100 * read(PAPER)["summary"]["superex"]["auc_first_half"], 1),
                   fixed(100 * read(PAPER)["summary"]["superex"]["los_auc_first_half"], 1),
                   fixed(100 * read(PAPER)["summary"]["superex"]["coverage@1000"], 1),
                   fixed(read(PAPER)["summary"]["superex"]["iou@0.10"], 3),
                   fixed(read(PAPER)["summary"]["superex"]["iou_bin_0.0_0.1"], 3),
                   fixed(read(PAPER)["summary"]["superex"]["scoring_ms_per_goal"], 1)]),
    Claim(BETTER_MAP, "| superex - mapex_lama_los | the headline",
          "| the headline | {} [{}, {}] {} % {}/{} | {} [{}, {}] {} % |", (PAPER,),
          "paired_vs_reference.superex: auc_first_half and los_auc_first_half (mean [low, high] ratio better/worse)",
          lambda: [*paired(superex_vs_mapex_lama_los("auc_first_half")),
                   percent(superex_vs_mapex_lama_los("auc_first_half")["ratio"]),
                   count(superex_vs_mapex_lama_los("auc_first_half")["better"]),
                   count(superex_vs_mapex_lama_los("auc_first_half")["worse"]),
                   *paired(superex_vs_mapex_lama_los("los_auc_first_half")),
                   percent(superex_vs_mapex_lama_los("los_auc_first_half")["ratio"])]),
    Claim(BETTER_MAP, PAPER_SECTION, "**not met, {} % ({} [{}, {}])**", (PAPER,),
          "paired_vs_reference.superex.auc_first_half: ratio, mean [low, high]",
          lambda: [percent(superex_vs_mapex_lama_los("auc_first_half")["ratio"]),
                   *paired(superex_vs_mapex_lama_los("auc_first_half"))]),
    Claim(BETTER_MAP, "| carving_only: observed map + SPAD carving",
          "| {} | {} [{}, {}] {} % {}/{} | {} [{}, {}] {} % {}/{} |", (ABLATIONS,),
          "carving_only.auc_first_half: vs_full.mean, vs_full and vs_reference (difference, interval, ratio, "
          "better/worse)",
          lambda: [fixed(read(ABLATIONS)["carving_only"]["auc_first_half"]["vs_full"]["mean"], 2),
                   *[value for versus in ("vs_full", "vs_reference") for value in (
                       *_pairs_entry(read(ABLATIONS)["carving_only"]["auc_first_half"][versus]),
                       percent(read(ABLATIONS)["carving_only"]["auc_first_half"][versus]["ratio"]),
                       count(read(ABLATIONS)["carving_only"]["auc_first_half"][versus]["better"]),
                       count(read(ABLATIONS)["carving_only"]["auc_first_half"][versus]["worse"]))]]),
    Claim(BETTER_MAP, PAPER_SECTION,
          "first-half AUC **{} %** ({} points [{}, {}], {} better / {} worse), line of sight only {} %", (ALTERED,),
          "paired_vs_reference.superex: auc_first_half (ratio, mean [low, high], better, worse), "
          "los_auc_first_half.ratio",
          lambda: [percent(read(ALTERED)["paired_vs_reference"]["superex"]["auc_first_half"]["ratio"]),
                   *paired(read(ALTERED)["paired_vs_reference"]["superex"]["auc_first_half"]),
                   count(read(ALTERED)["paired_vs_reference"]["superex"]["auc_first_half"]["better"]),
                   count(read(ALTERED)["paired_vs_reference"]["superex"]["auc_first_half"]["worse"]),
                   percent(read(ALTERED)["paired_vs_reference"]["superex"]["los_auc_first_half"]["ratio"])]),

    *[Claim(BETTER_MAP, CARVE_SECTION,
            f"| {label} | {{}} | {{}} | {{}} | {{}} [{{}}, {{}}] | {{}} % | {{}} / {{}} / {{}} |",
            (CARVE_CEILINGS[variant],), "scenarios_finished; auc_first_half: today, ceiling, difference [interval], "
                                        "relative, better / worse / tied",
            lambda variant=variant: carve_ceiling_row(variant))
      for label, variant in (("from the goal cell, weight 1", "goal"), ("along the path, weight 1", "path"),
                             ("from the goal cell, weight 3", "weight3"),
                             ("along the path, weight 3", "path_weight3"),
                             ("along the path, weight 3, 2 starts per floor, steps 1-350 of 700", "confirm"))],
    Claim(BETTER_MAP, CARVE_SECTION,
          "the confirmation: **{} %** ({} points [{}, {}], {} / {} / {} of {} scenarios)", (CARVE_CEILINGS["confirm"],),
          "auc_first_half: relative, difference [interval], better / worse / tied; scenarios_finished",
          lambda: [percent(carve_ceiling("confirm")["relative"]), points(carve_ceiling("confirm")["difference"]),
                   *interval(carve_ceiling("confirm")["interval"], 100.0),
                   *[count(carve_ceiling("confirm")[k]) for k in ("better", "worse", "tied")],
                   count(read(CARVE_CEILINGS["confirm"])["scenarios_finished"])]),

    # --- docs/benchmarks/spad.md ------------------------------------------------------------------------------
    Claim(SPAD_PAGE, "## Single scans and episodes", "| {} | {} | {} | {}x | {}x | {} % |", (SPAD,),
          "episodes: median_los_ms, median_spad_ms, median_nlos_ms, their ratios, fans_traced / all fans",
          lambda: [*[fixed(read(SPAD)["episodes"][f"median_{stage}_ms"], 2) for stage in ("los", "spad", "nlos")],
                   fixed(spad_episodes("spad", "los"), 1),
                   fixed(spad_episodes("nlos", "spad"), 2),
                   fixed(100 * read(SPAD)["episodes"]["fans_traced"]
                         / (read(SPAD)["episodes"]["fans_traced"] + read(SPAD)["episodes"]["fans_reused"]), 1)]),
    Claim(SPAD_PAGE, "## Single scans and episodes",
          "cold SPAD / LOS {}x (one thread {}x), cached SPAD / LOS {}x, NLOS / cold SPAD {}x, NLOS / cached SPAD {}x",
          (SPAD,), "single_scans.median_ratios",
          lambda: [fixed(read(SPAD)["single_scans"]["median_ratios"][k], d) for k, d in (
              ("cold_spad_over_los", 2), ("cold_one_thread_spad_over_los", 1), ("cached_spad_over_los", 2),
              ("nlos_over_cold_spad", 2), ("nlos_over_cached_spad", 1))]),

    # --- docs/benchmarks/resolution.md ------------------------------------------------------------------------
    Claim(RESOLUTION_PAGE, "| first-half AUC (%)", "| first-half AUC (%) | {} | {} | {} | {} % | {} [{}, {}] |",
          (RESOLUTION,), "'first-half AUC (%)': scenarios, mean_0.1m, mean_0.05m, their ratio, difference, interval",
          lambda: [count(resolution("first-half AUC (%)")["scenarios"]),
                   fixed(resolution("first-half AUC (%)")["mean_0.1m"], 3),
                   fixed(resolution("first-half AUC (%)")["mean_0.05m"], 3),
                   percent(fine_to_coarse("first-half AUC (%)")),
                   signed(resolution("first-half AUC (%)")["difference"], 3),
                   *interval(resolution("first-half AUC (%)")["interval"], decimals=3)]),
    Claim(RESOLUTION_PAGE, "## Step time at 0.05 m", "Met on both floors: p99 {} / {} ms, mean {} / {} ms at 0.05 m",
          (FINE,), "timing['realtime@50015847@x2'], timing['realtime@generated@0.05']: p99_ms, mean_ms",
          lambda: [fixed(timing(FINE, "realtime@50015847@x2")["p99_ms"], 1),
                   fixed(timing(FINE, "realtime@generated@0.05")["p99_ms"], 1),
                   fixed(timing(FINE, "realtime@50015847@x2")["mean_ms"], 1),
                   fixed(timing(FINE, "realtime@generated@0.05")["mean_ms"], 1)]),

    Claim(BETTER_MAP, "", "Re-run with what ships (`benchmarks/eval_altered/shipped44/`, the lattice filter on, the "
          "carving's step rule): **{} %** ({} points [{}, {}], {} better / {} worse)", (ALTERED_NOW,),
          "paired_vs_reference.superex.auc_first_half: ratio, mean [low, high], better, worse",
          lambda: [percent(read(ALTERED_NOW)["paired_vs_reference"]["superex"]["auc_first_half"]["ratio"]),
                   *paired(read(ALTERED_NOW)["paired_vs_reference"]["superex"]["auc_first_half"]),
                   count(read(ALTERED_NOW)["paired_vs_reference"]["superex"]["auc_first_half"]["better"]),
                   count(read(ALTERED_NOW)["paired_vs_reference"]["superex"]["auc_first_half"]["worse"])]),

    # --- docs/on-a-robot.md -----------------------------------------------------------------------------------
    Claim(ROBOT_PAGE, "", "the explorer's wall IoU is {} of noise-free", (ROBUSTNESS,),
          f"settings['{ROBOT_POINT}'].map_iou_vs_noise_free", lambda: [fixed(robot("map_iou_vs_noise_free"), 3)]),
    Claim(ROBOT_PAGE, "",
          "Of the {} per 1,000, {} have no wall of the map within a cell; the IoU that forgives a wall one cell off is "
          "{} of noise-free", (ROBUSTNESS,),
          f"settings['{ROBOT_POINT}']: held_free_per_1000_seen, missing_per_1000_seen, "
          "map_iou_within_cell_vs_noise_free",
          lambda: [fixed(robot("held_free_per_1000_seen"), 0), fixed(robot("missing_per_1000_seen"), 0),
                   fixed(robot("map_iou_within_cell_vs_noise_free"), 2)]),
]

# Tables a page copies from a benchmark's own markdown: (page, the line that opens the copy, the line that closes
# it, the benchmark's markdown). Every table row of the copy must be a row of the file.
COPIED_TABLES = [
    (ROBOT_PAGE, "<!-- table -->", "<!-- /table -->", "benchmarks/robustness/robustness.md"),
    ("docs/benchmarks/onboard.md", "## A map that grows", "## ", "benchmarks/growth/growth.md"),
]


def _failure(claim: Claim, found: list[str], expected: list[str]) -> str:
    return (f"{claim.page} ({claim.where or 'the page'}) prints {found} where {', '.join(claim.files)} "
            f"({claim.key}) gives {expected}, for the phrase:\n    {claim.template}\nUpdate the page (or, if the "
            "file is what is wrong, regenerate it with the command in its folder's README.md).")


@pytest.mark.parametrize("claim", CLAIMS, ids=[claim.id for claim in CLAIMS])
def test_page_number_matches_its_benchmark_file(claim):
    found = read_numbers(_scope(_page(claim.page), claim.where), claim.template)
    expected = claim.values()
    assert len(expected) == len(found) == claim.template.count("{}"), "a claim reads one value per {}"
    assert found == expected, _failure(claim, found, expected)


@pytest.mark.parametrize("page, opening, closing, source", COPIED_TABLES, ids=[t[0] for t in COPIED_TABLES])
def test_copied_tables_match_their_benchmark_markdown(page, opening, closing, source):
    lines = _page(page).splitlines()
    start = lines.index(opening)
    end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith(closing)), len(lines))
    rows = [line for line in lines[start + 1:end] if line.startswith("|")]
    assert rows, f"no table between {opening!r} and {closing!r} in {page}"
    file_rows = {line for line in _page(source).splitlines() if line.startswith("|")}
    stale = [row for row in rows if row not in file_rows]
    assert not stale, f"{page} has table rows that {source} does not:\n" + "\n".join(stale)


def _perturbed(value, counter: itertools.count):
    """Every number of a parsed JSON file moved by a different amount (so a ratio of two of them moves too)."""
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return value
    if isinstance(value, (int, float)):
        factor = 1.0 + 0.07 * (next(counter) % 5 + 1)
        return value * factor + (1 if isinstance(value, int) else 0.0123)
    if isinstance(value, list):
        return [_perturbed(item, counter) for item in value]
    return {key: _perturbed(item, counter) for key, item in value.items()}


def test_every_claim_fails_when_its_file_moves(monkeypatch):
    """Each claim reads its numbers from its file: with every number of the committed files moved, no claim still
    gives the page's numbers (so none can pass by accident, e.g. by reading a constant)."""
    moved = {}

    def read_moved(path: str):
        if path not in moved:
            moved[path] = _perturbed(_json(path), itertools.count())
        return moved[path]

    monkeypatch.setitem(globals(), "read", read_moved)
    still = []
    for claim in CLAIMS:
        found = read_numbers(_scope(_page(claim.page), claim.where), claim.template)
        if claim.values() == found:
            still.append(claim.id)
    assert not still, "claims whose numbers do not depend on their file:\n" + "\n".join(still)


def test_a_claim_fails_when_its_page_changes():
    """The comparison is of the printed numbers: a page that says another number fails."""
    claim = CLAIMS[0]
    text = _scope(_page(claim.page), claim.where)
    first = read_numbers(text, claim.template)[0]
    changed = text.replace(first, first + "1", 1)
    assert read_numbers(changed, claim.template) != claim.values()


def _readme_test_count() -> str:
    counts = re.findall(r"\b(\d[\d,]*) tests\b", _page(README))
    assert len(counts) == 1, f"the README states the suite's test count once, found {counts}"
    return counts[0]


def test_only_the_readme_states_the_test_count():
    """The suite's size is stated in one place (the README, which the maintainers update): a page that states a
    count of its own drifts as soon as a test is added."""
    _readme_test_count()
    stated = []
    for path in sorted((ROOT / "docs").rglob("*.md")):
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
            if re.search(r"\b\d[\d,]* (?:of the \d[\d,]* )?tests\b", line):
                stated.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()}")
    assert not stated, "pages that state a test count (point at the README instead):\n" + "\n".join(stated)


# A script path in running text: `scripts/NAME.py` or `.sh`, not part of a longer path (`MapEx/scripts/...`) and not
# a file of an earlier revision (`REV:scripts/...`, as `git show` takes it).
_SCRIPT = re.compile(r"(?<![\w/.:-])scripts/([\w.-]+\.(?:py|sh))\b")
# A script of an earlier revision, named with the commit that has it (a study's script that left with its options).
_OLD_SCRIPT = re.compile(r"\b[0-9a-f]{7,40}:scripts/[\w.-]+\.(?:py|sh)\b")


def test_named_scripts_exist():
    """Every script the README, the docs and the benchmark folders' READMEs tell a reader to run is in scripts/."""
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md")),
             *sorted((ROOT / "benchmarks").rglob("README.md"))]
    missing = []
    for path in pages:
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
            for name in _SCRIPT.findall(line):
                if not (ROOT / "scripts" / name).is_file():
                    missing.append(f"{path.relative_to(ROOT)}:{number}: scripts/{name}")
    assert not missing, "pages name scripts that are not in scripts/:\n" + "\n".join(missing)


def test_every_benchmark_folder_says_how_to_regenerate_it():
    """Each folder under benchmarks/ has a README.md that names the command that regenerates it (a script of
    scripts/, `superex benchmark`, or a script that left, named with the commit that has it: `REV:scripts/NAME.py`),
    and the benchmarks index lists it."""
    listed = re.findall(r"`([\w*.-]+/)`", _scope(_page(INDEX), "## The files under `benchmarks/`"))
    problems = []
    for folder in sorted(p for p in (ROOT / "benchmarks").iterdir() if p.is_dir()):
        if not any(fnmatch.fnmatch(f"{folder.name}/", entry) for entry in listed):
            problems.append(f"benchmarks/{folder.name}/ is not listed in {INDEX}")
        readme = folder / "README.md"
        if not readme.is_file():
            problems.append(f"benchmarks/{folder.name}/ has no README.md")
            continue
        text = readme.read_text(encoding="utf-8")
        if not (_SCRIPT.search(text) or "superex benchmark" in text or _OLD_SCRIPT.search(text)):
            problems.append(f"benchmarks/{folder.name}/README.md names no script nor `superex benchmark` command")
    assert not problems, "\n".join(problems)


def test_no_loose_files_under_benchmarks():
    """benchmarks/ holds one folder per benchmark and nothing else: a file directly under it has no README to say
    what regenerates it (put it in its benchmark's folder, or a superseded run under benchmarks/history/)."""
    loose = [path.name for path in sorted((ROOT / "benchmarks").iterdir()) if not path.is_dir()]
    assert not loose, f"files directly under benchmarks/ (move each into its benchmark's folder): {loose}"
