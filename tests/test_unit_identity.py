"""Issue 23: every unit has an identity. `--unit-serial` (or a config's device.serial) names the
unit on run, calibrate, import and resume; the registry lists it by that serial; a run without
one is recorded as such, listed and shown, and drift is never taken across different or missing
serials."""
from __future__ import annotations

import hashlib
import re

import numpy as np
import pytest

from drivers.sim.handheld import simulate_handheld, to_text
from fieldcal.acceptance import evaluate, spec_from_document
from fieldcal.calibration import Calibration
from fieldcal.cli.main import main
from fieldcal.config import CONFIGS_DIR
from fieldcal.earth import Station
from fieldcal.model import k_from_params
from fieldcal.paramfile import ParameterFile, load, save
from fieldcal.procedure.positions import load_procedure
from fieldcal.run.runner import RunSpec
from fieldcal.session.history import previous_calibration
from fieldcal.units import STANDARD_GRAVITY

MG = STANDARD_GRAVITY * 1e-3
SPEC = spec_from_document({"schema": "fieldcal-spec/1", "product": "MIMU-9", "triads": {
    "accelerometer": {"bias": {"unit": "mg", "max_drift": 1.0}}}}, "spec.yaml")


def unit_file(path, serial, bias_mg):
    theta = np.r_[np.array(bias_mg) * MG, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0]
    cal = Calibration(name="accelerometer", kind="specific_force", output_unit="m/s^2", method="powell",
                      K=k_from_params(theta), bias=theta[:3], sigma=np.r_[[0.03 * MG] * 3, [1e-5] * 6],
                      residual_rms=1e-4)
    pf = ParameterFile.build((cal,), station=Station(40.0, 50.0), procedure="field-18", method="powell",
                             input_sha256=hashlib.sha256(str((serial, bias_mg)).encode()).hexdigest(),
                             device_name="MIMU-9", device_serial=serial)
    return save(pf, path)


def units_listed(capsys, registry) -> dict[str, int]:
    capsys.readouterr()
    assert main(["units", "--registry", str(registry)]) == 0
    rows = capsys.readouterr().out.splitlines()[1:]
    return {row.split()[0]: int(re.search(r"\s(\d+)\s+\d{4}-", row).group(1)) for row in rows}


def test_drift_only_between_calibrations_of_one_serial(tmp_path):
    """Bias x 2 mg then 5 mg: 3 mg of drift (over the 1 mg limit) when both files name unit A;
    none at all (a note says why) when either has no serial or the serials differ."""
    now = load(unit_file(tmp_path / "now.yaml", "A", [5.0, 0.0, 0.0]))
    cases = {"A": None, "B": "of unit 'B', this one of 'A'", None: "previous calibration's unit has no serial"}
    for serial, why in cases.items():
        before = load(unit_file(tmp_path / f"before-{serial}.yaml", serial, [2.0, 0.0, 0.0]))
        verdict = evaluate(SPEC, now, before)
        drift = {c.parameter: c.drift for c in verdict.checks}["bias_x"]
        if why is None:
            assert drift == pytest.approx(3.0) and not verdict.passed
        else:
            assert drift is None and verdict.passed
            assert any(n.startswith("drift not checked") and why in n for n in verdict.notes), verdict.notes
    unnamed = load(unit_file(tmp_path / "unnamed.yaml", None, [5.0, 0.0, 0.0]))
    before = load(tmp_path / "before-None.yaml")
    verdict = evaluate(SPEC, unnamed, before)  # two serial-less files are not one unit either
    assert {c.parameter: c.drift for c in verdict.checks}["bias_x"] is None
    assert any("this calibration's unit has no serial" in n for n in verdict.notes)


def test_a_unit_without_a_serial_has_no_previous_calibration(tmp_path):
    for name, serial in (("s1", None), ("s2", None), ("s3", "A")):
        (tmp_path / name).mkdir()
        unit_file(tmp_path / name / "parameters.yaml", serial, [1.0, 0.0, 0.0])
    assert previous_calibration(tmp_path, "MIMU-9", None, exclude=tmp_path / "s1") == (None, 0)
    found, _ = previous_calibration(tmp_path, "MIMU-9", "A", exclude=tmp_path / "s1")
    assert found is not None and found.path.parent.name == "s3"


