"""A C header for firmware: per triad the bias and K⁻¹, so calibrated = K⁻¹·(raw − bias)."""
from __future__ import annotations

import re

import numpy as np


def _identifier(name: str) -> str:
    ident = re.sub(r"\W", "_", name, flags=re.ASCII).upper()
    return ident if ident[:1].isalpha() else "T_" + ident


def _numbers(values) -> str:
    return ", ".join(repr(float(v)) for v in values)


def c_header(parameters, *, accelerometer: str = "accelerometer", gyroscope: str = "gyroscope") -> str:
    """Every triad's arrays; the triads --accelerometer and --gyroscope name (when the file has
    them) must be of those kinds, as firmware takes FIELDCAL_<NAME>_* by the name."""
    from fieldcal.export.autopilot import check_kind, refuse_not_calibrated

    for name, option in ((accelerometer, "--accelerometer"), (gyroscope, "--gyroscope")):
        if name in parameters.names:
            check_kind(parameters, name, option, "c-header")
    refuse_not_calibrated("c-header", parameters.triads, "firmware would take every term of BIAS and KINV, a "
                          "nominal among them, as calibrated")
    p = parameters.provenance
    lines = ["/* fieldcal calibration parameters, generated: do not edit.",
             f" * fieldcal {p.software_version}, procedure {p.procedure}, method {p.method},",
             f" * device {p.device_name or '?'} {p.device_serial or ''}, inputs sha256 {p.input_sha256}.",
             " * Per triad: calibrated[i] = sum_j KINV[i][j] * (raw[j] - BIAS[j]). */",
             "#ifndef FIELDCAL_CALIBRATION_H", "#define FIELDCAL_CALIBRATION_H", ""]
    for cal in parameters.triads:
        ident = _identifier(cal.name)
        kinv = np.linalg.inv(cal.K)
        lines += [f"/* {cal.name} ({cal.kind}): raw in {cal.output_unit}, calibrated in {cal.input_unit} */",
                  f"static const double FIELDCAL_{ident}_BIAS[3] = {{{_numbers(cal.bias)}}};",
                  f"static const double FIELDCAL_{ident}_KINV[3][3] = {{"
                  + ", ".join(f"{{{_numbers(row)}}}" for row in kinv) + "};", ""]
    return "\n".join(lines + ["#endif /* FIELDCAL_CALIBRATION_H */"]) + "\n"
