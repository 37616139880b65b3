"""scikit-image against the package's own code, for each job scikit-image is made for: resampling grids between
resolutions (``skimage.measure.block_reduce``, ``skimage.transform.rescale``), connected frontier regions
(``skimage.measure.label``), the classic Laplacian filter (``skimage.filters``), minimum-cost paths
(``skimage.graph.MCP_Geometric``), and the robot's disc footprint (``skimage.morphology.disk``, compared, not
timed).

Each pair runs on the largest eval floor (by cell count) at 0.1 m and at 0.05 m (the same floor upsampled x2, as
``superex benchmark --maps MAP@x2`` does), on a map known within ``--known-m`` of its first start (walls OCCUPIED,
the building's free cells FREE, the rest UNKNOWN), with the package's inputs of that step: pooling by 2 blocks
(a 0.1 m model on a 0.05 m grid), the Laplacian on a back-projection patch of the NLOS window around the robot, the
Dijkstra on the planning map's costs. The package's code ("today"; for a function that now calls scikit-image,
the code before it, kept in ``tests/naive.py``) and scikit-image's are called alternately (the order flips every
repeat), ``--repeats`` times; the table gives the median ms of each, their ratio (scikit-image / today: above 1,
scikit-image is slower) and whether the two outputs are equal to the bit on that input.

    PYTHONPATH=$PWD python scripts/bench_skimage.py                      # ~1 min on a loaded 2-core machine
    PYTHONPATH=$PWD python scripts/bench_skimage.py --repeats 3 --out /tmp/sk   # smoke test

Writes ``OUT/skimage.json`` and ``OUT/skimage.md`` (default ``benchmarks/skimage``).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np

from superex_deploy.evaluation import write_json, write_text
from superex_deploy.maps import list_maps, load_map, start_poses
from superex_deploy.onboard.mapping.blocks import coarsen_observed
from superex_deploy.onboard.nlos import NlosConfig
from superex_deploy.onboard.nlos.shared import GridPatch
from superex_deploy.onboard.nlos.filters import laplacian_filter_patch, widened_box
from superex_deploy.onboard.planning import motion
from superex_deploy.onboard.planning.coarse import pool_prediction_blocks
from superex_deploy.onboard.planning.frontiers import find_frontiers, frontier_cells, frontiers_of_regions
from superex_deploy.onboard.prediction import scale
from superex_deploy.onboard.types import FREE, OCCUPIED, UNKNOWN, Frontier, Prediction
from superex_deploy.sim.generated_floors import upsampled

ROOT = Path(__file__).resolve().parents[1]
K = 2
"""The block side of the pooling pairs: a 0.1 m model on a 0.05 m grid."""


def _load_naive():
    """``tests/naive.py`` (the code before each swap), loaded from its file: the tests are no package of the
    install."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("superex_tests_naive", ROOT / "tests" / "naive.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _largest_eval_floor() -> str:
    return max(list_maps("eval"), key=lambda name: load_map(name).occupied.size)


def _observed(grid, start_rc, known_m: float) -> np.ndarray:
    """int8 ``[H, W]``: the floor known within ``known_m`` of ``start_rc``."""
    rows, cols = np.mgrid[:grid.occupied.shape[0], :grid.occupied.shape[1]]
    seen = np.hypot(rows - start_rc[0], cols - start_rc[1]) * grid.resolution_m <= known_m
    observed = np.full(grid.occupied.shape, UNKNOWN, np.int8)
    observed[seen & grid.valid] = FREE
    observed[seen & grid.occupied] = OCCUPIED
    return observed


def _planning_costs(observed, pose_rc, resolution_m, cfg=motion.MotionConfig()):
    """The per-cell move costs :func:`~superex_deploy.onboard.planning.motion.planning_map` searches (whole map)."""
    walls, free = observed == OCCUPIED, observed == FREE
    free[pose_rc] = True
    distance = motion.wall_distance(walls, motion.check_wall_reach(cfg, resolution_m))
    traversable = free & (distance > cfg.robot_radius_m / resolution_m)
    traversable[pose_rc] = True
    proximity = np.maximum(1.0 - distance / (cfg.wall_cost_range_m / resolution_m), 0.0)
    return np.where(traversable, 1.0 + cfg.wall_cost_weight * proximity, np.inf)


