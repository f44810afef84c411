"""Config dataclasses set from text: ``FIELD=VALUE`` overrides (nested fields
with dots: ``tracker.relative_cost_tol=1e-4``) and TOML (or YAML, when PyYAML is
installed) files, applied to frozen or plain dataclass instances with
:func:`dataclasses.replace`; written back as TOML with each field's meaning
from its class's docstring as a comment (:func:`config_to_toml`,
:mod:`spgeo.config_docs`); and
:func:`config_class`, the decorator of the config dataclasses (field types checked at
construction, a ``repr`` of the fields that differ from the defaults).  The library
home of the command line's ``--set`` / ``--config`` / ``--dump-config``
(:mod:`spgeo.cli.config_args`); notebooks and evaluation scripts use it directly.

Every error is a :class:`ConfigError` (a ``ValueError``) with a one-line
message naming the offending field or file.
"""
from __future__ import annotations

import ast
import collections.abc
import dataclasses
import functools
import json
import logging
import numbers
import textwrap
import typing
from pathlib import Path
from typing import Any, Dict, Iterable, List, Mapping, Optional, Sequence, Union

import numpy as np

from .config_docs import field_meanings, short_meaning

__all__ = ["ConfigError", "ConfigTypeError", "UnknownFieldError", "check_field_types",
           "parse_value", "parse_assignments", "nest", "flatten", "apply_overrides",
           "own_section", "load_config_file", "config_to_dict", "config_to_toml",
           "resolve_config", "config_class", "changed_fields"]

log = logging.getLogger(__name__)

Overrides = Union[Mapping[str, Any], Iterable[str]]


class ConfigError(ValueError):
    """A bad ``--set`` / ``--config`` entry (unknown field, wrong type, unreadable file)."""


class ConfigTypeError(ConfigError, TypeError):
    """A field given a value of the wrong type (also a ``TypeError``)."""


class UnknownFieldError(ConfigError, TypeError):
    """A field the dataclass does not have (also a ``TypeError``, as
    :func:`dataclasses.replace` raises for an unexpected field)."""


def parse_value(text: str, strict: bool = False) -> Any:
    """A Python literal (``1e-4``, ``None``, ``(1, 2)``, ``'x'``, ``True``), a
    TOML boolean (``true`` / ``false``, any case: what a config file writes) or,
    when ``text`` is none of these, the stripped string itself (with ``strict``:
    ``ValueError`` / ``SyntaxError`` instead)."""
    s = text.strip()
    if s.lower() in ("true", "false"):
        return s.lower() == "true"
    try:
        return ast.literal_eval(s)
    except (ValueError, SyntaxError, MemoryError, RecursionError):
        if strict:
            raise
        return s


def parse_assignments(items: Iterable[str], strict: bool = False) -> Dict[str, Any]:
    """``["a=1", "b.c=x"]`` -> ``{"a": 1, "b.c": "x"}`` (dotted keys, values
    by :func:`parse_value` with ``strict``, later items win); ``ConfigError``
    for an item without ``=`` or with an empty field name."""
    out: Dict[str, Any] = {}
    for item in items:
        key, sep, val = str(item).partition("=")
        path = [k.strip() for k in key.split(".")]
        if not sep or not all(path):
            raise ConfigError(f"--set expects FIELD=VALUE (e.g. window=7), got {item!r}")
        out[".".join(path)] = parse_value(val, strict)
    return out


def nest(dotted: Mapping[str, Any]) -> Dict[str, Any]:
    """Dotted keys -> nested mapping: ``{"a.b": 1}`` -> ``{"a": {"b": 1}}``;
    ``ConfigError`` when a name is set both as a value and as a group."""
    out: Dict[str, Any] = {}
    for key, val in dotted.items():
        path = key.split(".")
        node = out
        for k in path[:-1]:
            node = node.setdefault(k, {})
            if not isinstance(node, dict):
                raise ConfigError(f"{k!r} is set both as a value and as a group")
        if isinstance(node.get(path[-1]), dict):
            raise ConfigError(f"{path[-1]!r} is set both as a value and as a group")
        node[path[-1]] = val
    return out


