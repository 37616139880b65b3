"""Figures (matplotlib, Agg backend): a SPAD scan and its NLOS processing."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_scan_figure(path: Path, grid, pose_rc, seen_free: np.ndarray, seen_wall: np.ndarray, scan, result,
                     truth: np.ndarray, zoom_m: float = 12.0) -> Path:
    """Ground truth, line-of-sight observation, carved free space, raw and Laplacian-filtered back-projection
    (with the NLOS ground truth in red), and a few histograms; map panels show ``zoom_m`` around the robot.
    Returns the written path."""
    plt = _pyplot()
    fig, axes = plt.subplots(2, 3, figsize=(16, 10))
    walls = grid.occupied
    axes[0, 0].imshow(~walls, cmap="gray")
    axes[0, 0].set_title(f"ground truth: {grid.name}")
    observation = np.full(walls.shape, 0.5)
    observation[seen_free] = 1.0
    observation[seen_wall] = 0.0
    axes[0, 1].imshow(observation, cmap="gray", vmin=0, vmax=1)
    axes[0, 1].set_title("line-of-sight observation")
    carved = observation.copy()
    overlay = np.zeros(walls.shape + (4,))
    overlay[result.carved & ~seen_free] = (0.1, 0.6, 1.0, 0.9)
    overlay[result.carved & walls] = (1.0, 0.0, 0.0, 1.0)
    axes[0, 2].imshow(carved, cmap="gray", vmin=0, vmax=1)
    axes[0, 2].imshow(overlay)
    axes[0, 2].set_title(f"carved beyond sight: {int((result.carved & ~seen_free).sum())} cells (blue)")
    for ax, image, title in ((axes[1, 0], result.bp, "back-projection"),
                             (axes[1, 1], result.bp_filtered, "Laplacian-filtered back-projection")):
        ax.imshow(image, cmap="magma", vmin=0, vmax=1)
        ys, xs = np.nonzero(truth)
        ax.scatter(xs, ys, s=1, c="red", alpha=0.4, label="hidden walls (h2)")
        ax.set_title(title)
    half = int(round(zoom_m / grid.resolution_m))
    for ax in axes.flat[:5]:
        ax.plot(pose_rc[1], pose_rc[0], "g*", markersize=12)
        ax.set_xlim(max(pose_rc[1] - half, 0) - 0.5, min(pose_rc[1] + half, walls.shape[1] - 1) + 0.5)
        ax.set_ylim(min(pose_rc[0] + half, walls.shape[0] - 1) + 0.5, max(pose_rc[0] - half, 0) - 0.5)
        ax.set_xticks([])
        ax.set_yticks([])
    ax = axes[1, 2]
    late = np.flatnonzero(result.los.first_late_bin >= 0)
    bins_m = (np.arange(scan.histograms.shape[1]) + 0.5) * scan.bin_path_m
    for ray in late[np.linspace(0, len(late) - 1, min(4, len(late))).astype(int)] if len(late) else []:
        ax.semilogy(bins_m, np.maximum(scan.histograms[ray], 1e-3), label=f"ray {ray}")
    ax.set_xlabel("round-trip path (m)")
    ax.set_ylabel("photons per bin")
    ax.set_title("histograms (direct peak, then three-bounce returns)")
    if len(late):
        ax.legend(fontsize=8)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _observed_image(observed: np.ndarray) -> np.ndarray:
    image = np.full(observed.shape, 0.5)
    image[observed == 0] = 1.0
    image[observed == 1] = 0.0
    return image


def save_map_image(observed: np.ndarray, path: Path) -> Path:
    """The observed map (int8 ``[H, W]``: -1 unknown, 0 free, 1 wall; row 0 at the top) as an 8-bit grey PNG, one
    pixel per cell, in map_saver's colours (free 254, wall 0, unknown 205)."""
    from PIL import Image

    observed = np.asarray(observed)
    image = np.full(observed.shape, 205, np.uint8)
    image[observed == 0] = 254
    image[observed == 1] = 0
    Image.fromarray(image).save(path, format="PNG")
    return Path(path)


