"""Reading YAML written by people: safe loading, and field checks whose errors name the field.

Every problem becomes one line, ``<file>: <dotted.field>: expected <what>, got <what>``, raised
as the caller's own ValueError subclass.
"""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Sequence

import numpy as np
import yaml


class UniqueKeyLoader(yaml.SafeLoader):
    """safe_load, but a key given twice in one mapping is an error instead of last-one-wins."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen = set()
            for key_node, _ in node.value:
                if not isinstance(key_node, yaml.ScalarNode) or key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node)
                if key in seen:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"key {key!r} appears twice in one mapping", key_node.start_mark)
                seen.add(key)
        return super().construct_mapping(node, deep)


MISSING = object()


def join(where: str, key: str) -> str:
    return f"{where}.{key}" if where else key


def describe(value) -> str:
    if value is MISSING:
        return "nothing (the key is missing)"
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if math.isnan(value):
            return ".nan"
        if math.isinf(value):
            return ".inf" if value > 0 else "-.inf"
        return repr(value)
    if isinstance(value, int):
        text = repr(value)
        return text if len(text) <= 40 else text[:37] + "..."
    if isinstance(value, str):
        return repr(value) if len(value) <= 60 else repr(value[:57]) + "..."
    if isinstance(value, (list, dict)) and not value:
        return f"an empty {'list' if isinstance(value, list) else 'mapping'}"
    if isinstance(value, list):
        return f"a list of {len(value)} item{'s' if len(value) != 1 else ''}"
    if isinstance(value, dict):
        return "a mapping"
    return f"a {type(value).__name__}"


class FieldReader:
    """Validating accessors that raise ``error(message, path, field)`` naming the file and field."""

    def __init__(self, path: str, error: type[ValueError]) -> None:
        self.path = path
        self.error = error

    def fail(self, where: str, expected: str, got: str) -> None:
        prefix = f"{self.path}: {where}: " if where else f"{self.path}: "
        raise self.error(f"{prefix}expected {expected}, got {got}", self.path, where)

    def mapping(self, value, where: str, required: Sequence[str], optional: Sequence[str] = (),
                what: str = "a mapping") -> dict:
        if not isinstance(value, dict):
            keys = ", ".join(required or optional)
            self.fail(where, f"{what} with keys {keys}" if keys else what, describe(value))
        known = (*required, *optional)
        for key in value:
            if key not in known:
                self.fail(join(where, key) if isinstance(key, str) else where,
                          f"only the keys {', '.join(known)}", f"the unknown key {describe(key)}")
        return value

    def number(self, m: dict, key: str, where: str, minimum: float | None = None) -> float:
        return self.value(m.get(key, MISSING), join(where, key), minimum)

    def value(self, value, here: str, minimum: float | None = None) -> float:
        """A finite int or float (not a bool, not a string), as a float."""
        expected = "a number" if minimum is None else f"a number >= {minimum:g}"
        if isinstance(value, str):
            try:
                numeric = math.isfinite(float(value))
            except ValueError:
                numeric = False
            hint = " (text: YAML reads quoted or dot-less numbers as strings; write e.g. 1.0e-05)" \
                if numeric else ""
            self.fail(here, expected, describe(value) + hint)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(here, expected, describe(value))
        try:
            x = float(value)
        except OverflowError:
            x = math.inf
        if not math.isfinite(x):
            self.fail(here, "a finite number", describe(value))
        if minimum is not None and x < minimum:
            self.fail(here, expected, describe(value))
        return x

    def string(self, m: dict, key: str, where: str, allowed: Sequence[str] | None = None,
               optional: bool = False) -> str | None:
        value = m.get(key, MISSING)
        if value is MISSING and optional:
            return None
        here = join(where, key)
        if allowed is not None:
            if value not in allowed or not isinstance(value, str):
                choices = " or ".join(repr(a) for a in allowed)
                self.fail(here, choices, describe(value))
        elif not isinstance(value, str) or not value:
            self.fail(here, "a non-empty string" + (" (quote it)" if isinstance(value, (int, float)) else ""),
                      describe(value))
        return value

    def vector(self, m: dict, keys: Sequence[str], where: str, minimum: float | None = None) -> np.ndarray:
        return np.array([self.number(m, k, where, minimum) for k in keys])


def parse_yaml(text: str, path: str, error: type[ValueError]):
    """yaml safe loading (duplicate keys refused); a syntax error is one line naming the line."""
    try:
        return yaml.load(text, Loader=UniqueKeyLoader)  # noqa: S506 -- a SafeLoader subclass
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f"line {mark.line + 1}: " if mark is not None else ""
        what = (exc.problem or exc.context or "malformed").splitlines()[0]
        raise error(f"{path}: not valid YAML ({where}{what})", path) from None
    except Exception as exc:  # noqa: BLE001 -- e.g. a date like 2024-02-30 raises ValueError
        detail = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise error(f"{path}: not valid YAML ({detail})", path) from None


def read_yaml_file(path: str | os.PathLike, error: type[ValueError], what: str):
    """Read, decode and parse a YAML file; every failure is one line naming the file."""
    name = os.fspath(path)
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise error(f"{name}: cannot read {what} ({exc.strerror or exc})", name) from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{name}: not valid YAML (not UTF-8 text at byte {exc.start})", name) from None
    return parse_yaml(text, name, error)
