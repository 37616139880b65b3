"""Slow, obviously-correct references for every numba kernel. Each section belongs to one module."""

from __future__ import annotations

import numpy as np

# --- geometry ---


def naive_first_hit(occupied, y0, x0, angle, max_t):
    """First occupied cell along a ray, found by listing every grid-line crossing (no DDA stepping).

    Returns (row, col, t_entry, entry_axis) like ``geometry._trace_first_hit``.
    """
    n_rows, n_cols = occupied.shape
    dy, dx = np.sin(angle), np.cos(angle)
    r0, c0 = int(np.floor(y0)), int(np.floor(x0))
    if occupied[r0, c0]:
        return r0, c0, 0.0, -1
    crossings = []  # (t, axis): axis 0 = a row boundary y = k, 1 = a column boundary x = k
    if dy != 0.0:
        for k in range(0, n_rows + 1):
            t = (k - y0) / dy
            if t > 1e-12:
                crossings.append((t, 0))
    if dx != 0.0:
        for k in range(0, n_cols + 1):
            t = (k - x0) / dx
            if t > 1e-12:
                crossings.append((t, 1))
    crossings.sort()
    for i, (t, axis) in enumerate(crossings):
        if t > max_t:
            return -1, -1, max_t, -1
        t_next = crossings[i + 1][0] if i + 1 < len(crossings) else t + 1.0
        t_mid = 0.5 * (t + t_next)
        r, c = int(np.floor(y0 + t_mid * dy)), int(np.floor(x0 + t_mid * dx))
        if not (0 <= r < n_rows and 0 <= c < n_cols):
            return -1, -1, t, -1
        if occupied[r, c]:
            return r, c, t, axis
    return -1, -1, max_t, -1


def naive_mark_rays(occupied, y0, x0, angles, max_t):
    """Free and hit masks of a line-of-sight scan, by sampling each ray densely (step 1e-3 cells)."""
    free = np.zeros(occupied.shape, bool)
    hit = np.zeros(occupied.shape, bool)
    for angle in angles:
        r, c, t_hit, _ = naive_first_hit(occupied, y0, x0, angle, max_t)
        stop = t_hit if r >= 0 else t_hit
        for t in np.arange(0.0, stop, 1e-3):
            rr, cc = int(np.floor(y0 + t * np.sin(angle))), int(np.floor(x0 + t * np.cos(angle)))
            if 0 <= rr < occupied.shape[0] and 0 <= cc < occupied.shape[1]:
                free[rr, cc] = True
        if r >= 0:
            hit[r, c] = True
    return free, hit

def naive_mark_ranges(shape, y0, x0, angles, ranges_cells, max_t, tolerance=1e-6):
    """Free and hit masks of a measured scan, from a sorted list of every grid-line crossing (no DDA stepping):
    cells left before ``range + tolerance`` are free, the cell holding that point is hit; ``inf``: no return."""
    n_rows, n_cols = shape
    free = np.zeros(shape, bool)
    hit = np.zeros(shape, bool)
    for angle, distance in zip(angles, ranges_cells):
        cells = [(0.0, int(np.floor(y0)), int(np.floor(x0)))] + _naive_cells_along_ray(n_rows, n_cols, y0, x0, angle)
        hit_at = distance + tolerance if np.isfinite(distance) else None
        for k, (t_in, r, c) in enumerate(cells):
            if t_in > max_t or not (0 <= r < n_rows and 0 <= c < n_cols):
                break
            t_out = cells[k + 1][0] if k + 1 < len(cells) else np.inf
            if hit_at is not None and t_out > hit_at:
                hit[r, c] = True
                break
            free[r, c] = True
    return free, hit


# --- spad ---


def naive_thin_wall_normals(occupied, weak):
    """Minor principal axis (numpy eigh) of the wall cells in each weak cell's 5x5 window; 0 if isotropic."""
    normals = np.zeros(occupied.shape + (2,))
    for r, c in zip(*np.nonzero(weak)):
        window = [(rr - r, cc - c) for rr in range(r - 2, r + 3) for cc in range(c - 2, c + 3)
                  if 0 <= rr < occupied.shape[0] and 0 <= cc < occupied.shape[1] and occupied[rr, cc]]
        values, vectors = np.linalg.eigh(np.cov(np.array(window, float).T, bias=True))
        if values[1] - values[0] > 1e-9 and values.sum() > 1e-9:
            normals[r, c] = vectors[:, 0]
    return normals


def _naive_facing_normal(scene, r, c, entry_axis, dy, dx, towards):
    ny, nx = scene.normals[r, c]
    if ny == 0.0 and nx == 0.0:
        if entry_axis == 0:
            return (-1.0 if dy > 0 else 1.0), 0.0
        if entry_axis == 1:
            return 0.0, (-1.0 if dx > 0 else 1.0)
        return -dy, -dx
    if scene.two_sided[r, c] and ny * towards[0] + nx * towards[1] < 0.0:
        return -ny, -nx
    return ny, nx


def naive_group_by_cell(hit_rc, n_cols):
    """geometry.group_by_cell with a dict: distinct hit cells sorted by row * n_cols + col, the first ray (in
    ray order) that hit each, and the group of every ray (-1 for no hit)."""
    first_ray = {}
    for i, (r, c) in enumerate(hit_rc.tolist()):
        if r >= 0:
            first_ray.setdefault((r, c), i)
    cells = sorted(first_ray, key=lambda rc: rc[0] * n_cols + rc[1])
    index = {cell: u for u, cell in enumerate(cells)}
    ray_group = np.array([index[(r, c)] if r >= 0 else -1 for r, c in hit_rc.tolist()])
    return ray_group, np.array(cells, int).reshape(-1, 2), np.array([first_ray[cell] for cell in cells], int)


def naive_sort_paths(path_m, gain):
    """spad.fans._sort_paths: (path_m, gain) reordered by a stable sort of path_m."""
    order = np.argsort(path_m, kind="stable")
    return path_m[order], gain[order]


