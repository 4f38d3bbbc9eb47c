"""Simulator worlds: the built-in worlds, the file format and its errors, the ground-truth map."""

from __future__ import annotations

import math
import textwrap

import numpy as np
import pytest

from slam2d.errors import InputError
from slam2d.sim.world import (
    MATERIALS,
    World,
    builtin_world_names,
    check_pose,
    first_blocked,
    load_world,
    parse_world,
    rasterize,
    segment_distances,
)

BUILTIN = ("paper-arena", "static-can", "broken-wall", "rebound-wall", "long-corridor", "corridor-loop", "office")
CLEARANCE = 0.4  # m: the default paths keep at least this far from every wall


def write(tmp_path, text, name="w.yaml"):
    path = tmp_path / name
    path.write_text(textwrap.dedent(text).lstrip("\n"))
    return path


def load_error(tmp_path, text, name="w.yaml") -> InputError:
    path = write(tmp_path, text, name)
    with pytest.raises(InputError) as info:
        load_world(path)
    err = info.value
    assert err.path == str(path), err
    assert "\n" not in str(err)
    return err


def one_wall(x0=0.0, y0=0.0, x1=1.0, y1=0.0, circles=()) -> World:
    c = np.array(circles, dtype=np.float64).reshape(-1, 3)
    return World("t", "", np.array([[x0, y0, x1, y1]]), [0], c, [0] * len(c))


def proper_crossings(segments):
    """Pairs (i, j) of segments whose interiors cross at one point (brute force, parametric form)."""
    out = []
    for i in range(len(segments)):
        for j in range(i + 1, len(segments)):
            p, r = segments[i, :2], segments[i, 2:] - segments[i, :2]
            q, s = segments[j, :2], segments[j, 2:] - segments[j, :2]
            denom = r[0] * s[1] - r[1] * s[0]
            if abs(denom) < 1e-12:
                continue
            t = ((q - p)[0] * s[1] - (q - p)[1] * s[0]) / denom
            u = ((q - p)[0] * r[1] - (q - p)[1] * r[0]) / denom
            if 1e-6 < t < 1 - 1e-6 and 1e-6 < u < 1 - 1e-6:
                out.append((i, j))
    return out


# --------------------------------------------------------------------------- built-in worlds


def test_materials_come_from_the_noise_model():
    from slam2d.sensors import range_noise

    assert MATERIALS is range_noise.MATERIALS


def test_builtin_names():
    assert set(BUILTIN) <= set(builtin_world_names())


@pytest.mark.parametrize("name", BUILTIN)
def test_builtin_world_is_sound(name):
    world = load_world(name)
    assert world.name == name and world.source == f"built-in:{name}" and world.description
    assert len(world.segments) + len(world.circles) > 0
    assert set(np.unique(world.segment_material)) <= set(range(len(MATERIALS)))
    assert proper_crossings(world.segments) == []
    # Start inside and clear; every leg of the default path (and the leg that closes the loop) clear.
    assert world.start is not None and world.waypoints is not None
    check_pose(world, world.start, CLEARANCE)
    legs = np.vstack([world.start[:2], world.waypoints, world.waypoints[:1]])
    for k in range(len(legs) - 1):
        assert first_blocked(world, legs[k], legs[k + 1], CLEARANCE) is None, (name, k)
        # Independent check: sample the leg densely and measure the distance to every wall and circle.
        pts = legs[k] + np.linspace(0.0, 1.0, 400)[:, None] * (legs[k + 1] - legs[k])
        assert segment_distances(world.segments, pts).min() >= CLEARANCE
        if len(world.circles):
            centre = np.hypot(pts[:, None, 0] - world.circles[:, 0], pts[:, None, 1] - world.circles[:, 1])
            assert (centre - world.circles[:, 2]).min() >= CLEARANCE


