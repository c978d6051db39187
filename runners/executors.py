"""Where jobs run: fresh local processes (``local``, the default) or a Ray cluster (``ray``).

A job is a generator function ``fn(job)`` and its picklable argument. It runs in a process of its
own — one process per job, so that (1) the memory a system uses to load its map is measured in a
clean process and (2) a process that dies fails only its own job — and every message it yields
(a plain dict) reaches the driver as soon as it is yielded: a trial's record and trajectories
stream back the moment the trial ends, so a crash of the worker, or of the driver, loses at most
the trial that was running. Jobs never write the results folder; the driver alone does.

Order: a job waits in the queue until a slot is free; jobs of a lower ``priority`` start first,
in submission order among equals (several runs share one executor: an earlier run's jobs go
first and a later run's fill the slots it leaves idle, ``runners.driver``). Each event names where
its job ran (``worker``: host, process id and, on Ray, the node id), a fact of the execution like
its timing.

Streaming: ``local`` sends each message through a pipe from the spawned process; ``ray`` runs the
job as a Ray generator task (one ``ObjectRef`` per message, ``max_calls=1`` so that each task gets
a fresh worker process, ``max_retries=0`` so that a trial that killed its worker is not run
again). One driver thread per running job reads its stream into one queue; ``Executor.events``
yields from that queue.

Limits: a message may carry ``"deadline_s"``: the job must yield its next message within that
many seconds of wall clock, else the executor kills it and reports ``Failure("timeout")``. A job
whose process dies (a signal, ``os.abort``, an exit) ends with ``Failure("crashed")``; a job that
raises ends with ``Failure("error")``. The caller decides what a failure means for the work left.

Ctrl-C (SIGINT to the driver) stops at once: local workers ignore SIGINT (a terminal sends it to
the whole process group; the driver decides), and leaving ``events`` (or ``close``) drops the
queued jobs and kills the running ones; ``KeyboardInterrupt`` reaches the caller. Ctrl-C again
during that cleanup is ignored until it ends (``uninterrupted``). A local worker also exits by
itself when its driver is gone (killed with SIGKILL), so nothing runs on unseen.

Ray stays on loopback unless given a cluster's address: before Ray is imported the environment
turns off its usage statistics and points HTTP proxies at a closed local port; a private instance
(``--executor ray`` without ``--ray-address``) starts with ``address="local"``, no dashboard, its
node on 127.0.0.1 and a temporary folder of its own, and is shut down when the executor closes.
"""

from __future__ import annotations

import contextlib
import heapq
import importlib.util
import multiprocessing
import os
import queue
import shutil
import signal
import socket
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

from navkit.errors import BenchError

EXECUTORS = ("local", "ray")
RAY_INSTALL_HINT = "pip install 'navtopo-bench[ray]' (from a clone: pip install -e '.[ray]')"


class ExecutorUnavailable(BenchError):
    """An executor that cannot run (unknown, Ray not installed, no cluster at the address): the
    command cannot start (one line, exit 2)."""


def check_executor(executor: str) -> None:
    """Refuse an executor that cannot run, before any work starts."""
    if executor not in EXECUTORS:
        raise ExecutorUnavailable(f"--executor: unknown executor {executor!r} (choose from {', '.join(EXECUTORS)})")
    if executor == "ray" and importlib.util.find_spec("ray") is None:
        raise ExecutorUnavailable(f"--executor ray: Ray is not installed; {RAY_INSTALL_HINT}")


def one_line(exc: BaseException) -> str:
    return (f"{type(exc).__name__}: {exc}".splitlines() or [type(exc).__name__])[0][:300]


@dataclass
class Failure:
    kind: str  # "error" (the job raised), "crashed" (its process died), "timeout" (a deadline passed)
    detail: str  # one line


@dataclass
class Event:
    """A message a job yielded (``message``), or its end (``done``; ``failure`` if it ended early).
    ``worker``: where the job ran, {host, pid, node} (node: the Ray node id; None locally), once known."""

    key: Any
    message: dict[str, Any] | None = None
    done: bool = False
    failure: Failure | None = None
    worker: dict[str, Any] | None = None


@dataclass
class _Running:
    id: int
    key: Any
    fn: Callable[[Any], Iterator[dict[str, Any]]]
    job: Any
    deadline: float | None = None
    limit_s: float | None = None
    handle: Any = None
    worker: dict[str, Any] | None = None


