"""Per-grid precomputation of the SPAD simulator (:class:`SpadScene`, :func:`prepare_scene`): the wall normals
(Sobel gradients, and the principal axis of the 5x5 window for one-cell-thick walls), the map of wall blocks and the
cell codes the tracer steps by, the wall-cell index keying the fan caches, and the fan caches themselves. One scene
per grid, kept for the grid's lifetime.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass, field

import numba
import numpy as np
from scipy import ndimage

from superex_deploy.geometry import minor_axis_2x2, window_covariance
from superex_deploy.maps import OccupancyGrid
import superex_deploy.sim.spad.fans as fans
from superex_deploy.sim.spad.fans import FanCache
from superex_deploy.sim.spad.tracer import BLOCK_CELLS, CELL_FREE, CELL_OPEN_BLOCK, CELL_WALL

__all__ = ["SpadScene", "prepare_scene"]


@numba.njit(cache=True)
def _thin_wall_normals(occupied, weak, normals):
    """Minor principal axis of the wall cells in the 5x5 window around each ``weak`` wall cell (unit, arbitrary
    sign); left at zero where the window's wall cells are isotropic (an isolated cell or a blob)."""
    n_rows, n_cols = occupied.shape
    for r in range(n_rows):
        for c in range(n_cols):
            if not weak[r, c]:
                continue
            _, cyy, cxx, cxy = window_covariance(occupied, r, c, 2)
            # The minor axis of the points' covariance is the wall's normal.
            half_trace, spread, vy, vx, norm = minor_axis_2x2(cyy, cxx, cxy)
            if spread < 1e-9 or half_trace < 1e-9:
                continue
            normals[r, c, 0] = vy / norm
            normals[r, c, 1] = vx / norm


@dataclass(frozen=True, eq=False)
class SpadScene:
    """Per-grid precomputation shared by every scan in that grid (ground-truth geometry only).

    Attributes:
        grid: the ground-truth occupancy grid, as a ``weakref.proxy``: the cache of scenes is keyed by a weak
            reference to the grid, and a strong one here would keep every grid ever scanned alive.
        normals: float64 ``[H, W, 2]`` unit normal ``(dy, dx)`` at wall cells; Sobel-based (pointing out of the
            wall, physical sign) where ``two_sided`` is False, principal-axis based (sign unknown) where True,
            zero where undefined (isolated cells: the entry face is used instead).
        two_sided: bool ``[H, W]`` wall cells whose normal sign is not physical (thin walls).
        wall_blocks: bool ``[ceil(H / 4), ceil(W / 4)]``: True where the 4x4 block of cells holds a wall.
        cell_kind: uint8 ``[H, W]``: ``CELL_WALL`` at walls, ``CELL_OPEN_BLOCK`` at free cells of wall-free
            blocks, ``CELL_FREE`` at the other free cells (codes from :mod:`superex_deploy.sim.spad.tracer`). Rays
            cross wall-free blocks four cells at a time (see :func:`.tracer.trace_first_hit_blocks`); one byte per
            cell tells a cell step both outcomes at once.
        wall_index: int32 ``[H, W]``: running index of each wall cell (row-major), -1 at free cells; keys the
            fan caches.
        n_wall_cells: number of wall cells.
        fan_caches: ``(n_secondary, range in cells) -> FanCache``, filled by the scans.
    """

    grid: OccupancyGrid
    normals: np.ndarray
    two_sided: np.ndarray
    wall_blocks: np.ndarray
    cell_kind: np.ndarray
    wall_index: np.ndarray
    n_wall_cells: int
    fan_caches: dict = field(default_factory=dict, repr=False)

    def fan_cache(self, n_secondary: int, max_t: float) -> FanCache:
        """The fan cache for ``n_secondary`` rays of range ``max_t`` cells (created empty on first use)."""
        key = (int(n_secondary), float(max_t))
        cache = self.fan_caches.get(key)
        if cache is None:
            # The size is read from the fans module at call time (tests shrink it there).
            cache = self.fan_caches[key] = FanCache(self.n_wall_cells, n_secondary, fans.MAX_CACHED_FAN_BYTES)
        return cache

    def clear_fan_caches(self) -> None:
        """Forget every cached fan: the next scan traces all of its fans (a cold scan)."""
        self.fan_caches.clear()


_SCENES: "weakref.WeakKeyDictionary[OccupancyGrid, SpadScene]" = weakref.WeakKeyDictionary()


def _wall_blocks(occupied: np.ndarray) -> np.ndarray:
    """bool ``[ceil(H / B), ceil(W / B)]`` (``B = BLOCK_CELLS``): which blocks of ``B x B`` cells hold a wall."""
    n_rows = -(-occupied.shape[0] // BLOCK_CELLS)
    n_cols = -(-occupied.shape[1] // BLOCK_CELLS)
    padded = np.zeros((n_rows * BLOCK_CELLS, n_cols * BLOCK_CELLS), bool)
    padded[:occupied.shape[0], :occupied.shape[1]] = occupied
    return padded.reshape(n_rows, BLOCK_CELLS, n_cols, BLOCK_CELLS).any(axis=(1, 3))


def _cell_kind(occupied: np.ndarray, wall_blocks: np.ndarray) -> np.ndarray:
    """uint8 ``[H, W]``, see :attr:`SpadScene.cell_kind`."""
    in_open_block = ~np.repeat(np.repeat(wall_blocks, BLOCK_CELLS, 0), BLOCK_CELLS, 1)
    kind = np.where(in_open_block[:occupied.shape[0], :occupied.shape[1]], CELL_OPEN_BLOCK, CELL_FREE)
    kind[occupied] = CELL_WALL
    return kind.astype(np.uint8)


def prepare_scene(grid: OccupancyGrid) -> SpadScene:
    """Wall normals and wall blocks of a grid, computed once and cached for the grid's lifetime (a weak
    reference to the grid keys the cache: scans of one grid share them and its fan caches, and they go when the
    grid goes)."""
    if not isinstance(grid, OccupancyGrid):
        raise ValueError(f"grid must be an OccupancyGrid, got {type(grid).__name__}")
    scene = _SCENES.get(grid)
    if scene is None:
        walls = grid.occupied.astype(np.float64)
        grad_y = ndimage.sobel(walls, axis=0, mode="nearest")
        grad_x = ndimage.sobel(walls, axis=1, mode="nearest")
        magnitude = np.hypot(grad_y, grad_x)
        strong = grid.occupied & (magnitude >= 1.0)
        normals = np.zeros(grid.shape + (2,), np.float64)
        # Occupancy rises into the wall, so the outward (free-side) normal is minus the gradient.
        normals[strong, 0] = -grad_y[strong] / magnitude[strong]
        normals[strong, 1] = -grad_x[strong] / magnitude[strong]
        weak = grid.occupied & ~strong
        _thin_wall_normals(grid.occupied, weak, normals)
        wall_blocks = _wall_blocks(grid.occupied)
        wall_index = np.where(grid.occupied, np.cumsum(grid.occupied.ravel()).reshape(grid.shape) - 1, -1)
        scene = SpadScene(grid=weakref.proxy(grid), normals=normals, two_sided=weak, wall_blocks=wall_blocks,
                          cell_kind=_cell_kind(grid.occupied, wall_blocks), wall_index=wall_index.astype(np.int32),
                          n_wall_cells=int(np.count_nonzero(grid.occupied)))
        _SCENES[grid] = scene
    return scene