def naive_simulate_histograms(scene, pose_rc, cfg):
    """Noise-free histograms by brute force: every primary ray traces its own fan with naive_first_hit.

    Follows simulate_scan's documented model (fan from X1 on the normal through the cell centre, offset start,
    clamped cosines, the fan of a cell built with the entry face of the first ray that hit it).
    """
    from superex_deploy.sim.spad import FAN_OFFSET_CELLS, MIN_DISTANCE_CELLS

    grid = scene.grid
    res = grid.resolution_m
    y0, x0 = pose_rc[0] + 0.5, pose_rc[1] + 0.5
    max_t = cfg.range_m / res
    histograms = np.zeros((cfg.n_rays, cfg.n_bins))
    first_axis = {}
    primaries = []
    for i in range(cfg.n_rays):
        angle = 2.0 * np.pi * i / cfg.n_rays
        r, c, t, axis = naive_first_hit(grid.occupied, y0, x0, angle, max_t)
        primaries.append((angle, r, c, t))
        if r >= 0:
            first_axis.setdefault((r, c), axis)
    for i, (angle, r, c, t) in enumerate(primaries):
        if r < 0:
            continue
        d1 = max(t * res, MIN_DISTANCE_CELLS * res)
        histograms[i, int(2 * d1 / cfg.bin_path_m)] += cfg.direct_counts
        cy, cx = r + 0.5, c + 0.5
        towards = (y0 - cy, x0 - cx)
        ny, nx = _naive_facing_normal(scene, r, c, first_axis[(r, c)], cy - y0, cx - x0, towards)
        if ny * towards[0] + nx * towards[1] < 0:
            ny, nx = -ny, -nx
        cos1 = max(0.0, -(np.sin(angle) * ny + np.cos(angle) * nx))
        if cos1 == 0.0:
            continue
        half = 0.5 / max(abs(ny), abs(nx))
        x1 = (cy + half * ny, cx + half * nx)
        origin = (x1[0] + FAN_OFFSET_CELLS * ny, x1[1] + FAN_OFFSET_CELLS * nx)
        if not (0 <= origin[0] < grid.shape[0] and 0 <= origin[1] < grid.shape[1]):
            continue
        for k in range(cfg.n_secondary):
            phi = -0.5 * np.pi + (k + 0.5) * np.pi / cfg.n_secondary
            dy = ny * np.cos(phi) - nx * np.sin(phi)
            dx = ny * np.sin(phi) + nx * np.cos(phi)
            r2, c2, t2, axis2 = naive_first_hit(grid.occupied, origin[0], origin[1], np.arctan2(dy, dx), max_t)
            if r2 < 0:
                continue
            hit = (origin[0] + t2 * np.sin(np.arctan2(dy, dx)), origin[1] + t2 * np.cos(np.arctan2(dy, dx)))
            d2 = max(np.hypot(hit[0] - x1[0], hit[1] - x1[1]) * res, MIN_DISTANCE_CELLS * res)
            if t2 == 0.0:
                cos2 = 1.0
            else:
                n2y, n2x = _naive_facing_normal(scene, r2, c2, axis2, dy, dx, (-dy, -dx))
                cos2 = max(0.0, -(dy * n2y + dx * n2x))
            if cos2 == 0.0:
                continue
            b = int((2 * d1 + 2 * d2) / cfg.bin_path_m)
            if b < cfg.n_bins:
                histograms[i, b] += cfg.three_bounce_scale(res) * cos1 * cos2 / (d1 * d2 * d2)
    return histograms


# --- nlos ---


def naive_los_and_first_late_bins(histograms, threshold, guard):
    """(los_bin, first_late) per ray (nlos.los._los_and_first_late_bins): the direct return is the strongest of the
    guard bins from the first detection (count > threshold), the first late bin the first detection from
    los_bin + guard on; -1 where none."""
    los_bin = np.full(len(histograms), -1)
    first_late = np.full(len(histograms), -1)
    for i, row in enumerate(histograms):
        detections = np.flatnonzero(row > threshold)
        if len(detections) == 0:
            continue
        first = detections[0]
        los_bin[i] = first + np.argmax(row[first:first + guard])
        late = detections[detections >= los_bin[i] + guard]
        first_late[i] = late[0] if len(late) else -1
    return los_bin, first_late


def naive_hit_normals(points, radius, max_minor_ratio=0.1, interior=1.5, max_residual=np.inf, max_gap=np.inf):
    """numpy eigh of the covariance of the points within radius of each point (nlos.normals.hit_normals);
    ``interior``: one distance for every point, or one each."""
    normals = np.zeros((len(points), 2))
    reliable = np.zeros(len(points), bool)
    interiors = np.broadcast_to(np.asarray(interior, float), (len(points),))
    for u, p in enumerate(points):
        interior = interiors[u]
        near = points[np.hypot(*(points - p).T) <= radius]
        if len(near) < 3:
            continue
        values, vectors = np.linalg.eigh(np.cov(near.T, bias=True))
        if values[1] > 0 and values[0] <= max_minor_ratio * values[1]:
            normals[u] = vectors[:, 0]
            along = (near - p) @ np.array([-vectors[1, 0], vectors[0, 0]])
            straight = np.abs((near - near.mean(axis=0)) @ vectors[:, 0]).max() <= max_residual
            contiguous = np.all(np.diff(np.sort(along)) <= max_gap)
            reliable[u] = straight and contiguous and along.min() <= -interior and along.max() >= interior
    return normals, reliable


def naive_carve_sectors(shape, apex, normals, radius_cells, strip_cells, cos_limit):
    """Test every cell of the grid against every wall point's carve sector (nlos.carving.carve_sectors);
    ``strip_cells`` and ``cos_limit``: one value for every wall point, or one each."""
    out = np.zeros(shape, bool)
    strips = np.broadcast_to(np.asarray(strip_cells, float), (len(apex),))
    limits = np.broadcast_to(np.asarray(cos_limit, float), (len(apex),))
    for (ay, ax), (ny, nx), radius, strip_cells, cos_limit in zip(apex, normals, radius_cells, strips, limits):
        if not radius > strip_cells:
            continue
        oy, ox = ay + 0.75 * ny, ax + 0.75 * nx
        for r in range(shape[0]):
            for c in range(shape[1]):
                vy, vx = r + 0.5 - ay, c + 0.5 - ax
                if vy * vy + vx * vx >= radius * radius or vy * ny + vx * nx < strip_cells:
                    continue
                wy, wx = r + 0.5 - oy, c + 0.5 - ox
                norm = np.hypot(wy, wx)
                if norm == 0.0 or (wy * ny + wx * nx) / norm >= cos_limit:
                    out[r, c] = True
    return out


