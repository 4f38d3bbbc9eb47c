"""User-facing errors and the problem log that readers fill.

Two kinds of trouble reach a user:

* :class:`InputError` stops the work. It names the file, where in it (a line
  number or a message index), the field and what is wrong, and the CLI prints
  it as one line and exits non-zero. A traceback is kept for bugs.
* A *problem* that does not stop the work (a skipped corrupt line, odometry out
  of order) goes into a :class:`ProblemLog`, which counts each kind, keeps the
  first few examples and is reported at the end of a command.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path


def one_line(text: object) -> str:
    """``text`` (an error message, a library's exception) on one line: a user error prints as one line."""
    return " ".join(str(text).split())


class Slam2dError(Exception):
    """Base of every error slam2d raises on purpose."""


class InputError(Slam2dError):
    """Bad input from the user: a file, an option or a parameter.

    ``where`` is a line number (int) or a free-form location such as
    ``"message 12 on /scan"``.
    """

    def __init__(
        self,
        message: str,
        *,
        path: str | Path | None = None,
        where: int | str | None = None,
        field: str | None = None,
    ) -> None:
        self.message = message
        self.path = None if path is None else str(path)
        self.where = where
        self.field = field
        super().__init__(self.__str__())

    def in_file(self, path: str | Path, where: int | str | None = None) -> InputError:
        """This error, placed in ``path`` (and at ``where``) when it names no file of its own.

        For a mistake a helper found without knowing where its input came from
        (a command file's velocity, a pose that grows the map without bound).
        """
        if self.path is not None:
            return self
        return InputError(self.message, path=path, where=self.where if where is None else where, field=self.field)

    def __str__(self) -> str:
        location = ""
        if self.path is not None:
            location = self.path
            if isinstance(self.where, int):
                location += f":{self.where}"
            elif self.where:
                location += f" ({self.where})"
            location += ": "
        elif self.where is not None:
            location = f"{self.where}: "
        fieldpart = f"{self.field}: " if self.field else ""
        return f"{location}{fieldpart}{self.message}"


@dataclass
class ProblemLog:
    """Counts of non-fatal problems by kind, with the first few examples of each."""

    max_examples: int = 3
    counts: Counter[str] = field(default_factory=Counter)
    examples: dict[str, list[str]] = field(default_factory=dict)

    def add(self, kind: str, example: str) -> None:
        self.counts[kind] += 1
        bucket = self.examples.setdefault(kind, [])
        if len(bucket) < self.max_examples:
            bucket.append(example)

    def clear(self) -> None:
        """Forget everything: readers call it when a new pass over the file starts."""
        self.counts.clear()
        self.examples.clear()

    def snapshot(self) -> tuple[Counter[str], dict[str, list[str]]]:
        """The current state, for :meth:`restore` when a reader starts another pass."""
        return Counter(self.counts), {k: list(v) for k, v in self.examples.items()}

    def restore(self, state: tuple[Counter[str], dict[str, list[str]]]) -> None:
        counts, examples = state
        self.counts = Counter(counts)
        self.examples = {k: list(v) for k, v in examples.items()}

    def __bool__(self) -> bool:
        return bool(self.counts)

    def total(self) -> int:
        return sum(self.counts.values())

    def lines(self) -> list[str]:
        """One line per kind: ``count x kind (e.g. example; example)``."""
        out = []
        for kind, n in self.counts.most_common():
            ex = "; ".join(self.examples.get(kind, []))
            out.append(f"{n} x {kind}" + (f" (e.g. {ex})" if ex else ""))
        return out

    def as_dict(self) -> dict[str, dict[str, object]]:
        return {k: {"count": n, "examples": self.examples.get(k, [])} for k, n in self.counts.items()}
