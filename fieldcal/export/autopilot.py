"""ArduPilot and PX4 parameters: an offset and a diagonal scale per triad, in SI units.

Both apply corrected = (raw − offset) · scale per axis (ArduPilot: INS_ACCOFFS_*, INS_ACCSCAL_*,
INS_GYROFFS_* and no gyro scale; PX4: CAL_ACC0_*OFF, CAL_ACC0_*SCALE, CAL_GYRO0_*OFF). The rest
of K (its misalignment, and for ArduPilot's gyro its scale factors) is dropped. What that costs
is computed, not guessed: with K_si the triad's K in SI units and A the diagonal the format keeps,
a true input u reads A⁻¹·K_si·u instead of u, so the worst error over all directions of an input
of size |u| is ‖A⁻¹·K_si − I‖₂·|u| (the largest singular value).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fieldcal.model import ANGULAR_RATE, SPECIFIC_FORCE, SI_UNIT, terms_from_k
from fieldcal.units import BIAS, SI_PER_UNIT, STANDARD_GRAVITY, operator_unit

# The input size the dropped error is quoted at: 1 g, and a brisk 100 °/s.
REFERENCE_INPUT = {SPECIFIC_FORCE: (STANDARD_GRAVITY, "at 1 g")}
_RATE_REFERENCE = (np.deg2rad(100.0), "at 100 °/s")


@dataclass(frozen=True)
class Dropped:
    """What a diagonal format cannot hold of one triad, and the worst error it costs."""

    triad: str
    what: tuple[str, ...]  # "m_xy = 0.2 mrad", "scale_x = 1.0001", ...
    error: float  # operator units (mg, °/h), at ``reference``
    unit: str
    reference: str

    def line(self) -> str:
        if not self.what:
            return f"{self.triad}: nothing dropped"
        return (f"{self.triad}: dropped {', '.join(self.what)}; worst error {self.error:.3g} {self.unit} "
                f"{self.reference}")


def si_model(cal, fmt: str) -> tuple[np.ndarray, np.ndarray]:
    """(K, bias) of a triad in SI units; one-line error if its output unit is not physical."""
    si = SI_PER_UNIT[cal.kind].get(cal.output_unit)
    if si is None:
        raise ValueError(f"export {fmt}: triad {cal.name!r} reports in {cal.output_unit!r}; {fmt} takes "
                         f"readings in {SI_UNIT[cal.kind]} (calibrate a device reporting physical units)")
    return cal.K * si, cal.bias * si


def dropped(cal, K_si: np.ndarray, kept_scale: np.ndarray) -> Dropped:
    """What keeping only ``kept_scale`` (the diagonal A) of ``K_si`` drops, and its worst error."""
    size, reference = REFERENCE_INPUT.get(cal.kind, _RATE_REFERENCE)
    error_si = np.linalg.norm(K_si / kept_scale[:, None] - np.eye(3), ord=2) * size
    factor, unit = operator_unit(cal.kind, SI_UNIT[cal.kind], BIAS)
    k, terms = terms_from_k(K_si)
    what = [f"{n} = {v * 1e3:.3g} mrad" for n, v in zip(("m_xy", "m_xz", "m_yx", "m_yz", "m_zx", "m_zy"), terms)
            if v != 0]
    what += [f"scale_{a} = {s:.7f}" for a, s, kept in zip("xyz", k, kept_scale) if kept != s and s != 1]
    return Dropped(cal.name, tuple(what), float(error_si * factor), unit, reference)


# What each option names: the triad a format writes as its accelerometer or its gyro.
OPTION_KIND = {"--accelerometer": SPECIFIC_FORCE, "--gyroscope": ANGULAR_RATE}


def _triad(parameters, name: str, option: str, fmt: str = ""):
    """The triad ``option`` names, refused unless it is of the kind the option asks for (a
    gyro's offsets written as an accelerometer's would be applied in the wrong unit)."""
    if name not in parameters.names:
        raise ValueError(f"export: no triad named {name!r} in the parameter file (it has "
                         f"{', '.join(parameters.names)}); name it with {option}")
    check_kind(parameters, name, option, fmt)
    return parameters.triad(name)


def check_kind(parameters, name: str, option: str, fmt: str) -> None:
    """One line if the triad ``name`` is not of the kind ``option`` names."""
    expected, cal = OPTION_KIND[option], parameters.triad(name)
    if cal.kind != expected:
        fitting = [c.name for c in parameters.triads if c.kind == expected]
        hint = f" (the file's {expected} triad{'s' * (len(fitting) > 1)}: {', '.join(fitting)})" if fitting else ""
        raise ValueError(f"export{' ' + fmt if fmt else ''}: {option} {name}: that triad is {cal.kind} in "
                         f"{cal.output_unit}, not {expected}: name the {expected} triad with {option}{hint}")


def diagonal_parameters(parameters, fmt: str, accelerometer: str, gyroscope: str, gyro_scale: bool):
    """([(name suffix, triad, offsets, scales or None)], [Dropped]) in SI units."""
    rows, losses = [], []
    for name, option, with_scale in ((accelerometer, "--accelerometer", True),
                                     (gyroscope, "--gyroscope", gyro_scale)):
        cal = _triad(parameters, name, option, fmt)
        K_si, bias_si = si_model(cal, fmt)
        kept = np.diag(K_si).copy() if with_scale else np.ones(3)
        rows.append((cal, bias_si, 1.0 / kept if with_scale else None))
        losses.append(dropped(cal, K_si, kept))
    return rows, losses


def _comments(parameters, fmt: str, losses) -> list[str]:
    p = parameters.provenance
    device = " ".join(x for x in (p.device_name, p.device_serial) if x) or "unnamed device"
    return [f"# {fmt} calibration of {device} by fieldcal {p.software_version} ({p.procedure}, {p.method})",
            f"# {fmt} keeps an offset and a diagonal scale per triad; the rest is dropped:",
            *(f"#   {d.line()}" for d in losses)]


NOT_WRITTEN = "# not written, not calibrated (the vehicle keeps its own values): "


def refuse_not_calibrated(fmt: str, triads, why: str) -> None:
    """One line refusing a format that holds every term of ``triads`` when one of them has
    parameters not calibrated (``why``: what the format would do with a nominal)."""
    marked = [t for t in triads if t.not_calibrated]
    if marked:
        t = marked[0]
        raise ValueError(f"export {fmt}: {t.name}: {', '.join(t.not_calibrated)} not calibrated"
                         f"{' (' + t.not_calibrated_why + ')' if t.not_calibrated_why else ''}; {why}: export px4, "
                         "ardupilot (only what is calibrated) or json (the marks kept) instead")


def only_calibrated(fmt: str, values, *, more: bool = False) -> tuple[list, list[str]]:
    """Of ``values`` [(name, value, triad, parameter)], those whose parameter is calibrated, and
    comment lines naming the others: a flight stack loading a partial file keeps its own value of
    a parameter not in it, where a nominal written as a value would pass for a calibrated one.
    One line refuses the export when nothing it would write is calibrated (issue 27), unless
    ``more``: the format writes something else besides (a thermal model of a PX4 thermal log)."""
    kept = [(n, v) for n, v, cal, parameter in values if parameter not in cal.not_calibrated]
    left = [(n, cal) for n, _, cal, parameter in values if parameter in cal.not_calibrated]
    if not left:
        return kept, []
    if not kept and not more:
        raise ValueError(f"export {fmt}: none of what {fmt} holds is calibrated in this file "
                         f"({'; '.join(sorted({c.name + ': ' + c.not_calibrated_why for _, c in left}))})")
    why = sorted({f"{c.name}: {c.not_calibrated_why}" for _, c in left if c.not_calibrated_why})
    return kept, [f"{NOT_WRITTEN}{', '.join(n for n, _ in left)}",
                  *(f"#   {w}" for w in why)]


def _diagonal_values(rows, offset: str, scale: str, gyro_offset: str) -> list:
    """[(name, value, triad, parameter)] of a diagonal format: the accelerometer's offsets and
    scales, the gyro's offsets (names formatted with the axis letter)."""
    (acc, acc_off, acc_scale), (gyr, gyr_off, _) = rows
    values = [(offset.format(a), float(o), acc, f"bias_{a.lower()}") for a, o in zip("XYZ", acc_off)]
    values += [(scale.format(a), float(k), acc, f"scale_{a.lower()}") for a, k in zip("XYZ", acc_scale)]
    return values + [(gyro_offset.format(a), float(o), gyr, f"bias_{a.lower()}") for a, o in zip("XYZ", gyr_off)]


