"""The one job runner: every task of a job through one function, in this process, in a process
pool or on a Dask cluster, each result handed back to the caller as it finishes.

A job is ``fn`` and its tasks by key: ``{key: args}``; :func:`run_tasks` calls ``fn(*args)`` for
every task and ``on_result(key, result)`` in the calling process, in the order the tasks finish
(one by one, so the caller can record each, e.g. a done file or a manifest, before the next).
Resuming is the caller's: it leaves out the keys already done (:func:`pending`).

Engines:

* ``"local"``: ``workers`` processes (0 = every core); with one worker or one task, in this
  process, in key order. Pool workers are started with ``spawn`` and end with their parent
  (:func:`~synth.common.processes.exit_with_parent`).
* ``"dask"``: a Dask cluster at ``address`` (``tcp://HOST:PORT``), or a local cluster of
  ``workers`` single-threaded processes when ``address`` is None.

On an error (a task raising, a worker dying) the tasks not yet started are cancelled and the
error propagates; results handed over before it stay handed over. With ``on_error``, a task that
raises an ``Exception`` is handed to ``on_error(key, exc)`` instead and the others go on; a worker
that died (a killed pool process, a lost Dask worker) is not the task's error and still propagates.
"""

from __future__ import annotations

import os
from typing import Any, Callable, Hashable, Iterable, Mapping

ENGINES = ("local", "dask")


def pending(keys: Iterable[Hashable], done: Iterable[Hashable]) -> list:
    """The keys of a job still to run, in order: ``keys`` without those in ``done``."""
    finished = set(done)
    return [k for k in keys if k not in finished]


def check_engine(engine: str, workers: int) -> None:
    """Raise ``ValueError`` for an engine or worker count :func:`run_tasks` does not take."""
    if engine not in ENGINES:
        raise ValueError(f"engine must be 'local' or 'dask', got {engine!r}")
    if not isinstance(workers, int) or isinstance(workers, bool) or workers < 0:
        raise ValueError(f"workers must be a whole number >= 0 (0 = all cores), got {workers!r}")


Handler = Callable[[Hashable, Any], None]


def run_tasks(fn: Callable[..., Any], tasks: Mapping[Hashable, tuple], on_result: Handler, workers: int = 0,
              engine: str = "local", address: str | None = None, on_error: Handler | None = None) -> None:
    """``fn(*args)`` for every ``key: args`` of ``tasks``; ``on_result(key, result)`` here as each
    finishes. ``fn`` and its arguments must pickle for a pool or Dask (a module-level function)."""
    check_engine(engine, workers)
    workers = workers or os.cpu_count() or 1
    if engine == "dask":
        _run_dask(fn, tasks, _Hand(on_result, on_error), workers, address)
    elif workers == 1 or len(tasks) <= 1:
        hand = _Hand(on_result, on_error)
        for key, args in tasks.items():
            hand(key, lambda: fn(*args))
    else:
        _run_pool(fn, tasks, _Hand(on_result, on_error), workers)


class _Hand:
    """Hands a finished task's result (or, with ``on_error``, its exception) to the caller."""

    def __init__(self, on_result: Handler, on_error: Handler | None) -> None:
        self.on_result, self.on_error = on_result, on_error

    def __call__(self, key: Hashable, result: Callable[[], Any]) -> None:
        if self.on_error is None:
            self.on_result(key, result())
            return
        try:
            value = result()
        except Exception as exc:  # the caller records it (on_error) and the job goes on
            if worker_died(exc):
                raise
            self.on_error(key, exc)
            return
        self.on_result(key, value)


def worker_died(exc: BaseException) -> bool:
    """Whether ``exc`` says the process running a task died (a pool's ``BrokenProcessPool``, Dask's
    ``KilledWorker`` / ``CommClosedError``), not that the task raised."""
    return type(exc).__name__ in ("BrokenProcessPool", "KilledWorker", "CommClosedError")


def _run_pool(fn, tasks, hand: _Hand, workers: int) -> None:
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed

    from synth.common.processes import exit_with_parent

    with ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"),
                             initializer=exit_with_parent) as pool:
        futures = {pool.submit(fn, *args): key for key, args in tasks.items()}
        try:
            for f in as_completed(futures):
                hand(futures[f], f.result)
        except BaseException:
            for f in futures:
                f.cancel()
            raise


def _run_dask(fn, tasks, hand: _Hand, workers: int, address: str | None) -> None:
    from distributed import Client, LocalCluster, as_completed

    cluster = None
    if address is None:
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address=None)
    client = Client(address or cluster)
    try:
        futures = {client.submit(fn, *args, pure=False, retries=0): key for key, args in tasks.items()}
        try:
            for f in as_completed(futures):
                hand(futures[f], f.result)
        except BaseException:
            client.cancel(list(futures))
            raise
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
