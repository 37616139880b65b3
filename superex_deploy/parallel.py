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

Signals: one rule for the whole package. Inside :func:`stop_signals` (``superex`` runs every command in it) SIGINT
and SIGTERM raise :class:`Interrupted`, a ``KeyboardInterrupt`` that carries the signal, so the code that cleans
up after Ctrl-C cleans up after a scheduler's SIGTERM too and the command exits with the code a shell reports for
the signal (:attr:`Interrupted.exit_code`: 130, 143). Work that a signal must not cut in half (a recorded step)
runs inside :func:`signals_deferred`, which holds a signal until the block ends. The workers of
:class:`LocalBackend` ignore SIGINT (a Ctrl-C reaches the whole process group; the parent stops them) and leave
at once on SIGTERM, from a thread that waits for it alone, after releasing the named semaphore numba made in them
(the resource tracker would report it leaked).
"""

from __future__ import annotations

import ctypes
import json
import multiprocessing
import os
import signal
import sys
import threading
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from contextlib import contextmanager
from typing import Callable, Iterator, Optional, Sequence

__all__ = ["process_pool", "run_tasks", "read_journal", "Interrupted", "interruption_in", "stop_signals",
           "signals_deferred", "LocalBackend", "RayBackend", "kernel_parts"]

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


def _exit_on_sigterm() -> None:
    """A worker's SIGTERM watcher: waits for the signal (blocked in every other thread), releases the named
    semaphores the process created (numba's lock; the resource tracker would report them leaked) and leaves at
    once, whatever the main thread is doing (a kernel, or waiting on the pool's queue lock, which a Python signal
    handler would never interrupt if the signal went to another thread)."""
    signal.sigwait({signal.SIGTERM})
    try:
        from multiprocessing import util

        util._run_finalizers(0)  # the SemLock finalizers: unlink each name, unregister it from the tracker
    finally:
        os._exit(128 + signal.SIGTERM)


def _journal_worker() -> None:
    """A :class:`LocalBackend` worker: dies with its parent, ignores SIGINT (the parent, which a Ctrl-C reaches
    too, stops the pool), leaves at once and cleanly on the SIGTERM that stops it, one numba thread."""
    _die_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):
        # Blocked before any other thread starts (numba's, ONNX Runtime's, the explorer's): they all inherit it, and
        # only the watcher takes the signal.
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGTERM})
        threading.Thread(target=_exit_on_sigterm, name="superex-sigterm", daemon=True).start()
    _single_threaded_worker()


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
"""The signals that stop a run: Ctrl-C and what a cluster scheduler (or ``kill``) sends."""


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM stopped the run (raised inside :func:`stop_signals`, and by :func:`run_tasks`, whose
    workers are then stopped and whose journal is consistent).

    A ``KeyboardInterrupt``, so that ``except Exception`` never swallows it and cleanup written for Ctrl-C runs
    for SIGTERM as well.

    Attributes:
        signum: the signal's number.
        kept: what the interrupted command kept, in a few words for its one line on stderr ("" for nothing);
            set by the command before it re-raises.
    """

    def __init__(self, signum: int):
        self.signum = int(signum)
        self.kept = ""
        super().__init__(f"stopped by {signal.Signals(self.signum).name}")

    def __reduce__(self):
        return Interrupted, (self.signum,)

    @property
    def signal_name(self) -> str:
        """``"SIGINT"`` or ``"SIGTERM"``."""
        return signal.Signals(self.signum).name

    @property
    def exit_code(self) -> int:
        """``128 + signum``, what a shell reports for a process the signal ended: 130 for SIGINT, 143 for SIGTERM."""
        return 128 + self.signum


def _raise_interrupted(signum, frame):
    raise Interrupted(signum)


def interruption_in(error: BaseException) -> Optional[Interrupted]:
    """The :class:`Interrupted` that ``error`` is or carries in its chain of causes (None if it carries none).

    The handlers of :func:`stop_signals` raise wherever the main thread is; inside a C callback (numba's unpickling
    of a compiled function's constants, for one) the exception comes out wrapped in a ``SystemError``. A command
    treats such an error as the signal it is."""
    seen = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, Interrupted):
            return error
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return None


def _in_main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


@contextmanager
def stop_signals() -> Iterator[None]:
    """Within the block, SIGINT and SIGTERM raise :class:`Interrupted`; the previous handlers come back after it.

    Signal handlers belong to the main thread: called from another thread, the block runs with the handlers as
    they are.
    """
    if not _in_main_thread():
        yield
        return
    previous = {sig: signal.getsignal(sig) for sig in STOP_SIGNALS}
    for sig in STOP_SIGNALS:
        signal.signal(sig, _raise_interrupted)
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, signal.SIG_DFL if handler is None else handler)


@contextmanager
def signals_deferred() -> Iterator[None]:
    """Run a block that a signal must not cut in half (a recorded step, closing a file): SIGINT or SIGTERM arriving
    inside it is held, and handled by the handler installed before the block as soon as the block ends (with the
    default handlers: KeyboardInterrupt, or the process ends as it would have).

    In a thread other than the main one the block just runs: Python runs signal handlers in the main thread only,
    so no signal can interrupt it there.
    """
    if not _in_main_thread():
        yield
        return
    held: list[int] = []
    previous = {sig: signal.getsignal(sig) for sig in STOP_SIGNALS}
    for sig in STOP_SIGNALS:
        signal.signal(sig, lambda signum, frame: held.append(signum))
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, signal.SIG_DFL if handler is None else handler)
        if held:
            handler = previous[held[0]]
            if callable(handler):
                handler(held[0], None)
            elif handler == signal.SIG_DFL:
                os.kill(os.getpid(), held[0])  # what would have happened without the block


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


def _waking(results) -> Iterator:
    """The pool's results, waiting at most half a second at a time: a signal that reached another thread of this
    process is then handled within that time, not when the next result arrives."""
    while True:
        try:
            yield results.next(timeout=0.5)
        except multiprocessing.TimeoutError:
            continue
        except StopIteration:
            return


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
            yield _waking(pool.imap_unordered(function, items))
            pool.close()
        except BaseException:
            with signals_deferred():  # a second Ctrl-C must not cut the shutdown short
                pool.terminate()
                pool.join()
            raise
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
        _drop_torn_line(journal)
        with stop_signals(), open(journal, "a") as out, \
                tqdm(total=len(keys), initial=len(keys) - len(todo), desc=progress, unit="episode",
                     disable=progress is None) as bar, \
                backend.imap_unordered(_call, todo) as finished:
            if _in_main_thread():
                for sig in STOP_SIGNALS:  # again: starting Ray installs its own SIGTERM handler
                    signal.signal(sig, _raise_interrupted)
            for key, result in finished:
                out.write(json.dumps({"key": key, "result": result}) + "\n")
                out.flush()
                os.fsync(out.fileno())
                done[key] = result
                bar.update(1)
    return [done[key] for key in keys]
