"""benchmarks/processes.py times Python children as an installed package runs: its warm-up run
writes their bytecode even where the shell sets PYTHONDONTWRITEBYTECODE (otherwise an editable
install's own modules were compiled afresh in every timed run, a quarter second per calibrate)."""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from processes import run_once  # noqa: E402


def test_a_timed_child_writes_its_bytecode_whatever_the_shell_says(tmp_path, monkeypatch):
    monkeypatch.setenv("PYTHONDONTWRITEBYTECODE", "1")
    (tmp_path / "probe_module.py").write_text("VALUE = 1\n")
    # Exit status 3 if bytecode writing is off in the child, else 0 once the import succeeded.
    run = run_once([sys.executable, "-c", "import sys, probe_module; sys.exit(3 * sys.dont_write_bytecode)"],
                   cwd=tmp_path)
    assert run.status == 0
    assert list((tmp_path / "__pycache__").glob("probe_module.*.pyc"))
