"""`make mutants`' runner (tools/mutation): its tally and table against hand-counted verdicts, and,
where the mutation environment is built, one real run on a two-function module whose mutants'
fates are known beforehand."""
from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
import textwrap
from collections import Counter
from pathlib import Path
from types import SimpleNamespace

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


def test_a_sample_is_drawn_the_same_in_another_process_and_a_larger_one_holds_it():
    names = [f"fieldcal.solvers.crb.x_f__mutmut_{i}" for i in range(1, 201)]
    small = run.sample_of("solvers/crb.py", names, 20)
    assert len(small) == 20 and small == sorted(small, key=names.index)  # drawn, in file order
    larger = run.sample_of("solvers/crb.py", names, 60)
    assert set(small) < set(larger) and len(larger) == 60
    assert run.sample_of("solvers/thermal.py", names, 20) != small  # each module its own draw
    assert run.sample_of("solvers/crb.py", names, 500) == names
    # a str seed is hashed by SHA-512, not by hash(): another process with another hash seed
    script = ("import importlib.util, json, sys; spec = importlib.util.spec_from_file_location('r', sys.argv[1]); "
              "r = importlib.util.module_from_spec(spec); spec.loader.exec_module(r); "
              "print(json.dumps(r.sample_of('solvers/crb.py', json.loads(sys.argv[2]), 20)))")
    other = subprocess.run([sys.executable, "-c", script, str(TOOLS / "run.py"), json.dumps(names)],
                           capture_output=True, text=True, check=True, env={"PYTHONHASHSEED": "12345"})
    assert json.loads(other.stdout) == small


def test_the_wilson_interval_against_hand_worked_values_and_scipy():
    # 9 of 10: centre (0.9 + z²/20)/(1 + z²/10) = 0.78898, half z/(1 + z²/10)·√(0.009 + z²/400) = 0.19314
    assert run.wilson_interval(9, 10) == pytest.approx((0.59585, 0.98212), abs=1e-5)
    # all killed: the upper end is 1 and the lower one n/(n + z²)
    assert run.wilson_interval(20, 20) == pytest.approx((20 / (20 + 1.959963984540054 ** 2), 1.0))
    assert run.wilson_interval(0, 0) == (0.0, 1.0)
    from scipy.stats import binomtest

    for killed, tried in ((9, 10), (57, 60), (60, 60), (0, 7), (71, 100)):
        peer = binomtest(killed, tried).proportion_ci(method="wilson")
        assert run.wilson_interval(killed, tried) == pytest.approx((peer.low, peer.high), abs=1e-9)


def test_the_estimate_of_all_weights_each_module_by_its_mutants():
    whole = Counter(mutants=100, killed=90, survived=10)  # run whole: no sampling error
    sampled = Counter(mutants=50, killed=38, timeout=2, survived=10, population=300)
    rate, low, high = run.weighted_estimate([("a.py", whole), ("b.py", sampled)])
    assert rate == pytest.approx((100 * 0.9 + 300 * 0.8) / 400)
    # ñ = 50 + z² = 53.84146, p̃ = (40 + z²/2)/ñ = 0.778596: centre 0.25·0.9 + 0.75·p̃ = 0.808947,
    # half-width z·√((300/400)²·p̃(1 − p̃)/ñ·(250/299)) = 0.076056
    assert (low, high) == pytest.approx((0.808947 - 0.076056, 0.808947 + 0.076056), abs=2e-6)
    assert run.weighted_estimate([("a.py", whole)]) == (0.9, 0.9, 0.9)
    assert run.weighted_estimate([("a.py", Counter(mutants=5, population=50, **{"not run": 5}))]) is None
    lines = run.table([("a.py", whole), ("b.py", sampled)]).splitlines()
    assert lines[0].split()[-4:] == ["sampled", "95", "%", "interval"]
    assert lines[1].endswith("all       (all run)")
    assert lines[2].split()[-5:] == ["80.0", "50", "of", "300", "67.0–88.8"]
    assert lines[3].split()[-5:] == ["82.5", "150", "of", "400", "73.3–88.5"]
    assert lines[3].startswith("all, weighted")


def test_a_sampled_run_runs_the_drawn_mutants_once_then_only_reports(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "pyproject.toml").write_text("")
    (tmp_path / "mutants" / "fieldcal" / "solvers").mkdir(parents=True)
    names = [f"fieldcal.solvers.crb.x_f__mutmut_{i}" for i in range(1, 11)]
    (tmp_path / "mutants" / "fieldcal" / "solvers" / "crb.py.meta").write_text(
        json.dumps({"exit_code_by_key": dict.fromkeys(names)}))
    monkeypatch.setitem(sys.modules, "generate", SimpleNamespace(generate=lambda: None))  # mutmut's, not here
    runs = []

    def run_module(module, todo, tests, floor):
        runs.append(list(todo))
        lines = "".join(f"{name}\t{'survived' if name == todo[0] else 'killed'}\tt\t1\t0.1\n" for name in todo)
        run.RESULTS.mkdir(parents=True, exist_ok=True)
        with open(run.results_path(module), "a", encoding="utf-8") as out:
            out.write(lines)

    monkeypatch.setattr(run, "run_module", run_module)
    monkeypatch.setattr(run, "HERE", tmp_path)
    (tmp_path / "tests.toml").write_text('"solvers/crb.py" = ["test_crb.py"]\n')
    assert run.main(["--sample", "3"]) == 0
    assert runs == [run.sample_of("solvers/crb.py", names, 3)]
    first = capsys.readouterr().out
    assert run.main(["--sample", "3"]) == 0
    assert len(runs) == 1  # every drawn mutant has its verdict: nothing run again
    again = capsys.readouterr().out
    assert again == first
    row = again.splitlines()[1].split()
    assert row[:9] == ["solvers/crb.py", "3", "2", "0", "1", "0", "0", "0", "66.7"]
    assert row[9:] == ["3", "of", "10", "20.8–93.9"]  # Wilson's, for 2 of 3
    # the estimate's: ñ = 3 + z² = 6.84146, p̃ = (2 + z²/2)/ñ = 0.57308, half z·√(p̃(1 − p̃)/ñ·7/9) = 0.32688
    assert again.splitlines()[2].split()[-1] == "24.6–90.0"
    assert "sampled: 66.7 % of these modules' 10 mutants estimated killed" in again
    with pytest.raises(SystemExit) as stop:
        run.main(["--sample", "-1"])
    assert str(stop.value) == "tools/mutation/run.py: --sample -1: a number of mutants, 1 or more (0: all)"


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
