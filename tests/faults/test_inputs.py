"""Hostile inputs: every YAML the tool reads, refused in one line that names the file.

Each YAML kind (station config, procedure, import map, parameter file) is fed alias bombs,
tags, huge documents, binary bytes, wrong types and misspelt keys, through the command that
reads it, run in-process (``fieldcal.cli.main.main``). Every refusal: exit 2, one line on
stderr starting with ``fieldcal: <file>``, no traceback.
"""
from __future__ import annotations

import contextlib
import resource

import pytest
import yaml

from fieldcal.cli.main import main
from fieldcal.config import CONFIGS_DIR
from fieldcal.paramfile import ParameterFileError, load as load_parameters
from fieldcal.procedure.positions import PROCEDURES_DIR, load_procedure
from fieldcal.recording.import_map import RECORDINGS_DIR
from fieldcal.validation import MAX_YAML_BYTES

PROCEDURE = (PROCEDURES_DIR / "field-18.yaml").read_text()
CONFIG = (CONFIGS_DIR / "sim.yaml").read_text()
IMPORT_MAP = (RECORDINGS_DIR / "single-csv.yaml").read_text()


def refused(capsys, argv, *, names) -> str:
    """Run the command; it must exit 2 with one line naming ``names``; returns the line."""
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"fieldcal: {names}"), err
    return lines[0]


