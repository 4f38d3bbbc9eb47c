"""``karto``: Karto's graph SLAM. Correlative scan matching, loop closure, sparse pose adjustment.

The front end (:mod:`slam2d.graph.frontend`) keeps a scan every 0.2 m or 10 deg,
matches it against the recent scans and older passes, closes loops with a wide
coarse match confirmed by a fine one, and optimises the graph with ``spa``
(Levenberg-Marquardt) after every closure. ``--set backend=lago`` swaps the optimiser.
Unlike Karto, a scan retracing older passes already connected there adds no node
(``revisit_without_nodes``): driving an area again grows the graph with the area, not the scans.
"""

from __future__ import annotations

from dataclasses import dataclass

from slam2d.graph import GraphSlam, GraphSlamParams
from slam2d.methods.registry import register

__all__ = ["KartoParams", "Karto"]


@dataclass
class KartoParams(GraphSlamParams):
    """open_karto's mapper parameters and defaults; the back end is SPA."""


@register
class Karto(GraphSlam):
    name = "karto"
    Params = KartoParams
    summary = "Karto graph SLAM: correlative matching, loop closure, SPA back end"
