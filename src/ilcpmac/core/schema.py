"""The one schema kit: fields declared once, parsed from TOML, checked, written back as TOML or JSON.

A field of a frozen dataclass is declared with `param` (its check, its one-line doc, whether it is one of a
sum of sines' parallel lists) or `setting` (the same with a default). From that declaration come:

- parsing: `parse_section` builds the dataclass from a TOML table, coercing each value to the field's type
  (`coerce_value`) and refusing unknown, missing, mistyped and out-of-range keys with one line naming the
  file, table and key (the field's doc quoted);
- checking: `section_problem` (and `value_problem`, `lengths_problem`) check an object built in code;
- writing: `section_toml` writes a dataclass as the TOML table it was read from, `toml_text` a dict of
  tables, both through `toml_value`; `finite_json` makes values JSON, and `unique_keys` refuses a JSON
  object that gives a key twice.

Why our own kit and not pydantic, msgspec or cattrs: benchmarks/schema_kits.py measures it.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
import reprlib
import tomllib
import types
import typing
from dataclasses import Field, field, fields
from pathlib import Path
from typing import Callable

import numpy as np

from ilcpmac.core.errors import ConfigError, IlcpmacError
from ilcpmac.core.files import read_bounded

__all__ = ["MAX_TOML_BYTES", "all_of", "coerce_value", "config_key", "field_like", "finite_json", "finite_number",
           "in_range", "key_table", "length_in", "lengths_problem", "param", "parse_section", "read_toml",
           "section_problem", "section_toml", "setting", "shown", "toml_name", "toml_text", "toml_value", "unique_keys",
           "unknown_key", "value_problem"]

#: Largest TOML file read (a campaign config, bench.toml, scan.toml, a mapping or a sweep spec), bytes.
MAX_TOML_BYTES = 2**20

_SHORT = reprlib.Repr()
_SHORT.maxstring = _SHORT.maxother = 60
_SHORT.maxlist = _SHORT.maxtuple = 8

#: a check: True when a value is acceptable
Check = Callable[[typing.Any], bool]


def shown(value: object) -> str:
    """``repr(value)`` cut short, a tuple shown as the TOML list it was read from, for one-line errors."""
    return _SHORT.repr(list(value) if isinstance(value, tuple) else value)


def finite_number(x: object) -> bool:
    """A real number (not a bool), finite and within the range of a float (a larger integer is not)."""
    if isinstance(x, bool) or not isinstance(x, (int, float, np.integer, np.floating)):
        return False
    try:
        return math.isfinite(x)
    except OverflowError:
        return False


def in_range(low: float, high: float, *, low_open: bool = False, high_open: bool = False) -> Check:
    """A check: the value (or every value of a list) lies in [low, high], without an end that is open.

    NaN fails every comparison, so it is out of every range.
    """
    def check(x: typing.Any) -> bool:
        values = tuple(x) if isinstance(x, (tuple, list, np.ndarray)) else (x,)
        return all((low < v if low_open else low <= v) and (v < high if high_open else v <= high)
                   for v in values)

    return check


def length_in(low: int, high: int) -> Check:
    """A check: a list of ``low`` to ``high`` values."""
    return lambda x: low <= len(x) <= high


def all_of(*checks: Check) -> Check:
    """A check that passes when every one of ``checks`` does (in order, so a length check guards the rest)."""
    return lambda x: all(check(x) for check in checks)


def param(check: Check | None = None, doc: str = "", *, parallel: bool = False, commented: bool = False,
          **kw: typing.Any) -> typing.Any:
    """A dataclass field with its ``check`` and one-line ``doc`` (quoted by every error about it).

    ``parallel``: one of the lists that describe a sum of sines together (orders, amplitudes, phases): the
    parallel lists of one object must have equal lengths (`lengths_problem`). ``commented``: `section_toml`
    writes the doc after the value, as a comment. ``kw`` go to `dataclasses.field`.
    """
    return field(metadata={"check": check, "doc": doc, "parallel": parallel, "commented": commented}, **kw)


def setting(check: Check | None, doc: str, default: typing.Any, *, commented: bool = False) -> typing.Any:
    """A field of an optional config key: `param` with its ``default``."""
    return param(check, doc, default=default, commented=commented)


def field_like(cls: type, name: str, **kw: typing.Any) -> typing.Any:
    """A dataclass field checked and documented as field ``name`` of dataclass ``cls``."""
    (like,) = [f for f in fields(cls) if f.name == name]
    return field(metadata=like.metadata, **kw)


def value_problem(f: Field[typing.Any], value: object) -> str | None:
    """``"key: invalid value ... (doc)"`` if field ``f``'s check refuses ``value``, else None.

    None is the value of an optional field left out.
    """
    check = f.metadata.get("check")
    if check is None or (value is None and f.default is None) or check(value):
        return None
    return f"{f.name}: invalid value {shown(value)} ({f.metadata.get('doc', '')})"


def lengths_problem(obj: typing.Any) -> str | None:
    """``"a, b: must have equal lengths ..."`` if the parallel lists of dataclass ``obj`` differ, else None."""
    lengths = {f.name: len(getattr(obj, f.name)) for f in fields(obj)
               if f.metadata.get("parallel") and isinstance(getattr(obj, f.name), tuple)}
    if len(set(lengths.values())) > 1:
        return f"{', '.join(lengths)}: must have equal lengths, got {lengths}"
    return None


def config_key(table: str, key: str) -> str:
    """``"[table] key"``: how a message names a key (a reader may name it otherwise)."""
    return f"[{table}] {key}"


def section_problem(table: str, obj: typing.Any, name: Callable[[str, str], str] = config_key) -> str | None:
    """The first field of dataclass ``obj`` out of its range, or its unequal parallel lists, as "[table] ...".

    ``name(table, key)`` names a key in the message.
    """
    for f in fields(obj):
        problem = value_problem(f, getattr(obj, f.name))
        if problem is not None:
            return f"{name(table, f.name)}{problem.removeprefix(f.name)}"
    problem = lengths_problem(obj)
    return None if problem is None else f"{name(table, '')}{problem}"


# ---------------------------------------------------------------- reading TOML


def coerce_value(value: typing.Any, annotation: typing.Any, where: str,
                 error: type[IlcpmacError] = ConfigError) -> typing.Any:
    """``value`` from TOML as the type ``annotation`` names (ints as floats, lists as tuples); ``error``
    naming ``where`` for any other type."""
    origin = typing.get_origin(annotation)
    if origin in (typing.Union, types.UnionType):
        (annotation,) = [a for a in typing.get_args(annotation) if a is not type(None)]
        return coerce_value(value, annotation, where, error)
    if origin is tuple:
        (item,) = {a for a in typing.get_args(annotation) if a is not Ellipsis}
        if not isinstance(value, list):
            raise error(f"{where}: expected a list, got {shown(value)}")
        return tuple(coerce_value(v, item, where, error) for v in value)
    if annotation is bool:
        if not isinstance(value, bool):
            raise error(f"{where}: expected true or false, got {shown(value)}")
        return value
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise error(f"{where}: expected an integer, got {shown(value)}")
        return value
    if annotation is float:
        if not finite_number(value):
            raise error(f"{where}: expected a finite number, got {shown(value)}")
        return float(value)
    if annotation is str:
        if not isinstance(value, str):
            raise error(f"{where}: expected a string, got {shown(value)}")
        return value
    raise TypeError(f"unsupported config type {annotation}")  # a programming error, not user input


def unknown_key(table: dict[str, typing.Any], known: typing.Iterable[str]) -> str | None:
    """``"unknown key 'k' (known: a, b)"`` for the first key of ``table`` (sorted) not in ``known``, else None."""
    unknown = sorted(set(table) - set(known))
    return f"unknown key {shown(unknown[0])} (known: {', '.join(known)})" if unknown else None


def toml_name(key: str) -> str:
    """A table or key name as a message shows it: bare if TOML allows, else quoted and cut short."""
    return key if re.fullmatch(r"[A-Za-z0-9_-]{1,60}", key) else shown(key)


def parse_section(table: object, cls: type, source: str, section: str, given: dict[str, typing.Any] | None = None,
                  error: type[IlcpmacError] = ConfigError, label: str | None = None,
                  sources: typing.Mapping[str, str] | None = None) -> typing.Any:
    """Build dataclass ``cls`` from TOML ``table``; every error (an ``error``) names ``source`` and the key.

    A field whose metadata names a ``"table"`` class is the optional sub-table
    ``[section.field]``; the fields in ``given`` take its values and are not read.
    ``label`` names the table in messages (default ``"[section]"``; e.g. ``"[[trials]] #2"``).
    ``sources`` names, by dotted name (``"section.key"``, ``"section"`` for the table itself), where a table
    or key came from when not from ``source`` (a config's keys from one it extends); an error about it names
    that instead. An empty ``source`` names none (a stage's options, which its caller names the file of).
    """
    label = label or f"[{section}]"
    sources = sources or {}
    if not isinstance(table, dict):
        raise error(f"{_at(sources.get(section, source))}{label} must be a table")
    given = given or {}
    hints = typing.get_type_hints(cls)
    known = {f.name: f for f in fields(cls) if f.name not in given and f.init}
    unknown = sorted(set(table) - set(known))
    renamed = getattr(cls, "RENAMED", {})
    if unknown:
        from_ = sources.get(f"{section}.{unknown[0]}", source)
        if unknown[0] in renamed:
            raise error(f"{_at(from_)}{label} {unknown[0]} is now {renamed[unknown[0]]}")
        raise error(f"{_at(from_)}{label} {unknown_key(table, known)}")
    values = dict(given)
    for name, f in known.items():
        from_ = sources.get(f"{section}.{name}", source)
        if "table" in f.metadata:
            values[name] = (parse_section(table[name], f.metadata["table"], source, f"{section}.{name}",
                                          error=error, sources=sources) if name in table else None)
            continue
        if name not in table:
            if f.default is not dataclasses.MISSING:
                values[name] = f.default
                continue
            raise error(f"{_at(source)}{label} {name}: missing ({f.metadata.get('doc', '')})")
        values[name] = coerce_value(table[name], hints[name], f"{_at(from_)}{label} {name}", error)
        problem = value_problem(f, values[name])
        if problem is not None:
            raise error(f"{_at(from_)}{label} {problem}")
    obj = cls(**values)
    problem = lengths_problem(obj)
    if problem is not None:
        raise error(f"{_at(source)}{label} {problem}")
    return obj


def _at(source: str) -> str:
    """``source`` as a message begins with it: "FILE: ", or nothing for none."""
    return f"{source}: " if source else ""


def read_toml(path: Path, error: type[IlcpmacError] = ConfigError) -> dict[str, typing.Any]:
    """Read a TOML file of at most `MAX_TOML_BYTES`; anything else raises ``error`` naming it.

    A folder, FIFO or device is refused: the file is opened without blocking
    and checked to be a regular file before a byte is read. A file that is
    too large, not UTF-8 or nested too deeply for the parser is refused too.
    """
    raw = read_bounded(path, MAX_TOML_BYTES, error)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        line = raw.count(b"\n", 0, e.start) + 1
        raise error(f"{path}: line {line}: not UTF-8 text (byte {raw[e.start]:#04x})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise error(f"{path}: not valid TOML ({e})") from None
    except RecursionError:
        raise error(f"{path}: not valid TOML (nested too deeply)") from None


# ---------------------------------------------------------------- writing TOML and JSON


def toml_value(value: typing.Any) -> str:
    """``value`` as TOML: a bool, string, integer, float, list (a tuple or array too) or inline table."""
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, str):
        # JSON's escapes of a string are TOML's, but for DEL, which TOML wants escaped too
        return json.dumps(value, ensure_ascii=False).replace("\x7f", "\\u007f")
    if isinstance(value, (list, tuple, np.ndarray)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{toml_key(k)} = {toml_value(v)}" for k, v in value.items()) + "}"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    return repr(float(value))


def toml_key(key: str) -> str:
    """A key as TOML: bare where TOML allows, else quoted."""
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else toml_value(key)


def toml_text(data: dict[str, typing.Any], prefix: str = "") -> str:
    """TOML text of ``data`` (tables of tables, scalars and lists), as `tomllib` reads it back."""
    lines = [f"{toml_key(k)} = {toml_value(v)}" for k, v in data.items() if not isinstance(v, dict)]
    for k, v in data.items():
        if isinstance(v, dict):
            name = f"{prefix}{toml_key(k)}"
            lines += ["", f"[{name}]", toml_text(v, f"{name}.")]
    return "\n".join(line for line in lines if line) + "\n"


def section_toml(obj: typing.Any) -> str:
    """The lines of dataclass ``obj`` as the TOML table `parse_section` reads it from: every field without a
    default, and every other one whose value is not its default; a ``commented`` field's doc follows its
    value as a comment."""
    lines = []
    for f in fields(obj):
        value = getattr(obj, f.name)
        if f.default is dataclasses.MISSING or value != f.default:
            comment = f"  # {f.metadata['doc']}" if f.metadata.get("commented") else ""
            lines.append(f"{toml_key(f.name)} = {toml_value(value)}{comment}\n")
    return "".join(lines)


def _type_name(annotation: typing.Any) -> str:
    """A field's type as a config's reader knows it: number, integer, string, true/false, a list of one."""
    origin = typing.get_origin(annotation)
    if origin in (typing.Union, types.UnionType):
        (inner,) = [a for a in typing.get_args(annotation) if a is not type(None)]
        return _type_name(inner)
    if origin is tuple:
        (item,) = {a for a in typing.get_args(annotation) if a is not Ellipsis}
        return f"list of {_type_name(item)}s"
    return {int: "integer", float: "number", str: "string", bool: "true/false"}.get(annotation, str(annotation))


def key_table(cls: type, table: str, given: typing.Iterable[str] = (), heading: str | None = None) -> str:
    """A Markdown table of the keys of TOML table ``[table]`` that dataclass ``cls`` declares: key, type,
    default ("required" where there is none) and the field's doc; the fields in ``given`` are left out
    (another table gives them), and so is a sub-table field. ``heading`` replaces the heading
    ``### [table]`` (keys outside any table)."""
    hints = typing.get_type_hints(cls)
    rows = [heading or f"### [{table}]", "", "| key | type | default | meaning |", "|---|---|---|---|"]
    for f in fields(cls):
        if f.name in given or "table" in f.metadata or not f.init:
            continue
        default = ("required" if f.default is dataclasses.MISSING
                   else "left out" if f.default is None else f"`{toml_value(f.default)}`")
        doc = f.metadata.get("doc", "").replace("|", "\\|")
        rows.append(f"| `{f.name}` | {_type_name(hints[f.name])} | {default} | {doc} |")
    return "\n".join(rows) + "\n"


def unique_keys(pairs: list[tuple[str, typing.Any]]) -> dict[str, typing.Any]:
    """A JSON object from its ``pairs`` (``json.loads(..., object_pairs_hook=unique_keys)``); a key given twice
    raises ValueError naming it, where `json.loads` would keep the last silently."""
    data: dict[str, typing.Any] = {}
    for key, value in pairs:
        if key in data:
            raise ValueError(f"key {shown(key)} given twice")
        data[key] = value
    return data


def finite_json(value: typing.Any) -> typing.Any:
    """``value`` (dicts, lists and numbers) with every NaN and infinity made None: JSON has no such numbers."""
    if isinstance(value, dict):
        return {k: finite_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_json(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