def sector_without_steps(wall_cells, wall_normal, cfg, yaw_margin_rad=0.0, steps=None):
    """The carving's sector before the step rule (nlos.carving.sector_cos_limits' signature): cos(90 deg -
    sector_margin_deg) for every wall point, what the legacy loop and the property's old rule carved with."""
    return np.full(len(wall_cells), np.cos(np.deg2rad(90.0 - cfg.sector_margin_deg)))


def naive_step_deviation(points, normals):
    """Angle (radians) between each point's wall line and the direction to each of its 8 neighbours, the largest
    (nlos.normals.step_deviation): numpy over all pairs."""
    out = np.zeros(len(points))
    for u, p in enumerate(points):
        d = points - p
        near = (np.abs(d) <= 1.0).all(axis=1) & (np.abs(d).sum(axis=1) > 0)
        if near.any():
            tangent = np.array([-normals[u, 1], normals[u, 0]])
            cosines = np.abs(d[near] @ tangent) / np.hypot(*d[near].T)
            out[u] = np.arccos(np.minimum(cosines, 1.0)).max()
    return out


def naive_back_projection(histograms, los_bin, ray_wall, d1_m, apex, normals, guard, threshold, background,
                          bin_path_m, resolution_m, window, known, n_radii):
    """Every ray, every late bin, every window cell tested for membership of that bin's ring (unnormalised)."""
    bp = np.zeros(known.shape)
    r_lo, r_hi, c_lo, c_hi = window
    for i in range(histograms.shape[0]):
        u = ray_wall[i]
        if u < 0:
            continue
        for b in range(los_bin[i] + guard, histograms.shape[1]):
            if histograms[i, b] <= threshold:
                continue
            d2 = (b - los_bin[i]) * bin_path_m / 2.0
            q = int(np.floor(d2 / resolution_m + 0.5))
            if q >= n_radii:
                continue
            vote = (histograms[i, b] - background) * d1_m[i] * d2 * d2
            for r in range(r_lo, r_hi + 1):
                for c in range(c_lo, c_hi + 1):
                    vy, vx = r + 0.5 - apex[u, 0], c + 0.5 - apex[u, 1]
                    dist2 = vy * vy + vx * vx
                    front = vy * normals[u, 0] + vx * normals[u, 1] > 0
                    if int(np.sqrt(dist2) + 0.5) == q and front and not known[r, c]:
                        bp[r, c] += vote
    return bp


def naive_draw_rings(apex, normals, votes, window, known):
    """Every window cell tested against every (wall point, radius) ring (nlos.back_projection._draw_rings); a
    cell at distance rho (cells) from the apex lies on ring floor(rho + 0.5)."""
    bp = np.zeros(known.shape)
    r_lo, r_hi, c_lo, c_hi = window
    for u, q in zip(*np.nonzero(votes)):
        for r in range(r_lo, r_hi + 1):
            for c in range(c_lo, c_hi + 1):
                vy, vx = r + 0.5 - apex[u, 0], c + 0.5 - apex[u, 1]
                if int(np.sqrt(vy * vy + vx * vx) + 0.5) == q \
                        and vy * normals[u, 0] + vx * normals[u, 1] > 0 and not known[r, c]:
                    bp[r, c] += votes[u, q]
    return bp


# --- explore ---

# explore: core


def naive_frontier_regions(observed, min_cells):
    """Frontier regions by flood fill: [(cells sorted row-major, goal cell)], ordered by first cell.

    A frontier cell is FREE (0) with an UNKNOWN (-1) 4-neighbour; regions are 8-connected; the goal is the
    region cell nearest to the centroid, ties to the first in row-major order (explore.frontiers)."""
    h, w = observed.shape
    is_frontier = np.zeros((h, w), bool)
    for r in range(h):
        for c in range(w):
            if observed[r, c] != 0:
                continue
            for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1)):
                if 0 <= r + dr < h and 0 <= c + dc < w and observed[r + dr, c + dc] == -1:
                    is_frontier[r, c] = True
    seen = np.zeros((h, w), bool)
    regions = []
    for r in range(h):
        for c in range(w):
            if not is_frontier[r, c] or seen[r, c]:
                continue
            stack, cells = [(r, c)], []
            seen[r, c] = True
            while stack:
                cr, cc = stack.pop()
                cells.append((cr, cc))
                for dr in (-1, 0, 1):
                    for dc in (-1, 0, 1):
                        nr, nc = cr + dr, cc + dc
                        if 0 <= nr < h and 0 <= nc < w and is_frontier[nr, nc] and not seen[nr, nc]:
                            seen[nr, nc] = True
                            stack.append((nr, nc))
            if len(cells) < min_cells:
                continue
            cells.sort()
            mean_r = sum(p[0] for p in cells) / len(cells)
            mean_c = sum(p[1] for p in cells) / len(cells)
            goal = min(cells, key=lambda p: ((p[0] - mean_r) ** 2 + (p[1] - mean_c) ** 2, p))
            regions.append((cells, goal))
    return regions


def naive_travel_cost(costs, source):
    """Dijkstra over 8-connected cells with scikit-image MCP_Geometric's edge cost: a step from a to b costs
    (costs[a] + costs[b]) / 2 times its length (1 or sqrt 2); inf cells are impassable (explore.motion)."""
    import heapq

    h, w = costs.shape
    best = np.full((h, w), np.inf)
    best[source] = 0.0
    queue = [(0.0, source)]
    while queue:
        d, (r, c) = heapq.heappop(queue)
        if d > best[r, c]:
            continue
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                nr, nc = r + dr, c + dc
                if (dr or dc) and 0 <= nr < h and 0 <= nc < w and np.isfinite(costs[nr, nc]):
                    step = 0.5 * (costs[r, c] + costs[nr, nc]) * np.hypot(dr, dc)
                    if d + step < best[nr, nc]:
                        best[nr, nc] = d + step
                        heapq.heappush(queue, (d + step, (nr, nc)))
    return best


