"""Freiburg relations files: exact round trips, the plain 8-column format, and bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from slam2d.core import se2
from slam2d.errors import InputError
from slam2d.io.relations import Relations, read_relations, relations_from_trajectory, write_relations

# Two lines in the style of the Freiburg intel.relations file.
FREIBURG = (
    "1134864642.914187 1134864643.913637 0.002349 -0.000012 0.000000 0.000000 0.000000 -0.001049\n"
    "1134864643.913637 1134864642.914187 -0.002349 0.000014 0.000000 0.000000 0.000000 0.001049\n"
)


def _write(path: Path, text: str | bytes) -> Path:
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text, encoding="utf-8")
    return path


def _error(path: Path) -> InputError:
    with pytest.raises(InputError) as err:
        read_relations(path)
    return err.value


# ---------------------------------------------------------------------------- reading and writing


def test_reads_freiburg_lines_in_file_order():
    import tempfile

    with tempfile.TemporaryDirectory() as folder:
        path = _write(Path(folder) / "intel.relations", FREIBURG)
        rel = read_relations(path)
    assert isinstance(rel, Relations) and len(rel) == 2 and rel.path == path
    assert rel.t1.tolist() == [1134864642.914187, 1134864643.913637]
    assert rel.t2.tolist() == [1134864643.913637, 1134864642.914187]  # t2 < t1 kept as is
    assert rel.motion.tolist() == [[0.002349, -0.000012, -0.001049], [-0.002349, 0.000014, 0.001049]]


def test_comments_and_blank_lines_are_skipped(tmp_path):
    text = "# t1 t2 x y z roll pitch yaw\n\n" + FREIBURG.replace("\n", "\n   \n", 1) + "  # end\n"
    rel = read_relations(_write(tmp_path / "r.relations", text))
    assert len(rel) == 2


def test_round_trip_is_exact(tmp_path):
    rng = np.random.default_rng(0)
    n = 300
    t1 = 1134864642.914187 + np.cumsum(rng.uniform(1e-6, 2.0, n))
    t2 = t1 + rng.uniform(-5.0, 5.0, n)
    motion = np.column_stack([rng.normal(0, 3, n), rng.normal(0, 3, n), rng.uniform(-np.pi, np.pi, n)])
    motion[0] = [1e-300, -0.0, 5e-324]  # extremes survive too
    path = write_relations(tmp_path / "out.relations", t1, t2, motion)
    assert path == tmp_path / "out.relations" and list(tmp_path.iterdir()) == [path]
    rel = read_relations(path)
    assert np.array_equal(rel.t1, t1) and np.array_equal(rel.t2, t2)
    assert np.array_equal(rel.motion, motion)


def test_written_file_is_plain_eight_columns_without_header(tmp_path):
    # Cartographer's text reader stops at the first line that is not 8 numbers: no header
    path = write_relations(tmp_path / "r.relations", [1.0, 2.0], [2.0, 3.0], [[0.5, 0.25, 0.1], [1.0, 0.0, -0.2]])
    first = path.read_text(encoding="utf-8").splitlines()[0]
    assert [float(v) for v in first.split()] == [1.0, 2.0, 0.5, 0.25, 0.0, 0.0, 0.0, 0.1]
    table = np.loadtxt(path)
    assert table.shape == (2, 8) and np.array_equal(table[:, 4:7], np.zeros((2, 3)))


def test_write_replaces_existing_file_and_rejects_bad_arrays(tmp_path):
    target = _write(tmp_path / "r.relations", "old content that is not relations\n")
    write_relations(target, [0.0], [1.0], [[1.0, 2.0, 0.5]])
    assert len(read_relations(target)) == 1
    before = target.read_bytes()
    with pytest.raises(ValueError, match="same length"):
        write_relations(target, [0.0, 1.0], [1.0], [[1.0, 2.0, 0.5]])
    with pytest.raises(ValueError, match="finite"):
        write_relations(target, [0.0], [1.0], [[np.nan, 2.0, 0.5]])
    assert target.read_bytes() == before and sorted(tmp_path.iterdir()) == [target]


def test_tiny_roll_and_pitch_are_planar(tmp_path):
    rel = read_relations(_write(tmp_path / "r.relations", "0 1 1.0 0.0 1e-9 -1e-8 5e-7 0.3\n"))
    assert rel.motion.tolist() == [[1.0, 0.0, 0.3]]


def test_relations_from_trajectory():
    times = np.array([0.0, 1.0, 2.0, 3.0])
    poses = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, np.pi / 2], [1.0, 1.0, np.pi], [0.0, 1.0, -np.pi / 2]])
    rel = relations_from_trajectory(times, poses, np.array([[0, 1], [1, 3], [3, 0]]))
    assert rel.path is None and len(rel) == 3
    assert rel.t1.tolist() == [0.0, 1.0, 3.0] and rel.t2.tolist() == [1.0, 3.0, 0.0]
    # from pose 1 (at (1,0) facing +y) pose 3 (at (0,1)) is 1 ahead and 1 to the left, turned by 180 deg
    assert np.allclose(rel.motion[1], [1.0, 1.0, -np.pi])
    assert np.allclose(rel.motion[0], [1.0, 0.0, np.pi / 2])
    assert np.allclose(se2.compose(poses[3], rel.motion[2]), poses[0])
    with pytest.raises(ValueError, match="lie in"):
        relations_from_trajectory(times, poses, np.array([[0, 4]]))
    with pytest.raises(ValueError, match="integer"):
        relations_from_trajectory(times, poses, np.array([[0.0, 1.0]]))
    with pytest.raises(ValueError, match="timestamps"):
        relations_from_trajectory(times[:3], poses, np.array([[0, 1]]))


# ---------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    ("line", "field", "message"),
    [
        ("0 1 1.0 0.0 0.0 0.0 0.0", "columns", "7 columns, 8 expected: t1 t2 x y z roll pitch yaw"),
        ("0 1 1.0 0.0 0.0 0.0 0.0 0.1 7", "columns", "9 columns, 8 expected"),
        ("0 1 1.0 0,5 0.0 0.0 0.0 0.1", "y", "'0,5' is not a number"),
        ("0 1 1.0 0.0 0.0 0.0 0.0 nan", "yaw", "'nan' is not a finite number"),
        ("inf 1 1.0 0.0 0.0 0.0 0.0 0.1", "t1", "'inf' is not a finite number"),
        ("0 1 1.0 0.0 0.0 0.01 0.0 0.1", "roll", "not a planar relation"),
        ("0 1 1.0 0.0 0.0 0.0 -0.2 0.1", "pitch", "not a planar relation"),
        ("0 1 1.0 0.0 0.5 0.0 0.0 0.1", "z", "not a planar relation"),
    ],
)
def test_bad_line_names_file_line_and_field(tmp_path, line, field, message):
    path = _write(tmp_path / "bad.relations", "# header\n" + FREIBURG.splitlines()[0] + "\n" + line + "\n")
    err = _error(path)
    assert err.path == str(path) and err.where == 3 and err.field == field
    text = str(err)
    assert text.startswith(f"{path}:3: {field}: ")
    assert message in text and "\n" not in text


def test_non_utf8_bytes(tmp_path):
    path = _write(tmp_path / "bin.relations", FREIBURG.encode() + b"\x00\xff\xfe binary\n")
    err = _error(path)
    assert err.where == 3
    assert str(err).startswith(f"{path}:3: ") and "0xff" in str(err) and "not UTF-8" in str(err)


def test_missing_file_folder_empty_and_no_relations(tmp_path):
    missing = tmp_path / "nope.relations"
    assert str(_error(missing)) == f"{missing}: no such file"
    assert "is a folder" in str(_error(tmp_path))
    empty = _write(tmp_path / "empty.relations", "")
    assert str(_error(empty)) == f"{empty}: file is empty"
    comments = _write(tmp_path / "comments.relations", "# only a comment\n\n")
    assert str(_error(comments)) == f"{comments}: no relations in the file"
