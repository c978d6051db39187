"""Place recognition: descriptors, sparse convolutions, Scan Context, weights, training.

Scans come from a tiny numpy lidar (16 channels, [-15°, 15°], 1° steps, 15 m, mounted at
0.6 m) cast into box-furnished corridors: no simulator needed.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from navtopo.place_recognition import (
    PlaceRecognitionDataset,
    TrainingConfig,
    available_descriptors,
    batch_hard_triplet_loss,
    evaluate_recall,
    evaluate_revisits,
    make_descriptor,
    nearest,
    retrieve,
    rotate_yaw,
    train,
)
from navtopo.place_recognition.sparse import (
    DownsampleConv3d,
    SparseTensor,
    SubmanifoldConv3d,
    UpsampleConv3d,
    VoxelSet,
)

MOUNT = 0.6


@pytest.fixture(autouse=True, scope="module")
def one_torch_thread():
    """The test machine is shared: one torch thread is several times faster than two."""
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


# -- a numpy lidar in a corridor of boxes ---------------------------------------------------
def lidar_directions() -> np.ndarray:
    elevation = np.deg2rad(np.linspace(-15.0, 15.0, 16))
    azimuth = np.deg2rad(np.arange(0.0, 360.0, 1.0))
    e, a = np.meshgrid(elevation, azimuth, indexing="ij")
    return np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], -1).reshape(-1, 3)


def corridor_world(seed: int, length: float = 30.0, width: float = 4.0, boxes: int = 16) -> dict:
    """Floor, ceiling and side walls (an inside-out box) with boxes standing along the walls."""
    rng = np.random.default_rng(seed)
    lows, highs = [], []
    for _ in range(boxes):
        size = rng.uniform([0.3, 0.3, 0.3], [1.8, 1.2, 2.0])
        x = rng.uniform(0.0, length)
        y = size[1] / 2 if rng.integers(2) == 0 else width - size[1] / 2
        centre = np.array([x, y, size[2] / 2])
        lows.append(centre - size / 2)
        highs.append(centre + size / 2)
    return {
        "inside_min": np.array([0.0, 0.0, 0.0]),
        "inside_max": np.array([length, width, 2.6]),
        "box_min": np.array(lows),
        "box_max": np.array(highs),
    }


def lidar_scan(world: dict, x: float, y: float, yaw: float) -> np.ndarray:
    """(N, 3) float32 returns in the robot frame, z from the floor (slab-method ray casting)."""
    c, s = np.cos(yaw), np.sin(yaw)
    rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    origin = np.array([x, y, MOUNT])
    directions = lidar_directions() @ rotation.T
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = 1.0 / directions
        exits = np.maximum((world["inside_min"] - origin) * inverse, (world["inside_max"] - origin) * inverse)
        ranges = np.nanmin(np.where(exits > 0, exits, np.inf), axis=1)
        near = (world["box_min"][None] - origin) * inverse[:, None]
        far = (world["box_max"][None] - origin) * inverse[:, None]
        entry = np.nanmax(np.minimum(near, far), axis=2)
        leave = np.nanmin(np.maximum(near, far), axis=2)
        hit = (entry <= leave) & (entry > 0)
        ranges = np.minimum(ranges, np.where(hit, entry, np.inf).min(axis=1))
    keep = ranges < 15.0
    points = (directions[keep] * ranges[keep, None]) @ rotation  # world -> robot axes
    points[:, 2] += MOUNT
    return points.astype(np.float32)


@pytest.fixture(scope="module")
def corridor_scans() -> PlaceRecognitionDataset:
    """Two worlds, two passes each (along y = 1.5 and y = 2.5, random headings)."""
    rng = np.random.default_rng(0)
    clouds, positions, worlds, sequences = [], [], [], []
    for world_id in range(2):
        world = corridor_world(seed=10 + world_id)
        for sequence, lane in enumerate((1.5, 2.5)):
            for x in np.arange(1.0, 29.5, 2.0):
                yaw = rng.uniform(-np.pi, np.pi)
                clouds.append(lidar_scan(world, x, lane, yaw))
                positions.append((x, lane))
                worlds.append(world_id)
                sequences.append(sequence)
    return PlaceRecognitionDataset(clouds, np.array(positions), np.array(worlds), np.array(sequences))


def untrained(name: str):
    return make_descriptor(name) if name == "scan_context" else make_descriptor(name, weights=None)


# -- registry and interface -----------------------------------------------------------------
def test_registry_lists_the_three_descriptors_and_refuses_unknown_names():
    assert {"minkloc3d", "polar_bev", "scan_context"} <= set(available_descriptors())
    with pytest.raises(KeyError, match="unknown place descriptor 'nope'"):
        make_descriptor("nope")


@pytest.mark.parametrize("name", ["minkloc3d", "polar_bev", "scan_context"])
def test_embeddings_have_the_declared_shape_and_unit_length(name, corridor_scans):
    descriptor = untrained(name)
    single = descriptor.embed(corridor_scans.clouds[0])
    batch = descriptor.embed_batch(corridor_scans.clouds[:3])
    assert single.shape == (descriptor.dim,) and single.dtype == np.float32
    assert batch.shape == (3, descriptor.dim) and batch.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(batch, axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(batch[0], single, atol=1e-5)
    # a scan that sees nothing above the floor still gets a finite descriptor
    floor_only = np.array([[1.0, 0.0, 0.0], [2.0, 1.0, 0.05]], dtype=np.float32)
    assert np.isfinite(descriptor.embed(floor_only)).all()


def test_nearest_returns_sorted_k_nearest_rows():
    database = np.eye(4, dtype=np.float32)
    indices, distances = nearest(np.array([0.9, 0.1, 0.0, 0.0]), database, k=2)
    assert indices.tolist() == [0, 1]
    assert distances[0] < distances[1]


# -- sparse convolutions against dense torch ------------------------------------------------
def random_voxels(seed: int, count: int = 60, extent: int = 7, batch: int = 2):
    generator = torch.Generator().manual_seed(seed)
    coords = torch.cat(
        [
            torch.randint(0, batch, (count, 1), generator=generator),
            torch.randint(-extent, extent, (count, 3), generator=generator),
        ],
        dim=1,
    )
    voxels = VoxelSet.from_coords(coords, batch_size=batch)
    feats = torch.randn(len(voxels), 3, generator=generator, dtype=torch.float64)
    return voxels, feats


def to_dense(voxels: VoxelSet, feats: torch.Tensor, low: int, size: int) -> torch.Tensor:
    dense = torch.zeros(voxels.batch_size, feats.shape[1], size, size, size, dtype=feats.dtype)
    b, x, y, z = (voxels.coords - torch.tensor([0, low, low, low])).T
    dense[b, :, x, y, z] = feats
    return dense


def read_dense(dense: torch.Tensor, voxels: VoxelSet, low: int) -> torch.Tensor:
    b, x, y, z = (voxels.coords - torch.tensor([0, low, low, low])).T
    return dense[b, :, x, y, z]


@pytest.mark.parametrize("kernel_size", [3, 5])
def test_submanifold_conv_equals_dense_conv3d_at_active_voxels(kernel_size):
    voxels, feats = random_voxels(seed=kernel_size)
    conv = SubmanifoldConv3d(3, 4, kernel_size).double()
    out = conv(SparseTensor(feats, voxels)).feats
    weight = conv.weight.detach().permute(2, 1, 0).reshape(4, 3, *(kernel_size,) * 3)
    dense = torch.nn.functional.conv3d(to_dense(voxels, feats, -8, 16), weight, padding=kernel_size // 2)
    torch.testing.assert_close(out, read_dense(dense, voxels, -8), atol=1e-9, rtol=0)
    # and its hand-written backward equals autograd through the dense convolution
    feats_sparse = feats.clone().requires_grad_(True)
    feats_dense = feats.clone().requires_grad_(True)
    weight_dense = weight.clone().requires_grad_(True)
    upstream = torch.randn(len(voxels), 4, dtype=torch.float64)
    (conv(SparseTensor(feats_sparse, voxels)).feats * upstream).sum().backward()
    dense = torch.nn.functional.conv3d(to_dense(voxels, feats_dense, -8, 16), weight_dense, padding=kernel_size // 2)
    (read_dense(dense, voxels, -8) * upstream).sum().backward()
    torch.testing.assert_close(feats_sparse.grad, feats_dense.grad, atol=1e-9, rtol=0)
    weight_grad = weight_dense.grad.reshape(4, 3, -1).permute(2, 1, 0)
    torch.testing.assert_close(conv.weight.grad, weight_grad, atol=1e-9, rtol=0)


def test_stride_two_convs_equal_dense_conv3d_and_its_transpose():
    voxels, feats = random_voxels(seed=1)
    down = DownsampleConv3d(3, 4).double()
    coarse = down(SparseTensor(feats, voxels))
    weight = down.weight.detach().permute(2, 1, 0).reshape(4, 3, 2, 2, 2)
    dense = torch.nn.functional.conv3d(to_dense(voxels, feats, -8, 16), weight, stride=2)
    torch.testing.assert_close(coarse.feats, read_dense(dense, coarse.voxels, -4), atol=1e-9, rtol=0)

    up = UpsampleConv3d(4, 2).double()
    fine = up(coarse, voxels)
    weight_t = up.weight.detach().permute(1, 2, 0).reshape(4, 2, 2, 2, 2)
    dense_up = torch.nn.functional.conv_transpose3d(to_dense(coarse.voxels, coarse.feats.detach(), -4, 8), weight_t, stride=2)
    torch.testing.assert_close(fine.feats, read_dense(dense_up, voxels, -8), atol=1e-9, rtol=0)


# -- Scan Context ---------------------------------------------------------------------------
def test_scan_context_finds_a_scan_turned_by_30_degrees_and_its_yaw(corridor_scans):
    descriptor = make_descriptor("scan_context")
    original = corridor_scans.clouds[3]
    turned = rotate_yaw(original, np.deg2rad(30.0))
    elsewhere = corridor_scans.clouds[10]
    distances, yaws = descriptor.compare(
        descriptor.signature(turned),
        np.stack([descriptor.signature(c) for c in (original, elsewhere)]),
    )
    assert distances[0] < 0.02
    assert distances[1] > 0.1
    assert np.rad2deg(yaws[0]) == pytest.approx(30.0, abs=1e-6)
    # the ring key is heading-invariant (up to beams on sector borders: the 1-degree beams
    # meet the 6-degree borders, and rounding sends a few either way)
    assert float(descriptor.embed(turned) @ descriptor.embed(original)) > 0.995

    embeddings, signatures = descriptor.describe_batch(corridor_scans.clouds[:12])
    query_embedding, query_signature = descriptor.describe_batch([turned])
    best = retrieve(descriptor, query_embedding[0], embeddings, 1, query_signature[0], signatures)
    assert best[0].index == 3
    assert np.rad2deg(best[0].yaw) == pytest.approx(30.0, abs=1e-6)


def test_polar_bev_is_heading_invariant(corridor_scans):
    descriptor = make_descriptor("polar_bev", weights=None)
    original = corridor_scans.clouds[5]
    turned = rotate_yaw(original, np.deg2rad(36.0))  # 12 sectors: a multiple of the azimuth stride 4
    np.testing.assert_allclose(descriptor.embed(turned), descriptor.embed(original), atol=0.05)


def test_recall_is_perfect_when_queries_repeat_the_database(corridor_scans):
    clouds, positions = corridor_scans.clouds[:15], corridor_scans.positions[:15]
    recall = evaluate_recall(make_descriptor("scan_context"), clouds, positions, clouds, positions)
    assert recall["recall_at_1"] == 1.0 and recall["recall_at_5"] == 1.0
    assert recall["queries"] == 15


def test_revisits_query_only_scans_of_earlier_passes():
    # out along a corridor and back, facing the way of travel: coming back, a scan sees the
    # place it saw on the way out turned by 180 degrees
    world = corridor_world(seed=12)
    stations = np.arange(1.0, 29.5, 2.0)
    xs = np.concatenate([stations, stations[::-1]])
    yaws = np.concatenate([np.zeros(len(stations)), np.full(len(stations), np.pi)])
    clouds = [lidar_scan(world, x, 2.0, yaw) for x, yaw in zip(xs, yaws, strict=True)]
    positions = np.column_stack([xs, np.full(len(xs), 2.0)])
    travelled = np.concatenate([[0.0], np.cumsum(np.abs(np.diff(xs)))])
    recall = evaluate_revisits(make_descriptor("scan_context"), clouds, positions, travelled, min_gap_m=10.0)
    # a scan on the way back queries the way out only if it was taken >= 10 m of driving later
    expected = sum(
        any(t <= travelled[i] - 10.0 and abs(xs[j] - xs[i]) <= 3.0 for j, t in enumerate(travelled)) for i in range(len(xs))
    )
    assert recall["queries"] == expected >= 10
    assert recall["recall_at_1"] >= 0.9


# -- weights -------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["minkloc3d", "polar_bev"])
def test_weights_round_trip_gives_identical_descriptors(name, corridor_scans, tmp_path):
    torch.manual_seed(3)
    first = make_descriptor(name, weights=None)
    for module in first.network.modules():  # non-trivial running statistics
        if isinstance(module, torch.nn.modules.batchnorm._BatchNorm):
            module.running_mean.uniform_(-0.5, 0.5)
            module.running_var.uniform_(0.5, 2.0)
    path = first.save_weights(tmp_path / f"{name}.pt", meta={"note": "test"})
    second = make_descriptor(name, weights=path)
    clouds = corridor_scans.clouds[:4]
    np.testing.assert_array_equal(first.embed_batch(clouds), second.embed_batch(clouds))
    assert second.weights_meta == {"note": "test"}


@pytest.mark.parametrize("name", ["minkloc3d", "polar_bev"])
def test_shipped_weights_load_and_tell_places_apart(name, corridor_scans):
    descriptor = make_descriptor(name)  # weights/<name>.pt
    assert descriptor.weights_meta["descriptor"] == name
    embeddings = descriptor.embed_batch(corridor_scans.clouds[:15])
    np.testing.assert_allclose(np.linalg.norm(embeddings, axis=1), 1.0, atol=1e-5)
    assert np.ptp(embeddings, axis=0).max() > 0.05  # not collapsed to one point


def test_weight_files_of_another_descriptor_or_missing_are_refused(tmp_path):
    path = make_descriptor("polar_bev", weights=None).save_weights(tmp_path / "polar.pt")
    with pytest.raises(ValueError, match="weights of 'polar_bev', not 'minkloc3d'"):
        make_descriptor("minkloc3d", weights=path)
    with pytest.raises(FileNotFoundError):
        make_descriptor("minkloc3d", weights=tmp_path / "absent.pt")
    (tmp_path / "broken.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="not a readable weight file"):
        make_descriptor("minkloc3d", weights=tmp_path / "broken.pt")


# -- training ------------------------------------------------------------------------------
def test_batch_hard_triplet_loss_picks_the_hardest_pairs():
    embeddings = torch.tensor([[1.0, 0.0], [0.8, 0.6], [0.0, 1.0], [0.6, 0.8]])
    positions = np.array([[0.0, 0.0], [2.0, 0.0], [20.0, 0.0], [6.0, 0.0]])
    worlds = np.zeros(4, dtype=np.int64)
    loss, stats = batch_hard_triplet_loss(embeddings, positions, worlds, margin=0.3)
    # anchors 0 and 1 (each other's positive, 2 m apart); 3 is 4-6 m away: neither kind
    d01 = float(torch.dist(embeddings[0], embeddings[1]))
    d02 = float(torch.dist(embeddings[0], embeddings[2]))
    d12 = float(torch.dist(embeddings[1], embeddings[2]))
    expected = (max(0.0, d01 - d02 + 0.3) + max(0.0, d01 - d12 + 0.3)) / 2
    assert float(loss) == pytest.approx(expected, abs=1e-6)
    assert stats["anchors"] == 2


def test_dataset_round_trips_through_npz(corridor_scans, tmp_path):
    path = corridor_scans.save(tmp_path / "scans.npz")
    loaded = PlaceRecognitionDataset.load(path)
    assert len(loaded) == len(corridor_scans)
    np.testing.assert_array_equal(loaded.clouds[7], corridor_scans.clouds[7])
    np.testing.assert_array_equal(loaded.sequence_ids, corridor_scans.sequence_ids)
    database, queries = corridor_scans.database_and_queries()
    assert len(database) + len(queries) == len(corridor_scans)
    assert set(database.sequence_ids) == {0} and set(queries.sequence_ids) == {1}


def test_a_few_training_steps_reduce_the_loss_and_write_weights(tmp_path):
    # two worlds x two places x two lanes 1 m apart: every batch holds all eight scans as
    # anchor and positive, so the loss curve is that of full-batch descent, not sampling noise
    clouds, positions, worlds = [], [], []
    for world_id in range(2):
        world = corridor_world(seed=10 + world_id)
        for x in (6.0, 20.0):
            for lane in (1.5, 2.5):
                clouds.append(lidar_scan(world, x, lane, yaw=0.3 * lane))
                positions.append((x, lane))
                worlds.append(world_id)
    scans = PlaceRecognitionDataset(clouds, np.array(positions), np.array(worlds))
    config = TrainingConfig(
        descriptor="minkloc3d",
        architecture={"max_range": 8.0},  # fewer voxels: a faster test
        steps=6,
        max_seconds=120.0,
        batch_pairs=8,
        worlds_per_batch=2,
        yaw_augmentation=False,
        lr=1e-3,
        lr_final=1e-3,
        output_dir=str(tmp_path),
    )
    seen = []
    metrics = train(scans, config, progress=seen.append)
    losses = [loss for _, loss in metrics["loss_curve"]]
    assert metrics["steps"] == len(losses) == 6
    assert np.mean(losses[-2:]) < 0.5 * losses[0]
    assert [p.step for p in seen] == [1, 2, 3, 4, 5, 6]
    assert [p.loss for p in seen] == pytest.approx(losses)

    stats = json.loads((tmp_path / "minkloc3d.json").read_text())
    assert stats["steps"] == 6 and stats["descriptor"] == "minkloc3d"
    assert stats["architecture"]["max_range"] == 8.0
    reloaded = make_descriptor("minkloc3d", weights=tmp_path / "minkloc3d.pt", max_range=8.0)
    assert reloaded.weights_meta["steps"] == 6
    assert np.isfinite(reloaded.embed_batch(clouds)).all()
