"""The memory a run may take, checked before a large allocation instead of found by the OOM killer.

A parameter a user may set (a map's ``resolution``, the number of ``particles``)
can ask for more memory than the machine has: ``--set resolution=0.001`` on a
40 m building is a 1.6-billion-cell map. The grids and the particle filter call
:func:`check_allocation` with the bytes they are about to take; above the budget
it stops with one line naming the parameter, the size asked for and the size
allowed. The budget is 75 % of the memory available at that moment (so
allocations add up), or what ``--max-memory`` says less what the process
already holds (:func:`set_budget`).
"""

from __future__ import annotations

import os
import re

from slam2d.errors import InputError

__all__ = [
    "return_freed_memory", "available_bytes", "resident_bytes", "budget_override", "budget_bytes", "set_budget", "parse_size", "format_size",
    "check_allocation",
]

#: Blocks at least this large come from their own mapping and go back to the system when freed.
_MMAP_THRESHOLD = 128 * 1024
_M_MMAP_THRESHOLD = -3  # glibc's mallopt parameter number


def return_freed_memory() -> bool:
    """Make freed large blocks (numpy's and numba's arrays) go back to the system at once; True where it applies.

    glibc raises its mmap threshold to the largest block freed so far, after which such blocks come
    from the heap and a freed one stays there, counted in the resident size while later blocks of
    another size cannot reuse it. A fixed 128 KB threshold (glibc's starting value) keeps peak memory
    near what is live: karto on intel 446 -> 356 MB, lago on fr101 418 -> 332 MB, CPU time unchanged
    (crsm's, which grows its map often, 3.7 -> 4.5 s on fr101). Called once by the command line; a
    library user decides for their own process.
    """
    import ctypes
    import ctypes.util
    import sys

    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        return bool(libc.mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD))
    except (OSError, AttributeError):  # not glibc (musl has no mallopt)
        return False


#: Share of the available memory a run may take by default.
DEFAULT_SHARE = 0.75


def available_bytes() -> int | None:
    """Memory available to new allocations now (Linux: MemAvailable), or None when unknown."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


#: Where ``--max-memory`` is kept (bytes): in the environment, so worker processes a command starts
#: (``compare --jobs``, ``sweep``) hold to it too.
ENVIRONMENT = "SLAM2D_MAX_MEMORY"


def budget_override() -> int | None:
    """The limit ``--max-memory`` set (bytes), or None for the default share of the available memory."""
    text = os.environ.get(ENVIRONMENT)
    try:
        return parse_size(text) if text else None
    except ValueError:
        return None


def resident_bytes() -> int | None:
    """This process's resident memory now (Linux), or None when unknown."""
    try:
        with open("/proc/self/statm", encoding="ascii") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError, AttributeError):
        return None


def budget_bytes() -> int | None:
    """What one more allocation may take now, in bytes (None: no limit known).

    With ``--max-memory``: that total less what the process already holds. Without: DEFAULT_SHARE of the
    memory available now, so allocations add up (64 filters of particles each fit alone, not together).
    """
    limit = budget_override()
    if limit is not None:
        return max(0, limit - (resident_bytes() or 0))
    free = available_bytes()
    return None if free is None else int(DEFAULT_SHARE * free)


def set_budget(limit: int | None) -> None:
    """Set the budget in bytes (``--max-memory``); None restores the default share of the available memory."""
    if limit is None:
        os.environ.pop(ENVIRONMENT, None)
    else:
        os.environ[ENVIRONMENT] = str(limit)


_UNITS = {"": 1, "b": 1, "k": 1024, "kb": 1024, "m": 1024**2, "mb": 1024**2, "g": 1024**3, "gb": 1024**3,
          "t": 1024**4, "tb": 1024**4}


def parse_size(text: str) -> int:
    """``"2G"``, ``"500MB"``, ``"1.5g"`` or a plain byte count -> bytes (ValueError naming the text)."""
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*([a-zA-Z]*)\s*", text)
    unit = m.group(2).lower() if m else ""
    if m is None or unit not in _UNITS or float(m.group(1)) <= 0:
        raise ValueError(f"{text!r} is not a size (e.g. 2G, 500M, 1.5GB)")
    return int(float(m.group(1)) * _UNITS[unit])


def format_size(nbytes: float) -> str:
    for unit, size in (("TB", 1024**4), ("GB", 1024**3), ("MB", 1024**2), ("kB", 1024)):
        if nbytes >= size:
            return f"{nbytes / size:.3g} {unit}"
    return f"{int(nbytes)} B"


def check_allocation(nbytes: float, what: str, field: str) -> None:
    """Raise :class:`InputError` naming ``field`` when ``what`` needs more than the budget allows now."""
    limit = budget_bytes()
    if limit is not None and nbytes > limit:
        total = budget_override()
        how = (f"--max-memory {format_size(total)} less the {format_size(resident_bytes() or 0)} this run holds"
               if total is not None else f"{DEFAULT_SHARE:.0%} of the memory available; --max-memory sets it")
        raise InputError(f"{what} would need {format_size(nbytes)}, more than the {format_size(limit)} allowed "
                         f"({how})", field=field)
