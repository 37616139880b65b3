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
