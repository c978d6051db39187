"""The place-recognition registry and the interface every global descriptor implements.

A descriptor turns one lidar scan into a fixed-length vector so that places can be
retrieved by nearest neighbours (habitat-lab style registry: a new descriptor is a class
and a decorator, ``@register_descriptor("name")``).

Retrieval has two stages so that learned and hand-made descriptors share one code path
(see :mod:`navtopo.place_recognition.retrieval`):

1. **shortlist** by Euclidean distance between L2-normalised embeddings (``embed``), which
   is what a topological graph stores and searches;
2. **re-rank** (optional) with ``compare`` on richer *signatures*; Scan Context shortlists by
   its ring key and re-ranks by the column-shift distance of the full context, which also
   gives the relative yaw. A learned descriptor's signature is its embedding.

Points everywhere: ``(N, 3)`` float32 in the robot frame, x forward, y left, z up from the
floor below the robot (floor hits included; each descriptor crops them).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from typing import Any, ClassVar, TypeVar

import numpy as np
from numpy.typing import NDArray

Cloud = NDArray[np.float32]
"""(N, 3) float32 points in the robot frame."""


class PlaceDescriptor(ABC):
    """A global descriptor of a lidar scan.

    Subclasses set ``dim`` and implement ``embed_batch``; hand-made descriptors that re-rank
    (Scan Context) also override ``signature_batch``, ``compare`` and ``rerank_candidates``.
    """

    name: ClassVar[str] = ""
    dim: int
    rerank_candidates: int = 0
    """How many embedding neighbours ``retrieve`` shortlists for ``compare``; 0: no re-ranking."""

    @abstractmethod
    def embed_batch(self, clouds: Sequence[Cloud]) -> NDArray[np.float32]:
        """(B, dim) float32 embeddings, each row L2-normalised."""

    @property
    def nbytes(self) -> int:
        """Bytes of learned weights held in memory (0 for a hand-made descriptor)."""
        return 0

    def embed(self, points: Cloud) -> NDArray[np.float32]:
        """(dim,) float32 L2-normalised embedding of one scan."""
        return self.embed_batch([points])[0]

    def signature_batch(self, clouds: Sequence[Cloud]) -> NDArray[np.float32]:
        """What ``compare`` reads, stacked: (B, ...) float32. Default: the embeddings."""
        return self.embed_batch(clouds)

    def signature(self, points: Cloud) -> NDArray[np.float32]:
        return self.signature_batch([points])[0]

    def describe_batch(self, clouds: Sequence[Cloud]) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        """``(embeddings (B, dim), signatures (B, ...))`` in one pass where possible."""
        embeddings = self.embed_batch(clouds)
        if self.rerank_candidates == 0:
            return embeddings, embeddings
        return embeddings, self.signature_batch(clouds)

    def compare(
        self, query_signature: NDArray[np.float32], candidate_signatures: NDArray[np.float32]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
        """Distances (M,) from one query signature to M candidate signatures (smaller is
        more alike; the scale is the descriptor's own) and, where the descriptor measures it,
        the yaw (M,) in radians that turns each candidate's scan onto the query's
        (``query ≈ R(yaw) · candidate``), else None.

        Default: Euclidean distance between embeddings, no yaw.
        """
        diff = np.asarray(candidate_signatures, np.float64) - np.asarray(query_signature, np.float64)
        return np.linalg.norm(diff.reshape(len(diff), -1), axis=1), None

    def __repr__(self) -> str:
        return f"{type(self).__name__}(name={self.name!r}, dim={self.dim})"


DescriptorT = TypeVar("DescriptorT", bound=type[PlaceDescriptor])

_REGISTRY: dict[str, type[PlaceDescriptor]] = {}


def register_descriptor(name: str) -> Callable[[DescriptorT], DescriptorT]:
    """Class decorator: make a descriptor available to ``make_descriptor(name)``."""

    def decorate(cls: DescriptorT) -> DescriptorT:
        if name in _REGISTRY and _REGISTRY[name] is not cls:
            raise ValueError(f"place descriptor {name!r} is already registered by {_REGISTRY[name]}")
        cls.name = name
        _REGISTRY[name] = cls
        return cls

    return decorate


def make_descriptor(name: str, **kwargs: Any) -> PlaceDescriptor:
    """Build a registered descriptor by name, e.g. ``make_descriptor("scan_context")``.

    Learned descriptors load their shipped weights by default (``weights="default"``);
    pass ``weights=None`` for an untrained network or a path for other weights.
    """
    if name not in _REGISTRY:
        known = ", ".join(sorted(_REGISTRY)) or "none"
        raise KeyError(f"unknown place descriptor {name!r} (registered: {known})")
    return _REGISTRY[name](**kwargs)


def available_descriptors() -> list[str]:
    """Names of the registered descriptors, sorted."""
    return sorted(_REGISTRY)


def normalize_rows(vectors: NDArray[np.floating]) -> NDArray[np.float32]:
    """L2-normalise each row; an all-zero row stays zero."""
    vectors = np.asarray(vectors, dtype=np.float32)
    norms = np.linalg.norm(vectors, axis=-1, keepdims=True)
    return (vectors / np.maximum(norms, 1e-12)).astype(np.float32)