@pytest.mark.parametrize(
    "name, width, height",
    [
        ("paper-arena", (4.0, 6.0), (4.0, 6.0)),
        ("long-corridor", (30.0, 30.0), (2.0, 2.0)),
        ("corridor-loop", (18.0, 22.0), (13.0, 17.0)),
        ("office", (20.0, 40.0), (20.0, 40.0)),
        ("static-can", (2.0, 3.0), (1.0, 3.0)),
        ("broken-wall", (2.0, 3.0), (1.0, 3.0)),
        ("rebound-wall", (2.0, 3.0), (1.0, 3.0)),
    ],
)
def test_builtin_world_sizes(name, width, height):
    xmin, ymin, xmax, ymax = load_world(name).bounds()
    assert width[0] <= xmax - xmin <= width[1] and height[0] <= ymax - ymin <= height[1]


def test_study_worlds_match_the_set_ups():
    can = load_world("static-can")
    assert can.circles.shape == (1, 3) and can.circles[0, 2] == pytest.approx(0.033)
    wall = can.segments[0]
    robot_to_wall = abs(wall[1] - can.start[1])
    assert 1.0 <= robot_to_wall <= 1.5 and 2.0 <= abs(wall[2] - wall[0]) <= 3.0
    # The can stands between the robot and the wall, and the robot faces it.
    assert can.start[1] < can.circles[0, 1] < wall[1]
    assert can.start[2] == pytest.approx(math.pi / 2)
    # broken-wall has angled sections; rebound-wall a rectangular recess (only axis-aligned walls).
    seg = load_world("broken-wall").segments
    angles = np.degrees(np.arctan2(seg[:, 3] - seg[:, 1], seg[:, 2] - seg[:, 0])) % 180
    assert np.any((angles > 10) & (angles < 80) | (angles > 100) & (angles < 170))
    seg = load_world("rebound-wall").segments
    angles = np.degrees(np.arctan2(seg[:, 3] - seg[:, 1], seg[:, 2] - seg[:, 0])) % 90
    assert np.allclose(angles, 0.0)
    arena = load_world("paper-arena")
    assert {MATERIALS[i] for i in arena.segment_material} >= set(MATERIALS[:4])


def test_world_arrays_are_read_only():
    world = load_world("paper-arena")
    with pytest.raises(ValueError):
        world.segments[0, 0] = 1.0


# --------------------------------------------------------------------------- file format


@pytest.mark.parametrize("name", BUILTIN)
def test_to_yaml_round_trips(tmp_path, name):
    world = load_world(name)
    path = tmp_path / "again.yaml"
    path.write_text(world.to_yaml())
    again = load_world(path)
    assert again == world and again.source == str(path)


def test_to_yaml_keeps_awkward_floats_exact(tmp_path):
    third = 1.0 / 3.0
    world = World(
        'a "quoted" name',
        "line one: with colon\nline two",
        np.array([[1e-5, third, 2.5e1, 7.0], [0.0, -1e-300, 25.0, -3.0]]),
        [0, 4],
        np.array([[3.0, 3.0, 1e-3]]),
        [2],
        start=np.array([20.0, 0.1 + 0.2, -math.pi]),
        waypoints=np.array([[20.0, 2.0], [30 * third, 1.0]]),
    )
    path = tmp_path / "w.yaml"
    path.write_text(world.to_yaml())
    again = load_world(path)
    assert again == world
    assert again.segments[0, 1] == third and again.segments[1, 1] == -1e-300 and again.start[1] == 0.1 + 0.2


def test_all_wall_forms_and_json(tmp_path):
    text = """
    name: forms
    walls:
      - {from: [0, 0], to: [4, 0], material: varnished-wood}
      - polyline: [[4, 0], [4, 3], [0, 3]]
        material: white-textile
      - {polyline: [[0, 3], [0, 0]], closed: false, material: white-paper}
      - {box: {min: [1, 1], max: [2, 1.5]}, material: cardboard}
      - {polyline: [[3, 2], [3.5, 2], [3.5, 2.5]], closed: true, material: black-metal}
    circles:
      - {center: [2.5, 2.5], radius: 0.033, material: white-paper}
    start: [0.5, 0.5, 0]
    path: [[3.5, 0.5], [3.5, 1.5]]
    """
    world = load_world(write(tmp_path, text))
    assert len(world.segments) == 1 + 2 + 1 + 4 + 3
    assert world.segment_material.tolist() == [0, 1, 1, 2, 3, 3, 3, 3, 4, 4, 4]
    assert world.circle_material.tolist() == [2] and world.circles[0].tolist() == [2.5, 2.5, 0.033]
    assert world.bounds() == (0.0, 0.0, 4.0, 3.0)
    json_path = tmp_path / "w.json"
    json_path.write_text(
        '{"name": "j", "walls": [{"box": {"min": [0, 0], "max": [2, 1]}, "material": "cardboard"}],'
        ' "start": [1, 0.5, 0]}'
    )
    j = load_world(json_path)
    assert j.name == "j" and len(j.segments) == 4 and j.waypoints is None


