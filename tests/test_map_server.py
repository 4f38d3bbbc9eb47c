"""map_server maps: writer and reader agree with ROS 1 map_saver / map_server and nav2."""

from __future__ import annotations


import numpy as np
import pytest

from slam2d.errors import InputError
from slam2d.grids import GridParams, OccupancyGrid
from slam2d.io.map_server import (
    LOADERS,
    read_map,
    read_pgm,
    save_grid,
    write_map,
    write_pgm,
)

ALL_VALUES = np.concatenate([[-1], np.arange(101)]).astype(np.int8).reshape(2, 51)


def map_saver_class(v: np.ndarray) -> np.ndarray:
    """What ROS 1 map_saver (--occ 65 --free 25) + map_server make of a value."""
    return np.where((v >= 0) & (v <= 25), 0, np.where(v >= 65, 100, -1))


@pytest.mark.parametrize("loader", LOADERS)
def test_trinary_round_trip(tmp_path, loader):
    yaml_path, image = write_map(tmp_path / "map.yaml", ALL_VALUES, 0.05, (-3.0, 2.0, 0.0))
    assert image == tmp_path / "map.pgm" and image.read_bytes().startswith(b"P5\n")
    m = read_map(yaml_path, loader=loader)
    np.testing.assert_array_equal(m.occupancy, map_saver_class(ALL_VALUES))
    pixels, maxval = read_pgm(image)
    assert maxval == 255 and set(np.unique(pixels).tolist()) == {0, 205, 254}
    assert m.mode == "trinary" and not m.negate
    assert (m.occupied_thresh, m.free_thresh) == (0.65, 0.196)


def test_scale_round_trip_is_exact_for_nav2_and_within_2_for_ros1(tmp_path):
    yaml_path, image = write_map(tmp_path / "scaled.yaml", ALL_VALUES, 0.05, (0.0, 0.0, 0.0), mode="scale")
    assert image.suffix == ".png"
    nav2 = read_map(yaml_path, loader="nav2")
    np.testing.assert_array_equal(nav2.occupancy, ALL_VALUES)
    ros1 = read_map(yaml_path, loader="ros1")
    known = ALL_VALUES >= 0
    assert np.all(ros1.occupancy[~known] == -1)
    assert np.abs(ros1.occupancy[known].astype(int) - ALL_VALUES[known]).max() <= 2
    # Free stays white and occupied black, as a viewer expects.
    from PIL import Image

    la = np.asarray(Image.open(image))
    grey = la[::-1, :, 0]  # back to row 0 = lowest y
    assert grey[ALL_VALUES == 0][0] >= 250 and grey[ALL_VALUES == 100][0] <= 5
    assert np.all(np.diff(grey[known].astype(int)) <= 0)  # darker as the value grows


def test_scale_without_unknown_cells_can_be_pgm(tmp_path):
    values = np.arange(101, dtype=np.int8).reshape(1, 101)
    yaml_path, image = write_map(tmp_path / "s.yaml", values, 0.1, (0, 0, 0), mode="scale", image_format="pgm")
    assert image.suffix == ".pgm"
    np.testing.assert_array_equal(read_map(yaml_path).occupancy, values)
    with pytest.raises(InputError, match="image_format: .*alpha"):
        write_map(tmp_path / "bad.yaml", ALL_VALUES, 0.1, (0, 0, 0), mode="scale", image_format="pgm")
    assert not (tmp_path / "bad.yaml").exists() and not (tmp_path / "bad.pgm").exists()


@pytest.mark.parametrize("loader", LOADERS)
def test_raw_round_trip_is_exact(tmp_path, loader):
    yaml_path, _ = write_map(tmp_path / "raw.yaml", ALL_VALUES, 0.05, (0, 0, 0), mode="raw")
    np.testing.assert_array_equal(read_map(yaml_path, loader=loader).occupancy, ALL_VALUES)
    with pytest.raises(InputError, match="negate"):
        write_map(tmp_path / "raw2.yaml", ALL_VALUES, 0.05, (0, 0, 0), mode="raw", negate=1)


def test_origin_and_resolution_are_exact(tmp_path):
    origin = (-12.345678901234567, 0.007100000000000001, 0.3)
    resolution = 0.012345678901234
    yaml_path, _ = write_map(tmp_path / "m.yaml", ALL_VALUES, resolution, origin)
    m = read_map(yaml_path)
    assert m.origin == origin and m.resolution == resolution


