"""Worker processes that coexist with numba's threaded kernels.

The NLOS processing runs some kernels on numba's threads (``NlosConfig.threads``). On Linux numba usually
picks its OpenMP threading layer, and with GNU OpenMP a process that has run a threaded kernel cannot ``fork``
a worker: the worker aborts ("fork() called from a process already using GNU OpenMP, this is unsafe"). Every
process pool of the project therefore comes from :func:`process_pool`, whose workers start from a fresh
``forkserver`` process, and runs single-threaded numba kernels, since the workers already share the cores.
Code outside the project that forks after running SuperEx should do the same (or set
``NUMBA_THREADING_LAYER=workqueue``, which is fork-safe but gained little here).

Long sweeps go through :func:`run_tasks`: every finished task is appended to a journal at once, a rerun skips what
the journal holds, and SIGTERM / SIGINT stop the workers instead of leaving them running.
"""

from __future__ import annotations

import ctypes
import json
import multiprocessing
import os
import signal
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from contextlib import contextmanager
from typing import Callable, Iterator, Optional, Sequence

__all__ = ["process_pool", "run_tasks", "read_journal", "Interrupted", "LocalBackend", "RayBackend", "kernel_parts"]

_PR_SET_PDEATHSIG = 1


def kernel_parts(requested: int = 0) -> int:
    """How many parts a threaded numba kernel splits its work into: ``requested`` when positive, else numba's
    current thread count. The kernels' results never depend on it (each part writes its own rows or cells)."""
    import numba

    return int(requested) or numba.get_num_threads()


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


def _die_with_parent() -> None:
    """Ask Linux to send this process SIGTERM when its parent dies (a killed benchmark leaves no workers)."""
    if not sys.platform.startswith("linux"):
        return
    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    except OSError:  # no glibc: the pool's terminate() on SIGTERM / SIGINT still stops the workers
        pass


def _journal_worker() -> None:
    _die_with_parent()
    _single_threaded_worker()


class Interrupted(Exception):
    """SIGTERM or SIGINT arrived while :func:`run_tasks` ran; the workers were stopped, the journal is consistent."""


def read_journal(path: Path) -> dict:
    """``key -> result`` of a journal written by :func:`run_tasks`. A last line cut short (a kill mid-write) is
    ignored; any other unreadable line raises ``ValueError``."""
    done = {}
    if not path.is_file():
        return done
    lines = path.read_text().split("\n")
    for number, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
            done[record["key"]] = record["result"]
        except (json.JSONDecodeError, KeyError, TypeError):
            if number == len(lines) or (number == len(lines) - 1 and not lines[-1]):
                continue  # the line being written when the run was killed
            raise ValueError(f"{path}: line {number} is not a journal record") from None
    return done


def _drop_torn_line(journal: Path) -> None:
    """Cut a last line left unfinished by a kill, so that the next record starts on a line of its own."""
    if not journal.is_file() or journal.stat().st_size == 0:
        return
    with open(journal, "rb+") as file:
        data = file.read()
        if not data.endswith(b"\n"):
            file.truncate(data.rfind(b"\n") + 1)


def _call(payload):
    worker, key, task = payload
    return key, worker(task)


class LocalBackend:
    """``jobs`` worker processes on this machine (a fork-server pool, one numba thread each)."""

    def __init__(self, jobs: int):
        if isinstance(jobs, bool) or int(jobs) != jobs or jobs < 1:
            raise ValueError(f"jobs must be an integer >= 1, got {jobs}")
        self.jobs = int(jobs)

    def __repr__(self) -> str:
        return f"LocalBackend(jobs={self.jobs})"

    @contextmanager
    def imap_unordered(self, function: Callable, items: Sequence) -> Iterator:
        """``function(item)`` for every item, in the order they finish; the workers stop when the block exits
        early (an exception, a signal)."""
        pool = multiprocessing.get_context("forkserver").Pool(self.jobs, initializer=_journal_worker)
        try:
            yield pool.imap_unordered(function, items)
            pool.close()
        except BaseException:
            pool.terminate()
            raise
        finally:
            pool.join()


