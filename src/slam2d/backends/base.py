"""What every pose-graph back end returns, and the small interface they share."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from slam2d.backends.graph import PoseGraph

__all__ = ["OptimizationResult", "Backend"]


@dataclass
class OptimizationResult:
    """The outcome of one ``optimize`` call.

    ``cost_before`` and ``cost_after`` are always the plain quadratic cost
    ``sum e^T Omega e`` (comparable across back ends and kernels);
    ``objective_before``/``objective_after`` are what the optimiser minimised
    (the robust cost when a kernel is on, else equal to the cost).
    ``wall_s`` and ``cpu_s`` time the whole call.
    """

    poses: NDArray[np.float64]
    cost_before: float
    cost_after: float
    iterations: int
    converged: bool
    wall_s: float
    cpu_s: float = 0.0
    objective_before: float = float("nan")
    objective_after: float = float("nan")
    message: str = ""
    extra: dict[str, Any] = field(default_factory=dict)


class Backend:
    """A pose-graph optimiser: ``optimize(graph)`` returns new poses, the graph is not changed."""

    name: ClassVar[str] = ""
    #: whether ``optimize`` uses the graph's current poses as its starting point
    needs_initial_guess: ClassVar[bool] = True

    def optimize(self, graph: PoseGraph) -> OptimizationResult:  # pragma: no cover - interface
        raise NotImplementedError
