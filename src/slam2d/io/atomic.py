"""Atomic output: a file or folder appears complete, or not at all.

Everything slam2d writes goes to a temporary name in the destination folder
first and is renamed into place only when it is complete, so an error or a
Ctrl-C never leaves a half-written map, trajectory or bag behind.

A command's ``--out`` folder is written the same way, whole: into a staging
folder beside it (:func:`staged_folder`), which replaces the old folder in one
rename when the command is done. A folder is replaced only when it is empty,
an earlier output of the same command (its :data:`OUTPUT_MARKER` says which),
or ``--overwrite`` was given (:func:`check_output_folder`): a user's own files
are never clobbered, and a rerun never leaves one method's files beside
another's.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from slam2d.errors import InputError

__all__ = [
    "atomic_path", "write_text_atomic", "write_bytes_atomic", "json_ready", "json_text", "write_json_atomic", "OUTPUT_MARKER", "check_output_folder",
    "staged_folder", "swap_into_place",
]

#: The file in every output folder naming the command that wrote it (``{"command": "run"}``).
OUTPUT_MARKER = ".slam2d-output.json"


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


def json_ready(value: Any) -> Any:
    """``value`` as strict JSON takes it: NaN and infinities as null (``Infinity`` is not JSON: jq and browsers
    reject it), numpy values as Python ones, paths and anything else unknown as text."""
    if isinstance(value, dict):
        return {str(k): json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(v) for v in value]
    if isinstance(value, np.ndarray):
        return json_ready(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if value is None or isinstance(value, (bool, int, str)):
        return value
    return str(value)


def json_text(value: Any, *, indent: int | None = 2) -> str:
    """Strict JSON text of ``value`` (see :func:`json_ready`)."""
    return json.dumps(json_ready(value), indent=indent, allow_nan=False)


def write_json_atomic(path: str | Path, value: Any, *, indent: int | None = 2) -> None:
    write_text_atomic(path, json_text(value, indent=indent) + "\n")


def _written_by(out: Path) -> str | None:
    """The command an earlier output folder was written by (its marker), or None."""
    try:
        return str(json.loads((out / OUTPUT_MARKER).read_text(encoding="utf-8"))["command"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def check_output_folder(out: str | Path, command: str, *, overwrite: bool = False) -> None:
    """Refuse an ``--out`` that must not or cannot be replaced by ``command``'s output, before any work."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError("exists and is a file; a folder is needed here", path=out, field="--out")
    if out.is_dir() and not overwrite and any(out.iterdir()):
        by = _written_by(out)
        if by != command:
            what = f"an earlier 'slam2d {by}' output" if by else "not an earlier slam2d output"
            raise InputError(f"is a folder that is not empty ({what}); it is not replaced: give a new or empty "
                             f"folder, an earlier 'slam2d {command}' output, or --overwrite", path=out, field="--out")
    probe = out.resolve().parent
    while not probe.exists():  # the nearest existing ancestor must let us create the folder
        probe = probe.parent
    if not probe.is_dir():
        raise InputError("a part of this path is a file, not a folder", path=out, field="--out")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise InputError(f"cannot write into {probe}", path=out, field="--out")


def swap_into_place(stage: Path, out: Path) -> None:
    """Move the finished folder ``stage`` to ``out``, replacing what was there whole."""
    target = Path(out).resolve()
    old = None
    if target.exists() or target.is_symlink():
        old = Path(tempfile.mkdtemp(prefix=f".{target.name}.old-", dir=target.parent))
        old.rmdir()
        target.rename(old)
    try:
        stage.rename(target)
    except BaseException:
        if old is not None:
            old.rename(target)
        raise
    if old is not None:
        if old.is_dir() and not old.is_symlink():
            shutil.rmtree(old, ignore_errors=True)
        else:
            old.unlink(missing_ok=True)


# Files that may name their own folder (a report linking its runs, an evaluation naming its run).
_TEXT_SUFFIXES = {".json", ".md", ".html", ".yaml", ".yml", ".csv", ".txt"}


def _relocate_text(stage: Path, target: Path) -> None:
    """Where a text file names the staging folder, make it name ``target``, where the folder is going."""
    import html

    old, new = str(stage), str(target)
    pairs = {(old, new), (json.dumps(old)[1:-1], json.dumps(new)[1:-1]), (html.escape(old), html.escape(new))}
    for path in stage.rglob("*"):
        if path.suffix.lower() not in _TEXT_SUFFIXES or not path.is_file():
            continue
        try:
            text = path.read_text(encoding="utf-8")
        except (UnicodeDecodeError, OSError):
            continue
        if not any(a in text for a, _ in pairs):
            continue
        for a, b in pairs:
            text = text.replace(a, b)
        path.write_text(text, encoding="utf-8")


@contextmanager
def staged_folder(out: str | Path, command: str) -> Iterator[Path]:
    """Yield an empty staging folder beside ``out``; on success mark it as ``command``'s and put it in place.

    On an exception (or Ctrl-C) the staging folder is removed and ``out`` is
    left as it was. Call :func:`check_output_folder` first.
    """
    target = Path(out).resolve()
    target.parent.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=f".{target.name}.partial-", dir=target.parent))
    try:
        yield stage
        _relocate_text(stage, target)
        (stage / OUTPUT_MARKER).write_text(json.dumps({"command": command}) + "\n", encoding="utf-8")
        swap_into_place(stage, target)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
