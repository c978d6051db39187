"""What a job costs the executors beyond its own work: local processes against Ray tasks.

Each job runs in a fresh process on both executors (``runners.executors``), so the cost per job
is a process start plus the imports the job needs. Two kinds of job are timed: ``empty`` (yields
one message, imports nothing) and ``imports`` (imports what a navigation job imports before its
first trial: ``runners.navigation``, numpy, scipy, pybullet, numba ...). Reported: seconds to
open the executor (a private Ray instance starts here), and wall seconds per job with
``--workers`` jobs at once.

    python benchmarks/bench_executors.py --jobs 20 --workers 2 [--executors local,ray]

Optionally (``--run-tiny``) the wall time of ``navtopo-bench run tiny --systems oracle,metric_grid``
with each ``--workers`` value in ``--run-workers`` (default 1,2): the speed-up of a real run.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from runners.executors import open_executor  # noqa: E402


def empty_job(index: int):
    yield {"kind": "done", "index": index, "pid": os.getpid()}


def imports_job(index: int):
    import runners.navigation  # noqa: F401 - the imports a navigation job pays for

    yield {"kind": "done", "index": index, "pid": os.getpid()}


def time_executor(name: str, fn, jobs: int, workers: int) -> dict:
    t0 = time.perf_counter()
    pool = open_executor(name, workers)
    opened = time.perf_counter() - t0
    try:
        t0 = time.perf_counter()
        for index in range(jobs):
            pool.submit(index, fn, index)
        pids, failures = set(), 0
        for event in pool.events(poll_s=0.05):
            if event is not None and event.message is not None:
                pids.add(event.message["pid"])
            if event is not None and event.failure is not None:
                failures += 1
        wall = time.perf_counter() - t0
    finally:
        pool.close()
    return {
        "executor": name,
        "job": fn.__name__,
        "jobs": jobs,
        "workers": workers,
        "open_s": round(opened, 2),
        "wall_s": round(wall, 2),
        "s_per_job": round(wall / jobs, 3),
        "s_per_job_per_worker": round(wall * workers / jobs, 3),
        "processes": len(pids),
        "failures": failures,
    }


def time_tiny_run(workers: int) -> dict:
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "run"
        command = [sys.executable, "-m", "runners.cli", "run", "tiny", "--systems", "oracle,metric_grid"]
        t0 = time.perf_counter()
        done = subprocess.run([*command, "--workers", str(workers), "--out", str(out)], cwd=ROOT, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        if done.returncode != 0:
            raise SystemExit(done.stderr[-2000:])
        records = sorted(
            (json.loads(line) for line in (out / "trials.jsonl").read_text().splitlines()),
            key=lambda r: (r["system"], r["trial"]),
        )
        outcomes = [(r["system"], r["trial"], r["success"], r["travelled_m"]) for r in records]
    return {"run": "tiny oracle,metric_grid", "workers": workers, "wall_s": round(wall, 1), "outcomes": outcomes}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=20)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--executors", default="local,ray")
    parser.add_argument("--run-tiny", action="store_true")
    parser.add_argument("--run-workers", default="1,2")
    args = parser.parse_args()
    for name in args.executors.split(","):
        for fn in (empty_job, imports_job):
            print(json.dumps(time_executor(name, fn, args.jobs, args.workers)), flush=True)
    if args.run_tiny:
        runs = [time_tiny_run(int(w)) for w in args.run_workers.split(",")]
        for run in runs:
            print(json.dumps({k: v for k, v in run.items() if k != "outcomes"}), flush=True)
        print(json.dumps({"same_outcomes": all(r["outcomes"] == runs[0]["outcomes"] for r in runs)}))


if __name__ == "__main__":
    main()
