"""The settings schema's vocabulary: a config field with its documentation, type checks of the
values a YAML file gives, and a walk over every key.

    iterations: int = setting(40, "Adam iterations on the pose per frame", unit="iterations",
                              trades="more: slower, a pose closer to the loss's minimum")
    check(value, hint, "tracking.iterations", "my.yaml")   # InputError: my.yaml: tracking.iterations
                                                           # = 'ten': expected an integer
    for key, field, hint in leaves(Config): ...            # "tracking.align.stride", ...

The field's type annotation is the schema: bool, int, float (ints accepted), str, Literal choices,
`X | None`, list[X], dict[str, X] and nested sections (dataclasses). docs/settings.md is generated
from the same fields (splat_core/settings_doc.py).
"""

from __future__ import annotations

import copy
import dataclasses
import numbers
import types
from functools import cache
from typing import Literal, Union, get_args, get_origin, get_type_hints

from .errors import InputError


def setting(default, doc: str, *, unit: str = "", trades: str = ""):
    """A config field: its default, what it does, its unit and what it trades (speed against
    accuracy, memory, ...), kept beside the field for docs/settings.md."""
    metadata = {"doc": doc, "unit": unit, "trades": trades}
    if isinstance(default, (dict, list)):
        return dataclasses.field(default_factory=lambda: copy.deepcopy(default), metadata=metadata)
    return dataclasses.field(default=default, metadata=metadata)


def section(cls, doc: str):
    """A nested section of keys (a dataclass), e.g. tracking.align."""
    return dataclasses.field(default_factory=cls, metadata={"doc": doc})


@cache
def field_types(cls) -> dict:
    """The resolved type annotations of a config dataclass (its module's names, Literal aliases)."""
    return get_type_hints(cls)


def leaves(cls, prefix: str = ""):
    """(dotted key, dataclass field, type) of every setting below `cls`, sections walked in order."""
    hints = field_types(cls)
    for f in dataclasses.fields(cls):
        if dataclasses.is_dataclass(hints[f.name]):
            yield from leaves(hints[f.name], f"{prefix}{f.name}.")
        else:
            yield f"{prefix}{f.name}", f, hints[f.name]


def accepts(value, hint) -> bool:
    """Whether a YAML value fits the type `hint` (bools are not integers; integers are numbers)."""
    origin, args = get_origin(hint), get_args(hint)
    if hint is type(None):
        return value is None
    if origin in (Union, types.UnionType):
        return any(accepts(value, a) for a in args)
    if origin is Literal:
        return any(type(value) is type(a) and value == a for a in args)
    if hint is bool:
        return isinstance(value, bool)
    if hint is int:
        return isinstance(value, numbers.Integral) and not isinstance(value, bool)
    if hint is float:
        return isinstance(value, numbers.Real) and not isinstance(value, bool)
    if hint is list or origin is list:
        return isinstance(value, list) and (not args or all(accepts(v, args[0]) for v in value))
    if hint is dict or origin is dict:
        return isinstance(value, dict) and (not args or all(accepts(v, args[1]) for v in value.values()))
    return isinstance(value, hint)


_NAMES = {bool: ("true or false", "booleans"), int: ("an integer", "integers"), float: ("a number", "numbers"),
          str: ("a string", "strings")}


def describe(hint) -> str:
    """What `hint` expects, in words: 'an integer', 'a number or null', 'one of all, random'."""
    origin, args = get_origin(hint), get_args(hint)
    if origin in (Union, types.UnionType):
        words = [describe(a) for a in args if a is not type(None)] + (["null"] if type(None) in args else [])
        return ", ".join(words[:-1]) + " or " + words[-1] if len(words) > 1 else words[0]
    if origin is Literal:
        return "one of " + ", ".join(str(a) for a in args)
    if hint is list or origin is list:
        return f"a list of {_NAMES[args[0]][1]}" if args else "a list"
    if hint is dict or origin is dict:
        return "a mapping"
    return _NAMES.get(hint, (getattr(hint, "__name__", str(hint)),))[0]


def check(value, hint, key: str, where: str) -> None:
    """InputError `where: key = value: expected ...` unless `value` fits `hint`."""
    if accepts(value, hint):
        return
    note = ""
    if isinstance(value, str) and any(c.isdigit() for c in value) and accepts(1.0, hint):
        try:
            float(value)
            note = " (YAML reads this as text: write a number with a decimal point and a signed exponent, e.g. 1.0e-3)"
        except ValueError:
            pass
    raise InputError(f"{where}: {key} = {value!r}: expected {describe(hint)}{note}")
