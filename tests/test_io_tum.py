"""TUM trajectories: exact round trips, bad input, and matching poses to scan times."""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slam2d.core import se2
from slam2d.errors import InputError
from slam2d.io.tum import interpolate_poses, read_tum, write_tum
from tests.conftest import dataset_file


def _write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


def _error(path: Path) -> str:
    with pytest.raises(InputError) as err:
        read_tum(path)
    return str(err.value)


# ---------------------------------------------------------------------------- round trip


def test_round_trip_is_exact(tmp_path):
    rng = np.random.default_rng(0)
    t = 1134864642.914187 + np.cumsum(rng.uniform(1e-6, 2.0, 500))
    poses = np.column_stack([rng.normal(0, 100, 500), rng.normal(0, 100, 500), rng.uniform(-np.pi, np.pi, 500)])
    path = write_tum(tmp_path / "traj.tum", t, poses)
    assert path == tmp_path / "traj.tum" and list(tmp_path.iterdir()) == [path]
    times, read = read_tum(path)
    assert np.array_equal(times, t)
    assert np.array_equal(read[:, :2], poses[:, :2])
    assert np.max(np.abs(se2.wrap_angle(read[:, 2] - poses[:, 2]))) <= 1e-12


def test_written_file_is_plain_tum(tmp_path):
    # evo and the TUM tools read 8 space-separated columns, '#' comments allowed
    path = write_tum(tmp_path / "t.tum", [1.5, 2.5], [[1.0, 2.0, np.pi / 2], [3.0, 4.0, -1.0]])
    table = np.loadtxt(path, comments="#")
    assert table.shape == (2, 8)
    assert np.array_equal(table[:, 3:6], np.zeros((2, 3)))
    assert np.allclose(np.linalg.norm(table[:, 4:8], axis=1), 1.0)
    assert table[0, 6] == pytest.approx(math.sin(np.pi / 4)) and table[0, 7] == pytest.approx(math.cos(np.pi / 4))


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.floats(1e-9, 1e4),
            st.floats(-1e6, 1e6),
            st.floats(-1e6, 1e6),
            st.floats(-math.pi, math.pi),
        ),
        min_size=1,
        max_size=20,
    ),
    st.floats(0.0, 2e9),
)
def test_round_trip_property(rows, start):
    steps, xs, ys, yaws = (np.array(c) for c in zip(*rows))
    t = start + np.cumsum(steps)
    if np.any(np.diff(t) <= 0):  # steps below the float resolution at this start time
        return
    poses = np.column_stack([xs, ys, yaws])
    with tempfile.TemporaryDirectory() as folder:
        times, read = read_tum(write_tum(Path(folder) / "p.tum", t.tolist(), poses))
    assert np.array_equal(times, t)
    assert np.array_equal(read[:, :2], poses[:, :2])
    assert np.all(np.abs(se2.wrap_angle(read[:, 2] - yaws)) <= 1e-12)


def test_reads_comments_blank_lines_and_general_quaternions(tmp_path):
    yaw = 0.7
    # a quaternion with small roll and pitch still gives the heading
    q = [0.001, -0.002, math.sin(yaw / 2), math.cos(yaw / 2)]
    path = _write(
        tmp_path / "c.tum",
        f"# comment\n\n1.0 1 2 0.5 {q[0]} {q[1]} {q[2]} {q[3]}\n  # indented comment\n2.0 3 4 0 0 0 0 1\n",
    )
    times, poses = read_tum(path)
    assert times.tolist() == [1.0, 2.0]
    assert poses[0, :2].tolist() == [1.0, 2.0] and poses[0, 2] == pytest.approx(yaw, abs=1e-5)
    assert poses[1].tolist() == [3.0, 4.0, 0.0]


def test_write_rejects_mismatched_arrays(tmp_path):
    with pytest.raises(ValueError, match="poses"):
        write_tum(tmp_path / "x.tum", [1.0, 2.0], [[0, 0, 0]])
    with pytest.raises(ValueError, match="finite"):
        write_tum(tmp_path / "x.tum", [1.0], [[0, np.nan, 0]])
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------- bad input


def test_wrong_column_count(tmp_path):
    text = _error(_write(tmp_path / "cols.tum", "1 0 0 0 0 0 0 1\n2 0 0 0 0 0 1\n"))
    assert "cols.tum:2:" in text and "columns" in text and "7 columns, 8 expected" in text


def test_non_number(tmp_path):
    text = _error(_write(tmp_path / "num.tum", "# c\n1 0 abc 0 0 0 0 1\n"))
    assert "num.tum:2:" in text and "y:" in text and "'abc' is not a number" in text
    text = _error(_write(tmp_path / "inf.tum", "1 0 0 0 0 0 0 1\n2 inf 0 0 0 0 0 1\n"))
    assert "inf.tum:2:" in text and "x:" in text and "not a finite number" in text


def test_non_unit_quaternion(tmp_path):
    text = _error(_write(tmp_path / "q.tum", "1 0 0 0 0 0 0 1\n2 0 0 0 0 0 0.1 0.9\n"))
    assert "q.tum:2:" in text and "quaternion" in text and "norm" in text
    # within 1e-3 of unit length is accepted (9-decimal files)
    read_tum(_write(tmp_path / "ok.tum", "1 0 0 0 0 0 0 1.0009\n"))