def test_name_defaults_to_the_file_name_and_exponents_are_numbers(tmp_path):
    world = load_world(write(tmp_path, "walls: [{from: [0, 0], to: [1e0, 2e-1], material: cardboard}]\n", "my-room.yaml"))
    assert world.name == "my-room" and world.segments[0].tolist() == [0.0, 0.0, 1.0, 0.2]


# --------------------------------------------------------------------------- bad input


def test_unknown_top_level_key(tmp_path):
    err = load_error(tmp_path, """
    name: x
    walls:
      - {from: [0, 0], to: [1, 0], material: cardboard}
    colour: red
    """)
    assert err.where == 4 and err.field == "colour" and "unknown key 'colour'" in str(err)
    assert f"{err.path}:4:" in str(err)


def test_unknown_key_inside_a_wall(tmp_path):
    err = load_error(tmp_path, """
    walls:
      - {from: [0, 0], to: [1, 0], material: cardboard}
      - from: [0, 1]
        to: [1, 1]
        thickness: 0.1
        material: cardboard
    """)
    assert err.where == 5 and err.field == "walls[2].thickness" and "thickness" in str(err)


def test_unknown_key_inside_a_box_and_a_circle(tmp_path):
    err = load_error(tmp_path, "walls:\n  - {box: {min: [0, 0], max: [1, 1], maxx: [2, 2]}, material: cardboard}\n")
    assert err.where == 2 and "maxx" in err.field
    err = load_error(tmp_path, """
    walls: [{from: [0, 0], to: [1, 0], material: cardboard}]
    circles:
      - {centre: [0.5, 0.5], radius: 0.1, material: cardboard}
    """)
    assert err.where == 3 and err.field == "circles[1].centre"


def test_crossing_walls(tmp_path):
    err = load_error(tmp_path, """
    walls:
      - {from: [0, 0], to: [2, 0], material: cardboard}
      - {from: [0, -1], to: [0, 1], material: cardboard}
      - {from: [1, -1], to: [1.5, 1], material: cardboard}
    """)
    # Wall 2 only touches wall 1 in a T (allowed); wall 3 crosses wall 1 at (1.25, 0).
    assert "walls 1 and 3 cross at (1.25, 0)" in str(err) and err.where == 4


def test_touching_and_collinear_walls_are_allowed(tmp_path):
    world = load_world(write(tmp_path, """
    walls:
      - {from: [0, 0], to: [2, 0], material: cardboard}
      - {from: [2, 0], to: [2, 2], material: cardboard}
      - {from: [1, 0], to: [1, 1], material: cardboard}
      - {from: [0.5, 0], to: [1.5, 0], material: white-paper}
    """))
    assert len(world.segments) == 4


def test_self_crossing_polyline(tmp_path):
    err = load_error(tmp_path, "walls:\n  - {polyline: [[0, 0], [2, 2], [2, 0], [0, 2]], material: cardboard}\n")
    assert "wall 1 crosses itself at (1, 1)" in str(err) and err.where == 2


def test_empty_world(tmp_path):
    for text in ("name: nothing\n", "walls: []\ncircles: []\n", "", "walls:\n"):
        err = load_error(tmp_path, text)
        assert "empty" in str(err) and err.field == "walls"


