"""Exploration metrics: coverage and map IoU, and the benchmark's results table."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from superex_deploy.maps import OccupancyGrid

__all__ = ["map_iou", "evaluation_area", "summarise"]


def evaluation_area(grid: OccupancyGrid) -> np.ndarray:
    """bool ``[H, W]``: the valid area grown by two cells, so the walls bounding it are scored too."""
    return ndimage.binary_dilation(grid.valid, iterations=2)


def map_iou(mean: np.ndarray, grid: OccupancyGrid, threshold: float = 0.5) -> float:
    """Occupied-class IoU of a predicted map (``mean >= threshold`` is a wall) against the ground-truth walls,
    within :func:`evaluation_area`."""
    mean = np.asarray(mean)
    if mean.shape != grid.shape:
        raise ValueError(f"prediction has shape {mean.shape}, the map has {grid.shape}")
    area = evaluation_area(grid)
    predicted = (mean >= threshold) & area
    truth = grid.occupied & area
    union = np.count_nonzero(predicted | truth)
    return np.count_nonzero(predicted & truth) / union if union else 1.0


def _mean_std(values: list) -> tuple[float, float]:
    return (float(np.mean(values)), float(np.std(values))) if values else (float("nan"), float("nan"))


def summarise(results: list[dict], checkpoints=(250, 500, 1000)) -> list[dict]:
    """Per-planner mean and standard deviation of coverage at step checkpoints (an episode that finished early
    keeps its final coverage), final path length and final IoU, from :meth:`EpisodeResult.to_json` dicts."""
    by_planner: dict[str, list[dict]] = {}
    for result in results:
        by_planner.setdefault(result["planner"], []).append(result)
    rows = []
    for planner, runs in sorted(by_planner.items()):
        row = {"planner": planner, "episodes": len(runs)}
        for step in checkpoints:
            values = [r["coverage"][min(step, len(r["coverage"])) - 1] for r in runs if r["coverage"]]
            row[f"coverage@{step}"] = _mean_std(values)
        lengths = [r["path_length_m"][-1] for r in runs if r["path_length_m"]]
        row["path_length_m"] = _mean_std(lengths)
        ious = [r["iou"]["iou"][-1] for r in runs if r["iou"]["iou"]]
        row["final_iou"] = _mean_std(ious)
        rows.append(row)
    return rows
