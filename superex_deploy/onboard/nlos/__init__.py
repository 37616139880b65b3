"""NLOS processing of SPAD histograms: LOS peaks, space carving and back-projection.

Everything here works from what a real sensor gives: the histograms, the ray angles, the robot pose, the bin
width and the sensor's own configuration. Only the detections are read (bins whose count exceeds the detection
threshold: every non-zero bin without noise), as :class:`~superex_deploy.spad_types.SparseHistograms`: the simulator's
noise-free scans come in that form, dense (noisy) histograms are read once to extract them. The simulator's
ground truth (``scan.truth``) is never read here: the labels come from
:func:`superex_deploy.sim.spad.nlos_ground_truth`.

Stages, one module each
-----------------------
- :mod:`.config`: the parameters (:class:`NlosConfig`), the per-ray estimates (:class:`LosEstimate`), the results
  (:class:`GridPatch`, :class:`NlosResult`) and the small helpers every stage shares;
- :mod:`.los`: direct returns, wall points and first late bins (:func:`estimate_los`);
- :mod:`.normals`: wall normals from the scan's own hits, and which are trusted for carving;
- :mod:`.carving`: space carving (:func:`carve`), with the argument for why it is sound;
- :mod:`.back_projection`: back-projection of the late photons (:func:`back_project`);
- :mod:`.filters`: the Laplacian filter of the back-projection (:func:`laplacian_filter`);
- here: :func:`process_scan`, all of them on one scan. The offline metrics of the results (wall IoU) are
  evaluation, in :mod:`superex_deploy.evaluation.metrics`.

Cost
----
The results cover a small part of the map, so :func:`process_scan` makes them as :class:`GridPatch` es (the
window, the carved sectors' box); whole maps are made only when asked for. The normals, the votes, the carving
and the ring drawing run on numba's threads (``NlosConfig.threads``), each part owning its wall cells or rows,
so the results do not depend on the thread count; the Laplacian filter is ``scipy.ndimage``'s, rewritten in
numba with the same order of operations (equal to the last bit) to skip scipy's per-call overhead and the
whole-map copies.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from superex_deploy.onboard.nlos.back_projection import back_project, back_project_patch
from superex_deploy.onboard.nlos.carving import carve, carve_patch
from superex_deploy.onboard.nlos.shared import GridPatch, LosEstimate, NlosConfig, NlosResult, carve_radius_cap_m
from superex_deploy.onboard.nlos.filters import laplacian_filter, laplacian_filter_patch
from superex_deploy.onboard.nlos.los import estimate_los
from superex_deploy.spad_types import SpadScan

__all__ = ["NlosConfig", "LosEstimate", "GridPatch", "NlosResult", "estimate_los", "carve", "back_project",
           "laplacian_filter", "process_scan", "carve_radius_cap_m"]


def process_scan(scan: SpadScan, cfg: NlosConfig = NlosConfig(), known: Optional[np.ndarray] = None,
                 pose_sigma=(0.0, 0.0), map_walls: Optional[np.ndarray] = None) -> NlosResult:
    """LOS estimates, carved free space, back-projection and its Laplacian-filtered version (as patches; the
    result's ``carved``, ``bp`` and ``bp_filtered`` give whole maps). ``pose_sigma``: ``(sigma_xy_m,
    sigma_yaw_rad)`` of the scan's pose, which widens the carving margins; ``map_walls``: the map's wall cells,
    which support the carving's normals (both :func:`carve`)."""
    los = estimate_los(scan, cfg)
    bp = back_project_patch(scan, los, cfg, known)
    return NlosResult(carved_patch=carve_patch(scan, los, cfg, pose_sigma, map_walls), bp_patch=bp,
                      bp_filtered_patch=laplacian_filter_patch(bp, cfg.in_cells(scan.resolution_m).laplacian_sigma),
                      los=los)
