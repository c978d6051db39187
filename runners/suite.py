"""A suite file: the runs of a study in one YAML file (``navtopo-bench run --suite FILE``).

    format: navtopo-suite/1
    systems: [navtopo, metric_grid]     # default of every entry (else navtopo, metric_grid, oracle)
    trials: 5                           # default of every entry (else all the scenario's trials)
    runs:
      - scenarios: [corridor_150m, scenes/office_t.yaml]   # bundled names or paths (from this file)
        seeds: [1, 2, 3]                # default: the scenario's own seed
        settings: [precise, noisy]      # default: the scenario file's own noise
      - scenarios: [loop_office]
        systems: [navtopo]
        trials: 2

Each entry is one run per scenario x setting x seed, as ``run A B --seeds --setting`` makes; its
folder is ``<out>/<scenario name>/s<seed>`` (``-<setting>`` appended when one is given), so that
the same command again keeps the finished runs and resumes the others, as sweeps do. A bad file is
one ``SuiteError`` naming the file, the key and the reason (``suite.yaml: runs.0.seeds.1: ...``),
raised before anything is written.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, ValidationError

from runners.protocol import SETTINGS
from runners.systems import system_names
from scenarios import Scenario, ScenarioError, load_scenario
from scenarios.schema import Strict, first_problem, read_yaml

FORMAT = "navtopo-suite/1"
DEFAULT_SYSTEMS = ("navtopo", "metric_grid", "oracle")  # the `run` command's

Name = Annotated[str, Field(strict=True, min_length=1)]
Count = Annotated[int, Field(strict=True, ge=0)]


class SuiteError(ScenarioError):
    """A suite file that cannot be used; ``str(error)`` is the one line to show a user."""


class EntrySpec(Strict):
    scenarios: Annotated[list[Name], Field(min_length=1)]
    seeds: Annotated[list[Count], Field(min_length=1)] | None = None
    settings: Annotated[list[Name], Field(min_length=1)] | None = None
    systems: Annotated[list[Name], Field(min_length=1)] | None = None
    trials: Count | None = None


class SuiteSpec(Strict):
    format: Literal["navtopo-suite/1"]
    systems: Annotated[list[Name], Field(min_length=1)] | None = None
    trials: Count | None = None
    runs: Annotated[list[EntrySpec], Field(min_length=1)]


@dataclass
class SuiteRun:
    """One run of a suite: ``folder`` is relative to the suite's results folder."""

    scenario: Scenario
    seed: int
    setting: str | None
    systems: list[str]
    trials: int | None
    folder: Path
    entry: int  # its entry in ``runs``


def read_suite(path: Path) -> list[SuiteRun]:
    """The runs of the suite file at ``path``, every scenario loaded; ``SuiteError`` on the first problem."""
    data = read_yaml(path, path)  # a ScenarioError naming the file and line: the same one line
    if not isinstance(data, dict):
        raise SuiteError(path, "", f"not a YAML mapping of keys (a suite file: format: {FORMAT}, runs: [...])")
    try:
        spec = SuiteSpec.model_validate(data)
    except ValidationError as exc:
        raise SuiteError(path, *first_problem(exc)) from None
    known = system_names()
    runs: list[SuiteRun] = []
    taken: dict[Path, int] = {}
    loaded: dict[str, Scenario] = {}  # a scenario named by several entries is loaded once
    for number, entry in enumerate(spec.runs):
        systems_key = f"runs.{number}.systems" if entry.systems is not None else "systems"
        systems = list(entry.systems or spec.systems or DEFAULT_SYSTEMS)
        if unknown := [s for s in systems if s not in known]:
            raise SuiteError(path, systems_key, f"unknown system(s) {', '.join(unknown)} (available: {', '.join(sorted(known))})")
        if len(set(systems)) < len(systems):
            raise SuiteError(path, systems_key, "a system is named twice")
        if unknown := [s for s in entry.settings or [] if s not in SETTINGS]:
            raise SuiteError(
                path, f"runs.{number}.settings", f"unknown setting {', '.join(unknown)} (choose from {', '.join(SETTINGS)})"
            )
        trials = entry.trials if entry.trials is not None else spec.trials
        for k, name in enumerate(entry.scenarios):
            if name not in loaded:
                loaded[name] = _load(path, f"runs.{number}.scenarios.{k}", name)
            scenario = loaded[name]
            settings: list[str | None] = list(entry.settings) if entry.settings else [None]  # None: the file's own noise
            for setting in settings:
                for seed in entry.seeds or [scenario.spec.seed]:
                    folder = Path(scenario.name) / (f"s{seed}" + (f"-{setting}" if setting else ""))
                    if folder in taken:
                        raise SuiteError(
                            path,
                            f"runs.{number}",
                            f"{folder} is run twice (by runs.{taken[folder]} too): each scenario, seed and setting once",
                        )
                    taken[folder] = number
                    runs.append(SuiteRun(scenario, seed, setting, systems, trials, folder, number))
    return runs


def _load(suite: Path, key: str, name: str) -> Scenario:
    """A bundled scenario by name, or a YAML file by its path from the suite file's folder."""
    looks_like_path = "/" in name or Path(name).suffix in (".yaml", ".yml")
    target = suite.parent / name if looks_like_path else name
    try:
        return load_scenario(target)
    except ScenarioError as exc:
        raise SuiteError(suite, key, str(exc)) from None
    except Exception as exc:  # noqa: BLE001 - a bug or an odd file: still one line
        raise SuiteError(suite, key, f"{name}: cannot be loaded: {type(exc).__name__}: {exc}") from None
