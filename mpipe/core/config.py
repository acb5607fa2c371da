"""Loading YAML into validated frozen dataclasses.

A configuration class is a frozen dataclass whose fields carry their unit, meaning and
check in ``dataclasses.field(metadata=...)``: keys ``unit``, ``doc`` and ``check``
(a callable returning an error message or ``None``). :func:`build` walks the YAML mapping
against the type hints, and every problem becomes a :class:`ConfigError` naming the file,
the key path and what was expected. A class may name keys and choices it no longer has in
``removed_keys`` (key -> what became of it) and ``removed_choices`` (key -> {choice -> what
to use}); such a key gets that message instead of "unknown key". A class may spell a field
otherwise in files with ``file_keys`` (field -> key): only that key is accepted, and errors
name and offer it. A class may define
``_check(self, where)`` for checks across fields; it raises through
``where.error(key, message)``.

Supported field types: ``float``, ``int``, ``str``, ``bool``, ``X | None``, ``Literal``,
nested configuration dataclasses and ``tuple[X, ...]`` of any of these.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
import textwrap
import types
import typing
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import yaml

_YAML11_FLOAT = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+")


class ConfigError(ValueError):
    """A configuration file or mapping does not describe a valid set-up."""


@dataclasses.dataclass(frozen=True)
class Where:
    """Position inside a configuration source, for error messages.

    Attributes
    ----------
    source : str
        File name (or another description of where the mapping came from).
    path : str
        Dotted key path inside it, e.g. ``bore.segments[1].radius``.
    """

    source: str
    path: str = ""

    def child(self, key: str | int) -> Where:
        """Return the position of a key or list index below this one."""
        if isinstance(key, int):
            return Where(self.source, f"{self.path}[{key}]")
        return Where(self.source, f"{self.path}.{key}" if self.path else key)

    def error(self, key: str | None, message: str) -> ConfigError:
        """Build an error for ``key`` below this position (or for this position itself)."""
        where = self.child(key) if key else self
        return ConfigError(f"{where.source}: {where.path or '<top level>'}: {message}")


def spec(unit: str = "", doc: str = "", check: Callable[[Any], str | None] | None = None, **kwargs):
    """Declare a configuration field with its unit, meaning and check.

    Parameters
    ----------
    unit : str
        SI unit of the value ("" for dimensionless or non-numeric).
    doc : str
        One-line meaning, shown by ``mpipe config`` and docs/settings.md.
    check : callable, optional
        ``check(value) -> message | None``.
    **kwargs
        Passed to :func:`dataclasses.field` (``default``, ``default_factory``).
    """
    return dataclasses.field(metadata={"unit": unit, "doc": doc, "check": check}, **kwargs)


def between(lo: float, hi: float, what: str = "") -> Callable[[float], str | None]:
    """Check that a number lies in ``[lo, hi]``; ``what`` hints at the likely mistake."""

    def check(value: float) -> str | None:
        if not lo <= value <= hi:
            hint = f" ({what})" if what else ""
            return f"expected a value in [{lo:g}, {hi:g}], got {value:g}{hint}"
        return None

    return check


def positive(value: float) -> str | None:
    """Check that a number is strictly positive."""
    return None if value > 0 else f"expected a positive value, got {value:g}"


class _DuplicateKey(Exception):
    """A mapping gives one key twice (raised inside the loader, named by :func:`parse_yaml`)."""

    def __init__(self, key, first_line: int, second_line: int):
        super().__init__(key, first_line, second_line)
        self.key, self.first_line, self.second_line = key, first_line, second_line


class _UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing a key given twice in one mapping.

    PyYAML keeps the last of two equal keys without a word: a fingering listed twice
    plays the wrong bore, a second ``inversion:`` section wipes the first. Keys brought in
    by a merge (``<<: *anchor``) may be overridden, as YAML intends.
    """

    def construct_mapping(self, node, deep=False):
        seen: dict = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue
            key = self.construct_object(key_node, deep=True)
            line = key_node.start_mark.line + 1
            try:
                if key in seen:
                    raise _DuplicateKey(key, seen[key], line)
                seen[key] = line
            except TypeError:  # an unhashable key: the base loader says so
                continue
        return super().construct_mapping(node, deep)


