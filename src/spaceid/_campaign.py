"""Campaigns: independent tasks mapped over a scheduler, with seeds, per-task results on disk
(resume) and progress.

A scheduler (``scheduler``) is ``processes`` (a local process pool; one job runs in the calling
process), ``dask`` (a :class:`distributed.LocalCluster` of ``jobs`` worker processes, one thread
each) or the address of a running ``dask scheduler`` (``tcp://HOST:PORT``); with none given,
``DASK_SCHEDULER_ADDRESS`` is used if set, else ``processes``. Every task runs with one BLAS
thread: the work is many small factorisations, and threads spinning on busy cores slow every
worker down. Tasks get their seeds from the one root seed (:func:`task_seeds`), never from the
worker or the order of completion, so results are the same bit for bit on every scheduler.

With a folder, each task's result is written there as it completes (atomically), tagged with the
campaign's fingerprint; a resumed campaign loads the results that are there and runs the rest.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import pickle
import re
import shutil
from concurrent.futures import FIRST_COMPLETED, Future
from concurrent.futures import wait as wait_futures
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ._atomic import atomic_path
from ._errors import SpaceidError
from ._threads import _controller, process_pool

__all__ = ["SCHEDULERS", "Workers", "fingerprint", "open_workers", "resolve_scheduler", "run_campaign", "task_seeds"]

SCHEDULERS = ("processes", "dask")
"""Scheduler names; any other scheduler is a ``dask scheduler`` address."""

_ADDRESS = re.compile(r"^(tcp|tls|ws|wss|inproc|ucx)://\S+$")
_TASKS = ".tasks"  # the suffix of the hidden sibling folder of the per-task results
_CONNECT_TIMEOUT = "20s"


def resolve_scheduler(scheduler: str | None) -> str:
    """``scheduler``, or ``DASK_SCHEDULER_ADDRESS`` (else ``processes``) when None; raises on
    anything that is neither a scheduler name nor an address."""
    if scheduler is None:
        scheduler = os.environ.get("DASK_SCHEDULER_ADDRESS") or "processes"
    scheduler = str(scheduler).strip()
    if scheduler in SCHEDULERS or _ADDRESS.match(scheduler):
        return scheduler
    raise SpaceidError(f"`scheduler`: {scheduler!r} is neither processes, dask nor a scheduler address: give "
                       "e.g. dask or tcp://HOST:8786")  # fmt: skip


def task_seeds(seed: int, n: int) -> np.ndarray:
    """Seeds ``(n,)`` (uint32) of ``n`` tasks: task i's is the first 32-bit word of
    ``np.random.SeedSequence(seed).spawn(n)[i]``, a function of ``(seed, i)`` alone."""
    return np.array([s.generate_state(1)[0] for s in np.random.SeedSequence(seed).spawn(n)], dtype=np.uint32)


def fingerprint(settings: dict, *arrays) -> str:
    """SHA-256 of the JSON of ``settings`` and the bytes of ``arrays``: what a campaign's task
    results must belong to for a resume to use them."""
    digest = hashlib.sha256(json.dumps(settings, sort_keys=True, default=repr).encode())
    for a in arrays:
        digest.update(np.ascontiguousarray(a).tobytes())
    return digest.hexdigest()


# --- workers ------------------------------------------------------------------------------------

_SHARED = None  # what every task of a process pool needs, received once at start-up


def _init_process(shared):
    global _SHARED
    _SHARED = shared


def _call_with(function, shared, *args):  # a Dask task: shared arrives as a scattered future's value
    with _controller().limit(limits=1):
        return function(shared, *args)


def _call_shared(function, *args):  # a process-pool task
    return _call_with(function, _SHARED, *args)


@dataclass
class Workers:
    """Workers of an open scheduler: :meth:`submit` runs ``function(shared, *args)`` on one of
    ``n`` worker threads and returns a future (``concurrent.futures`` or ``distributed``);
    ``wait_first(pending)`` returns the set of those done (at least one); ``in_flight`` tasks
    at once keep every worker busy (one in this process, where a task runs as it is submitted)."""

    n: int
    submit_call: object
    wait_first: object
    in_flight: int

    def submit(self, function, *args):
        return self.submit_call(function, *args)


def _in_process(shared) -> Workers:
    def submit(function, *args):
        future = Future()
        try:
            future.set_result(_call_with(function, shared, *args))
        except Exception as exc:  # noqa: BLE001 - re-raised by future.result(), as from a pool
            future.set_exception(exc)
        return future

    return Workers(1, submit, lambda pending: set(pending), 1)


def _first_done(pending):
    return wait_futures(pending, return_when=FIRST_COMPLETED).done


@contextlib.contextmanager
def _dask_client(scheduler: str, jobs: int):
    """A :class:`distributed.Client` of a new LocalCluster (``dask``) or of the address."""
    import distributed

    with contextlib.ExitStack() as stack:
        if scheduler == "dask":
            # dashboard on a free port (its HTTP server starts anyway); silent: on a busy machine the
            # workers log errors of streams closed at shutdown, which are not ours
            cluster = stack.enter_context(distributed.LocalCluster(
                n_workers=jobs, threads_per_worker=1, processes=True, dashboard_address=":0",
                silence_logs=logging.CRITICAL))  # fmt: skip
            client = stack.enter_context(distributed.Client(cluster))
        else:
            try:
                client = stack.enter_context(distributed.Client(scheduler, timeout=_CONNECT_TIMEOUT))
            except (OSError, TimeoutError) as exc:
                raise SpaceidError(f"`scheduler`: cannot connect to {scheduler} ({exc}): start 'dask scheduler' "
                                   "and 'dask worker' there, or use the scheduler dask") from None  # fmt: skip
        yield client


@contextlib.contextmanager
def open_workers(scheduler: str, jobs: int, shared):
    """Yield :class:`Workers` of ``scheduler`` (see the module docstring) whose tasks get
    ``shared``, sent once to every worker; ``processes`` with one job runs tasks in this
    process, as they are submitted."""
    scheduler = resolve_scheduler(scheduler)
    if scheduler == "processes" and jobs == 1:
        yield _in_process(shared)
    elif scheduler == "processes":
        with process_pool(jobs, _init_process, (shared,)) as pool:  # an interrupt stops the workers
            yield Workers(jobs, lambda function, *args: pool.submit(_call_shared, function, *args),
                          _first_done, 2 * jobs)
    else:
        import distributed

        with _dask_client(scheduler, jobs) as client:
            n = sum(client.nthreads().values())
            if n == 0:
                raise SpaceidError(f"`scheduler`: {scheduler} has no workers: start 'dask worker {scheduler}'")
            [remote] = client.scatter([shared], broadcast=True, hash=False)
            yield Workers(n, lambda function, *args: client.submit(_call_with, function, remote, *args, pure=False),
                          lambda pending: distributed.wait(pending, return_when="FIRST_COMPLETED").done,
                          2 * n)  # fmt: skip


# --- campaigns ----------------------------------------------------------------------------------


def task_folder(folder) -> Path:
    """Where a campaign whose study folder is ``folder`` keeps its task results: the hidden sibling
    ``.NAME.tasks/``, outside the report folder (which is replaced whole when its report is
    written, :func:`spaceid._atomic.atomic_folder`), until :func:`discard_tasks` removes it."""
    folder = Path(os.path.realpath(folder))
    return folder.parent / f".{folder.name}{_TASKS}"


def discard_tasks(folder) -> None:
    """Remove the task results of ``folder``'s campaign (once its report is written)."""
    shutil.rmtree(task_folder(folder), ignore_errors=True)


