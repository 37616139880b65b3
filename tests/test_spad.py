import numpy as np
import pytest

from superex_deploy.geometry import cast_rays, ray_angles
from superex_deploy.maps import OccupancyGrid
from superex_deploy.sim.spad import fans as spad_fans, simulate as spad_simulate
from superex_deploy.spad_types import SPEED_OF_LIGHT, SpadConfig, SpadNoise, SparseHistograms
from superex_deploy.sim.spad import BLOCK_CELLS, FAN_OFFSET_CELLS, prepare_scene, simulate_scan
from superex_deploy.sim.spad.fans import _sort_paths, trace_fans
from superex_deploy.sim.spad.scene import _thin_wall_normals
from superex_deploy.sim.spad.tracer import cast_primaries, trace_first_hit_blocks
from tests.naive import naive_first_hit, naive_simulate_histograms, naive_sort_paths, naive_thin_wall_normals

RES = 0.1


def _grid(walls):
    return OccupancyGrid(walls, ~walls, RES, "test")


def _corridor():
    """60x60: horizontal walls at rows 20 and 40; the robot at (30, 30) between them."""
    walls = np.zeros((60, 60), bool)
    walls[20, :] = walls[40, :] = True
    return _grid(walls)


def _ray_index(cfg, angle):
    return int(round(angle / (2 * np.pi) * cfg.n_rays)) % cfg.n_rays


def test_corridor_direct_count_is_eq1_and_late_peak_lands_in_the_analytic_bin():
    cfg = SpadConfig(n_rays=360, n_secondary=64)
    scan = simulate_scan(_corridor(), (30, 30), cfg)
    up = _ray_index(cfg, 1.5 * np.pi)
    d1 = (30.5 - 21.0) * RES  # to the bottom face of row 20
    b1 = int(2 * d1 / cfg.bin_path_m)
    hist = scan.histograms[up].astype(np.float64)
    assert hist[b1] == pytest.approx(cfg.direct_counts, rel=1e-6)
    assert cfg.direct_counts == pytest.approx(
        cfg.detector_efficiency * cfg.pulse_energy_j * cfg.reflectance / np.pi * cfg.wavelength_m
        / (6.62607015e-34 * 299792458.0), rel=1e-12)
    assert not hist[:b1].any()
    # The fan leaves X1 = (21, 30.5); its nearest hit is the opposite wall (entry y = 40), 19 cells away, along
    # the secondary ray closest to the normal (1.4 degrees off with 64 rays).
    d2 = 19.0 * RES / np.cos(0.5 * np.pi / cfg.n_secondary)
    expected = int((2 * d1 + 2 * d2) / cfg.bin_path_m)
    late = np.flatnonzero(hist[b1 + 1:]) + b1 + 1
    assert abs(late[0] - expected) <= 1
    assert np.argmax(hist[b1 + 1:]) + b1 + 1 in range(expected - 1, expected + 2)


def test_l_corner_hidden_wall_appears_at_its_analytic_bin():
    """Robot in a corridor (rows 45-55) ending at a wall at col 40; a side corridor (cols 30-39) leads north to a
    hidden wall at row 9, out of the robot's sight. A secondary ray from the end wall travels up the side corridor
    to the hidden wall."""
    walls = np.ones((70, 60), bool)
    walls[45:56, 1:40] = False
    walls[10:45, 30:40] = False
    grid = _grid(walls)
    cfg = SpadConfig(n_rays=720, n_secondary=128)
    scan = simulate_scan(grid, (48, 10), cfg)
    ray = _ray_index(cfg, 0.0)
    assert tuple(scan.truth.h1_rc[ray]) == (48, 40)
    d1 = (40.0 - 10.5) * RES
    b1 = int(2 * d1 / cfg.bin_path_m)
    assert scan.histograms[ray, b1] == pytest.approx(cfg.direct_counts, rel=1e-6)
    # Secondary k = 0 leaves X1 = (48.5, 40) at phi = -90 + 0.703 degrees about the normal (0, -1): nearly north.
    phi = -0.5 * np.pi + 0.5 * np.pi / cfg.n_secondary
    dy, dx = np.sin(phi), -np.cos(phi)
    origin = np.array([48.5, 40.0 - FAN_OFFSET_CELLS])
    t = (origin[0] - 10.0) / -dy
    hit = origin + t * np.array([dy, dx])
    assert 30 <= hit[1] < 40  # it stays in the side corridor up to the hidden wall
    d2 = np.hypot(*(hit - [48.5, 40.0])) * RES
    expected = int((2 * d1 + 2 * d2) / cfg.bin_path_m)
    assert scan.histograms[ray, expected - 1:expected + 2].max() > 0
    hidden = scan.truth.h2_rc[(scan.truth.h2_ray == ray) & (scan.truth.h2_counts > 0)]
    assert np.any(hidden[:, 0] == 9)
    # The robot's own line of sight never reaches row 9.
    assert not np.any(scan.truth.h1_rc[:, 0] == 9)


