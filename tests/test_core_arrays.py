"""slam2d.core.arrays.grown: the one way the per-node stores gain rows."""

from __future__ import annotations

import numpy as np

from slam2d.core.arrays import grown


def test_grown_keeps_rows_fills_new_ones_and_doubles():
    a = np.arange(6, dtype=np.int64).reshape(3, 2)
    assert grown(a, 3) is a  # enough rows: the array itself
    b = grown(a, 4, fill=-1)
    assert b.shape == (6, 2) and b.dtype == a.dtype  # doubled
    assert np.array_equal(b[:3], a) and np.all(b[3:] == -1)
    assert grown(a, 10).shape == (10, 2)  # more than double: what is needed
    assert grown(np.zeros(0), 1, minimum=16).shape == (16,)
    assert not grown(np.ones(2, bool), 3).tolist()[2]  # new rows of a bool store are False


def test_freed_large_blocks_go_back_to_the_system_on_linux():
    import platform
    import sys

    from slam2d.core.memory import return_freed_memory

    applied = return_freed_memory()
    if sys.platform.startswith("linux") and platform.libc_ver()[0] == "glibc":
        assert applied  # glibc: mallopt took the fixed threshold
    else:
        assert not applied
