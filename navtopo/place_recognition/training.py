"""Training a learned place descriptor from arrays: clouds, 2D positions, world ids.

The data come from whoever drives a simulator (``runners/``); this module only sees
arrays. Metric learning as in MinkLoc3D (Sec. 3.3) with the settings docs/NOTES.md measured on
two CPU cores:

* a batch is ``batch_pairs`` anchor-positive pairs from ``worlds_per_batch`` worlds (16 pairs
  from 2 worlds: 32 scans); two scans of one world are positives within ``positive_radius``
  (3 m) and negatives beyond ``negative_radius`` (10 m); scans of different worlds are
  negatives; pairs in between are ignored;
* batch-hard triplet loss (Hermans et al. 2017): per anchor, the farthest positive and the
  nearest negative in the batch, ``max(0, d_pos - d_neg + margin)``, margin 0.3;
* every scan turned by a random yaw (the robot may come back facing any way);
* Adam, learning rate decaying exponentially from ``lr`` to ``lr_final`` over the run, which
  ends after ``steps`` or ``max_seconds``, whichever comes first.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from .clouds import rotate_yaw
from .learned import LearnedDescriptor, torch_threads
from .registry import Cloud, make_descriptor
from .retrieval import evaluate_recall


@dataclass
class PlaceRecognitionDataset:
    """Scans with where they were taken.

    clouds:       M arrays (N_i, 3) float32, robot frame (as the lidar gives them).
    positions:    (M, 2) float64 true 2D positions in metres, in each world's own frame.
    world_ids:    (M,) int64; positions of different worlds are never compared.
    sequence_ids: (M,) int64 pass / drive number within a world (0 if one pass); evaluation
                  uses a world's first sequence as the database and the others as queries.
    """

    clouds: list[Cloud]
    positions: NDArray[np.float64]
    world_ids: NDArray[np.int64]
    sequence_ids: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))

    def __post_init__(self) -> None:
        self.clouds = [np.asarray(c, dtype=np.float32).reshape(-1, 3) for c in self.clouds]
        self.positions = np.asarray(self.positions, dtype=np.float64).reshape(-1, 2)
        self.world_ids = np.asarray(self.world_ids, dtype=np.int64).reshape(-1)
        if len(self.sequence_ids) == 0:
            self.sequence_ids = np.zeros(len(self.clouds), dtype=np.int64)
        self.sequence_ids = np.asarray(self.sequence_ids, dtype=np.int64).reshape(-1)
        sizes = {len(self.clouds), len(self.positions), len(self.world_ids), len(self.sequence_ids)}
        if len(sizes) != 1:
            raise ValueError(
                f"dataset arrays disagree in length: clouds {len(self.clouds)}, positions "
                f"{len(self.positions)}, world_ids {len(self.world_ids)}, sequence_ids "
                f"{len(self.sequence_ids)}"
            )

    def __len__(self) -> int:
        return len(self.clouds)

    def subset(self, rows: NDArray[np.int64] | NDArray[np.bool_]) -> PlaceRecognitionDataset:
        """The scans at ``rows`` (indices or a boolean mask)."""
        index = np.flatnonzero(rows) if np.asarray(rows).dtype == bool else np.asarray(rows, dtype=np.int64)
        return PlaceRecognitionDataset(
            [self.clouds[int(i)] for i in index],
            self.positions[index],
            self.world_ids[index],
            self.sequence_ids[index],
        )

    def database_and_queries(self) -> tuple[PlaceRecognitionDataset, PlaceRecognitionDataset]:
        """Each world's first sequence as the database, its later sequences as queries."""
        first = np.zeros(len(self), dtype=bool)
        for world in np.unique(self.world_ids):
            in_world = self.world_ids == world
            first |= in_world & (self.sequence_ids == self.sequence_ids[in_world].min())
        return self.subset(first), self.subset(~first)

    def save(self, path: str | Path) -> Path:
        """One ``.npz``: points concatenated, with per-scan offsets."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        counts = np.array([len(c) for c in self.clouds], dtype=np.int64)
        points = np.concatenate(self.clouds) if self.clouds else np.zeros((0, 3), np.float32)
        np.savez_compressed(
            path,
            points=points,
            counts=counts,
            positions=self.positions,
            world_ids=self.world_ids,
            sequence_ids=self.sequence_ids,
        )
        return path

    @staticmethod
    def load(path: str | Path) -> PlaceRecognitionDataset:
        with np.load(path) as data:
            splits = np.cumsum(data["counts"])[:-1]
            clouds = np.split(data["points"], splits) if len(data["counts"]) else []
            return PlaceRecognitionDataset(list(clouds), data["positions"], data["world_ids"], data["sequence_ids"])


@dataclass
class TrainingConfig:
    descriptor: str = "minkloc3d"
    architecture: dict[str, Any] = field(default_factory=dict)  # descriptor keyword arguments
    init_weights: str | None = None  # continue from these weights
    steps: int = 100_000
    max_seconds: float = 600.0
    batch_pairs: int = 16
    worlds_per_batch: int = 2
    positive_radius: float = 3.0
    negative_radius: float = 10.0
    margin: float = 0.3
    lr: float = 1e-3
    lr_final: float = 1e-4
    weight_decay: float = 0.0
    yaw_augmentation: bool = True
    seed: int = 0
    threads: int | None = None  # torch threads while training (None: torch's default)
    output_dir: str | None = None  # where {descriptor}.pt and {descriptor}.json go; None: not saved


@dataclass(frozen=True)
class TrainingProgress:
    """What the progress callback receives after every step."""

    step: int
    steps: int
    elapsed_s: float
    max_seconds: float
    loss: float
    active_fraction: float  # share of anchors whose triplet still violates the margin
    lr: float

    @property
    def fraction(self) -> float:
        """How far the run is, 0..1, by steps or by time, whichever is further."""
        return min(1.0, max(self.step / max(self.steps, 1), self.elapsed_s / self.max_seconds))


def batch_hard_triplet_loss(
    embeddings: torch.Tensor,
    positions: NDArray[np.float64],
    world_ids: NDArray[np.int64],
    margin: float = 0.3,
    positive_radius: float = 3.0,
    negative_radius: float = 10.0,
) -> tuple[torch.Tensor, dict[str, float]]:
    """Batch-hard triplet loss over B embeddings (B, D) with positions (B, 2) and world ids (B,).

    Returns the mean loss over anchors that have a positive and a negative in the batch, and
    statistics: ``active_fraction``, ``positive_distance`` and ``negative_distance`` (means of
    the hardest ones), ``anchors``.
    """
    batch = len(embeddings)
    squared = (embeddings[:, None, :] - embeddings[None, :, :]).pow(2).sum(-1)
    distance = squared.clamp(min=1e-12).sqrt()  # the clamp keeps the gradient finite at 0
    gaps = np.linalg.norm(positions[:, None, :] - positions[None, :, :], axis=2)
    same_world = world_ids[:, None] == world_ids[None, :]
    positive = same_world & (gaps <= positive_radius) & ~np.eye(batch, dtype=bool)
    negative = ~same_world | (gaps >= negative_radius)
    positive_t, negative_t = torch.from_numpy(positive), torch.from_numpy(negative)
    hardest_positive = distance.masked_fill(~positive_t, -1.0).max(dim=1).values
    hardest_negative = distance.masked_fill(~negative_t, float("inf")).min(dim=1).values
    anchors = torch.from_numpy(positive.any(axis=1) & negative.any(axis=1))
    if not bool(anchors.any()):
        zero = embeddings.sum() * 0.0
        return zero, {
            "active_fraction": 0.0,
            "positive_distance": 0.0,
            "negative_distance": 0.0,
            "anchors": 0,
        }
    losses = torch.relu(hardest_positive[anchors] - hardest_negative[anchors] + margin)
    stats = {
        "active_fraction": float((losses.detach() > 0).float().mean()),
        "positive_distance": float(hardest_positive[anchors].detach().mean()),
        "negative_distance": float(hardest_negative[anchors].detach().mean()),
        "anchors": int(anchors.sum()),
    }
    return losses.mean(), stats


class PairSampler:
    """Draws batches of anchor-positive pairs, ``worlds_per_batch`` worlds at a time."""

    def __init__(self, dataset: PlaceRecognitionDataset, config: TrainingConfig, rng: np.random.Generator):
        self.rng = rng
        self.pairs_per_world = max(1, config.batch_pairs // max(config.worlds_per_batch, 1))
        self.worlds_per_batch = config.worlds_per_batch
        self.positives: dict[int, list[NDArray[np.int64]]] = {}
        self.anchors: dict[int, NDArray[np.int64]] = {}
        for world in np.unique(dataset.world_ids):
            rows = np.flatnonzero(dataset.world_ids == world)
            tree = cKDTree(dataset.positions[rows])
            neighbours = tree.query_ball_point(dataset.positions[rows], config.positive_radius)
            partners = [rows[[j for j in near if j != i]] for i, near in enumerate(neighbours)]
            has_partner = np.array([len(p) > 0 for p in partners], dtype=bool)
            if has_partner.any():
                self.anchors[int(world)] = rows[has_partner]
                self.positives[int(world)] = [p for p in partners if len(p)]
        if not self.anchors:
            raise ValueError(f"no two scans of one world lie within {config.positive_radius} m: nothing to learn from")
        self.worlds = np.array(sorted(self.anchors))

    def sample(self) -> NDArray[np.int64]:
        """Rows of one batch: anchor, positive, anchor, positive, ..."""
        count = min(self.worlds_per_batch, len(self.worlds))
        worlds = self.rng.choice(self.worlds, size=count, replace=False)
        rows = []
        for world in worlds:
            anchors = self.anchors[int(world)]
            picks = self.rng.choice(len(anchors), size=min(self.pairs_per_world, len(anchors)), replace=False)
            for pick in picks:
                partners = self.positives[int(world)][pick]
                rows += [anchors[pick], partners[self.rng.integers(len(partners))]]
        return np.asarray(rows, dtype=np.int64)


def train(
    dataset: PlaceRecognitionDataset,
    config: TrainingConfig | None = None,
    progress: Callable[[TrainingProgress], None] | None = None,
    validation: PlaceRecognitionDataset | None = None,
    descriptor: LearnedDescriptor | None = None,
) -> dict[str, Any]:
    """Train on ``dataset``; returns (and, with ``output_dir``, saves) training statistics.

    The network is ``config.descriptor`` built fresh (or from ``config.init_weights``), or
    ``descriptor`` if given, which is then trained in place. ``validation`` (held-out worlds,
    several sequences each) is scored with ``evaluate_recall`` at the end.
    """
    config = config or TrainingConfig()
    rng = np.random.default_rng(config.seed)
    torch.manual_seed(config.seed)
    if descriptor is None:
        built = make_descriptor(config.descriptor, weights=config.init_weights, **config.architecture)
        if not isinstance(built, LearnedDescriptor):
            raise ValueError(f"place descriptor {config.descriptor!r} has nothing to train")
        descriptor = built
    sampler = PairSampler(dataset, config, rng)
    with torch_threads(config.threads):
        run = _optimise(descriptor, dataset, config, sampler, rng, progress)
        threads = torch.get_num_threads()
        recall = None
        if validation is not None and len(validation):
            database, queries = validation.database_and_queries()
            recall = evaluate_recall(descriptor, database.clouds, database.positions, queries.clouds, queries.positions)

    losses, active = run["losses"], run["active"]
    window = max(1, min(10, len(losses) // 4))
    metrics: dict[str, Any] = {
        "descriptor": descriptor.name,
        "architecture": descriptor.architecture,
        "parameters": descriptor.parameter_count,
        "config": asdict(config),
        "scans": len(dataset),
        "worlds": int(len(np.unique(dataset.world_ids))),
        "steps": len(losses),
        "batch_size": int(2 * config.batch_pairs),
        "epochs": run["scans_seen"] / max(len(dataset), 1),
        "seconds": run["seconds"],
        "ms_per_step": 1000.0 * run["seconds"] / max(len(losses), 1),
        "loss_first": float(np.mean(losses[:window])) if losses else None,
        "loss_last": float(np.mean(losses[-window:])) if losses else None,
        "active_fraction_last": float(np.mean(active[-window:])) if active else None,
        "loss_curve": _curve(losses),
        "torch": str(torch.__version__),
        "threads": threads,
    }
    if recall is not None and validation is not None:
        metrics["validation"] = {
            "scans": len(validation),
            "worlds": int(len(np.unique(validation.world_ids))),
            **recall,
        }
    if config.output_dir is not None:
        output = Path(config.output_dir)
        summary = {k: v for k, v in metrics.items() if k not in ("loss_curve", "config")}
        weights = descriptor.save_weights(
            output / f"{descriptor.name}.pt",
            meta=json.loads(json.dumps(summary, default=_jsonable)),
        )
        metrics["weights_path"] = str(weights)
        metrics["weights_bytes"] = weights.stat().st_size
        stats_path = output / f"{descriptor.name}.json"
        stats_path.write_text(json.dumps(metrics, indent=2, default=_jsonable) + "\n")
        metrics["stats_path"] = str(stats_path)
    return metrics


def _optimise(
    descriptor: LearnedDescriptor,
    dataset: PlaceRecognitionDataset,
    config: TrainingConfig,
    sampler: PairSampler,
    rng: np.random.Generator,
    progress: Callable[[TrainingProgress], None] | None,
) -> dict[str, Any]:
    """The training loop; returns per-step losses and active fractions, scans seen, seconds."""
    network = descriptor.network
    optimizer = torch.optim.Adam(network.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    decay = config.lr_final / config.lr
    losses: list[float] = []
    active: list[float] = []
    scans_seen = 0
    started = time.perf_counter()
    network.train()
    while len(losses) < config.steps:
        elapsed = time.perf_counter() - started
        if elapsed >= config.max_seconds:
            break
        lr = config.lr * decay ** min(1.0, max(len(losses) / config.steps, elapsed / config.max_seconds))
        for group in optimizer.param_groups:
            group["lr"] = lr
        rows = sampler.sample()
        clouds = [dataset.clouds[i] for i in rows]
        if config.yaw_augmentation:
            clouds = [rotate_yaw(c, rng.uniform(-np.pi, np.pi)) for c in clouds]
        embeddings = network(descriptor.collate(clouds))
        loss, stats = batch_hard_triplet_loss(
            embeddings,
            dataset.positions[rows],
            dataset.world_ids[rows],
            config.margin,
            config.positive_radius,
            config.negative_radius,
        )
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        scans_seen += len(rows)
        losses.append(float(loss.detach()))
        active.append(stats["active_fraction"])
        if progress is not None:
            progress(
                TrainingProgress(
                    step=len(losses),
                    steps=config.steps,
                    elapsed_s=time.perf_counter() - started,
                    max_seconds=config.max_seconds,
                    loss=losses[-1],
                    active_fraction=active[-1],
                    lr=lr,
                )
            )
    network.eval()
    return {
        "losses": losses,
        "active": active,
        "scans_seen": scans_seen,
        "seconds": time.perf_counter() - started,
    }


def _curve(values: Sequence[float], points: int = 200) -> list[list[float]]:
    """[[step, mean loss], ...] over at most ``points`` equal windows (1-based end steps)."""
    if not values:
        return []
    edges = np.linspace(0, len(values), min(points, len(values)) + 1).astype(int)
    return [
        [int(end), float(np.mean(values[start:end]))] for start, end in zip(edges[:-1], edges[1:], strict=True) if end > start
    ]


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return str(value)
