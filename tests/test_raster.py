"""The one grid frame and the one map_server reader/writer (navkit.raster)."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from navkit.raster import (
    FREE,
    OCCUPIED,
    TILE,
    UNKNOWN,
    GridFrame,
    MapFileError,
    TiledRaster,
    inside,
    read_map_server,
    trinary_image,
    write_map_server,
)

# --- the grid frame ---------------------------------------------------------------------------


def test_cell_centre_convention_round_trips():
    frame = GridFrame(np.array([-1.0, 3.0]), 0.1)
    assert np.allclose(frame.to_world((2, 5)), [-1.0 + 0.55, 3.0 + 0.25])
    cells = np.array([[0, 0], [2, 5], [7, 1]])
    world = frame.to_world(cells)
    assert world.shape == (3, 2) and world.dtype == np.float64
    back = frame.to_cell(world)
    assert back.dtype == np.int64 and np.array_equal(back, cells)
    # a point just inside a cell's lower-left corner belongs to that cell
    assert np.array_equal(frame.to_cell([-1.0 + 1e-9, 3.0 + 1e-9]), [0, 0])
    assert np.array_equal(frame.to_cell([-1.05, 2.95]), [-1, -1])


def test_a_centred_frame_puts_the_origin_on_the_corner_of_the_four_central_cells():
    # a location grid of 300 cells of 0.1 m: (0, 0) is the corner shared by cells 149 and 150
    frame = GridFrame.centred(300, 0.1)
    assert np.array_equal(frame.to_cell([[0.01, 0.01], [-0.01, -0.01], [0.01, -0.01]]), [[150, 150], [149, 149], [149, 150]])
    assert np.allclose(frame.to_world([150, 150]), [0.05, 0.05])
    # the same arithmetic as floor(x / res) + half, bit for bit, on points near cell borders
    rng = np.random.default_rng(3)
    xy = np.round(rng.uniform(-15, 15, (5000, 2)), 1) + rng.choice([-1e-12, 0.0, 1e-12], (5000, 2))
    expected = np.floor(xy[:, ::-1] / 0.1).astype(np.int64) + 150
    assert np.array_equal(frame.to_cell(xy), expected)
    cells = rng.integers(0, 300, (100, 2))
    assert np.array_equal(frame.to_world(cells), np.stack([(cells[:, 1] - 150 + 0.5) * 0.1, (cells[:, 0] - 150 + 0.5) * 0.1], 1))


def test_a_window_keeps_its_cells_in_place():
    # a cropped grid starting at row 100, col 120 of a centred 300-cell grid
    full = GridFrame.centred(300, 0.1)
    window = full.shifted(100, 120)
    point = np.array([1.23, -4.56])
    assert np.array_equal(window.to_cell(point), full.to_cell(point) - [100, 120])
    assert np.allclose(window.to_world([7, 9]), full.to_world([107, 129]))


def test_centres_extent_and_inside():
    frame = GridFrame(np.array([2.0, -1.0]), 0.5)
    mask = np.zeros((4, 6), bool)
    mask[0, 0] = mask[3, 5] = True
    assert np.allclose(frame.centres(mask), [[2.25, -0.75], [4.75, 0.75]])
    assert frame.extent(mask.shape) == (2.0, -1.0, 5.0, 1.0)
    assert list(inside(np.array([[0, 0], [3, 5], [4, 0], [0, -1]]), mask.shape)) == [True, True, False, False]


# --- map_server files ---------------------------------------------------------------------------


def test_a_written_map_reads_back_cell_for_cell(tmp_path):
    rng = np.random.default_rng(1)
    cells = rng.choice(np.array([UNKNOWN, FREE, OCCUPIED], np.uint8), (37, 53))
    frame = GridFrame(np.array([-3.2, 7.5]), 0.05)
    for image_format in ("png", "pgm"):
        path = write_map_server(tmp_path / f"m_{image_format}.yaml", trinary_image(cells), frame, image_format=image_format)
        read = read_map_server(path)
        assert np.array_equal(read.cells, cells)
        assert np.array_equal(read.frame.origin, frame.origin) and read.frame.resolution == 0.05
        assert read.image_path == (tmp_path / f"m_{image_format}.{image_format}").resolve()


def test_the_image_top_row_is_the_largest_y(tmp_path):
    cells = np.full((3, 2), FREE, np.uint8)
    cells[2, 0] = OCCUPIED  # row 2: the largest y
    path = write_map_server(tmp_path / "m.yaml", trinary_image(cells), GridFrame(np.zeros(2), 1.0))
    import cv2

    image = cv2.imread(str(tmp_path / "m.png"), cv2.IMREAD_UNCHANGED)
    assert image[0, 0] == 0 and image[2, 0] == 254  # the occupied cell is in the image's first row
    assert read_map_server(path).cells[2, 0] == OCCUPIED


def test_pixels_are_classified_as_map_server_does(tmp_path):
    # p = (255 - value) / 255: 0.65 < p occupied, p < 0.25 free, else unknown
    values = np.array([[0, 80, 90, 100, 190, 192, 255]], np.uint8)
    path = tmp_path / "m.yaml"
    (tmp_path / "m.pgm").write_bytes(b"P5\n7 1\n255\n" + values.tobytes())
    meta = {"image": "m.pgm", "resolution": 0.1, "origin": [0, 0, 0], "occupied_thresh": 0.65, "free_thresh": 0.25}
    path.write_text(yaml.safe_dump(meta))
    assert list(read_map_server(path).cells[0]) == [OCCUPIED, OCCUPIED, UNKNOWN, UNKNOWN, UNKNOWN, FREE, FREE]
    meta["negate"] = 1
    path.write_text(yaml.safe_dump(meta))
    assert list(read_map_server(path).cells[0]) == [FREE, UNKNOWN, UNKNOWN, UNKNOWN, OCCUPIED, OCCUPIED, OCCUPIED]


def test_a_pgm_maxval_is_full_intensity(tmp_path):
    # maxval 100: 100 is white (free), 0 black (occupied), 50 grey (unknown)
    (tmp_path / "m.pgm").write_bytes(b"P5\n# a comment\n3 1\n100\n" + bytes([100, 0, 50]))
    (tmp_path / "m.yaml").write_text(yaml.safe_dump({"image": "m.pgm", "resolution": 0.1, "origin": [0, 0, 0]}))
    assert list(read_map_server(tmp_path / "m.yaml").cells[0]) == [FREE, OCCUPIED, UNKNOWN]


@pytest.mark.parametrize(
    ("change", "key", "reason"),
    [
        ({"origin": [0, 0, 0.5]}, "origin", "rotated"),
        ({"resolution": 0}, "resolution", "must be > 0"),
        ({"free_thresh": 0.9}, "free_thresh", "not below occupied_thresh"),
        ({"mode": "colour"}, "mode", "unknown mode"),
        ({"image": "missing.pgm"}, "image", "not found"),
    ],
)
def test_a_bad_map_is_one_error_naming_file_key_and_reason(tmp_path, change, key, reason):
    (tmp_path / "m.pgm").write_bytes(b"P5\n1 1\n255\n\xfe")
    meta = {"image": "m.pgm", "resolution": 0.1, "origin": [0, 0, 0], **change}
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(meta))
    with pytest.raises(MapFileError) as caught:
        read_map_server(tmp_path / "m.yaml")
    assert caught.value.key == key and reason in caught.value.reason
    assert str(caught.value).startswith(f"{tmp_path / 'm.yaml'}: {key}: ")
    assert isinstance(caught.value, ValueError) and caught.value.exit_code == 2


def test_a_size_check_refuses_before_decoding(tmp_path):
    write_map_server(tmp_path / "m.yaml", trinary_image(np.ones((40, 30), np.uint8)), GridFrame(np.zeros(2), 0.1))
    seen = []

    def check(shape, resolution, image):
        seen.append((shape, resolution, image.name))
        raise ValueError("too large for this test")

    with pytest.raises(MapFileError, match="m.yaml: image: too large for this test"):
        read_map_server(tmp_path / "m.yaml", check_size=check)
    assert seen == [((40, 30), 0.1, "m.png")]  # from the header, once: nothing was decoded


def test_a_tiled_raster_keeps_every_value_and_only_the_tiles_off_its_fill():
    """``TiledRaster``: lossless (``dense`` and ``at`` give the raster back, ragged edges included)
    and only the tiles that hold a value other than the fill are stored."""
    rng = np.random.default_rng(3)
    for height, width in [(1, 1), (16, 16), (17, 33), (70, 45)]:
        dense = np.full((height, width), 500, np.int16)
        marked = rng.random((height, width)) < 0.01
        dense[marked] = rng.integers(-400, 400, int(marked.sum()))
        tiled = TiledRaster.of(dense, 500)
        assert np.array_equal(tiled.dense(), dense) and tiled.dense().dtype == np.int16
        rows, cols = np.indices(dense.shape)
        assert np.array_equal(tiled.at(rows, cols), dense)
        live = {(r // TILE, c // TILE) for r, c in zip(*np.nonzero(dense != 500), strict=True)}
        assert len(tiled.tiles) == len(live) + 1 and tiled.fill == 500
        assert tiled.nbytes == tiled.tile_of.nbytes + (len(live) + 1) * TILE * TILE * 2
