"""Issue 14: every bad input is one clear line and a non-zero exit (never a traceback, a hang or
a navigation result), Ctrl-C stops, nothing is overwritten or half-written."""

from __future__ import annotations

import pytest


# ---------------------------------------------------------------------------------------------
# files


@pytest.mark.parametrize("umask", [0o022, 0o027])
def test_results_and_maps_are_written_with_the_users_umask(tmp_path, umask):
    import os

    import numpy as np

    from navtopo.files import atomic_write
    from runners.results import write_json, write_tum

    old = os.umask(umask)
    try:
        write_json(tmp_path / "a" / "manifest.json", {"x": 1})
        write_tum(tmp_path / "a" / "trial-0.tum", np.zeros((2, 4)))
        atomic_write(tmp_path / "a" / "graph.json", b"{}")
    finally:
        os.umask(old)
    for name in ("manifest.json", "trial-0.tum", "graph.json"):
        assert (tmp_path / "a" / name).stat().st_mode & 0o777 == 0o666 & ~umask, name
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["graph.json", "manifest.json", "trial-0.tum"]
