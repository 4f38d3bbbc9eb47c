"""Pose graphs in g2o and TORO text formats.

g2o (2D)::

    VERTEX_SE2 id x y theta
    EDGE_SE2 i j dx dy dtheta  I11 I12 I13 I22 I23 I33     # upper triangle of the information, row by row
    FIX id                                                  # optional gauge

TORO::

    VERTEX2 id x y theta
    EDGE2 i j dx dy dtheta  I11 I12 I22 I33 I13 I23         # TORO's order: xx xy yy tt xt yt

In both an edge's measurement is the pose of ``j`` in ``i``'s frame, as in
:class:`~slam2d.backends.PoseGraph`. Vertex ids need not be 0..N-1; readers
return the ids next to the graph (node ``k`` has id ``ids[k]``). Writers are
atomic. A malformed line raises :class:`~slam2d.errors.InputError` naming the
file, the line and the field.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from slam2d.backends.graph import PoseGraph
from slam2d.errors import InputError
from slam2d.io.atomic import write_text_atomic

__all__ = ["read_g2o", "write_g2o", "read_toro", "write_toro", "read_pose_graph", "write_pose_graph"]

# positions of the 6 upper-triangle entries (row, col) in each format's field order
_G2O_ORDER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
_TORO_ORDER = ((0, 0), (0, 1), (1, 1), (2, 2), (0, 2), (1, 2))
_POSE_FIELDS = ("x", "y", "theta")
_EDGE_FIELDS = ("from", "to", "dx", "dy", "dtheta")


def _info_fields(order: tuple[tuple[int, int], ...]) -> tuple[str, ...]:
    names = "xy" + "t"
    return tuple(f"I_{names[r]}{names[c]}" for r, c in order)


def _fmt(v: float) -> str:
    return repr(float(v))


def _write(path: str | Path, graph: PoseGraph, ids: ArrayLike | None, vtag: str, etag: str, order, fix: bool) -> None:
    n = graph.num_nodes
    ids = np.arange(n) if ids is None else np.asarray(ids, dtype=np.int64)
    if ids.shape != (n,) or np.unique(ids).size != n:
        raise InputError(f"need {n} distinct node ids, got shape {ids.shape}", path=path, field="ids")
    lines = [f"{vtag} {int(k)} {_fmt(p[0])} {_fmt(p[1])} {_fmt(p[2])}" for k, p in zip(ids, graph.poses)]
    info = graph.information
    tri = np.stack([info[:, r, c] for r, c in order], axis=1) if graph.num_edges else np.zeros((0, 6))
    for i, j, z, t in zip(graph.edge_i, graph.edge_j, graph.measurements, tri):
        lines.append(f"{etag} {int(ids[i])} {int(ids[j])} " + " ".join(_fmt(v) for v in z) + " " + " ".join(_fmt(v) for v in t))
    if fix and n:
        lines.append(f"FIX {int(ids[graph.fixed])}")
    write_text_atomic(path, "\n".join(lines) + "\n")


def write_g2o(path: str | Path, graph: PoseGraph, ids: ArrayLike | None = None) -> None:
    """Write ``graph`` as g2o ``VERTEX_SE2``/``EDGE_SE2`` lines plus ``FIX`` for the fixed node."""
    _write(path, graph, ids, "VERTEX_SE2", "EDGE_SE2", _G2O_ORDER, fix=True)


def write_toro(path: str | Path, graph: PoseGraph, ids: ArrayLike | None = None) -> None:
    """Write ``graph`` as TORO ``VERTEX2``/``EDGE2`` lines (TORO has no fixed-node record: it anchors the first)."""
    _write(path, graph, ids, "VERTEX2", "EDGE2", _TORO_ORDER, fix=False)


def _numbers(path: Path, lineno: int, parts: list[str], names: tuple[str, ...], kind: str) -> list[float]:
    if len(parts) != len(names):
        raise InputError(
            f"{kind} needs {len(names)} values ({' '.join(names)}), found {len(parts)}", path=path, where=lineno, field=kind
        )
    out = []
    for name, text in zip(names, parts):
        try:
            v = float(text)
        except ValueError:
            raise InputError(f"{text!r} is not a number", path=path, where=lineno, field=name) from None
        if not np.isfinite(v):
            raise InputError(f"{text!r} is not finite", path=path, where=lineno, field=name)
        out.append(v)
    return out


def _as_id(path: Path, lineno: int, value: float, text: str, name: str) -> int:
    if not float(value).is_integer():
        raise InputError(f"{text!r} is not an integer id", path=path, where=lineno, field=name)
    return int(value)


def _read(path: str | Path, vtags: tuple[str, ...], etags: tuple[str, ...], order, fmt: str) -> tuple[PoseGraph, NDArray[np.int64]]:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError("no such file", path=path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot be read as a {fmt} text file: {exc}", path=path) from None
    vid: list[int] = []
    vpose: list[list[float]] = []
    vline: dict[int, int] = {}
    edges: list[list[float]] = []
    elines: list[int] = []
    fix: tuple[int, int] | None = None
    info_names = _info_fields(order)
    for lineno, line in enumerate(text.splitlines(), start=1):
        parts = line.split()
        if not parts or parts[0].startswith("#"):
            continue
        tag, rest = parts[0], parts[1:]
        if tag in vtags:
            vals = _numbers(path, lineno, rest, ("id",) + _POSE_FIELDS, tag)
            k = _as_id(path, lineno, vals[0], rest[0], "id")
            if k in vline:
                raise InputError(f"vertex {k} defined again (first on line {vline[k]})", path=path, where=lineno, field="id")
            vline[k] = lineno
            vid.append(k)
            vpose.append(vals[1:])
        elif tag in etags:
            vals = _numbers(path, lineno, rest, _EDGE_FIELDS + info_names, tag)
            _as_id(path, lineno, vals[0], rest[0], "from")
            _as_id(path, lineno, vals[1], rest[1], "to")
            edges.append(vals)
            elines.append(lineno)
        elif tag == "FIX" and fmt == "g2o":
            if len(rest) < 1:
                raise InputError("FIX needs a vertex id", path=path, where=lineno, field="FIX")
            vals = _numbers(path, lineno, rest[:1], ("id",), "FIX")
            fix = (_as_id(path, lineno, vals[0], rest[0], "id"), lineno)
        else:
            known = ", ".join(vtags + etags + (("FIX",) if fmt == "g2o" else ()))
            raise InputError(f"unsupported {fmt} record {tag!r} (2D pose graphs only: {known})", path=path, where=lineno, field="tag")
    ids = np.asarray(vid, dtype=np.int64)
    index = {k: i for i, k in enumerate(vid)}
    g = PoseGraph()
    if vpose:
        g.add_nodes(np.asarray(vpose))
    if edges:
        e = np.asarray(edges)
        ii = np.empty(len(edges), dtype=np.int64)
        jj = np.empty(len(edges), dtype=np.int64)
        for row, (a, b) in enumerate(e[:, :2].astype(np.int64)):
            for name, k, out in (("from", a, ii), ("to", b, jj)):
                if k not in index:
                    raise InputError(f"edge refers to vertex {k}, which is not defined", path=path, where=elines[row], field=name)
                out[row] = index[k]
            if a == b:
                raise InputError(f"edge connects vertex {a} to itself", path=path, where=elines[row], field="to")
        info = np.zeros((len(edges), 3, 3))
        for col, (r, c) in enumerate(order):
            info[:, r, c] = e[:, 5 + col]
            info[:, c, r] = e[:, 5 + col]
        bad = np.linalg.eigvalsh(info)[:, 0] < -1e-9 * np.abs(info).max(axis=(1, 2))
        if np.any(bad):
            row = int(np.argmax(bad))
            raise InputError("information matrix is not positive semi-definite", path=path, where=elines[row], field="information")
        g.add_edges(ii, jj, e[:, 2:5], info)
    if fix is not None:
        if fix[0] not in index:
            raise InputError(f"FIX names vertex {fix[0]}, which is not defined", path=path, where=fix[1], field="id")
        g.fixed = index[fix[0]]
    return g, ids


def read_g2o(path: str | Path) -> tuple[PoseGraph, NDArray[np.int64]]:
    """Read a 2D g2o file: the graph (node ``k`` in file order) and the vertex ids."""
    return _read(path, ("VERTEX_SE2",), ("EDGE_SE2",), _G2O_ORDER, "g2o")


def read_toro(path: str | Path) -> tuple[PoseGraph, NDArray[np.int64]]:
    """Read a TORO 2D file (``VERTEX2``/``EDGE2``; the older ``VERTEX``/``EDGE`` tags too)."""
    return _read(path, ("VERTEX2", "VERTEX"), ("EDGE2", "EDGE"), _TORO_ORDER, "toro")


def _format_of(path: Path, fmt: str | None) -> str:
    if fmt is not None:
        if fmt not in ("g2o", "toro"):
            raise InputError(f"unknown pose-graph format {fmt!r}; use g2o or toro", path=path, field="format")
        return fmt
    if path.suffix.lower() == ".g2o":
        return "g2o"
    if path.suffix.lower() in (".graph", ".toro"):
        return "toro"
    raise InputError("cannot tell the pose-graph format from the name; use .g2o, .graph or .toro", path=path, field="format")


def read_pose_graph(path: str | Path, fmt: str | None = None) -> tuple[PoseGraph, NDArray[np.int64]]:
    """Read g2o (``.g2o``) or TORO (``.graph``, ``.toro``), or the format named by ``fmt``."""
    path = Path(path)
    return (read_g2o if _format_of(path, fmt) == "g2o" else read_toro)(path)


def write_pose_graph(path: str | Path, graph: PoseGraph, fmt: str | None = None, ids: ArrayLike | None = None) -> None:
    """Write g2o (``.g2o``) or TORO (``.graph``, ``.toro``), or the format named by ``fmt``."""
    path = Path(path)
    (write_g2o if _format_of(path, fmt) == "g2o" else write_toro)(path, graph, ids)
