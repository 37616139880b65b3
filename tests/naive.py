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

# --- spad ---

# --- nlos ---

# --- explore ---

# explore: planners


def _naive_cells_along_ray(n_rows, n_cols, y0, x0, angle, max_t):
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


def naive_visible_ranges(mean, y0, x0, n_rays, max_t, hit_threshold):
    """Per-ray visible range of the probabilistic raycast (planners._ray_visible_ranges)."""
    n_rows, n_cols = mean.shape
    ranges = np.empty(n_rays)
    for k in range(n_rays):
        angle = 2.0 * np.pi * k / n_rays
        blocked = float(mean[int(np.floor(y0)), int(np.floor(x0))])
        if blocked >= hit_threshold:
            ranges[k] = 0.5
            continue
        transmittance = 1.0 - blocked
        reach = max_t
        for t, r, c in _naive_cells_along_ray(n_rows, n_cols, y0, x0, angle, max_t):
            if t >= max_t:
                break
            if not (0 <= r < n_rows and 0 <= c < n_cols):
                reach = t
                break
            transmittance *= 1.0 - float(mean[r, c])
            if 1.0 - transmittance >= hit_threshold:
                reach = min(t + 0.5, max_t)
                break
        ranges[k] = reach
    return ranges


def naive_fill_visibility(ranges, y0, x0, observed, variance):
    """Visible mask, visible-unknown count and variance sum by testing every cell (planners._fill_visibility)."""
    n_rays = len(ranges)
    visible = np.zeros(observed.shape, bool)
    step = 2.0 * np.pi / n_rays
    for r in range(observed.shape[0]):
        for c in range(observed.shape[1]):
            vy, vx = r + 0.5 - y0, c + 0.5 - x0
            rho = np.hypot(vy, vx)
            phi = np.arctan2(vy, vx) % (2.0 * np.pi)
            k0 = int(np.floor(phi / step)) % n_rays
            k1 = (k0 + 1) % n_rays
            visible[r, c] = rho <= max(ranges) and (rho <= min(ranges[k0], ranges[k1]) or rho < 0.75)
    unknown = visible & (observed == -1)
    return visible, int(unknown.sum()), float(variance[unknown].astype(np.float64).sum())


def naive_grow_rrt(traversable, start_y, start_x, samples, expand_cells):
    """Pure-Python RRT with the same steering and collision rule as planners._grow_rrt."""

    def segment_free(y0, x0, y1, x1):
        n = int(np.ceil(np.hypot(y1 - y0, x1 - x0) / 0.5)) + 1
        return all(traversable[int(np.floor(y0 + i / n * (y1 - y0))), int(np.floor(x0 + i / n * (x1 - x0)))]
                   for i in range(n + 1))

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
    return np.array(nodes), np.array(parents), np.array(depths)
