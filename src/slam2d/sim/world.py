"""Simulated worlds: walls and round objects with surface materials, from small YAML files.

A :class:`World` is a set of wall segments and circles (a beverage can, a
pillar), each made of one of the materials of the range-noise model
(:data:`slam2d.sensors.range_noise.MATERIALS`), plus an optional default start
pose and path for the robot. :func:`load_world` reads a built-in world by name
(:func:`builtin_world_names`) or a YAML/JSON file and checks it thoroughly:
every mistake is an :class:`~slam2d.errors.InputError` naming the file, the
line and the field. :func:`rasterize` turns a world into the ground-truth
occupancy map; :func:`first_blocked` and :func:`check_pose` keep robots out of
walls. The file format is described in docs/worlds.md.

Walls and circles are numbered from 1 in file order in messages ("wall 3" is
the third entry under ``walls:``; a polyline or a box is one entry however many
segments it makes).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import ArrayLike, NDArray

from slam2d.errors import InputError
from slam2d.sensors.range_noise import MATERIALS

__all__ = [
    "World",
    "load_world",
    "parse_world",
    "builtin_world_names",
    "rasterize",
    "first_blocked",
    "check_pose",
    "segment_distances",
]

# Geometric tolerance (m): touching within this is touching, not crossing, and
# a clearance is met if missed by less than this.
_EPS = 1e-9
# A world file is a few kilobytes; refuse anything absurd before parsing it.
_MAX_FILE_BYTES = 20_000_000

_TOP_KEYS = ("name", "description", "walls", "circles", "start", "path")
_WALL_KEYS = ("from", "to", "polyline", "closed", "box", "material")
_BOX_KEYS = ("min", "max")
_CIRCLE_KEYS = ("center", "radius", "material")


# --------------------------------------------------------------------------- the world


@dataclass(frozen=True, eq=False)
class World:
    """Walls and circles in the plane (metres), with materials and a default drive.

    Attributes:
        name, description: what the world is.
        segments: ``(M, 4)`` wall segments ``[x0, y0, x1, y1]``.
        segment_material: ``(M,)`` index into ``MATERIALS`` per segment.
        circles: ``(K, 3)`` circles ``[cx, cy, r]`` (their outline reflects).
        circle_material: ``(K,)`` index into ``MATERIALS`` per circle.
        start: default start pose ``[x, y, theta]`` of the robot, or None.
        waypoints: ``(P, 2)`` default path of the robot, or None.
        source: the file it came from, or ``"built-in:NAME"``.
        locations: line numbers of top-level fields in the source file
            (``"start"``, ``"path"``), so later checks can point at them.

    The arrays are read-only. Two worlds are equal when their names,
    descriptions, geometry, materials, start and path are equal (the source
    is not compared).
    """

    name: str
    description: str
    segments: NDArray[np.float64]
    segment_material: NDArray[np.int64]
    circles: NDArray[np.float64]
    circle_material: NDArray[np.int64]
    start: NDArray[np.float64] | None = None
    waypoints: NDArray[np.float64] | None = None
    source: str = ""
    locations: Mapping[str, int] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        def frozen(arr: Any, dtype: Any, shape: tuple[int, ...]) -> NDArray[Any]:
            out = np.array(arr, dtype=dtype).reshape(shape)
            out.setflags(write=False)
            return out

        object.__setattr__(self, "segments", frozen(self.segments, np.float64, (-1, 4)))
        object.__setattr__(self, "segment_material", frozen(self.segment_material, np.int64, (-1,)))
        object.__setattr__(self, "circles", frozen(self.circles, np.float64, (-1, 3)))
        object.__setattr__(self, "circle_material", frozen(self.circle_material, np.int64, (-1,)))
        if self.start is not None:
            object.__setattr__(self, "start", frozen(self.start, np.float64, (3,)))
        if self.waypoints is not None:
            object.__setattr__(self, "waypoints", frozen(self.waypoints, np.float64, (-1, 2)))
        if len(self.segment_material) != len(self.segments) or len(self.circle_material) != len(self.circles):
            raise ValueError("one material per segment and per circle is needed")

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, World):
            return NotImplemented

        def same(a: NDArray[Any] | None, b: NDArray[Any] | None) -> bool:
            if a is None or b is None:
                return a is None and b is None
            return a.shape == b.shape and bool(np.array_equal(a, b))

        return (
            self.name == other.name
            and self.description == other.description
            and same(self.segments, other.segments)
            and same(self.segment_material, other.segment_material)
            and same(self.circles, other.circles)
            and same(self.circle_material, other.circle_material)
            and same(self.start, other.start)
            and same(self.waypoints, other.waypoints)
        )

    __hash__ = None  # type: ignore[assignment]  # mutable-looking arrays: not hashable

    def bounds(self) -> tuple[float, float, float, float]:
        """``(xmin, ymin, xmax, ymax)`` of all walls and circles, metres.

        This is what "inside the world" means for :func:`check_pose`: the
        start and path are not included, so a start pose off in empty space is
        caught.
        """
        xs = [self.segments[:, 0], self.segments[:, 2]]
        ys = [self.segments[:, 1], self.segments[:, 3]]
        if len(self.circles):
            c = self.circles
            xs += [c[:, 0] - c[:, 2], c[:, 0] + c[:, 2]]
            ys += [c[:, 1] - c[:, 2], c[:, 1] + c[:, 2]]
        x = np.concatenate(xs)
        y = np.concatenate(ys)
        if x.size == 0:
            raise ValueError("an empty world has no bounds")
        return float(x.min()), float(y.min()), float(x.max()), float(y.max())

    def material_names(self) -> tuple[list[str], list[str]]:
        """Material names per segment and per circle."""
        return (
            [MATERIALS[int(i)] for i in self.segment_material],
            [MATERIALS[int(i)] for i in self.circle_material],
        )

    def to_yaml(self) -> str:
        """The world as a YAML world file; :func:`load_world` reads it back equal.

        Walls are written one segment per entry (polylines and boxes are not
        reconstructed) with floats in shortest round-trip form, so the
        geometry comes back bit for bit.
        """
        seg_names, circ_names = self.material_names()
        lines = [f"name: {json.dumps(self.name)}", f"description: {json.dumps(self.description)}", "walls:"]
        for s, m in zip(self.segments, seg_names):
            lines.append(f"  - {{from: {_yaml_list(s[:2])}, to: {_yaml_list(s[2:])}, material: {m}}}")
        if len(self.circles):
            lines.append("circles:")
            for c, m in zip(self.circles, circ_names):
                lines.append(f"  - {{center: {_yaml_list(c[:2])}, radius: {_yaml_float(c[2])}, material: {m}}}")
        if self.start is not None:
            lines.append(f"start: {_yaml_list(self.start)}")
        if self.waypoints is not None:
            lines.append("path:")
            lines += [f"  - {_yaml_list(w)}" for w in self.waypoints]
        return "\n".join(lines) + "\n"


def _yaml_float(value: float) -> str:
    """``repr`` of a float in a form YAML 1.1 (PyYAML) reads back as that float."""
    text = repr(float(value))
    if "e" in text and "." not in text.split("e")[0]:
        mantissa, exponent = text.split("e")
        text = f"{mantissa}.0e{exponent if exponent[0] in '+-' else '+' + exponent}"
    return text


def _yaml_list(values: ArrayLike) -> str:
    return "[" + ", ".join(_yaml_float(v) for v in np.asarray(values).reshape(-1)) + "]"


# --------------------------------------------------------------------------- built-in worlds


def _builtin_dir() -> Any:
    return resources.files("slam2d.sim").joinpath("worlds")


def builtin_world_names() -> list[str]:
    """Names of the worlds shipped with slam2d, sorted."""
    folder = _builtin_dir()
    return sorted(p.name[: -len(".yaml")] for p in folder.iterdir() if p.name.endswith(".yaml"))


def load_world(name_or_path: str | Path) -> World:
    """A built-in world by name, or a world from a YAML (or JSON) file.

    An existing file wins over a built-in name. Every problem is an
    :class:`~slam2d.errors.InputError` naming the file, the line and the
    field: unknown keys, missing or non-numeric values, unknown materials, a
    non-positive radius, zero-length walls, walls that cross, a wall through a
    circle, an empty world, a start pose outside the world or on a wall, a
    default path through a wall.
    """
    path = Path(name_or_path)
    text_name = str(name_or_path)
    if path.is_file():
        try:
            size = path.stat().st_size
            if size > _MAX_FILE_BYTES:
                raise InputError(
                    f"{size} bytes is far too large for a world file", path=path, field="world"
                )
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError as exc:
            raise InputError(f"not a text file ({exc.reason})", path=path, field="world") from None
        except OSError as exc:
            raise InputError(f"cannot read: {exc.strerror}", path=path, field="world") from None
        return parse_world(text, source=str(path), default_name=path.stem)
    names = builtin_world_names()
    if text_name in names:
        resource = _builtin_dir().joinpath(f"{text_name}.yaml")
        return parse_world(
            resource.read_text(encoding="utf-8"), source=f"built-in:{text_name}", default_name=text_name,
            error_path=str(resource),
        )
    if path.exists():
        raise InputError("is not a file", path=path, field="world")
    raise InputError(
        f"{text_name!r} is neither a file nor a built-in world (built-in: {', '.join(names)})", field="world"
    )


# --------------------------------------------------------------------------- parsing with line numbers


@dataclass
class _Node:
    """A parsed YAML value with the 1-based line where it starts."""

    value: Any  # dict[str, _Node] | list[_Node] | scalar
    line: int
    key_lines: dict[str, int] | None = None  # for mappings: line of each key


class _Parser:
    """Turns the YAML text into checked arrays, raising InputError with file and line."""

    def __init__(self, text: str, error_path: str) -> None:
        self.text = text
        self.path = error_path
        self._loader = yaml.SafeLoader("")

    def fail(self, message: str, line: int | None, field: str) -> InputError:
        return InputError(message, path=self.path, where=line, field=field)

    # -- YAML to nodes

    def parse_document(self) -> _Node:
        try:
            root = yaml.compose(self.text, Loader=yaml.SafeLoader)
        except yaml.MarkedYAMLError as exc:
            mark = exc.problem_mark or exc.context_mark
            line = mark.line + 1 if mark is not None else None
            problem = (exc.problem or exc.context or "invalid YAML").strip()
            raise self.fail(f"not valid YAML: {problem}", line, "world") from None
        except yaml.YAMLError as exc:
            raise self.fail(f"not valid YAML: {exc}", None, "world") from None
        if root is None:
            raise self.fail("the file is empty: a world needs walls or circles", 1, "walls")
        return self.convert(root, "world")

    def convert(self, node: yaml.Node, where: str) -> _Node:
        line = node.start_mark.line + 1
        if isinstance(node, yaml.MappingNode):
            values: dict[str, _Node] = {}
            key_lines: dict[str, int] = {}
            for key_node, value_node in node.value:
                key_line = key_node.start_mark.line + 1
                if not isinstance(key_node, yaml.ScalarNode):
                    raise self.fail("a key must be a plain name", key_line, where)
                key = str(key_node.value)
                if key in values:
                    raise self.fail(f"key {key!r} appears twice (first on line {key_lines[key]})", key_line, where)
                values[key] = self.convert(value_node, f"{where}.{key}")
                key_lines[key] = key_line
            return _Node(values, line, key_lines)
        if isinstance(node, yaml.SequenceNode):
            return _Node([self.convert(v, where) for v in node.value], line)
        try:
            value = self._loader.construct_object(node, deep=True)
        except yaml.YAMLError as exc:
            raise self.fail(f"cannot read this value: {exc}", line, where) from None
        return _Node(value, line)

    # -- typed accessors

    def mapping(self, node: _Node, field: str, allowed: tuple[str, ...]) -> dict[str, _Node]:
        if not isinstance(node.value, dict):
            raise self.fail(
                f"expected a mapping of {', '.join(allowed)}; got {_describe(node)}", node.line, field or "world"
            )
        assert node.key_lines is not None
        for key, key_line in node.key_lines.items():
            if key not in allowed:
                raise self.fail(
                    f"unknown key {key!r} (allowed here: {', '.join(allowed)})", key_line, _join(field, key)
                )
        return node.value

    def sequence(self, node: _Node, field: str) -> list[_Node]:
        if not isinstance(node.value, list):
            raise self.fail(f"expected a list; got {_describe(node)}", node.line, field)
        return node.value

    def number(self, node: _Node, field: str) -> float:
        value = node.value
        number: float | None = None
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            number = float(value)
        elif isinstance(value, str):
            # PyYAML (YAML 1.1) reads "1e-3" as a string; accept numbers written that way.
            try:
                number = float(value)
            except ValueError:
                number = None
        if number is None or not math.isfinite(number):
            raise self.fail(f"expected a finite number (metres or radians); got {_describe(node)}", node.line, field)
        return number

    def point(self, node: _Node, field: str, size: int = 2, what: str = "[x, y]") -> NDArray[np.float64]:
        items = node.value if isinstance(node.value, list) else None
        if items is None or len(items) != size:
            raise self.fail(f"expected {what}; got {_describe(node)}", node.line, field)
        return np.array([self.number(v, field) for v in items], dtype=np.float64)

    def string(self, node: _Node, field: str) -> str:
        if isinstance(node.value, (dict, list)) or node.value is None:
            raise self.fail(f"expected text; got {_describe(node)}", node.line, field)
        return str(node.value)

    def material(self, item: dict[str, _Node], item_node: _Node, field: str) -> int:
        if "material" not in item:
            raise self.fail(
                f"missing 'material' (one of: {', '.join(MATERIALS)})", item_node.line, _join(field, "material")
            )
        node = item["material"]
        name = self.string(node, _join(field, "material"))
        if name not in MATERIALS:
            raise self.fail(
                f"unknown material {name!r} (one of: {', '.join(MATERIALS)})", node.line, _join(field, "material")
            )
        return MATERIALS.index(name)

    def flag(self, node: _Node, field: str) -> bool:
        if not isinstance(node.value, bool):
            raise self.fail(f"expected true or false; got {_describe(node)}", node.line, field)
        return bool(node.value)


def _join(field: str, key: str) -> str:
    return f"{field}.{key}" if field else key


def _describe(node: _Node) -> str:
    value = node.value
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, list):
        return f"a list of {len(value)}"
    if value is None:
        return "nothing"
    return repr(value)


def parse_world(text: str, *, source: str, default_name: str = "world", error_path: str | None = None) -> World:
    """Parse and check the text of a world file (see :func:`load_world`).

    ``source`` is recorded in the world; errors name ``error_path``
    (default: ``source``).
    """
    p = _Parser(text, error_path or source)
    root = p.parse_document()
    top = p.mapping(root, "", _TOP_KEYS)
    locations = {key: line for key, line in (root.key_lines or {}).items()}

    name = p.string(top["name"], "name") if "name" in top else default_name
    description = p.string(top["description"], "description") if "description" in top else ""

    seg_rows: list[NDArray[np.float64]] = []
    seg_material: list[int] = []
    seg_entry: list[int] = []  # wall number (1-based) of each segment
    entry_lines: list[int] = []
    walls = p.sequence(top["walls"], "walls") if "walls" in top and top["walls"].value is not None else []
    for number, wall_node in enumerate(walls, start=1):
        fname = f"walls[{number}]"
        wall = p.mapping(wall_node, fname, _WALL_KEYS)
        material = p.material(wall, wall_node, fname)
        forms = [k for k in ("from", "polyline", "box") if k in wall]
        if "to" in wall and "from" not in wall:
            forms.append("to")
        if len(forms) != 1:
            raise p.fail(
                "a wall needs exactly one of: from + to, polyline, box"
                + (f" (got {', '.join(forms)})" if forms else ""),
                wall_node.line,
                fname,
            )
        form = forms[0]
        if form == "to":
            raise p.fail("'to' without 'from'", wall["to"].line, _join(fname, "from"))
        if "closed" in wall and form != "polyline":
            raise p.fail("'closed' only applies to a polyline", wall["closed"].line, _join(fname, "closed"))
        if form == "from":
            if "to" not in wall:
                raise p.fail("'from' without 'to'", wall["from"].line, _join(fname, "to"))
            a = p.point(wall["from"], _join(fname, "from"))
            b = p.point(wall["to"], _join(fname, "to"))
            rows = [np.concatenate([a, b])]
        elif form == "polyline":
            pts_nodes = p.sequence(wall["polyline"], _join(fname, "polyline"))
            pts = [p.point(v, _join(fname, "polyline")) for v in pts_nodes]
            closed = p.flag(wall["closed"], _join(fname, "closed")) if "closed" in wall else False
            need = 3 if closed else 2
            if len(pts) < need:
                raise p.fail(
                    f"a{' closed' if closed else ''} polyline needs at least {need} points; got {len(pts)}",
                    wall["polyline"].line,
                    _join(fname, "polyline"),
                )
            if closed:
                pts = pts + [pts[0]]
            rows = [np.concatenate([pts[i], pts[i + 1]]) for i in range(len(pts) - 1)]
        else:
            box = p.mapping(wall["box"], _join(fname, "box"), _BOX_KEYS)
            for key in _BOX_KEYS:
                if key not in box:
                    raise p.fail(f"missing '{key}'", wall["box"].line, _join(fname, f"box.{key}"))
            lo = p.point(box["min"], _join(fname, "box.min"))
            hi = p.point(box["max"], _join(fname, "box.max"))
            if not np.all(hi > lo):
                raise p.fail(
                    f"max {hi.tolist()} must be above min {lo.tolist()} in both x and y",
                    box["max"].line,
                    _join(fname, "box.max"),
                )
            (x0, y0), (x1, y1) = lo, hi
            rows = [np.array(r, dtype=np.float64) for r in
                    ((x0, y0, x1, y0), (x1, y0, x1, y1), (x1, y1, x0, y1), (x0, y1, x0, y0))]
        for k, row in enumerate(rows):
            if math.hypot(row[2] - row[0], row[3] - row[1]) <= _EPS:
                raise p.fail(
                    f"segment {k + 1} has zero length (both ends at ({row[0]:g}, {row[1]:g}))",
                    wall_node.line,
                    fname,
                )
        seg_rows += rows
        seg_material += [material] * len(rows)
        seg_entry += [number] * len(rows)
        entry_lines.append(wall_node.line)

    circ_rows: list[NDArray[np.float64]] = []
    circ_material: list[int] = []
    circ_lines: list[int] = []
    circles = p.sequence(top["circles"], "circles") if "circles" in top and top["circles"].value is not None else []
    for number, circle_node in enumerate(circles, start=1):
        fname = f"circles[{number}]"
        circle = p.mapping(circle_node, fname, _CIRCLE_KEYS)
        for key in ("center", "radius"):
            if key not in circle:
                raise p.fail(f"missing '{key}'", circle_node.line, _join(fname, key))
        center = p.point(circle["center"], _join(fname, "center"))
        radius = p.number(circle["radius"], _join(fname, "radius"))
        if radius <= 0.0:
            raise p.fail(f"radius must be positive; got {radius:g} m", circle["radius"].line, _join(fname, "radius"))
        material = p.material(circle, circle_node, fname)
        circ_rows.append(np.array([center[0], center[1], radius]))
        circ_material.append(material)
        circ_lines.append(circle_node.line)

    if not seg_rows and not circ_rows:
        line = top["walls"].line if "walls" in top else root.line
        raise p.fail("the world is empty: give at least one wall or circle", line, "walls")

    segments = np.array(seg_rows, dtype=np.float64).reshape(-1, 4)
    circle_arr = np.array(circ_rows, dtype=np.float64).reshape(-1, 3)
    _check_crossings(p, segments, np.array(seg_entry, dtype=np.int64), entry_lines)
    _check_walls_through_circles(p, segments, np.array(seg_entry, dtype=np.int64), entry_lines, circle_arr, circ_lines)

    start = p.point(top["start"], "start", 3, "[x, y, theta]") if "start" in top else None
    waypoints = None
    if "path" in top:
        path_nodes = p.sequence(top["path"], "path")
        if not path_nodes:
            raise p.fail("the path is empty: give at least one [x, y] waypoint or leave it out", top["path"].line, "path")
        waypoints = np.array([p.point(v, "path") for v in path_nodes], dtype=np.float64)

    world = World(
        name=name,
        description=description,
        segments=segments,
        segment_material=np.array(seg_material, dtype=np.int64),
        circles=circle_arr,
        circle_material=np.array(circ_material, dtype=np.int64),
        start=start,
        waypoints=waypoints,
        source=source,
        locations=locations,
    )
    _check_default_drive(world, p.path)
    return world


def _side(origin: NDArray[np.float64], direction: NDArray[np.float64], norm: NDArray[np.float64],
          points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Signed distance (m) of ``points`` from the lines through ``origin`` along ``direction`` (left > 0)."""
    rel = points - origin
    return (direction[..., 0] * rel[..., 1] - direction[..., 1] * rel[..., 0]) / norm