def flatten(mapping: Mapping[str, Any], prefix: str = "") -> Dict[str, Any]:
    """Nested mapping -> dotted keys: ``{"a": {"b": 1}}`` -> ``{"a.b": 1}``."""
    out: Dict[str, Any] = {}
    for key, val in mapping.items():
        name = f"{prefix}{key}"
        if isinstance(val, Mapping):
            out.update(flatten(val, name + "."))
        else:
            out[name] = val
    return out


def _as_dotted(overrides: Overrides) -> Dict[str, Any]:
    if isinstance(overrides, Mapping):
        return flatten(overrides)
    if isinstance(overrides, str):
        return parse_assignments([overrides])
    return parse_assignments(overrides)


@functools.lru_cache(maxsize=None)
def _class_hints(cls: type) -> Dict[str, Any]:
    """The resolved annotations of the dataclass ``cls`` (``{}`` when one cannot
    be resolved: no type information), once per class."""
    try:
        return typing.get_type_hints(cls)
    except Exception:       # unresolvable annotation: no type information
        return {}


def _allows_none(hint: Any) -> bool:
    if hint is None or hint is Any:
        return True
    return type(None) in typing.get_args(hint)


def _coerce(name: str, value: Any, current: Any, hint: Any) -> Any:
    """``value`` checked against the field's current value (and its annotation for None)."""
    def bad(expected: str) -> ConfigError:
        return ConfigError(f"field {name!r} expects {expected}, got {value!r}")

    if value is None:
        if current is None or _allows_none(hint):
            return None
        raise bad(f"a {type(current).__name__} (not None)")
    if current is None:
        return tuple(value) if isinstance(value, list) else value
    if isinstance(current, bool):
        if not isinstance(value, bool):
            raise bad("True or False")
        return value
    if isinstance(current, int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise bad("an integer")
        return value
    if isinstance(current, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise bad("a number")
        return float(value)
    if isinstance(current, str):
        if not isinstance(value, str):
            raise bad("a string")
        return value
    if isinstance(current, tuple):
        if not isinstance(value, (list, tuple)):
            raise bad("a tuple, e.g. (1, 2)")
        return tuple(value)
    return value


def _valid_fields(obj: Any, prefix: str = "") -> List[str]:
    out = []
    for f in dataclasses.fields(obj):
        sub = getattr(obj, f.name)
        if dataclasses.is_dataclass(sub) and not isinstance(sub, type):
            out.append(f"{prefix}{f.name}.*")
        else:
            out.append(f"{prefix}{f.name}")
    return out


def _set(obj: Any, path: Sequence[str], value: Any, done: str) -> Any:
    """``obj`` with the field at ``path`` replaced (recursively for nested dataclasses)."""
    name = path[0]
    full = f"{done}{name}"
    names = {f.name for f in dataclasses.fields(obj) if f.init}
    if name not in names:
        raise UnknownFieldError(f"unknown field {full!r} of {type(obj).__name__}; valid fields: "
                          f"{', '.join(_valid_fields(obj, done))}")
    current = getattr(obj, name)
    nested = dataclasses.is_dataclass(current) and not isinstance(current, type)
    hint = _class_hints(type(obj)).get(name)
    if len(path) > 1:
        if not nested:
            raise ConfigError(f"field {full!r} of {type(obj).__name__} has no sub-fields "
                              f"(cannot set {done}{'.'.join(path)})")
        new = _set(current, path[1:], value, full + ".")
    elif nested:
        if not isinstance(value, Mapping):
            raise ConfigError(f"field {full!r} is a {type(current).__name__}: set its "
                              f"sub-fields ({full}.FIELD=VALUE)")
        new = current
        for key, val in flatten(value).items():
            new = _set(new, key.split("."), val, full + ".")
    else:
        new = _coerce(full, value, current, hint)
    return _replace(obj, name, new, full)


def _replace(obj: Any, name: str, new: Any, full: str) -> Any:
    """``dataclasses.replace(obj, name=new)``; its errors as :class:`ConfigError` naming ``full``."""
    try:
        return dataclasses.replace(obj, **{name: new})
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{full}: {exc}") from None


def apply_overrides(config: Any, overrides: Overrides, route: Optional[str] = None) -> Any:
    """A copy of the dataclass instance ``config`` with ``overrides`` applied.

    Args:
        config: a dataclass instance (nested dataclass fields are reached with
            dotted names).
        overrides: ``["field=value", "sub.field=value", ...]`` (values parsed
            by :func:`parse_value`) or a mapping, nested or with dotted keys
            (e.g. from :func:`load_config_file`).  Later entries win.
        route: name of a nested-dataclass field of ``config`` that receives
            every key whose first part is not a field of ``config`` (``vo``:
            ``"odometry"``, so ``window=7`` means ``odometry.window=7``); default
            the class's ``config_route`` (``VORunConfig``: ``"odometry"``), if any.

    A mapping written for an enclosing config (a ``spgeo vo`` file, with an
    ``[odometry]`` table, given to an ``OdometryConfig``) is first reduced to
    this config's part by :func:`own_section`.

    Values must match the field's current type (an int is accepted for a
    float field, a list for a tuple field; None only for optional fields).
    Raises ``ConfigError`` naming an unknown field and listing the valid ones.
    """
    if route is None:
        route = getattr(type(config), "config_route", None)
    if isinstance(overrides, Mapping):
        overrides = own_section(config, overrides)
    top = {f.name for f in dataclasses.fields(config)}
    out = config
    for key, value in _as_dotted(overrides).items():
        path = key.split(".")
        if route is not None and path[0] not in top:
            sub = getattr(config, route)
            if path[0] not in {f.name for f in dataclasses.fields(sub)}:
                raise UnknownFieldError(
                    f"unknown field {key!r}; valid fields: "
                    f"{', '.join(_valid_fields(config) + _valid_fields(sub))}")
            path = [route] + path
        out = _set(out, path, value, "")
    return out


def own_section(config: Any, data: Mapping[str, Any]) -> Mapping[str, Any]:
    """The part of ``data`` (a nested mapping, e.g. from :func:`load_config_file`)
    that is ``config``'s, for a class declaring ``config_section`` (``OdometryConfig``:
    ``"odometry"``) when ``data`` holds a table of that name that is not one of its
    fields: the keys of ``data`` that are ``config``'s fields, then that table
    (it wins).  The other keys belong to the enclosing config (``spgeo vo``'s run
    fields) and are left out, with an INFO log naming them.  Any other ``data``
    is returned as it is."""
    name = getattr(type(config), "config_section", None)
    fields = {f.name for f in dataclasses.fields(config)}
    if name is None or name in fields or not isinstance(data.get(name), Mapping):
        return data
    others = sorted(k for k in data if k != name and k not in fields)
    if others:
        log.info("%s reads the [%s] table; not its fields, left out: %s",
                 type(config).__name__, name, ", ".join(others))
    flat = {k: v for k, v in data.items() if k in fields}
    return {**flatten(flat), **flatten(data[name])}


def load_config_file(path: Union[str, Path]) -> Dict[str, Any]:
    """A ``.toml`` file (``tomllib``) or a ``.yaml`` / ``.yml`` file (PyYAML,
    if installed) -> its top-level table as a dict.  ``ConfigError`` for a
    missing or unparsable file, another suffix, or YAML without PyYAML."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"config file not found: {p}")
    suffix = p.suffix.lower()
    if suffix == ".toml":
        import tomllib

        try:
            data = tomllib.loads(p.read_text(encoding="utf-8"))
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise ConfigError(f"cannot parse {p}: {exc}") from None
    elif suffix in (".yaml", ".yml"):
        try:
            import yaml
        except ImportError:
            raise ConfigError(f"cannot read {p}: YAML needs PyYAML (pip install pyyaml); "
                              f"or write the config as TOML") from None
        try:
            data = yaml.safe_load(p.read_text(encoding="utf-8"))
        except (yaml.YAMLError, UnicodeDecodeError) as exc:
            raise ConfigError(f"cannot parse {p}: {' '.join(str(exc).split())}") from None
        data = {} if data is None else data
    else:
        raise ConfigError(f"config file {p} must end in .toml, .yaml or .yml")
    if not isinstance(data, dict):
        raise ConfigError(f"config file {p} must hold a table of FIELD = VALUE entries")
    return data


def config_to_dict(config: Any) -> Dict[str, Any]:
    """A dataclass instance as a JSON-ready nested dict (tuples become lists)."""
    def plain(v: Any) -> Any:
        if isinstance(v, dict):
            return {k: plain(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [plain(x) for x in v]
        return v

    return plain(dataclasses.asdict(config))


def resolve_config(config: Any, config_file: Optional[Union[str, Path]] = None,
                   sets: Sequence[str] = (), route: Optional[str] = None) -> Any:
    """``config`` with ``config_file`` (:func:`load_config_file`) and then
    ``sets`` (``FIELD=VALUE`` strings; they override the file) applied by
    :func:`apply_overrides`.  One file serves the command line and Python: a
    ``spgeo vo --dump-config`` file (run fields, ``[odometry]`` table) gives
    ``resolve_config(VORunConfig(), f)`` everything and ``resolve_config(
    OdometryConfig(), f)`` its ``[odometry]`` table; a file without tables gives
    a ``VORunConfig`` its fields and the odometry's (``config_route``)."""
    if config_file:
        config = apply_overrides(config, load_config_file(config_file), route)
    if sets:
        config = apply_overrides(config, list(sets), route)
    return config


def _toml_value(value: Any) -> str:
    """One TOML value (bool, number, string, array); ``TypeError`` for None or
    another type."""
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, numbers.Integral):
        return str(int(value))
    if isinstance(value, numbers.Real):
        return repr(float(value))       # 'inf', '-inf' and 'nan' are TOML too
    if isinstance(value, str):
        return json.dumps(value)        # a TOML basic string: JSON's escapes are TOML's
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"no TOML form for {value!r}")


