"""The topological graph: edges both ways, Dijkstra, k-NN, save/load and exact bytes."""

from __future__ import annotations

import json

import numpy as np
import pytest

from navtopo import geometry as se2
from navtopo.graph import GraphFormatError, TopologicalGraph
from navtopo.local_grid import FREE, OCCUPIED, CroppedGrid


def small_grid(seed: int) -> CroppedGrid:
    rng = np.random.default_rng(seed)
    cells = rng.choice([0, FREE, OCCUPIED], size=(20 + seed, 30), p=[0.2, 0.6, 0.2]).astype(np.uint8)
    return CroppedGrid(cells, 100 + seed, 90, 300)


def chain(n: int = 5) -> tuple[TopologicalGraph, np.ndarray]:
    """Vertices every 3 m along x, each turned a little; edges from the true relative poses."""
    poses = np.array([[3.0 * i, 1.0 * (i % 2), 0.1 * i] for i in range(n)])  # a zigzag
    graph = TopologicalGraph(descriptor_dim=8)
    for i, pose in enumerate(poses):
        graph.add_vertex(small_grid(i), np.eye(8, dtype=np.float32)[i % 8], pose, stamp=float(i))
    for i in range(n - 1):
        graph.add_edge(i, i + 1, se2.between(poses[i], poses[i + 1]))
    return graph, poses


def test_an_edge_is_stored_both_ways_with_the_inverse_pose():
    graph, poses = chain(3)
    np.testing.assert_allclose(graph.edge(1, 0), se2.between(poses[1], poses[0]), atol=1e-12)
    graph.remove_edge(0, 1)
    assert not graph.has_edge(1, 0) and graph.edge_count == 1


def test_dijkstra_follows_translation_lengths_and_composes_the_true_pose():
    graph, poses = chain(5)
    # a straight edge 0-4 is shorter than the zigzag chain, but not on the way to 3
    graph.add_edge(0, 4, se2.between(poses[0], poses[4]))
    path, length = graph.shortest_path(0, 3)
    assert path == [0, 1, 2, 3]
    expected = sum(np.hypot(*(poses[i + 1, :2] - poses[i, :2])) for i in range(3))
    assert length == pytest.approx(expected)
    np.testing.assert_allclose(graph.path_pose(path), se2.between(poses[0], poses[3]), atol=1e-9)
    assert graph.shortest_path(0, 4)[0] == [0, 4]


def test_nearest_descriptors():
    graph, _ = chain(5)
    ids, distances = graph.nearest(np.eye(8, dtype=np.float32)[3], k=2)
    assert ids[0] == 3 and distances[0] == pytest.approx(0.0)


def test_save_then_load_gives_the_identical_graph_and_bytes(tmp_path):
    graph, _ = chain(6)
    graph.save(tmp_path / "g", extra={"grid_config": {"resolution": 0.1}})
    loaded, extra = TopologicalGraph.load(tmp_path / "g")
    assert extra == {"grid_config": {"resolution": 0.1}}
    assert loaded.nbytes == graph.nbytes
    assert len(loaded) == len(graph) and loaded.edge_count == graph.edge_count
    for a, b in zip(graph.vertices, loaded.vertices, strict=True):
        assert np.array_equal(a.grid.cells, b.grid.cells) and (a.grid.row0, a.grid.col0) == (b.grid.row0, b.grid.col0)
        np.testing.assert_array_equal(a.pose_hint, b.pose_hint)
    np.testing.assert_array_equal(loaded.descriptors, graph.descriptors)
    for u, v, pose in graph.edges():
        np.testing.assert_array_equal(loaded.edge(u, v), pose)


def test_exact_bytes_count_every_array():
    graph, _ = chain(4)
    grids = sum(v.grid.cells.nbytes + 24 for v in graph.vertices)
    assert graph.nbytes == grids + 4 * 8 * 4 + 4 * 3 * 8 + 4 * 8 + 2 * 3 * 40


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (lambda d: (d / "graph.json").unlink(), "graph.json: missing"),
        (lambda d: (d / "graph.json").write_text("{not json"), "graph.json: not valid JSON"),
        (lambda d: (d / "grids" / "000002.png").unlink(), "000002.png: missing"),
        (lambda d: (d / "grids" / "000001.png").write_bytes(b"garbage"), "000001.png: corrupt grid image"),
        (lambda d: np.save(d / "descriptors.npy", np.zeros((2, 8), np.float32)), "descriptors.npy: shape (2, 8)"),
        (
            lambda d: (d / "graph.json").write_text(
                json.dumps({**json.loads((d / "graph.json").read_text()), "edges": [[0, 99, 0, 0, 0]]})
            ),
            "edges.0: bad edge",
        ),
    ],
)
def test_a_corrupt_saved_graph_is_refused_with_one_clear_line(tmp_path, damage, message):
    graph, _ = chain(4)
    folder = tmp_path / "g"
    graph.save(folder)
    damage(folder)
    with pytest.raises(GraphFormatError) as info:
        TopologicalGraph.load(folder)
    assert message in str(info.value) and "\n" not in str(info.value)
