"""The command line's consoles and its one-line messages.

Results go to ``console`` (stdout), refusals, notes and warnings to ``err`` (stderr). Without a
terminal (a log, CI, a pipe) lines are not wrapped below 160 (stdout) or 200 (stderr) columns, so
that a path stays on one line. A message is always one line (``one_line``), its markup escaped.
"""

from __future__ import annotations

import sys

from rich.console import Console
from rich.markup import escape

console = Console(width=None if sys.stdout.isatty() else 160)
err = Console(stderr=True, width=None if sys.stderr.isatty() else 200)


def one_line(message: object) -> str:
    return " ".join(str(message).split("\n")).strip()


def error_line(message: str) -> None:
    err.print(f"[bold red]error:[/] {escape(one_line(message))}", highlight=False, soft_wrap=True)


def note(message: str) -> None:
    err.print(f"note: {escape(one_line(message))}", highlight=False, soft_wrap=True)