def test_unknown_material(tmp_path):
    err = load_error(tmp_path, "walls:\n  - {from: [0, 0], to: [1, 0], material: steel}\n")
    assert err.where == 2 and err.field == "walls[1].material" and "'steel'" in str(err)
    assert all(m in str(err) for m in MATERIALS)
    err = load_error(tmp_path, "walls:\n  - {from: [0, 0], to: [1, 0]}\n")
    assert "missing 'material'" in str(err) and err.field == "walls[1].material"


@pytest.mark.parametrize("radius", ["-0.1", "0"])
def test_non_positive_radius(tmp_path, radius):
    err = load_error(tmp_path, f"""
    walls: [{{from: [0, 0], to: [1, 0], material: cardboard}}]
    circles:
      - center: [0.5, 1]
        radius: {radius}
        material: cardboard
    """)
    assert err.where == 4 and err.field == "circles[1].radius" and "positive" in str(err)


def test_non_numeric_coordinates(tmp_path):
    err = load_error(tmp_path, "walls:\n  - {from: [0, zero], to: [1, 0], material: cardboard}\n")
    assert err.field == "walls[1].from" and "'zero'" in str(err) and err.where == 2
    err = load_error(tmp_path, "walls:\n  - {from: [0, .nan], to: [1, 0], material: cardboard}\n")
    assert err.field == "walls[1].from" and "finite" in str(err)
    err = load_error(tmp_path, "walls:\n  - {from: [0, 0, 0], to: [1, 0], material: cardboard}\n")
    assert err.field == "walls[1].from" and "[x, y]" in str(err)
    err = load_error(tmp_path, "walls:\n  - {from: [0, 0], to: [1, 0], material: cardboard}\nstart: [1, 2]\n")
    assert err.field == "start" and err.where == 3 and "[x, y, theta]" in str(err)


def test_malformed_walls(tmp_path):
    cases = [
        ("walls:\n  - {from: [0, 0], material: cardboard}\n", "walls[1].to", "without 'to'"),
        ("walls:\n  - {from: [0, 0], to: [0, 0], material: cardboard}\n", "walls[1]", "zero length"),
        ("walls:\n  - {box: {min: [1, 1], max: [0, 2]}, material: cardboard}\n", "walls[1].box.max", "above min"),
        ("walls:\n  - {polyline: [[0, 0]], material: cardboard}\n", "walls[1].polyline", "at least 2"),
        ("walls:\n  - {from: [0, 0], to: [1, 0], box: {min: [0, 0], max: [1, 1]}, material: cardboard}\n",
         "walls[1]", "exactly one"),
        ("walls:\n  - {from: [0, 0], to: [1, 0], closed: true, material: cardboard}\n", "walls[1].closed", "polyline"),
        ("walls: {from: [0, 0], to: [1, 0]}\n", "walls", "expected a list"),
        ("walls:\n  - [0, 0, 1, 0]\n", "walls[1]", "expected a mapping"),
    ]
    for text, field, needle in cases:
        err = load_error(tmp_path, text)
        assert err.field == field and needle in str(err), (text, str(err))
        assert err.where is not None


def test_wall_through_a_circle(tmp_path):
    err = load_error(tmp_path, """
    walls: [{from: [0, 0], to: [2, 0], material: cardboard}]
    circles: [{center: [1, 0.01], radius: 0.033, material: white-paper}]
    """)
    assert "runs through the inside of circle 1" in str(err) and err.where == 2


def test_yaml_syntax_error_and_duplicate_key(tmp_path):
    err = load_error(tmp_path, "walls:\n  - {from: [0, 0], to: [1, 0]\nname: x\n")
    assert "not valid YAML" in str(err) and isinstance(err.where, int)
    err = load_error(tmp_path, "name: a\nname: b\nwalls: [{from: [0, 0], to: [1, 0], material: cardboard}]\n")
    assert "appears twice" in str(err) and err.where == 2


