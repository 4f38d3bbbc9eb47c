"""Time numba spends compiling, so that no method is charged for it.

The hot loops are numba functions compiled on first use and cached on disk. In
a fresh clone the first run of a method compiles dozens of them: karto's first
run on intel took 38.6 s against 4.9 s for the second, and one update at scan
93 took 3.9 s of CPU. A method's time per scan, a run's ``wall_s`` and the
reports are the method's cost, not the compiler's: :func:`compile_clock` is
read before and after, and the difference is taken out and reported on its own.
"""

from __future__ import annotations

import time

__all__ = ["compile_clock"]

_totals = [0.0, 0.0]  # wall, CPU seconds of outermost compilations so far
_installed = False


def _install() -> None:
    global _installed
    from numba.core import event

    class _Clock(event.Listener):
        """Outermost "numba:compile" events only: compiling a function compiles its callees inside it."""

        def __init__(self) -> None:
            self.depth = 0
            self.start = (0.0, 0.0)

        def on_start(self, ev) -> None:
            if self.depth == 0:
                self.start = (time.perf_counter(), time.process_time())
            self.depth += 1

        def on_end(self, ev) -> None:
            self.depth -= 1
            if self.depth == 0:
                _totals[0] += time.perf_counter() - self.start[0]
                _totals[1] += time.process_time() - self.start[1]

    event.register("numba:compile", _Clock())
    _installed = True


def compile_clock() -> tuple[float, float]:
    """``(wall s, CPU s)`` this process has spent compiling numba functions so far."""
    if not _installed:
        _install()
    return _totals[0], _totals[1]
