"""Issue 25 (last review, item 6): standard output that cannot take the command's output.

`solve S >&-` exited 0 having shown nothing (print() to a closed stdout drops everything), and
`export > /dev/full` said only "No space left on device". Now a command started with stdout
closed is refused in one line before its work (export and apply: unless --out gives a file),
and a failed write to stdout names it, exit 1. Run as a user runs it: a child process whose
descriptor 1 is closed, or is /dev/full.
"""
from __future__ import annotations

import os
import subprocess
import sys

import pytest
from faultlib import QUICK, ROOT, unit_parameter_file


def _fieldcal(argv, stdout, close_stdout=False) -> subprocess.CompletedProcess:
    def close():
        os.close(1)
    proc = subprocess.run([sys.executable, "-m", "fieldcal.cli.main", *map(str, argv)], cwd=ROOT,
                          stdout=stdout, stderr=subprocess.PIPE, text=True, timeout=300,
                          preexec_fn=close if close_stdout else None)
    assert "Traceback" not in proc.stderr, proc.stderr
    return proc


COMMANDS = {
    "solve": ["solve", "{S}"], "replay": ["replay", "{S}", "--quiet"], "allan": ["allan", "{S}"],
    "resolve": ["resolve", "{S}", "--method", "lsq", "--registry", "{W}/r.sqlite"],
    "units": ["units", "--registry", "{W}/r.sqlite"], "history": ["history", "A", "--registry", "{W}/r.sqlite"],
    "certificate": ["certificate", "{S}", "--out", "{W}/c.html"],
    "run": ["run", "--headless", "--quiet", "--procedure", QUICK, "--out", "{W}/runs"],
    "export": ["export", "{S}/parameters.yaml", "--format", "px4"],
    "apply": ["apply", "{S}/parameters.yaml", "{W}/in.csv", "--map", "single-csv"],
}


@pytest.mark.parametrize("command", list(COMMANDS))
def test_a_command_started_with_stdout_closed_is_refused_before_its_work(tmp_path, session_copy, command):
    (tmp_path / "in.csv").write_text("time_ms,ax_mg,ay_mg,az_mg,gx_dps,gy_dps,gz_dps\n"
                                     + "".join(f"{10 * i},1,2,1000,0.5,0,0\n" for i in range(20)))
    argv = [str(a).replace("{S}", str(session_copy)).replace("{W}", str(tmp_path)) for a in COMMANDS[command]]
    before = sorted(p.name for p in session_copy.iterdir())
    proc = _fieldcal(argv, subprocess.DEVNULL, close_stdout=True)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"fieldcal: {command}: standard output is closed"), lines
    assert sorted(p.name for p in session_copy.iterdir()) == before  # no plot, no parameter file
    assert not (tmp_path / "runs").exists() and not (tmp_path / "c.html").exists()


def test_export_with_out_needs_no_stdout(tmp_path, session_copy):
    out = tmp_path / "x.params"
    proc = _fieldcal(["export", session_copy / "parameters.yaml", "--format", "px4", "--out", out],
                     subprocess.DEVNULL, close_stdout=True)
    assert proc.returncode == 0, proc.stderr
    assert out.read_text().startswith("# ")


@pytest.mark.parametrize("argv", [["export", "{S}/parameters.yaml", "--format", "imucal-json"], ["solve", "{S}"]])
def test_a_full_stdout_is_named(session_copy, argv):
    with open("/dev/full", "w") as full:
        proc = _fieldcal([a.replace("{S}", str(session_copy)) for a in argv], full)
    assert proc.returncode == 1
    assert proc.stderr.splitlines()[-1] == "fieldcal: standard output: No space left on device"
    assert proc.stderr.count("No space left") == 1


def test_apply_to_a_full_stdout_names_it(tmp_path):
    """Issue 25, round 4, item 2: `apply ... > /dev/full` said only "No space left on device" (its
    CSV goes to stdout's byte buffer, which the named stdout did not cover)."""

    params = unit_parameter_file(tmp_path / "p.yaml")
    (tmp_path / "in.csv").write_text("time_ms,ax_mg,ay_mg,az_mg,gx_dps,gy_dps,gz_dps\n"
                                     + "".join(f"{10 * i},1,2,1000,0.5,0,0\n" for i in range(2000)))
    with open("/dev/full", "w") as full:
        proc = _fieldcal(["apply", params, tmp_path / "in.csv", "--map", "single-csv"], full)
    assert proc.returncode == 1, proc.stderr
    assert proc.stderr.splitlines()[-1] == "fieldcal: standard output: No space left on device"
    assert proc.stderr.count("No space left") == 1