def _check_crossings(p: _Parser, segments: NDArray[np.float64], entry: NDArray[np.int64], lines: list[int]) -> None:
    """Refuse walls that cross each other properly (touching ends and T-junctions are fine)."""
    m = len(segments)
    if m < 2:
        return
    a, b = segments[:, :2], segments[:, 2:]
    d = b - a
    length = np.hypot(d[:, 0], d[:, 1])
    chunk = max(1, 2_000_000 // m)  # bounded memory for big worlds
    for lo in range(0, m, chunk):
        hi = min(m, lo + chunk)
        ai, di, li = a[lo:hi, None, :], d[lo:hi, None, :], length[lo:hi, None]
        # Signed distances of each segment's ends from the other's line, for all pairs (i, j).
        s_a = _side(ai, di, li, a[None, :, :])
        s_b = _side(ai, di, li, b[None, :, :])
        s_c = _side(a[None, :, :], d[None, :, :], length[None, :], ai)
        s_d = _side(a[None, :, :], d[None, :, :], length[None, :], b[lo:hi, None, :])
        proper = (
            (np.abs(s_a) > _EPS) & (np.abs(s_b) > _EPS) & (np.sign(s_a) != np.sign(s_b))
            & (np.abs(s_c) > _EPS) & (np.abs(s_d) > _EPS) & (np.sign(s_c) != np.sign(s_d))
        )
        proper &= np.arange(lo, hi)[:, None] < np.arange(m)[None, :]  # each pair once
        if proper.any():
            i_rel, j = np.argwhere(proper)[0]
            i = lo + int(i_rel)
            # Point where segment j meets segment i's line.
            t = s_a[i_rel, j] / (s_a[i_rel, j] - s_b[i_rel, j])
            x, y = a[j] + t * d[j]
            wi, wj = int(entry[i]), int(entry[j])
            if wi == wj:
                raise p.fail(f"wall {wi} crosses itself at ({x:.4g}, {y:.4g})", lines[wi - 1], f"walls[{wi}]")
            first, second = sorted((wi, wj))
            raise p.fail(
                f"walls {first} and {second} cross at ({x:.4g}, {y:.4g}) (lines {lines[first - 1]} and "
                f"{lines[second - 1]}); walls may meet at their ends or in a T, not cross",
                lines[second - 1],
                f"walls[{second}]",
            )


def _check_walls_through_circles(
    p: _Parser,
    segments: NDArray[np.float64],
    entry: NDArray[np.int64],
    wall_lines: list[int],
    circles: NDArray[np.float64],
    circle_lines: list[int],
) -> None:
    """Refuse a wall running through the inside of a circle (a can cut by a wall)."""
    if len(circles) == 0 or len(segments) == 0:
        return
    dist = segment_distances(segments, circles[:, :2])  # (K, M)
    inside = dist < circles[:, 2:3] - 1e-6
    if inside.any():
        k, j = np.argwhere(inside)[0]
        w = int(entry[j])
        raise p.fail(
            f"wall {w} (line {wall_lines[w - 1]}) runs through the inside of circle {k + 1}",
            circle_lines[k],
            f"circles[{k + 1}]",
        )


def _check_default_drive(world: World, error_path: str) -> None:
    """The start pose must be inside the world and off the walls; the default path must not go through a wall."""
    if world.start is not None:
        check_pose(world, world.start, 0.0, field="start", path=error_path)
    if world.waypoints is not None:
        line = world.locations.get("path")
        xmin, ymin, xmax, ymax = world.bounds()
        wp = world.waypoints
        outside = (wp[:, 0] < xmin) | (wp[:, 0] > xmax) | (wp[:, 1] < ymin) | (wp[:, 1] > ymax)
        if outside.any():
            k = int(np.flatnonzero(outside)[0])
            raise InputError(
                f"waypoint {k + 1} ({wp[k, 0]:g}, {wp[k, 1]:g}) is outside the world "
                f"(x {xmin:g}..{xmax:g}, y {ymin:g}..{ymax:g})",
                path=error_path, where=line, field="path",
            )
        legs = wp if world.start is None else np.vstack([world.start[:2], wp])
        for k in range(len(legs) - 1):
            hit = first_blocked(world, legs[k], legs[k + 1], 0.0)
            if hit is not None:
                raise InputError(
                    f"leg {k + 1} from ({legs[k, 0]:g}, {legs[k, 1]:g}) to ({legs[k + 1, 0]:g}, "
                    f"{legs[k + 1, 1]:g}) goes through a wall at ({hit[0]:.4g}, {hit[1]:.4g})",
                    path=error_path, where=line, field="path",
                )


# --------------------------------------------------------------------------- geometry queries


def segment_distances(segments: ArrayLike, points: ArrayLike) -> NDArray[np.float64]:
    """Distance (m) from each point ``(K, 2)`` to each segment ``(M, 4)``: a ``(K, M)`` array."""
    seg = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    a = seg[None, :, :2]
    d = seg[None, :, 2:] - seg[None, :, :2]
    rel = pts[:, None, :] - a
    length2 = np.maximum((d * d).sum(-1), 1e-300)
    t = np.clip((rel * d).sum(-1) / length2, 0.0, 1.0)
    closest = a + t[..., None] * d
    return np.hypot(pts[:, None, 0] - closest[..., 0], pts[:, None, 1] - closest[..., 1])


def _disc_entry(a: NDArray[np.float64], d: NDArray[np.float64], centers: NDArray[np.float64],
                radii: NDArray[np.float64]) -> NDArray[np.float64]:
    """First ``t`` in [0, 1] at which ``a + t d`` is within ``radii`` of ``centers`` (inf if never)."""
    rel = a[None, :] - centers
    qa = float(d @ d)
    qb = 2.0 * (rel @ d)
    qc = (rel * rel).sum(-1) - radii * radii
    entry = np.full(len(centers), np.inf)
    entry[qc <= 0.0] = 0.0
    if qa > 0.0:
        disc = qb * qb - 4.0 * qa * qc
        with np.errstate(invalid="ignore"):
            t = (-qb - np.sqrt(disc)) / (2.0 * qa)
        ok = (qc > 0.0) & (disc >= 0.0) & (t >= 0.0) & (t <= 1.0)
        entry[ok] = t[ok]
    return entry


def _slab_entry(a: NDArray[np.float64], d: NDArray[np.float64], segments: NDArray[np.float64],
                half_width: float) -> NDArray[np.float64]:
    """First ``t`` in [0, 1] at which ``a + t d`` is in the rectangle around each segment (inf if never).

    The rectangle spans the segment's length and ``half_width`` either side of
    it; with the discs at the ends it makes the segment's clearance capsule.
    """
    p0 = segments[:, :2]
    e = segments[:, 2:] - p0
    length = np.hypot(e[:, 0], e[:, 1])
    e = e / length[:, None]
    n = np.stack([-e[:, 1], e[:, 0]], axis=-1)
    rel = a[None, :] - p0
    u0, du = (rel * e).sum(-1), e @ d
    v0, dv = (rel * n).sum(-1), n @ d
    t_in = np.zeros(len(segments))
    t_out = np.ones(len(segments))
    for start, rate, low, high in ((u0, du, 0.0, length), (v0, dv, -half_width, half_width)):
        moving = np.abs(rate) > 1e-15
        with np.errstate(divide="ignore", invalid="ignore"):
            t_low = (low - start) / rate
            t_high = (high - start) / rate
        enter = np.where(moving, np.minimum(t_low, t_high), -np.inf)
        leave = np.where(moving, np.maximum(t_low, t_high), np.inf)
        # A path parallel to the slab is either always inside it or never.
        still_outside = ~moving & ((start < low - _EPS) | (start > high + _EPS))
        t_in = np.maximum(t_in, enter)
        t_out = np.minimum(t_out, np.where(still_outside, -np.inf, leave))
    return np.where(t_in <= t_out, t_in, np.inf)


def first_blocked(world: World, a: ArrayLike, b: ArrayLike, clearance: float) -> tuple[float, float] | None:
    """Where a straight move from ``a`` to ``b`` first comes within ``clearance`` of a wall or circle.

    Returns the position ``(x, y)`` of the moving point (the robot's centre)
    at that moment, or None when the whole move keeps at least ``clearance``
    metres from every wall and circle outline. With ``clearance`` 0 it finds
    where the move crosses or touches a wall. Exact: the move is intersected
    with each obstacle's clearance zone (a capsule around a segment, a larger
    disc around a circle), all obstacles at once.
    """
    start = np.asarray(a, dtype=np.float64).reshape(-1)[:2]
    end = np.asarray(b, dtype=np.float64).reshape(-1)[:2]
    if not (np.all(np.isfinite(start)) and np.all(np.isfinite(end))):
        raise InputError(f"a move from {start.tolist()} to {end.tolist()} is not finite", field="path")
    margin = max(float(clearance) - _EPS, 0.0)
    d = end - start
    seg = world.segments
    entries = [
        _slab_entry(start, d, seg, margin),
        _disc_entry(start, d, seg[:, :2], np.full(len(seg), margin)),
        _disc_entry(start, d, seg[:, 2:], np.full(len(seg), margin)),
    ]
    if len(world.circles):
        entries.append(_disc_entry(start, d, world.circles[:, :2], world.circles[:, 2] + margin))
    t = min((float(e.min()) for e in entries if e.size), default=np.inf)
    if not math.isfinite(t):
        return None
    point = start + t * d
    return float(point[0]), float(point[1])


def _nearest_obstacle(world: World, point: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
    """Distance from ``point`` to the nearest wall or circle outline, and the nearest point on it."""
    best = np.inf
    nearest = point
    if len(world.segments):
        dist = segment_distances(world.segments, point[None, :])[0]
        j = int(np.argmin(dist))
        best = float(dist[j])
        s = world.segments[j]
        d = s[2:] - s[:2]
        t = np.clip(np.dot(point - s[:2], d) / np.dot(d, d), 0.0, 1.0)
        nearest = s[:2] + t * d
    if len(world.circles):
        c = world.circles
        rel = point[None, :] - c[:, :2]
        centre_dist = np.hypot(rel[:, 0], rel[:, 1])
        dist = np.abs(centre_dist - c[:, 2])
        k = int(np.argmin(dist))
        if dist[k] < best:
            best = float(dist[k])
            direction = rel[k] / centre_dist[k] if centre_dist[k] > 0 else np.array([1.0, 0.0])
            nearest = c[k, :2] + c[k, 2] * direction
    return best, nearest


def check_pose(
    world: World, pose: ArrayLike, clearance: float, *, field: str = "start", path: str | None = None
) -> None:
    """Refuse a robot pose outside the world's bounds or within ``clearance`` (m) of a wall or circle.

    "Inside" means within :meth:`World.bounds` (the box around all walls and
    circles); a pose in an enclosed space the robot cannot reach (inside a
    box-shaped obstacle) is not detected. Errors name ``path`` (default: the
    world's source) and the line of ``field`` when the world file gave it.
    """
    where = world.locations.get(field)
    path = path if path is not None else world.source
    arr = np.asarray(pose, dtype=np.float64).reshape(-1)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise InputError(f"{np.asarray(pose).tolist()} is not a finite pose [x, y, theta]",
                         path=path, where=where, field=field)
    xmin, ymin, xmax, ymax = world.bounds()
    x, y = float(arr[0]), float(arr[1])
    if not (xmin <= x <= xmax and ymin <= y <= ymax):
        raise InputError(
            f"({x:g}, {y:g}) is outside the world (x {xmin:g}..{xmax:g}, y {ymin:g}..{ymax:g})",
            path=path, where=where, field=field,
        )
    dist, nearest = _nearest_obstacle(world, arr[:2])
    if dist < clearance - _EPS or dist <= _EPS:
        raise InputError(
            f"({x:g}, {y:g}) is {dist:.3f} m from a wall at ({nearest[0]:.3g}, {nearest[1]:.3g}); "
            f"it needs {clearance:g} m of clearance",
            path=path, where=where, field=field,
        )


# --------------------------------------------------------------------------- ground-truth map


def _snap(cells: NDArray[np.float64]) -> NDArray[np.float64]:
    """Cell coordinates within 1e-9 cells of a whole number are taken as that number.

    Without it, a coordinate on a cell boundary (3 * 0.05 / 0.05 = 2.9999999999999996)
    would fall into a cell depending on rounding.
    """
    nearest = np.rint(cells)
    return np.where(np.abs(cells - nearest) < 1e-9, nearest, cells)


def _segment_cells(u0: float, v0: float, u1: float, v1: float) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Cells ``(cols, rows)`` a segment in cell coordinates passes through (cell k = [k, k+1)).

    The segment is cut where it crosses a grid line; the middle of every piece
    lies inside exactly one cell, so the cells of the pieces are exactly the
    cells the segment passes through (a cell only touched at a corner is not).
    A segment lying exactly on a grid line counts in the cell above / to the
    right of it, like a point on a boundary.
    """
    cuts = [np.array([0.0, 1.0])]
    for start, stop in ((u0, u1), (v0, v1)):
        if stop != start:
            lines = np.arange(math.floor(min(start, stop)) + 1, math.ceil(max(start, stop)))
            cuts.append((lines - start) / (stop - start))
    t = np.unique(np.clip(np.concatenate(cuts), 0.0, 1.0))
    # Where the segment crosses a grid corner, the x and y cuts agree only to rounding: drop the
    # sliver between them, or its middle would land in a cell the segment only touches.
    length = math.hypot(u1 - u0, v1 - v0)
    keep = (t[1:] - t[:-1]) * length > 1e-9
    mid = 0.5 * (t[:-1] + t[1:])[keep]
    cols = np.floor(_snap(u0 + mid * (u1 - u0))).astype(np.int64)
    rows = np.floor(_snap(v0 + mid * (v1 - v0))).astype(np.int64)
    return cols, rows


def _circle_cells(cu: float, cv: float, r: float) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Cells ``(cols, rows)`` a circle outline in cell coordinates passes through (same rule as segments)."""
    angles = [np.array([0.0, 2.0 * np.pi])]
    for centre, trig in ((cu, np.arccos), (cv, np.arcsin)):
        lines = np.arange(math.floor(centre - r) + 1, math.ceil(centre + r))
        base = trig(np.clip((lines - centre) / r, -1.0, 1.0))
        # x = cu + r cos(a): a = +-acos; y = cv + r sin(a): a = asin, pi - asin.
        other = -base if trig is np.arccos else np.pi - base
        angles += [np.mod(base, 2.0 * np.pi), np.mod(other, 2.0 * np.pi)]
    a = np.unique(np.concatenate(angles))
    keep = (a[1:] - a[:-1]) * r > 1e-9  # slivers at grid corners, as for segments
    mid = 0.5 * (a[:-1] + a[1:])[keep]
    cols = np.floor(_snap(cu + r * np.cos(mid))).astype(np.int64)
    rows = np.floor(_snap(cv + r * np.sin(mid))).astype(np.int64)
    return cols, rows


def rasterize(world: World, resolution: float = 0.05, margin: float = 0.5) -> Any:
    """The ground-truth occupancy map of a world, as an :class:`~slam2d.grids.occupancy.OccupancyGrid`.

    Occupied (100): every cell a wall segment or a circle outline passes
    through (a cell only touched at a corner is not). Free (0): every other
    cell overlapping :meth:`World.bounds` (inside solid obstacles too: the
    map records where surfaces are, not what a robot can see). Unknown (-1):
    the ``margin`` (m) around the bounds.

    Cell centres lie on whole multiples of ``resolution``, so walls at round
    coordinates run through the middle of cells and never along a cell
    boundary where rounding would pick a side: a 1 m wall from x = 0 to
    x = 1 at 0.05 m covers the 21 cells centred on 0, 0.05, ..., 1.0.
    """
    from slam2d.grids.occupancy import OccupancyGrid

    res = float(resolution)
    if not (math.isfinite(res) and res > 0.0):
        raise InputError(f"{resolution!r} is not a positive cell size", field="resolution")
    if not (math.isfinite(margin) and margin >= 0.0):
        raise InputError(f"{margin!r} is not a margin >= 0", field="margin")
    xmin, ymin, xmax, ymax = world.bounds()
    cells = ((xmax - xmin + 2 * margin) / res + 1) * ((ymax - ymin + 2 * margin) / res + 1)
    if not math.isfinite(cells):  # coordinates too large to count cells in
        raise InputError(
            f"the world spans {xmax - xmin:.4g} m x {ymax - ymin:.4g} m: too large to map at {res:g} m",
            path=world.source, field="resolution",
        )
    # Cell k spans [(k - 0.5) res, (k + 0.5) res).
    col_lo = math.floor(_snap(np.array((xmin - margin) / res + 0.5)))
    row_lo = math.floor(_snap(np.array((ymin - margin) / res + 0.5)))
    col_hi = math.floor(_snap(np.array((xmax + margin) / res + 0.5)))
    row_hi = math.floor(_snap(np.array((ymax + margin) / res + 0.5)))
    origin = ((col_lo - 0.5) * res, (row_lo - 0.5) * res)
    shape = (row_hi - row_lo + 1, col_hi - col_lo + 1)
    if shape[0] * shape[1] > 200_000_000:
        raise InputError(
            f"a {shape[1]} x {shape[0]} cell map is too large; use a coarser resolution", field="resolution"
        )
    occupancy = np.full(shape, -1, dtype=np.int8)
    # Free: the cells overlapping the bounds box.
    c0 = math.floor(_snap(np.array(xmin / res + 0.5))) - col_lo
    r0 = math.floor(_snap(np.array(ymin / res + 0.5))) - row_lo
    c1 = math.floor(_snap(np.array(xmax / res + 0.5))) - col_lo
    r1 = math.floor(_snap(np.array(ymax / res + 0.5))) - row_lo
    occupancy[r0 : r1 + 1, c0 : c1 + 1] = 0

    def cell_coords(x: NDArray[np.float64] | float, y: NDArray[np.float64] | float) -> tuple[Any, Any]:
        return (np.asarray(x) - origin[0]) / res, (np.asarray(y) - origin[1]) / res

    cols_all: list[NDArray[np.int64]] = []
    rows_all: list[NDArray[np.int64]] = []
    su0, sv0 = cell_coords(world.segments[:, 0], world.segments[:, 1])
    su1, sv1 = cell_coords(world.segments[:, 2], world.segments[:, 3])
    su0, sv0, su1, sv1 = (_snap(v) for v in (su0, sv0, su1, sv1))
    for k in range(len(world.segments)):  # a loop over segments; each is whole-array over its cells
        cols, rows = _segment_cells(float(su0[k]), float(sv0[k]), float(su1[k]), float(sv1[k]))
        cols_all.append(cols)
        rows_all.append(rows)
    for cx, cy, r in world.circles:
        cu, cv = cell_coords(cx, cy)
        cols, rows = _circle_cells(float(cu), float(cv), float(r) / res)
        cols_all.append(cols)
        rows_all.append(rows)
    if cols_all:
        cols = np.concatenate(cols_all)
        rows = np.concatenate(rows_all)
        inside = (rows >= 0) & (rows < shape[0]) & (cols >= 0) & (cols < shape[1])
        occupancy[rows[inside], cols[inside]] = 100
    return OccupancyGrid.from_occupancy(occupancy, res, origin)
