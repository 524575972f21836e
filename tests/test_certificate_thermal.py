"""The thermal model on the certificate (issue 28): a session whose unit warmed shows each
triad's reference, range, order and terms ± 1σ in operator units, as the parameter file holds
them, with the spec's thermal limits and verdicts, and its bias against temperature with a ±1σ
band worked out here; an old session's certificate has no thermal section."""
from __future__ import annotations

import numpy as np
import pytest

from drivers.sim.thermal import SimThermal, TemperatureProfile, ThermalTruth
from fieldcal.certificate.thermal import bias_band
from fieldcal.cli.main import main
from fieldcal.earth import Station
from fieldcal.paramfile import load
from fieldcal.procedure.positions import load_procedure, parse_procedure
from fieldcal.units import STANDARD_GRAVITY
from test_certificate import Page, assert_self_contained

MG = STANDARD_GRAVITY * 1e-3
DEG_H = np.pi / 180 / 3600


@pytest.fixture(scope="module")
def warm_session(tmp_path_factory):
    """A short field-18 (3 s dwells at 20 Hz) through the conductor, the unit warming 0.05 K/s
    (as tests/test_thermal_solver.py's): the accelerometer's bias 3, -5, 8 mg/K, the gyro's
    0.02, -0.05, 0.08 °/s/K."""
    from fieldcal.run.runner import RunSpec, run_headless

    text = load_procedure("field-18").text.replace("name: field-18", "name: mini").replace("dwell_s: 200", "dwell_s: 3") \
        .replace("rate_step: {rate_deg_s: 10, turns: 1, ramp_s: 2, settle_s: 1}",
                 "rate_step: {rate_deg_s: 60, turns: 1, ramp_s: 3, settle_s: 1}")
    thermal = SimThermal(TemperatureProfile("ramp", start_c=10.0, rise_k=30.0, rate_k_per_s=0.05),
                         {"accelerometer": ThermalTruth(25.0, np.array([[3.0, -5.0, 8.0]]) * MG, np.zeros(3)),
                          "gyroscope": ThermalTruth(25.0, np.radians([[0.02, -0.05, 0.08]]), np.zeros(3))})
    spec = RunSpec(parse_procedure(text, "mini.yaml"), Station(40.0, 50.0), seed=3, rate_hz=20.0,
                   sim_thermal=thermal)
    directory = tmp_path_factory.mktemp("warm") / "run"
    run_headless(spec, directory)
    return directory


SPEC = """schema: fieldcal-spec/1
product: warming unit
triads:
  accelerometer:
    thermal:
      bias_drift: {unit: mg/K, min: -6, max: 6}
  inclinometer:
    thermal:
      bias_drift: {unit: mg/K, min: -1, max: 1}
"""