def parse_yaml(text: str, source: str) -> Any:
    """Parse YAML text, refusing a key given twice in one mapping.

    The one YAML parser of mpipe: pipeline, calibration, reed, score and sidecar files
    all go through it (:func:`load_yaml`).

    Parameters
    ----------
    text : str
        The YAML document.
    source : str
        Where it came from (a file name), for error messages.

    Returns
    -------
    Any
        The parsed value.

    Raises
    ------
    ConfigError
        ``"{source}: key 'k' given twice (lines 3 and 9)"``, or naming the syntax error.
    """
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 - a SafeLoader subclass
    except _DuplicateKey as dup:
        lines = (
            f"line {dup.first_line}"
            if dup.first_line == dup.second_line
            else f"lines {dup.first_line} and {dup.second_line}"
        )
        raise ConfigError(f"{source}: key {dup.key!r} given twice ({lines}); keep one") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{source}: not valid YAML: {exc}") from None


def load_yaml(path: str | Path) -> Mapping:
    """Read a YAML file that must hold a mapping, with errors naming the file.

    Raises
    ------
    ConfigError
        When the file cannot be read, is not YAML, gives a key twice in one mapping
        (naming the key and its lines) or does not hold a mapping.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read configuration file: {exc.strerror}") from None
    except UnicodeDecodeError:
        # an audio file or another binary where a YAML file belongs (arguments swapped)
        raise ConfigError(
            f"{path}: expected a YAML text file here, got binary data (are the arguments in "
            "the right order?)"
        ) from None
    data = parse_yaml(text, str(path))
    if not isinstance(data, Mapping):
        raise ConfigError(f"{path}: expected a mapping of keys at the top level")
    return data


def build(cls: type, data: Any, where: Where):
    """Build the configuration dataclass ``cls`` from a parsed YAML value.

    Parameters
    ----------
    cls : type
        A frozen dataclass declared with :func:`spec` fields.
    data : Any
        The parsed YAML value (must be a mapping).
    where : Where
        Its position, for error messages.

    Returns
    -------
    cls
        The validated instance.

    Raises
    ------
    ConfigError
        Naming the file, key path and what was expected.
    """
    if not isinstance(data, Mapping):
        raise where.error(None, f"expected a mapping, got {_describe(data)}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    # a field spelt otherwise in files (a note's ``lambda`` is the field ``lam``): errors
    # name and offer the file's spelling, the only one accepted
    file_keys = getattr(cls, "file_keys", {})
    field_of = {file_keys.get(n, n): n for n in fields}
    unknown = [k for k in data if k not in field_of]
    removed = getattr(cls, "removed_keys", {})
    gone = [k for k in unknown if k in removed]
    if len(gone) == 1:
        why = removed[gone[0]]
        raise where.error(str(gone[0]), f"removed from mpipe: {why}; delete this key")
    if gone:
        # an earlier mpipe's full pipeline file holds several: name them all at once
        raise where.error(
            None,
            f"{', '.join(map(str, gone))}: removed from mpipe; delete these keys "
            "(what became of each: docs/settings.md, Removed settings)",
        )
    if unknown:
        keys = sorted(
            file_keys.get(n, n) for n, f in fields.items() if not f.metadata.get("derived")
        )
        close = difflib.get_close_matches(str(unknown[0]), keys, n=1)
        hint = f" (did you mean {close[0]}?)" if close else ""
        raise where.error(str(unknown[0]), f"unknown key{hint}; expected one of: {', '.join(keys)}")
    data = {field_of[k]: v for k, v in data.items()}
    values = {}
    for name, f in fields.items():
        if name not in data:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise where.error(file_keys.get(name, name), "missing required key")
            continue
        child = where.child(file_keys.get(name, name))
        retired = getattr(cls, "removed_choices", {}).get(name, {})
        if isinstance(data[name], str) and data[name] in retired:
            why = retired[data[name]]
            raise child.error(None, f"{data[name]!r} was removed from mpipe: {why}")
        value = _convert(hints[name], data[name], child)
        check = f.metadata.get("check")
        if check is not None and value is not None:
            message = check(value)
            if message:
                unit = f.metadata.get("unit")
                raise child.error(None, message + (f" [{unit}]" if unit else ""))
        values[name] = value
    obj = cls(**values)
    hook = getattr(obj, "_check", None)
    if hook is not None:
        hook(where)
    return obj


def _convert(tp: Any, value: Any, where: Where):
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        if len(inner) == 1:
            return _convert(inner[0], value, where)
        errors = []
        for a in inner:
            try:
                return _convert(a, value, where)
            except ConfigError as exc:
                errors.append(str(exc))
        raise where.error(None, f"value {value!r} matches none of the allowed forms")
    if origin is typing.Literal:
        if value not in args:
            choices = ", ".join(repr(a) for a in args)
            raise where.error(None, f"expected one of {choices}, got {value!r}")
        return value
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise where.error(None, f"expected a list, got {_describe(value)}")
        return tuple(_convert(args[0], v, where.child(i)) for i, v in enumerate(value))
    if dataclasses.is_dataclass(tp):
        return build(tp, value, where)
    if tp is float:
        if isinstance(value, str) and _YAML11_FLOAT.fullmatch(value.strip()):
            # PyYAML follows YAML 1.1, where 8.66e6 (no dot, no exponent sign) is a string
            value = float(value)
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise where.error(None, f"expected a number, got {_describe(value)}")
        if not math.isfinite(value):
            raise where.error(None, f"expected a finite number, got {value!r}")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise where.error(None, f"expected an integer, got {_describe(value)}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise where.error(None, f"expected true or false, got {_describe(value)}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise where.error(None, f"expected a string, got {_describe(value)}")
        return value
    raise TypeError(f"configuration type {tp!r} is not supported")  # programming error


def _describe(value: Any) -> str:
    if value is None:
        return "nothing (null)"
    if isinstance(value, str):
        return f"the string {value!r}"
    if isinstance(value, Mapping):
        return "a mapping"
    if isinstance(value, list):
        return "a list"
    return f"{type(value).__name__} {value!r}"


@dataclasses.dataclass(frozen=True)
class Setting:
    """One key of a configuration class, as documentation shows it.

    Attributes
    ----------
    key : str
        Key path, e.g. ``inversion.bounds.k`` (``[]`` marks the items of a list of sections).
    unit : str
        SI unit ("" for dimensionless or non-numeric).
    doc : str
        One-line meaning.
    default : Any
        Default value; :data:`dataclasses.MISSING` for a required key, and for a section.
    section : bool
        True for a key holding a nested configuration class (its keys follow it).
    """

    key: str
    unit: str
    doc: str
    default: Any
    section: bool


def settings_of(cls: type, prefix: str = "") -> list[Setting]:
    """Every key of a configuration class, sections followed by their keys, in order.

    Fields set by a loader from another key (metadata ``derived``) are left out.
    """
    rows = []
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if f.metadata.get("derived"):
            continue  # set by the loader from another key, documented there
        key = f"{prefix}{f.name}"
        tp = hints[f.name]
        inner = [a for a in (typing.get_args(tp) or (tp,)) if dataclasses.is_dataclass(a)]
        default = dataclasses.MISSING if inner else _default(f)
        unit, doc = f.metadata.get("unit", ""), f.metadata.get("doc", "")
        rows.append(Setting(key, unit, doc, default, bool(inner)))
        if inner:
            sub = "[]." if typing.get_origin(tp) is tuple else "."
            rows.extend(settings_of(inner[0], key + sub))
    return rows


def describe_keys(cls: type, prefix: str = "") -> list[tuple[str, str, str]]:
    """List ``(key path, unit, meaning)`` for every key of a configuration class.

    Used to document configuration files from the code that reads them.
    """
    return [(s.key, s.unit, s.doc) for s in settings_of(cls, prefix)]


def _default(f: dataclasses.Field) -> Any:
    """A field's default value (:data:`dataclasses.MISSING` when it has none)."""
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return dataclasses.MISSING