def test_row_order_lowest_y_is_the_last_image_row(tmp_path):
    occ = np.full((4, 3), 0, dtype=np.int8)
    occ[0, 2] = 100  # lowest y, highest x
    occ[3, 0] = -1  # highest y, lowest x
    yaml_path, image = write_map(tmp_path / "m.yaml", occ, 0.05, (0, 0, 0))
    pixels, _ = read_pgm(image)
    assert pixels.shape == (4, 3)
    assert pixels[3, 2] == 0  # last image row, right: occupied
    assert pixels[0, 0] == 205  # first image row, left: unknown
    assert int((pixels == 254).sum()) == 10
    np.testing.assert_array_equal(read_map(yaml_path).occupancy, occ)


@pytest.mark.parametrize("mode", ["trinary", "scale"])
def test_negate(tmp_path, mode):
    plain_yaml, plain_img = write_map(tmp_path / "plain.yaml", ALL_VALUES, 0.05, (0, 0, 0), mode=mode)
    neg_yaml, neg_img = write_map(tmp_path / "neg.yaml", ALL_VALUES, 0.05, (0, 0, 0), mode=mode, negate=1)
    assert "negate: 1" in neg_yaml.read_text()
    if mode == "trinary":
        np.testing.assert_array_equal(read_pgm(neg_img)[0], 255 - read_pgm(plain_img)[0])
    for loader in LOADERS:
        np.testing.assert_array_equal(
            read_map(neg_yaml, loader=loader).occupancy, read_map(plain_yaml, loader=loader).occupancy
        )


def test_map_written_like_ros1_map_saver_loads(tmp_path):
    # 4 x 3 map as map_saver writes it: header comment, %f numbers, no mode key.
    rows = [[254, 254, 0], [205, 254, 0], [205, 205, 0], [0, 0, 0]]  # top row first
    header = b"P5\n# CREATOR: map_saver.cpp 0.050 m/pix\n3 4\n255\n"
    (tmp_path / "lab.pgm").write_bytes(header + bytes(np.array(rows, dtype=np.uint8).ravel()))
    (tmp_path / "lab.yaml").write_text(
        "image: lab.pgm\nresolution: 0.050000\norigin: [-10.000000, -5.200000, 0.000000]\n"
        "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n\n"
    )
    m = read_map(tmp_path / "lab.yaml")
    np.testing.assert_array_equal(
        m.occupancy, [[100, 100, 100], [-1, -1, 100], [-1, 0, 100], [0, 0, 100]]
    )
    assert m.origin == (-10.0, -5.2, 0.0) and m.resolution == 0.05 and m.mode == "trinary"
    assert m.image_path == tmp_path / "lab.pgm"
    grid = m.to_grid()
    assert grid.origin == (-10.0, -5.2) and grid.shape == (4, 3)
    assert grid.occupancy()[0, 0] == 97 and grid.occupancy()[1, 0] == -1  # clamped to p_max


