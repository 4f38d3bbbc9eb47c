"""What an experiment hands to a report: tables, figures and a verdict, all plain data."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass
class Table:
    """A table of results; ``rows`` hold numbers or text in the order of ``columns``."""

    caption: str
    columns: list[str]
    rows: list[list[Any]]
    #: Column name -> unit, shown in the header ("ATE [m]").
    units: dict[str, str] = field(default_factory=dict)


@dataclass
class Figure:
    """A picture written by the experiment; ``path`` is relative to the experiment's folder."""

    path: str
    caption: str


@dataclass
class ExperimentResult:
    """One experiment's outcome, ready for a report.

    ``verdict`` says in a sentence or two whether the study's finding holds here and by how
    much; ``study`` records the study's own numbers the table is compared with (or is empty).
    """

    name: str
    title: str
    summary: str
    tables: list[Table] = field(default_factory=list)
    figures: list[Figure] = field(default_factory=list)
    study: dict[str, Any] = field(default_factory=dict)
    verdict: str = ""
    #: Machine-readable numbers (for tests and JSON output), e.g. {"mean_entropy": 3.1}.
    numbers: dict[str, float] = field(default_factory=dict)
