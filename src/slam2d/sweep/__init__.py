"""Parameter studies: many runs (methods x parameters x datasets x seeds) on a local pool or a Dask cluster.

* :mod:`~slam2d.sweep.spec`: read and check a YAML sweep spec;
* :mod:`~slam2d.sweep.expand`: the concrete datasets and runs, each with a stable id;
* :mod:`~slam2d.sweep.execute`: what a worker does for one dataset or one run;
* :mod:`~slam2d.sweep.executors`: the local process pool and the Dask executor;
* :mod:`~slam2d.sweep.engine`: :func:`run_sweep`, resumable;
* :mod:`~slam2d.sweep.table` and :mod:`~slam2d.sweep.report`: the results table, plots and summary.
"""

from slam2d.sweep.engine import SweepResult, run_sweep
from slam2d.sweep.spec import METRICS, SweepSpec, check_methods, load_spec

__all__ = ["METRICS", "SweepSpec", "SweepResult", "load_spec", "check_methods", "run_sweep"]
