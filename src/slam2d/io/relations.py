"""Freiburg ``.relations`` files: expected relative motions between two times.

The relation-based metric of Kümmerle et al., "On measuring the accuracy of
SLAM algorithms" (Autonomous Robots 27(4), 2009) compares a trajectory with a
list of relations, one per line::

    t1 t2 x y z roll pitch yaw

meaning "from the robot pose at time ``t1`` to the one at ``t2`` the robot
moved by (x, y, z) and turned by (roll, pitch, yaw)", expressed in the frame of
the pose at ``t1`` (metres, radians, seconds). This is the text format of the
Freiburg slamevaluation tools and of Cartographer's
``compute_relations_metrics -read_text_file_with_unix_timestamps``.

slam2d is planar, so a relation must have z, roll and pitch (near) zero;
anything else is rejected rather than silently projected. Relations keep the
order and time order (``t2`` may be before ``t1``) of the file.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from slam2d.core import se2
from slam2d.errors import InputError
from slam2d.io.atomic import atomic_path
from slam2d.io.numeric_text import numeric_rows

__all__ = ["Relations", "read_relations", "write_relations", "relations_from_trajectory"]

_COLUMNS = ("t1", "t2", "x", "y", "z", "roll", "pitch", "yaw")
#: Largest |z| (m) and |roll|, |pitch| (rad) still taken as a planar relation.
_PLANAR_TOLERANCE = 1e-6


@dataclass(frozen=True)
class Relations:
    """Expected relative motions: ``motion[k]`` takes pose(``t1[k]``) to pose(``t2[k]``).

    ``motion`` is ``(N, 3)`` ``[x, y, yaw]`` in the frame of the pose at ``t1``.
    ``path`` is the file they came from (``None`` when built in memory).
    """

    path: Path | None
    t1: NDArray[np.float64]
    t2: NDArray[np.float64]
    motion: NDArray[np.float64]

    def __len__(self) -> int:
        return int(self.t1.shape[0])


def read_relations(path: str | Path) -> Relations:
    """Read a Freiburg relations file (``t1 t2 x y z roll pitch yaw`` per line).

    ``#`` comment lines and blank lines are skipped. A line with another
    number of columns, a value that is not a finite number, a relation that is
    not planar (|z|, |roll| or |pitch| of 1e-6 or more), bytes that are not
    UTF-8, a missing file, a folder or a file without relations raise
    :class:`InputError` naming ``file:line`` and the column. The file is read
    line by line.
    """
    path = Path(path)
    rows: list[list[float]] = []
    for lineno, values in numeric_rows(path, _COLUMNS, "relations file"):
        for name, value, unit in (("z", values[4], "m"), ("roll", values[5], "rad"), ("pitch", values[6], "rad")):
            if abs(value) >= _PLANAR_TOLERANCE:
                raise InputError(
                    f"{value!r} {unit} is not zero: not a planar relation (slam2d compares x, y, yaw only)",
                    path=path,
                    where=lineno,
                    field=name,
                )
        rows.append(values)
    if not rows:
        raise InputError(
            "file is empty" if path.stat().st_size == 0 else "no relations in the file", path=path
        )
    table = np.array(rows, dtype=np.float64)
    return Relations(
        path=path,
        t1=table[:, 0].copy(),
        t2=table[:, 1].copy(),
        motion=table[:, [2, 3, 7]].copy(),
    )


def write_relations(path: str | Path, t1: ArrayLike, t2: ArrayLike, motion: ArrayLike) -> Path:
    """Write relations ``t1 (N,)``, ``t2 (N,)``, ``motion (N, 3)`` to ``path``; return the path.

    One ``t1 t2 x y 0.0 0.0 0.0 yaw`` line per relation and no header, because
    Cartographer's reader stops at the first line that is not 8 numbers.
    Numbers are written with ``repr`` so that reading gives back the same
    floats. The file appears only when complete. Raises ``ValueError`` for
    arrays of the wrong shape or non-finite values (a program error).
    """
    path = Path(path)
    a = np.asarray(t1, dtype=np.float64).reshape(-1)
    b = np.asarray(t2, dtype=np.float64).reshape(-1)
    m = se2.as_poses(motion).reshape(-1, 3)
    if b.shape != a.shape or m.shape[0] != a.shape[0]:
        raise ValueError(f"t1 {a.shape}, t2 {b.shape} and motion {m.shape} do not have the same length")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b)) and np.all(np.isfinite(m))):
        raise ValueError("relation times and motions must be finite")
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="\n") as out:
        for ta, tb, (x, y, yaw) in zip(a.tolist(), b.tolist(), m.tolist()):
            out.write(f"{ta!r} {tb!r} {x!r} {y!r} 0.0 0.0 0.0 {yaw!r}\n")
    return path


def relations_from_trajectory(times: ArrayLike, poses: ArrayLike, pairs: ArrayLike) -> Relations:
    """Relations measured on a trajectory: for each index pair ``(i, j)`` the motion from pose i to pose j.

    ``times (N,)``, ``poses (N, 3)``, ``pairs (M, 2)`` of integer indices.
    Used to make relations from a simulator's ground truth. Raises
    ``ValueError`` for shapes that do not match or indices out of range.
    """
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    p = se2.as_poses(poses).reshape(-1, 3)
    if p.shape[0] != t.shape[0]:
        raise ValueError(f"poses: {p.shape[0]} poses for {t.shape[0]} timestamps")
    idx = np.asarray(pairs)
    if idx.size == 0:
        idx = idx.reshape(0, 2)
    if idx.ndim != 2 or idx.shape[1] != 2 or not np.issubdtype(idx.dtype, np.integer):
        raise ValueError(f"pairs must be an (M, 2) integer array; got shape {idx.shape}, dtype {idx.dtype}")
    if idx.size and (idx.min() < 0 or idx.max() >= t.shape[0]):
        raise ValueError(f"pair indices must lie in [0, {t.shape[0]}); got {idx.min()}..{idx.max()}")
    i, j = idx[:, 0], idx[:, 1]
    return Relations(path=None, t1=t[i].copy(), t2=t[j].copy(), motion=se2.relative(p[i], p[j]))
