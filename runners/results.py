"""The results folder of a run: the one container every tool reads (DESIGN.md, "Contracts").

Writes are atomic (temporary file + rename) except ``trials.jsonl``, which is appended one
flushed line per finished trial; a torn last line (a crash mid-write) is ignored on reading, so
``--resume`` loses no finished trial and duplicates none. Every file is created with the user's
umask (0644 for the usual 022), temporary files included.
"""

from __future__ import annotations

import fcntl
import io
import json
import os
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from navkit.files import atomic_write


def write_json(path: Path, data: Any) -> None:
    atomic_write(path, json.dumps(data, indent=2, allow_nan=False, default=_plain) + "\n")


def _plain(value: Any) -> Any:
    """numpy scalars and arrays as plain JSON values."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def read_json(path: Path) -> Any:
    return json.loads(path.read_text())


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
    def trials_path(self) -> Path:
        return self.root / "trials.jsonl"

    @property
    def summary_path(self) -> Path:
        return self.root / "summary.json"

    def mapping_path(self, system: str) -> Path:
        return self.root / "mapping" / f"{system}.json"

    def map_dir(self, system: str) -> Path:
        return self.root / "maps" / system

    def trajectory_path(self, system: str, trial: int, estimate: bool = False) -> Path:
        return self.root / "trajectories" / system / f"trial-{trial}{'.est' if estimate else ''}.tum"

    def append_trial(self, record: dict[str, Any]) -> None:
        """Append one record as one flushed line, under a lock shared by every writer process."""
        self.root.mkdir(parents=True, exist_ok=True)
        line = json.dumps(record, allow_nan=False)
        with open(self.root / ".trials.lock", "a") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            try:
                with open(self.trials_path, "a") as f:
                    f.write(line + "\n")
                    f.flush()
                    os.fsync(f.fileno())
            finally:
                fcntl.flock(lock, fcntl.LOCK_UN)

    def read_trials(self) -> list[dict[str, Any]]:
        """Finished trials, first record of each (system, trial); torn lines skipped."""
        if not self.trials_path.is_file():
            return []
        records, seen = [], set()
        text = self.trials_path.read_text()
        lines = text.split("\n")
        if not text.endswith("\n"):
            lines = lines[:-1]  # a torn last line: the trial did not finish writing
        for line in lines:
            if not line.strip():
                continue
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                continue
            key = (record.get("system"), record.get("trial"))
            if key in seen:
                continue
            seen.add(key)
            records.append(record)
        return records

    def repair_trials(self) -> None:
        """Drop a torn last line so that appends start on a fresh line."""
        if not self.trials_path.is_file():
            return
        text = self.trials_path.read_text()
        if text and not text.endswith("\n"):
            atomic_write(self.trials_path, text[: text.rfind("\n") + 1])


class TrialsTail:
    """Follows trials.jsonl: the complete records appended since the last call."""

    def __init__(self, run: RunDir, skip: set[tuple[str, int]] | None = None) -> None:
        self.path = run.trials_path
        self.offset = self.path.stat().st_size if self.path.is_file() else 0
        self.skip = set(skip or ())

    def new_records(self) -> list[dict[str, Any]]:
        if not self.path.is_file():
            return []
        with open(self.path) as f:
            f.seek(self.offset)
            text = f.read()
        end = text.rfind("\n") + 1  # only whole lines; a line being written waits for the next call
        self.offset += len(text[:end].encode())
        records = []
        for line in text[:end].splitlines():
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                continue
            key = (record.get("system"), record.get("trial"))
            if key not in self.skip:
                self.skip.add(key)
                records.append(record)
        return records


def disk_bytes(directory: Path) -> int:
    return sum(p.stat().st_size for p in Path(directory).rglob("*") if p.is_file())


def point_latest(run_dir: Path) -> None:
    """``<parent>/latest`` -> run_dir (a relative symlink, replaced atomically)."""
    link = run_dir.parent / "latest"
    tmp = run_dir.parent / f".latest.{os.getpid()}"
    tmp.unlink(missing_ok=True)
    os.symlink(run_dir.name, tmp)
    os.replace(tmp, link)
