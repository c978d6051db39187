"""What a job carries instead of paths: the scenario's files and a saved map, as bytes.

Workers may run on other machines (``--executor ray``) with no shared file system, so a job holds
the content it needs: ``ScenarioFiles`` (the scenario YAML and the map files it reads, by path
relative to a common folder) and a map folder packed as an uncompressed tar archive. The worker
unpacks both into a temporary folder of its own.
"""

from __future__ import annotations

import io
import os
import shutil
import tarfile
from dataclasses import dataclass
from pathlib import Path

from scenarios import Scenario, load_scenario


def scenario_files(scenario: Scenario) -> list[Path]:
    """The files a scenario is read from: its YAML file, then its map's YAML and image (if any)."""
    files = [scenario.path]
    if scenario.spec.world.map is not None:
        map_yaml = scenario.path.parent / scenario.spec.world.map.yaml
        files.append(map_yaml)
        for line in map_yaml.read_text(encoding="utf-8", errors="replace").splitlines():
            if line.strip().startswith("image:"):
                image = map_yaml.parent / line.split(":", 1)[1].strip()
                if image.is_file():
                    files.append(image)
    return files


@dataclass(frozen=True)
class ScenarioFiles:
    """A scenario's files by relative path (``entry`` is the scenario YAML among them)."""

    entry: str
    files: dict[str, bytes]

    @classmethod
    def of(cls, scenario: Scenario) -> ScenarioFiles:
        paths = [p.resolve() for p in scenario_files(scenario)]
        base = Path(os.path.commonpath([p.parent for p in paths]))
        files = {p.relative_to(base).as_posix(): p.read_bytes() for p in paths}
        return cls(entry=paths[0].relative_to(base).as_posix(), files=files)

    def write(self, folder: Path) -> Path:
        """Write the files under ``folder``; the scenario file's path there."""
        for relative, data in self.files.items():
            path = folder / relative
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(data)
        return folder / self.entry

    def load(self, folder: Path) -> Scenario:
        """Write the files under ``folder`` and load the scenario from there."""
        return load_scenario(self.write(folder))


def pack_dir(folder: Path) -> bytes:
    """A folder as an uncompressed tar archive (paths relative to the folder, sorted)."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w") as archive:
        for path in sorted(Path(folder).rglob("*")):
            archive.add(path, arcname=path.relative_to(folder).as_posix(), recursive=False)
    return buffer.getvalue()


def unpack_dir(data: bytes, folder: Path) -> Path:
    """Extract an archive of ``pack_dir`` into ``folder`` (plain files and folders only), with the
    modes of files this process creates (the user's umask), as every other results file."""
    folder.mkdir(parents=True, exist_ok=True)

    def data_with_umask(member: tarfile.TarInfo, path: str) -> tarfile.TarInfo:
        # the "data" filter's checks, but its mode (group write dropped) is not kept: mode None
        # skips the chmod, so a file is as open() and mkdir() make it
        return tarfile.data_filter(member, path).replace(mode=None, deep=False)  # type: ignore[arg-type] # None: keep

    with tarfile.open(fileobj=io.BytesIO(data), mode="r") as archive:
        archive.extractall(folder, filter=data_with_umask)
    return folder


def install_dir(data: bytes, folder: Path) -> None:
    """Unpack an archive as ``folder`` all at once: into a hidden sibling, then renamed, so that a
    crash leaves either no folder or a whole one (a half-written one from an older crash is replaced)."""
    staging = folder.with_name(f".{folder.name}.partial")
    shutil.rmtree(staging, ignore_errors=True)
    unpack_dir(data, staging)
    if folder.exists():
        shutil.rmtree(folder)
    os.replace(staging, folder)