def test_check_with_a_previous_file_of_another_unit_takes_no_drift(tmp_path, capsys):
    now = unit_file(tmp_path / "now.yaml", "A", [5.0, 0.0, 0.0])
    other = unit_file(tmp_path / "other.yaml", "B", [2.0, 0.0, 0.0])
    (tmp_path / "spec.yaml").write_text("schema: fieldcal-spec/1\nproduct: MIMU-9\ntriads:\n"
                                        "  accelerometer: {bias: {unit: mg, max_drift: 1.0}}\n")
    assert main(["check", str(now), "--spec", str(tmp_path / "spec.yaml"), "--previous", str(other)]) == 0
    out = capsys.readouterr().out
    assert "drift since" not in out and "drift not checked: the previous calibration is of unit 'B'" in out


def short_field18(tmp_path) -> str:
    """field-18 with 20 s dwells and 30 °/s turns (test_headless's): every triad solves, from a
    tenth of the samples, which is all a test of the unit's serial needs of a run."""
    path = tmp_path / "field-18-short.yaml"
    path.write_text(load_procedure("field-18").text.replace("dwell_s: 200", "dwell_s: 20")
                    .replace("rate_deg_s: 10", "rate_deg_s: 30"), encoding="utf-8")
    return str(path)


def test_the_simulator_keeps_the_serial_given_on_the_command_line_or_in_its_config(tmp_path, capsys):
    """`units` lists the simulated unit by the serial of `--unit-serial`, else of the config's
    device.serial; a run with neither is listed as (none), and `history "(none)"` shows it
    without taking any drift."""
    registry = tmp_path / "r.sqlite"
    config = tmp_path / "sim-serial.yaml"
    text = (CONFIGS_DIR / "sim.yaml").read_text()
    config.write_text(text.replace("  rate_hz: 250\n", "  rate_hz: 250\n  serial: SIM-CONF-7\n", 1))
    common = ["run", "--headless", "--out", str(tmp_path / "s"), "--quiet", "--registry", str(registry),
              "--procedure", short_field18(tmp_path)]
    assert main([*common, "--config", str(config)]) == 0
    assert main([*common, "--unit-serial", "SIM-ARG-1", "--seed", "2"]) == 0
    assert main([*common, "--seed", "3"]) == 0
    assert main([*common, "--seed", "4"]) == 0
    assert units_listed(capsys, registry) == {"SIM-CONF-7": 1, "SIM-ARG-1": 1, "(none)": 2}
    serials = {load(p).provenance.device_serial for p in (tmp_path / "s").glob("*/parameters.yaml")}
    assert serials == {"SIM-CONF-7", "SIM-ARG-1", None}
    assert main(["history", "(none)", "--registry", str(registry)]) == 0
    out = capsys.readouterr().out
    assert "#2 " in out and "σ)" not in out and "no drift is taken between them" in out


def test_run_spec_keeps_the_serial_through_the_session_metadata():
    spec = RunSpec(load_procedure("field-18"), Station(40.0, 50.0), unit_serial="SIM-9")
    again = RunSpec.from_metadata(spec.session_metadata("in-process"))
    assert again.device_serial == "SIM-9"
    unnamed = RunSpec.from_metadata(RunSpec(load_procedure("field-18"), Station(40.0, 50.0)).session_metadata(None))
    assert unnamed.device_serial is None


def test_resume_refuses_another_units_serial(tmp_path, capsys):
    out = tmp_path / "s"
    assert main(["run", "--headless", "--out", str(out), "--quiet", "--unit-serial", "SIM-5",
                 "--procedure", short_field18(tmp_path),
                 "--registry", str(tmp_path / "r.sqlite")]) == 0
    session = next(out.iterdir())
    capsys.readouterr()
    assert main(["resume", str(session), "--unit-serial", "SIM-6"]) == 2
    err = capsys.readouterr().err
    assert "is a run of unit 'SIM-5', not 'SIM-6'" in err and err.count("\n") == 1


