"""fieldcal.validation's strict YAML loading: libyaml's parser where PyYAML has it, the pure-Python
loader (UniqueKeyLoader) as the oracle: the same documents, lines and refusals either way."""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from fieldcal.validation import MarkedDict, UniqueKeyLoader, parse_yaml

ROOT = Path(__file__).resolve().parent.parent
# Every YAML file the project ships or tests with: configs, specs, import maps, procedures, golden
# parameter files.
SHIPPED = sorted(p for d in ("configs", "procedures", "tests") for p in (ROOT / d).rglob("*.yaml"))


class Refused(ValueError):
    def __init__(self, message: str, path: str = "") -> None:
        super().__init__(message)


def same(a, b) -> bool:
    """Equal values of equal types, and every mapping's lines equal too."""
    if type(a) is not type(b):
        return False
    if isinstance(a, dict):
        if isinstance(a, MarkedDict) and (a.line, a.key_lines) != (b.line, b.key_lines):
            return False
        return list(a) == list(b) and all(same(a[k], b[k]) for k in a)
    if isinstance(a, list):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    return a == b


def test_every_shipped_yaml_loads_as_the_pure_python_loader_loads_it():
    from fieldcal import validation

    assert len(SHIPPED) > 10
    if validation._FastLoader is not None:  # not vacuous: libyaml's path is the one these take
        assert all(validation._plain(path.read_text()) for path in SHIPPED)
    for path in SHIPPED:
        text = path.read_text()
        assert same(parse_yaml(text, str(path), Refused), yaml.load(text, Loader=UniqueKeyLoader)), path


@pytest.mark.parametrize("text, message", [
    ("a: 1\na: 2\n", "key 'a' appears twice in one mapping"),
    ("a: !!python/object:os.system x\n", "the tag tag:yaml.org,2002:python/object:os.system is not allowed"),
    ("a: !!str 5\n", "is not allowed"),
    ("a: &x [1, 2]\nb: [" + ", ".join(["*x"] * 101) + "]\n", "more than 100 aliases"),
    ("a: [1, 2\nb: 3\n", "line 2"),
    ("a: \x07bell\n", "not valid YAML"),
])
def test_what_the_strict_loader_refuses_is_refused(text, message):
    with pytest.raises(Refused, match="^doc.yaml: not valid YAML") as info:
        parse_yaml(text, "doc.yaml", Refused)
    assert message in str(info.value)


def test_a_few_aliases_load_as_before():
    text = "base: &b {x: 1.0, y: 2}\ncopy: *b\n"
    data = parse_yaml(text, "doc.yaml", Refused)
    assert data["copy"] == {"x": 1.0, "y": 2} and same(data, yaml.load(text, Loader=UniqueKeyLoader))