def ardupilot(parameters, *, accelerometer: str = "accelerometer", gyroscope: str = "gyroscope") -> str:
    """A Mission Planner .parm file (NAME,VALUE), offsets in SI units, scales dimensionless."""
    rows, losses = diagonal_parameters(parameters, "ardupilot", accelerometer, gyroscope, gyro_scale=False)
    from fieldcal.export.ardupilot_thermal import ardupilot_thermal
    thermal, thermal_values = ardupilot_thermal(rows[0][0], rows[1][0])
    thermal += [line for row in rows for line in scale_drift_dropped(row[0])]
    values, unwritten = only_calibrated("ardupilot", _diagonal_values(
        rows, "INS_ACCOFFS_{}", "INS_ACCSCAL_{}", "INS_GYROFFS_{}"), more=bool(thermal_values))
    order = {f"INS_ACC{p}_{a}": 2 * i + j for i, a in enumerate("XYZ") for j, p in enumerate(("OFFS", "SCAL"))}
    values.sort(key=lambda nv: order.get(nv[0], 6))  # ArduPilot's offset and scale per axis, as before
    values += thermal_values
    lines = _comments(parameters, "ardupilot", losses) + unwritten + thermal
    lines += [f"{name},{value!r}" for name, value in values]
    return "\n".join(lines) + "\n"