def test_the_thermal_model_is_on_the_certificate_as_the_file_holds_it(tmp_path, warm_session):
    spec = tmp_path / "spec.yaml"
    spec.write_text(SPEC)
    out = tmp_path / "cert.html"
    assert main(["certificate", str(warm_session), "--spec", str(spec), "--out", str(out), "--no-pdf"]) == 3
    text = out.read_text(encoding="utf-8")
    page = Page(text)
    assert_self_contained(page)
    pf = load(next(warm_session.glob("parameters-*.yaml")))
    thermal_triads = [c for c in pf.triads if c.thermal is not None]
    assert {c.name for c in thermal_triads} >= {"accelerometer", "gyroscope"}
    tables = {a["data-triad"]: rows for a, rows in page.tables[1:] if a.get("class") == "thermal"}
    assert set(tables) == {c.name for c in thermal_triads}
    for cal in thermal_triads:
        model = cal.thermal
        [div] = [a for tag, a in page.attrs if tag == "div" and a.get("data-triad") == cal.name]
        assert float(div["data-reference-c"]) == model.reference_c and int(div["data-order"]) == model.order
        assert (float(div["data-low-c"]), float(div["data-high-c"])) == model.range_c
        per = {"accelerometer": MG, "gyroscope": DEG_H, "inclinometer": MG}[cal.name]
        unit = {"accelerometer": "mg/K", "gyroscope": "°/h/K", "inclinometer": "mg/K"}[cal.name]
        rows = {row[0]: row for row in tables[cal.name][1:]}
        assert len(rows) == 3 * model.order + (3 if model.scale_drift is not None else 0)
        for k in range(model.order):
            for i, axis in enumerate("xyz"):
                row = rows[f"b{k + 1} {axis}"]
                assert float(row[1]) == pytest.approx(model.bias_terms[k, i] / per, rel=1e-4)
                assert float(row[2]) == pytest.approx(model.bias_terms_sigma[k, i] / per, rel=1e-2)
                assert row[3] == unit + ("", "²", "³")[k]
    acc = {row[0]: row for row in tables["accelerometer"][1:]}
    # the truth is 3, -5, 8 mg/K: z above the spec's 6 mg/K, x and y within it
    assert acc["b1 x"][-2] == "-6 to 6 mg/K" and acc["b1 x"][-1] == "PASS" and acc["b1 y"][-1] == "PASS"
    assert acc["b1 z"][-1].startswith("FAIL: ") and "above the maximum 6 mg/K" in acc["b1 z"][-1]
    assert float(acc["b1 x"][1]) == pytest.approx(3.0, abs=4 * float(acc["b1 x"][2]))  # the truth within 4σ
    assert all(row[-1] == "– not in the spec" for row in tables["gyroscope"][1:])  # as its parameters say
    # the plot: one per thermal triad, in the bias unit
    figures = [a for tag, a in page.attrs if tag == "figure" and a.get("class") == "thermal"]
    assert {a["data-triad"] for a in figures} == set(tables)


def test_the_bias_band_is_the_polynomial_and_its_independent_sigma_hand_worked(warm_session):
    pf = load(next(warm_session.glob("parameters-*.yaml")))
    cal = pf.triad("accelerometer")
    m = cal.thermal
    t = np.array([m.range_c[0], m.reference_c, m.range_c[1]])
    bias, sigma = bias_band(cal, t)
    dt = t - m.reference_c
    for j, d in enumerate(dt):
        want = cal.bias + sum(m.bias_terms[k] * d ** (k + 1) for k in range(m.order))
        np.testing.assert_allclose(bias[j], want, rtol=0, atol=1e-15)
        var = cal.file_sigma[:3] ** 2 + sum((m.bias_terms_sigma[k] * d ** (k + 1)) ** 2 for k in range(m.order))
        np.testing.assert_allclose(sigma[j], np.sqrt(var), rtol=1e-12)
    np.testing.assert_allclose(sigma[1], cal.file_sigma[:3], rtol=1e-12)  # at the reference: b₀'s σ


def test_an_old_sessions_certificate_has_no_thermal_section(tmp_path):
    from pathlib import Path

    old = Path(__file__).parent / "data" / "golden" / "headless-resumed"
    out = tmp_path / "cert.html"
    assert main(["certificate", str(old), "--out", str(out), "--no-pdf"]) == 0
    text = out.read_text(encoding="utf-8")
    assert "thermal" not in text.lower() and "Thermal model" not in text
    assert len(Page(text).tables) == 1 + len(load(old / "parameters.yaml").triads)
    # against a spec with thermal limits: one line says it was not calibrated for temperature
    spec = tmp_path / "spec.yaml"
    spec.write_text(SPEC)
    assert main(["certificate", str(old), "--spec", str(spec), "--out", str(out), "--force", "--no-pdf"]) == 3
    text = out.read_text(encoding="utf-8")
    assert text.count("bias drift: FAIL: not calibrated for temperature: the parameter file has no thermal "
                      "model") == 2  # accelerometer and inclinometer
    assert "Thermal model" not in text
