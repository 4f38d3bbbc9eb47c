"""Graph SLAM: the Karto-class front end that turns scans into a pose graph, and the method built on it."""

from slam2d.graph.frontend import GraphFrontend, GraphSlamParams, LoopClosure
from slam2d.graph.method import GraphSlam

__all__ = ["GraphFrontend", "GraphSlamParams", "LoopClosure", "GraphSlam"]