def naive_planning_costs(observed, pose, resolution_m, robot_radius_m, weight, range_m):
    """Per-cell move cost of explore.motion's planning map, cell by cell: inf unless known FREE and farther
    than the radius from every observed wall (the robot's cell always passes); else 1 + weight * max(0, 1 -
    d / range) with d the distance (metres) to the nearest observed wall."""
    h, w = observed.shape
    walls = [(r, c) for r in range(h) for c in range(w) if observed[r, c] == 1]
    costs = np.full((h, w), np.inf)
    for r in range(h):
        for c in range(w):
            d = min((np.hypot(r - wr, c - wc) for wr, wc in walls), default=np.inf) * resolution_m
            if (observed[r, c] == 0 and d > robot_radius_m) or (r, c) == tuple(pose):
                costs[r, c] = 1.0 + weight * max(0.0, 1.0 - d / range_m)
    return costs

# explore: planners


def _naive_cells_along_ray(n_rows, n_cols, y0, x0, angle):
    """(t_entry, row, col) of every cell a ray enters after its start cell, from a sorted list of crossings."""
    dy, dx = np.sin(angle), np.cos(angle)
    crossings = []
    if abs(dy) > 1e-15:
        crossings += [(k - y0) / dy for k in range(n_rows + 1)]
    if abs(dx) > 1e-15:
        crossings += [(k - x0) / dx for k in range(n_cols + 1)]
    crossings = sorted(t for t in crossings if t > 1e-12)
    out = []
    for i, t in enumerate(crossings):
        t_next = crossings[i + 1] if i + 1 < len(crossings) else t + 1.0
        t_mid = 0.5 * (t + t_next)
        out.append((t, int(np.floor(y0 + t_mid * dy)), int(np.floor(x0 + t_mid * dx))))
    return out


def naive_visible_ranges(mean, y0, x0, n_rays, max_t, hit_threshold, accumulate):
    """Per-ray visible range of the probabilistic raycast (visibility.ray_visible_ranges): a cell blocks when its
    probability (or, accumulating, 1 - prod(1 - p) from the start cell on) reaches the threshold; the range
    ends at the blocking cell's entry + 0.5, at max_t or at the border; all zero from a blocking start cell."""
    n_rows, n_cols = mean.shape
    own = float(mean[int(np.floor(y0)), int(np.floor(x0))])
    if own >= hit_threshold:
        return np.zeros(n_rays)
    ranges = np.empty(n_rays)
    for k in range(n_rays):
        angle = 2.0 * np.pi * k / n_rays
        probabilities = [own]
        reach = max_t
        for t, r, c in _naive_cells_along_ray(n_rows, n_cols, y0, x0, angle):
            if t >= max_t:
                break
            if not (0 <= r < n_rows and 0 <= c < n_cols):
                reach = t
                break
            probabilities.append(float(mean[r, c]))
            blocked_probability = 1.0 - np.prod(1.0 - np.array(probabilities)) if accumulate else probabilities[-1]
            if blocked_probability >= hit_threshold:
                reach = min(t + 0.5, max_t)
                break
        ranges[k] = reach
    return ranges


def naive_fill_visibility(ranges, y0, x0, observed, variance):
    """Visible mask, visible-unknown count and variance sum (visibility._fill_visibility), testing every cell
    centre against the triangle (viewpoint, end point k, end point k + 1) of its angular sector by barycentric
    coordinates."""
    n_rays = len(ranges)
    visible = np.zeros(observed.shape, bool)
    if max(ranges) <= 0:
        return visible, 0, 0.0
    step = 2.0 * np.pi / n_rays
    ends = [(ranges[k] * np.sin(step * k), ranges[k] * np.cos(step * k)) for k in range(n_rays)]
    for r in range(observed.shape[0]):
        for c in range(observed.shape[1]):
            vy, vx = r + 0.5 - y0, c + 0.5 - x0
            if np.hypot(vy, vx) > max(ranges):
                continue
            k0 = int((np.arctan2(vy, vx) % (2.0 * np.pi)) / step) % n_rays
            (ay, ax), (by, bx) = ends[k0], ends[(k0 + 1) % n_rays]
            # v = s a + u b inside the sector; inside the triangle when s + u <= 1.
            det = ax * by - ay * bx
            s = (vx * by - vy * bx) / det
            u = (ax * vy - ay * vx) / det
            visible[r, c] = s + u <= 1.0
    unknown = visible & (observed == -1)
    return visible, int(unknown.sum()), float(variance[unknown].astype(np.float64).sum())