def _meaning_lines(meanings: Mapping[str, str], name: str) -> List[str]:
    """The meaning of field ``name`` (:func:`~spgeo.config_docs.short_meaning`)
    as TOML comment lines of at most 88 characters; none when undocumented."""
    if name not in meanings:
        return []
    return [f"# {line}" for line in textwrap.wrap(short_meaning(meanings[name]), 86,
                                                  break_long_words=False,
                                                  break_on_hyphens=False)]


def _toml_lines(config: Any, table: str) -> List[str]:
    """``config``'s fields as TOML, each below its meaning: its values, then a
    ``[table.sub]`` per nested config."""
    lines: List[str] = []
    nested = []
    meanings = field_meanings(type(config))
    for f in dataclasses.fields(config):
        if not f.init:
            continue
        value = getattr(config, f.name)
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            nested.append((f.name, value))
            continue
        lines += _meaning_lines(meanings, f.name)
        try:
            lines.append(f"{f.name} = {_toml_value(value)}")
        except TypeError:
            lines.append(f"# {f.name} = {value!r}  (TOML cannot write it: leave the line out)")
    for name, sub in nested:
        path = f"{table}.{name}" if table else name
        lines += [""] + _meaning_lines(meanings, name) + [f"[{path}]"] + _toml_lines(sub, path)
    return lines


