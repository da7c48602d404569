"""Thread and process use: how many threads array work may take, single-threaded BLAS for small
dense linear algebra, work run beside the caller on an idle core, and process pools that an
interrupt stops at once."""

from __future__ import annotations

import contextlib
import functools
import math
import os
import signal
import threading
import time
from concurrent.futures import Future, ProcessPoolExecutor, ThreadPoolExecutor

from threadpoolctl import ThreadpoolController


@functools.cache
def _controller() -> ThreadpoolController:
    return ThreadpoolController()  # inspecting the loaded libraries takes ~1 ms: once


def blas_threads() -> int:
    """Threads BLAS may use now; array work follows it, so that ``threadpool_limits(1)`` (as in
    the worker processes of design and Monte Carlo) keeps everything serial."""
    return max([1] + [lib["num_threads"] for lib in _controller().info() if lib["user_api"] == "blas"])


LOAD_WINDOW = 60.0
"""Time constant [s] of the load average that :func:`work_threads` reads (Linux's 1-minute average)."""

_own = {"at": time.monotonic(), "cpu": time.process_time(), "share": 0.0}
_own_lock = threading.Lock()


def _own_load() -> float:
    """This process's share of the 1-minute load average: the cores its threads kept busy, averaged
    as the kernel averages the load (exponentially, over :data:`LOAD_WINDOW`), from its processor time
    since the last call (the first: since this module's import)."""
    with _own_lock:
        now, cpu = time.monotonic(), time.process_time()
        elapsed = now - _own["at"]
        if elapsed > 0:
            keep = math.exp(-elapsed / LOAD_WINDOW)
            _own.update(at=now, cpu=cpu, share=keep * _own["share"] + (1 - keep) * (cpu - _own["cpu"]) / elapsed)
        return _own["share"]


def _running_now() -> int | None:
    """Threads of other processes running or runnable on the machine now (Linux: ``/proc/loadavg``'s count
    less this process's own running threads, BLAS's spinning ones included), or None where that is not known."""
    try:
        with open("/proc/loadavg") as f:
            running = int(f.read().split()[3].split("/")[0])
        own = 0
        for task in os.scandir("/proc/self/task"):
            with open(os.path.join(task.path, "stat")) as f:
                own += f.read().rpartition(")")[2].split()[0] == "R"  # the state follows the command's name
        return max(running - own, 0)
    except (OSError, IndexError, ValueError):
        return None


BUSY_WINDOW = 0.25
"""Shortest time [s] over which :func:`_busy_others` measures the other processes' processor time."""


def _busy_time() -> float | None:
    """The machine's processor time [s] since boot, all cores (Linux: ``/proc/stat``, idle and waiting
    excluded), or None where that is not known."""
    try:
        with open("/proc/stat") as f:
            ticks = [int(v) for v in f.readline().split()[1:]]
        return (sum(ticks) - ticks[3] - ticks[4]) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


_busy = {"at": time.monotonic(), "cpu": time.process_time(), "busy": _busy_time(), "share": None}


def _busy_others() -> float | None:
    """The cores the other processes kept busy lately: the machine's processor time less this process's, over
    the last :data:`BUSY_WINDOW` or more (from this module's import on), or None before the first window has
    passed or where it is not known. A process that runs for an instant (one ran 100 times in 3 s here, for 0.1
    to 5 ms each) is running in :func:`_running_now` while it does, which had kept identifications on one thread;
    here it is the few milliseconds it took."""
    busy, now, cpu = _busy_time(), time.monotonic(), time.process_time()
    with _own_lock:
        last = _busy
        if busy is not None and last["busy"] is not None and now - last["at"] >= BUSY_WINDOW:
            share = (busy - last["busy"] - (cpu - last["cpu"])) / (now - last["at"])
            last.update(at=now, cpu=cpu, busy=busy, share=max(share, 0.0))
        return last["share"]


def work_threads() -> int:
    """Threads for block-parallel array work (the regressor's blocks, the blockwise factorisations):
    :func:`blas_threads`, but no more than the cores the other processes leave idle: ``os.cpu_count()``
    less their load, rounded. Their load: the 1-minute load average without this process's own share
    (:func:`_own_load`), at most the threads running now (:func:`_running_now`), so that a process
    that has just ended does not count for a minute, and at most the cores they kept busy lately
    (:func:`_busy_others`), so that one that runs for an instant does not count either. On 2 cores
    under a load of 14 the Gram product of 30,000 x 496 took 2.3 s on 2 such threads and 1.8 s on 1
    (threaded BLAS: 3.7 s, one BLAS thread 1.2 s; ``benchmarks/bench_stream.py``); on idle cores 2
    threads halve it. Read as another's, the load a process made itself or its predecessor left in the
    average kept it on one thread for a minute on 2 idle cores (10,000 servicer samples identified in a
    row: ``benchmarks/bench_ml.py``). In a :func:`side_by_side` block, the caller's thread keeps the
    threads it had on entering it (BLAS's one thread there is the block's own limit), its workers one."""
    limit = blas_threads()
    if limit == 1:  # (the load need not be read)
        return getattr(_caller, "threads", 1)
    try:
        others = max(os.getloadavg()[0] - _own_load(), 0.0)
    except OSError:  # no load average on this platform
        others = 0.0
    others = min([others] + [v for v in (_running_now(), _busy_others()) if v is not None])
    return max(1, min(limit, int((os.cpu_count() or 1) - others + 0.5)))


