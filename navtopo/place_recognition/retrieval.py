"""Top-k place retrieval with any registered descriptor, and recall@k.

One code path serves every descriptor (see :mod:`.registry`):

1. shortlist the ``max(k, descriptor.rerank_candidates)`` database entries whose embeddings
   are nearest to the query's (Euclidean; on unit vectors this is the cosine order);
2. if the descriptor re-ranks (Scan Context), order the shortlist by
   ``descriptor.compare(query_signature, signatures)``, which may also give a relative yaw.

What a map must keep per place: the embedding (D,) always, plus the signature when
``descriptor.rerank_candidates > 0`` (a learned descriptor's signature *is* its embedding).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .registry import Cloud, PlaceDescriptor


@dataclass(frozen=True)
class PlaceMatch:
    """One retrieved database entry.

    ``distance``: the descriptor's own scale, smaller is more alike (embedding distance, or
    the re-ranking distance when the descriptor re-ranks). ``yaw``: radians turning the
    database scan onto the query (``query ≈ R(yaw) · database``), or None if not measured.
    """

    index: int
    distance: float
    yaw: float | None = None


def nearest(queries: ArrayLike, database: ArrayLike, k: int) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """k nearest database rows of each query by Euclidean distance.

    queries (Q, D) or (D,), database (M, D) -> indices (Q, k') and distances (Q, k') sorted
    nearest first, with k' = min(k, M); a single query gives (k',) arrays.
    """
    query_array = np.asarray(queries, dtype=np.float64)
    single = query_array.ndim == 1
    query_array = np.atleast_2d(query_array)
    database_array = np.asarray(database, dtype=np.float64).reshape(-1, query_array.shape[1])
    k = min(int(k), len(database_array))
    if k == 0:
        empty = np.zeros((len(query_array), 0))
        return (empty.astype(np.int64)[0], empty[0]) if single else (empty.astype(np.int64), empty)
    squared = (query_array**2).sum(1)[:, None] - 2.0 * query_array @ database_array.T + (database_array**2).sum(1)[None, :]
    distances = np.sqrt(np.maximum(squared, 0.0))
    top = np.argpartition(distances, k - 1, axis=1)[:, :k]
    order = np.take_along_axis(distances, top, axis=1).argsort(axis=1, kind="stable")
    indices = np.take_along_axis(top, order, axis=1)
    top_distances = np.take_along_axis(distances, indices, axis=1)
    if single:
        return indices[0], top_distances[0]
    return indices, top_distances


def retrieve(
    descriptor: PlaceDescriptor,
    query_embedding: ArrayLike,
    database_embeddings: ArrayLike,
    k: int = 5,
    query_signature: ArrayLike | None = None,
    database_signatures: ArrayLike | None = None,
) -> list[PlaceMatch]:
    """The k best database places for one query, best first.

    Re-ranks with ``descriptor.compare`` when the descriptor re-ranks and both signatures are
    given; otherwise orders by embedding distance.
    """
    rerank = descriptor.rerank_candidates > 0 and query_signature is not None and database_signatures is not None
    shortlist = max(k, descriptor.rerank_candidates) if rerank else k
    indices, distances = nearest(query_embedding, database_embeddings, shortlist)
    if not rerank:
        return [PlaceMatch(int(i), float(d)) for i, d in zip(indices, distances, strict=True)]
    candidates = np.asarray(database_signatures)[indices]
    rerank_distances, yaws = descriptor.compare(np.asarray(query_signature), candidates)
    order = np.argsort(rerank_distances, kind="stable")[:k]
    return [
        PlaceMatch(
            int(indices[i]),
            float(rerank_distances[i]),
            None if yaws is None else float(yaws[i]),
        )
        for i in order
    ]


def evaluate_recall(
    descriptor: PlaceDescriptor,
    db_clouds: Sequence[Cloud],
    db_pos: ArrayLike,
    query_clouds: Sequence[Cloud],
    query_pos: ArrayLike,
    threshold: float = 3.0,
    ks: Sequence[int] = (1, 5),
) -> dict[str, float | int | None]:
    """Recall@k of retrieving, for each query, a database scan within ``threshold`` metres.

    A query counts as recalled at k when any of its top-k retrieved places lies within
    ``threshold`` of its true 2D position. Queries with no database scan within
    ``threshold`` cannot be recalled and are left out (``queries`` counts the rest).

    Returns ``{"recall_at_1", "recall_at_5", "queries", "ms_per_scan", "ms_per_query"}``:
    recall None when no query has a true match; ``ms_per_scan`` is describing one scan,
    ``ms_per_query`` one retrieval (shortlist and re-ranking) against the whole database.
    """
    db_xy = np.asarray(db_pos, dtype=np.float64)[:, :2]
    query_xy = np.asarray(query_pos, dtype=np.float64)[:, :2]
    gaps = np.linalg.norm(query_xy[:, None, :] - db_xy[None, :, :], axis=2)
    kept = np.flatnonzero((gaps <= threshold).any(axis=1))

    started = time.perf_counter()
    db_embeddings, db_signatures = descriptor.describe_batch(list(db_clouds))
    query_embeddings, query_signatures = descriptor.describe_batch([query_clouds[int(i)] for i in kept])
    ms_per_scan = 1000.0 * (time.perf_counter() - started) / max(len(db_clouds) + len(kept), 1)

    candidates = np.arange(len(db_xy))
    queries = [(query_embeddings[row], query_signatures[row], gaps[index], candidates) for row, index in enumerate(kept)]
    result = _recall(descriptor, db_embeddings, db_signatures, queries, threshold, ks)
    result["ms_per_scan"] = ms_per_scan
    return result


def evaluate_revisits(
    descriptor: PlaceDescriptor,
    clouds: Sequence[Cloud],
    positions: ArrayLike,
    travelled_m: ArrayLike,
    threshold: float = 3.0,
    min_gap_m: float = 30.0,
    ks: Sequence[int] = (1, 5),
) -> dict[str, float | int | None]:
    """Recall@k along one drive: each scan queries the scans of earlier passes.

    ``travelled_m`` (M,) is the distance driven when each scan was taken; scan i's database is
    every scan taken at least ``min_gap_m`` of driving before it (so the scans just behind the
    robot, which trivially match, are not in it). Scans with no database scan within
    ``threshold`` metres are not queries. Same keys as ``evaluate_recall``.
    """
    xy = np.asarray(positions, dtype=np.float64)[:, :2]
    travelled = np.asarray(travelled_m, dtype=np.float64)
    started = time.perf_counter()
    embeddings, signatures = descriptor.describe_batch(list(clouds))
    ms_per_scan = 1000.0 * (time.perf_counter() - started) / max(len(clouds), 1)
    queries = []
    for index in range(len(xy)):
        earlier = np.flatnonzero(travelled <= travelled[index] - min_gap_m)
        gaps = np.linalg.norm(xy[earlier] - xy[index], axis=1)
        if (gaps <= threshold).any():
            queries.append((embeddings[index], signatures[index], gaps, earlier))
    result = _recall(descriptor, embeddings, signatures, queries, threshold, ks)
    result["ms_per_scan"] = ms_per_scan
    return result


def _recall(
    descriptor: PlaceDescriptor,
    db_embeddings: NDArray[np.float32],
    db_signatures: NDArray[np.float32],
    queries: list[tuple[NDArray, NDArray, NDArray[np.float64], NDArray[np.int64]]],
    threshold: float,
    ks: Sequence[int],
) -> dict[str, float | int | None]:
    """Queries are (embedding, signature, distances in metres to the candidates, candidate
    rows of the database)."""
    hits = {k: 0 for k in ks}
    started = time.perf_counter()
    for embedding, signature, gaps, rows in queries:
        matches = retrieve(descriptor, embedding, db_embeddings[rows], max(ks), signature, db_signatures[rows])
        close = gaps[[m.index for m in matches]] <= threshold
        for k in ks:
            hits[k] += bool(close[:k].any())
    ms_per_query = 1000.0 * (time.perf_counter() - started) / max(len(queries), 1)
    result: dict[str, float | int | None] = {f"recall_at_{k}": (hits[k] / len(queries) if queries else None) for k in ks}
    result.update(queries=len(queries), ms_per_query=ms_per_query)
    return result
