"""ArduPilot's IMU temperature calibration (INS_TCAL1_*) of the triads that have a thermal model.

ArduPilot (libraries/AP_InertialSensor/AP_InertialSensor_tempcal.cpp, correct_sensor) corrects
each reading, before its INS_ACCOFFS/INS_GYROFFS offsets and scales, by

    v −= p(T − 35) − p(T_cal − 35),   p(x) = (c₁x + c₂x² + c₃x³)·10⁻⁶

with T and T_cal (INS_ACC1_CALTEMP, INS_GYR1_CALTEMP: where the offsets were calibrated) held
within [INS_TCAL1_TMIN, INS_TCAL1_TMAX], cₖ = INS_TCAL1_ACCk_* / INS_TCAL1_GYRk_* in SI units
×10⁶, about its fixed reference of 35 °C. fieldcal's bias terms about T_ref, re-centred on 35 °C
(``fieldcal.thermal.truth_about``; their constant is what T_cal cancels), with T_cal = T_ref
where the file's offsets are written, give back exactly Σ bₖ (T − T_ref)ᵏ. Where the offsets are
not calibrated (a PX4 thermal log), T_cal is not written: the vehicle's own stays, and the
correction is the bias's change from the temperature its own offsets were calibrated at.

What it cannot hold: a scale drift (said with its cost), a range per triad (one TMIN/TMAX per
IMU: the ranges' overlap is written), the σ. ArduPilot's TCAL_* (AP_TempCalibration) is the
barometer's and holds nothing of an IMU.
"""
from __future__ import annotations

import numpy as np

from fieldcal.thermal import truth_about
from fieldcal.units import SI_PER_UNIT

TEMP_REFERENCE_C = 35.0  # AP_InertialSensor_tempcal.cpp TEMP_REFERENCE
SCALE_FACTOR = 1e6  # AP_InertialSensor_tempcal.cpp SCALE_FACTOR
IMU = 1  # the first IMU, as INS_ACCOFFS_* and INS_GYROFFS_* are


def ardupilot_terms(model, si: float) -> np.ndarray:
    """(3, 3): c₁..c₃ per axis as ArduPilot stores them (about 35 °C, SI units ×10⁶)."""
    nominal = np.r_[np.zeros(3), np.ones(3), np.zeros(3)]
    _, terms = truth_about(nominal, model.reference_c, model.bias_terms, np.zeros(3), TEMP_REFERENCE_C)
    out = np.zeros((3, 3))
    out[:len(terms)] = terms * si * SCALE_FACTOR
    return out


def ardupilot_thermal(accelerometer, gyroscope) -> tuple[list[str], list[tuple[str, float]]]:
    """([comment lines], [(name, value)]) of INS_TCAL1_* for the triads with a thermal model (the
    scale drift it drops is said by the caller, as for PX4)."""
    triads = [(cal, name) for cal, name in ((accelerometer, "ACC"), (gyroscope, "GYR")) if cal.thermal is not None]
    if not triads:
        return [], []
    low = max(cal.thermal.range_c[0] for cal, _ in triads)
    high = min(cal.thermal.range_c[1] for cal, _ in triads)
    if low > high:
        raise ValueError(f"export ardupilot: the accelerometer's and gyro's thermal models share no temperature "
                         f"(INS_TCAL{IMU} holds one range for both): calibrate them over a common range")
    prefix = f"INS_TCAL{IMU}"
    comments = [f"# {prefix}: ArduPilot's polynomial about 35 °C, valid {low:.2f} to {high:.2f} °C (held at the "
                "nearer end outside it); no scale drift, one range per IMU (TCAL_* is the barometer's)"]
    values: list[tuple[str, float]] = [(f"{prefix}_ENABLE", 1), (f"{prefix}_TMIN", low), (f"{prefix}_TMAX", high)]
    for cal, name in triads:
        model = cal.thermal
        terms = ardupilot_terms(model, SI_PER_UNIT[cal.kind][cal.output_unit])
        comments.append(f"# {prefix}_{name}k: {cal.name}'s thermal model, order {model.order}, about "
                        f"{model.reference_c:.2f} °C")
        values += [(f"{prefix}_{name}{k + 1}_{a}", float(terms[k, i])) for k in range(3) for i, a in enumerate("XYZ")]
        if not any(p.startswith("bias") for p in cal.not_calibrated):
            values.append((f"INS_{name}{IMU}_CALTEMP", model.reference_c))  # where its offsets hold
    missing = [n for cal, n in ((accelerometer, "ACC"), (gyroscope, "GYR")) if cal.thermal is None]
    if missing:
        comments.append(f"# not written, no thermal model (the vehicle keeps its own values): "
                        f"{', '.join(f'{prefix}_{n}1..3_*' for n in missing)}")
    return comments, values