def threads_for(tasks: int) -> int:
    """Threads for ``tasks`` independent blocks: :func:`work_threads`, at most one a block; one block is run in
    the caller without asking (the question reads ``/proc``: 0.13 ms, more than a few samples' kinematics)."""
    return min(tasks, work_threads()) if tasks > 1 else 1


def one_blas_thread():
    """Context manager: BLAS on one thread, for factorisations of p x p matrices (p ~ 10-500).
    Threads gain little at these sizes, and when the cores are busy OpenBLAS's waiting threads
    made an eigendecomposition of 496 x 496 take 1.3 s instead of 10 ms (measured)."""
    return _controller().limit(limits=1, user_api="blas")


def _done(fn, *args) -> Future:
    """A finished :class:`~concurrent.futures.Future` of ``fn(*args)``, run now (its exception kept for ``result``)."""
    future = Future()
    try:
        future.set_result(fn(*args))
    except BaseException as exc:  # noqa: BLE001 (raised by result(), as from a worker)
        future.set_exception(exc)
    return future


_caller = threading.local()
"""``threads``: the :func:`work_threads` of the thread that opened a :func:`side_by_side` block, while in it."""


@contextlib.contextmanager
def side_by_side(workers: int = 1):
    """Context manager yielding ``submit(fn, *args)``, a :class:`~concurrent.futures.Future` of ``fn(*args)``: run
    in submission order on ``workers`` threads beside the caller when the machine leaves it an idle core
    (:func:`work_threads`), else at once in the caller. Array work releases the GIL, so independent computations
    then take the longest one's time, not their sum; each is the same computation either way, so the results are
    bit-identical. A job that waits on another's result holds its worker meanwhile: submit it after that one.
    BLAS runs on one thread in the block (nested :func:`one_blas_thread` then restore one thread, whichever thread
    leaves last); leaving it waits for the workers."""
    threads = work_threads()  # before the limit below, which it follows
    with one_blas_thread():
        if threads < 2:
            yield _done
            return
        kept, _caller.threads = getattr(_caller, "threads", None), threads
        try:
            with ThreadPoolExecutor(workers, thread_name_prefix="spaceid-side") as pool:
                yield pool.submit
        finally:
            if kept is None:
                del _caller.threads
            else:
                _caller.threads = kept


def _start_worker(initializer, initargs):
    """A pool worker's start: signals left to the parent, then ``initializer(*initargs)``.

    Ctrl-C reaches the whole process group: the workers ignore it, and the parent, which gets
    it too, stops them (see :func:`process_pool`). SIGTERM kills a worker outright (a forked
    worker would otherwise inherit the command line's handler, which turns it into an
    exception that the pool's task loop catches and carries on)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if hasattr(signal, "pthread_sigmask"):  # held back while it was forked (process_pool): its own handlers now
        signal.pthread_sigmask(signal.SIG_UNBLOCK, _HELD)
    initializer(*initargs)


_HELD = {signal.SIGINT, signal.SIGTERM}
"""The signals held back while :func:`process_pool` forks its workers."""


def _fork_workers(pool) -> None:
    """Start the workers of ``pool`` (forked at its first task, all at once) with Ctrl-C and SIGTERM held
    back meanwhile: a worker gets them only once it has its own handlers (:func:`_start_worker`). One that
    came as it was forked ran the parent's handler in it, which left it hung, and the command waited for it
    at exit (seen once in CI); held back, it reaches the parent when the workers are started."""
    if not hasattr(signal, "pthread_sigmask"):
        return
    held = signal.pthread_sigmask(signal.SIG_BLOCK, _HELD)
    try:
        pool.submit(int)
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, held)


@contextlib.contextmanager
def process_pool(workers: int, initializer, initargs=()):
    """A :class:`~concurrent.futures.ProcessPoolExecutor` of ``workers`` processes, each started
    by ``initializer(*initargs)``, that an exception in the block (a Ctrl-C, a SIGTERM turned
    into an exception, an error) ends at once: pending tasks cancelled, workers terminated and
    reaped. Leaving the block normally waits for the tasks, as the executor does (and a Ctrl-C while it waits
    ends them the same way)."""
    pool = ProcessPoolExecutor(workers, initializer=functools.partial(_start_worker, initializer, initargs))
    try:
        _fork_workers(pool)
        yield pool
        pool.shutdown(wait=True)  # (a Ctrl-C here, as the last tasks end, had left the manager thread running)
    except BaseException:
        processes = list((pool._processes or {}).values())  # the executor has no public terminate (Python < 3.14)
        # the executor's manager thread closes its wake-up pipe once it sees the workers gone; at exit Python wakes
        # every such thread without a lock, and a pipe closed in between printed "Exception ignored ... Bad file
        # descriptor" after the command's last line: it is let finish first (taken before shutdown, which drops it)
        manager = getattr(pool, "_executor_manager_thread", None)  # (a private attribute: None if it goes)
        pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            process.terminate()
        for process in processes:
            process.join(timeout=5)
        if manager is not None:
            manager.join(timeout=5)
        raise
