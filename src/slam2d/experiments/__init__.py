"""The source study's experiments, rerun in simulation with exact ground truth.

Each experiment returns an :class:`ExperimentResult`: numbers first (a table), the study's own
values beside them where it gave any, figures, and a plain verdict. ``slam2d paper`` assembles
them into one report; each also runs alone as a command.
"""

from slam2d.experiments.result import ExperimentResult, Figure, Table

__all__ = ["ExperimentResult", "Figure", "Table"]
