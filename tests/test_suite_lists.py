"""The suite's own lists stay true: every test tests/slow_tests.txt names exists, so a renamed
test cannot drop out of the slow set (and back into `make test-fast`) unnoticed."""
from __future__ import annotations

import ast
from pathlib import Path

TESTS = Path(__file__).parent
SLOW_LIST = TESTS / "slow_tests.txt"  # read by conftest.py (not imported here: tests/faults has one too)


def slow_test_ids() -> set[str]:
    lines = (line.strip() for line in SLOW_LIST.read_text(encoding="utf-8").splitlines())
    return {f"tests/{line}" for line in lines if line and not line.startswith("#")}


def test_every_test_the_slow_list_names_exists():
    ids = slow_test_ids()
    assert len(ids) > 100  # the list was read, not an empty file
    missing = []
    functions: dict[Path, set[str]] = {}
    for node_id in sorted(ids):
        path, _, name = node_id.removeprefix("tests/").partition("::")
        file = TESTS / path
        if not file.is_file():
            missing.append(node_id)
            continue
        if file not in functions:
            tree = ast.parse(file.read_text(encoding="utf-8"))
            functions[file] = {n.name for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))}
        if name and name.split("[")[0] not in functions[file]:
            missing.append(node_id)
    assert not missing, f"{SLOW_LIST.name} names tests that do not exist: {missing}"
