"""The results folder of a run: the one container every tool reads (DESIGN.md, "Contracts").

Its JSON files are the records of ``reports.records`` (manifest, trial records, mapping and
navigation reports, summary), written here through those models. Writes are atomic (temporary
file + rename) except ``trials.jsonl``, which is appended one flushed line per finished trial; a
torn last line (a crash mid-write) is ignored on reading, so ``--resume`` loses no finished trial
and duplicates none. Every file is created with the user's umask (0644 for the usual 022),
temporary files included.
"""

from __future__ import annotations

import datetime as dt
import fcntl
import io
import json
import os
import socket
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from navkit.errors import BenchError
from navkit.files import atomic_write
from reports.records import Record, TrialRecord, read_trials
from reports.records import read_json as read_json  # the one reader of a results folder's JSON files


class FolderInUse(BenchError):
    """A run folder another driver holds (``RunDir.hold``): refused before anything is written (exit 2)."""

    exit_code = 2


def write_json(path: Path, data: Any) -> None:
    """``data`` (a record, or plain values holding records) as indented JSON, atomically."""
    atomic_write(path, json.dumps(data, indent=2, allow_nan=False, default=_plain) + "\n")


def _plain(value: Any) -> Any:
    """Records as their JSON objects; numpy scalars and arrays as plain JSON values."""
    if isinstance(value, Record):
        return value.as_json()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def quaternion_z(yaw: NDArray) -> NDArray:
    return np.stack([np.zeros_like(yaw), np.zeros_like(yaw), np.sin(yaw / 2), np.cos(yaw / 2)], axis=-1)


def write_tum(path: Path, rows: NDArray) -> None:
    """rows (T, 4): time, x, y, yaw -> TUM lines 'timestamp x y z qx qy qz qw' (readable by evo)."""
    rows = np.asarray(rows, dtype=np.float64).reshape(-1, 4)
    q = quaternion_z(rows[:, 3])
    table = np.column_stack([rows[:, 0], rows[:, 1], rows[:, 2], np.zeros(len(rows)), q])
    buffer = io.StringIO()
    np.savetxt(buffer, table, fmt="%.6f")
    atomic_write(path, buffer.getvalue())


MAP_FRAME_FILE = "map_frame.json"


def write_map_frame(path: Path, world_from_map: NDArray) -> None:
    """Where the map frame of the ``*.est.tum`` files lies in the scenario frame of the ``*.tum``
    files: the pose [x, y, yaw] of the mapping route's start, in evo's transform format
    (``evo_traj tum trial-0.est.tum --transform_left map_frame.json``), so the error is measured
    without an alignment that would hide drift."""
    x, y, yaw = (float(v) for v in np.asarray(world_from_map, dtype=np.float64))
    qx, qy, qz, qw = (float(v) for v in quaternion_z(np.array(yaw)))
    write_json(
        path,
        {
            "parent_frame": "scenario",
            "child_frame": "map",
            "x": x,
            "y": y,
            "z": 0.0,
            "qx": qx,
            "qy": qy,
            "qz": qz,
            "qw": qw,
            "yaw_deg": float(np.degrees(yaw)),
        },
    )


class RunDir:
    """``results/<scenario>/<run-id>/`` and the files in it."""

    def __init__(self, root: Path) -> None:
        self.root = Path(root)
        self.warnings = 0  # trials of this execution that failed in their worker (their record has a detail)
        # system -> (stage, why): its mapping failed, or its navigation could not start (its map
        # cannot be loaded); its trials are not run, and the run stays unfinished for --resume
        self.failed_stages: dict[str, tuple[str, str]] = {}

    @property
    def manifest_path(self) -> Path:
        return self.root / "manifest.json"

    @property
    def scenario_dir(self) -> Path:
        """The scenario file and its maps as the run read them (``run.keep_scenario``)."""
        return self.root / "scenario"

    @property
    def trials_path(self) -> Path:
        return self.root / "trials.jsonl"

    @property
    def summary_path(self) -> Path:
        return self.root / "summary.json"

    def mapping_path(self, system: str) -> Path:
        return self.root / "mapping" / f"{system}.json"

    def navigation_path(self, system: str) -> Path:
        return self.root / "navigation" / f"{system}.json"

    def map_dir(self, system: str) -> Path:
        return self.root / "maps" / system

    def trajectory_path(self, system: str, trial: int, estimate: bool = False) -> Path:
        return self.root / "trajectories" / system / f"trial-{trial}{'.est' if estimate else ''}.tum"

    @contextmanager
    def hold(self) -> Iterator[None]:
        """The folder for one driver: an exclusive lock on ``.driver.lock`` for the run's whole life,
        which names its holder (host, pid, start, command). The operating system frees it when the
        driver's process ends, however it ends. ``FolderInUse`` if another driver holds it."""
        self.root.mkdir(parents=True, exist_ok=True)
        path = self.root / ".driver.lock"
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd)
            os.close(fd)
            raise FolderInUse(
                f"{self.root}: another driver is running this run ({holder}); one driver per run folder: "
                "wait for it to end, or stop it and --resume"
            ) from None
        try:
            me = {
                "host": socket.gethostname(),
                "pid": os.getpid(),
                "since": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
                "command": " ".join([os.path.basename(sys.argv[0]), *sys.argv[1:]]),
            }
            os.ftruncate(fd, 0)
            os.pwrite(fd, (json.dumps(me) + "\n").encode(), 0)
            yield
        finally:
            os.ftruncate(fd, 0)
            fcntl.flock(fd, fcntl.LOCK_UN)
            os.close(fd)

    def append_trial(self, record: TrialRecord) -> None:
        """Append one record as one flushed line, under a lock shared by every writer process."""
        self.root.mkdir(parents=True, exist_ok=True)
        line = json.dumps(record.as_json(), allow_nan=False)
        with open(self.root / ".trials.lock", "a") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            try:
                with open(self.trials_path, "a") as f:
                    f.write(line + "\n")
                    f.flush()
                    os.fsync(f.fileno())
            finally:
                fcntl.flock(lock, fcntl.LOCK_UN)

    def read_trials(self) -> list[TrialRecord]:
        """Finished trials, first record of each (system, trial); torn and unreadable lines skipped."""
        return read_trials(self.trials_path, skip_unreadable=True)

    def repair_trials(self) -> None:
        """Drop a torn last line so that appends start on a fresh line."""
        if not self.trials_path.is_file():
            return
        text = self.trials_path.read_text()
        if text and not text.endswith("\n"):
            atomic_write(self.trials_path, text[: text.rfind("\n") + 1])


def _holder(fd: int) -> str:
    """Who holds a driver lock, as its file says (it may be mid-write: then "unknown")."""
    try:
        data = json.loads(os.pread(fd, 4096, 0).decode())
        return f"pid {data['pid']} on {data['host']} since {data['since']}: {data['command']}"
    except (OSError, ValueError, KeyError, TypeError):
        return "holder unknown"


def disk_bytes(directory: Path) -> int:
    return sum(p.stat().st_size for p in Path(directory).rglob("*") if p.is_file())


def point_latest(run_dir: Path) -> None:
    """``<parent>/latest`` -> run_dir (a relative symlink, replaced atomically)."""
    link = run_dir.parent / "latest"
    tmp = run_dir.parent / f".latest.{os.getpid()}"
    tmp.unlink(missing_ok=True)
    os.symlink(run_dir.name, tmp)
    os.replace(tmp, link)