def test_not_a_world_at_all(tmp_path):
    err = load_error(tmp_path, "- just\n- a list\n")
    assert err.field == "world" and err.where == 1 and "expected a mapping" in str(err)
    err = load_error(tmp_path, "name: a\n---\nname: b\n")
    assert "not valid YAML" in str(err)
    with pytest.raises(InputError) as info:
        load_world(tmp_path)
    assert "not a file" in str(info.value)


def test_not_text(tmp_path):
    path = tmp_path / "w.yaml"
    path.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(InputError) as info:
        load_world(path)
    assert str(path) in str(info.value)


def test_unknown_world_name():
    with pytest.raises(InputError) as info:
        load_world("no-such-world")
    assert "no-such-world" in str(info.value) and "paper-arena" in str(info.value)
    assert info.value.field == "world"


def test_start_outside_the_world(tmp_path):
    err = load_error(tmp_path, """
    walls:
      - {box: {min: [0, 0], max: [4, 3]}, material: cardboard}
    start: [10, 1, 0]
    """)
    assert err.field == "start" and err.where == 3 and "outside the world" in str(err)


def test_start_on_a_wall_and_check_pose_clearance(tmp_path):
    err = load_error(tmp_path, "walls:\n  - {box: {min: [0, 0], max: [4, 3]}, material: cardboard}\nstart: [4, 1, 0]\n")
    assert err.field == "start" and "0.000 m from a wall" in str(err)
    world = load_world(write(tmp_path, "walls:\n  - {box: {min: [0, 0], max: [4, 3]}, material: cardboard}\n"
                                       "start: [0.2, 1, 0]\n"))
    check_pose(world, world.start, 0.15)
    with pytest.raises(InputError) as info:
        check_pose(world, world.start, 0.3)
    err = info.value
    assert err.field == "start" and err.where == 3 and err.path == world.source
    assert "(0.2, 1) is 0.200 m from a wall at (0, 1)" in str(err) and "0.3 m" in str(err)
    with pytest.raises(InputError):
        check_pose(world, [1.0, np.nan, 0.0], 0.1)


def test_default_path_through_a_wall(tmp_path):
    err = load_error(tmp_path, """
    walls:
      - {box: {min: [0, 0], max: [4, 3]}, material: cardboard}
      - {from: [2, 0], to: [2, 2], material: cardboard}
    start: [1, 1, 0]
    path:
      - [1, 2.5]
      - [3, 1]
    """)
    assert err.field == "path" and err.where == 5 and "leg 2" in str(err) and "goes through a wall" in str(err)
    err = load_error(tmp_path, "walls:\n  - {box: {min: [0, 0], max: [4, 3]}, material: cardboard}\npath: [[1, 1], [5, 1]]\n")
    assert err.field == "path" and "waypoint 2" in str(err) and "outside" in str(err)


# --------------------------------------------------------------------------- first_blocked


def test_first_blocked_exact_points():
    wall = one_wall(2.0, -1.0, 2.0, 1.0)
    # Straight at the wall: stops `clearance` before it.
    assert first_blocked(wall, [0, 0], [4, 0], 0.3) == pytest.approx((1.7, 0.0))
    assert first_blocked(wall, [0, 0], [4, 0], 0.0) == pytest.approx((2.0, 0.0))
    assert first_blocked(wall, [0, 0], [1.6, 0], 0.3) is None
    # Passing the wall's end: touches the disc around the end point.
    end = one_wall(2.0, 0.0, 2.0, 1.0)
    assert first_blocked(end, [0, -0.2], [4, -0.2], 0.3) == pytest.approx((2.0 - math.sqrt(0.05), -0.2))
    assert first_blocked(end, [0, -0.2], [4, -0.2], 0.19) is None
    # Driving parallel to a wall, 0.2 m from it: blocked where it first comes within 0.3 m.
    side = one_wall(2.0, 0.2, 5.0, 0.2)
    assert first_blocked(side, [0, 0], [6, 0], 0.3) == pytest.approx((2.0 - math.sqrt(0.05), 0.0))
    assert first_blocked(side, [3, 0], [6, 0], 0.3) == pytest.approx((3.0, 0.0))  # already too close
    assert first_blocked(side, [0, 0], [6, 0], 0.19) is None
    # A circle: clearance adds to its radius.
    can = one_wall(10, 10, 11, 10, circles=[(3.0, 0.0, 0.5)])
    assert first_blocked(can, [0, 0], [5, 0], 0.2) == pytest.approx((2.3, 0.0))
    assert first_blocked(can, [0, 0.8], [5, 0.8], 0.2) is None


