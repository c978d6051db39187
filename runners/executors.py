"""Where trial jobs run: a local pool of fresh processes (default), or a Ray cluster (later).

Each job runs in a fresh process (``max_tasks_per_child=1`` under the spawn start method), so
that the memory a system uses to load its map is measured in a clean process.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any


class ExecutorUnavailable(RuntimeError):
    pass


def run_local(fn: Callable[[Any], Any], jobs: list[Any], workers: int) -> Iterator[tuple[Any, Any, BaseException | None]]:
    """Yield (job, result, error) as jobs finish; a job that raises yields its exception."""
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=max(1, workers), mp_context=context, max_tasks_per_child=1) as pool:
        futures = {pool.submit(fn, job): job for job in jobs}
        for future in as_completed(futures):
            job = futures[future]
            try:
                yield job, future.result(), None
            except BaseException as exc:  # noqa: BLE001 - reported per job, the run goes on
                yield job, None, exc


def run_jobs(
    fn: Callable[[Any], Any], jobs: list[Any], workers: int, executor: str = "local", address: str | None = None
) -> Iterator[tuple[Any, Any, BaseException | None]]:
    if executor == "local":
        return run_local(fn, jobs, workers)
    if executor == "ray":
        raise ExecutorUnavailable(
            "the ray executor is not part of this version yet (cluster runs are a later milestone); use --executor local"
        )
    raise ExecutorUnavailable(f"unknown executor {executor!r} (local, ray)")
