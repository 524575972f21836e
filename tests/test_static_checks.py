"""The static checks, run with the tests so that a fresh clone's `make test` (and CI) runs them:
import contracts (import-linter: the layers, drivers never importing fieldcal, pure solvers, no
import circle), lint (ruff: unused imports and variables, undefined names, likely bugs) and types
(mypy on the session, the run, the solvers and the engine). Each tool is configured in
pyproject.toml, is the version pinned in the `test` extra, and runs from this interpreter's
environment; a failure shows what the tool said."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


@pytest.fixture(scope="module")
def mypy_cache(request, tmp_path_factory):
    """One mypy cache for this module's two mypy runs (one xdist group, conftest.SHARED_FIXTURES),
    kept from one test run to the next in pytest's own cache folder (.pytest_cache, ignored by
    git): a run checks again only what differs, by content hash (mypy's cache takes a module whose
    path or mtime changed but whose hash did not), where a cold one spent 6.5 s of CPU, most of
    it on numpy's stubs (issue 26; 0.2 s warm). mypy keys the cache by its version and options and
    each module by its hash: a stale entry is checked again, never trusted. mypy's cache is not
    safe for two mypy processes at once: a lock holds off another pytest run's mypy tests until
    this module's are done. Without pytest's cache (-p no:cacheprovider), a cache of this run."""
    import fcntl

    cache = getattr(request.config, "cache", None)
    if cache is None:
        yield tmp_path_factory.mktemp("mypy-cache")
        return
    directory = Path(cache.mkdir("mypy"))
    with open(directory / "lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        yield directory


def _run(argv: list[str], tmp_path: Path, mypy_cache: Path | None = None) -> subprocess.CompletedProcess:
    # caches in the test's own directory: nothing written into the checkout, nothing stale
    env = {**os.environ, "RUFF_CACHE_DIR": str(tmp_path / "ruff"),
           "MYPY_CACHE_DIR": str(mypy_cache or tmp_path / "mypy")}
    return subprocess.run(argv, cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)


def _tool(name: str) -> str:
    path = BIN / name
    if not path.is_file():
        pytest.fail(f"{path}: not installed; the `test` extra installs it (make .venv/.installed)")
    return str(path)


def _said(proc: subprocess.CompletedProcess) -> str:
    return f"exit {proc.returncode}\n{proc.stdout}\n{proc.stderr}"


def test_import_contracts_are_kept(tmp_path):
    proc = _run([_tool("lint-imports"), "--no-cache", "--no-logo"], tmp_path)
    assert proc.returncode == 0, _said(proc)
    assert "0 broken" in proc.stdout, _said(proc)  # it checked the contracts (none skipped)


def test_ruff_finds_nothing(tmp_path):
    proc = _run([_tool("ruff"), "check", "--output-format", "concise", "fieldcal", "drivers", "tests",
                 "benchmarks"], tmp_path)
    assert proc.returncode == 0, _said(proc)


def test_mypy_finds_no_type_error(tmp_path, mypy_cache):
    proc = _run([sys.executable, "-m", "mypy"], tmp_path, mypy_cache)  # the files: pyproject.toml's [tool.mypy]
    assert proc.returncode == 0, _said(proc)
    assert "Success: no issues found" in proc.stdout, _said(proc)


def test_each_check_fails_on_what_it_guards(tmp_path, mypy_cache):
    """The checks can fail: a copy of the package with one upward import, one unused import and
    one type error is refused by each tool, naming the line."""
    import shutil

    copy = tmp_path / "tree"
    shutil.copytree(ROOT / "fieldcal", copy / "fieldcal", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copytree(ROOT / "drivers", copy / "drivers", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", copy / "pyproject.toml")
    bad = copy / "fieldcal" / "solvers" / "methods.py"
    bad.write_text(bad.read_text() + "\n\nimport os  # unused\n\n\ndef upward() -> int:\n"
                   "    from fieldcal.session import capture  # a solver reading a session\n"
                   "    return capture  # not an int\n")
    env = {**os.environ, "PYTHONPATH": str(copy), "RUFF_CACHE_DIR": str(tmp_path / "ruff"),
           "MYPY_CACHE_DIR": str(mypy_cache)}

    def run(argv):
        return subprocess.run(argv, cwd=copy, env=env, capture_output=True, text=True, timeout=300)

    contracts = run([_tool("lint-imports"), "--no-cache", "--no-logo"])
    assert contracts.returncode != 0 and "fieldcal.solvers.methods -> fieldcal.session.capture" in \
        contracts.stdout, _said(contracts)
    lint = run([_tool("ruff"), "check", "--output-format", "concise", "fieldcal"])
    assert lint.returncode != 0 and "fieldcal/solvers/methods.py" in lint.stdout and "F401" in lint.stdout, \
        _said(lint)
    types = run([sys.executable, "-m", "mypy"])
    assert types.returncode != 0 and "fieldcal/solvers/methods.py" in types.stdout, _said(types)
