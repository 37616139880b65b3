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