class RayBackend:
    """Ray tasks, one CPU each, with one numba / OpenMP thread per task (the ``ray`` extra).

    Args:
        address: a running cluster (``"auto"`` or ``"HOST:PORT"``, as ``ray start --head`` prints), or None to start a
            local Ray instance for the run (shut down afterwards).
        num_cpus: CPUs of the local instance (ignored with ``address``).

    Every node needs this package installed (``pip install 'superex[ray]'``); tasks are pickled by reference.
    """

    def __init__(self, address: Optional[str] = None, num_cpus: Optional[int] = None):
        try:
            import ray  # noqa: F401
        except ModuleNotFoundError:
            raise ValueError("the Ray backend needs Ray: pip install 'superex[ray]'") from None
        if num_cpus is not None and (isinstance(num_cpus, bool) or int(num_cpus) != num_cpus or num_cpus < 1):
            raise ValueError(f"num_cpus must be an integer >= 1, got {num_cpus}")
        self.address, self.num_cpus = address, num_cpus

    def __repr__(self) -> str:
        return f"RayBackend(address={self.address!r}, num_cpus={self.num_cpus})"

    @contextmanager
    def imap_unordered(self, function: Callable, items: Sequence) -> Iterator:
        import ray

        started = not ray.is_initialized()
        if started:
            threads = {"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
            options = dict(runtime_env={"env_vars": threads}, include_dashboard=False, log_to_driver=False,
                           configure_logging=False)
            if self.address is None:
                ray.init(num_cpus=self.num_cpus, **options)
            else:
                ray.init(address=self.address, **options)
        remote = ray.remote(num_cpus=1, max_retries=0)(function)
        pending = [remote.remote(item) for item in items]

        def results():
            nonlocal pending
            while pending:
                done, pending = ray.wait(pending, num_returns=1)
                yield ray.get(done[0])

        try:
            yield results()
        finally:
            for ref in pending:  # stopped early: nothing keeps running on the cluster
                ray.cancel(ref, force=True)
            if started:
                ray.shutdown()


def run_tasks(worker: Callable, tasks: Sequence, keys: Sequence[str], backend, journal: Path,
              progress: Optional[str] = None) -> list:
    """Run ``worker(task)`` for every task on ``backend`` (:class:`LocalBackend`, :class:`RayBackend`, or an int:
    that many local workers), appending each result to ``journal`` (one JSON line ``{"key", "result"}``, flushed
    and synced) the moment it arrives, and skipping the tasks whose key the journal already holds. Returns the
    results in task order, whichever backend ran them and in whatever order they finished.

    SIGTERM and SIGINT stop the workers at once (a local worker also dies with its parent, even on SIGKILL; Ray
    tasks are cancelled) and raise :class:`Interrupted`; the journal then holds every finished task, so the same
    call resumes the run.

    Args:
        worker: a module-level function of one task returning something JSON-serialisable.
        tasks, keys: the tasks and a unique string key for each.
        backend: where the tasks run.
        journal: the ``.jsonl`` file to append to (its folder must exist).
        progress: a tqdm label, or None for no progress bar.

    Raises:
        ValueError: a bad backend, keys that are not unique or do not match the tasks, a corrupt journal.
        Interrupted: a signal stopped the run.
    """
    from tqdm import tqdm

    if not isinstance(backend, (LocalBackend, RayBackend)):
        backend = LocalBackend(backend)
    if len(keys) != len(tasks) or len(set(keys)) != len(keys):
        raise ValueError("run_tasks needs one unique key per task")
    journal = Path(journal)
    done = read_journal(journal)
    todo = [(worker, key, task) for key, task in zip(keys, tasks) if key not in done]
    if todo:
        previous = {sig: signal.getsignal(sig) for sig in (signal.SIGTERM, signal.SIGINT)}

        def stop(signum, frame):
            raise Interrupted(f"stopped by {signal.Signals(signum).name}")

        for sig in previous:
            signal.signal(sig, stop)
        _drop_torn_line(journal)
        try:
            with open(journal, "a") as out, tqdm(total=len(keys), initial=len(keys) - len(todo), desc=progress,
                                                 unit="episode", disable=progress is None) as bar, \
                    backend.imap_unordered(_call, todo) as finished:
                for sig in previous:  # again: starting Ray installs its own SIGTERM handler
                    signal.signal(sig, stop)
                for key, result in finished:
                    out.write(json.dumps({"key": key, "result": result}) + "\n")
                    out.flush()
                    os.fsync(out.fileno())
                    done[key] = result
                    bar.update(1)
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
    return [done[key] for key in keys]