def save_episode_figure(path: Path, grid, result) -> Path:
    """Ground truth with the driven path; the final observed map with the goals chosen (red crosses) and the
    frontier regions left (orange, dots at their goal cells); the final prediction."""
    from superex_deploy.onboard import ExplorerConfig
    from superex_deploy.onboard.planning.frontiers import find_frontiers

    plt = _pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(18, 6))
    axes[0].imshow(~grid.occupied, cmap="gray")
    axes[0].plot(result.poses[:, 1], result.poses[:, 0], "-", color="tab:blue", linewidth=1.2)
    axes[0].plot(result.start_rc[1], result.start_rc[0], "g*", markersize=12)
    axes[0].set_title(f"{grid.name}: path {result.path_length_m[-1] if len(result.path_length_m) else 0:.1f} m")
    axes[1].imshow(_observed_image(result.final_observed), cmap="gray", vmin=0, vmax=1)
    explorer_cfg = ExplorerConfig.from_json(result.config["explorer"])
    frontiers = find_frontiers(result.final_observed, explorer_cfg.frontier_min_cells(grid.resolution_m))
    if frontiers:
        cells = np.concatenate([f.cells for f in frontiers])
        axes[1].plot(cells[:, 1], cells[:, 0], ",", color="tab:orange")
        goal_cells = np.array([f.cell_rc for f in frontiers])
        axes[1].plot(goal_cells[:, 1], goal_cells[:, 0], "o", color="tab:orange", markersize=3)
    if result.goals:
        goals = np.array(result.goals)
        axes[1].plot(goals[:, 1], goals[:, 0], "rx", markersize=5)
    coverage = result.coverage[-1] if len(result.coverage) else 0.0
    axes[1].set_title(f"observed ({result.planner}): coverage {coverage:.1%}")
    if result.final_prediction is not None:
        axes[2].imshow(result.final_prediction.mean, cmap="gray_r", vmin=0, vmax=1)
        last_iou = result.iou[-1] if result.iou else float("nan")
        axes[2].set_title(f"prediction ({result.predictor}): map IoU {last_iou:.3f}")
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


class GifRecorder:
    """Collects observed-map frames (robot in red, path in blue) every ``every`` steps; at most ``max_side``
    pixels on the longer side, so GIFs of large maps stay small.

    Raises:
        ValueError: ``every`` or ``max_side`` not an integer >= 1.
    """

    def __init__(self, every: int = 5, max_side: int = 400):
        for name, value in (("every", every), ("max_side", max_side)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"GifRecorder: {name} must be an integer >= 1, got {value!r}")
        self.every = int(every)
        self.max_side = int(max_side)
        self.frames: list[np.ndarray] = []
        self._trail: list[tuple[int, int]] = []

    def __call__(self, state) -> None:
        """Record one step (an :class:`~superex_deploy.evaluation.episodes.EpisodeState`; the episode's ``on_step``)."""
        self._trail.append(state.pose)
        if state.step % self.every:
            return
        rgb = (np.repeat(_observed_image(state.observed)[..., None], 3, axis=2) * 255).astype(np.uint8)
        trail = np.array(self._trail)
        rgb[trail[:, 0], trail[:, 1]] = (40, 110, 255)
        r, c = state.pose
        rgb[max(r - 2, 0):r + 3, max(c - 2, 0):c + 3] = (230, 30, 30)
        stride = max(1, int(np.ceil(max(rgb.shape[:2]) / self.max_side)))
        self.frames.append(rgb[::stride, ::stride])

    def save(self, path: Path) -> Path:
        import imageio.v2 as imageio

        path = Path(path)
        imageio.mimsave(path, self.frames or [np.zeros((2, 2, 3), np.uint8)], duration=0.08, loop=0)
        return path


