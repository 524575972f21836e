import re

import pytest

import numpy as np

from fieldcal.cli.main import main


def test_demo_prints_every_triad_beside_its_truth(capsys):
    assert main(["demo", "--seed", "3"]) == 0
    out = capsys.readouterr().out
    for triad in ("accelerometer", "gyroscope", "inclinometer"):
        assert f"{triad} (powell" in out
    worst = float(re.search(r"largest error: ([0-9.]+)σ", out).group(1))
    assert worst < 4.0
    assert "g = 9.801" in out and "mg" in out and "°/h" in out


def test_demo_raw_counts_reports_counts(capsys):
    assert main(["demo", "--seed", "4", "--raw-counts"]) == 0
    out = capsys.readouterr().out
    assert "count" in out and float(re.search(r"largest error: ([0-9.]+)σ", out).group(1)) < 4.0


def test_bad_procedure_is_one_line_error(capsys, tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\ndwell_s: 200\npositions:\n  - {id: 1, axes: {x: up, y: east, z: south}}\n")
    assert main(["demo", "--procedure", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "bad.yaml: positions[0].axes" in err and "left-handed" in err
    assert main(["demo", "--procedure", "no-such-procedure"]) == 2
    assert capsys.readouterr().err.startswith("fieldcal: no-such-procedure: no such procedure (not a file, nor ")
    assert main(["demo", "--procedure", str(tmp_path)]) == 2  # a directory
    assert capsys.readouterr().err == f"fieldcal: {tmp_path}: cannot read procedure (Is a directory)\n"


def test_demo_parameter_file_loads_and_is_deterministic(capsys, tmp_path):
    from fieldcal.paramfile import load

    first, second = tmp_path / "a.yaml", tmp_path / "b.yaml"
    assert main(["demo", "--seed", "5", "--params", str(first)]) == 0
    assert main(["demo", "--seed", "5", "--params", str(second)]) == 0
    assert first.read_bytes() == second.read_bytes()
    pf = load(first)
    assert set(pf.names) == {"accelerometer", "gyroscope", "inclinometer"}
    assert pf.provenance.simulation is True and pf.provenance.procedure == "field-18"
    # The file's calibration undoes the simulated device's errors.
    from drivers.sim.device import paper_mimu
    acc = paper_mimu()["accelerometer"]
    true = np.array([[0.0, 0.0, 9.8], [3.0, -4.0, 8.0]])
    recovered = pf["accelerometer"].calibrate(true @ acc.K.T + acc.bias)
    np.testing.assert_allclose(recovered, true, atol=3e-3)  # a few σ of the bias, in m/s²


def test_measured_gravity_overrides_the_model_and_bad_values_are_refused(capsys):
    assert main(["demo", "--seed", "6", "--gravity", "9.80200"]) == 0
    assert "g = 9.802000 m/s² (measured)" in capsys.readouterr().out
    assert main(["demo", "--gravity", "98.02"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "fieldcal: --gravity: expected 9.7..9.9 m/s², got 98.02"


def _procedure_subset(tmp_path, count: int) -> str:
    import yaml

    from fieldcal.procedure.positions import PROCEDURES_DIR
    doc = yaml.safe_load((PROCEDURES_DIR / "field-18.yaml").read_text())
    doc["positions"] = doc["positions"][:8] + doc["positions"][12:12 + count - 8]
    path = tmp_path / f"first-{count}.yaml"
    path.write_text(yaml.safe_dump(doc, allow_unicode=True))
    return str(path)


def test_nine_positions_solve_as_an_exact_fit(capsys, tmp_path):
    assert main(["demo", "--procedure", _procedure_subset(tmp_path, 9)]) == 0
    out = capsys.readouterr().out
    assert "exact fit, no χ²" in out and "largest error" in out


def test_procedure_that_cannot_calibrate_says_why_per_triad(capsys, tmp_path):
    # The shape of the shipped "allan" procedure (one position, no rate steps), with a 60 s
    # record instead of its 6 h: the reasons depend on the shape only.
    from fieldcal.procedure.positions import PROCEDURES_DIR
    one_position = tmp_path / "allan-short.yaml"
    one_position.write_text((PROCEDURES_DIR / "allan.yaml").read_text().replace("dwell_s: 21600", "dwell_s: 60"))
    assert main(["demo", "--procedure", str(one_position)]) == 1
    out = capsys.readouterr().out
    assert "accelerometer: not calibrated: accelerometer: 1 equations for 9 unknowns" in out
    assert "gyroscope: not calibrated: gyroscope: the procedure has no rate steps" in out


def test_aligned_procedure_uses_the_classic_solver(capsys):
    assert main(["demo", "--procedure", "classic-12", "--seed", "2"]) == 0
    out = capsys.readouterr().out
    assert "accelerometer (classic least squares over 12 averages" in out
    assert "gyroscope (classic least squares over 24 averages" in out


@pytest.mark.parametrize("argv, message", [
    (["demo", "--height", "1e7"], "--height: expected -500..9000 m above the ellipsoid, got 10000000.0"),
    (["demo", "--height", "nan"], "--height: expected -500..9000 m above the ellipsoid, got nan"),
    (["demo", "--latitude", "91"], "--latitude: expected -90..90, got 91.0"),
    (["demo", "--gravity", "3"], "--gravity: expected 9.7..9.9 m/s², got 3.0"),
    (["sim", "serve", "--latitude", "-91"], "--latitude: expected -90..90, got -91.0"),
])
def test_bad_station_is_one_line_error(capsys, argv, message):
    assert main(argv) == 2
    assert capsys.readouterr().err.strip() == f"fieldcal: {message}"


def test_negative_seed_is_refused_by_name(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["demo", "--seed", "-1"])
    assert exit_info.value.code == 2
    assert "argument --seed: expected a whole number >= 0, got '-1'" in capsys.readouterr().err


@pytest.mark.parametrize("field, value, message", [
    ("dwell_s", ".inf", "dwell_s: expected a number from 1 to 86400 s, got .inf (line 7)"),
    ("dwell_s", "0.001", "dwell_s: expected a number from 1 to 86400 s, got 0.001 (line 7)"),
    ("rate_deg_s", "1.0e-9", "rate_step.rate_deg_s: expected a number from 0.1 to 400 °/s, got 1e-09 (line 8)"),
])
def test_procedure_numbers_are_bounded(capsys, tmp_path, field, value, message):
    from fieldcal.procedure.positions import PROCEDURES_DIR
    text = (PROCEDURES_DIR / "field-18.yaml").read_text()
    text = text.replace("dwell_s: 200", f"dwell_s: {value}") if field == "dwell_s" else \
        text.replace("rate_deg_s: 10", f"rate_deg_s: {value}")
    path = tmp_path / "bounded.yaml"
    path.write_text(text)
    assert main(["demo", "--procedure", str(path)]) == 2
    assert capsys.readouterr().err.strip() == f"fieldcal: {path}: {message}"


# ------------------------------------------------------------------------------------------------
# fieldcal solve: every parameter ± 1σ from the log's averages, samples.bin or not


@pytest.fixture(scope="module")
def short_field18_session(tmp_path_factory):
    """A headless run of field-18's positions with 4 s dwells and 60 °/s turns (tests/brisk_quick.py:
    everything solves, in 645 s of simulation)."""
    from brisk_quick import brisk_quick
    from fieldcal.earth import Station
    from fieldcal.procedure.positions import load_procedure
    from fieldcal.run.runner import RunSpec, run_headless

    procedure = load_procedure(brisk_quick(tmp_path_factory.mktemp("procedure")))
    spec = RunSpec(procedure, Station(40.0, 50.0), seed=5)
    return spec, run_headless(spec, tmp_path_factory.mktemp("solve") / "session")


# The operator's units, written out by hand (not through fieldcal.units): SI truth -> display.
_MG_PER_M_S2 = 1e3 / 9.80665
_DEG_H_PER_RAD_S = 180 / np.pi * 3600
_ROW_UNITS = {"specific_force": ("mg", _MG_PER_M_S2), "angular_rate": ("°/h", _DEG_H_PER_RAD_S)}
_LABELS = ("bias x", "bias y", "bias z", "scale x", "scale y", "scale z", "Δyz", "Δzy", "Δzx")


def _solve_tables(out: str) -> dict[str, dict[str, list[tuple[float, str]]]]:
    """triad -> row label -> [(number, unit)] as printed (value, σ per method)."""
    tables, triad = {}, None
    for line in out.splitlines():
        head = re.match(r"^(\w+) \((powell|lsq|classic)", line)
        if head:
            triad = head.group(1)
            tables.setdefault(triad, {})
            continue
        row = re.match(r"^  (bias [xyz]|scale [xyz]|Δ\w\w|m \w\w) (.*)$", line)
        if row and triad:
            tokens = row.group(2).split()
            cells = []
            for i, t in enumerate(tokens):
                try:
                    value = float(t)
                except ValueError:
                    continue
                unit = tokens[i + 1] if i + 1 < len(tokens) and not re.match(r"^[-+\d.]", tokens[i + 1]) else ""
                cells.append((value, unit))
            tables[triad][row.group(1)] = cells
    return tables


def test_solve_prints_every_parameter_within_its_sigma_of_the_truth_without_samples(
        tmp_path, capsys, short_field18_session):
    import shutil

    spec, result = short_field18_session
    copy = tmp_path / "session"
    shutil.copytree(result.session, copy)
    (copy / "samples.bin").unlink()  # the averages are in the log: enough to solve
    assert main(["solve", str(copy)]) == 0
    out = capsys.readouterr().out
    assert "re-solved from their averages in log.jsonl" in out
    tables = _solve_tables(out)
    truth, device = spec.truth(), spec.device()
    assert set(tables) == set(truth) == {"accelerometer", "gyroscope", "inclinometer"}
    for name, rows in tables.items():
        assert tuple(rows) == _LABELS, name  # misalignments too, not only bias and scale
        bias_unit, bias_factor = _ROW_UNITS[device[name].kind]
        for j, label in enumerate(_LABELS):
            cells = rows[label]
            assert len(cells) == 4, (name, label, cells)  # powell value ± σ, lsq value ± σ
            if j < 3:
                want_unit, factor = bias_unit, bias_factor
                assert [u for _, u in cells] == [bias_unit] * 4
            elif j < 6:  # a dimensionless factor, its σ in ppm
                want_unit, factor = "", 1.0
                assert [u for _, u in cells] == ["", "ppm", "", "ppm"]
            else:
                want_unit, factor = "mrad", 1e3
                assert [u for _, u in cells] == ["mrad"] * 4
            true = truth[name][j] * factor
            for (value, _), (sigma, _) in (cells[0:2], cells[2:4]):
                sigma = sigma * 1e-6 if j in (3, 4, 5) else sigma
                assert sigma > 0 and abs(value - true) < 4.5 * sigma + 1e-4 * abs(true), \
                    (name, label, value, true, sigma, want_unit)


def test_solve_of_a_session_without_its_log_says_so(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert main(["solve", str(tmp_path / "empty")]) != 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "log.jsonl" in err


def test_resume_refuses_a_config_for_a_simulated_session(tmp_path, capsys):
    """--config names the ports a live session is continued on; a simulator session has none, so
    the flag is refused in one line rather than ignored (the run would go on, on the simulator)."""
    import shutil
    from pathlib import Path

    session = tmp_path / "tui-quit"
    shutil.copytree(Path(__file__).parent / "data" / "golden" / "tui-quit", session)
    log_before = (session / "log.jsonl").read_bytes()
    assert main(["resume", str(session), "--config", "vn100", "--quiet"]) == 2
    captured = capsys.readouterr()
    assert captured.err.strip().count("\n") == 0 and "Traceback" not in captured.err
    assert "--config is for a live session's ports" in captured.err and "ran on the simulator" in captured.err
    assert "resuming" not in captured.out
    assert (session / "log.jsonl").read_bytes() == log_before and not (session / "parameters.yaml").exists()
