"""Reading the YAML files users write (scenarios, map_server maps, run configs), strictly.

PyBullet's and ROS's users write numbers as they would in Python: ``1e-3``, ``2E5``. YAML 1.1,
which PyYAML implements, reads a number without a dot (``1e-3``) as a *string*; this loader
reads every YAML 1.2 float (``1e-300``, ``1e308``, ``.5``, ``-2.5E+3``) as a float. A key given
twice in one mapping is an error (YAML says keys are unique; PyYAML silently keeps the last).
Every problem comes back as one ``YamlProblem`` with the line it is on: an expected failure
(``navkit.errors.BenchError``, an input refused); readers that know the file turn it into a
``FileProblem`` naming it (``scenarios.schema.read_yaml``).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import yaml

from navkit.errors import BenchError

# YAML 1.2 core schema floats that YAML 1.1 reads as strings (no dot, or a dot with a bare exponent)
_FLOAT_12 = re.compile(r"^[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)$")


class YamlProblem(BenchError, ValueError):
    """Not usable YAML: ``line`` (1-based, or None) and ``reason`` (one line). Still a ``ValueError``
    for callers that catch that."""

    def __init__(self, reason: str, line: int | None = None) -> None:
        self.reason, self.line = reason, line
        super().__init__(f"line {line}: {reason}" if line is not None else reason)


class StrictLoader(yaml.SafeLoader):
    """SafeLoader with YAML 1.2 floats and unique keys."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        if isinstance(node, yaml.MappingNode):
            seen: dict[Any, int] = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue  # `<<: *base` may be overridden by the keys that follow it
                key = self.construct_object(key_node, deep=True)
                try:
                    hash(key)
                except TypeError:
                    raise YamlProblem("a mapping key must be a plain value", key_node.start_mark.line + 1) from None
                if key in seen:
                    raise YamlProblem(
                        f"duplicate key {key!r} (first on line {seen[key]})",
                        key_node.start_mark.line + 1,
                    )
                seen[key] = key_node.start_mark.line + 1
        return super().construct_mapping(node, deep=deep)


StrictLoader.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT_12, list("-+.0123456789"))


def loads(text: str) -> Any:
    """Parse one YAML document; raise ``YamlProblem`` (with the line) on anything wrong."""
    try:
        return yaml.load(text, Loader=StrictLoader)  # noqa: S506 - a SafeLoader subclass
    except YamlProblem:
        raise
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        problem = exc.problem or exc.context or "cannot be parsed"
        raise YamlProblem(f"not valid YAML: {problem}", mark.line + 1 if mark is not None else None) from None
    except yaml.YAMLError as exc:
        raise YamlProblem(f"not valid YAML: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") from None
    except RecursionError:
        raise YamlProblem("not valid YAML: nested too deeply") from None


def read_text(path: Path) -> str:
    """The text of a file a user names; ``OSError`` / ``YamlProblem`` with a reason a person reads."""
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"{path} is a folder, not a file")
    data = path.read_bytes()
    if b"\x00" in data:
        raise YamlProblem("not a text file (it holds binary data)")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise YamlProblem(f"not a UTF-8 text file (byte {exc.start} cannot be decoded)") from None


def load_file(path: Path) -> Any:
    return loads(read_text(path))
