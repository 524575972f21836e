"""Reading YAML written by people: one strict loader, and field checks whose errors name the field.

Every YAML the tool reads (station configs, procedures, import maps, parameter files) goes
through :func:`parse_yaml`: safe loading with a size cap, an alias cap (a "billion laughs"
document is refused before anything expands it), no explicit tags, duplicate keys refused,
and every mapping remembering the line of each key so that errors can name it.

Every problem becomes one line, ``<file>: <dotted.field>: expected <what>, got <what> (line N)``,
raised as the caller's own ValueError subclass.
"""
from __future__ import annotations

import difflib
import errno
import math
import os
import re
import stat
from typing import Literal, NoReturn, Sequence, overload

import numpy as np
import yaml

from fieldcal.atomic import note_read

# A hand-written station file is a few kB; a parameter file for a dozen triads some tens of kB.
MAX_YAML_BYTES = 1 << 20
# Anchors and aliases are legal YAML, and a few are handy; thousands are an attack. The
# expanded size is capped too, because a handful of nested aliases can still expand to 10^9 nodes.
MAX_ALIASES = 100
MAX_EXPANDED_NODES = 100_000
# A name that becomes part of a file name or a dotted field (a triad's name): no separators.
IDENTIFIER = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,63}")


class MarkedDict(dict):
    """A YAML mapping that knows the line (1-based) of each of its keys, for error messages."""

    line: int | None = None
    key_lines: dict


yaml.SafeDumper.add_representer(MarkedDict, yaml.representer.SafeRepresenter.represent_dict)


class _Refused(yaml.MarkedYAMLError):
    """A document the strict loader will not build (tags, alias bombs)."""


class UniqueKeyLoader(yaml.SafeLoader):
    """safe_load, but strict: a key given twice in one mapping is an error instead of
    last-one-wins, explicit tags are refused, aliases are capped, and mappings remember lines."""

    def __init__(self, stream) -> None:
        super().__init__(stream)
        self._aliases = 0

    def compose_node(self, parent, index):
        event = self.peek_event()
        if isinstance(event, yaml.AliasEvent):
            self._aliases += 1
            if self._aliases > MAX_ALIASES:
                raise _Refused(None, None, f"more than {MAX_ALIASES} aliases (*name)", event.start_mark)
        elif getattr(event, "tag", None) not in (None, "!"):
            raise _Refused(None, None, f"the tag {event.tag} is not allowed (write plain values)",
                           event.start_mark)
        return super().compose_node(parent, index)

    def get_single_node(self):
        node = super().get_single_node()
        if node is not None and self._aliases:
            _check_expansion(node)
        return node

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

    def construct_marked_mapping(self, node):
        data = MarkedDict()
        data.line = node.start_mark.line + 1
        data.key_lines = {}
        yield data
        value = self.construct_mapping(node)
        data.update(value)
        for key_node, _ in node.value:
            if isinstance(key_node, yaml.ScalarNode):
                data.key_lines.setdefault(self.construct_object(key_node), key_node.start_mark.line + 1)


UniqueKeyLoader.add_constructor("tag:yaml.org,2002:map", UniqueKeyLoader.construct_marked_mapping)


def _check_expansion(root) -> None:
    """Refuse a document whose aliases would expand past MAX_EXPANDED_NODES, or loop."""
    sizes: dict[int, int] = {}
    active: set[int] = set()
    stack = [(root, False)]
    while stack:
        node, children_done = stack.pop()
        key = id(node)
        if key in sizes:
            continue
        children = [] if isinstance(node, yaml.ScalarNode) else (
            [n for pair in node.value for n in pair] if isinstance(node, yaml.MappingNode) else node.value)
        if children_done:
            active.discard(key)
            sizes[key] = 1 + sum(sizes[id(c)] for c in children)
            if sizes[key] > MAX_EXPANDED_NODES:
                raise _Refused(None, None, f"its aliases expand to more than {MAX_EXPANDED_NODES} "
                               "values", node.start_mark)
            continue
        if key in active:
            raise _Refused(None, None, "an alias refers to itself", node.start_mark)
        active.add(key)
        stack.append((node, True))
        stack.extend((c, False) for c in children if id(c) not in sizes)


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