def save_benchmark_plots(out_dir: Path, results: list[dict]) -> None:
    """coverage.png (mean coverage against step per planner) and iou_vs_coverage.png (map IoU against coverage)."""
    plt = _pyplot()
    by_planner: dict[str, list[dict]] = {}
    for result in results:
        by_planner.setdefault(result["planner"], []).append(result)
    fig, ax = plt.subplots(figsize=(7, 5))
    for planner, runs in sorted(by_planner.items()):
        length = max(len(r["coverage"]) for r in runs)
        # An episode that finished early keeps its final coverage.
        padded = np.array([np.pad(r["coverage"], (0, length - len(r["coverage"])), mode="edge")
                           if r["coverage"] else np.zeros(length) for r in runs])
        ax.plot(np.arange(1, length + 1), padded.mean(axis=0), label=f"{planner} ({len(runs)})")
    ax.set_xlabel("step")
    ax.set_ylabel("coverage of the valid area")
    ax.legend()
    fig.tight_layout()
    fig.savefig(Path(out_dir) / "coverage.png", dpi=90)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(7, 5))
    for planner, runs in sorted(by_planner.items()):
        xs = np.concatenate([r["iou"]["coverage"] for r in runs]) if runs else np.array([])
        ys = np.concatenate([r["iou"]["iou"] for r in runs]) if runs else np.array([])
        ax.scatter(xs, ys, s=6, alpha=0.5, label=planner)
    ax.set_xlabel("coverage")
    ax.set_ylabel("map IoU of the prediction (walls)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(Path(out_dir) / "iou_vs_coverage.png", dpi=90)
    plt.close(fig)


def save_suite_plots(out_dir: Path, rows: dict, steps: int) -> None:
    """The paper's two figures for ``superex benchmark --suite paper``: coverage.png (mean coverage with carving
    against step, per row, its bootstrap 95 % interval shaded) and iou_vs_coverage.png (mean map IoU per 5 %
    coverage bin, the interval over episodes shaded)."""
    from superex_deploy.evaluation.metrics import coverage_curves
    from superex_deploy.evaluation.summary import bootstrap_interval

    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 5.5))
    x = np.arange(1, steps + 1)
    for name, episodes in rows.items():
        curves = coverage_curves(episodes, steps)
        rng = np.random.default_rng(0)
        means = curves[rng.integers(0, len(curves), (1000, len(curves)))].mean(axis=1)
        line, = ax.plot(x, 100 * curves.mean(axis=0), label=f"{name} ({len(episodes)})", lw=1.2)
        ax.fill_between(x, 100 * np.quantile(means, 0.025, axis=0), 100 * np.quantile(means, 0.975, axis=0),
                        color=line.get_color(), alpha=0.15, lw=0)
    _finish(plt, fig, ax, "step (0.3 m each)", "coverage of the valid area, % (carving included)",
            Path(out_dir) / "coverage.png")
    fig, ax = plt.subplots(figsize=(8, 5.5))
    edges = np.arange(0.0, 0.65, 0.05)
    centres = 0.5 * (edges[:-1] + edges[1:])
    for name, episodes in rows.items():
        per_bin = [[] for _ in centres]
        for episode in episodes:
            cov, iou = np.asarray(episode["iou"]["coverage"]), np.asarray(episode["iou"]["iou"])
            for b in range(len(centres)):
                inside = (cov >= edges[b]) & (cov < edges[b + 1])
                if inside.any():
                    per_bin[b].append(float(iou[inside].mean()))
        keep = [b for b in range(len(centres)) if len(per_bin[b]) >= 3]
        if not keep:
            continue
        mean = np.array([np.mean(per_bin[b]) for b in keep])
        interval = np.array([bootstrap_interval(per_bin[b], resamples=1000) for b in keep])
        line, = ax.plot(100 * centres[keep], mean, marker="o", ms=3, lw=1.2, label=name)
        ax.fill_between(100 * centres[keep], interval[:, 0], interval[:, 1], color=line.get_color(), alpha=0.15,
                        lw=0)
    _finish(plt, fig, ax, "coverage, % (carving included)", "wall IoU of the predicted map",
            Path(out_dir) / "iou_vs_coverage.png")


def _finish(plt, fig, ax, xlabel: str, ylabel: str, path: Path) -> None:
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