class Executor:
    """Jobs in, events out: at most ``slots`` jobs run at once; the rest wait, lowest priority first."""

    name = "base"

    def __init__(self, slots: int) -> None:
        self.slots = max(1, int(slots))
        self._queued: list[tuple[int, int, _Running]] = []  # a heap of (priority, submission, job)
        self._running: dict[int, _Running] = {}
        self._inbox: queue.Queue[tuple[int, str, Any]] = queue.Queue()
        self._next_id = 0
        self.counts = {"done": 0, "failed": 0}

    # -- the caller's side -------------------------------------------------------------------
    def submit(self, key: Any, fn: Callable[[Any], Iterator[dict[str, Any]]], job: Any, priority: int = 0) -> None:
        self._next_id += 1
        heapq.heappush(self._queued, (priority, self._next_id, _Running(self._next_id, key, fn, job)))

    @property
    def running(self) -> int:
        return len(self._running)

    @property
    def queued(self) -> int:
        return len(self._queued)

    def events(self, poll_s: float = 0.5) -> Iterator[Event | None]:
        """Events until every submitted job (including those submitted meanwhile) has ended; None
        every ``poll_s`` without news, so that the caller can show progress."""
        try:
            while self._queued or self._running:
                while self._queued and len(self._running) < self.slots:
                    run = heapq.heappop(self._queued)[2]
                    self._running[run.id] = run
                    self._start(run)
                items = []
                try:
                    items.append(self._inbox.get(timeout=poll_s))
                    while True:
                        items.append(self._inbox.get_nowait())
                except queue.Empty:
                    pass
                for run_id, kind, payload in items:  # everything that arrived, before any deadline
                    job = self._running.get(run_id)
                    if job is None:
                        continue  # the rest of a job already ended (killed on its deadline)
                    if kind == "worker":
                        job.worker = payload
                    elif kind == "message":
                        job.limit_s = payload.pop("deadline_s", None)
                        job.deadline = time.monotonic() + job.limit_s if job.limit_s else None
                        yield Event(job.key, message=payload, worker=job.worker)
                    else:
                        del self._running[run_id]
                        self.counts["failed" if payload is not None else "done"] += 1
                        yield Event(job.key, done=True, failure=payload, worker=job.worker)
                now = time.monotonic()
                for run in [r for r in self._running.values() if r.deadline is not None and now > r.deadline]:
                    del self._running[run.id]
                    self._kill(run)
                    self.counts["failed"] += 1
                    yield Event(
                        run.key,
                        done=True,
                        failure=Failure("timeout", f"passed its wall-clock limit of {run.limit_s:g} s"),
                        worker=run.worker,
                    )
                if not items:
                    yield None
        except BaseException:  # Ctrl-C, or the caller stopped early: nothing queued may start
            self.cancel()
            raise

    def cancel(self, keys: Callable[[Any], bool] | None = None) -> None:
        """Drop the queued jobs and kill the running ones: all, or those whose key ``keys`` accepts
        (the jobs of one run that failed; the others go on). A cancelled job sends no event."""
        chosen = keys or (lambda _key: True)
        with uninterrupted():
            self._queued = [entry for entry in self._queued if not chosen(entry[2].key)]
            heapq.heapify(self._queued)
            running = [run for run in self._running.values() if chosen(run.key)]
            for run in running:
                del self._running[run.id]
                self._kill(run)

    def close(self) -> None:
        self.cancel()

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- a backend's side --------------------------------------------------------------------
    def _start(self, run: _Running) -> None:
        raise NotImplementedError

    def _kill(self, run: _Running) -> None:
        raise NotImplementedError

    def _put(self, run: _Running, kind: str, payload: Any) -> None:
        self._inbox.put((run.id, kind, payload))


