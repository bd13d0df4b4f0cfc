"""The one job runner (synth.common.runner): every task's result reaches the caller once, by its
key, in this process or from pool workers; errors propagate or, with ``on_error``, are handed over
while the other tasks go on. (The Dask engine runs in tests/synth/data/test_dataset.py.)"""

import operator
import os

import pytest

from synth.common.runner import check_engine, pending, run_tasks


def collect(tasks, fn=operator.mul, catch=False, **kw):
    """(results by key, errors by key) of one run_tasks; ``catch``: with an on_error."""
    got, errors = {}, {}
    on_error = errors.__setitem__ if catch else None
    run_tasks(fn, tasks, got.__setitem__, on_error=on_error, **kw)
    return got, errors


def test_one_worker_runs_in_this_process_in_key_order():
    order = []
    run_tasks(os.getpid, {"b": (), "a": ()}, lambda k, pid: order.append((k, pid)), workers=1)
    assert order == [("b", os.getpid()), ("a", os.getpid())]


def test_a_pool_hands_back_every_result_by_key_from_other_processes():
    got, _ = collect({k: (k, 3) for k in range(6)}, workers=2)
    assert got == {k: 3 * k for k in range(6)}
    pids, _ = collect({k: () for k in range(4)}, fn=os.getpid, workers=2)
    assert os.getpid() not in pids.values()


@pytest.mark.parametrize("workers", [1, 2])
def test_an_error_propagates_or_is_handed_over(workers):
    tasks = {"ok": (1.0, 2.0), "bad": (1.0, 0.0), "also": (3.0, 1.0)}
    with pytest.raises(ZeroDivisionError):
        collect(tasks, fn=operator.truediv, workers=workers)
    got, errors = collect(tasks, fn=operator.truediv, workers=workers, catch=True)
    assert got == {"ok": 0.5, "also": 3.0} and set(errors) == {"bad"}
    assert isinstance(errors["bad"], ZeroDivisionError)


def test_no_tasks_run_nothing():
    assert collect({}, workers=2) == ({}, {})


@pytest.mark.parametrize("engine,workers", [("spark", 1), ("local", -1), ("local", 1.5), ("local", True)])
def test_bad_engine_or_workers_fail_in_one_line(engine, workers):
    with pytest.raises(ValueError, match="engine|workers"):
        check_engine(engine, workers)
    with pytest.raises(ValueError):
        run_tasks(operator.mul, {1: (1, 1)}, lambda k, r: None, workers=workers, engine=engine)


def test_pending_keeps_order_and_drops_the_done():
    assert pending(range(5), {3, 0, 9}) == [1, 2, 4]


def _die() -> None:
    os._exit(1)  # the worker process dies: not an error this task raised


def test_a_dead_worker_propagates_even_with_on_error():
    """on_error is for a task that raised; a pool whose worker died stops the job (the caller
    resumes it) instead of recording the task as failed."""
    from concurrent.futures.process import BrokenProcessPool

    with pytest.raises(BrokenProcessPool):
        collect({"a": (), "b": ()}, fn=_die, workers=2, catch=True)