def test_timestamps_not_increasing(tmp_path):
    text = _error(_write(tmp_path / "back.tum", "10 0 0 0 0 0 0 1\n11 0 0 0 0 0 0 1\n5 0 0 0 0 0 0 1\n"))
    assert "back.tum:3:" in text and "timestamp" in text and "must increase" in text
    text = _error(_write(tmp_path / "dup.tum", "10 0 0 0 0 0 0 1\n10 0 0 0 0 0 0 1\n"))
    assert "dup.tum:2:" in text and "timestamp" in text and "repeats" in text
    # a small step back, as scan timestamps of real logs have, is accepted
    times, _ = read_tum(_write(tmp_path / "small.tum", "10 0 0 0 0 0 0 1\n11 0 0 0 0 0 0 1\n10.9 0 0 0 0 0 0 1\n"))
    assert times.tolist() == [10.0, 11.0, 10.9]


def test_empty_file(tmp_path):
    assert "empty.tum: file is empty" in _error(_write(tmp_path / "empty.tum", ""))
    assert "comments.tum: no poses" in _error(_write(tmp_path / "comments.tum", "# nothing\n\n"))
    assert "missing.tum: no such file" in _error(tmp_path / "missing.tum")
    (tmp_path / "dir.tum").mkdir()
    assert "folder" in _error(tmp_path / "dir.tum")


def test_undecodable(tmp_path):
    path = tmp_path / "bin.tum"
    path.write_bytes(b"1 0 0 0 0 0 0 1\n\x89PNG\n")
    assert "bin.tum:2:" in _error(path)


@pytest.mark.datasets
@pytest.mark.parametrize(("name", "count"), [("intel", 910), ("aces", 440), ("fr079", 4791), ("fr101", 292), ("csail", 406)])
def test_reference_trajectories_read(name, count):
    times, poses = read_tum(dataset_file(f"{name}/reference.tum"))
    assert times.shape == (count,) and poses.shape == (count, 3)
    assert np.all(np.isfinite(poses)) and np.all(np.abs(poses[:, 2]) <= np.pi)


# ---------------------------------------------------------------------------- interpolation


def test_interpolate_exact_between_outside_and_gap():
    t = np.array([0.0, 1.0, 2.0, 10.0])
    poses = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.5], [1.0, 2.0, 1.0], [5.0, 5.0, 2.0]])
    query = np.array([1.0, 0.25, 1.5, -0.1, 2.0 + 1e-9, 5.0, 10.0, 10.1, np.nan])
    out, valid = interpolate_poses(t, poses, query, max_gap=1.5)
    assert valid.tolist() == [True, True, True, False, False, False, True, False, False]
    assert np.array_equal(out[0], poses[1]) and np.array_equal(out[6], poses[3])
    assert np.allclose(out[1], [0.25, 0.0, 0.125])
    assert np.allclose(out[2], se2.interpolate(poses[1], poses[2], 0.5))
    assert np.isnan(out[~valid]).all()
    # a larger allowed gap bridges 2 s -> 10 s
    out, valid = interpolate_poses(t, poses, [6.0], max_gap=8.0)
    assert valid.all() and np.allclose(out[0, :2], [3.0, 3.5])


def test_interpolate_heading_takes_the_short_way_across_pi():
    poses = np.array([[0.0, 0.0, np.pi - 0.1], [0.0, 0.0, -np.pi + 0.1]])
    out, valid = interpolate_poses([0.0, 1.0], poses, [0.5], max_gap=2.0)
    assert valid.all() and abs(se2.wrap_angle(out[0, 2] - np.pi)) < 1e-12


def test_interpolate_unsorted_trajectory_matches_exactly():
    # the Intel reference steps back in time four times; every pose still matches its own time
    t = np.array([1.0, 2.0, 1.9, 3.0])
    poses = np.arange(12.0).reshape(4, 3)
    out, valid = interpolate_poses(t, poses, t, max_gap=0.0)
    assert valid.all() and np.array_equal(out, poses)


def test_interpolate_many_queries():
    t = np.arange(100_000) * 0.1
    poses = np.column_stack([t, -t, np.sin(t)])
    query = np.random.default_rng(1).uniform(-1.0, 10_001.0, 200_000)
    out, valid = interpolate_poses(t, poses, query, max_gap=0.2)
    inside = (query >= 0) & (query <= t[-1])
    assert np.array_equal(valid, inside)
    assert np.allclose(out[valid, 0], query[valid])


def test_a_byte_order_mark_is_not_part_of_the_first_timestamp(tmp_path):
    path = tmp_path / "bom.tum"
    path.write_text("\ufeff1.0 0 0 0 0 0 0 1\n2.0 1 0 0 0 0 0 1\n", encoding="utf-8")
    times, poses = read_tum(path)
    assert times.tolist() == [1.0, 2.0] and poses[1].tolist() == [1.0, 0.0, 0.0]