def naive_grow_rrt(passable, reachable, start_y, start_x, samples, expand_cells, variance):
    """Pure-Python RRT with planners.upen._grow_rrt's steering and collision rule; for every node the whole
    root-to-node path is walked again to sum its variance and find its exit (last cell before the first one
    outside ``reachable``)."""

    def segment_free(y0, x0, y1, x1):
        n = int(np.ceil(np.hypot(y1 - y0, x1 - x0) / 0.5)) + 1
        return all(passable[int(np.floor(y0 + i / n * (y1 - y0))), int(np.floor(x0 + i / n * (x1 - x0)))]
                   for i in range(n + 1))

    def edge_cells(a, b):
        n = max(1, int(np.ceil(max(abs(b[0] - a[0]), abs(b[1] - a[1])))))
        return [(int(np.floor(a[0] + i / n * (b[0] - a[0]))), int(np.floor(a[1] + i / n * (b[1] - a[1]))))
                for i in range(1, n + 1)]

    nodes, parents, depths = [(start_y, start_x)], [-1], [0]
    for sy, sx in samples:
        dists = [(ny - sy) ** 2 + (nx - sx) ** 2 for ny, nx in nodes]
        best = int(np.argmin(dists))
        dist = np.sqrt(dists[best])
        if dist < 1e-9:
            continue
        scale = min(1.0, expand_cells / dist)
        by, bx = nodes[best]
        new = (by + scale * (sy - by), bx + scale * (sx - bx))
        if segment_free(by, bx, *new):
            nodes.append(new)
            parents.append(best)
            depths.append(depths[best] + 1)
    path_variance, exits = [], []
    for node in range(len(nodes)):
        chain = [node]
        while parents[chain[-1]] >= 0:
            chain.append(parents[chain[-1]])
        chain.reverse()
        cells = [(int(np.floor(start_y)), int(np.floor(start_x)))]
        for a, b in zip(chain[:-1], chain[1:]):
            cells += edge_cells(nodes[a], nodes[b])
        path_variance.append(sum(float(variance[cell]) for cell in cells[1:]))
        outside = [k for k, cell in enumerate(cells) if not reachable[cell]]
        exits.append(cells[outside[0] - 1] if outside else cells[-1])
    return np.array(nodes), np.array(parents), np.array(depths), np.array(path_variance), np.array(exits)


# --- superex planner ---


def naive_path_gain(mean, observed, path, every, n_rays, range_cells, hit_threshold):
    """Unknown cells visible from path[every], path[2 every], ... and the path's last cell (the SuperEx
    planner's pathwise gain), by the naive visibility reference."""
    seen = np.zeros(observed.shape, bool)
    for k in list(range(every, len(path) - 1, every)) + [len(path) - 1]:
        r, c = path[k]
        ranges = naive_visible_ranges(mean, r + 0.5, c + 0.5, n_rays, range_cells, hit_threshold, False)
        visible, _, _ = naive_fill_visibility(ranges, r + 0.5, c + 0.5, observed, np.zeros(observed.shape))
        seen |= visible
    return int(np.count_nonzero(seen & (observed == -1)))


# --- onboard.mapper ---


def naive_clear_limits(angles, reach, sigma_xy, sigma_yaw, sigmas, max_half=np.pi / 6.0):
    """onboard.mapping.log_odds.clear_limits by brute force: for each ray, lower ``t`` from its own reach to the nearest reach
    among all rays within ``min(atan(u(t) / t), max_half)`` of its angle (``u(t) = sigmas sqrt(sigma_xy^2 +
    (t sigma_yaw)^2)``) until every one of them reaches ``t`` (at most 8 times)."""
    angles = np.mod(np.asarray(angles, np.float64), 2.0 * np.pi)
    reach = np.asarray(reach, np.float64)
    if sigmas == 0.0 or (sigma_xy == 0.0 and sigma_yaw == 0.0):
        return reach.copy()
    out = np.empty(reach.size)
    for i in range(reach.size):
        t = reach[i]
        for _ in range(8):
            half = min(np.arctan2(sigmas * np.sqrt(sigma_xy ** 2 + (t * sigma_yaw) ** 2), max(t, 1e-9)), max_half)
            gap = np.abs(angles - angles[i])
            nearest = reach[np.minimum(gap, 2.0 * np.pi - gap) <= half].min()
            if nearest >= t:
                break
            t = nearest
        out[i] = t
    return out


def naive_integrate_log_odds(log_odds, y0, x0, angles, ranges_cells, max_t, hit, miss, lowest, highest,
                             hit_shift=0.0, usable_t=np.inf, stop_at=np.inf, pose_sigmas=None, sigmas=1.0):
    """onboard.mapper._integrate_log_odds one ray at a time from :func:`naive_mark_ranges`: each return placed
    ``hit_shift`` farther (its ray walked up to it even beyond ``max_t``); a ray without a return walked up to
    ``min(max_t, usable_t)`` from the sorted grid-line crossings, cut before the first cell whose log-odds is
    ``stop_at`` or more; with ``pose_sigmas`` ``(sigma_xy cells, sigma_yaw rad)`` a ray crosses only the cells it
    leaves by its :func:`naive_clear_limits` limit when that is short of its reach (a return's hit is placed all
    the same); every cell the scan touched gets one update, ``hit`` where at least as many rays returned in it as
    crossed it, else ``miss``, clamped; returns a new float32 grid."""
    crossed = np.zeros(log_odds.shape, np.int64)
    returned = np.zeros(log_odds.shape, np.int64)
    n_rows, n_cols = log_odds.shape
    ranges_cells = np.asarray(ranges_cells, np.float64)
    reach = np.where(np.isfinite(ranges_cells), ranges_cells + hit_shift + 1e-6, min(max_t, usable_t))
    limits = np.full(reach.size, np.inf)
    if pose_sigmas is not None:
        found = naive_clear_limits(angles, reach, pose_sigmas[0], pose_sigmas[1], sigmas)
        limits = np.where(found < reach, found, np.inf)
    for angle, distance, limit in zip(angles, ranges_cells, limits):
        cells = [(0.0, int(np.floor(y0)), int(np.floor(x0)))] + _naive_cells_along_ray(n_rows, n_cols, y0, x0, angle)
        if not np.isfinite(distance):
            for k, (t_in, r, c) in enumerate(cells):
                if t_in > min(max_t, usable_t) or not (0 <= r < n_rows and 0 <= c < n_cols) or \
                        log_odds[r, c] >= stop_at:
                    break
                if (cells[k + 1][0] if k + 1 < len(cells) else np.inf) > limit:
                    break
                crossed[r, c] += 1
            continue
        shifted = distance + hit_shift
        walk = max(max_t, shifted + 1e-6) if hit_shift > 0.0 else max_t
        if not np.isfinite(limit):
            ray_free, ray_hit = naive_mark_ranges(log_odds.shape, y0, x0, [angle], [shifted], walk)
            crossed += ray_free
            returned += ray_hit
            continue
        for k, (t_in, r, c) in enumerate(cells):  # naive_mark_ranges, crossing only the cells left by the limit
            if t_in > walk or not (0 <= r < n_rows and 0 <= c < n_cols):
                break
            t_out = cells[k + 1][0] if k + 1 < len(cells) else np.inf
            if t_out > shifted + 1e-6:
                returned[r, c] += 1
                break
            crossed[r, c] += t_out <= limit
    out = log_odds.copy()
    for r, c in np.argwhere((crossed > 0) | (returned > 0)):
        delta = hit if returned[r, c] > 0 and returned[r, c] >= crossed[r, c] else miss
        out[r, c] = np.float32(min(max(float(out[r, c]) + delta, lowest), highest))
    return out


