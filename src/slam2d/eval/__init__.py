"""Evaluation: map quality metrics (trajectory metrics live alongside)."""

from slam2d.eval.map_metrics import run_lengths, scan_agreement, scan_consistency, wall_thickness

__all__ = ["wall_thickness", "run_lengths", "scan_agreement", "scan_consistency"]
