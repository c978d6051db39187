"""Many runs, one executor: the driver's loop.

A command may ask for many runs (``run A B --seeds 1,2,3``, a suite file, the sizes of a sweep).
They share one executor and are in flight together, so that a run's tail (its last mapping job
while the others are done, its last trials) leaves no slot idle and Ray starts once.

A run is written as *steps*: a generator that yields the jobs it wants started (a list, maybe
empty) and receives, at each yield, the next event of one of its own jobs; it returns when it is
done (``runners.run.run_steps``: mapping, then navigation once its own mapping is in, then the
summary). ``drive`` starts every run's steps in order, submits their jobs to the executor with the
run's place in the list as priority — an earlier run's jobs start first, a later run's fill the
slots it leaves — and hands each event to the run whose job it is. Only this process writes the
runs' folders. A run that raises ends alone: its queued jobs are dropped, its running ones killed,
and the other runs go on. Ctrl-C (or any other ``BaseException``) ends every job and propagates.
"""

from __future__ import annotations

import dataclasses
import traceback
from collections.abc import Callable, Generator, Iterator
from dataclasses import dataclass
from typing import Any

from runners.executors import Event, Executor

JobFunction = Callable[[Any], Iterator[dict[str, Any]]]
Submission = tuple[Any, JobFunction, Any]  # (the job's key within its run, the job function, its argument)
Steps = Generator[list[Submission], Event, Any]


@dataclass
class Outcome:
    """How a run's steps ended: ``value`` (what they returned) or ``error`` (what they raised, with
    its ``traceback``); neither if the steps still waited for events when no job was left (a bug)."""

    value: Any = None
    error: Exception | None = None
    traceback: str = ""


def drive(steps: list[Steps], pool: Executor, on_jobs: Callable[[dict[str, int]], None] | None = None) -> list[Outcome]:
    """Run every steps generator to its end on ``pool``; one outcome each, in order.

    on_jobs({done, failed, running, queued}): the executor's jobs, all runs together, while they run."""
    outcomes = [Outcome() for _ in steps]
    waiting: dict[int, Steps] = {}

    def advance(index: int, event: Event | None) -> None:
        try:
            submissions = next(waiting[index]) if event is None else waiting[index].send(event)
        except StopIteration as end:
            outcomes[index].value = end.value
            del waiting[index]
            return
        except Exception as exc:  # noqa: BLE001 - this run failed; the others go on
            outcomes[index].error, outcomes[index].traceback = exc, traceback.format_exc()
            del waiting[index]
            pool.cancel(lambda key: key[0] == index)
            return
        for key, function, job in submissions:
            pool.submit((index, key), function, job, priority=index)

    try:
        for index, run_steps in enumerate(steps):
            waiting[index] = run_steps
            advance(index, None)
        for event in pool.events():
            if on_jobs is not None:
                on_jobs({**pool.counts, "running": pool.running, "queued": pool.queued})
            if event is None:
                continue
            index, key = event.key
            if index in waiting:
                advance(index, dataclasses.replace(event, key=key))
    except BaseException:  # Ctrl-C, or a bug of the driver: nothing may run on unseen
        pool.cancel()
        raise
    for index in list(waiting):
        outcomes[index].error = RuntimeError("its steps waited for events of jobs that never were submitted")
        waiting.pop(index).close()
    return outcomes