# --- onboard.scan_matching ---


def naive_score_poses(field, rho, angles, y0, x0, yaw, offsets):
    """onboard.scan_matching._score_poses, one return at a time: each return placed from each candidate pose in the
    grid's (y down, x right) cells, the field read by bilinear interpolation between the four surrounding cell
    centres (0 where they are not all inside the grid), averaged over the returns."""
    n_rows, n_cols = field.shape
    scores = []
    for dy, dx, dyaw in offsets:
        values = []
        for r, a in zip(rho, angles):
            heading = yaw + dyaw + a
            y = y0 + dy - r * np.sin(heading)  # map y up, rows down
            x = x0 + dx + r * np.cos(heading)
            u, v = y - 0.5, x - 0.5  # cell centres at half-integers
            i, j = int(np.floor(u)), int(np.floor(v))
            if not (0 <= i and 0 <= j and i + 1 < n_rows and j + 1 < n_cols):
                values.append(0.0)
                continue
            wu, wv = u - i, v - j
            corners = [(i, j, (1 - wu) * (1 - wv)), (i, j + 1, (1 - wu) * wv), (i + 1, j, wu * (1 - wv)),
                       (i + 1, j + 1, wu * wv)]
            values.append(sum(w * field[a_, b_] for a_, b_, w in corners))
        scores.append(float(np.mean(values)))
    return np.array(scores)


# --- expected visibility ---


def naive_expected_gain(mean, observed, groups, n_rays, max_t, min_transmittance=0.0, variance=None):
    """Expected unknown cells seen from each group of viewpoint cells (expected_visibility.expected_visible_gains),
    from a sorted list of every grid-line crossing per ray (no DDA stepping): along each ray the transmittance
    before a cell is 1 - max(p) over the cells crossed (p = mean on unknown cells, 0 on known free, 1 on known
    walls); a group's cell counts once with the largest transmittance of any ray of any viewpoint."""
    n_rows, n_cols = mean.shape
    variance = np.zeros(mean.shape) if variance is None else variance
    out, out_variance = [], []
    for group in groups:
        best = {}
        for r0, c0 in group:
            if observed[r0, c0] == 1:
                continue
            if observed[r0, c0] == -1:
                best[(r0, c0)] = 1.0
            for k in range(n_rays):
                angle = 2.0 * np.pi * k / n_rays
                crossed = []
                transmittance = 1.0
                for t, r, c in _naive_cells_along_ray(n_rows, n_cols, r0 + 0.5, c0 + 0.5, angle):
                    if t >= max_t or not (0 <= r < n_rows and 0 <= c < n_cols) or observed[r, c] == 1:
                        break
                    if observed[r, c] == -1:
                        best[(r, c)] = max(best.get((r, c), 0.0), transmittance)
                        crossed.append(float(mean[r, c]))
                        transmittance = 1.0 - max(crossed)
                    if transmittance <= min_transmittance:
                        break
        out.append(sum(best.values()))
        out_variance.append(sum(value * float(variance[cell]) for cell, value in best.items()))
    return np.array(out), np.array(out_variance)


def brute_force_expected_visible(mean, observed, viewpoint, n_rays, max_t):
    """The exact expected number of unknown cells seen from ``viewpoint``: every unknown cell with 0 < p < 1 is
    a wall or not, independently; for each of the 2^k configurations (weight: the product of p or 1 - p) the
    same rays are cast on the binary map (a ray sees every cell it enters up to and including the first wall)
    and the unknown cells seen by at least one ray are counted; returns the weighted mean (over the
    configurations where the viewpoint is free: the robot stands there)."""
    from itertools import product

    n_rows, n_cols = mean.shape
    unknown = observed == -1
    uncertain = [tuple(cell) for cell in np.argwhere(unknown & (mean > 0.0) & (mean < 1.0))]
    rays = [_naive_cells_along_ray(n_rows, n_cols, viewpoint[0] + 0.5, viewpoint[1] + 0.5, 2.0 * np.pi * k / n_rays)
            for k in range(n_rays)]
    expected, total = 0.0, 0.0
    for config in product((False, True), repeat=len(uncertain)):
        walls = (observed == 1) | (unknown & (mean >= 1.0))
        weight = 1.0
        for cell, wall in zip(uncertain, config):
            walls[cell] = wall
            weight *= float(mean[cell]) if wall else 1.0 - float(mean[cell])
        if walls[viewpoint]:  # the robot stands in a free cell: the configurations with a wall there are excluded
            continue
        total += weight
        seen = np.zeros(mean.shape, bool)
        seen[viewpoint] = True
        for cells in rays:
            for t, r, c in cells:
                if t >= max_t or not (0 <= r < n_rows and 0 <= c < n_cols):
                    break
                seen[r, c] = True
                if walls[r, c]:
                    break
        expected += weight * np.count_nonzero(seen & unknown)
    return expected / total


# --- goal choice references (the code before the batched kernels, kept callable) ---


def naive_descend(travel_cost, goal_rc):
    """The SuperEx planner's descent as first written (planners.superex.descend before _descend_paths): from the
    goal, step to the least-cost cell of the clipped 3 x 3 window (np.argmin: the first in row-major order)
    until cost 0 or no lower neighbour; returns the cells from the robot's end."""
    r, c = int(goal_rc[0]), int(goal_rc[1])
    if not np.isfinite(travel_cost[r, c]):
        raise ValueError(f"goal {(r, c)} is unreachable (infinite travel cost)")
    path = [(r, c)]
    while travel_cost[r, c] > 0.0:
        window = travel_cost[max(r - 1, 0):r + 2, max(c - 1, 0):c + 2]
        k = int(np.argmin(window))
        nr, nc = max(r - 1, 0) + k // window.shape[1], max(c - 1, 0) + k % window.shape[1]
        if travel_cost[nr, nc] >= travel_cost[r, c]:
            break
        r, c = nr, nc
        path.append((r, c))
    return path[::-1]


