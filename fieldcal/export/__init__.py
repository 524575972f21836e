"""A parameter file in the formats other tools read: ``export(parameters, format) -> text``.

ardupilot and px4 hold only an offset and a diagonal scale per triad (and ArduPilot no gyro
scale): what they cannot hold is listed with the error it costs (``fieldcal.export.autopilot``).
imucal-json is imucal's Ferraris calibration, c-header arrays for firmware, json the parameter
file's own document.
"""
from __future__ import annotations

import json

# format -> (module, function): imported only when a file is exported, so that building the
# command line (which needs only FORMATS) stays light (issue 12: no numpy for `fieldcal --help`).
_EXPORTERS = {"ardupilot": ("fieldcal.export.autopilot", "ardupilot"),
              "px4": ("fieldcal.export.autopilot", "px4"),
              "imucal-json": ("fieldcal.export.imucal_json", "imucal_json"),
              "c-header": ("fieldcal.export.c_header", "c_header"),
              "json": (__name__, "_json")}
FORMATS = tuple(_EXPORTERS)


def _json(parameters, **_) -> str:
    from fieldcal.paramfile import to_document
    return json.dumps(to_document(parameters), indent=2, ensure_ascii=False) + "\n"


def exporter(fmt: str):
    """The function that writes ``fmt``."""
    import importlib

    module, name = _EXPORTERS[fmt]
    return getattr(importlib.import_module(module), name)


def export(parameters, fmt: str, *, accelerometer: str = "accelerometer", gyroscope: str = "gyroscope") -> str:
    """The text of ``parameters`` (a ParameterFile) in ``fmt``; ValueError (one line) if the file
    cannot be expressed in it."""
    return exporter(fmt)(parameters, accelerometer=accelerometer, gyroscope=gyroscope)
