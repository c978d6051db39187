"""Where trial jobs run: local fresh processes (default), or a Ray cluster (a later milestone).

Each job runs in a process of its own (spawn start method, a one-worker pool per job), so that
(1) the memory a system uses to load its map is measured in a clean process and (2) a worker
that dies — killed, out of memory — fails only its own job, not its neighbours'.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, ThreadPoolExecutor, wait
from typing import Any

EXECUTORS = ("local", "ray")


class ExecutorUnavailable(RuntimeError):
    pass


def check_executor(executor: str) -> None:
    """Refuse an executor that cannot run, before any work starts."""
    if executor == "ray":
        raise ExecutorUnavailable(
            "--executor ray is not part of this version yet (cluster runs are a later milestone); use --executor local"
        )
    if executor not in EXECUTORS:
        raise ExecutorUnavailable(f"--executor: unknown executor {executor!r} (choose from {', '.join(EXECUTORS)})")


def _in_own_process(fn: Callable[[Any], Any], job: Any) -> Any:
    with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
        return pool.submit(fn, job).result()


def run_jobs(
    fn: Callable[[Any], Any],
    jobs: list[Any],
    workers: int,
    executor: str = "local",
    address: str | None = None,
    on_poll: Callable[[], None] | None = None,
    poll_s: float = 0.5,
) -> Iterator[tuple[Any, Any, BaseException | None]]:
    """Yield (job, result, error) as jobs finish; ``on_poll`` is called while they run."""
    check_executor(executor)
    with ThreadPoolExecutor(max_workers=max(1, workers)) as threads:
        futures: dict[Future, Any] = {threads.submit(_in_own_process, fn, job): job for job in jobs}
        pending = set(futures)
        while pending:
            done, pending = wait(pending, timeout=poll_s, return_when=FIRST_COMPLETED)
            if on_poll is not None:
                on_poll()
            for future in done:
                try:
                    yield futures[future], future.result(), None
                except BaseException as exc:  # noqa: BLE001 - reported per job; the run goes on
                    yield futures[future], None, exc