@contextlib.contextmanager
def uninterrupted() -> Iterator[None]:
    """Ctrl-C pressed again while an executor cleans up (kills its jobs, shuts a private Ray
    instance down: seconds) must not cut the cleanup short and leave processes or temporary files
    behind: SIGINT is ignored until it is done (SIGTERM and SIGKILL still end the driver)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


# ---------------------------------------------------------------------------------------------
# local: a spawned process per job, messages through a pipe


def _exit_with_driver() -> None:
    """End this worker if its driver dies (SIGKILL leaves orphans that nobody reads)."""
    driver = os.getppid()

    def watch() -> None:
        while True:
            time.sleep(1.0)
            if os.getppid() != driver:
                os._exit(1)

    threading.Thread(target=watch, daemon=True).start()


def one_thread_per_job() -> None:
    """A job computes on one core: the pool runs one job per core. Torch's default of a thread per
    core made two jobs on 2 cores slower than one (OpenMP workers spin waiting for cores: a sweep of
    one size took 72 s with two workers against 57 s with one, on an idle machine), and one thread
    whatever the number of workers keeps results independent of it."""
    for name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ[name] = "1"
    torch = sys.modules.get("torch")  # imported already when unpickling the job's function
    if torch is not None:
        torch.set_num_threads(1)


def _local_worker(fn: Callable[[Any], Iterator[dict[str, Any]]], job: Any, sender: Any) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _exit_with_driver()
    one_thread_per_job()
    try:
        for message in fn(job):
            sender.send(("message", message))
        sender.send(("end", None))
    except Exception as exc:  # noqa: BLE001 - reported as the job's failure
        sender.send(("raised", one_line(exc)))
    finally:
        sender.close()


def death(exitcode: int | None) -> str:
    """How a process ended, in words: 'killed by SIGABRT', 'exited with status 3'."""
    if exitcode is not None and exitcode < 0:
        try:
            return f"worker process killed by {signal.Signals(-exitcode).name}"
        except ValueError:
            return f"worker process killed by signal {-exitcode}"
    return f"worker process exited with status {exitcode} before finishing its job"


class LocalExecutor(Executor):
    name = "local"

    def __init__(self, slots: int | None = None) -> None:
        super().__init__(slots or os.cpu_count() or 1)
        self._context = multiprocessing.get_context("spawn")

    def _start(self, run: _Running) -> None:
        receiver, sender = self._context.Pipe(duplex=False)
        process = self._context.Process(target=_local_worker, args=(run.fn, run.job, sender), name=f"job-{run.id}")
        process.start()
        sender.close()  # the worker holds the only sending end: its death ends our reads
        run.handle = process
        run.worker = {"host": socket.gethostname(), "pid": process.pid, "node": None}
        threading.Thread(target=self._pump, args=(run, receiver, process), daemon=True).start()

    def _pump(self, run: _Running, receiver: Any, process: Any) -> None:
        ending: tuple[str, Any] | None = None
        try:
            while True:
                kind, payload = receiver.recv()
                if kind != "message":
                    ending = (kind, payload)
                    break
                self._put(run, "message", payload)
        except (EOFError, OSError):
            pass
        finally:
            receiver.close()
        process.join()
        if ending is not None and ending[0] == "end":
            self._put(run, "end", None)
        elif ending is not None:
            self._put(run, "end", Failure("error", ending[1]))
        else:
            self._put(run, "end", Failure("crashed", death(process.exitcode)))

    def _kill(self, run: _Running) -> None:
        if run.handle is not None and run.handle.is_alive():
            run.handle.kill()


# ---------------------------------------------------------------------------------------------
# ray: a generator task per job

# Ray reaches for the network by default (usage statistics, cloud metadata probes from its
# dashboard, proxies); these keep a driver and a private instance on loopback.
RAY_LOOPBACK_ENV = {
    "RAY_USAGE_STATS_ENABLED": "0",
    "RAY_USAGE_STATS_REPORT_URL": "http://127.0.0.1:9/",
    "http_proxy": "http://127.0.0.1:9",
    "https_proxy": "http://127.0.0.1:9",
    "no_proxy": "127.0.0.1,localhost",
    "RAY_AUTH_MODE": "disabled",
}


def _probe(address: str, timeout_s: float = 5.0) -> None:
    """Raise ConnectionError at once if nothing listens at HOST:PORT (``auto`` is not probed)."""
    if address == "auto" or ":" not in address:
        return
    host, port = address.rsplit(":", 1)
    try:
        socket.create_connection((host, int(port)), timeout=timeout_s).close()
    except (OSError, ValueError) as exc:
        raise ConnectionError(f"nothing answers at {address} ({exc})") from None


def _ray_job(fn: Callable[[Any], Iterator[dict[str, Any]]], job: Any, sys_path: list[str]) -> Iterator[dict[str, Any]]:
    """The task: first where it runs (for ``Event.worker``), then the job's messages."""
    import sys

    import ray

    yield {"host": socket.gethostname(), "pid": os.getpid(), "node": ray.get_runtime_context().get_node_id()}
    sys.path.extend(p for p in sys_path if p not in sys.path)  # as a spawned local worker gets it
    one_thread_per_job()
    yield from fn(job)


