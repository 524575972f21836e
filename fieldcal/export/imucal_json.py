"""imucal's Ferraris calibration JSON (``imucal.FerrarisCalibrationInfo``), written without imucal.

imucal calibrates acc = R_a⁻¹·K_a⁻¹·(raw − b_a) into m/s² and gyr = R_g⁻¹·K_g⁻¹·(raw − K_ga·acc − b_g)
into deg/s. fieldcal's K = diag(k)·(I + M) splits into K = diag(k) and R = I + M (imucal only
inverts R, so it need not be a rotation); the gyro's K is per deg/s, and fieldcal has no
g-sensitivity term, so K_ga = 0.
"""
from __future__ import annotations

import json

import numpy as np

from fieldcal.export.autopilot import _triad, refuse_not_calibrated

# imucal's file format version this writer produces (imucal 2.x reads it).
IMUCAL_FORMAT_VERSION = "2.0.0"
_RAD_PER_DEG = np.pi / 180.0


def _split(K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    k = np.diag(K).copy()
    return np.diag(k), K / k[:, None]


def imucal_json(parameters, *, accelerometer: str = "accelerometer", gyroscope: str = "gyroscope") -> str:
    acc = _triad(parameters, accelerometer, "--accelerometer", "imucal-json")
    gyr = _triad(parameters, gyroscope, "--gyroscope", "imucal-json")
    refuse_not_calibrated("imucal-json", (acc, gyr), "imucal's calibration holds every term and has no mark "
                          "for a nominal one")
    K_a, R_a = _split(acc.K)
    K_g, R_g = _split(gyr.K * _RAD_PER_DEG)  # output units per deg/s
    p = parameters.provenance
    comment = (f"fieldcal {p.software_version}: {p.procedure}, {p.method}, device "
               f"{p.device_name or '?'} {p.device_serial or ''}".rstrip())
    document = {"acc_unit": "m/s^2", "gyr_unit": "deg/s", "from_acc_unit": acc.output_unit,
                "from_gyr_unit": gyr.output_unit, "comment": comment,
                "K_a": K_a.tolist(), "R_a": R_a.tolist(), "b_a": acc.bias.tolist(),
                "K_g": K_g.tolist(), "R_g": R_g.tolist(), "K_ga": np.zeros((3, 3)).tolist(),
                "b_g": gyr.bias.tolist(), "cal_type": "Ferraris", "_format_version": IMUCAL_FORMAT_VERSION}
    return json.dumps(document, indent=2) + "\n"
