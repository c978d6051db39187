"""Whole-file writes that a crash or Ctrl-C never leaves half done.

One way for every package (NavTopo's graph, the baseline's maps, the runner's results): a
temporary file beside the target, then a rename, so a reader sees the old file or the new one.
The temporary file is created like any other file, with the user's umask (``tempfile.mkstemp``
would make it 0600, and the rename would keep that mode).
"""

from __future__ import annotations

import os
import secrets
from pathlib import Path


def atomic_write(path: str | Path, data: str | bytes) -> Path:
    """Write ``data`` (text as UTF-8) to ``path`` through a temporary file and a rename; creates the
    parent folder."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    try:
        with open(tmp, "xb") as f:
            f.write(data.encode() if isinstance(data, str) else data)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path