def _back_projection(shape, pose_rc, resolution_m, rng) -> GridPatch:
    """A back-projection patch the size of the NLOS window around the robot: sparse votes in [0, 1]."""
    half = int(np.ceil(NlosConfig().window_m / resolution_m))
    r0, c0 = max(pose_rc[0] - half, 0), max(pose_rc[1] - half, 0)
    r1, c1 = min(pose_rc[0] + half + 1, shape[0]), min(pose_rc[1] + half + 1, shape[1])
    values = (rng.random((r1 - r0, c1 - c0)) * (rng.random((r1 - r0, c1 - c0)) < 0.2)).astype(np.float32)
    return GridPatch(values, r0, c0, shape)


# --- scikit-image's side of each pair ---------------------------------------------------------------------------


def sk_pool_observed(observed, k):
    from skimage.measure import block_reduce

    return block_reduce(observed, (k, k), np.max, cval=UNKNOWN)


def sk_pool_mean(values, k):
    """Each block's sum (float64, padded with zeros) over the number of cells it has."""
    from skimage.measure import block_reduce

    sums = block_reduce(values.astype(np.float64), (k, k), np.sum, cval=0.0)
    counts = block_reduce(np.ones(values.shape), (k, k), np.sum, cval=0.0)
    return (sums / counts).astype(np.float32)


def sk_pool_mixture(prediction, k):
    from skimage.measure import block_reduce

    mean, variance = prediction.mean.astype(np.float64), prediction.variance.astype(np.float64)
    counts = block_reduce(np.ones(mean.shape), (k, k), np.sum, cval=0.0)
    average = block_reduce(mean, (k, k), np.sum, cval=0.0) / counts
    second = block_reduce(variance + mean * mean, (k, k), np.sum, cval=0.0) / counts
    return Prediction(mean=average.astype(np.float32),
                      variance=np.maximum(second - average * average, 0.0).astype(np.float32))


def sk_upsample_linear(values, k, shape):
    """Bilinear between the coarse cells' centres, the edge value held beyond them, cropped to ``shape``."""
    from skimage.transform import rescale

    fine = rescale(values.astype(np.float64), k, order=1, mode="edge", anti_aliasing=False, preserve_range=True)
    return fine[:shape[0], :shape[1]].astype(np.float32)


def sk_find_frontiers(observed, min_cells: int = 10) -> tuple[Frontier, ...]:
    """:func:`~superex_deploy.onboard.planning.frontiers.find_frontiers` with ``measure.label`` in place of its
    compiled labelling (whose labels are numbered in the row-major order of their first cell too), and the same
    choice of each region's goal cell."""
    from skimage.measure import label

    labels = label(frontier_cells(observed), connectivity=2)
    rows, cols = np.nonzero(labels)  # row-major
    return frontiers_of_regions(rows, cols, labels[rows, cols].astype(np.int64) - 1, int(labels.max()), min_cells)


def sk_laplacian_patch(bp: GridPatch, sigma_cells: float) -> GridPatch:
    """:func:`~superex_deploy.onboard.nlos.filters.laplacian_filter_patch` with ``filters.gaussian`` and
    ``filters.laplace`` (its kernel is the negative 5-point Laplacian) on the same widened box."""
    from skimage import filters

    box, r0, c0 = widened_box(bp, sigma_cells)
    if sigma_cells > 1e-15:
        box = filters.gaussian(box, sigma=sigma_cells, mode="reflect", truncate=4.0, preserve_range=True)
    box = np.clip(filters.laplace(box), 0.0, None)
    top = box.max()
    return GridPatch((box / top if top > 0 else box).astype(np.float32), r0, c0, bp.grid_shape)


def sk_travel_cost(costs, source_rc):
    from skimage.graph import MCP_Geometric

    cost_to_go, _ = MCP_Geometric(costs, fully_connected=True).find_costs([source_rc])
    return cost_to_go


def disc_offsets(radius_cells: float) -> list[tuple[int, int]]:
    """The offsets :func:`~superex_deploy.onboard.planning.motion.path_is_clear` checks: ``dr² + dc² <= r²``."""
    reach = int(np.floor(radius_cells))
    return [(dr, dc) for dr in range(-reach, reach + 1) for dc in range(-reach, reach + 1)
            if dr * dr + dc * dc <= radius_cells * radius_cells]


