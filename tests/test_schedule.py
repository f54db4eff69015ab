"""The scheduler of many experiments in one pool: dependencies, longest chain first, and results
that do not depend on the number of workers."""

from __future__ import annotations

import operator
from functools import partial

import pytest

from teamslam.errors import InputError
from teamslam.eval.schedule import Task, run_tasks


def _tasks() -> list[Task]:
    # a chain prepare → long run, one other long task, and short ones; every result is a
    # function of its inputs only
    return [
        Task("short-a", partial(operator.mul, 3, 7), cost=1.0),
        Task("other", partial(sum, range(1000)), cost=8.0),
        Task("prepare", partial(operator.add, 40, 2), cost=3.0),
        Task("run", partial(operator.mul, 10), cost=6.0, needs="prepare"),
        Task("check", partial(operator.neg), cost=0.5, needs="prepare"),
        Task("short-b", partial(pow, 2, 10), cost=1.0),
    ]


def test_tasks_start_by_longest_chain_and_get_their_inputs():
    results, schedule = run_tasks(_tasks(), workers=1, progress=False)
    assert results == {
        "short-a": 21,
        "other": 499500,
        "prepare": 42,
        "run": 420,
        "check": -42,
        "short-b": 1024,
    }
    # prepare heads the longest chain (3 + 6 = 9 > 8), its long follower comes right after the
    # other long task; equal chains keep the order given
    assert schedule.order == ["prepare", "other", "run", "short-a", "short-b", "check"]
    assert set(schedule.worker.values()) == {0}
    assert schedule.critical_path() == pytest.approx(sum(schedule.cpu.values()))


def test_results_do_not_depend_on_the_workers():
    one, _ = run_tasks(_tasks(), workers=1, progress=False)
    two, schedule = run_tasks(_tasks(), workers=2, progress=False)
    assert two == one
    assert schedule.workers == 2 and set(schedule.worker) == set(one)
    # every task ran on one of the two workers, and the busiest had at least half the CPU
    assert set(schedule.worker.values()) <= {0, 1}
    assert schedule.critical_path() >= 0.5 * sum(schedule.cpu.values()) - 1e-12
    # "run" cannot start before "prepare"
    assert schedule.order.index("prepare") < schedule.order.index("run")


@pytest.mark.parametrize(
    "tasks, message",
    [
        ([Task("a", int), Task("a", int)], "two tasks named"),
        ([Task("a", int, needs="b")], "not a task"),
        ([Task("a", int, needs="b"), Task("b", int, needs="a")], "cycle"),
    ],
)
def test_bad_tasks_are_refused(tasks, message):
    with pytest.raises(InputError, match=message):
        run_tasks(tasks, workers=1, progress=False)


def test_a_failing_task_raises_in_the_caller():
    tasks = [Task("ok", partial(operator.add, 1, 1)), Task("bad", partial(operator.truediv, 1, 0))]
    for workers in (1, 2):
        with pytest.raises(ZeroDivisionError):
            run_tasks(tasks, workers=workers, progress=False)
