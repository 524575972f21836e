"""`make mutants`' runner (tools/mutation): its tally and table against hand-counted verdicts, and,
where the mutation environment is built, one real run on a two-function module whose mutants'
fates are known beforehand."""
from __future__ import annotations

import importlib.util
import json
import subprocess
import textwrap
from collections import Counter
from pathlib import Path

import pytest

TOOLS = Path(__file__).resolve().parents[1] / "tools" / "mutation"
MUTANTS_PYTHON = Path(__file__).resolve().parents[1] / ".venv-mutants" / "bin" / "python"


def _load_run():
    spec = importlib.util.spec_from_file_location("mutants_run", TOOLS / "run.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


run = _load_run()


def test_a_tally_counts_each_verdict_and_equivalent_survivors_apart():
    names = ["m.x_f__mutmut_1", "m.x_f__mutmut_2", "m.x_f__mutmut_3", "m.x_f__mutmut_4", "m.x_g__mutmut_1",
             "m.x_g__mutmut_2"]
    verdicts = {"m.x_f__mutmut_1": ("killed", "t1"), "m.x_f__mutmut_2": ("timeout", "t2"),
                "m.x_f__mutmut_3": ("survived", ""), "m.x_f__mutmut_4": ("survived", ""),
                "m.x_g__mutmut_1": ("no tests", "")}
    counts = run.tally(names, verdicts, {"m.x_f__mutmut_3": "a default argument given its default"})
    assert counts == Counter({"mutants": 6, "killed": 1, "timeout": 1, "survived": 1, "equivalent": 1,
                              "no tests": 1, "not run": 1})
    # 2 killed of the 5 run: 40 %; of the 4 not equivalent: 50 %
    assert run.summary(counts) == ("2 of 5 run killed: 40.0 % (below the 90 % goal; 50.0 % of the 4 not "
                                   "equivalent); 1 not run yet")
    lines = run.table([("a.py", counts), ("b.py", Counter(mutants=10, killed=10))]).splitlines()
    assert lines[1].split() == ["a.py", "6", "1", "1", "1", "1", "1", "1", "40.0"]
    assert lines[2].split() == ["b.py", "10", "10", "0", "0", "0", "0", "0", "100.0"]
    # all listed: 12 of 15 run killed
    assert lines[3].split() == ["all", "listed", "16", "11", "1", "1", "1", "1", "1", "80.0"]


def test_verdicts_are_read_back_with_a_later_line_overriding_an_earlier_one(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    path = run.results_path("procedure/positions.py")
    assert path == Path("mutants/results/procedure.positions.tsv")
    path.parent.mkdir(parents=True)
    path.write_text("#STATS 3.0 s of CPU over 4 tests\n"
                    "a\tsurvived\t\t3\t0.2\n"
                    "b\tkilled\ttests/test_x.py::test_y\t1\t0.1\n"
                    "a\tkilled\ttests/test_new.py::test_z\t1\t0.0\n"
                    "c\tsurvived\t\t2\t0.1\n"
                    "c\tno tests\t\t0\t0.0\n"  # re-run against a file that does not reach it
                    "d\tno tests\t\t0\t0.0\n", encoding="utf-8")
    assert run.read_verdicts("procedure/positions.py") == {
        "a": ("killed", "tests/test_new.py::test_z"), "b": ("killed", "tests/test_x.py::test_y"),
        "c": ("survived", ""), "d": ("no tests", "")}
    assert run.read_verdicts("model.py") == {}


def test_modules_come_from_mutmuts_meta_files_and_tests_from_the_listing(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    folder = tmp_path / "mutants" / "fieldcal" / "export"
    folder.mkdir(parents=True)
    (folder / "px4.py.meta").write_text(json.dumps({"exit_code_by_key": {"fieldcal.export.px4.x_a__mutmut_1": None,
                                                                         "fieldcal.export.px4.x_a__mutmut_2": 0}}))
    (folder / "__init__.py.meta").write_text(json.dumps({"exit_code_by_key": {}}))
    assert run.core_modules() == {"export/px4.py": ["fieldcal.export.px4.x_a__mutmut_1",
                                                    "fieldcal.export.px4.x_a__mutmut_2"]}
    listing = {"model.py": ["test_model_terms.py"], "export/*": ["test_export.py", "faults/test_x.py"]}
    assert run.tests_for("export/px4.py", listing) == ["tests/test_export.py", "tests/faults/test_x.py"]
    assert run.tests_for("solvers/crb.py", listing) == []


def test_every_listed_test_file_exists_and_every_equivalent_line_has_a_reason():
    import tomllib

    listing = tomllib.loads((TOOLS / "tests.toml").read_text(encoding="utf-8"))
    tests = TOOLS.parents[1] / "tests"
    assert listing  # read, not empty
    missing = [name for files in listing.values() for name in files if not (tests / name).is_file()]
    assert not missing
    lines = [line for line in (TOOLS / "equivalent.txt").read_text(encoding="utf-8").splitlines()
             if line.strip() and not line.startswith("#")]
    assert all(len(line.split("\t", 1)) == 2 and line.split("\t", 1)[1].strip() for line in lines), lines


def test_naming_a_module_that_is_not_mutated_is_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "pyproject.toml").write_text("")
    (tmp_path / "mutants" / "fieldcal").mkdir(parents=True)
    (tmp_path / "mutants" / "fieldcal" / "model.py.meta").write_text(
        json.dumps({"exit_code_by_key": {"fieldcal.model.x_f__mutmut_1": None}}))
    with pytest.raises(SystemExit) as stop:
        run.main(["--report", "--modules", "solvers/nowhere.py"])
    assert str(stop.value) == ("tools/mutation/run.py: --modules 'solvers/nowhere.py' names no mutated module "
                               "(they are: model.py)")
    assert run.main(["--report", "--modules", "model.py"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[1].split() == ["model.py", "1", "0", "0", "0", "0", "0", "1", "-"]
    assert out[-1] == "no mutant run yet"


@pytest.mark.skipif(not MUTANTS_PYTHON.exists(), reason="the mutation environment .venv-mutants is built by "
                                                          "`make mutants`, not by `make test`")
def test_a_real_run_kills_the_checked_mutant_and_keeps_the_unchecked_one(tmp_path):
    """mutmut generates the mutants of `add` (checked by value) and `double` (reached, not checked);
    the in-process runner must call every `add` mutant killed and every `double` one survived."""
    (tmp_path / "tiny").mkdir()
    (tmp_path / "tiny" / "__init__.py").write_text("")
    (tmp_path / "tiny" / "calc.py").write_text(textwrap.dedent("""\
        def add(a, b):
            return a + b


        def double(x):
            return x * 2
    """))
    (tmp_path / "tests").mkdir()
    (tmp_path / "tests" / "test_calc.py").write_text(textwrap.dedent("""\
        from tiny.calc import add, double


        def test_add():
            assert add(2, 3) == 5


        def test_double_runs():
            double(4)
    """))
    (tmp_path / "pyproject.toml").write_text('[tool.mutmut]\nsource_paths = ["tiny/"]\n')
    subprocess.run([str(MUTANTS_PYTHON), str(TOOLS / "generate.py")], cwd=tmp_path, check=True,
                   capture_output=True, timeout=300)
    meta = json.loads((tmp_path / "mutants" / "tiny" / "calc.py.meta").read_text())
    names = list(meta["exit_code_by_key"])
    (tmp_path / "names.txt").write_text("\n".join(names) + "\n")
    out = tmp_path / "out.tsv"
    subprocess.run([str(MUTANTS_PYTHON), "-m", "pytest", "-p", "inprocess", "-p", "no:cacheprovider", "-q",
                    f"--basetemp={tmp_path / 'bt'}", "tests"],
                   cwd=tmp_path / "mutants", check=True, capture_output=True, timeout=300,
                   env={"PATH": "/usr/bin:/bin", "PYTHONPATH": str(TOOLS), "MUTANTS_NAMES": str(tmp_path / "names.txt"),
                        "MUTANTS_OUT": str(out)})
    verdicts = {line.split("\t")[0]: line.split("\t")[1] for line in out.read_text().splitlines()
                if not line.startswith("#")}
    assert set(verdicts) == set(names)
    assert {v for n, v in verdicts.items() if ".x_add__" in n} == {"killed"}
    assert {v for n, v in verdicts.items() if ".x_double__" in n} == {"survived"}
    assert any(".x_add__" in n for n in names) and any(".x_double__" in n for n in names)
