"""The method registry: name -> method class, filled by the method modules themselves.

Every module in :mod:`slam2d.methods` is imported once on first use, and each
registers its class with :func:`register`; a method in another package plugs
in through the ``slam2d.methods`` entry-point group. The CLI, the docs and the
comparison read the registry, so adding a method touches none of them.
"""

from __future__ import annotations

import importlib
import pkgutil
from importlib.metadata import entry_points
from typing import TYPE_CHECKING

from slam2d.errors import InputError

if TYPE_CHECKING:
    from slam2d.methods.base import SlamMethod

__all__ = ["register", "available", "get_method", "method_names"]

_REGISTRY: dict[str, type[SlamMethod]] = {}
_NOT_METHODS = {"base", "registry", "runner"}
_discovered = False


def register(cls: type[SlamMethod]) -> type[SlamMethod]:
    """Class decorator: make a :class:`~slam2d.methods.base.SlamMethod` available by its ``name``."""
    name = getattr(cls, "name", None)
    if not name or not isinstance(name, str):
        raise TypeError(f"{cls.__name__} has no 'name'")
    other = _REGISTRY.get(name)
    if other is not None and other is not cls:
        raise TypeError(f"method name {name!r} is taken by {other.__module__}.{other.__name__}")
    _REGISTRY[name] = cls
    return cls


def _discover() -> None:
    global _discovered
    if _discovered:
        return
    _discovered = True
    import slam2d.methods as package

    for info in pkgutil.iter_modules(package.__path__):
        if info.name not in _NOT_METHODS and not info.name.startswith("_"):
            importlib.import_module(f"{package.__name__}.{info.name}")
    for ep in entry_points(group="slam2d.methods"):
        register(ep.load())


def available() -> dict[str, type[SlamMethod]]:
    """Every registered method, by name, sorted."""
    _discover()
    return dict(sorted(_REGISTRY.items()))


def method_names() -> list[str]:
    return list(available())


def get_method(name: str) -> type[SlamMethod]:
    """The method class called ``name``; an unknown name is an :class:`InputError` listing the valid ones."""
    methods = available()
    cls = methods.get(name) or methods.get(name.replace("_", "-"))
    if cls is None:
        raise InputError(f"unknown method {name!r}; available: {', '.join(methods)}", field="method")
    return cls
