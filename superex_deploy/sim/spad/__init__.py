"""SPAD LiDAR simulator (the simulator's side; the sensor model and histogram types are in
:mod:`superex_deploy.spad_types`): time-of-flight histograms with the direct and the three-bounce (NLOS) returns.

The model is the seed paper's, in 2D and confocal (laser and detector at the robot cell centre):

* Primary ray ``i`` (``SpadConfig.n_rays`` over 360 degrees) hits wall cell ``h1`` at distance ``d1`` (metres,
  to the point where the ray enters the cell).
* The outward normal ``n1`` at ``h1`` comes from Sobel gradients of the ground-truth grid. One-cell-thick walls
  (5-25 % of KTH wall cells) have no Sobel response, so there the normal is the minor principal axis of the
  wall cells in a 5x5 window, and for an isolated cell the face the primary ray entered. The normal at ``h1``
  faces the robot.
* ``n_secondary`` rays leave ``h1`` uniformly over [-90, 90] degrees about ``n1`` (midpoint sampling, so none
  is exactly grazing) until they hit a wall ``h2`` at distance ``d2``.
* Bins: ``b = floor(path / bin_path_m)`` with path ``2 d1`` (direct) and ``2 d1 + 2 d2`` (three-bounce).
* Counts: eq. (1) ``N1 = alpha E rho / pi * lambda / (h c)`` and eq. (2)
  ``N2 = E rho^3 cos(theta1) cos(theta2) s^2 alpha / (pi^3 d1 d2^2) * lambda / (h c)`` per secondary ray
  (``theta1``: incidence of the primary at ``h1``; ``theta2``: of the secondary at ``h2``; ``s``: the grid
  resolution in metres, the size of the reflecting patch).

Two discretisation choices, both at the grid's 0.1 m scale:

* **Per-cell fans.** All primaries hitting the same cell share one secondary fan (traced once per grid), from
  the point ``X1`` where the normal through the cell centre leaves the cell. Rays reaching the same 0.1 m patch
  see the same hidden scene up to a few centimetres, and this makes the scan affordable.
* **Staircase walls.** A fan started right at ``X1`` would graze the staircase of its own rasterised wall and
  return at ``d2 ~ 0.1 m`` for every oblique wall. Tracing therefore starts at ``X1 + FAN_OFFSET_CELLS * n1``
  (``d2`` is still measured from ``X1``), and Lambertian cosines are clamped at zero: a secondary ray arriving
  at the back of a thick wall's surface (``d . n2 > 0``) returns nothing. If the offset start lies in a wall,
  the return is recorded at ``d2 = FAN_OFFSET_CELLS`` cells (an early, conservative return).

Distances ``d1, d2`` are floored at half a cell so eq. (2) stays finite for a robot touching a wall.

Cost. :func:`prepare_scene` computes, once per grid, the wall normals and a 4x4-block occupancy map (cached on
the grid: it costs several scans; measured in docs/benchmarks/spad.md). Every scan then traces the primaries and one
fan per distinct hit cell with a two-level DDA that crosses wall-free 4x4 blocks in one step and returns the
exact DDA's hits, groups the rays by hit cell and writes the histograms. A fan depends on its wall cell and
the normal it leaves along, not on the robot's pose, so each grid keeps the fans traced so far
(:class:`FanCache`): along an exploration episode a scan traces only the fans of wall cells it is the first to
see. The histograms are written sparse (:class:`SparseHistograms`: at most ``1 + n_secondary`` of the
``n_bins`` bins of a noise-free ray are non-zero), and densified only when asked for. The primaries, the new
fans and the histograms are each split over numba's threads; the split never changes a scan.

Modules (one per job): :mod:`.truth` (:class:`SpadTruth`), :mod:`.scene` (wall normals, wall blocks and cell
codes: :class:`SpadScene`, :func:`prepare_scene`), :mod:`.tracer` (the two-level first-hit DDA, the primaries, the
normal a ray sees), :mod:`.fans` (:class:`FanCache`, looking up and tracing fans), :mod:`.histograms` (the sparse
histograms), :mod:`.noise` (detector noise), :mod:`.simulate` (:func:`simulate_scan`, :func:`measured_frame`) and :mod:`.labels`
(:func:`nlos_ground_truth`).
"""

from superex_deploy.sim.spad.fans import FAN_OFFSET_CELLS, FAN_VARIANTS, MAX_CACHED_FAN_BYTES, FanCache
from superex_deploy.sim.spad.labels import nlos_ground_truth
from superex_deploy.sim.spad.scene import SpadScene, prepare_scene
from superex_deploy.sim.spad.simulate import MIN_DISTANCE_CELLS, measured_frame, simulate_scan
from superex_deploy.sim.spad.tracer import BLOCK_CELLS, BLOCK_SHIFT, CELL_FREE, CELL_OPEN_BLOCK, CELL_WALL
from superex_deploy.sim.spad.truth import SpadTruth

# The constants above are re-exported for reading; each is read from its own module (to resize the fan caches, set
# superex_deploy.sim.spad.fans.MAX_CACHED_FAN_BYTES).
__all__ = ["SpadTruth", "SpadScene", "FanCache", "prepare_scene", "simulate_scan", "measured_frame", "nlos_ground_truth"]
