import numba
import numpy as np
import pytest

from superex_deploy.maps import load_map, start_poses
from superex_deploy.onboard.nlos import NlosConfig, process_scan
from superex_deploy.parallel import process_pool
from superex_deploy.spad_types import SpadConfig
from superex_deploy.sim.spad import simulate_scan

MAP = "50052750"
SPAD = SpadConfig(n_rays=400, n_secondary=16)


def _back_projection(pose_index: int) -> tuple[np.ndarray, int]:
    grid = load_map(MAP)
    scan = simulate_scan(grid, start_poses(MAP)[pose_index], SPAD)
    return process_scan(scan, NlosConfig(threads=2)).bp, numba.get_num_threads()


@pytest.mark.slow
def test_pool_workers_run_threaded_kernels_after_the_parent_has():
    # The parent runs the threaded back-projection first: a plainly forked worker would then abort under GNU
    # OpenMP ("fork() called from a process already using GNU OpenMP").
    expected = [_back_projection(k)[0] for k in range(2)]
    assert all(bp.any() for bp in expected)
    with process_pool(2) as pool:
        results = list(pool.map(_back_projection, range(2)))
    for (bp, worker_threads), reference in zip(results, expected):
        np.testing.assert_allclose(bp, reference, rtol=1e-6, atol=0)
        assert worker_threads == 1  # the workers already share the cores


@pytest.mark.parametrize("jobs", [0, -2, 1.5])
def test_pool_size_is_checked(jobs):
    with pytest.raises(ValueError, match="jobs"):
        process_pool(jobs)