def config_to_toml(config: Any, title: str = "") -> str:
    """The dataclass instance ``config`` as a TOML document that
    :func:`resolve_config` (and ``--config``) reads back to an equal config:
    fields with a value TOML cannot hold (None) are written as comments, so
    reading the file keeps their defaults.  Above each field (and nested
    table) a comment says what it means: the first clause of its entry in its
    class's docstring ``Attributes:`` (:mod:`spgeo.config_docs`).  ``title``:
    first comment lines."""
    head = [f"# {line}" for line in title.splitlines()] + ([""] if title else [])
    return "\n".join(head + _toml_lines(config, "")) + "\n"


def changed_fields(config: Any) -> Dict[str, Any]:
    """The init fields of the dataclass instance ``config`` whose values differ from
    the class defaults, as ``{name: value}`` (a nested config dataclass that differs
    appears as itself).  Fields without a default are always included."""
    out: Dict[str, Any] = {}
    for f in dataclasses.fields(config):
        if not f.init or not f.repr:
            continue
        value = getattr(config, f.name)
        if f.default is not dataclasses.MISSING:
            default = f.default
        elif f.default_factory is not dataclasses.MISSING:
            default = f.default_factory()
        else:
            out[f.name] = value
            continue
        try:
            same = bool(value == default)
        except Exception:       # array-valued fields: compare by identity only
            same = value is default
        if not same:
            out[f.name] = value
    return out