def test_plain_pgm_with_comments_and_other_maxval(tmp_path):
    (tmp_path / "p2.pgm").write_text("P2\n# made by hand\n3 2\n# maxval next\n15\n0 15 7\n15 15 0\n")
    pixels, maxval = read_pgm(tmp_path / "p2.pgm")
    assert maxval == 15 and pixels.tolist() == [[0, 15, 7], [15, 15, 0]]
    (tmp_path / "m.yaml").write_text(
        "image: p2.pgm\nresolution: 1\norigin: [0, 0, 0]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    # 7/15 -> shade 119 -> occ 0.53: unknown; 0 -> occupied; 15 -> free.
    assert read_map(tmp_path / "m.yaml").occupancy.tolist() == [[0, 0, 100], [100, 0, -1]]
    big = np.array([[0, 65535], [32768, 65535]], dtype=">u2")
    (tmp_path / "b.pgm").write_bytes(b"P5 2 2 65535\n" + big.tobytes())
    pixels, maxval = read_pgm(tmp_path / "b.pgm")
    assert maxval == 65535 and pixels.tolist() == [[0, 65535], [32768, 65535]]


def test_write_pgm_is_atomic_and_readable(tmp_path):
    data = np.arange(12, dtype=np.uint8).reshape(3, 4)
    write_pgm(tmp_path / "x.pgm", data)
    np.testing.assert_array_equal(read_pgm(tmp_path / "x.pgm")[0], data)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.pgm"]


GOOD = "image: m.pgm\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"


@pytest.mark.parametrize(
    "text, field, line, needle",
    [
        (GOOD.replace("image: m.pgm\n", ""), "image", None, "required key is missing"),
        (GOOD.replace("resolution: 0.05\n", ""), "resolution", None, "required key is missing"),
        (GOOD.replace("0.05", "-0.05"), "resolution", 2, "must be > 0"),
        (GOOD.replace("0.05", "fast"), "resolution", 2, "not a finite number"),
        (GOOD + "mode: fancy\n", "mode", 7, "'fancy' is not a map mode"),
        (GOOD.replace("[0.0, 0.0, 0.0]", "[1.0, 2.0]"), "origin", 3, r"not \[x, y, yaw\]"),
        (GOOD.replace("negate: 0", "negate: 2"), "negate", 4, "must be 0 or 1"),
        (GOOD.replace("free_thresh: 0.196\n", ""), "free_thresh", None, "required key is missing"),
        (GOOD.replace("m.pgm", "missing.pgm"), "image", 1, "not found"),
        (GOOD.replace("occupied_thresh: 0.65", "occupied_thresh: 65"), "occupied_thresh", 5,
         r"65 is not a probability in \[0, 1\]"),
        (GOOD.replace("free_thresh: 0.196", "free_thresh: -0.1"), "free_thresh", 6, "not a probability"),
    ],
)
def test_bad_yaml_names_file_line_and_key(tmp_path, text, field, line, needle):
    write_pgm(tmp_path / "m.pgm", np.zeros((2, 2), np.uint8))
    path = tmp_path / "m.yaml"
    path.write_text(text)
    with pytest.raises(InputError, match=needle) as err:
        read_map(path)
    assert err.value.path == str(path) and err.value.field == field and err.value.where == line
    assert str(err.value).startswith(str(path))


def test_yaml_syntax_error_and_not_a_mapping(tmp_path):
    path = tmp_path / "m.yaml"
    path.write_text("image: m.pgm\nresolution: [0.05\n")
    with pytest.raises(InputError, match="not valid YAML") as err:
        read_map(path)
    assert err.value.path == str(path) and isinstance(err.value.where, int)
    path.write_text("- just\n- a list\n")
    with pytest.raises(InputError, match="mapping"):
        read_map(path)
    with pytest.raises(InputError, match="no such file"):
        read_map(tmp_path / "absent.yaml")
    image = tmp_path / "m.pgm"  # the image given where its YAML goes
    write_pgm(image, np.full((2, 2), 205, np.uint8))
    with pytest.raises(InputError, match="is not text") as err:
        read_map(image)
    assert err.value.path == str(image) and "codec" not in str(err.value)


@pytest.mark.parametrize(
    "content, needle",
    [
        (b"P6\n2 2\n255\n" + bytes(12), "netpbm type P6"),
        (b"P5\n2 x\n255\n" + bytes(4), "height b'x' is not a positive integer"),
        (b"P5\n2 2\n", "maxval is missing"),
        (b"P5\n0 2\n255\n", "empty"),
        (b"P5\n2 2\n255\n" + bytes(3), "raster is 3 bytes"),
        (b"GIF89a not a map", "not a readable image"),
    ],
)
def test_bad_image_header_is_an_input_error(tmp_path, content, needle):
    (tmp_path / "m.pgm").write_bytes(content)
    (tmp_path / "m.yaml").write_text(GOOD)
    with pytest.raises(InputError, match=needle) as err:
        read_map(tmp_path / "m.yaml")
    assert err.value.path == str(tmp_path / "m.pgm")
    assert err.value.field in ("header", "raster")


def test_thresholds_that_would_misread_the_shades_are_refused(tmp_path):
    with pytest.raises(InputError, match="free_thresh"):
        # nav2's save default 0.25 would read the unknown shade 205 (occ 0.196) as free.
        write_map(tmp_path / "m.yaml", ALL_VALUES, 0.05, (0, 0, 0), free_thresh=0.25)
    assert list(tmp_path.iterdir()) == []


def test_save_grid_writes_a_cropped_map_that_loads_back(tmp_path):
    grid = OccupancyGrid(GridParams(resolution=0.05))
    angles = np.linspace(-np.pi, np.pi, 360, endpoint=False)
    for _ in range(3):
        grid.integrate_scan([1.0, 2.0, 0.0], np.full(360, 2.0), angles)
    yaml_path, image = save_grid(grid, tmp_path / "ring.yaml")
    m = read_map(yaml_path)
    cropped = grid.crop_to_observed(1)
    assert m.shape == cropped.shape
    assert m.origin == (*cropped.origin, 0.0)
    np.testing.assert_array_equal(m.occupancy, map_saver_class(cropped.occupancy()))
    loaded = m.to_grid()
    # The ring of hits is where it was, in world coordinates.
    ring = np.argwhere(m.occupancy == 100)
    centres = loaded.cell_to_world(ring)
    radius = np.hypot(centres[:, 0] - 1.0, centres[:, 1] - 2.0)
    assert len(ring) > 100 and np.all(np.abs(radius - 2.0) < 0.08)
    with pytest.raises(InputError, match="empty"):
        save_grid(OccupancyGrid(), tmp_path / "empty.yaml")
