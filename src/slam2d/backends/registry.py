"""Back ends by name: ``get_backend("spa", max_iterations=20)``."""

from __future__ import annotations

import importlib
from typing import Any

from slam2d.backends.base import Backend
from slam2d.errors import InputError
from slam2d.params import from_mapping

__all__ = ["get_backend", "available_backends", "backend_params", "BACKENDS"]

#: name -> (module, backend class, parameter dataclass); imported lazily
BACKENDS: dict[str, tuple[str, str, str]] = {
    "spa": ("slam2d.backends.spa", "SpaBackend", "SpaParams"),
    "lago": ("slam2d.backends.lago", "LagoBackend", "LagoParams"),
    "gtsam": ("slam2d.backends.gtsam_backend", "GtsamBackend", "GtsamParams"),
}


def _load(name: str) -> tuple[type, type]:
    if name not in BACKENDS:
        raise InputError(f"unknown pose-graph back end {name!r}; known: {', '.join(BACKENDS)}", field="backend")
    module, cls, params = BACKENDS[name]
    mod = importlib.import_module(module)
    return getattr(mod, cls), getattr(mod, params)


def backend_params(name: str) -> type:
    """The parameter dataclass of back end ``name``."""
    return _load(name)[1]


def available_backends() -> list[str]:
    """Names of back ends usable here (``gtsam`` only when its package imports)."""
    out = []
    for name in BACKENDS:
        cls, _ = _load(name)
        if getattr(cls, "available", lambda: True)():
            out.append(name)
    return out


def get_backend(name: str, params: Any = None, **options: Any) -> Backend:
    """Make back end ``name``; ``params`` is its parameter dataclass instance, ``options`` override fields.

    Unknown options and out-of-range values raise :class:`InputError` naming the field.
    """
    cls, pcls = _load(name)
    if not getattr(cls, "available", lambda: True)():
        raise InputError(cls.unavailable_reason(), field="backend")
    if params is None:
        params = from_mapping(pcls, dict(options))
    else:
        if not isinstance(params, pcls):
            raise InputError(f"back end {name!r} takes {pcls.__name__}, got {type(params).__name__}", field="backend")
        if options:
            from slam2d.params import as_dict

            merged = as_dict(params)
            merged.update(options)
            params = from_mapping(pcls, merged)
    return cls(params)
