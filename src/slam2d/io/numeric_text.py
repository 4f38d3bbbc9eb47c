"""Whitespace-separated tables of numbers, one record per line (TUM trajectories, relations files).

:func:`numeric_rows` streams such a file and turns every way it can be wrong
(missing, a folder, unreadable, not UTF-8, the wrong number of columns, a value
that is not a finite number) into one :class:`~slam2d.errors.InputError`
naming ``file:line`` and the column. ``#`` comments and blank lines are skipped.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

from slam2d.errors import InputError

__all__ = ["numeric_rows", "token_lines", "parse_numbers"]


def token_lines(path: Path, what: str) -> Iterator[tuple[int, list[str]]]:
    """Yield ``(line number, tokens)`` for every non-blank, non-comment line of ``path``.

    A missing, unreadable or non-UTF-8 file is an :class:`InputError` naming the
    file (and the line); ``what`` names the format in the message.
    """
    if not path.exists():
        raise InputError("no such file", path=path)
    if path.is_dir():
        raise InputError(f"is a folder, not a {what}", path=path)
    try:
        f = open(path, "rb")
    except OSError as exc:
        raise InputError(f"cannot be read: {exc.strerror or exc}", path=path) from None
    with f:
        for lineno, raw in enumerate(f, start=1):
            try:
                line = raw.decode("utf-8")
            except UnicodeDecodeError as exc:
                raise InputError(
                    f"byte 0x{raw[exc.start]:02x} at column {exc.start + 1} is not UTF-8 text (is this a {what}?)",
                    path=path,
                    where=lineno,
                ) from None
            text = line.strip()
            if lineno == 1:
                text = text.removeprefix("\ufeff").strip()  # an editor's byte-order mark
            if not text or text.startswith("#"):
                continue
            yield lineno, text.split()


def parse_numbers(tokens: list[str], columns: tuple[str, ...], path: Path, lineno: int) -> list[float]:
    """``tokens`` as finite floats, one per named column; a bad one is an :class:`InputError` naming its column."""
    values = []
    for name, token in zip(columns, tokens):
        try:
            value = float(token)
        except ValueError:
            raise InputError(f"{token!r} is not a number", path=path, where=lineno, field=name) from None
        if not math.isfinite(value):
            raise InputError(f"{token!r} is not a finite number", path=path, where=lineno, field=name)
        values.append(value)
    return values


def numeric_rows(path: Path, columns: tuple[str, ...], what: str) -> Iterator[tuple[int, list[float]]]:
    """Yield ``(line number, values)`` for every data line of ``path``; ``what`` names the format in errors."""
    for lineno, tokens in token_lines(path, what):
        if len(tokens) != len(columns):
            raise InputError(
                f"{len(tokens)} columns, {len(columns)} expected: {' '.join(columns)}",
                path=path,
                where=lineno,
                field="columns",
            )
        yield lineno, parse_numbers(tokens, columns, path, lineno)