class _TaskStore:
    """Per-task results in :func:`task_folder` ``/KEY.pkl``, each tagged with the campaign's fingerprint."""

    def __init__(self, folder, campaign: str):
        self.folder, self.campaign = task_folder(folder), campaign

    def path(self, key: str) -> Path:
        return self.folder / f"{key}.pkl"

    def clear(self) -> None:
        for path in self.folder.glob("*.pkl") if self.folder.is_dir() else ():
            path.unlink()

    def load(self, keys) -> dict:
        """The results of ``keys`` that are there; raises on one of another campaign."""
        results = {}
        for key in keys:
            path = self.path(key)
            if not path.is_file():
                continue
            with path.open("rb") as f:
                record = pickle.load(f)  # our own files (the folder the user gave)
            if record.get("campaign") != self.campaign or record.get("key") != key:
                raise SpaceidError(f"`resume`: {path} holds a result of other settings: give the settings of the "
                                   "interrupted campaign, or a new `out` folder (or do not resume)")  # fmt: skip
            results[key] = record["result"]
        return results

    def save(self, key: str, result) -> None:
        with atomic_path(self.path(key)) as tmp:
            tmp.write_bytes(pickle.dumps({"campaign": self.campaign, "key": key, "result": result}))


def run_campaign(function, shared, tasks: dict, *, scheduler=None, jobs: int = 1, folder=None,
                 campaign: str = "", resume: bool = False, progress=None, sizes: dict | None = None) -> dict:
    """Run ``function(shared, *tasks[key])`` for every key of ``tasks`` on ``scheduler``.

    Parameters
    ----------
    function : callable
        A module-level function (it is pickled to the workers).
    shared : object
        What every task needs (picklable), sent once to every worker.
    tasks : dict of str to tuple
        Arguments of each task by key (a file name: letters, digits, ``-``).
    scheduler : str, optional
        See :func:`resolve_scheduler`.
    jobs : int
        Local worker processes (``processes``, ``dask``); an address brings its own workers.
    folder : path, optional
        Study folder: each result is written to :func:`task_folder` as it completes.
    campaign : str
        The campaign's :func:`fingerprint`, stored with every result.
    resume : bool
        Load the results in ``folder`` (they must carry ``campaign``) and run only the others;
        without it, results left there are removed first.
    progress : callable, optional
        ``progress(done, total)`` in units of ``sizes`` (default one a task), fed as futures complete.

    Returns
    -------
    dict
        Results by key, in the order of ``tasks``.
    """
    store = None if folder is None else _TaskStore(folder, campaign)
    if resume and store is None:
        raise SpaceidError("`resume`: needs the study folder of the interrupted campaign (`out`)")
    results = store.load(tasks) if resume else {}
    if store is not None and not resume:
        store.clear()
    sizes = sizes or dict.fromkeys(tasks, 1)
    total, done = sum(sizes.values()), sum(sizes[k] for k in results)
    if progress is not None:
        progress(done, total)
    todo = [key for key in tasks if key not in results]
    if todo:
        with open_workers(scheduler, max(1, min(jobs, len(todo))), shared) as workers:
            queue, pending = iter(todo), {}
            while True:
                while len(pending) < workers.in_flight and (key := next(queue, None)) is not None:
                    pending[workers.submit(function, *tasks[key])] = key
                if not pending:
                    break
                for future in workers.wait_first(set(pending)):
                    key = pending.pop(future)
                    results[key] = future.result()
                    if store is not None:
                        store.save(key, results[key])
                    done += sizes[key]
                    if progress is not None:
                        progress(done, total)
    return {key: results[key] for key in tasks}