def test_thin_wall_normals_match_naive():
    rng = np.random.default_rng(0)
    for _ in range(10):
        occupied = rng.random((15, 17)) < 0.3
        weak = occupied & (rng.random(occupied.shape) < 0.5)
        normals = np.zeros(occupied.shape + (2,))
        _thin_wall_normals(occupied, weak, normals)
        reference = naive_thin_wall_normals(occupied, weak)
        dots = np.abs(np.sum(normals * reference, axis=2))
        defined = np.any(reference != 0, axis=2)
        np.testing.assert_allclose(dots[defined], 1.0, atol=1e-6)  # same axis, sign is free
        assert not np.any(normals[~defined])


def test_thin_vertical_wall_gets_horizontal_normal():
    walls = np.zeros((12, 12), bool)
    walls[:, 6] = True
    scene = prepare_scene(_grid(walls))
    assert scene.two_sided[5, 6]
    np.testing.assert_allclose(np.abs(scene.normals[5, 6]), [0.0, 1.0], atol=1e-9)


def _rooms(rng, shape, n_walls):
    """Random axis-aligned and diagonal wall segments in a walled box: long open stretches (wall-free blocks)
    next to walled blocks."""
    walls = np.zeros(shape, bool)
    walls[[0, -1], :] = walls[:, [0, -1]] = True
    for _ in range(n_walls):
        r, c = rng.integers(0, shape[0]), rng.integers(0, shape[1])
        length = rng.integers(3, max(shape) // 2)
        dr, dc = [(0, 1), (1, 0), (1, 1), (1, -1)][rng.integers(4)]
        for k in range(length):
            if 0 <= r + k * dr < shape[0] and 0 <= c + k * dc < shape[1]:
                walls[r + k * dr, c + k * dc] = True
    return walls


@pytest.mark.parametrize("seed", range(6))
def test_block_tracer_matches_naive_first_hit(seed):
    """Hit cell, entry axis and entry distance of the two-level tracer equal the exact DDA's, through wall-free
    blocks, walled blocks, grid edges that cut blocks (shapes not multiples of 4) and short ranges."""
    rng = np.random.default_rng(seed)
    shape = (int(rng.integers(9, 40)), int(rng.integers(9, 40)))
    walls = _rooms(rng, shape, n_walls=int(rng.integers(0, 6))) if seed % 3 else rng.random(shape) < 0.04
    if seed == 5:
        walls[:] = False  # no wall at all: every ray leaves the grid
    scene = prepare_scene(_grid(walls))
    assert scene.wall_blocks.shape == (-(-shape[0] // BLOCK_CELLS), -(-shape[1] // BLOCK_CELLS))
    assert (~scene.wall_blocks).any() or walls.mean() > 0.2
    free = np.argwhere(~walls)
    for _ in range(150):
        r, c = free[rng.integers(len(free))]
        y0, x0 = r + rng.random(), c + rng.random()
        angle = rng.uniform(0, 2 * np.pi) if rng.random() < 0.9 else rng.integers(4) * np.pi / 2
        max_t = rng.uniform(1.0, 60.0)
        expected = naive_first_hit(walls, y0, x0, angle, max_t)
        got = trace_first_hit_blocks(scene.cell_kind, scene.wall_blocks, y0, x0, np.sin(angle), np.cos(angle),
                                     max_t)
        assert got[:2] == expected[:2]
        if expected[0] >= 0:
            assert got[3] == expected[3]
            assert got[2] == pytest.approx(expected[2], abs=1e-9)
    # A start inside a wall is a hit at distance 0.
    wall = np.argwhere(walls)
    if len(wall):
        r, c = wall[0]
        assert trace_first_hit_blocks(scene.cell_kind, scene.wall_blocks, r + 0.5, c + 0.5, 0.6, 0.8, 10.0) == (
            r, c, 0.0, -1)


@pytest.mark.parametrize("n_parts", [1, 2, 5])
def test_cast_primaries_match_geometry_cast_rays(n_parts):
    rng = np.random.default_rng(11)
    walls = _rooms(rng, (57, 83), n_walls=12)
    scene = prepare_scene(_grid(walls))
    free = np.argwhere(~walls)
    angles = ray_angles(997, offset_rad=0.123)
    for r, c in free[rng.choice(len(free), 5, replace=False)]:
        origin = (r + 0.5, c + 0.5)
        reference = cast_rays(walls, origin, angles, 45.0)
        hit_rc = np.empty((len(angles), 2), np.int32)
        distance = np.empty(len(angles))
        entry_axis = np.empty(len(angles), np.int8)
        direction = np.empty((len(angles), 2))
        cast_primaries(scene.cell_kind, scene.wall_blocks, origin[0], origin[1], angles, 45.0, hit_rc, distance,
                       entry_axis, direction, n_parts)
        np.testing.assert_array_equal(hit_rc, reference.hit_rc)
        np.testing.assert_array_equal(entry_axis, reference.entry_axis)
        hit = reference.hit_mask
        np.testing.assert_allclose(distance[hit], reference.distance_cells[hit], atol=1e-9)
        np.testing.assert_allclose(direction, np.stack([np.sin(angles), np.cos(angles)], axis=1), atol=1e-15)


@pytest.mark.parametrize("bin_path_m", [0.1, 0.45])  # 0.45 m: the direct and late photons share bins
@pytest.mark.parametrize("seed", range(6))
def test_simulate_scan_matches_naive_on_small_random_grids(seed, bin_path_m):
    rng = np.random.default_rng(seed)
    if seed >= 4:  # sparse rooms: fans cross wall-free blocks
        walls = _rooms(rng, (26, 30), n_walls=4)
    else:
        walls = rng.random((20, 20)) < 0.12
    walls[[0, -1], :] = walls[:, [0, -1]] = True
    free = np.argwhere(~walls)
    pose = tuple(free[rng.integers(len(free))])
    grid = _grid(walls)
    scene = prepare_scene(grid)
    if seed >= 4:
        assert (~scene.wall_blocks).sum() >= 4
    # 47 primaries and an even fan: no exact diagonals from a cell centre or a 45-degree wall corner, where
    # float rounding (not geometry) breaks the tie.
    cfg = SpadConfig(n_rays=47, n_secondary=12, range_m=3.0, bin_width_s=bin_path_m / SPEED_OF_LIGHT)
    scan = simulate_scan(grid, pose, cfg)
    reference = naive_simulate_histograms(scene, pose, cfg)
    # Same photons per ray; a path may only move to a neighbouring bin: with 0.1 m cells and 0.1 m bins, grid
    # paths often end exactly on a bin edge, where the two methods' rounding decides.
    actual = scan.histograms.astype(np.float64)
    np.testing.assert_allclose(actual.sum(axis=1), reference.sum(axis=1), rtol=2e-6)
    cum, ref_cum = np.cumsum(actual, axis=1), np.cumsum(reference, axis=1)
    lower = np.concatenate([np.zeros((cfg.n_rays, 1)), ref_cum[:, :-1]], axis=1)
    upper = np.concatenate([ref_cum[:, 1:], ref_cum[:, -1:]], axis=1)
    slack = 2e-6 * ref_cum[:, -1:]
    assert np.all(cum >= lower - slack) and np.all(cum <= upper + slack)
    assert np.mean(np.isclose(actual, reference, rtol=2e-6, atol=0)) > 0.99


def _random_rooms_and_walk(seed, shape=(60, 70), steps=12):
    """A random room map and a random walk of free cells through it (neighbouring cells, as an episode)."""
    rng = np.random.default_rng(seed)
    walls = _rooms(rng, shape, n_walls=6)
    walls[[0, -1], :] = walls[:, [0, -1]] = True
    free = np.argwhere(~walls)
    pose = free[rng.integers(len(free))]
    walk = [tuple(pose)]
    while len(walk) < steps:
        step = pose + rng.integers(-1, 2, size=2)
        if not walls[tuple(step)]:
            pose = step
            walk.append(tuple(pose))
    return _grid(walls), walk


def _assert_same_scan(a, b):
    for name in ("row_start", "bins", "counts"):
        np.testing.assert_array_equal(getattr(a.sparse, name), getattr(b.sparse, name))
    for name in ("h1_rc", "d1_m", "normal1", "cos1", "ray_fan", "fan_h2_rc", "fan_d2_m", "fan_cos2"):
        np.testing.assert_array_equal(getattr(a.truth, name), getattr(b.truth, name))


@pytest.mark.parametrize("seed", range(3))
def test_cached_fans_give_the_same_scans_as_fresh_ones(seed):
    """Scans along a walk reuse the fans earlier scans traced: every scan equals the one traced from scratch."""
    grid, walk = _random_rooms_and_walk(seed)
    cfg = SpadConfig(n_rays=240, n_secondary=24, range_m=5.0)
    scene = prepare_scene(grid)
    cached = [simulate_scan(grid, pose, cfg) for pose in walk]
    cache = scene.fan_cache(cfg.n_secondary, cfg.range_m / RES)
    assert cache.reused > cache.traced > 0  # most fans of a walk are seen again
    for pose, scan in zip(walk, cached):
        scene.clear_fan_caches()
        _assert_same_scan(scan, simulate_scan(grid, pose, cfg))
        # Sparse rows: bins strictly increasing within a ray, every stored count positive.
        sparse = scan.sparse
        rays = np.repeat(np.arange(sparse.n_rays), np.diff(sparse.row_start))
        assert np.all((np.diff(sparse.bins) > 0) | (np.diff(rays) > 0))
        assert np.all(sparse.counts > 0) and sparse.bins.min() >= 0 and sparse.bins.max() < sparse.n_bins


def test_fan_cache_restarts_within_its_size_and_earlier_truth_stays_valid(monkeypatch):
    grid, walk = _random_rooms_and_walk(3, steps=20)
    cfg = SpadConfig(n_rays=240, n_secondary=24, range_m=5.0)
    fresh = []
    for pose in walk:
        prepare_scene(grid).clear_fan_caches()
        fresh.append(simulate_scan(grid, pose, cfg))
    prepare_scene(grid).clear_fan_caches()
    # Room for a few more fans than one scan has: the cache restarts along the walk.
    n_fans = max(len(scan.truth.fan_rows) for scan in fresh)
    monkeypatch.setattr(spad_fans, "MAX_CACHED_FAN_BYTES", (n_fans + 3) * (cfg.n_secondary * 5 * 8 + 8))
    scans = [simulate_scan(grid, pose, cfg) for pose in walk]
    cache = prepare_scene(grid).fan_cache(cfg.n_secondary, cfg.range_m / RES)
    assert cache.restarts >= 2 and cache.reused > 0
    # A cache smaller than one scan restarts at every scan that needs a new fan and still gives the same scans.
    prepare_scene(grid).clear_fan_caches()
    monkeypatch.setattr(spad_fans, "MAX_CACHED_FAN_BYTES", n_fans // 3 * (cfg.n_secondary * 5 * 8 + 8))
    for pose, reference in zip(walk, fresh):
        _assert_same_scan(simulate_scan(grid, pose, cfg), reference)
    for scan, reference in zip(scans, fresh):  # truth read after later scans restarted the cache
        _assert_same_scan(scan, reference)


def test_a_scanned_grid_goes_with_its_scene_and_fan_caches():
    """The scenes are cached for their grid's lifetime only: a scene that held its grid strongly kept every grid
    ever scanned, and its fan caches (up to MAX_CACHED_FAN_BYTES each), alive for the whole process."""
    import gc
    import weakref

    from superex_deploy.sim.spad import scene as spad_scene

    grid = _corridor()
    scan = simulate_scan(grid, (30, 30), SpadConfig(n_rays=90, n_secondary=16))
    scene = prepare_scene(grid)
    assert scene.fan_caches and scene.grid.shape == grid.shape and scene.grid.occupied is grid.occupied
    gone, scenes_before = weakref.ref(grid), len(spad_scene._SCENES)
    del grid, scene
    gc.collect()
    assert gone() is None and len(spad_scene._SCENES) == scenes_before - 1
    assert scan.histograms.any()  # the scan keeps what it was taken with


def test_fan_tracing_does_not_depend_on_the_thread_split():
    grid, walk = _random_rooms_and_walk(4)
    cfg = SpadConfig(n_rays=240, n_secondary=24, range_m=5.0)
    scan = simulate_scan(grid, walk[0], cfg)
    scene = prepare_scene(grid)
    fans = scan.truth.fan_rows.shape[0]
    # The fans' cells and normals, recovered from the truth: each fan's first ray.
    first_ray = np.array([np.flatnonzero(scan.truth.ray_fan == u)[0] for u in range(fans)])
    cells = scan.truth.h1_rc[first_ray].astype(np.int64)
    normals = scan.truth.normal1[first_ray]
    outputs = []
    for n_parts in (1, 3, fans + 2):
        k = cfg.n_secondary
        arrays = [np.zeros((fans, k)), np.zeros((fans, k)), np.zeros((fans, k, 2), np.int32), np.zeros((fans, k)),
                  np.zeros((fans, k)), np.zeros(fans, np.int64)]
        trace_fans(scene.cell_kind, scene.wall_blocks, scene.normals, scene.two_sided, cells, normals,
                   np.arange(fans), np.arange(fans), k, cfg.range_m / RES, RES, 0.05, *arrays, n_parts)
        outputs.append(arrays)
    np.testing.assert_array_equal(outputs[0][0], scan.truth.fan_d2_m)
    for other in outputs[1:]:
        for a, b in zip(outputs[0], other):
            np.testing.assert_array_equal(a, b)


def test_sort_paths_matches_a_stable_sort():
    rng = np.random.default_rng(5)
    for trial in range(600):
        n = int(rng.integers(0, 70))
        if trial % 3 == 0:  # many ties: stability decides the order of the gains
            path = rng.integers(0, 4, n).astype(float)
        elif trial % 3 == 1:  # a wall across the fan: falling, then rising, with staircase jitter
            path = np.abs(np.arange(n) - rng.integers(0, n + 1)) + 0.5 * rng.integers(0, 2, n)
        else:
            path = rng.random(n) * 40.0
        gain = rng.random(n)
        # Rows hold more entries than the returning paths: the sort must leave the tail alone.
        row_path = np.concatenate([path, [-1.0, 7.0]])
        row_gain = np.concatenate([gain, [3.0, 4.0]])
        _sort_paths(row_path, row_gain, n, np.empty(n + 1), np.empty(n + 1), np.empty(n + 2, np.int64))
        expected_path, expected_gain = naive_sort_paths(path, gain)
        np.testing.assert_array_equal(row_path[:n], expected_path)
        np.testing.assert_array_equal(row_gain[:n], expected_gain)
        np.testing.assert_array_equal(row_path[n:], [-1.0, 7.0])
        np.testing.assert_array_equal(row_gain[n:], [3.0, 4.0])


def test_scans_do_not_depend_on_how_the_work_is_split(monkeypatch):
    """Primaries, fans and histograms are split into parts for numba's threads: any split gives the same scan."""
    grid, walk = _random_rooms_and_walk(6, steps=3)
    cfg = SpadConfig(n_rays=240, n_secondary=24, range_m=5.0)
    scans = {}
    for n_parts in (1, 2, 7, 300):  # 300: more parts than rays, most of them empty
        monkeypatch.setattr(spad_simulate, "kernel_parts", lambda requested=0, n_parts=n_parts: n_parts)
        prepare_scene(grid).clear_fan_caches()
        scans[n_parts] = [simulate_scan(grid, pose, cfg) for pose in walk]
    for n_parts in (2, 7, 300):
        for scan, reference in zip(scans[n_parts], scans[1]):
            _assert_same_scan(scan, reference)


def test_sparse_histograms_round_trip_and_validation():
    rng = np.random.default_rng(0)
    dense = (rng.random((30, 50)) < 0.1).astype(np.float32) * rng.random((30, 50)).astype(np.float32)
    dense[:4] = 0.0  # rays with no photon
    sparse = SparseHistograms.from_dense(dense)
    assert sparse.n_rays == 30 and sparse.n_bins == 50 and len(sparse.bins) == np.count_nonzero(dense)
    np.testing.assert_array_equal(sparse.to_dense(), dense)
    above = SparseHistograms.from_dense(dense, threshold=0.5)
    np.testing.assert_array_equal(above.to_dense(), np.where(dense > 0.5, dense, 0.0))
    for bad in (dense.astype(np.float64), dense[0]):
        with pytest.raises(ValueError, match="float32"):
            SparseHistograms.from_dense(bad)
    # A simulated scan holds its counts sparse; its dense histograms are the same counts.
    grid, walk = _random_rooms_and_walk(5)
    scan = simulate_scan(grid, walk[0], SpadConfig(n_rays=120, n_secondary=16, range_m=5.0))
    assert scan.is_sparse
    again = SparseHistograms.from_dense(scan.histograms)
    for name in ("row_start", "bins", "counts"):
        np.testing.assert_array_equal(getattr(again, name), getattr(scan.sparse, name))


def test_numerical_stress_cases():
    tiny = SpadConfig(n_rays=64, n_secondary=8)
    for walls, pose in [(np.zeros((1, 1), bool), (0, 0)), (np.zeros((30, 30), bool), (15, 15))]:
        scan = simulate_scan(_grid(walls), pose, tiny)
        assert not scan.histograms.any()  # nothing to reflect from
    # One cell from a wall, with grazing rays along it.
    walls = np.zeros((30, 30), bool)
    walls[10, :] = True
    scan = simulate_scan(_grid(walls), (11, 15), SpadConfig(n_rays=720, n_secondary=32))
    assert np.isfinite(scan.histograms).all() and (scan.histograms >= 0).all() and scan.histograms.any()
    # A 2000 x 2000 map.
    big = np.zeros((2000, 2000), bool)
    big[[0, -1], :] = big[:, [0, -1]] = True
    big[1000, 500:1500] = True
    scan = simulate_scan(_grid(big), (900, 1000), tiny)
    assert np.isfinite(scan.histograms).all() and scan.histograms.any()
    # Extremes: counts spanning ~1e-30 .. 1e30 stay finite and non-negative.
    room = np.zeros((40, 40), bool)
    room[[0, -1], :] = room[:, [0, -1]] = True
    room[5:20, 20] = True
    for energy, rho, alpha in [(1e-45, 1e-6, 1e-6), (1e15, 1.0, 1.0), (1e40, 1.0, 1.0)]:
        cfg = SpadConfig(n_rays=180, n_secondary=16, pulse_energy_j=energy, reflectance=rho,
                         detector_efficiency=alpha)
        scan = simulate_scan(_grid(room), (30, 10), cfg)
        h = scan.histograms
        assert np.isfinite(h).all() and (h >= 0).all() and h.any()
    assert SpadConfig(pulse_energy_j=1e15).direct_counts > 1e30


def test_noise_is_seeded_and_has_the_stated_background():
    room = np.zeros((30, 30), bool)
    room[[0, -1], :] = room[:, [0, -1]] = True
    noise = SpadNoise(enabled=True, ambient_per_bin=2.0, dark_per_bin=0.5, jitter_s=0.0)
    cfg = SpadConfig(n_rays=90, n_secondary=8, noise=noise, range_m=2.0)
    grid = _grid(room)
    a = simulate_scan(grid, (15, 15), cfg, rng=np.random.default_rng(7))
    b = simulate_scan(grid, (15, 15), cfg, rng=np.random.default_rng(7))
    np.testing.assert_array_equal(a.histograms, b.histograms)
    clean = simulate_scan(grid, (15, 15), SpadConfig(n_rays=90, n_secondary=8, range_m=2.0))
    background = a.histograms[clean.histograms == 0]
    # 2.5 counts/bin over thousands of bins: the sample mean is within 5 standard errors.
    assert background.mean() == pytest.approx(2.5, abs=5 * np.sqrt(2.5 / background.size))
    draws = np.stack([simulate_scan(grid, (15, 15), cfg, rng=np.random.default_rng(s)).histograms
                      for s in range(40)])
    signal = clean.histograms > 0
    np.testing.assert_allclose(draws.mean(axis=0)[signal], clean.histograms[signal] + 2.5, rtol=0.02)
    with pytest.raises(ValueError, match="pass rng"):
        simulate_scan(grid, (15, 15), cfg)


def test_jitter_spreads_the_direct_peak_without_losing_photons():
    room = np.zeros((30, 30), bool)
    room[[0, -1], :] = room[:, [0, -1]] = True
    noise = SpadNoise(enabled=True, ambient_per_bin=0.0, dark_per_bin=0.0, jitter_s=3 * 0.1 / 299792458.0)
    cfg = SpadConfig(n_rays=8, n_secondary=4, noise=noise, range_m=2.0, pulse_energy_j=1e-12)
    clean = simulate_scan(_grid(room), (15, 15), SpadConfig(n_rays=8, n_secondary=4, range_m=2.0,
                                                              pulse_energy_j=1e-12))
    noisy = simulate_scan(_grid(room), (15, 15), cfg, rng=np.random.default_rng(0))
    assert (noisy.histograms[0] > 0).sum() > (clean.histograms[0] > 0).sum()
    assert noisy.histograms.sum() == pytest.approx(clean.histograms.sum(), rel=0.01)


def test_deterministic_and_truth_is_consistent():
    grid = _corridor()
    cfg = SpadConfig(n_rays=360, n_secondary=16)
    a, b = simulate_scan(grid, (30, 30), cfg), simulate_scan(grid, (30, 30), cfg)
    np.testing.assert_array_equal(a.histograms, b.histograms)
    truth = a.truth
    assert np.all(grid.occupied[truth.h2_rc[:, 0], truth.h2_rc[:, 1]])
    assert np.all(grid.occupied[truth.h1_rc[truth.h1_rc[:, 0] >= 0, 0], truth.h1_rc[truth.h1_rc[:, 0] >= 0, 1]])
    assert truth.h2_rc.shape[0] == truth.h2_ray.shape[0] == truth.d2_m.shape[0] == truth.h2_counts.shape[0]
    assert np.all(truth.h2_counts >= 0)


def test_bad_inputs_raise_clear_errors():
    grid = _corridor()
    with pytest.raises(ValueError, match="outside"):
        simulate_scan(grid, (60, 3))
    with pytest.raises(ValueError, match="inside a wall"):
        simulate_scan(grid, (20, 3))
    with pytest.raises(ValueError, match="inside a wall"):
        simulate_scan(_grid(np.ones((5, 5), bool)), (2, 2))
    with pytest.raises(ValueError, match="OccupancyGrid"):
        simulate_scan(np.zeros((5, 5), bool), (2, 2))
    with pytest.raises(ValueError, match="SpadConfig"):
        simulate_scan(grid, (30, 30), cfg={"n_rays": 3})
    with pytest.raises(ValueError, match="n_rays"):
        SpadConfig(n_rays=0)
    with pytest.raises(ValueError, match="reflectance"):
        SpadConfig(reflectance=1.5)
    with pytest.raises(ValueError, match="bin_width_s"):
        SpadConfig(bin_width_s=-1.0)
    with pytest.raises(ValueError, match="widen the bins"):
        SpadConfig(bin_width_s=1e-15)
    with pytest.raises(ValueError, match="ambient_per_bin"):
        SpadNoise(ambient_per_bin=-1.0)
    with pytest.raises(ValueError, match="enabled must be a bool"):
        SpadNoise(enabled="yes")
    with pytest.raises(ValueError, match="n_secondary must be a positive integer"):
        SpadConfig(n_secondary=True)
    with pytest.raises(ValueError, match="range_m must be a real number"):
        SpadConfig(range_m="20")
    with pytest.raises(ValueError, match="noise must be a SpadNoise"):
        SpadConfig(noise=None)
    with pytest.raises(ValueError, match="infinite photon count"):
        SpadConfig(pulse_energy_j=1e300)
    with pytest.raises(ValueError, match="bool"):
        OccupancyGrid(np.zeros((5, 5), np.uint8), np.ones((5, 5), bool), RES, "bad")
    with pytest.raises(ValueError, match="2-D"):
        OccupancyGrid(np.zeros(5, bool), np.ones(5, bool), RES, "bad")
    noisy = SpadConfig(noise=SpadNoise(enabled=True))
    with pytest.raises(ValueError, match="Generator"):
        simulate_scan(grid, (30, 30), noisy, rng=42)