def test_first_blocked_agrees_with_dense_sampling():
    world = load_world("paper-arena")
    rng = np.random.default_rng(3)
    xmin, ymin, xmax, ymax = world.bounds()
    samples = np.linspace(0.0, 1.0, 4001)
    blocked = 0
    for _ in range(150):
        a = rng.uniform([xmin, ymin], [xmax, ymax])
        b = rng.uniform([xmin, ymin], [xmax, ymax])
        clearance = rng.uniform(0.0, 0.5)
        pts = a + samples[:, None] * (b - a)
        close = segment_distances(world.segments, pts).min(axis=1) < clearance
        hit = first_blocked(world, a, b, clearance)
        step = np.linalg.norm(b - a) / (len(samples) - 1)
        if not close.any():
            assert hit is None or segment_distances(world.segments, np.array([hit])).min() >= clearance - 1e-6
            continue
        blocked += 1
        assert hit is not None
        if close[0]:  # starts too close already
            assert hit == pytest.approx(tuple(a))
            continue
        first = pts[np.argmax(close)]
        # The exact first contact lies at most one sample step before the first sampled contact.
        assert np.linalg.norm(np.array(hit) - first) <= step + 1e-9
        assert segment_distances(world.segments, np.array([hit])).min() == pytest.approx(clearance, abs=1e-6)
    assert blocked > 50


def test_segment_distances():
    seg = np.array([[0.0, 0.0, 2.0, 0.0], [5.0, 5.0, 5.0, 6.0]])
    d = segment_distances(seg, [[1.0, 1.0], [-3.0, -4.0], [5.0, 5.5]])
    assert d.shape == (3, 2)
    assert d[:, 0].tolist() == pytest.approx([1.0, 5.0, math.hypot(3.0, 5.5)])
    assert d[2, 1] == 0.0


# --------------------------------------------------------------------------- ground-truth map


def test_one_metre_wall_cell_count():
    # Cell centres sit on multiples of the resolution, so a wall from x = 0 to x = 1 has
    # its ends in the middle of the cells centred on 0 and 1: cells 0, 0.05, ..., 1.0 = 21.
    grid = rasterize(one_wall(0.0, 0.5, 1.0, 0.5), resolution=0.05)
    assert grid.occupied().sum() == 21
    occupied_x = grid.cell_to_world(np.argwhere(grid.occupied()))[:, 0]
    assert occupied_x.min() == pytest.approx(0.0) and occupied_x.max() == pytest.approx(1.0)
    # Shifted so both ends lie on cell boundaries, exactly 20 cells hold the wall.
    assert rasterize(one_wall(0.025, 0.5, 1.025, 0.5), resolution=0.05).occupied().sum() == 20
    # Anywhere else a 1 m wall straddles 21 cells; vertical and diagonal alike.
    assert rasterize(one_wall(0.013, 0.5, 1.013, 0.5), resolution=0.05).occupied().sum() == 21
    assert rasterize(one_wall(0.3, 0.0, 0.3, 1.0), resolution=0.05).occupied().sum() == 21
    assert rasterize(one_wall(0.0, 0.0, 1.0, 1.0), resolution=0.05).occupied().sum() == 21


def _sampled_cells(grid, points):
    """Cells of sample points, leaving out points within 1e-6 m of a cell boundary (ambiguous)."""
    ox, oy = grid.origin
    u = (points[:, 0] - ox) / grid.resolution
    v = (points[:, 1] - oy) / grid.resolution
    clear = (np.abs(u - np.rint(u)) > 1e-6 / grid.resolution) & (np.abs(v - np.rint(v)) > 1e-6 / grid.resolution)
    cells = np.stack([np.floor(v[clear]), np.floor(u[clear])], axis=-1).astype(np.int64)
    return {tuple(c) for c in cells}


