"""Atomic output: a file or folder appears complete, or not at all.

Everything slam2d writes goes to a temporary name in the destination folder
first and is renamed into place only when it is complete, so an error or a
Ctrl-C never leaves a half-written map, trajectory or bag behind.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from slam2d.errors import InputError

__all__ = ["atomic_path", "write_text_atomic", "write_bytes_atomic"]


@contextmanager
def atomic_path(path: str | Path, *, suffix: str | None = None) -> Iterator[Path]:
    """Yield a fresh temporary path next to ``path``; rename it onto ``path`` on success.

    The temporary path does not exist yet, so the caller may create a file or
    a folder there (rosbag2 writes a folder). On an exception it is removed and
    ``path`` is left untouched. A folder at ``path`` is replaced only by a
    folder: a file written where a folder stands is an :class:`InputError`.
    ``suffix`` (default: that of ``path``) is kept on the temporary name for
    writers that choose a format by extension.
    """
    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    parent.mkdir(parents=True, exist_ok=True)
    if suffix is None:
        suffix = "".join(path.suffixes)
    fd, tmpname = tempfile.mkstemp(prefix=f".{path.name}.", suffix=f".partial{suffix}", dir=parent)
    os.close(fd)
    os.unlink(tmpname)
    tmp = Path(tmpname)
    try:
        yield tmp
        if path.is_dir() and not path.is_symlink():
            if not tmp.is_dir():
                # A folder given where a file goes (``--out some/folder``): never delete it for a file.
                raise InputError("is a folder; a file was expected here (the folder is left as it is)", path=path)
            shutil.rmtree(path)
        os.replace(tmp, path)
    except BaseException:
        if tmp.is_dir() and not tmp.is_symlink():
            shutil.rmtree(tmp, ignore_errors=True)
        else:
            tmp.unlink(missing_ok=True)
        raise


def write_bytes_atomic(path: str | Path, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text_atomic(path: str | Path, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
