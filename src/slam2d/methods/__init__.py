"""SLAM methods behind one interface (:class:`~slam2d.methods.base.SlamMethod`).

One short module per method, composed from the shared parts in
:mod:`slam2d.grids`, :mod:`slam2d.matching`, :mod:`slam2d.backends` and
:mod:`slam2d.sensors`. Look a method up by name with
:func:`~slam2d.methods.registry.get_method`; list them with
:func:`~slam2d.methods.registry.available`.
"""

from slam2d.methods.base import Diagnostics, SlamMethod
from slam2d.methods.registry import available, get_method, method_names, register

__all__ = ["SlamMethod", "Diagnostics", "available", "get_method", "method_names", "register"]
