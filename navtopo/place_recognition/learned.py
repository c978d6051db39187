"""What the learned descriptors share: a torch network, its input batching, weight files.

A weight file is a ``torch.save`` dict read back with ``weights_only=True`` (no code runs and
nothing is fetched when loading)::

    {"format": "navtopo-place-recognition/1", "descriptor": name,
     "architecture": {constructor keyword arguments}, "state_dict": {...}, "meta": {...}}
"""

from __future__ import annotations

import io
from abc import abstractmethod
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from torch import nn

from navkit.files import atomic_write

from .registry import Cloud, PlaceDescriptor

WEIGHTS_FORMAT = "navtopo-place-recognition/1"
WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"


@contextmanager
def torch_threads(threads: int | None) -> Iterator[None]:
    """Run torch with ``threads`` intra-op threads inside the block (None: leave as is).

    On a machine shared by several processes, one thread per process is often much faster
    than torch's default of one per core: its OpenMP workers spin while waiting for cores.
    """
    if threads is None:
        yield
        return
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def default_weights_path(name: str) -> Path:
    """Where the shipped weights of descriptor ``name`` live."""
    return WEIGHTS_DIR / f"{name}.pt"


class LearnedDescriptor(PlaceDescriptor):
    """A descriptor computed by ``self.network`` (an ``nn.Module`` returning (B, dim)
    L2-normalised rows) from the batch that ``collate`` builds.

    ``weights``: ``"default"`` loads the shipped file (a missing file is an error that says how
    to train one), a path loads that file, ``None`` keeps the random initialisation.
    ``threads``: torch threads while embedding (None: torch's setting).
    """

    network: nn.Module
    architecture: dict[str, Any]
    batch_size: int = 32

    def __init__(self, weights: str | Path | None = "default", threads: int | None = None) -> None:
        self.threads = threads
        self.weights_meta: dict[str, Any] = {}
        self._weights_path: Path | None = None
        if weights is not None:
            path = default_weights_path(self.name) if weights == "default" else Path(weights)
            if weights == "default" and not path.exists():
                raise FileNotFoundError(
                    f"no shipped weights for place descriptor {self.name!r} at {path}; "
                    f"train them with `navtopo-bench train-descriptor` or pass weights=None "
                    f"for an untrained network"
                )
            self.load_weights(path)
        self.network.eval()

    @abstractmethod
    def collate(self, clouds: Sequence[Cloud]) -> Any:
        """Turn B robot-frame clouds into the network's input batch."""

    def embed_batch(self, clouds: Sequence[Cloud]) -> NDArray[np.float32]:
        self.network.eval()
        chunks = []
        with torch_threads(self.threads), torch.inference_mode():
            for start in range(0, len(clouds), self.batch_size):
                batch = self.collate(clouds[start : start + self.batch_size])
                chunks.append(self.network(batch).numpy())
        if not chunks:
            return np.zeros((0, self.dim), dtype=np.float32)
        return np.concatenate(chunks).astype(np.float32)

    @property
    def parameter_count(self) -> int:
        return sum(p.numel() for p in self.network.parameters())

    @property
    def nbytes(self) -> int:
        """Bytes of the network's weights and buffers as loaded."""
        tensors = [*self.network.parameters(), *self.network.buffers()]
        return int(sum(t.numel() * t.element_size() for t in tensors))

    @property
    def weights_path(self) -> Path | None:
        """The file the weights were loaded from (None: untrained)."""
        return self._weights_path

    def save_weights(self, path: str | Path, meta: dict[str, Any] | None = None) -> Path:
        """Write the network's weights and architecture; returns the path."""
        checkpoint = {
            "format": WEIGHTS_FORMAT,
            "descriptor": self.name,
            "architecture": dict(self.architecture),
            "state_dict": {k: v.detach().clone() for k, v in self.network.state_dict().items()},
            "meta": dict(meta or {}),
        }
        buffer = io.BytesIO()
        torch.save(checkpoint, buffer)
        return atomic_write(path, buffer.getvalue())

    def load_weights(self, path: str | Path) -> None:
        """Load weights written by ``save_weights`` for this descriptor and architecture."""
        path = Path(path)
        try:
            checkpoint = torch.load(path, map_location="cpu", weights_only=True)
        except FileNotFoundError:
            raise
        except Exception as error:  # a truncated or foreign file
            raise ValueError(f"{path}: not a readable weight file ({error})") from error
        if not isinstance(checkpoint, dict) or checkpoint.get("format") != WEIGHTS_FORMAT:
            raise ValueError(f"{path}: not a {WEIGHTS_FORMAT} weight file")
        if checkpoint["descriptor"] != self.name:
            raise ValueError(f"{path}: weights of {checkpoint['descriptor']!r}, not {self.name!r}")
        if checkpoint["architecture"] != self.architecture:
            raise ValueError(
                f"{path}: architecture {checkpoint['architecture']} differs from this "
                f"descriptor's {self.architecture}; build it with those arguments"
            )
        self.network.load_state_dict(checkpoint["state_dict"])
        self.weights_meta = dict(checkpoint.get("meta", {}))
        self._weights_path = path
        self.network.eval()
