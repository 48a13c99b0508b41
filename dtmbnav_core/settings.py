"""Dotted settings of nested dataclasses, as a command line gives them: ``integrity.rate_sigma_mps=0.02``.

``dtmbnav evaluate --set`` and ``dtmbnav fuse --set`` change any scalar
field of :class:`fusion.run.FusionConfig` (and of the configurations nested in
it) without a flag of its own, so a setting tried on the tuning walks is a
command a reviewer can rerun. The value is parsed by the field's annotated
type; the configuration's own checks (``__post_init__``) then apply.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Iterable
from typing import Any, TypeVar

Config = TypeVar("Config")

_TRUE = frozenset({"true", "yes", "on", "1"})
_FALSE = frozenset({"false", "no", "off", "0"})


def parse_setting(text: str) -> tuple[str, str]:
    """``"NAME=VALUE"`` -> ``(NAME, VALUE)``, both stripped.

    Raises
    ------
    ValueError
        When there is no ``=`` or no name.
    """
    name, separator, value = text.partition("=")
    if not separator or not name.strip():
        raise ValueError(f"a setting is NAME=VALUE (e.g. integrity.rate_sigma_mps=0.02), got {text!r}")
    return name.strip(), value.strip()


def setting_names(config: Any) -> list[str]:
    """The dotted names of every scalar field of ``config`` (a dataclass instance), nested ones included."""
    names = []
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if dataclasses.is_dataclass(value):
            names += [f"{f.name}.{inner}" for inner in setting_names(value)]
        else:
            names.append(f.name)
    return names


def with_settings(config: Config, settings: Iterable[tuple[str, str]]) -> Config:
    """``config`` with each ``(dotted name, value text)`` of ``settings`` applied, in order.

    Parameters
    ----------
    config : dataclass instance
        Frozen or not; it is not modified.
    settings : iterable of (str, str)
        E.g. ``[("integrity.rate_sigma_mps", "0.02"), ("n_particles", "2000")]``.
        Booleans read true/false, yes/no, on/off, 1/0; an optional field
        reads ``none``.

    Raises
    ------
    ValueError
        For an unknown name (the message lists the known ones), a name of a
        group rather than a field, a value its type cannot read, or a value
        the configuration's own checks refuse.
    """
    for name, text in settings:
        config = _with_setting(config, config, name.split("."), text, name)
    return config


def _with_setting(root: Any, config: Any, path: list[str], text: str, name: str) -> Any:
    fields = {f.name for f in dataclasses.fields(config)}
    head = path[0]
    if head not in fields:
        raise ValueError(f"unknown setting {name!r}; known: {', '.join(setting_names(root))}")
    current = getattr(config, head)
    if len(path) > 1:
        if not dataclasses.is_dataclass(current):
            raise ValueError(f"unknown setting {name!r}: {head} has no fields")
        return dataclasses.replace(config, **{head: _with_setting(root, current, path[1:], text, name)})
    if dataclasses.is_dataclass(current):
        raise ValueError(f"setting {name!r} is a group: set its fields ({', '.join(setting_names(current))})")
    value = _parse(text, typing.get_type_hints(type(config))[head], name)
    return dataclasses.replace(config, **{head: value})


def _parse(text: str, hint: Any, name: str) -> Any:
    """``text`` read as the annotated type ``hint`` (bool, int, float, str, or one of them or None)."""
    options = typing.get_args(hint) if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union \
        else (hint,)
    if type(None) in options and text.lower() == "none":
        return None
    kinds = [kind for kind in options if kind is not type(None)]
    if len(kinds) != 1 or kinds[0] not in (bool, int, float, str):
        raise ValueError(f"setting {name!r} ({hint}) cannot be given on the command line")
    kind = kinds[0]
    if kind is bool:
        if text.lower() in _TRUE | _FALSE:
            return text.lower() in _TRUE
        raise ValueError(f"setting {name!r} is true or false, got {text!r}")
    try:
        return kind(text)
    except ValueError:
        raise ValueError(f"setting {name!r} must be {kind.__name__}, got {text!r}") from None
