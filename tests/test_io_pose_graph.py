"""g2o and TORO pose-graph files: exact round trips, information ordering, clear errors."""

from __future__ import annotations

import numpy as np
import pytest

from slam2d.backends import PoseGraph
from slam2d.backends.synthetic import manhattan_graph
from slam2d.errors import InputError
from slam2d.io.pose_graph import read_g2o, read_pose_graph, read_toro, write_g2o, write_pose_graph, write_toro


def _graph():
    g, _ = manhattan_graph(60, 120, seed=2)
    # a full (correlated) information matrix on one edge, to check the ordering of its entries
    info = g.information.copy()
    g2 = PoseGraph()
    g2.add_nodes(g.poses)
    info[5] = [[10.0, 1.0, 2.0], [1.0, 20.0, 3.0], [2.0, 3.0, 30.0]]
    g2.add_edges(g.edge_i, g.edge_j, g.measurements, info)
    g2.fixed = 7
    return g2


@pytest.mark.parametrize("suffix", [".g2o", ".graph"])
def test_round_trip_is_exact(tmp_path, suffix):
    g = _graph()
    ids = np.arange(g.num_nodes) * 3 + 100  # ids need not be 0..N-1
    path = tmp_path / f"g{suffix}"
    write_pose_graph(path, g, ids=ids)
    h, hids = read_pose_graph(path)
    assert np.array_equal(hids, ids)
    assert np.array_equal(h.poses, g.poses)
    assert np.array_equal(h.edge_i, g.edge_i) and np.array_equal(h.edge_j, g.edge_j)
    assert np.array_equal(h.measurements, g.measurements)
    assert np.array_equal(h.information, g.information)
    if suffix == ".g2o":
        assert h.fixed == 7  # FIX record
    assert not [p for p in tmp_path.iterdir() if p.name != path.name]  # no temporary files left


def test_information_ordering_of_each_format(tmp_path):
    g2o = tmp_path / "a.g2o"
    g2o.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0  11 12 13 22 23 33\n")
    g, _ = read_g2o(g2o)
    assert np.array_equal(g.information[0], [[11, 12, 13], [12, 22, 23], [13, 23, 33]])
    toro = tmp_path / "a.graph"
    # TORO: inf_ff inf_fs inf_ss inf_rr inf_fr inf_sr = xx xy yy tt xt yt
    toro.write_text("VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0\nEDGE2 0 1 1 0 0  11 12 22 33 13 23\n")
    t, _ = read_toro(toro)
    assert np.array_equal(t.information[0], g.information[0])
    write_toro(tmp_path / "b.graph", g)
    assert (tmp_path / "b.graph").read_text().splitlines()[-1].split()[6:] == ["11.0", "12.0", "22.0", "33.0", "13.0", "23.0"]
    write_g2o(tmp_path / "b.g2o", t)
    lines = (tmp_path / "b.g2o").read_text().splitlines()
    assert lines[2].split()[6:] == ["11.0", "12.0", "13.0", "22.0", "23.0", "33.0"]
    assert lines[-1] == "FIX 0"


def test_comments_blank_lines_and_old_toro_tags(tmp_path):
    p = tmp_path / "c.graph"
    p.write_text("# made by hand\n\nVERTEX 5 0 0 0\nVERTEX 9 1 0 0\nEDGE 5 9 1 0 0 1 0 1 1 0 0\n")
    g, ids = read_toro(p)
    assert g.num_nodes == 2 and g.num_edges == 1 and list(ids) == [5, 9]


@pytest.mark.parametrize(
    "body, line, field, match",
    [
        ("VERTEX_SE2 0 0 0\n", 1, "VERTEX_SE2", "needs 4 values"),
        ("VERTEX_SE2 0 0 zero 0\n", 1, "y", "not a number"),
        ("VERTEX_SE2 0.5 0 0 0\n", 1, "id", "integer"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 0 1 0 0\n", 2, "id", "defined again"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 2 1 0 0 1 0 0 1 0 1\n", 3, "to", "not defined"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0\n", 3, "EDGE_SE2", "needs 11 values"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 nan 1 0 0 1 0 1\n", 3, "dtheta", "not finite"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 -1 0 0 1 0 1\n", 3, "information", "positive"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 1 1 1 0 0 1 0 0 1 0 1\n", 3, "to", "itself"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_XY 1 1 0\n", 2, "tag", "unsupported"),
        ("VERTEX_SE2 0 0 0 0\nFIX 4\n", 2, "id", "not defined"),
    ],
)
def test_bad_lines_name_file_line_and_field(tmp_path, body, line, field, match):
    p = tmp_path / "bad.g2o"
    p.write_text(body)
    with pytest.raises(InputError, match=match) as exc:
        read_g2o(p)
    assert exc.value.where == line and exc.value.field == field
    assert str(p) in str(exc.value) and f":{line}:" in str(exc.value)


def test_bad_toro_line(tmp_path):
    p = tmp_path / "bad.graph"
    p.write_text("VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0\nEDGE2 0 1 1 0 0 1 0 1 x 0 0\n")
    with pytest.raises(InputError) as exc:
        read_toro(p)
    assert exc.value.where == 3 and exc.value.field == "I_tt"


def test_missing_file_and_unknown_format(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        read_g2o(tmp_path / "none.g2o")
    with pytest.raises(InputError, match="format"):
        read_pose_graph(tmp_path / "x.txt")
    with pytest.raises(InputError, match="format"):
        write_pose_graph(tmp_path / "x.g2o", PoseGraph(), fmt="vertigo")


def test_failed_write_keeps_old_file(tmp_path):
    p = tmp_path / "keep.g2o"
    p.write_text("old\n")
    g = _graph()
    with pytest.raises(InputError):
        write_g2o(p, g, ids=np.zeros(g.num_nodes))  # ids not distinct
    assert p.read_text() == "old\n"
