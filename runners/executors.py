"""Where trial jobs run: local fresh processes (default), or a Ray cluster (a later milestone).

Each job runs in a process of its own (spawn start method, a one-worker pool per job), so that
(1) the memory a system uses to load its map is measured in a clean process and (2) a worker
that dies — killed, out of memory — fails only its own job, not its neighbours'.

Ctrl-C (SIGINT to the runner) stops at once: the workers ignore SIGINT (a terminal sends it to
the whole process group; the runner decides), queued jobs are cancelled, running workers are
terminated, and ``KeyboardInterrupt`` reaches the caller. Trials already recorded stay recorded,
so the run folder resumes with nothing lost.
"""

from __future__ import annotations

import multiprocessing
import signal
import threading
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


def _ignore_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)


class _Workers:
    """The one-worker pools of the running jobs, so that an interrupted run can end them."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.pools: set[ProcessPoolExecutor] = set()
        self.stopping = False

    def run(self, fn: Callable[[Any], Any], job: Any) -> Any:
        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=1, mp_context=context, initializer=_ignore_sigint) as pool:
            with self.lock:  # submitted (its process started) and registered at once, or not at all
                if self.stopping:
                    raise KeyboardInterrupt
                future = pool.submit(fn, job)
                self.pools.add(pool)
            try:
                return future.result()
            finally:
                with self.lock:
                    self.pools.discard(pool)

    def stop(self) -> None:
        with self.lock:
            self.stopping = True
            pools = list(self.pools)
        for pool in pools:
            for process in list(getattr(pool, "_processes", {}).values()):  # the executor keeps no public handle
                process.terminate()


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
    running = _Workers()
    threads = ThreadPoolExecutor(max_workers=max(1, workers))
    try:
        futures: dict[Future, Any] = {threads.submit(running.run, fn, job): job for job in jobs}
        pending = set(futures)
        while pending:
            done, pending = wait(pending, timeout=poll_s, return_when=FIRST_COMPLETED)
            if on_poll is not None:
                on_poll()
            for future in done:
                try:
                    yield futures[future], future.result(), None
                except Exception as exc:  # noqa: BLE001 - reported per job; the run goes on
                    yield futures[future], None, exc
    except BaseException:  # Ctrl-C, or the caller stopped early: nothing queued may start
        threads.shutdown(wait=False, cancel_futures=True)
        running.stop()
        raise
    finally:
        threads.shutdown(wait=True)
