"""Graph SLAM: the Karto-class front end that turns scans into a pose graph, and the method built on it."""

from slam2d.graph.frontend import GraphFrontend
from slam2d.graph.loop_closing import LoopClosure
from slam2d.graph.params import GraphSlamParams
from slam2d.graph.method import GraphSlam

__all__ = ["GraphFrontend", "GraphSlamParams", "LoopClosure", "GraphSlam"]
