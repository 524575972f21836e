"""A real device as a calibration run knows it: identity, link, and each triad's station model.

The simulated bench knows its device's truth; a real one is known only by its config: the
noise that sets the stillness thresholds and the solver's weights, and the nominal zero and
sensitivity that turn raw output into a gravity direction for the orientation check. All of it
goes into the session, so a replay rebuilds the run without the config file.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drivers.noise import TriadNoise
from fieldcal.config import ConfigError, StationConfig
from fieldcal.solvers.solve import TriadModel

# The triads the engine watches for stillness and orientation, and for the table rate.
SPECIFIC_FORCE_TRIAD, ANGULAR_RATE_TRIAD = "accelerometer", "gyroscope"


@dataclass(frozen=True)
class LiveDevice:
    name: str
    serial: str | None
    protocol: str
    url: str
    models: dict[str, TriadModel]
    zeros: dict[str, tuple[float, float, float]]

    @classmethod
    def from_config(cls, config: StationConfig) -> LiveDevice:
        device = config.device
        names = [t.name for t in device.triads]
        for needed in (SPECIFIC_FORCE_TRIAD, ANGULAR_RATE_TRIAD):
            if needed not in names:
                raise ConfigError(f"{config.path}: device.triads: a calibration run needs a triad named "
                                  f"{needed!r} (it has {', '.join(names)})", config.path, "device.triads")
        models: dict[str, TriadModel] = {}
        zeros: dict[str, tuple[float, float, float]] = {}
        for t in device.triads:
            if t.noise is None:
                raise ConfigError(f"{config.path}: device.triads.{t.name}.noise: expected {{white, "
                                  "bias_instability}} in SI units for a calibration run (measure them "
                                  "with `fieldcal allan`)", config.path, f"device.triads.{t.name}.noise")
            models[t.name] = TriadModel(t.kind, t.unit, t.noise, np.diag(t.sensitivity), t.lsb)
            zeros[t.name] = t.zero  # (a tuple of three: the config made it)
        assert device.port is not None  # (the config gives a real device its port)
        return cls(device.name, device.serial, device.protocol, device.port.url, models, zeros)

    def to_metadata(self) -> dict:
        return {"name": self.name, "serial": self.serial, "protocol": self.protocol, "url": self.url,
                "triads": {n: {"kind": m.kind, "unit": m.output_unit, "zero": list(self.zeros[n]),
                               "sensitivity": np.diag(m.sensitivity).tolist(), "lsb": m.lsb,
                               "noise": {"white": m.noise.white,
                                         "bias_instability": m.noise.bias_instability}}
                           for n, m in self.models.items()}}

    @classmethod
    def from_metadata(cls, d: dict) -> LiveDevice:
        models = {n: TriadModel(t["kind"], t["unit"], TriadNoise(**t["noise"]), np.diag(t["sensitivity"]),
                                t["lsb"]) for n, t in d["triads"].items()}
        zeros = {n: tuple(t["zero"]) for n, t in d["triads"].items()}
        return cls(d["name"], d["serial"], d["protocol"], d["url"], models, zeros)
