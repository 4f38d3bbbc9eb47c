"""Localization in a fixed map (``slam2d localize``): a particle filter and scan-to-map tracking."""

from slam2d.localization.localizer import STATES, LocalizationParams, Localizer, ScanResult

__all__ = ["LocalizationParams", "Localizer", "ScanResult", "STATES"]
