"""Reading a small YAML file a user wrote (parameters, a sensor model), with errors that name the line."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from slam2d.errors import InputError

__all__ = ["read_yaml"]


def _loader():
    """A safe YAML loader that refuses a key given twice in one mapping (PyYAML keeps the last, silently)."""
    import yaml

    class UniqueKeyLoader(yaml.SafeLoader):
        pass

    def mapping(loader, node, deep=False):
        seen: dict[Any, int] = {}
        for key_node, _ in node.value:
            key = loader.construct_object(key_node, deep=deep)
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"{key!r} is given twice (first at line {seen[key]})", key_node.start_mark)
            seen[key] = key_node.start_mark.line + 1
        return yaml.SafeLoader.construct_mapping(loader, node, deep=deep)

    UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, mapping)
    return UniqueKeyLoader


def read_yaml(path: str | Path, what: str) -> Any:
    """The parsed document of ``path``; :class:`InputError` if it is missing, not text or not YAML.

    ``what`` names the file's purpose in the messages ("parameter file", "sensor model file").
    """
    import yaml

    path = Path(path)
    if not path.is_file():
        raise InputError(f"no such {what}" if not path.exists() else "is not a file", path=path)
    try:
        return yaml.load(path.read_text(encoding="utf-8"), Loader=_loader())  # noqa: S506 (a SafeLoader)
    except UnicodeDecodeError:
        raise InputError(f"is not text (a YAML {what} was expected)", path=path) from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = mark.line + 1 if mark is not None else None
        raise InputError(f"not valid YAML: {getattr(exc, 'problem', None) or exc}", path=path, where=where) from None