class RayExecutor(Executor):
    """Jobs as Ray tasks. ``address`` None: a private local instance of ``slots`` CPUs (default: the
    machine's cores); else a running cluster (``auto`` or HOST:PORT), whose CPUs set the slots."""

    name = "ray"

    def __init__(self, slots: int | None = None, address: str | None = None) -> None:
        check_executor("ray")
        for key, value in RAY_LOOPBACK_ENV.items():
            os.environ.setdefault(key, value)
        loopback = address is None or address.rsplit(":", 1)[0] in ("127.0.0.1", "localhost")
        if loopback:
            # else Ray swaps a loopback address for the one it guesses from a UDP "connect" to a
            # public address (read once, when Ray is imported; see ray._private.services)
            os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
        self._temp_dir = None
        self._ray = None
        self._queued, self._running = [], {}  # close() may run before the executor is complete
        if address is None:
            self._temp_dir = tempfile.mkdtemp(prefix="ntb-ray-")  # short: Ray's socket paths must fit 107 bytes
            os.environ["RAY_TMPDIR"] = self._temp_dir
        import ray

        self._ray = ray
        try:
            if address is None:
                ray.init(
                    address="local",
                    num_cpus=slots or os.cpu_count() or 1,
                    include_dashboard=False,
                    _node_ip_address="127.0.0.1",
                    _temp_dir=self._temp_dir,
                    log_to_driver=False,
                    logging_level="WARNING",  # type: ignore[arg-type] # Ray takes a level's name too (its default: "info")
                )
            else:
                _probe(address)  # Ray itself waits minutes for an address where nothing listens
                extra: dict[str, Any] = {"_node_ip_address": "127.0.0.1"} if loopback else {}
                ray.init(address=address, log_to_driver=False, logging_level="WARNING", **extra)  # type: ignore[arg-type]
        except Exception as exc:  # noqa: BLE001 - no cluster to run on: the command cannot start
            self.close()
            where = f"--ray-address {address}: cannot join the Ray cluster" if address else "--executor ray: Ray did not start"
            raise ExecutorUnavailable(f"{where}: {one_line(exc)}") from None
        super().__init__(slots or int(ray.cluster_resources().get("CPU", 1)))
        self._task = ray.remote(num_cpus=1, max_calls=1, max_retries=0)(_ray_job)
        # a private instance shares this machine: its workers find what this process imports
        # (e.g. a system registered by the user's module); on a cluster each node has its own
        self._sys_path = list(sys.path) if address is None else []

    def _start(self, run: _Running) -> None:
        run.handle = self._task.remote(run.fn, run.job, self._sys_path)
        threading.Thread(target=self._pump, args=(run,), daemon=True).start()

    def _pump(self, run: _Running) -> None:
        ray = self._ray
        assert ray is not None  # set before any job starts
        try:
            for number, ref in enumerate(run.handle):
                self._put(run, "worker" if number == 0 else "message", ray.get(ref))
        except ray.exceptions.RayTaskError as exc:  # the job raised: its own exception, one line
            cause = exc.cause if isinstance(exc.cause, BaseException) else exc
            self._put(run, "end", Failure("error", one_line(cause)))
        except ray.exceptions.RayError as exc:  # the worker died, or its node
            self._put(run, "end", Failure("crashed", f"worker process died ({type(exc).__name__})"))
        except Exception as exc:  # noqa: BLE001 - the connection to Ray ended
            self._put(run, "end", Failure("crashed", one_line(exc)))
        else:
            self._put(run, "end", None)

    def _kill(self, run: _Running) -> None:
        if run.handle is not None and self._ray is not None:
            try:
                self._ray.cancel(run.handle, force=True)
            except Exception:  # noqa: BLE001 - already finished
                pass

    def close(self) -> None:
        with uninterrupted():
            self._close()

    def _close(self) -> None:
        super().close()
        if self._ray is not None and self._ray.is_initialized():
            self._ray.shutdown()
        if self._temp_dir is not None:
            for _ in range(3):  # Ray's processes may still write their last files while they end
                shutil.rmtree(self._temp_dir, ignore_errors=True)
                if not os.path.exists(self._temp_dir):
                    break
                time.sleep(0.5)


def open_executor(executor: str = "local", workers: int | None = None, address: str | None = None) -> Executor:
    """The executor of that name (``check_executor`` first); close it (or use ``with``) when done."""
    check_executor(executor)
    if executor == "ray":
        return RayExecutor(workers, address)
    if address is not None:
        raise ExecutorUnavailable("--ray-address: only with --executor ray")
    return LocalExecutor(workers)