@contextlib.contextmanager
def memory_cap(extra_bytes: int = 1 << 30):
    """At most 1 GB more address space than now: a bomb that expanded would fail here with a
    MemoryError instead of eating the machine."""
    with open("/proc/self/statm") as f:
        in_use = int(f.read().split()[0]) * resource.getpagesize()
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    resource.setrlimit(resource.RLIMIT_AS, (in_use + extra_bytes, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


def alias_bomb(key: str) -> str:
    """'billion laughs': 9 levels of 9 aliases, 9^9 (387 million) strings once expanded."""
    lines = ['lol0: &l0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for level in range(1, 9):
        lines.append(f"lol{level}: &l{level} [" + ", ".join([f"*l{level - 1}"] * 9) + "]")
    return "\n".join(lines) + f"\n{key}: *l8\n"


# How each YAML input is read by the command line, and a key at its top level.
def _procedure_cmd(path, tmp_path):
    return ["run", "--headless", "--procedure", str(path), "--out", str(tmp_path / "out")]


def _config_cmd(path, tmp_path):
    return ["monitor", "--config", str(path), "--samples", "1"]


def _map_cmd(path, tmp_path):
    data = tmp_path / "data.csv"
    data.write_text("0,0,0,0,0,0,0\n")
    return ["import", str(data), "--map", str(path), "--out", str(tmp_path / "out")]


KINDS = {"procedure": (PROCEDURE, _procedure_cmd, "title"),
         "config": (CONFIG, _config_cmd, "device"),
         "import map": (IMPORT_MAP, _map_cmd, "description")}


@pytest.fixture(params=sorted(KINDS))
def kind(request):
    return request.param


HOSTILE = {
    "alias bomb": lambda text, key: alias_bomb(key),
    "self-referring alias": lambda text, key: f"{key}: &a [*a]\n",
    "python tag": lambda text, key: f"{key}: !!python/object/apply:os.system ['true']\n" + text,
    "str tag": lambda text, key: text.replace(f"{key}:", f"{key}: !!str", 1),
    "huge document": lambda text, key: text + "#" + "x" * MAX_YAML_BYTES + "\n",
    "syntax error": lambda text, key: text + "\n  - [unclosed\n",
    "a list": lambda text, key: "- 1\n- 2\n",
    "empty": lambda text, key: "",
    "duplicate key": lambda text, key: text + f"\n{key}: again\n",
    "deep nesting": lambda text, key: "[" * 20000 + "]" * 20000 + "\n",  # a C parser's stack
    "tab before a value": lambda text, key: text.replace(f"{key}:", f"{key}:\t", 1),
}


@pytest.mark.parametrize("hostile", sorted(HOSTILE))
def test_hostile_yaml_is_one_line(capsys, tmp_path, kind, hostile):
    text, command, key = KINDS[kind]
    path = tmp_path / "hostile.yaml"
    path.write_text(HOSTILE[hostile](text, key))
    with memory_cap():
        refused(capsys, command(path, tmp_path), names=path)


def test_alias_bomb_is_refused_before_expanding(capsys, tmp_path):
    path = tmp_path / "bomb.yaml"
    path.write_text(alias_bomb("title") + PROCEDURE.replace("title:", "subtitle:"))
    line = refused(capsys, _procedure_cmd(path, tmp_path), names=path)
    assert "aliases" in line


def test_binary_file_is_one_line(capsys, tmp_path, kind):
    path = tmp_path / "binary.yaml"
    path.write_bytes(bytes(range(256)) * 4)
    line = refused(capsys, KINDS[kind][1](path, tmp_path), names=path)
    assert "UTF-8" in line


def test_syntax_error_names_the_line(capsys, tmp_path, kind):
    text = KINDS[kind][0]
    path = tmp_path / "broken.yaml"
    path.write_text(text + "\nbroken: [\n")
    line = refused(capsys, KINDS[kind][1](path, tmp_path), names=path)
    assert f"line {text.count(chr(10)) + 3}" in line


# A misspelt key must not be ignored (a typo `rate_stepp` silently dropped the gyro steps).
@pytest.mark.parametrize("kind_, old, new, field, guess", [
    ("procedure", "rate_step:", "rate_stepp:", "rate_stepp", "rate_step"),
    ("procedure", "dwell_s:", "dwel_s:", "dwel_s", "dwell_s"),
    ("config", "  rate_hz:", "  rate_hz_:", "device.rate_hz_", "rate_hz"),
    ("config", "station:", "statoin:", "statoin", "station"),
    ("import map", "delimiter:", "delimter:", "files[0].delimter", "delimiter"),
])
def test_unknown_key_names_the_nearest(capsys, tmp_path, kind_, old, new, field, guess):
    text, command, _ = KINDS[kind_]
    assert old in text
    changed = text.replace(old, new, 1)
    path = tmp_path / "typo.yaml"
    path.write_text(changed)
    line_no = changed[: changed.index(new)].count("\n") + 1
    line = refused(capsys, command(path, tmp_path), names=path)
    assert line == (f"fieldcal: {path}: {field}: unknown key {new.strip().rstrip(':')!r}; "
                    f"did you mean {guess!r}? (line {line_no})")


@pytest.mark.parametrize("old, new, message", [
    ("dwell_s: 200", 'dwell_s: 200\naligned: "false"',
     "aligned: expected true or false (unquoted), got 'false'"),
    ("name: field-18", "name: [1, 2]", "name: expected a non-empty string, got a list of 2 items"),
    ("name: field-18", 'name: ""', "name: expected a non-empty string, got ''"),
    ("name: field-18", 'name: "../../../escaped"', "name: expected a plain file name"),
    ("name: field-18", f"name: {'x' * 300}", "name: expected a plain file name"),
    ("title: Fast", "title: [Fast", "not valid YAML"),
    ("rate_step: {rate_deg_s: 10, turns: 1,", "rate_step: {rate_deg_s: 10, turns: true,",
     "rate_step.turns: expected a whole number from 1 to 100, got true"),
    ("dwell_s: 200\n", "", "dwell_s: missing (a required key)"),
    ("{id: 1, ", "{", "positions[0].id: missing (a required key)"),
])
def test_procedure_fields_are_strict(capsys, tmp_path, old, new, message):
    assert old in PROCEDURE
    path = tmp_path / "strict.yaml"
    path.write_text(PROCEDURE.replace(old, new, 1))
    line = refused(capsys, _procedure_cmd(path, tmp_path), names=path)
    assert message in line and "None" not in line
    assert not (tmp_path / "out").exists()  # refused before anything was written


def test_procedure_booleans_are_real_booleans():
    assert load_procedure("classic-12").aligned is True
    assert load_procedure("field-18").aligned is False


@pytest.mark.parametrize("drop, field", [("device", "device"), ("station", "station"),
                                         ("triads", "device.triads")])
@pytest.mark.parametrize("command", [
    ["monitor", "--samples", "1"], ["run", "--headless"], ["tui", "--go", "--no-capture"]])
def test_config_missing_a_section_is_one_line(capsys, tmp_path, drop, field, command):
    doc = yaml.safe_load(CONFIG)
    if drop == "triads":
        del doc["device"]["triads"]
    else:
        del doc[drop]
    path = tmp_path / "station.yaml"
    path.write_text(yaml.safe_dump(doc))
    argv = command + ["--config", str(path)] + (["--out", str(tmp_path)] if command[0] == "run" else [])
    line = refused(capsys, argv, names=path)
    assert f"{field}: missing" in line


def test_parameter_file_alias_bomb_is_one_line(tmp_path):
    path = tmp_path / "cal.yaml"
    path.write_text(alias_bomb("schema"))
    with pytest.raises(ParameterFileError) as info:
        load_parameters(path)
    assert str(info.value).startswith(f"{path}: ") and "\n" not in str(info.value)
    assert "aliases" in str(info.value)


# ------------------------------------------------------------------------------------------------
# fieldcal sim serve: its numbers, and no stale links after SIGTERM


@pytest.mark.parametrize("flag, value", [("--rate", "0"), ("--rate", "nan"), ("--rate", "-5"),
                                         ("--rate", "inf"), ("--rate", "1e9"), ("--speed", "nan"),
                                         ("--speed", "-1"), ("--speed", "inf")])
def test_sim_serve_numbers_are_checked(capsys, flag, value):
    with pytest.raises(SystemExit) as info:
        main(["sim", "serve", flag, value])
    err = capsys.readouterr().err
    assert info.value.code == 2 and "Traceback" not in err
    assert f"argument {flag}: expected a number" in err and repr(value) in err


def test_sim_serve_removes_its_links_on_sigterm(tmp_path):
    import os
    import signal
    import subprocess
    import sys
    from pathlib import Path

    proc = subprocess.Popen([sys.executable, "-m", "fieldcal.cli.main", "sim", "serve", "--speed", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        imu = Path(proc.stdout.readline().rsplit(": ", 1)[1].strip())
        table = Path(proc.stdout.readline().rsplit(": ", 1)[1].strip())
        assert proc.stdout.readline().startswith("serving")
        assert imu.is_symlink() and table.is_symlink()
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0 and "Traceback" not in err, err
    assert out.startswith("stopped after ")
    for link in (imu, table):
        assert not os.path.lexists(link) and not link.parent.exists()


# ------------------------------------------------------------------------------------------------
# fieldcal monitor: a port that never opens, a device in another protocol


def _device_config(tmp_path, url: str, protocol: str = "vectornav"):
    path = tmp_path / "device.yaml"
    path.write_text(f"""device:
  name: unit under test
  protocol: {protocol}
  rate_hz: 250
  port: {{url: {url}, baudrate: 115200}}
  triads:
    accelerometer: {{kind: specific_force, unit: m/s^2}}
    gyroscope: {{kind: angular_rate, unit: rad/s}}
station: {{latitude_deg: 40.0}}
""")
    return path


def test_monitor_on_a_port_that_never_opens(capsys, tmp_path):
    port = tmp_path / "ttyUSB9"
    config = _device_config(tmp_path, str(port))
    assert main(["monitor", "--config", str(config), "--seconds", "0.5"]) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err and "port lost" not in err and "Errno" not in err
    said = [line for line in err.splitlines() if line.startswith("cannot open")]
    assert said == [f"cannot open {port}: No such file or directory; retrying every 2 s (Ctrl-C to stop)"]
    assert err.splitlines()[-1] == (f"fieldcal: no samples: {port} never opened (is the unit plugged "
                                    f"in, and is device.port.url in {config} right?)")


def test_monitor_of_a_device_in_another_protocol(capsys, tmp_path):
    from drivers.sim.device import paper_mimu
    from drivers.sim.serve import SimulatedDevices

    with SimulatedDevices(paper_mimu(), 9.8, 0.7, imu_protocol="xsens", table_protocol=None) as sim:
        config = _device_config(tmp_path, sim.imu_url, protocol="vectornav")
        assert main(["monitor", "--config", str(config), "--seconds", "1"]) == 1
    err = capsys.readouterr().err
    last = err.splitlines()[-1]
    assert "Traceback" not in err and last.startswith("fieldcal: no samples: ")
    assert "none decoded as vectornav frames: check device.protocol and the baud rate " \
           f"(device.port.baudrate, now 115200) in {config}" in last


# ------------------------------------------------------------------------------------------------
# Recordings: a wild sample, a rest too short to measure the noise


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    from drivers.sim.handheld import simulate_handheld, to_text
    return to_text(simulate_handheld(3, n_poses=5), tmp_path_factory.mktemp("recording"))


def test_a_wild_sample_is_refused_with_its_line(capsys, tmp_path, recording):
    """Issue 16: one 1e308 sample ended in "add poses with z down"."""
    acc, gyro = recording
    lines = acc.read_text().splitlines(True)
    fields = lines[4999].split()
    fields[2] = "1e308"
    lines[4999] = " ".join(fields) + "\n"
    wild = tmp_path / "acc.txt"
    wild.write_text("".join(lines))
    line = refused(capsys, ["calibrate", str(wild), str(gyro), "--map", "imu_tk", "--latitude", "40",
                            "--out", str(tmp_path / "s")], names=wild)
    assert line == (f"fieldcal: {wild}: line 5000: accelerometer reads 1e+308 count, beyond any "
                    "sensor's range (|x| > 1e+12): fix or delete the line (1 such line in the file)")


def test_a_rest_too_short_to_measure_is_said(capsys, tmp_path, recording):
    """Issue 16: --rest 0.4 gave "attempt to get argmax of an empty sequence"."""
    acc, gyro = recording
    line = refused(capsys, ["calibrate", str(acc), str(gyro), "--map", "imu_tk", "--latitude", "40",
                            "--rest", "0.4", "--out", str(tmp_path / "s")], names="an initial rest")
    assert "of 0.4 s is too short to measure the noise" in line and "(--rest)" in line


@pytest.mark.parametrize("old, new, message", [
    ("  height_m: 50.0", "  height_m: -1.0e+9",
     "station.height_m: expected a number from -500 to 9000 m above the ellipsoid, got -1000000000.0 (line 19)"),
    ("    gyroscope: {kind", '    "../../gyro": {kind',
     "device.triads: expected triad names of ASCII letters, digits and _ (starting with a letter), "
     "got '../../gyro' (line 14)"),
])
def test_config_values_are_named_with_the_file(capsys, tmp_path, old, new, message):
    """Issue 16: station errors named no file; a triad name is part of file names (allan plots)."""
    assert old in CONFIG
    path = tmp_path / "station.yaml"
    path.write_text(CONFIG.replace(old, new, 1))
    line = refused(capsys, ["monitor", "--config", str(path), "--samples", "1"], names=path)
    assert line == f"fieldcal: {path}: {message}"


def test_remembered_setup_alias_bomb_is_forgotten(tmp_path):
    """The TUI's remembered setup is a convenience: a hostile one is ignored, never expanded."""
    from fieldcal.tui.choices import load_last_choice

    path = tmp_path / "last.yaml"
    path.write_text(alias_bomb("config"))
    with memory_cap():
        assert load_last_choice(path) is None


@pytest.mark.parametrize("value", ["nan", "-1", "0", "inf"])
def test_replay_speed_is_checked(capsys, value):
    with pytest.raises(SystemExit) as info:
        main(["replay", "somewhere", "--speed", value])
    err = capsys.readouterr().err
    assert info.value.code == 2 and f"argument --speed: expected a number > 0, got {value!r}" in err