def disk_match(radius_cells: float) -> str:
    """The ``skimage.morphology.disk`` (integer radius ``n``, ``x² + y² <= n²``, or with ``strict_radius=False``
    ``<= (n + 0.5)²``) whose offsets are :func:`disc_offsets`' (``"disk(1, strict_radius=False)"``), or ``""``."""
    from skimage.morphology import disk

    wanted = disc_offsets(radius_cells)
    for n in range(int(np.ceil(radius_cells)) + 1):
        for strict in (True, False):
            footprint = disk(n, strict_radius=strict)
            offsets = [tuple(int(v) for v in o) for o in np.argwhere(footprint) - footprint.shape[0] // 2]
            if offsets == wanted:
                return f"disk({n})" if strict else f"disk({n}, strict_radius=False)"
    return ""


def draw_disk_differences(n_discs: int, seed: int) -> int:
    """Of ``n_discs`` random footprints (origin anywhere in a cell or at its centre, radius up to 6 cells, a third
    of them whole or half cells), how many :meth:`~superex_deploy.onboard.mapping.mapper.Mapper.clear_footprint`'s
    disc (cell centres within the radius, ``<=``, and the cell holding the origin) and ``skimage.draw.disk``
    (``<``, cell ``(r, c)``'s centre at ``(r, c)``) draw differently."""
    from skimage.draw import disk

    from superex_deploy.onboard.mapping.mapper import Mapper

    rng = np.random.default_rng(seed)
    shape = (40, 40)
    differ = 0
    for _ in range(n_discs):
        y0, x0 = rng.uniform(10.0, 30.0, size=2)
        if rng.random() < 0.3:
            y0, x0 = np.floor(y0) + 0.5, np.floor(x0) + 0.5
        radius = rng.uniform(0.0, 6.0)
        if rng.random() < 1 / 3:
            radius = np.round(radius * 2.0) / 2.0
        mapper = Mapper(shape)  # all unknown (log-odds 0): with everything=True exactly the disc is cleared
        mapper.clear_footprint((y0, x0), radius, everything=True)
        today = mapper.log_odds != 0.0
        drawn = np.zeros(shape, bool)
        if radius > 0:
            drawn[disk((y0 - 0.5, x0 - 0.5), radius, shape=shape)] = True
        drawn[int(y0), int(x0)] = True
        differ += not np.array_equal(today, drawn)
    return differ


# --- the run ------------------------------------------------------------------------------------------------------


def _equal(a, b) -> bool:
    if isinstance(a, Prediction):
        return np.array_equal(a.mean, b.mean) and np.array_equal(a.variance, b.variance)
    if isinstance(a, GridPatch):
        return a.slices == b.slices and np.array_equal(a.values, b.values)
    if isinstance(a, Frontier):
        return a.cell_rc == b.cell_rc and np.array_equal(a.cells, b.cells) and a.cells.dtype == b.cells.dtype
    if isinstance(a, tuple):
        return len(a) == len(b) and all(_equal(x, y) for x, y in zip(a, b))
    return np.array_equal(a, b)


def _pairs(grid, resolution_m, start_rc, known_m, naive, rng, k=K) -> list[tuple[str, str, str, Callable,
                                                                          Callable]]:
    """``(job, today's name, scikit-image's name, today, scikit-image)`` on this grid's inputs."""
    observed = _observed(grid, start_rc, known_m)
    shape = observed.shape
    values = rng.random(shape).astype(np.float32)
    prediction = Prediction(mean=rng.random(shape).astype(np.float32),
                            variance=(0.25 * rng.random(shape)).astype(np.float32))
    coarse = scale.pool_mean(values, k)
    half_shape = (shape[0] // k, shape[1] // k)  # pool_prediction takes whole blocks only
    whole = Prediction(mean=prediction.mean[:half_shape[0] * k, :half_shape[1] * k],
                       variance=prediction.variance[:half_shape[0] * k, :half_shape[1] * k])
    costs = _planning_costs(observed, start_rc, resolution_m)
    bp = _back_projection(shape, start_rc, resolution_m, rng)
    sigma = NlosConfig().in_cells(resolution_m).laplacian_sigma
    return [
        ("pool an observed map (swapped)", "numpy reshape (tests/naive.py)", "measure.block_reduce max",
         lambda: naive.naive_pool_observed(observed, k), lambda: scale.pool_observed(observed, k)),
        ("coarsen an observed map", "mapping.blocks.coarsen_observed (numba)", "measure.block_reduce max",
         lambda: coarsen_observed(observed, k), lambda: sk_pool_observed(observed, k)),
        ("pool evidence (block mean)", "prediction.scale.pool_mean (numba)", "measure.block_reduce sum / count",
         lambda: scale.pool_mean(values, k), lambda: sk_pool_mean(values, k)),
        ("pool a prediction onto planning blocks", "planning.coarse.pool_prediction_blocks (numba)",
         "measure.block_reduce sums", lambda: pool_prediction_blocks(prediction, k),
         lambda: sk_pool_mixture(prediction, k)),
        ("pool a prediction back to a coarser grid (swapped)", "numpy reshape (tests/naive.py)",
         "measure.block_reduce mean, var",
         lambda: Prediction(*naive.naive_pool_prediction(whole.mean, whole.variance, k)),
         lambda: scale.pool_prediction(whole, k, half_shape)),
        ("interpolate a model's answer onto the grid", "prediction.scale.upsample_linear (numpy)",
         "transform.rescale order 1", lambda: scale.upsample_linear(coarse, k, shape),
         lambda: sk_upsample_linear(coarse, k, shape)),
        ("find frontier regions", "planning.frontiers.find_frontiers (numba labels)", "measure.label connectivity 2",
         lambda: find_frontiers(observed), lambda: sk_find_frontiers(observed)),
        ("Laplacian filter of a back-projection", "nlos.filters.laplacian_filter_patch (numba)",
         "filters.gaussian + filters.laplace", lambda: laplacian_filter_patch(bp, sigma),
         lambda: sk_laplacian_patch(bp, sigma)),
        ("cost-to-go from the robot", "planning.motion.dijkstra (numba)", "graph.MCP_Geometric",
         lambda: motion.dijkstra(costs, start_rc)[0], lambda: sk_travel_cost(costs, start_rc)),
    ]


def run(repeats: int, known_m: float, seed: int) -> dict:
    naive = _load_naive()
    name = _largest_eval_floor()
    floor = load_map(name)
    start = start_poses(name)[0]
    rows = []
    for factor in (1, 2):
        grid = floor if factor == 1 else upsampled(floor, factor)
        start_rc = (start[0] * factor, start[1] * factor)
        pairs = _pairs(grid, grid.resolution_m, start_rc, known_m, naive, np.random.default_rng(seed))
        times = {job: ([], []) for job, *_ in pairs}
        equal = {job: _equal(today(), library()) for job, _, _, today, library in pairs}  # also warms numba
        for repeat in range(repeats):
            for job, _, _, today, library in pairs:
                for side in ((0, 1) if repeat % 2 == 0 else (1, 0)):
                    call = (today, library)[side]
                    begin = time.perf_counter()
                    call()
                    times[job][side].append(1e3 * (time.perf_counter() - begin))
        for job, today_name, library_name, _, _ in pairs:
            today_ms, library_ms = (float(np.median(t)) for t in times[job])
            row = {"job": job, "resolution_m": grid.resolution_m, "shape": list(grid.occupied.shape),
                   "today": today_name, "skimage": library_name, "today_ms": round(today_ms, 3),
                   "skimage_ms": round(library_ms, 3), "ratio": round(library_ms / today_ms, 2),
                   "equal": bool(equal[job])}
            rows.append(row)
            print(f"{grid.resolution_m:g} m  {job:44s} today {today_ms:8.2f} ms  skimage {library_ms:8.2f} ms  "
                  f"x{library_ms / today_ms:5.2f}  equal {equal[job]}", flush=True)
    # The block pairs with the other block sides a model serves (3 and 4 cells: a 0.0333 / 0.025 m grid under a
    # 0.1 m model), on the 0.1 m floor's inputs, equality only.
    other_factors = []
    for k in range(2, scale.MAX_POOL + 1):
        if k == K:
            continue
        for job, _, _, today, library in _pairs(floor, floor.resolution_m, start, known_m, naive,
                                                 np.random.default_rng(seed), k)[:6]:
            other_factors.append({"job": job, "factor": k, "equal": bool(_equal(today(), library()))})
            print(f"x{k}: {job:44s} equal {other_factors[-1]['equal']}", flush=True)
    footprint = []
    for resolution_m in (0.2, 0.1, 0.05, 0.025):
        radius_cells = motion.MotionConfig().robot_radius_m / resolution_m
        footprint.append({"resolution_m": resolution_m, "radius_cells": radius_cells,
                          "disk": disk_match(radius_cells)})
    footprint_draw = {"discs": 3000, "differ": draw_disk_differences(3000, seed)}
    import skimage

    return {"floor": name, "start_rc": list(start), "known_m": known_m, "pool_factor": K, "repeats": repeats,
            "seed": seed, "skimage_version": skimage.__version__, "rows": rows,
            "other_factors": other_factors, "footprint": footprint,
            "footprint_draw": footprint_draw,
            "machine": f"{platform.node()} {platform.processor() or platform.machine()}, {os.cpu_count()} cores"}


def markdown(result: dict) -> str:
    lines = [f"# scikit-image against the package's own code",
             "",
             f"`scripts/bench_skimage.py --repeats {result['repeats']}`: the largest eval floor, {result['floor']}, "
             f"known within {result['known_m']:g} m of start {tuple(result['start_rc'])}, at 0.1 m and upsampled x2 "
             f"to 0.05 m; pooling by {result['pool_factor']} x {result['pool_factor']} blocks; scikit-image "
             f"{result['skimage_version']}; medians of {result['repeats']} alternated calls on "
             f"{result['machine']} (other jobs on the cores: read the ratios, not the milliseconds). Ratio: "
             f"scikit-image / today (above 1: scikit-image is slower). Equal: the two outputs equal to the bit.",
             "",
             "| job | grid | today | ms | scikit-image | ms | ratio | equal |",
             "|---|---|---|---:|---|---:|---:|---|"]
    for row in result["rows"]:
        lines.append(f"| {row['job']} | {row['resolution_m']:g} m ({row['shape'][0]} x {row['shape'][1]}) | "
                     f"{row['today']} | {row['today_ms']:.2f} | {row['skimage']} | {row['skimage_ms']:.2f} | "
                     f"{row['ratio']:.2f} | {'yes' if row['equal'] else 'no'} |")
    lines += ["", "The pooling and interpolation pairs with the other block sides a model serves (3 and 4 cells: a "
              "0.0333 / 0.025 m grid under a 0.1 m model), on the 0.1 m floor's inputs, equality only:", "",
              "| job | block side | equal |", "|---|---:|---|"]
    for row in result["other_factors"]:
        lines.append(f"| {row['job']} | {row['factor']} | {'yes' if row['equal'] else 'no'} |")
    lines += ["",
              "The robot's disc (`planning.motion.path_is_clear`: the offsets with dr² + dc² <= r², r the robot "
              "radius in planning cells, as the float it is) against `skimage.morphology.disk` (integer radii n: "
              "x² + y² <= n², or (n + 0.5)² with `strict_radius=False`), for the default 0.15 m robot radius:",
              "",
              "| planning cell | r (cells) | the disk with the same offsets |",
              "|---|---:|---|"]
    for row in result["footprint"]:
        lines.append(f"| {row['resolution_m']:g} m | {row['radius_cells']!r} | {row['disk'] or 'none'} |")
    draw = result["footprint_draw"]
    lines += ["", f"The map's footprint clearing (`mapping.mapper.Mapper.clear_footprint`: the cells whose centre lies "
              f"within the radius of the robot's position, which may lie anywhere in a cell, and the cell holding it) "
              f"against `skimage.draw.disk` (strictly inside the radius): {draw['differ']} of {draw['discs']} random "
              f"discs differ."]
    return "\n".join(lines) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=21, help="alternated calls per pair and grid")
    parser.add_argument("--known-m", type=float, default=60.0, help="the map is known within this of the start (m)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "skimage")
    args = parser.parse_args()
    if args.repeats < 1:
        parser.error("--repeats must be >= 1")
    result = run(args.repeats, args.known_m, args.seed)
    write_json(args.out / "skimage.json", result, newline=True)
    write_text(args.out / "skimage.md", markdown(result))
    print(f"wrote {args.out / 'skimage.json'} and {args.out / 'skimage.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
