"""Issue 25, items 13 and 18: the small refusals, each one line naming what is wrong."""
import os
import subprocess
import sys
from pathlib import Path

import pytest

from fieldcal.cli.main import main

CSV_HEAD = "time_ms,ax_mg,ay_mg,az_mg,gx_dps,gy_dps,gz_dps\n"


def _one_line(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err


def _csv(path: Path, rows: int = 300, columns: int = 7) -> Path:
    lines = [",".join([str(10 * i), "1.5", "-2", "1000"][:columns] + ["0.25"] * max(0, columns - 4))
             for i in range(rows)]
    path.write_text(CSV_HEAD + "\n".join(lines) + "\n")
    return path


def test_apply_from_a_pipe_named_dash_is_refused(tmp_path, capsys):
    """The README promises a one-line refusal of a pipe; '-' said "No such file or directory"."""
    params = tmp_path / "p.yaml"
    params.write_text("not read\n")
    for extra in ([], ["--map", "single-csv"]):
        assert main(["apply", str(params), "-", *extra]) == 2
        assert _one_line(capsys).startswith("fieldcal: -: fieldcal reads a recording from a file, not from "
                                            "standard input (a pipe)")


def test_lines_with_too_few_columns_are_malformed_not_header(tmp_path, capsys):
    """They were counted as header lines: "0 malformed, 51176 header lines"."""
    path = _csv(tmp_path / "three.csv", rows=40, columns=3)
    assert main(["import", str(path), "--map", "single-csv", "--out", str(tmp_path / "s")]) == 2
    assert "in 41 lines (40 malformed, 1 header lines)" in _one_line(capsys)
    with path.open("a") as f:  # then whole lines: the short ones are malformed lines of the file
        f.write("".join(f"{1000 + 10 * i},1,2,3,4,5,6\n" for i in range(20)))
    assert main(["import", str(path), "--map", "single-csv", "--out", str(tmp_path / "t")]) == 0
    out = capsys.readouterr().out
    assert "1 header line skipped" in out and "40 malformed lines not used: 2, 3, 4" in out


@pytest.mark.parametrize("replacement", ["directory", "/dev/zero"])
def test_a_samples_file_that_is_no_file_is_named_as_such(tmp_path, capsys, replacement):
    """A session whose samples.bin is a directory or a link to /dev/zero was called "missing"."""
    csv = _csv(tmp_path / "log.csv")
    assert main(["import", str(csv), "--map", "single-csv", "--out", str(tmp_path / "s")]) == 0
    samples = tmp_path / "s" / "samples.bin"
    samples.unlink()
    if replacement == "directory":
        samples.mkdir()
        expected = "a directory, not a file"
    else:
        samples.symlink_to(replacement)
        expected = "a character device (a link to /dev/zero), not a file"
    capsys.readouterr()
    assert main(["calibrate", str(tmp_path / "s"), "--latitude", "40"]) == 2
    assert f"{samples}: {expected}, but log.jsonl line" in _one_line(capsys)


def test_height_without_latitude_and_a_wild_table_rate_are_refused(tmp_path, capsys):
    csv = _csv(tmp_path / "log.csv")
    out = ["--map", "single-csv", "--out", str(tmp_path / "s")]
    assert main(["calibrate", str(csv), "--height", "1e9", *out]) == 2
    assert "--height: expected -500..9000 m above the ellipsoid, got 1e+09" in _one_line(capsys)
    assert main(["calibrate", str(csv), "--height", "300", *out]) == 2  # in range, but alone it sets nothing
    assert "--height: needs --latitude too" in _one_line(capsys)
    assert main(["calibrate", str(csv), "--latitude", "40", "--table-rate", "1e9", *out]) == 2
    assert "--table-rate: expected a rate above 0 and up to 2000 °/s" in _one_line(capsys)
    assert not (tmp_path / "s").exists()


def test_export_to_a_closed_stdout_is_one_line(tmp_path):
    """`export ... >&-` ended in AttributeError: 'NoneType' object has no attribute 'write'."""
    source = Path(__file__).parent / "data" / "golden" / "headless-resumed" / "parameters.yaml"
    done = subprocess.run([sys.executable, "-m", "fieldcal.cli.main", "export", str(source), "--format", "json"],
                          capture_output=False, stderr=subprocess.PIPE, text=True,
                          preexec_fn=lambda: os.close(1))
    assert done.returncode == 2 and done.stderr == "fieldcal: export: standard output is closed: give --out FILE\n"


@pytest.mark.parametrize("argv", [["export", "{fifo}", "--format", "json"],
                                  ["run", "--headless", "--config", "{fifo}"],
                                  ["run", "--headless", "--procedure", "{fifo}"]])
def test_a_fifo_given_as_a_yaml_input_is_refused_at_once(tmp_path, capsys, argv):
    """A FIFO with no writer as a parameter file, config or procedure: one line, never a command
    blocked for ever in open() (a reviewer's reproduction hung each of these)."""
    import os

    fifo = tmp_path / "in.yaml"
    os.mkfifo(fifo)
    assert main([a.format(fifo=fifo) for a in argv] + (["--out", str(tmp_path / "s")] if argv[0] == "run" else [])) == 2
    assert f"{fifo}: not a regular file (a FIFO, socket or device)" in _one_line(capsys)