def yaml_scalar(value: Any) -> str:
    """One scalar or flat list in YAML that PyYAML (YAML 1.1) reads back unchanged."""
    if isinstance(value, tuple | list):
        return "[" + ", ".join(yaml_scalar(v) for v in value) + "]"
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        text = repr(value)
        if value != 0 and not 1e-3 <= abs(value) < 1e5:
            # scientific notation for very large and small values, if it reads back exactly
            mantissa, exponent = f"{value:.14e}".split("e")
            mantissa = mantissa.rstrip("0")
            short = (
                f"{mantissa}0e{int(exponent):+03d}"
                if mantissa.endswith(".")
                else (f"{mantissa}e{int(exponent):+03d}")
            )
            text = short if float(short) == value else text
        # YAML 1.1 reads 1e-05 as a string: it needs a dot in the mantissa
        if "e" in text and "." not in text.split("e")[0]:
            mantissa, exponent = text.split("e")
            text = f"{mantissa}.0e{exponent}"
        return text
    if isinstance(value, int):
        return str(value)
    return yaml.safe_dump(value, default_flow_style=True).strip().removesuffix("\n...").strip()


def to_commented_yaml(
    obj: Any,
    indent: int = 0,
    skip: tuple[str, ...] = (),
    width: int = 96,
    show: Callable[[str, bool], bool] | None = None,
    prefix: str = "",
) -> str:
    """Write a configuration dataclass as YAML, each key commented with unit and meaning.

    Every field is written (defaults included) unless ``show`` says otherwise; a value that
    differs from the default says so in its comment. :func:`build` reads the text back into
    an equal object when every key left out holds its default.

    Parameters
    ----------
    obj : dataclass instance
        A configuration object declared with :func:`spec` fields.
    indent : int
        Indentation of the top-level keys, in spaces.
    skip : tuple of str
        Top-level field names to leave out (e.g. fields set by a loader).
    width : int
        Comment lines are wrapped to this many characters.
    show : callable, optional
        ``show(key path, changed) -> bool`` picks the keys written, given the dotted path
        (``inversion.bounds.k``) and whether the value differs from its default; a section
        is written when one of its keys is. Default: every key.
    prefix : str
        Key path of ``obj`` itself, ending in a dot ("" at the top level).

    Returns
    -------
    str
        The YAML text ("" when ``show`` picks no key).
    """
    pad = " " * indent
    lines: list[str] = []
    hints = typing.get_type_hints(type(obj))
    for f in dataclasses.fields(obj):
        if f.name in skip or not f.init or f.metadata.get("derived"):
            continue  # a derived field is set by the loader from another key
        value, key = getattr(obj, f.name), prefix + f.name
        unit, doc = f.metadata.get("unit", ""), f.metadata.get("doc", "")
        if dataclasses.is_dataclass(hints[f.name]) and dataclasses.is_dataclass(value):
            body = to_commented_yaml(value, indent + 2, (), width, show, key + ".")
            if body:
                lines.extend([""] if indent == 0 else [])
                lines.append(f"{pad}{f.name}:" + (f"  # {doc}" if doc else ""))
                lines.append(body.rstrip("\n"))
            continue
        default = _default(f)
        changed = default is dataclasses.MISSING or value != default
        if show is not None and not show(key, changed):
            continue
        note = f"[{unit}] {doc}" if unit else doc
        if default is not dataclasses.MISSING and changed:
            note += f" (default {yaml_scalar(default)})"
        if note:
            lines.extend(
                textwrap.wrap(
                    note, width - indent, initial_indent=f"{pad}# ", subsequent_indent=f"{pad}#   "
                )  # fmt: skip
            )
        lines.append(f"{pad}{f.name}: {yaml_scalar(value)}")
    return "\n".join(lines) + "\n" if lines else ""