@pytest.mark.parametrize("bad", ["", "   ", "a\tb"])
def test_a_bad_serial_is_one_line(bad, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["run", "--headless", "--unit-serial", bad])
    assert exc.value.code == 2 and "--unit-serial: expected the unit's serial number" in capsys.readouterr().err


def test_import_and_calibrate_keep_the_unit_serial(tmp_path, capsys):
    """`import --unit-serial` keeps it in the session, `calibrate SESSION` writes it into the
    parameter file and the registry, and refuses another; `calibrate --config` keeps the
    config's device.serial."""
    sim = simulate_handheld(2, n_poses=16)
    acc, gyro = to_text(sim, tmp_path)
    registry = tmp_path / "r.sqlite"
    session = tmp_path / "imported"
    assert main(["import", str(acc), str(gyro), "--map", "imu_tk", "--out", str(session),
                 "--unit-serial", "HH-1"]) == 0
    assert main(["calibrate", str(session), "--latitude", "40", "--registry", str(registry)]) == 0
    assert load(session / "parameters.yaml").provenance.device_serial == "HH-1"
    capsys.readouterr()
    assert main(["calibrate", str(session), "--latitude", "40", "--unit-serial", "HH-2",
                 "--registry", str(registry)]) == 2
    assert "was imported as unit 'HH-1', not 'HH-2'" in capsys.readouterr().err

    config = tmp_path / "vn100-serial.yaml"
    text = (CONFIGS_DIR / "vn100.yaml").read_text()
    config.write_text(text.replace("  rate_hz: 200\n", "  rate_hz: 200\n  serial: VN-CONF-3\n", 1))
    assert main(["calibrate", str(acc), str(gyro), "--map", "imu_tk", "--config", str(config),
                 "--latitude", "40", "--out", str(tmp_path / "c"), "--registry", str(registry)]) == 0
    written = next((tmp_path / "c").glob("*/parameters.yaml"))
    assert load(written).provenance.device_serial == "VN-CONF-3"
    assert units_listed(capsys, registry) == {"HH-1": 1, "VN-CONF-3": 1}


def test_shipped_configs_carry_no_serial():
    """A serial in a shipped config would be every copied config's: all their units one unit."""
    from fieldcal.config import load_config

    for path in CONFIGS_DIR.glob("*.yaml"):
        assert load_config(path).device.serial is None, path


def test_the_terminal_ui_takes_the_unit_serial_for_the_simulator_and_a_live_device(tmp_path):
    """`tui --unit-serial` names the simulated unit, and a live device's over its config's."""
    import types

    from fieldcal.cli.tui import live_spec, sim_run
    from fieldcal.config import load_config

    args = types.SimpleNamespace(seed=None, method="auto", on_motion="restart", thermal=None, speed=None, no_capture=True,
                                 out=str(tmp_path), unit_serial="TUI-1")
    spec, _, _ = sim_run(load_config("sim"), load_procedure("field-18"), args)
    assert spec.device_serial == "TUI-1"
    assert RunSpec.from_metadata(spec.session_metadata(None, "tui")).device_serial == "TUI-1"
    args.unit_serial = None
    assert sim_run(load_config("sim"), load_procedure("field-18"), args)[0].device_serial is None
    (tmp_path / "static.yaml").write_text(
        "name: static\ndwell_s: 20\npositions:\n"
        "  - {id: 1, description: z up, axes: {x: south, y: east, z: up}}\n")
    procedure = load_procedure(str(tmp_path / "static.yaml"))
    args.unit_serial = "VN-77"
    assert live_spec(load_config("vn100"), procedure, args).device_serial == "VN-77"
    args.unit_serial = None
    assert live_spec(load_config("vn100"), procedure, args).device_serial is None  # ships none
