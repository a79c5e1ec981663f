"""Set any inverse-rendering option by name: ``reroom invert --set line_phi_smooth=1e6``.

Researchers tune what the command line does not name (smoothness, clearances, the solve's
subset, the Huber threshold); the same experiments otherwise need a Python script.
:func:`with_overrides` takes ``NAME=VALUE`` strings, ``NAME`` a field of
:class:`~reroom.invert.pipeline.InvertOptions` or ``solve.NAME`` one of
:class:`~reroom.invert.solve.SolveOptions`, and ``VALUE`` JSON (``1e-4``, ``true``,
``null``) or a bare word (``alternating``). Every value is checked against the field's
type, so a typo is an error that names the field, not a silently ignored setting.
"""

from __future__ import annotations

import dataclasses
import json
import types
import typing
from collections.abc import Iterable
from typing import Any

from reroom.invert.pipeline import InvertOptions
from reroom.invert.solve import SolveOptions

__all__ = ["option_names", "with_overrides"]


def option_names() -> list[str]:
    """Every name :func:`with_overrides` accepts, ``solve.*`` last."""
    top = [f.name for f in dataclasses.fields(InvertOptions) if f.name != "solve"]
    return top + [f"solve.{f.name}" for f in dataclasses.fields(SolveOptions)]


def _parse(text: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text  # a bare word: a string option's value


def _allowed(hint: Any) -> tuple[list[type], tuple | None, bool]:
    """``(types, literal choices or None, None allowed)`` of a field's type hint."""
    origin = typing.get_origin(hint)
    if origin is typing.Literal:
        return [str], typing.get_args(hint), False
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(hint)
        kinds: list[type] = []
        choices, optional = None, type(None) in args
        for a in args:
            if a is type(None):
                continue
            k, c, _ = _allowed(a)
            kinds += k
            choices = c or choices
        return kinds, choices, optional
    return [hint], None, False


def _coerce(name: str, hint: Any, value: Any) -> Any:
    kinds, choices, optional = _allowed(hint)
    if value is None:
        if optional:
            return None
        raise ValueError(f"option {name} cannot be null")
    for kind in kinds:
        if kind is bool and isinstance(value, bool):
            return value
        if kind is int and isinstance(value, int) and not isinstance(value, bool):
            return value
        if kind is float and isinstance(value, int | float) and not isinstance(value, bool):
            return float(value)
        if kind is str and isinstance(value, str):
            if choices is not None and value not in choices:
                raise ValueError(
                    f"option {name} must be one of {', '.join(map(str, choices))}, got {value!r}"
                )
            return value
    wanted = " or ".join(k.__name__ for k in kinds) + (" or null" if optional else "")
    raise ValueError(f"option {name} needs {wanted}, got {value!r}")


def with_overrides(options: InvertOptions, settings: Iterable[str]) -> InvertOptions:
    """A copy of ``options`` with each ``NAME=VALUE`` of ``settings`` applied.

    Parameters
    ----------
    options : InvertOptions
        The options to start from (not modified).
    settings : iterable of str
        ``NAME=VALUE`` strings: ``NAME`` an ``InvertOptions`` field or ``solve.FIELD`` of
        its ``SolveOptions``; ``VALUE`` parsed as JSON, else taken as a string.

    Returns
    -------
    InvertOptions

    Raises
    ------
    ValueError
        A setting without ``=``, an unknown name (the message lists the known ones), or a
        value of the wrong type or outside a field's choices.

    Examples
    --------
    >>> opts = with_overrides(InvertOptions(), ["line_phi_smooth=1e6", "solve.max_vertices=null"])
    >>> opts.line_phi_smooth, opts.solve.max_vertices
    (1000000.0, None)
    """
    top_hints = typing.get_type_hints(InvertOptions)
    solve_hints = typing.get_type_hints(SolveOptions)
    top: dict[str, Any] = {}
    solve: dict[str, Any] = {}
    for item in settings:
        name, sep, text = item.partition("=")
        name = name.strip()
        if not sep or not name:
            raise ValueError(f"--set needs NAME=VALUE, got {item!r}")
        value = _parse(text.strip())
        if name.startswith("solve.") and name[6:] in solve_hints:
            solve[name[6:]] = _coerce(name, solve_hints[name[6:]], value)
        elif name in top_hints and name != "solve":
            top[name] = _coerce(name, top_hints[name], value)
        else:
            raise ValueError(
                f"unknown option {name!r}; the options are: {', '.join(option_names())}"
            )
    new_solve = dataclasses.replace(options.solve, **solve)
    return dataclasses.replace(options, **top, solve=new_solve)
