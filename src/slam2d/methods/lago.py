"""``lago``: the Karto front end with LAGO's linear back end (Carlone et al. 2012).

Same scans, matches and loop closures as ``karto``; after every closure the
graph is solved by LAGO (orientations first, then positions; no initial guess
needed) instead of SPA. ``--set backend=spa`` swaps it back.
"""

from __future__ import annotations

from dataclasses import dataclass

from slam2d.graph import GraphSlam, GraphSlamParams
from slam2d.methods.registry import register
from slam2d.params import param

__all__ = ["LagoParams", "Lago"]


@dataclass
class LagoParams(GraphSlamParams):
    """open_karto's mapper parameters and defaults; the back end is LAGO."""

    backend: str = param(
        "lago", choices=("spa", "lago", "gtsam"), help="pose-graph optimiser run after each loop closure"
    )


@register
class Lago(GraphSlam):
    name = "lago"
    Params = LagoParams
    summary = "graph SLAM with the Karto front end and LAGO's linear back end (no initial guess)"