@pytest.mark.parametrize("name", BUILTIN)
def test_rasterize_marks_exactly_the_wall_cells(name):
    world = load_world(name)
    grid = rasterize(world, resolution=0.05)
    occupied = {tuple(c) for c in np.argwhere(grid.occupied())}
    # Every cell a densely sampled wall or circle point lies in is occupied ...
    s = np.linspace(0.0, 1.0, 20001)[:, None]
    pts = [seg[:2] + s * (seg[2:] - seg[:2]) for seg in world.segments]
    a = np.linspace(0.0, 2.0 * np.pi, 20001)
    pts += [np.stack([cx + r * np.cos(a), cy + r * np.sin(a)], axis=-1) for cx, cy, r in world.circles]
    sampled = _sampled_cells(grid, np.concatenate(pts))
    assert sampled <= occupied
    # ... and every occupied cell is one of them (dense sampling finds every cell a wall crosses
    # for more than 0.05 / 20000 * 30 m; a corner-only touch is not a crossing).
    assert occupied == sampled


def test_rasterize_free_unknown_and_layout():
    world = load_world("paper-arena")
    grid = rasterize(world, resolution=0.05, margin=0.5)
    xmin, ymin, xmax, ymax = grid.extent()
    assert xmin == pytest.approx(-0.525) and ymin == pytest.approx(-0.525)
    assert xmax == pytest.approx(5.525) and ymax == pytest.approx(4.525)
    occ = grid.occupancy()

    def value(x, y):
        row, col = grid.world_to_cell([x, y])
        return occ[row, col]

    assert value(2.5, 0.7) < 50 and value(0.7, 3.3) < 50  # free floor on the default path
    assert value(1.55, 1.55) < 50  # inside a box: free (the map holds surfaces only)
    assert value(0.0, 2.0) > 50 and value(1.2, 1.5) > 50 and value(3.6, 1.4) > 50  # walls
    assert value(-0.3, 2.0) == -1 and value(5.3, 4.3) == -1  # margin: unknown
    assert grid.observed.sum() == 101 * 81  # the cells overlapping the 5 m x 4 m room
    # Coarser maps keep every wall.
    coarse = rasterize(world, resolution=0.2)
    assert coarse.occupied().sum() > 0 and coarse.resolution == 0.2


def test_rasterize_small_can():
    grid = rasterize(one_wall(0.0, 0.0, 1.0, 0.0, circles=[(0.5, 0.5, 0.033)]), resolution=0.05)
    rows, cols = np.nonzero(grid.occupied())
    can = grid.cell_to_world(np.stack([rows, cols], axis=-1))
    near = np.hypot(can[:, 0] - 0.5, can[:, 1] - 0.5) < 0.1
    # The can (radius 0.033 m) is centred on a cell centre. Its outline pokes out of the centre
    # cell (half-width 0.025 m) into the four side neighbours but passes inside the centre cell's
    # corners (0.0354 m away), so it never reaches the diagonal neighbours: 5 cells.
    assert near.sum() == 5 and len(can) == 5 + 21
    expected = [[0.5, 0.45], [0.45, 0.5], [0.5, 0.5], [0.55, 0.5], [0.5, 0.55]]
    assert np.allclose(sorted(can[near].tolist()), sorted(expected))


def test_rasterize_office_and_bad_resolution():
    world = load_world("office")
    grid = rasterize(world, resolution=0.05)
    assert grid.shape == (421, 621)
    with pytest.raises(InputError):
        rasterize(world, resolution=0.0)
    with pytest.raises(InputError):
        rasterize(world, resolution=-1.0)


def test_rasterize_a_world_too_large_to_count_its_cells():
    world = parse_world(
        "walls:\n  - {from: [0, 0], to: [1e308, 1e308], material: cardboard}\n", source="huge.yaml"
    )
    with pytest.raises(InputError, match="too large to map") as info:
        rasterize(world, resolution=0.02)
    assert info.value.path == "huge.yaml"
