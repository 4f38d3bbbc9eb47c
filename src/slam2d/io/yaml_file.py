"""Reading a small YAML file a user wrote (parameters, a sensor model), with errors that name the line."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from slam2d.errors import InputError

__all__ = ["read_yaml"]


def read_yaml(path: str | Path, what: str) -> Any:
    """The parsed document of ``path``; :class:`InputError` if it is missing, not text or not YAML.

    ``what`` names the file's purpose in the messages ("parameter file", "sensor model file").
    """
    import yaml

    path = Path(path)
    if not path.is_file():
        raise InputError(f"no such {what}" if not path.exists() else "is not a file", path=path)
    try:
        return yaml.safe_load(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise InputError(f"is not text (a YAML {what} was expected)", path=path) from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = mark.line + 1 if mark is not None else None
        raise InputError(f"not valid YAML: {getattr(exc, 'problem', None) or exc}", path=path, where=where) from None
