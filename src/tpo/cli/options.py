"""Command-line flags generated from documented dataclasses, as CleanRL's ``Args``:
each field is declared once, with the docstring under it, and becomes a flag
(``num_envs`` -> ``--num-envs``) whose help is that docstring.

Flags are read as text and converted here, so a bad value is one
``tpo: error:`` line like every other mistake; the dataclass then checks the
value's range. A field's ``metadata`` may name its ``choices`` and ``metavar``.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
import textwrap
import types
import typing
from collections.abc import Callable, Collection
from itertools import pairwise
from typing import Any

from tpo.errors import TPOError


class UsageError(TPOError):
    """A bad command-line argument."""


def field_docs(cls: type) -> dict[str, str]:
    """The docstring under each field of the dataclass ``cls``, on one line."""
    body = ast.parse(textwrap.dedent(inspect.getsource(cls))).body[0].body
    docs = {}
    for node, after in pairwise(body):
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) \
                and isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant) \
                and isinstance(after.value.value, str):
            docs[node.target.id] = " ".join(after.value.value.split())
    return docs


def flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def add_fields(parser: argparse.ArgumentParser, cls: type, title: str,
               skip: Collection[str] = (), groups: dict[str, Collection[str]] | None = None
               ) -> None:
    """One flag per documented field of ``cls`` (not in ``skip``), in a group
    ``title`` (or, with ``groups``, in the group ``title: NAME`` that lists the
    field); unset flags stay ``None`` (the config file or the default decides)."""
    named = {name: g for g, names in (groups or {}).items() for name in names}
    made: dict[str, argparse._ArgumentGroup] = {}
    hints, docs = typing.get_type_hints(cls), field_docs(cls)
    for f in dataclasses.fields(cls):
        if f.name in skip:
            continue
        heading = f"{title}: {named[f.name]}" if f.name in named else title
        group = made.get(heading) or made.setdefault(heading,
                                                     parser.add_argument_group(heading))
        if f.name not in docs:
            raise TypeError(f"{cls.__name__}.{f.name} has no docstring")
        default = f.default_factory() if f.default is dataclasses.MISSING else f.default
        shown = ",".join(map(str, default)) if isinstance(default, tuple) else default
        help_text = f"{docs[f.name]} (default {shown if shown not in ('', None) else 'none'})"
        help_text = help_text.replace("%", "%%")  # argparse formats help with %
        if hints[f.name] is bool:
            group.add_argument(flag(f.name), action=argparse.BooleanOptionalAction,
                               default=None, help=help_text)
        else:
            group.add_argument(flag(f.name), default=None, metavar=_metavar(f, hints[f.name]),
                               help=help_text)


def read_fields(args: argparse.Namespace, cls: type, skip: Collection[str] = ()
                ) -> dict[str, Any]:
    """The fields of ``cls`` given on the command line, converted to their types."""
    hints = typing.get_type_hints(cls)
    given = {}
    for f in dataclasses.fields(cls):
        value = getattr(args, f.name, None)
        if f.name in skip or value is None:
            continue
        given[f.name] = value if isinstance(value, bool) else _convert(f, hints[f.name], value)
    return given


def _convert(f: dataclasses.Field, hint: Any, text: str) -> Any:
    choices = f.metadata.get("choices")
    if choices is not None and text not in choices:
        raise UsageError(f"bad {flag(f.name)} '{text}': choose one of {', '.join(choices)}")
    try:
        return _parser(hint)(text)
    except ValueError:
        raise UsageError(f"bad {flag(f.name)} '{text}': expected "
                         f"{_type_name(hint).lower()}") from None


def _parser(hint: Any) -> Callable[[str], Any]:
    args = [a for a in typing.get_args(hint) if a is not types.NoneType]
    if typing.get_origin(hint) is tuple:
        item = _parser(args[0])
        return lambda text: tuple(item(v.strip()) for v in text.split(","))
    if typing.get_origin(hint) in (types.UnionType, typing.Union):
        if len(args) == 1:
            return _parser(args[0])
        return lambda text: _first_parse([_parser(a) for a in args], text)
    if hint is int:
        return int
    if hint is float:
        return float
    if hint is str:
        return _nonempty
    raise TypeError(f"no command-line parser for {hint}")


def _nonempty(text: str) -> str:
    if not text.strip():
        raise ValueError(text)
    return text.strip()


def _first_parse(parsers: list[Callable[[str], Any]], text: str) -> Any:
    for parse in parsers[:-1]:
        try:
            return parse(text)
        except ValueError:
            continue
    return parsers[-1](text)


def _metavar(f: dataclasses.Field, hint: Any) -> str:
    if "metavar" in f.metadata:
        return f.metadata["metavar"]
    if "choices" in f.metadata:
        return "{" + ",".join(f.metadata["choices"]) + "}"
    return _type_name(hint)


def _type_name(hint: Any) -> str:
    args = [a for a in typing.get_args(hint) if a is not types.NoneType]
    if typing.get_origin(hint) is tuple:
        return f"{_type_name(args[0])},..."
    if typing.get_origin(hint) in (types.UnionType, typing.Union):
        return "|".join(_type_name(a) for a in args)
    return {int: "INT", float: "NUMBER", str: "TEXT"}[hint]
