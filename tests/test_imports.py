"""What a command imports: the heavy packages only where the command needs them.

Each case runs in a fresh interpreter (a test process has long since imported everything) and
reports sys.modules; what is asserted is the import graph, not how long it takes.
"""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

# Packages `fieldcal --help` must not pay for: numpy and everything built on it, the plotting and
# TUI stacks, the simulator, and the CSV libraries of `fieldcal apply`.
HEAVY = ("numpy", "scipy", "matplotlib", "allantools", "textual", "yaml", "drivers.sim",
         "fieldcal.solvers.norm", "polars")

_REPORT = """
import json, sys
{body}
print("\\n" + json.dumps(sorted(sys.modules)))
"""


def _modules_after(body: str) -> tuple[set[str], subprocess.CompletedProcess]:
    proc = subprocess.run([sys.executable, "-c", _REPORT.format(body=body)], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return set(json.loads(proc.stdout.strip().splitlines()[-1])), proc


def _cli(argv: list[str]) -> tuple[set[str], str, int]:
    body = (f"from fieldcal.cli.main import main\n"
            f"try:\n    main({argv!r})\nexcept SystemExit as exc:\n    print('exit', exc.code)")
    modules, proc = _modules_after(body)
    code = int([line for line in proc.stdout.splitlines() if line.startswith("exit ")][-1].split()[1])
    return modules, proc.stdout + proc.stderr, code


def _heavy(modules: set[str]) -> list[str]:
    return sorted(m for m in modules if any(m == h or m.startswith(h + ".") for h in HEAVY))


@pytest.mark.parametrize("argv", [["--help"], ["calibrate", "--help"], ["import", "--help"],
                                  ["tui", "--help"], ["run", "--help"], ["apply", "--help"]])
def test_help_imports_nothing_heavy(argv):
    modules, out, code = _cli(argv)
    assert code == 0 and "usage: fieldcal" in out
    assert _heavy(modules) == []


@pytest.mark.parametrize("argv", [["run", "--seed", "x"], ["no-such-command"],
                                  ["solve", "--method", "nelder-mead", "s"]])
def test_rejected_argument_imports_nothing_heavy(argv):
    modules, out, code = _cli(argv)
    assert code == 2 and "error:" in out
    assert _heavy(modules) == []


def test_the_engine_and_solvers_do_not_import_the_simulator():
    """Live runs and recordings are solved without the simulator, scipy.signal or scipy.stats."""
    modules, _ = _modules_after("import fieldcal.procedure.engine, fieldcal.solvers.solve, "
                                "fieldcal.recording.calibrate, fieldcal.run.livedevice, fieldcal.config")
    assert not [m for m in modules if m.startswith(("drivers.sim", "scipy.signal", "scipy.stats",
                                                    "matplotlib", "textual", "allantools"))]
    assert "fieldcal.solvers.norm" in modules  # the case is not vacuous: the solvers did load


def test_the_noise_model_is_one_class():
    """The simulator draws from the same TriadNoise the station's config builds."""
    from drivers.noise import TriadNoise
    from drivers.sim import TriadNoise as SimTriadNoise
    from fieldcal.config import TriadNoise as ConfigTriadNoise
    assert SimTriadNoise is TriadNoise and ConfigTriadNoise is TriadNoise


def test_the_library_never_imports_the_command_line():
    """fieldcal.cli is a front end: no library module imports it (and apply takes no other
    module's private names). Read from the source, so an import inside a function counts too."""
    import ast
    import re
    from pathlib import Path

    import fieldcal

    root = Path(fieldcal.__file__).parent
    offenders = []
    for path in sorted(root.rglob("*.py")):
        if path.relative_to(root).parts[0] in ("cli", "tui"):  # the front ends
            continue
        text = path.read_text()
        # Only a file naming "cli" (fieldcal.cli..., from fieldcal import cli) can import it, and
        # only apply's are checked for private names: the others need no parse (0.8 s of CPU).
        if path.relative_to(root).parts[0] != "apply" and not re.search(r"\bcli", text):
            continue
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
                private = [a.name for a in node.names if a.name.startswith("_")] \
                    if path.relative_to(root).parts[0] == "apply" else []
                if any(n.startswith("fieldcal.cli") for n in names) or \
                        (node.module.startswith("fieldcal.") and private):
                    offenders.append(f"{path.relative_to(root)}:{node.lineno} {node.module}")
            elif isinstance(node, ast.Import) and any(a.name.startswith("fieldcal.cli") for a in node.names):
                offenders.append(f"{path.relative_to(root)}:{node.lineno}")
    assert offenders == []


def test_calibrate_checks_its_paths_before_numpy_and_loads_only_what_it_uses(tmp_path):
    """`fieldcal calibrate` checks where it writes before it imports numpy (its imports are made
    with the collector paused, cli.startup), and runs without the spec checks (acceptance: no
    --spec) or procedure files (positions) loaded."""
    from drivers.sim.handheld import simulate_handheld, to_text

    acc, gyro = to_text(simulate_handheld(3), tmp_path)
    argv = ["calibrate", str(acc), str(gyro), "--map", "imu_tk", "--latitude", "40", "--gravity", "9.80",
            "--out", str(tmp_path / "sessions"), "--params", str(tmp_path / "unit.yaml"),
            "--registry", str(tmp_path / "registry.sqlite")]
    body = (f"from fieldcal.cli.main import build_parser, main\n"
            f"from fieldcal.cli.paths import check_paths\n"
            f"check_paths(build_parser().parse_args({argv!r}))\n"
            f"print(json.dumps(sorted(sys.modules)))\n"
            f"assert main({argv!r}) == 0\n")
    after_run, proc = _modules_after(body)
    after_checks = set(json.loads([line for line in proc.stdout.splitlines() if line.startswith("[")][0]))
    assert _heavy(after_checks) == []
    assert "numpy" in after_run and (tmp_path / "unit.yaml").is_file()  # not vacuous: it ran
    assert not after_run & {"fieldcal.acceptance", "fieldcal.procedure.positions"}


# What only other commands use: the binary protocols' parsers, the other commands' parser modules
# (the terminal UI's keys, the planner's), resolve's worker pool, the live stillness detector.
CALIBRATE_NEEDS_NOT = ("drivers.protocols.xsens", "drivers.protocols.vectornav", "fieldcal.cli.tui",
                       "fieldcal.tui", "fieldcal.tui.keys", "fieldcal.planning", "fieldcal.planning.command",
                       "fieldcal.cli.resolve", "fieldcal.procedure.stillness")


def test_the_calibrate_command_line_loads_none_of_what_only_other_commands_use(tmp_path):
    """`fieldcal calibrate` as run from the command line (main with its argv) builds only its own
    parser; the modules of the other commands' parsers stay unloaded, and the command runs."""
    from drivers.sim.handheld import simulate_handheld, to_text

    acc, gyro = to_text(simulate_handheld(3), tmp_path)
    argv = ["calibrate", str(acc), str(gyro), "--map", "imu_tk", "--gravity", "9.80",
            "--out", str(tmp_path / "sessions"), "--params", str(tmp_path / "unit.yaml"),
            "--registry", str(tmp_path / "registry.sqlite")]
    modules, _ = _modules_after(f"import sys\nfrom fieldcal.cli.main import main\nsys.argv[1:] = {argv!r}\n"
                                f"assert main() == 0\n")
    assert (tmp_path / "unit.yaml").is_file() and "fieldcal.recording.calibrate" in modules  # it ran
    assert sorted(modules & set(CALIBRATE_NEEDS_NOT)) == []
    # the case is not vacuous: the full parser loads the parser modules, a device parser the
    # protocols, the live engine the stillness detector
    full, _ = _modules_after("from fieldcal.cli.main import build_parser\nbuild_parser()\n"
                             "from drivers.protocols import make_parser\nmake_parser('xsens')\n"
                             "import fieldcal.procedure.engine\n")
    assert set(CALIBRATE_NEEDS_NOT) - {"fieldcal.cli.resolve"} <= full


@pytest.mark.parametrize("argv", [
    ["calibrate", "a.txt", "b.txt", "--map", "imu_tk", "--gravity", "9.81", "--force", "--latitude", "40"],
    ["calibrate", "session-dir"],
    ["import", "a.txt", "b.txt", "--map", "imu_tk", "--out", "sessions/x"],
])
def test_a_one_command_parser_parses_as_the_full_parser(argv):
    from fieldcal.cli.main import build_parser

    assert vars(build_parser(argv[0]).parse_args(argv)) == vars(build_parser().parse_args(argv))


@pytest.mark.parametrize("argv", [["calibrate", "--help"], ["import", "--help"], ["calibrate"],
                                  ["calibrate", "a.txt", "--gravity", "x"], ["calibrate", "a", "--bogus"],
                                  ["import", "--map"]])
def test_a_one_command_parser_says_what_the_full_parser_says(argv, capsys):
    from fieldcal.cli.main import build_parser

    said = []
    for parser in (build_parser(argv[0]), build_parser()):
        with pytest.raises(SystemExit) as exit_:
            parser.parse_args(argv)
        out, err = capsys.readouterr()
        said.append((exit_.value.code, out, err))
    assert said[0] == said[1] and said[0][1] + said[0][2]  # and it said something


def test_the_binary_protocols_classes_are_still_names_of_drivers_protocols():
    """drivers.protocols loads the Xsens and VectorNav modules on first use; their classes stay
    importable from it, as they were before that."""
    modules, _ = _modules_after("from drivers.protocols import XsensMtData2Parser, XsensMtData2Encoder, "
                                "VectorNavParser, VectorNavEncoder, PARSERS\n"
                                "assert PARSERS['xsens'] is XsensMtData2Parser")
    assert "drivers.protocols.xsens" in modules and "drivers.protocols.vectornav" in modules


def test_live_runs_and_recordings_load_scipy_optimize_only_for_a_search():
    """The norm method imports scipy.optimize when its search (Powell, least_squares) runs, not
    with the solver modules: importing the live engine's and the recording path's modules does
    not load it, nor scipy.spatial (the rotation solver's weighting imports it when it weighs)."""
    modules, _ = _modules_after("import fieldcal.procedure.engine, fieldcal.solvers.solve, "
                                "fieldcal.recording.calibrate, fieldcal.run.livedevice, fieldcal.tui.app")
    assert "fieldcal.solvers.norm" in modules and "fieldcal.solvers.rotation" in modules  # not vacuous
    assert not [m for m in modules if m.startswith(("scipy.optimize", "scipy.spatial"))]


def test_calibrate_imports_scipy_optimize_only_for_a_recording_whose_search_needs_it(tmp_path):
    """`fieldcal calibrate` on imucal's Ferraris session (six faces and three turns, real bytes:
    the aligned six-position solution and the gyro's rotations, no search) does not import
    scipy.optimize (~0.13 s of its 0.63 s CPU); then, in the same interpreter, a hand-held
    recording, whose accelerometer Powell's method solves, does (the case is not vacuous)."""
    from pathlib import Path

    from drivers.sim.handheld import simulate_handheld, to_text

    acc, gyro = to_text(simulate_handheld(3), tmp_path)
    session = Path(__file__).parent / "data" / "real" / "imucal_ferraris_session.csv.gz"
    runs = {"ferraris": [str(session), "--map", "imucal", "--rate", "102.4", "--gravity", "9.81"],
            "handheld": [str(acc), str(gyro), "--map", "imu_tk", "--gravity", "9.80"]}
    body = "from fieldcal.cli.main import main\n"
    for name, args in runs.items():
        argv = ["calibrate", *args, "--out", str(tmp_path / f"{name}-sessions"),
                "--params", str(tmp_path / f"{name}.yaml"), "--registry", str(tmp_path / "registry.sqlite")]
        body += f"code = main({argv!r})\nprint('@@', {name!r}, code, 'scipy.optimize' in sys.modules)\n"
    _, proc = _modules_after(body)
    said = [line.split()[1:] for line in proc.stdout.splitlines() if line.startswith("@@")]
    assert said == [["ferraris", "0", "False"], ["handheld", "0", "True"]], proc.stdout[-2000:]
    assert "Ferraris" in proc.stdout and (tmp_path / "ferraris.yaml").is_file()  # the protocol it was
