import re

import numpy as np

from fieldcal.cli import main


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
    assert "\n" not in err and "bad.yaml.positions[0].axes" in err and "left-handed" in err
    assert main(["demo", "--procedure", "no-such-procedure"]) == 2
    assert "cannot read procedure" in capsys.readouterr().err


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
    assert err == "fieldcal: gravity_m_s2: expected 9.7..9.9 m/s², got 98.02"
