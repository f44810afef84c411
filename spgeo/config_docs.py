"""What each field of a config dataclass means, read from the class's own
docstring: its Google-style ``Attributes:`` section, where every field is
described once (``name: text``, continuation lines indented further; ``a, b:
text`` describes two fields).  :func:`config_to_toml
<spgeo.configs.config_to_toml>` writes the first sentence of each meaning
(:func:`short_meaning`) as a comment above the field in ``--dump-config``.
"""
from __future__ import annotations

import dataclasses
import functools
import inspect
import re
from typing import Dict, List, Optional

__all__ = ["field_meanings", "short_meaning", "missing_meanings"]

_ENTRY = re.compile(r"^([A-Za-z_]\w*(?:\s*,\s*[A-Za-z_]\w*)*)\s*:\s*(.*)$")
_ROLE = re.compile(r":[\w:]+:`([^`<]+?)(?:\s*<[^>]*>)?`")
_LITERAL = re.compile(r"``(.+?)``")
_ABBREVIATIONS = ("e.g", "i.e", "etc", "cf", "vs")


def _attributes(doc: str) -> Dict[str, str]:
    """``{field: text}`` of the ``Attributes:`` section of the docstring ``doc``."""
    lines = inspect.cleandoc(doc).splitlines()
    starts = [i for i, line in enumerate(lines) if line.strip() == "Attributes:"]
    if not starts:
        return {}
    base = len(lines[starts[0]]) - len(lines[starts[0]].lstrip())
    entries: Dict[str, List[str]] = {}
    indent: Optional[int] = None
    text: Optional[List[str]] = None
    for line in lines[starts[0] + 1:]:
        if not line.strip():
            continue
        ind = len(line) - len(line.lstrip())
        if ind <= base:
            break
        indent = ind if indent is None else indent
        match = _ENTRY.match(line.strip()) if ind == indent else None
        if match:
            text = [match.group(2)]
            for name in match.group(1).split(","):
                entries[name.strip()] = text
        elif text is not None:
            text.append(line.strip())
    return {name: " ".join(" ".join(parts).split()) for name, parts in entries.items()}


@functools.lru_cache(maxsize=None)
def field_meanings(cls: type) -> Dict[str, str]:
    """``{field name: meaning}`` of the dataclass ``cls``, from the
    ``Attributes:`` sections of its docstring and its bases' (a subclass's
    entry wins); fields without an entry are absent."""
    out: Dict[str, str] = {}
    for klass in cls.__mro__:
        for name, text in _attributes(klass.__dict__.get("__doc__") or "").items():
            out.setdefault(name, text)
    return out


def short_meaning(text: str) -> str:
    """The first clause of a docstring meaning: up to its first full stop or
    semicolon outside parentheses (not the stop of ``e.g.`` / ``i.e.`` / an
    ellipsis), with the reST markup made plain: ``:class:`~a.B``` -> ``B``,
    ````x```` -> ``x``."""
    text = _ROLE.sub(lambda m: m.group(1)[1:].rsplit(".", 1)[-1] if m.group(1).startswith("~")
                     else m.group(1), text)
    text = _LITERAL.sub(r"\1", text)
    depth = 0
    for i, char in enumerate(text):
        depth += (char in "([{") - (char in ")]}")
        if char == ";" and depth <= 0:
            return text[:i]
        if (char == "." and depth <= 0 and (i + 1 == len(text) or text[i + 1] == " ")
                and text[i - 1:i] != "." and not text[:i].endswith(_ABBREVIATIONS)):
            return text[:i + 1]
    return text


def missing_meanings(config, prefix: str = "") -> List[str]:
    """Dotted names of the init fields of the dataclass instance ``config`` (and
    of its nested configs) that have no meaning in their class's docstring."""
    meanings = field_meanings(type(config))
    out = []
    for f in dataclasses.fields(config):
        if not f.init:
            continue
        if f.name not in meanings:
            out.append(prefix + f.name)
        value = getattr(config, f.name)
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            out += missing_meanings(value, f"{prefix}{f.name}.")
    return out
