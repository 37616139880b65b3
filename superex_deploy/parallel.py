"""Worker processes that coexist with numba's threaded kernels.

The NLOS processing runs some kernels on numba's threads (``NlosConfig.threads``). On Linux numba usually
picks its OpenMP threading layer, and with GNU OpenMP a process that has run a threaded kernel cannot ``fork``
a worker: the worker aborts ("fork() called from a process already using GNU OpenMP, this is unsafe"). Every
process pool of the project therefore comes from :func:`process_pool`, whose workers start from a fresh
``forkserver`` process, and runs single-threaded numba kernels, since the workers already share the cores.
Code outside the project that forks after running SuperEx should do the same (or set
``NUMBA_THREADING_LAYER=workqueue``, which is fork-safe but gained little here).
"""

from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor


def _single_threaded_worker() -> None:
    import numba

    numba.set_num_threads(1)


def process_pool(jobs: int) -> ProcessPoolExecutor:
    """A pool of ``jobs`` worker processes started by a fork server, each with one numba thread.

    The work submitted must be picklable by reference (module-level functions, or ``__main__`` functions of a
    script guarded by ``if __name__ == "__main__"``).

    Raises:
        ValueError: ``jobs`` < 1.
    """
    if int(jobs) != jobs or jobs < 1:
        raise ValueError(f"jobs must be an integer >= 1, got {jobs}")
    return ProcessPoolExecutor(max_workers=int(jobs), mp_context=multiprocessing.get_context("forkserver"),
                               initializer=_single_threaded_worker)
