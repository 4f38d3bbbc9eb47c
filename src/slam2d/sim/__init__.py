"""Simulation of test spaces with exact ground truth."""
