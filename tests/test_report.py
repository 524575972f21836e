"""Tables in the units an operator expects (issue 15): accelerometer and inclinometer bias in mg,
gyro bias in °/h, scale as a dimensionless factor (σ in ppm) or count per g / per °/s, angles in
mrad; columns aligned however long the unit. Expected figures are worked by hand here."""
from __future__ import annotations

import math
import re

import numpy as np

from fieldcal.calibration import Calibration
from fieldcal.model import ANGULAR_RATE, SPECIFIC_FORCE, k_from_params
from fieldcal.report import comparison_table, methods_table, solution_table

THETA = np.array([0.01, -0.02, 0.03, 1.0002, 0.9998, 1.0001, 1e-3, -2e-3, 5e-4])
SIGMA = np.array([1e-4, 1e-4, 1e-4, 2e-5, 2e-5, 2e-5, 1e-5, 1e-5, 1e-5])


def _calibration(kind: str, output_unit: str, per_si: float) -> Calibration:
    """A triad reporting in ``output_unit`` (``per_si`` of it per SI unit) with SI parameters THETA."""
    theta = THETA * np.r_[[per_si] * 6, [1.0] * 3]  # bias and k scale with the output unit
    return Calibration(name="t", kind=kind, output_unit=output_unit, method="powell", theta=theta,
                       sigma=SIGMA * np.r_[[per_si] * 6, [1.0] * 3], residual_rms=0.0)


def _rows(table: str) -> dict[str, list[str]]:
    """label -> the row's words (a two-word label is joined into one: "bias x", "m xy")."""
    out = {}
    for line in table.splitlines()[1:]:
        words = line.split()
        if words[0] in ("bias", "scale", "m"):
            words = [" ".join(words[:2])] + words[2:]
        out[words[0]] = words
    return out


def test_accelerometer_bias_in_mg_and_scale_dimensionless_whatever_the_output_unit():
    for unit, per_si in (("m/s^2", 1.0), ("g", 1 / 9.80665), ("mg", 1e3 / 9.80665)):
        rows = _rows(solution_table(_calibration(SPECIFIC_FORCE, unit, per_si)))
        # 0.01 m/s² = 1.0197 mg; σ 1e-4 m/s² = 0.0102 mg
        assert rows["bias x"][1:5] == ["1.0197", "mg", "0.0102", "mg"], (unit, rows["bias x"])
        assert rows["scale x"][1:4] == ["1.0002000", "20", "ppm"], (unit, rows["scale x"])
        assert rows["Δyz"][1:5] == ["1", "mrad", "0.01", "mrad"]
        assert "(m/s^2)" not in solution_table(_calibration(SPECIFIC_FORCE, unit, per_si))


def test_gyro_bias_in_degrees_per_hour():
    for unit, per_si in (("rad/s", 1.0), ("deg/s", 180 / math.pi)):
        rows = _rows(solution_table(_calibration(ANGULAR_RATE, unit, per_si)))
        # 0.01 rad/s = 2062.6 °/h; σ 1e-4 rad/s = 20.6 °/h
        assert rows["bias x"][1:5] == ["2062.6", "°/h", "20.6", "°/h"], (unit, rows["bias x"])
        assert rows["scale y"][1:4] == ["0.9998000", "20", "ppm"]


def test_raw_counts_keep_the_device_unit_and_give_sensitivity_per_g_and_per_degree_per_second():
    acc = _rows(solution_table(_calibration(SPECIFIC_FORCE, "count", 4096 / 9.80665)))
    assert acc["bias x"][1:3] == [f"{0.01 * 4096 / 9.80665:.5g}", "count"]
    assert acc["scale x"][1:3] == [f"{1.0002 * 4096:.5g}", "count/g"]  # 4096.8 count/g
    gyro = _rows(solution_table(_calibration(ANGULAR_RATE, "count", 16.4 * 180 / math.pi)))
    assert gyro["scale x"][1:3] == [f"{1.0002 * 16.4:.5g}", "count/(°/s)"]


def test_columns_stay_aligned_with_long_units():
    """Every number of a column ends at the same place on every row (right-aligned), and every
    unit starts at the same place, however long the unit text (count/(°/s) beside ppm)."""
    cal = _calibration(ANGULAR_RATE, "count", 16.4 * 180 / math.pi)
    truth = THETA * np.r_[[16.4 * 180 / math.pi] * 6, [1.0] * 3]
    for table in (solution_table(cal, truth), comparison_table(cal, cal),
                  methods_table({"powell": cal, "lsq": cal})):
        rows = table.splitlines()[1:]
        number_ends = [[m.end() for m in re.finditer(r"(?<!\S)[-+]?\d[\d.e+-]*(?!\S)", r)] for r in rows]
        assert all(ends == number_ends[0] for ends in number_ends), table
        unit_starts = [[m.start() for m in re.finditer(r"(?<=\d )(count\S*|ppm|mrad)", r)] for r in rows]
        columns = {len(u) for u in unit_starts}
        assert len(columns) == 1 and all(u == unit_starts[0] for u in unit_starts if u), table


def test_methods_side_by_side_mark_what_one_method_does_not_estimate():
    norm = _calibration(SPECIFIC_FORCE, "m/s^2", 1.0)
    full = Calibration(name="t", kind=SPECIFIC_FORCE, output_unit="m/s^2", method="classic",
                       K=k_from_params(THETA) + np.triu(np.full((3, 3), 1e-4), 1), bias=THETA[:3],
                       covariance=np.diag(np.full(12, 1e-10)), residual_rms=0.0,
                       parameter_names=("bias_x", "bias_y", "bias_z", "scale_x", "scale_y", "scale_z",
                                        "m_xy", "m_xz", "m_yx", "m_yz", "m_zx", "m_zy"))
    rows = _rows(methods_table({"powell": norm, "classic": full}))
    assert list(rows)[:9] == ["bias x", "bias y", "bias z", "scale x", "scale y", "scale z", "Δyz", "Δzy", "Δzx"]
    assert rows["Δyz"][5] == "—" and rows["m xy"][1] == "—"  # Δ: norm only; m xy: classic only
    assert rows["m xy"][2:4] == [f"{1e-4 / 1.0002 * 1e3:.5g}", "mrad"]  # K01 / K00, upper triangle
    # m_yx = K10 / K11 = −Δyz: the same angle, by the one conversion.
    assert rows["m yx"][2:4] == ["-1", "mrad"] and rows["Δyz"][1:3] == ["1", "mrad"]
