"""Refusals several commands share, each one line and exit 2 (``Refused``) before any work.

Numbers (nan, infinite, out of range), comma lists (a name twice), ``--systems``, the scenario a
command names, an output file or folder that cannot be written (checked by a real write: root
passes every permission check), the executor flags.
"""

from __future__ import annotations

import math
import os
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from navkit.errors import BenchError
from runners.commands.console import note
from runners.commands.errors import Refused
from runners.executors import ExecutorUnavailable, check_executor

if TYPE_CHECKING:
    from scenarios import Scenario

IMAGE_SUFFIXES = (".png", ".pdf", ".svg", ".jpg", ".jpeg")
LOCAL_WORKERS_PER_CORE = 4  # each local worker holds a simulator and the network weights (~0.5 GB)


def check_number(flag: str, value: float | None, unit: str, low: float, high: float = math.inf, finite: bool = True) -> None:
    """Refuse a number flag that is nan, infinite (unless ``finite`` is False) or outside
    [low, high]: typer's own range check would call nan "not greater than" its bound."""
    if value is None:
        return
    if math.isnan(value) or (finite and math.isinf(value)) or not low <= value <= high:
        bound = f"at least {low:,.12g}" if high == math.inf else f"{low:,.12g} to {high:,.12g}"
        raise Refused(f"{flag} {value:g}: expected {'a finite' if finite else 'a'} number of {unit}, {bound}")


def once_each(flag: str, raw: str, items: Sequence[object], what: str) -> None:
    """Refuse a comma list ``raw`` of ``flag`` whose parsed ``items`` repeat one."""
    if len(set(items)) < len(items):
        raise Refused(f"{flag} {raw!r}: {what}")


def systems_list(systems: str) -> list[str]:
    """The names of ``--systems``: known, at least one, none twice."""
    from runners.systems import system_names

    known = system_names()
    names = [s.strip() for s in systems.split(",") if s.strip()]
    unknown = [s for s in names if s not in known]
    if unknown:
        raise Refused(f"--systems: unknown system(s) {', '.join(unknown)} (available: {', '.join(sorted(known))})")
    if not names:
        raise Refused(f"--systems {systems!r}: give at least one system (available: {', '.join(sorted(known))})")
    once_each("--systems", systems, names, "a system is named twice")
    return names


def check_executor_flags(executor: str, ray_address: str | None, workers: int | None = None) -> None:
    """Refuse an unknown executor, Ray when it is not installed, an address without Ray
    (``ExecutorUnavailable``), more local workers than the machine can hold."""
    check_executor(executor)
    if ray_address is not None and executor != "ray":
        raise ExecutorUnavailable("--ray-address: only with --executor ray")
    cores = os.cpu_count() or 1
    if executor == "local" and workers is not None and workers > LOCAL_WORKERS_PER_CORE * cores:
        raise Refused(
            f"--workers {workers}: more than {LOCAL_WORKERS_PER_CORE} per core on this machine ({cores} cores; each "
            "worker holds a simulator and the network weights, ~0.5 GB); use --executor ray for a cluster"
        )


def open_scenario(name: str, with_trials: bool = True, quiet: bool = False) -> Scenario:
    """The scenario a command names (a bundled name or a YAML file), its notes printed; a file
    that does not load is its ``ScenarioError``, anything else one line naming the file."""
    from scenarios import load_scenario

    try:
        scenario = load_scenario(name, with_trials=with_trials)
    except BenchError:
        raise
    except Exception as exc:  # noqa: BLE001 - a bug or an odd file: still one line, naming the file
        raise Refused(f"{name}: cannot be loaded: {type(exc).__name__}: {exc}") from None
    if not quiet:
        for line in scenario.notes:
            note(line)
    return scenario


def writable_file(path: Path, option: str, suffixes: tuple[str, ...] | None = None) -> Path:
    """Refuse an output file that cannot be written, before any work is done."""
    if suffixes is not None and path.suffix.lower() not in suffixes:
        raise Refused(f"{option} {path}: the file name must end in {' or '.join(suffixes)}")
    if path.is_dir():
        raise Refused(f"{option} {path}: is a folder; give a file name")
    writable_dir(path.parent, option, named=path)
    return path


def writable_dir(path: Path, option: str, named: Path | None = None) -> Path:
    """Refuse a folder that cannot be made or written (an ancestor that is a file, no permission);
    the message names ``named`` (default: the folder)."""
    probe = Path(path)
    while not probe.exists():
        if probe.parent == probe:
            break
        probe = probe.parent
    named = path if named is None else named
    if probe.exists() and not probe.is_dir():
        raise Refused(f"{option} {named}: {probe} is a file, not a folder")
    if probe.exists() and not os.access(probe, os.W_OK | os.X_OK):
        raise Refused(f"{option} {named}: {probe} is not writable")
    if probe.is_dir():
        # os.access says yes to root everywhere: a read-only mount or /sys answers only a real write
        # (an unnamed file where the system has them, else one removed at once: nothing is left)
        try:
            with tempfile.TemporaryFile(dir=probe):
                pass
        except OSError as exc:
            raise Refused(f"{option} {named}: {probe} is not writable ({exc.strerror or exc})") from None
    return path
