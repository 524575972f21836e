"""The suite's own lists stay true: every test tests/slow_tests.txt names exists, so a renamed
test cannot drop out of the slow set (and back into `make test-fast`) unnoticed."""
from __future__ import annotations

import re
from pathlib import Path

TESTS = Path(__file__).parent
SLOW_LIST = TESTS / "slow_tests.txt"  # read by conftest.py (not imported here: tests/faults has one too)
DEF_LINE = re.compile(r"^[ \t]*(?:async[ \t]+)?def[ \t]+(\w+)", re.MULTILINE)


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
            # the names a `def` line gives (parsing every test file into a tree took 1.8 s of CPU)
            functions[file] = set(DEF_LINE.findall(file.read_text(encoding="utf-8")))
        if name and name.split("[")[0] not in functions[file]:
            missing.append(node_id)
    assert not missing, f"{SLOW_LIST.name} names tests that do not exist: {missing}"


def test_the_users_of_a_shared_fixture_run_as_one_xdist_group(tmp_path):
    """`make test` (--dist loadgroup) sends a shared module fixture's users to one worker, which
    builds it once, only if conftest.py's xdist_group marks are there when xdist's own collection
    hook turns them into node ids' "@group" suffixes (they were not, and test_plan's 66 s plan was
    built on both workers). And a test the slow list names is dealt out before the short ones,
    wherever its file puts it, so that no long test starts when the others are done. Run here on a
    four-test file with the real conftest.py, in one worker that runs the tests in the order dealt."""
    import shutil
    import subprocess
    import sys

    # node ids from tmp_path (tests/...), as in the repository
    (tmp_path / "pytest.ini").write_text("[pytest]\nmarkers =\n    slow: long\n", encoding="utf-8")
    tests = tmp_path / "tests"
    tests.mkdir()
    shutil.copy(TESTS / "conftest.py", tests / "conftest.py")
    (tests / SLOW_LIST.name).write_text("test_grouped.py::test_listed_slow\n", encoding="utf-8")
    (tests / "test_grouped.py").write_text(
        "import pytest\n\n\n@pytest.fixture(scope='module')\ndef solved():\n    return 1\n\n\n"
        "def test_one(solved):\n    pass\n\n\ndef test_two(solved):\n    pass\n\n\ndef test_alone():\n    pass\n\n\n"
        "def test_listed_slow():\n    pass\n", encoding="utf-8")
    # xdist alone of the installed plugins (the snapshot, Hypothesis and timeout plugins loaded in
    # both processes took a third of this test's CPU): it is xdist's hook the marks must precede
    import os

    done = subprocess.run([sys.executable, "-m", "pytest", "-p", "xdist.plugin", "-n", "1", "--dist", "loadgroup",
                           "-vv", "-p", "no:cacheprovider", "tests/test_grouped.py"], cwd=tmp_path, capture_output=True,
                          text=True, timeout=300, env={**os.environ, "PYTEST_DISABLE_PLUGIN_AUTOLOAD": "1"})
    assert done.returncode == 0, done.stdout + done.stderr
    passed = [line.split("PASSED ")[1].strip() for line in done.stdout.splitlines() if "PASSED " in line]
    group = "@tests/test_grouped.py:solved"
    assert passed == [f"tests/test_grouped.py::test_one{group}", f"tests/test_grouped.py::test_two{group}",
                      "tests/test_grouped.py::test_listed_slow", "tests/test_grouped.py::test_alone"], done.stdout


def test_every_test_file_keeps_a_fast_test_unless_the_list_names_it_whole():
    """`make test-fast` covers every module: a file whose every test function the slow list names
    (without a parameter, so all its cases) has dropped out of the fast loop unnoticed; a file
    meant to be slow as a whole is named alone. (Tests made slow by their fixture, conftest's
    SLOW_FIXTURES, are not seen here.)"""
    listed = [node_id.removeprefix("tests/") for node_id in slow_test_ids()]
    whole = {entry for entry in listed if "::" not in entry}
    every_case: dict[str, set[str]] = {}
    for entry in listed:
        path, _, name = entry.partition("::")
        if name and "[" not in name:
            every_case.setdefault(path, set()).add(name)
    without_fast = []
    for file in sorted(TESTS.rglob("test_*.py")):
        path = file.relative_to(TESTS).as_posix()
        tests = {name for name in DEF_LINE.findall(file.read_text(encoding="utf-8")) if name.startswith("test")}
        if path not in whole and tests and tests <= every_case.get(path, set()):
            without_fast.append(path)
    assert len(whole) >= 1 and every_case  # the list was read
    assert not without_fast, f"every test of these files is in {SLOW_LIST.name}: name the file alone, or keep one fast: {without_fast}"


def test_the_controller_writes_a_test_modules_rewritten_code_once_and_again_when_it_changes(tmp_path, request):
    """conftest.py's controller writes pytest's rewritten code of the test modules before the
    xdist workers start, so that they do not each rewrite them all (a fresh clone's workers spent
    6 s of CPU each on that). pytest's own reader of its cache is the judge: it takes the file,
    and the code in it is the rewritten one (a failing assert explains its values)."""
    from _pytest.assertion import rewrite

    conftest = next(plugin for plugin in request.config.pluginmanager.get_plugins()
                    if getattr(plugin, "__file__", None) == str(TESTS / "conftest.py"))
    module = tmp_path / "test_sums.py"
    module.write_text("def test_sum():\n    total = 1 + 1\n    assert total == 3\n", encoding="utf-8")
    pyc = rewrite.get_cache_dir(module) / ("test_sums" + rewrite.PYC_TAIL)

    assert conftest.rewrite_test_modules_once(request.config, [module]) == [module]
    code = rewrite._read_pyc(module, pyc)
    assert code is not None
    namespace: dict = {}
    exec(code, namespace)
    try:
        namespace["test_sum"]()
    except AssertionError as failed:
        assert "assert 2 == 3" in str(failed)  # pytest's explanation: the rewritten assert
    else:
        raise AssertionError("the module's assert did not fail")

    assert conftest.rewrite_test_modules_once(request.config, [module]) == []  # still current
    module.write_text("def test_sum():\n    assert 1 + 1 == 2\n", encoding="utf-8")
    assert conftest.rewrite_test_modules_once(request.config, [module]) == [module]  # edited: again
    assert rewrite._read_pyc(module, pyc) is not None