def _type_name(hint: Any) -> str:
    """``hint`` in words for an error message (``an integer``, ``a str or None``)."""
    if hint is type(None):
        return "None"
    origin = typing.get_origin(hint)
    if origin is Union:
        return " or ".join(_type_name(h) for h in typing.get_args(hint))
    if origin is typing.Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(hint))
    words = {bool: "True or False", int: "an integer", float: "a number", str: "a string",
             tuple: "a tuple", list: "a list", dict: "a table"}
    base = origin if origin is not None else hint
    return words.get(base, f"a {getattr(base, '__name__', str(base))}")


def _matches(value: Any, hint: Any) -> bool:
    """Whether ``value`` is of type ``hint`` (typing constructs included; a
    hint that cannot be checked, such as ``Any`` or a ``Callable``, matches)."""
    if hint is Any or isinstance(hint, (str, typing.TypeVar)):
        return True
    if hint is type(None):
        return value is None
    origin = typing.get_origin(hint)
    if origin is Union:
        return any(_matches(value, h) for h in typing.get_args(hint))
    if origin is typing.Literal:
        return value in typing.get_args(hint)
    base = origin if origin is not None else hint
    if base is bool:
        return isinstance(value, (bool, np.bool_))
    if base is int:
        return isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_))
    if base is float:
        return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))
    if base in (tuple, list, collections.abc.Sequence):
        return isinstance(value, (tuple, list))
    if not isinstance(base, type) or base is collections.abc.Callable:
        return True
    return isinstance(value, base)


def check_field_types(config: Any) -> None:
    """Raise :class:`ConfigTypeError` naming the first init field of the dataclass
    instance ``config`` whose value does not match its annotation (an int is a
    number; a list passes for a tuple; ``Optional`` admits None; annotations that
    cannot be checked, such as ``Any`` or a ``Callable``, admit anything)."""
    hints = _class_hints(type(config))
    for f in dataclasses.fields(config):
        hint = hints.get(f.name)
        if not f.init or hint is None:
            continue
        value = getattr(config, f.name)
        if not _matches(value, hint):
            raise ConfigTypeError(f"{type(config).__name__}.{f.name} expects "
                                  f"{_type_name(hint)}, got {value!r} "
                                  f"({type(value).__name__})")


def _checked_init(cls: type) -> None:
    """Run :func:`check_field_types` first at construction: before the class's own
    ``__post_init__`` (whose value checks assume the types), else after ``__init__``."""
    if "__post_init__" in cls.__dict__:
        post = cls.__dict__["__post_init__"]

        @functools.wraps(post)
        def __post_init__(self, *args) -> None:
            check_field_types(self)
            post(self, *args)

        cls.__post_init__ = __post_init__
    elif not hasattr(cls, "__post_init__"):
        init = cls.__init__

        @functools.wraps(init)
        def __init__(self, *args, **kwargs) -> None:
            init(self, *args, **kwargs)
            check_field_types(self)

        cls.__init__ = __init__


def config_class(cls: type) -> type:
    """Class decorator (above ``@dataclass``) of the config dataclasses: field types
    are checked at construction (:func:`check_field_types`: ``OdometryConfig(window="7")``
    raises :class:`ConfigTypeError` naming the field and the expected type), and
    ``repr`` shows only the fields that differ from the defaults, e.g.
    ``OdometryConfig(window=7)``; a default instance prints as ``OdometryConfig()``."""
    def __repr__(self) -> str:
        items = ", ".join(f"{k}={v!r}" for k, v in changed_fields(self).items())
        return f"{type(self).__name__}({items})"

    cls.__repr__ = __repr__
    _checked_init(cls)
    return cls
