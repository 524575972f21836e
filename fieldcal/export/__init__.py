"""A parameter file in the formats other tools read: ``export(parameters, format) -> text``.

ardupilot and px4 hold only an offset and a diagonal scale per triad (and ArduPilot no gyro
scale): what they cannot hold is listed with the error it costs (``fieldcal.export.autopilot``).
imucal-json is imucal's Ferraris calibration, c-header arrays for firmware, json the parameter
file's own document.
"""
from __future__ import annotations

import json

from fieldcal.export.autopilot import ardupilot, px4
from fieldcal.export.c_header import c_header
from fieldcal.export.imucal_json import imucal_json


def _json(parameters, **_) -> str:
    from fieldcal.paramfile import to_document
    return json.dumps(to_document(parameters), indent=2, ensure_ascii=False) + "\n"


EXPORTERS = {"ardupilot": ardupilot, "px4": px4, "imucal-json": imucal_json, "c-header": c_header,
             "json": _json}
FORMATS = tuple(EXPORTERS)


def export(parameters, fmt: str, *, accelerometer: str = "accelerometer", gyroscope: str = "gyroscope") -> str:
    """The text of ``parameters`` (a ParameterFile) in ``fmt``; ValueError (one line) if the file
    cannot be expressed in it."""
    return EXPORTERS[fmt](parameters, accelerometer=accelerometer, gyroscope=gyroscope)