def line_of(m, key=None) -> int | None:
    """The line of ``key`` in a loaded mapping (of the mapping itself without a key), if known."""
    if not isinstance(m, MarkedDict):
        return None
    return m.line if key is None else m.key_lines.get(key, m.line)


def nearest(word, choices: Sequence[str]) -> str | None:
    """The valid name closest to a misspelt one, if any is close (difflib's ratio >= 0.6)."""
    if not isinstance(word, str):
        return None
    close = difflib.get_close_matches(word, list(choices), n=1)
    return close[0] if close else None


class FieldReader:
    """Validating accessors that raise ``error(message, path, field)`` naming the file and field."""

    def __init__(self, path: str, error: type[ValueError]) -> None:
        self.path = path
        self.error = error

    def fail(self, where: str, expected: str, got: str, line: int | None = None) -> NoReturn:
        prefix = f"{self.path}: {where}: " if where else f"{self.path}: "
        at = f" (line {line})" if line else ""
        raise self.error(f"{prefix}expected {expected}, got {got}{at}", self.path, where)

    def refuse(self, where: str, message: str, line: int | None = None) -> NoReturn:
        """A one-line error in the file's own words (not "expected X, got Y")."""
        prefix = f"{self.path}: {where}: " if where else f"{self.path}: "
        at = f" (line {line})" if line else ""
        raise self.error(f"{prefix}{message}{at}", self.path, where)

    def mapping(self, value, where: str, required: Sequence[str], optional: Sequence[str] = (),
                what: str = "a mapping", line: int | None = None) -> dict:
        """A mapping with every required key and no key outside required + optional; an unknown
        key is named with the nearest valid one (a typo must not silently drop a setting)."""
        if not isinstance(value, dict):
            keys = ", ".join(required or optional)
            self.fail(where, f"{what} with keys {keys}" if keys else what, describe(value), line)
        known = (*required, *optional)
        for key in value:
            if key not in known:
                guess = nearest(key, known)
                hint = f"did you mean {guess!r}?" if guess else f"the keys are {', '.join(known)}"
                self.refuse(join(where, key) if isinstance(key, str) else where,
                            f"unknown key {describe(key)}; {hint}", line_of(value, key))
        for key in required:
            if key not in value:
                self.refuse(join(where, key), "missing (a required key)", line_of(value))
        return value

    def number(self, m: dict, key: str, where: str, minimum: float | None = None) -> float:
        return self.value(m.get(key, MISSING), join(where, key), minimum, line_of(m, key))

    def value(self, value, here: str, minimum: float | None = None, line: int | None = None) -> float:
        """A finite int or float (not a bool, not a string), as a float."""
        expected = "a number" if minimum is None else f"a number >= {minimum:g}"
        if value is MISSING:
            self.refuse(here, f"missing ({expected})", line)
        if isinstance(value, str):
            try:
                numeric = math.isfinite(float(value))
            except ValueError:
                numeric = False
            hint = " (text: YAML reads quoted or dot-less numbers as strings; write e.g. 1.0e-05)" \
                if numeric else ""
            self.fail(here, expected, describe(value) + hint, line)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(here, expected, describe(value), line)
        try:
            x = float(value)
        except OverflowError:
            x = math.inf
        if not math.isfinite(x):
            self.fail(here, "a finite number", describe(value), line)
        if minimum is not None and x < minimum:
            self.fail(here, expected, describe(value), line)
        return x

    def bounded(self, m: dict, key: str, where: str, low: float, high: float, unit: str) -> float:
        """A number in [low, high] ``unit``; the bounds keep a typo from meaning a run of days."""
        value = m.get(key, MISSING)
        numeric = isinstance(value, (int, float)) and not isinstance(value, bool)
        if numeric and not low <= value <= high:  # .inf and .nan too
            self.fail(join(where, key), f"a number from {low:g} to {high:g} {unit}",
                      describe(value), line_of(m, key))
        return self.number(m, key, where)

    def whole(self, m: dict, key: str, where: str, low: int, high: int) -> int:
        """An integer in [low, high] (not a bool, not 1.0)."""
        value = m.get(key, MISSING)
        expected = f"a whole number from {low} to {high}"
        if value is MISSING:
            self.refuse(join(where, key), f"missing ({expected})", line_of(m))
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            self.fail(join(where, key), expected, describe(value), line_of(m, key))
        return value

    def boolean(self, m: dict, key: str, where: str, default: bool) -> bool:
        """true or false, nothing else: the text "false" is not a way to say false."""
        value = m.get(key, default)
        if not isinstance(value, bool):
            self.fail(join(where, key), "true or false (unquoted)", describe(value), line_of(m, key))
        return value

    @overload
    def string(self, m: dict, key: str, where: str, allowed: Sequence[str] | None = None,
               optional: Literal[False] = False) -> str: ...

    @overload
    def string(self, m: dict, key: str, where: str, allowed: Sequence[str] | None = None,
               optional: bool = False) -> str | None: ...

    def string(self, m: dict, key: str, where: str, allowed: Sequence[str] | None = None,
               optional: bool = False) -> str | None:
        value = m.get(key, MISSING)
        if value is MISSING and optional:
            return None
        here = join(where, key)
        line = line_of(m, key)
        if allowed is not None:
            if value not in allowed or not isinstance(value, str):
                choices = " or ".join(repr(a) for a in allowed)
                self.fail(here, choices, describe(value), line)
        elif value is MISSING:
            self.refuse(here, "missing (a non-empty string)", line)
        elif not isinstance(value, str) or not value:
            self.fail(here, "a non-empty string" + (" (quote it)" if isinstance(value, (int, float)) else ""),
                      describe(value), line)
        return value

    def vector(self, m: dict, keys: Sequence[str], where: str, minimum: float | None = None) -> np.ndarray:
        return np.array([self.number(m, k, where, minimum) for k in keys])


