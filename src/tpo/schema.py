"""Tables read from files (``model.json``, env specs) checked against their keys and
the types of their values, with one line naming the first thing wrong."""

from __future__ import annotations

from typing import Any

from tpo.errors import TPOError

Number = int | float
NAMES = {str: "a string", bool: "true or false", int: "an integer", float: "a number",
         Number: "a number", list: "a list", dict: "a table"}


def check_table(table: Any, keys: dict[str, Any], what: str, also: tuple[str, ...] = ()
                ) -> None:
    """Raise :class:`TPOError` unless ``table`` is a dict with exactly ``keys`` (plus
    ``also``), each value of its type (``bool`` is not a number here). ``what``
    names the table in the message."""
    if not isinstance(table, dict):
        raise TPOError(f"{what} must be a table, got {type(table).__name__}")
    unknown = sorted(set(table) - set(keys) - set(also))
    if unknown:
        raise TPOError(f"{what} has unknown key {unknown[0]!r}")
    for key, kind in keys.items():
        if key not in table:
            raise TPOError(f"{what} lacks {key!r}")
        value = table[key]
        if (isinstance(value, bool) and kind is not bool) or not isinstance(value, kind):
            raise TPOError(f"{what}: {key} must be {NAMES.get(kind, kind)}, got {value!r:.60}")