def px4(parameters, *, accelerometer: str = "accelerometer", gyroscope: str = "gyroscope") -> str:
    """A QGroundControl parameter file (vehicle, component, name, value, type 9 = float)."""
    rows, losses = diagonal_parameters(parameters, "px4", accelerometer, gyroscope, gyro_scale=False)
    thermal = px4_thermal(parameters, ((rows[0][0], "A"), (rows[1][0], "G")))
    values, unwritten = only_calibrated("px4", _diagonal_values(
        rows, "CAL_ACC0_{}OFF", "CAL_ACC0_{}SCALE", "CAL_GYRO0_{}OFF"), more=bool(thermal[1]))
    lines = _comments(parameters, "px4", losses) + unwritten + ["# Vehicle-Id\tComponent-Id\tName\tValue\tType"]
    lines += thermal[0]
    values += thermal[1]
    lines += [f"1\t1\t{name}\t{value!r}\t{6 if name.endswith('_ENABLE') else 9}" for name, value in values]
    return "\n".join(lines) + "\n"


def px4_thermal(parameters, triads) -> tuple[list[str], list[tuple[str, float]]]:
    """PX4's thermal compensation (TC_A0_*, TC_G0_*) of the triads that have a thermal model:
    ([comment lines], [(name, value)]). PX4 subtracts x0 + x1·dT + x2·dT² + x3·dT³ per axis,
    dT = T − TREF with T held within [TMIN, TMAX], before its CAL_*OFF offset
    (src/modules/temperature_compensation/TemperatureCompensation.cpp, calc_thermal_offsets_3D;
    src/lib/sensor_calibration: data − thermal_offset − offset): so x0 = 0 (the offset at TREF
    is CAL_*OFF) and x1..x3 are the model's bias terms in SI units. PX4 holds no scale drift."""
    comments: list[str] = []
    values: list[tuple[str, float]] = []
    for cal, letter in triads:
        model = cal.thermal
        if model is None:
            continue
        si = SI_PER_UNIT[cal.kind][cal.output_unit]
        prefix = f"TC_{letter}0"
        low, high = model.range_c
        comments.append(f"# {prefix}: {cal.name}'s thermal model, order {model.order}, about {model.reference_c:.2f} °C "
                        f"over {low:.2f} to {high:.2f} °C (PX4 holds the offset of the nearer end outside it); "
                        f"set {prefix}_ID to the sensor's device id (CAL_{'ACC' if letter == 'A' else 'GYRO'}0_ID)")
        comments += scale_drift_dropped(cal)
        terms = np.zeros((3, 3))
        terms[:model.order] = model.bias_terms * si
        values.append((f"TC_{letter}_ENABLE", 1))
        for k in range(4):
            values += [(f"{prefix}_X{k}_{i}", float(terms[k - 1, i]) if k else 0.0) for i in range(3)]
        values += [(f"{prefix}_TREF", model.reference_c), (f"{prefix}_TMIN", low), (f"{prefix}_TMAX", high)]
    return comments, values


def scale_drift_dropped(cal) -> list[str]:
    """The comment line naming a thermal model's scale drift, which neither flight stack holds,
    with the worst error it costs over the calibrated range; [] without one."""
    model = cal.thermal
    if model is None or model.scale_drift is None:
        return []
    low, high = model.range_c
    factor, unit = operator_unit(cal.kind, SI_UNIT[cal.kind], BIAS)
    size, reference = REFERENCE_INPUT.get(cal.kind, _RATE_REFERENCE)
    worst = float(np.max(np.abs(model.scale_drift))) * max(high - model.reference_c, model.reference_c - low)
    return [f"#   dropped: scale drift {', '.join(f'{v * 1e6:+.3g}' for v in model.scale_drift)} "
            f"ppm/K; worst error {worst * size * factor:.3g} {unit} {reference} over the range"]
