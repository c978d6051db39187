"""The manifest of a run folder to resume, read with the results folder's one model.

``reports.results.Manifest`` reads a ``manifest.json`` for reports; a resume reads it strictly
(the JSON types a run writes: a seed ``"1"`` or ``true`` is not a seed) and needs more of it:
the scenario's file (a manifest without a scenario name is named by its file), the systems (known
to this installation, at least one) and a config for each. ``ResumableManifest`` is that model
with those requirements. A manifest that fails is one line naming the first problem in the order
a resume reads the keys, ``--resume <path>: <reason>; this folder cannot be resumed`` (exit 2).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from pydantic import Field, ValidationError, ValidationInfo, field_validator, model_validator

from reports.records import Manifest, ScenarioInfo
from runners.commands.errors import Refused

# the keys a resume reads, in the order it checks them, and the reason given when one is wrong
# (systems: the validator's own reason)
RESUME_REASONS = {
    "scenario": "scenario.file missing",
    "systems": "systems missing",
    "seed": "seed missing or not an integer",
    "config": "config of a system missing",
    "trial_count": "trial_count not an integer",
}


class ResumableScenario(ScenarioInfo):
    file: str  # the scenario is loaded again from it

    @model_validator(mode="before")
    @classmethod
    def _named_by_its_file(cls, data: Any) -> Any:
        if isinstance(data, dict) and "name" not in data and isinstance(data.get("file"), str):
            return {**data, "name": data["file"]}
        return data


class ResumableManifest(Manifest):
    """A manifest a resume can run from; validate with ``context={"systems": <known names>}``."""

    scenario: ResumableScenario
    config: dict[str, Any] = Field(default_factory=dict, validate_default=True)

    @field_validator("systems", mode="before")
    @classmethod
    def _known_systems(cls, value: Any, info: ValidationInfo) -> Any:
        if not (isinstance(value, list) and value):
            raise ValueError(RESUME_REASONS["systems"])
        known = (info.context or {}).get("systems", [])
        if unknown := [s for s in value if s not in known]:
            raise ValueError(f"systems: unknown system(s) {', '.join(map(str, unknown))}")
        return value

    @field_validator("config")
    @classmethod
    def _a_config_each(cls, value: dict[str, Any], info: ValidationInfo) -> dict[str, Any]:
        if not all(isinstance(value.get(s), dict) for s in info.data.get("systems", [])):
            raise ValueError(RESUME_REASONS["config"])
        return value


def read_resumable(run_dir: Path, known: list[str]) -> ResumableManifest:
    """The manifest of ``run_dir`` (which holds one), or ``Refused`` saying why it cannot be resumed."""
    path = run_dir / "manifest.json"
    try:
        data = json.loads(path.read_bytes())
    except OSError as exc:
        raise Refused(f"--resume {path}: cannot be read: {exc.strerror or exc}") from None
    except ValueError as exc:  # JSONDecodeError, UnicodeDecodeError
        raise Refused(f"--resume {path}: not valid JSON ({exc}); this folder cannot be resumed") from None
    if not isinstance(data, dict):
        problem = "not a JSON object"
    else:
        try:
            return ResumableManifest.model_validate(data, strict=True, context={"systems": known})
        except ValidationError as exc:
            problem = first_problem(exc)
    raise Refused(f"--resume {path}: {problem}; this folder cannot be resumed")


def first_problem(exc: ValidationError) -> str:
    """The reason of the first wrong key in the order a resume reads them; else the first error."""
    errors = exc.errors()
    for key, reason in RESUME_REASONS.items():
        for error in errors:
            if error["loc"][:1] != (key,) or (key == "scenario" and error["loc"] not in [("scenario",), ("scenario", "file")]):
                continue
            if error["type"] == "value_error":  # a validator of this module: its reason
                return str(error["msg"]).removeprefix("Value error, ")
            return reason
    first = errors[0]
    return f"{'.'.join(map(str, first['loc']))}: {first['msg']}"
