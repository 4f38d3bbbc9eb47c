"""Scan matchers: align a scan to a map (or to another scan), return the pose, its score, and how well it is constrained.

One module per search strategy: ``gauss_newton`` (Hector), ``hill_climb`` (GMapping),
``correlative`` (Karto), ``rmhc`` (CoreSLAM), ``rrhc`` and ``critical_rays`` (CRSM).
"""
