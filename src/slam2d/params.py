"""Parameter dataclasses: one definition gives the defaults, the units, the CLI and the docs.

A parameter set is a plain dataclass whose fields are made with :func:`param`::

    @dataclass
    class GridParams:
        resolution: float = param(0.05, unit="m", help="cell size", low=0.001)

:func:`add_arguments` turns it into ``argparse`` options (``--resolution``),
:func:`from_arguments` builds the instance back, :func:`markdown_table` writes
the table the docs show, and :func:`validate` checks types, choices and ranges
with an :class:`~slam2d.errors.InputError` that names the parameter.

A parameter made with ``param(..., advanced=True, group="wall refinement")`` is one
most users never set (a slam2d addition that is off by default, a tuning knob of one):
listings show the others first and the advanced ones after them, by group
(:func:`describe`), and a run's record holds it only when it differs from its
default (:func:`as_record`; :func:`from_mapping` fills in the defaults again).
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import math
import re
import types
import typing
from dataclasses import dataclass
from typing import Any

from slam2d.errors import InputError

__all__ = [
    "param",
    "ParamInfo",
    "describe",
    "add_arguments",
    "from_arguments",
    "validate",
    "coerce",
    "markdown_table",
    "from_mapping",
    "as_dict",
    "as_record",
    "advanced_groups",
    "AUTO",
    "is_auto",
    "auto_fields",
]

#: The value of a parameter that resolves from the recording before the run (see ``param(auto=...)``).
AUTO = "auto"


def is_auto(value: Any) -> bool:
    return isinstance(value, str) and value == AUTO

# Units a number may carry on the command line or in a parameter file
# ("--set max_range=450cm", "angular_update: 25deg"), with their factor to the
# unit the parameter is declared in. Units of one row convert into each other.
_UNIT_FACTORS: dict[str, dict[str, float]] = {
    "m": {"m": 1.0, "cm": 0.01, "mm": 0.001, "km": 1000.0},
    "rad": {"rad": 1.0, "deg": math.pi / 180.0},
    "s": {"s": 1.0, "ms": 0.001, "min": 60.0},
    "Hz": {"Hz": 1.0, "kHz": 1000.0},
}
_NUMBER_WITH_UNIT = re.compile(r"^\s*([-+0-9.eE]+|[-+]?inf|nan)\s*([A-Za-z]+)\s*$")


def param(
    default: Any,
    *,
    help: str,
    unit: str = "",
    choices: tuple[Any, ...] | None = None,
    low: float | None = None,
    high: float | None = None,
    auto: str | None = None,
    advanced: bool = False,
    group: str = "",
) -> Any:
    """A dataclass field carrying its unit, help line, allowed choices and range.

    ``advanced``: few users set it (listed after the others, under ``group``, the feature it
    belongs to, e.g. ``"loop correction"``; recorded in a run only when changed). An advanced
    parameter needs its group.

    With ``auto`` (a line saying what the value is resolved from), the field's default is
    :data:`AUTO`: the method resolves it from the recording before the run
    (:mod:`slam2d.sensors.recording_profile`), and ``default`` is the original's value it falls
    back to when the recording cannot tell. A user's explicit value always wins.
    """
    if advanced and not group:
        raise ValueError("an advanced parameter needs its group (the feature it belongs to)")
    meta = {"help": help, "unit": unit, "choices": choices, "low": low, "high": high,
            "auto": auto, "fallback": default, "advanced": advanced, "group": group}
    return dataclasses.field(default=AUTO if auto else default, metadata=meta)


@dataclass(frozen=True)
class ParamInfo:
    name: str
    type: Any
    default: Any
    unit: str
    help: str
    choices: tuple[Any, ...] | None
    low: float | None
    high: float | None
    auto: str | None = None  # what an ``auto`` default resolves from (None: no auto default)
    fallback: Any = None  # the value an ``auto`` default takes when the recording cannot tell
    advanced: bool = False  # few users set it: listed after the others, recorded only when changed
    group: str = ""  # the feature it belongs to ("loop correction")

    @property
    def optional(self) -> bool:
        return _is_optional(self.type)

    @property
    def base_type(self) -> Any:
        return _base_type(self.type)


def _is_optional(tp: Any) -> bool:
    return typing.get_origin(tp) in (typing.Union, types.UnionType) and type(None) in typing.get_args(tp)


def _base_type(tp: Any) -> Any:
    if _is_optional(tp):
        (inner,) = [a for a in typing.get_args(tp) if a is not type(None)]
        return inner
    return tp


def _by_class(cls: type) -> list[dataclasses.Field]:
    """The fields of ``cls``, its own first, then each base class's (in method resolution order), each class's in
    declaration order (a field redeclared by a subclass counts as the subclass's)."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    ordered: dict[str, dataclasses.Field] = {}
    for klass in cls.__mro__:
        for name in inspect.get_annotations(klass):
            if name in fields:
                ordered.setdefault(name, fields[name])
    return list(ordered.values())


def describe(cls: type) -> list[ParamInfo]:
    """The parameters of a parameter dataclass, in listing order.

    First the parameters that are not advanced: the class's own, then each base class's (so a
    method's parameters come before those of the features it inherits), each in declaration
    order; then the advanced ones, by group (the groups in the order they first appear).
    """
    hints = typing.get_type_hints(cls)
    out = []
    for f in _by_class(cls):
        m = f.metadata
        out.append(
            ParamInfo(
                name=f.name,
                type=hints[f.name],
                default=f.default,
                unit=m.get("unit", ""),
                help=m.get("help", ""),
                choices=m.get("choices"),
                low=m.get("low"),
                high=m.get("high"),
                auto=m.get("auto"),
                fallback=m.get("fallback", f.default),
                advanced=m.get("advanced", False),
                group=m.get("group", ""),
            )
        )
    groups = list(dict.fromkeys(p.group for p in out if p.advanced))
    return [p for p in out if not p.advanced] + [p for g in groups for p in out if p.advanced and p.group == g]


def advanced_groups(cls: type) -> dict[str, list[ParamInfo]]:
    """The advanced parameters of ``cls`` by group, in listing order."""
    groups: dict[str, list[ParamInfo]] = {}
    for p in describe(cls):
        if p.advanced:
            groups.setdefault(p.group, []).append(p)
    return groups


def auto_fields(instance: Any) -> list[ParamInfo]:
    """The parameters of an instance whose value is still :data:`AUTO`."""
    return [p for p in describe(type(instance)) if p.auto and is_auto(getattr(instance, p.name))]


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def _help_text(p: ParamInfo) -> str:
    text = p.help
    if p.unit:
        text += f" [{p.unit}]"
    if p.choices:
        text += f" (one of: {', '.join(map(str, p.choices))})"
    if p.auto:
        text += f" (default: auto, from {p.auto}; {p.fallback} when the recording cannot tell)"
    elif p.default is not None and p.base_type is not bool:
        text += f" (default: {p.default})"
    return text


def add_arguments(parser: argparse.ArgumentParser | argparse._ArgumentGroup, cls: type) -> None:
    """Add one ``--option`` per field of ``cls``; values are parsed later by :func:`from_arguments`."""
    for p in describe(cls):
        if p.base_type is bool:
            parser.add_argument(
                _flag(p.name),
                dest=p.name,
                action=argparse.BooleanOptionalAction,
                default=p.default,
                help=_help_text(p),
            )
        else:
            parser.add_argument(
                _flag(p.name),
                dest=p.name,
                default=None,
                metavar=p.unit.upper().replace(" ", "_") or p.base_type.__name__.upper(),
                help=_help_text(p),
            )


def coerce(p: ParamInfo, text: Any) -> Any:
    """Convert a string (from the command line or a file) to the parameter's type."""
    if text is None:
        return None
    if isinstance(text, str) and p.optional and text.strip().lower() in ("none", "null", ""):
        return None
    if p.auto and isinstance(text, str) and text.strip().lower() == AUTO:
        return AUTO
    t = p.base_type
    try:
        if isinstance(text, bool) and t in (int, float):
            raise ValueError(text)  # YAML's true/false is not 1/0
        if t is bool:
            if isinstance(text, bool):
                return text
            s = str(text).strip().lower()
            if s in ("1", "true", "yes", "on"):
                return True
            if s in ("0", "false", "no", "off"):
                return False
            raise ValueError(text)
        if t is int:
            if isinstance(text, float) and not text.is_integer():
                raise ValueError(text)
            return int(str(text)) if isinstance(text, str) else int(text)
        if t is float:
            if isinstance(text, str):
                return _float_with_unit(p, text)
            return float(text)
        if t is str:
            return str(text)
    except (TypeError, ValueError):
        raise InputError(
            f"{text!r} is not a valid {t.__name__}", field=p.name
        ) from None
    return text


def _float_with_unit(p: ParamInfo, text: str) -> float:
    """A float from text, converting a unit suffix into the parameter's unit."""
    m = _NUMBER_WITH_UNIT.match(text)
    if m is None:
        return float(text)
    number, unit = float(m.group(1)), m.group(2)
    for family in _UNIT_FACTORS.values():
        if p.unit in family:
            if unit not in family:
                break
            return number * family[unit] / family[p.unit]
    expected = f"in {p.unit}" if p.unit else "a plain number"
    raise InputError(f"{text!r} has unit {unit!r} but this parameter is {expected}", field=p.name)


def validate(instance: Any) -> None:
    """Check every field of a parameter dataclass against its choices and range."""
    for p in describe(type(instance)):
        value = getattr(instance, p.name)
        if value is None:
            if not p.optional:
                raise InputError("a value is required", field=p.name)
            continue
        if p.auto and is_auto(value):
            continue
        if p.choices and value not in p.choices:
            raise InputError(
                f"{value!r} is not one of: {', '.join(map(str, p.choices))}", field=p.name
            )
        unit = f" {p.unit}" if p.unit else ""
        if isinstance(value, float) and math.isnan(value):
            raise InputError(f"{value}{unit} is not a number", field=p.name)
        if p.low is not None and value < p.low:
            raise InputError(f"{value}{unit} is below the minimum {p.low}{unit}", field=p.name)
        if p.high is not None and value > p.high:
            raise InputError(f"{value}{unit} is above the maximum {p.high}{unit}", field=p.name)


def from_arguments(cls: type, namespace: argparse.Namespace) -> Any:
    """Build and validate an instance of ``cls`` from parsed command-line options."""
    values = {}
    for p in describe(cls):
        raw = getattr(namespace, p.name, None)
        if raw is not None:
            values[p.name] = coerce(p, raw)
    instance = cls(**values)
    validate(instance)
    return instance


def markdown_table(cls: type, *, names: str = "flags", advanced: str = "fold") -> str:
    """A Markdown table of the parameters: name, default, unit, meaning.

    ``names="flags"`` shows command-line options (``--max-range``);
    ``names="settings"`` shows the names ``--set NAME=VALUE`` takes (``max_range``).
    ``advanced="fold"``: the advanced parameters follow the table, a folded table per group;
    ``"omit"``: the table of the others alone; ``"sections"``: the advanced ones alone, a
    ``## group`` heading and a table per group (a reference page of their own).
    """
    if advanced not in ("fold", "omit", "sections"):
        raise ValueError(f"advanced must be 'fold', 'omit' or 'sections', not {advanced!r}")
    params = describe(cls)
    head = ["| parameter | default | unit | meaning |", "|---|---|---|---|"]
    groups = advanced_groups(cls)
    if advanced == "sections":
        rows = []
        for group, members in groups.items():
            rows += [f"## {group}", "", *head, *(_markdown_row(p, names) for p in members), ""]
        return "\n".join(rows)
    rows = head + [_markdown_row(p, names) for p in params if not p.advanced]
    if groups and advanced == "fold":
        count = sum(map(len, groups.values()))
        rows += ["", f"**Advanced** ({count} parameters, by the feature they belong to; most runs leave them at "
                 "their defaults):", ""]
        for group, members in groups.items():
            rows += [f"<details><summary>{group} ({len(members)})</summary>", "", *head,
                     *(_markdown_row(p, names) for p in members), "", "</details>", ""]
        rows.pop()
    return "\n".join(rows) + "\n"


def _markdown_row(p: ParamInfo, names: str) -> str:
    meaning = p.help.rstrip()
    if meaning and meaning[-1] not in ".!?)":
        meaning += "."
    if p.choices:
        meaning += " One of: " + ", ".join(f"`{c}`" for c in p.choices) + "."
    rng = []
    if p.low is not None:
        rng.append(f">= {p.low}")
    if p.high is not None:
        rng.append(f"<= {p.high}")
    if rng:
        meaning += " Range: " + ", ".join(rng) + "."
    if p.auto:
        meaning += f" `auto`: from {p.auto}; `{p.fallback}` when the recording cannot tell."
    shown = _flag(p.name) if names == "flags" else p.name
    return f"| `{shown}` | `{p.default}` | {p.unit or '-'} | {meaning} |"


def _suggest(name: str, valid) -> str:
    """The closest valid names (a typo), else all of them when few, else where to find them."""
    import difflib

    close = difflib.get_close_matches(name, list(valid), n=3, cutoff=0.6)
    if close:
        return "did you mean " + " or ".join(repr(c) for c in close) + "?"
    if len(valid) <= 20:
        return "valid: " + ", ".join(sorted(valid))
    return f"none of the {len(valid)} parameters is close ('slam2d methods METHOD --all' lists them)"


def from_mapping(cls: type, values: Any, *, path: Any = None, where: Any = None) -> Any:
    """Build and validate an instance of ``cls`` from a mapping of names to values.

    Values may be strings (``--set name=value``, with an optional unit suffix
    such as ``25deg``) or already typed (a YAML file). Dashes in names are
    accepted for underscores. A parameter not in ``values`` takes its default
    (so a record of :func:`as_record`, without the unchanged advanced ones,
    builds the same instance). An unknown name raises :class:`InputError`
    listing the valid ones; ``path``/``where`` say where the values came from.
    """
    if not isinstance(values, dict):
        raise InputError(
            f"expected a mapping of parameter names to values, got {type(values).__name__}", path=path, where=where
        )
    params = {p.name: p for p in describe(cls)}
    chosen = {}
    for raw_name, raw in values.items():
        name = str(raw_name).replace("-", "_")
        if name not in params:
            raise InputError(f"unknown parameter {raw_name!r}; {_suggest(name, params)}",
                             path=path, where=where, field=str(raw_name))
        try:
            chosen[name] = coerce(params[name], raw)
        except InputError as exc:
            raise InputError(exc.message, path=path, where=where, field=name) from None
    instance = cls(**chosen)
    try:
        validate(instance)
    except InputError as exc:
        raise InputError(exc.message, path=path, where=where, field=exc.field) from None
    return instance


def as_dict(instance: Any) -> dict[str, Any]:
    """Every parameter value of an instance, by name (JSON-friendly)."""
    return {p.name: getattr(instance, p.name) for p in describe(type(instance))}


def as_record(instance: Any) -> dict[str, Any]:
    """The parameter values a run records: every one that is not advanced, and the advanced ones only where they
    differ from their default (:func:`from_mapping` fills those in again)."""
    out = {}
    for p in describe(type(instance)):
        value = getattr(instance, p.name)
        if p.advanced and _same(value, p.default):
            continue
        out[p.name] = value
    return out


def _same(value: Any, default: Any) -> bool:
    if isinstance(value, float) and isinstance(default, float) and math.isnan(value) and math.isnan(default):
        return True
    return type(value) is type(default) and value == default