def reference_visible_gains(prediction, observed, cells_rc, cfg, resolution_m):
    """visibility.visible_gains as first written (one cast and one fill per viewpoint, from Python), the slow
    twin of visibility._grouped_gains without union."""
    from superex_deploy.onboard.planning.visibility import _NO_STAMP, _fill_visibility, ray_visible_ranges

    cells = np.asarray(cells_rc, np.int64).reshape(-1, 2)
    observed = np.ascontiguousarray(observed)
    counts = np.zeros(len(cells), np.int64)
    var_sums = np.zeros(len(cells), np.float64)
    ranges = np.empty(cfg.n_rays, np.float64)
    no_mask = np.zeros((1, 1), bool)
    max_t = cfg.range_m / float(resolution_m)
    for i, (r, c) in enumerate(cells):
        ray_visible_ranges(prediction.mean, r + 0.5, c + 0.5, cfg.n_rays, max_t, cfg.hit_threshold, cfg.accumulate,
                           ranges)
        counts[i], var_sums[i] = _fill_visibility(ranges, r + 0.5, c + 0.5, observed, prediction.variance, no_mask,
                                                  False, _NO_STAMP, -1)
    return counts, var_sums


def reference_union_visible_unknown(mean, observed, viewpoints, cfg, resolution_m):
    """visibility.union_visible_unknown as first written (a dict of casts, one fill per viewpoint and group, from
    Python), the slow twin of visibility._grouped_gains with union."""
    from superex_deploy.onboard.planning.visibility import _fill_visibility, ray_visible_ranges

    observed = np.ascontiguousarray(observed)
    max_t = cfg.range_m / float(resolution_m)
    stamp = np.full(mean.shape, -1, np.int32)
    no_variance = np.zeros(mean.shape, np.float32)
    no_mask = np.zeros((1, 1), bool)
    cast: dict = {}
    out = np.zeros(len(viewpoints), np.int64)
    for label, group in enumerate(viewpoints):
        for (r, c) in np.asarray(group, np.int64).reshape(-1, 2):
            key = (int(r), int(c))
            if key not in cast:
                ranges = np.empty(cfg.n_rays, np.float64)
                ray_visible_ranges(mean, r + 0.5, c + 0.5, cfg.n_rays, max_t, cfg.hit_threshold, cfg.accumulate,
                                   ranges)
                cast[key] = ranges
            count, _ = _fill_visibility(cast[key], r + 0.5, c + 0.5, observed, no_variance, no_mask, False, stamp,
                                        label)
            out[label] += count
    return out


def reference_superex_gains(planner, ctx, prediction, frontiers):
    """SuperexPlanner.gains for ``gain="path"`` as first written: a Python descent per frontier, then the
    reference union."""
    from superex_deploy.onboard.planning.visibility import VisibilityConfig

    cfg = planner.cfg
    every = max(1, int(round(cfg.sense_every_m / ctx.resolution_m)))
    viewpoints = []
    for frontier in frontiers:
        path = naive_descend(ctx.travel_cost, frontier.cell_rc)
        viewpoints.append([path[k] for k in list(range(every, len(path) - 1, every)) + [len(path) - 1]])
    visibility = VisibilityConfig(n_rays=cfg.n_rays, range_m=cfg.range_m, hit_threshold=cfg.wall_threshold)
    return reference_union_visible_unknown(prediction.mean, ctx.observed, viewpoints, visibility,
                                           ctx.resolution_m).astype(float)


