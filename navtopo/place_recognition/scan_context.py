"""Scan Context: a hand-made, yaw-searchable place descriptor (no learning).

Kim & Kim, "Scan Context: Egocentric Spatial Descriptor for Place Recognition within 3D
Point Cloud Map", IROS 2018:

* the context (Sec. III-A): ``rings x sectors`` polar bins around the sensor, each holding the
  maximum height of its points (0 where empty); here 20 rings over 15 m x 60 sectors of 6°,
  heights above the floor with floor hits dropped;
* the ring key (Sec. III-C): per ring, the fraction of occupied sectors; rotation-invariant,
  so it shortlists candidates by nearest neighbours (``embed`` returns it, L2-normalised);
* the distance (Sec. III-B): mean cosine distance between corresponding sector columns,
  minimised over all circular column shifts; columns empty in either context are skipped.
  The best shift is the relative yaw (``compare`` returns it).

docs/NOTES.md measured recall@1/@5 0.64/0.85 with 10 ring-key candidates on generated corridor
worlds (the ring key alone 0.69/0.89), ~7 ms per query.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from .clouds import CropConfig, crop_cloud, polar_bins
from .registry import Cloud, PlaceDescriptor, normalize_rows, register_descriptor


@register_descriptor("scan_context")
class ScanContext(PlaceDescriptor):
    """Scan Context behind the descriptor interface.

    ``embed``: the ring key (``rings``-d). ``signature``: the full (rings, sectors) context.
    ``compare``: the column-shift distance in [0, 1] and the yaw of the best shift.
    """

    def __init__(
        self,
        rings: int = 20,
        sectors: int = 60,
        max_range: float = 15.0,
        min_z: float = 0.15,
        max_z: float = 4.0,
        candidates: int = 10,
    ):
        self.rings, self.sectors = int(rings), int(sectors)
        self.crop = CropConfig(min_z=min_z, max_z=max_z, max_range=max_range)
        self.dim = self.rings
        self.rerank_candidates = int(candidates)

    # -- the context and its key ---------------------------------------------------------
    def context(self, points: Cloud) -> NDArray[np.float32]:
        """(rings, sectors) float32 maximum height per polar bin, 0 where empty."""
        points = crop_cloud(points, self.crop)
        ring, sector, inside = polar_bins(points, self.rings, self.sectors, self.crop.max_range)
        grid = np.zeros(self.rings * self.sectors, dtype=np.float32)
        np.maximum.at(grid, ring[inside] * self.sectors + sector[inside], points[inside, 2])
        return grid.reshape(self.rings, self.sectors)

    @staticmethod
    def ring_key(contexts: NDArray[np.float32]) -> NDArray[np.float32]:
        """(..., rings, sectors) -> (..., rings) L2-normalised fraction of occupied sectors."""
        return normalize_rows((contexts > 0).mean(axis=-1))

    def signature_batch(self, clouds: Sequence[Cloud]) -> NDArray[np.float32]:
        if len(clouds) == 0:
            return np.zeros((0, self.rings, self.sectors), dtype=np.float32)
        return np.stack([self.context(c) for c in clouds])

    def embed_batch(self, clouds: Sequence[Cloud]) -> NDArray[np.float32]:
        return self.ring_key(self.signature_batch(clouds))

    def describe_batch(self, clouds: Sequence[Cloud]) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        contexts = self.signature_batch(clouds)
        return self.ring_key(contexts), contexts

    # -- the distance ---------------------------------------------------------------------
    def compare(
        self, query_signature: NDArray[np.float32], candidate_signatures: NDArray[np.float32]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Column-shift distance (M,) in [0, 1] from one (rings, sectors) query context to M
        candidate contexts, and the yaw (M,) in radians with ``query ≈ R(yaw) · candidate``.

        All ``sectors`` shifts at once: shift s compares query column j with candidate column
        j - s, i.e. the candidate turned by s sectors (counter-clockwise).
        """
        query = np.asarray(query_signature, dtype=np.float64)
        candidates = np.asarray(candidate_signatures, dtype=np.float64).reshape(-1, self.rings, self.sectors)
        distances, yaws = [], []
        for start in range(0, len(candidates), 32):  # bounds memory: 32 x S x R x S doubles
            distance, yaw = self._shift_distance(query, candidates[start : start + 32])
            distances.append(distance)
            yaws.append(yaw)
        if not distances:
            return np.zeros(0), np.zeros(0)
        return np.concatenate(distances), np.concatenate(yaws)

    def _shift_distance(
        self, query: NDArray[np.float64], candidates: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        query_unit, query_valid = _unit_columns(query)  # (R, S), (S,)
        cand_unit, cand_valid = _unit_columns(candidates)  # (M, R, S), (M, S)
        # shifted[m, s, :, j] = candidate m column (j - s) mod S
        sectors = np.arange(self.sectors)
        column = (sectors[None, :] - sectors[:, None]) % self.sectors  # (S_shift, S)
        shifted_unit = cand_unit[:, :, column].transpose(0, 2, 1, 3)  # (M, S_shift, R, S)
        shifted_valid = cand_valid[:, column]  # (M, S_shift, S)
        similarity = np.einsum("rj,msrj->msj", query_unit, shifted_unit)
        both = shifted_valid & query_valid[None, None, :]
        count = both.sum(axis=2)
        mean_similarity = np.where(both, similarity, 0.0).sum(axis=2) / np.maximum(count, 1)
        distance = np.where(count > 0, 1.0 - mean_similarity, 1.0)  # (M, S_shift)
        best = distance.argmin(axis=1)
        yaw = best * (2.0 * np.pi / self.sectors)
        yaw = (yaw + np.pi) % (2.0 * np.pi) - np.pi
        return distance[np.arange(len(best)), best], yaw


def _unit_columns(contexts: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Columns (axis -2 = rings) scaled to unit length, and which columns are non-empty."""
    norms = np.linalg.norm(contexts, axis=-2)
    valid = norms > 0
    return contexts / np.where(valid, norms, 1.0)[..., None, :], valid