def parse_yaml(text: str, path: str, error: type[ValueError]):
    """Strict YAML loading (see the module's docstring); any failure is one line naming the
    file and, for a syntax error, the line."""
    if len(text) > MAX_YAML_BYTES:
        raise error(f"{path}: not loaded: {len(text)} characters, more than the "
                    f"{MAX_YAML_BYTES // 1024} kB a hand-written YAML file can need", path)
    try:
        return yaml.load(text, Loader=UniqueKeyLoader)  # noqa: S506 -- a SafeLoader subclass
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f"line {mark.line + 1}: " if mark is not None else ""
        what = (exc.problem or exc.context or "malformed").splitlines()[0]
        raise error(f"{path}: not valid YAML ({where}{what})", path) from None
    except RecursionError:
        raise error(f"{path}: not valid YAML (nested too deeply)", path) from None
    except Exception as exc:  # noqa: BLE001 -- e.g. a date like 2024-02-30 raises ValueError
        detail = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise error(f"{path}: not valid YAML ({detail})", path) from None


def read_yaml_text(path: str | os.PathLike, error: type[ValueError], what: str) -> str:
    """A YAML file's text: read (at most a little past the size cap) and decoded as UTF-8;
    every failure is one line naming the file."""
    name = os.fspath(path)
    try:
        # O_NONBLOCK: a FIFO with no writer would block the open (and the command) for ever
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
        with os.fdopen(fd, "rb") as f:
            st = os.fstat(fd)
            if stat.S_ISDIR(st.st_mode):
                raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), name)
            if not stat.S_ISREG(st.st_mode):
                raise error(f"{name}: not a regular file (a FIFO, socket or device): not read as a {what}", name)
            os.set_blocking(fd, True)
            note_read(st)  # a file this command read is never written over
            data = f.read(MAX_YAML_BYTES + 1)
    except OSError as exc:
        raise error(f"{name}: cannot read {what} ({exc.strerror or exc})", name) from None
    if len(data) > MAX_YAML_BYTES:
        raise error(f"{name}: not loaded: larger than the {MAX_YAML_BYTES // 1024} kB a "
                    f"hand-written {what} can need", name)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{name}: not a YAML {what} (not UTF-8 text at byte {exc.start}; a binary "
                    "file?)", name) from None


def read_yaml_file(path: str | os.PathLike, error: type[ValueError], what: str):
    """Read, decode and parse a YAML file; every failure is one line naming the file."""
    return parse_yaml(read_yaml_text(path, error, what), os.fspath(path), error)