def naive_pool_observed(observed, k):
    """onboard.prediction.scale.pool_observed before scikit-image's block_reduce: the map padded with UNKNOWN to
    whole blocks, viewed as ``[H/k, k, W/k, k]``; a wall where any cell is one, unknown where all are, else free."""
    rows, cols = -(-observed.shape[0] // k) * k, -(-observed.shape[1] // k) * k
    padded = np.full((rows, cols), -1, np.int8)
    padded[:observed.shape[0], :observed.shape[1]] = observed
    blocks = padded.reshape(rows // k, k, cols // k, k)
    wall = (blocks == 1).any(axis=(1, 3))
    unknown = (blocks == -1).all(axis=(1, 3))
    return np.where(wall, 1, np.where(unknown, -1, 0)).astype(np.int8)


def naive_pool_prediction(mean, variance, u):
    """onboard.prediction.scale.pool_prediction before scikit-image's block_reduce: float64 ``[H u, W u]`` maps
    viewed as ``[H, u, W, u]``; each block's mean, and its variance as one mixture."""
    rows, cols = mean.shape[0] // u, mean.shape[1] // u
    mean = np.asarray(mean, np.float64).reshape(rows, u, cols, u)
    variance = np.asarray(variance, np.float64).reshape(rows, u, cols, u)
    pooled = mean.mean(axis=(1, 3))
    spread = variance.mean(axis=(1, 3)) + mean.var(axis=(1, 3))
    return pooled.astype(np.float32), spread.astype(np.float32)


def naive_pool_mean(values, k):
    """onboard.prediction.scale._block_means with numpy: the map padded to whole blocks, each block's sum over the
    cells it has divided by their count."""
    values = np.asarray(values, np.float64)
    rows, cols = -(-values.shape[0] // k) * k, -(-values.shape[1] // k) * k
    padded, ones = np.zeros((rows, cols)), np.zeros((rows, cols))
    padded[:values.shape[0], :values.shape[1]] = values
    ones[:values.shape[0], :values.shape[1]] = 1.0
    sums = padded.reshape(rows // k, k, cols // k, k).sum(axis=(1, 3))
    counts = ones.reshape(rows // k, k, cols // k, k).sum(axis=(1, 3))
    return sums / counts


def naive_coarsen(observed, k):
    """onboard.mapping.blocks._coarsen block by block: a wall where any cell is one, else free where any cell is
    free, else unknown."""
    rows, cols = observed.shape
    out = np.empty((-(-rows // k), -(-cols // k)), np.int8)
    for r in range(out.shape[0]):
        for c in range(out.shape[1]):
            block = observed[r * k:(r + 1) * k, c * k:(c + 1) * k]
            out[r, c] = 1 if (block == 1).any() else (0 if (block == 0).any() else -1)
    return out


def naive_pool_mixture(mean, variance, k):
    """onboard.planning.coarse._pool_mixture: per block, the mean of the means and the mixture's variance."""
    mean, variance = np.asarray(mean, np.float64), np.asarray(variance, np.float64)
    out_mean = naive_pool_mean(mean, k)
    second = naive_pool_mean(variance + mean * mean, k)
    return out_mean, np.maximum(second - out_mean ** 2, 0.0)


def naive_in_frame(message, frame):
    """messages.OccupancyGridMessage.in_frame cell by cell: the frame cell holding each message cell's centre takes
    the largest of their values; a frame cell that holds none, the message cell under its own centre; else -1."""
    height, width = frame.shape
    out = np.full((height, width), -1, np.int16)
    hit = np.zeros((height, width), bool)
    grid = np.asarray(message.data).reshape(message.height, message.width)  # row 0 at the bottom
    res_f, res_m = frame.resolution_m, message.resolution_m
    (fx, fy), (mx, my) = frame.origin_xy, message.origin_xy
    for j in range(message.height):
        for i in range(message.width):
            c = int(np.floor((mx + (i + 0.5) * res_m - fx) / res_f))
            r = int(np.floor((my + (j + 0.5) * res_m - fy) / res_f))
            if 0 <= c < width and 0 <= r < height:
                top = height - 1 - r
                out[top, c] = max(out[top, c], grid[j, i]) if hit[top, c] else grid[j, i]
                hit[top, c] = True
    for top in range(height):
        for c in range(width):
            if hit[top, c]:
                continue
            i = int(np.floor((fx + (c + 0.5) * res_f - mx) / res_m))
            j = int(np.floor((fy + (height - 1 - top + 0.5) * res_f - my) / res_m))
            if 0 <= i < message.width and 0 <= j < message.height:
                out[top, c] = grid[j, i]
    return out.astype(np.int8)


# --- ros.tf (transforms as 4 x 4 matrices, rotations by Rodrigues' formula, the tree walked from the root) ---


def naive_rotation_matrix(q):
    """ros.tf.Transform.matrix's rotation: the unit quaternion ``(x, y, z, w)`` as an axis and an angle, turned into a
    3 x 3 matrix by Rodrigues' formula."""
    q = np.asarray(q, np.float64) / np.linalg.norm(q)
    s = np.linalg.norm(q[:3])
    if s == 0.0:
        return np.eye(3)
    ax, ay, az = q[:3] / s
    angle = 2.0 * np.arctan2(s, q[3])
    k = np.array([[0.0, -az, ay], [az, 0.0, -ax], [-ay, ax, 0.0]])
    return np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)


def naive_quaternion_product(a, b):
    """The quaternion ``a b`` in ``(x, y, z, w)`` order: the 4 x 4 left-multiplication matrix of ``a`` times ``b``."""
    x, y, z, w = a
    left = np.array([[w, -z, y, x], [z, w, -x, y], [-y, x, w, z], [-x, -y, -z, w]])
    return left @ np.asarray(b, np.float64)


def naive_slerp(q1, q2, ratio):
    """ros.tf.Transform.interpolate's rotation: ``q1`` turned by ``ratio`` of the relative rotation
    ``conj(q1) q2``, whose angle is taken in [0, pi] (the shorter arc), about the same axis."""
    q1 = np.asarray(q1, np.float64) / np.linalg.norm(q1)
    q2 = np.asarray(q2, np.float64) / np.linalg.norm(q2)
    relative = naive_quaternion_product(q1 * np.array([-1.0, -1.0, -1.0, 1.0]), q2)
    if relative[3] < 0.0:
        relative = -relative
    s = np.linalg.norm(relative[:3])
    if s == 0.0:
        return q1
    angle = 2.0 * np.arctan2(s, relative[3]) * ratio
    step = np.append(relative[:3] / s * np.sin(angle / 2.0), np.cos(angle / 2.0))
    return naive_quaternion_product(q1, step)


def naive_link_matrix(samples, stamp):
    """One link of ros.tf.TfBuffer at ``stamp``: ``samples`` is a list of ``(stamp, translation, quaternion)``; the
    sample at the stamp, else the two around it interpolated (translation lerp, :func:`naive_slerp`), as a 4 x 4."""
    samples = sorted(samples, key=lambda sample: sample[0])
    out = np.eye(4)
    for k, (t0, p0, q0) in enumerate(samples):
        if t0 == stamp or len(samples) == 1:
            out[:3, :3], out[:3, 3] = naive_rotation_matrix(q0), p0
            return out
        t1, p1, q1 = samples[k + 1]
        if t0 < stamp < t1:
            ratio = (stamp - t0) / (t1 - t0)
            out[:3, :3] = naive_rotation_matrix(naive_slerp(q0, q1, ratio))
            out[:3, 3] = (1.0 - ratio) * np.asarray(p0, np.float64) + ratio * np.asarray(p1, np.float64)
            return out
    raise ValueError(f"no sample around {stamp}")


def naive_lookup(links, target, source, stamp):
    """ros.tf.TfBuffer.lookup on a fixed tree: ``links`` maps each child to ``(parent, samples)`` (samples as
    :func:`naive_link_matrix` takes them; one sample for a static link); every frame's pose in its root is the
    product of its links' matrices from the root down, and the result is ``inv(target's) @ source's`` (4 x 4)."""
    def in_root(frame):
        pose = np.eye(4)
        while frame in links:
            parent, samples = links[frame]
            pose = naive_link_matrix(samples, stamp) @ pose
            frame = parent
        return pose
    return np.linalg.inv(in_root(target)) @ in_root(source)

