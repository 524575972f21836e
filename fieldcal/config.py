"""Station configuration: the device (port, protocol, channels, triads), the table, the station.

A file is validated on load; any problem is one line naming the file and the dotted field.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from drivers.noise import DEFAULT_FLICKER_TAU_MAX_S, FLICKER_TAU_MAX_RANGE_S, TriadNoise
from drivers.transport import PortSettings
from fieldcal.earth import Station
from fieldcal.model import KINDS
from fieldcal.paths import CONFIGS_DIR, find_named, not_found  # noqa: F401 (CONFIGS_DIR: imported from here)
from fieldcal.validation import IDENTIFIER, MISSING, FieldReader, describe, line_of, nearest, read_yaml_file

DEVICE_PROTOCOLS = ("sim", "delimited", "vectornav", "xsens")
# fieldcal.solvers.methods.THERMAL_MODES (the config sits below the solvers; a test keeps them equal)
THERMAL_SETTINGS = ("auto", "on", "off")
SIM_IMU_PROTOCOLS = ("xsens", "vectornav", "delimited")
TABLE_PROTOCOLS = ("ascii", "grbl")
_PARITIES = ("N", "E", "O", "M", "S")

if TYPE_CHECKING:  # the simulator is imported only by a config that simulates a temperature
    from drivers.sim.thermal import SimThermal, TemperatureProfile


class ConfigError(ValueError):
    def __init__(self, message: str, path: str = "", field: str = ""):
        super().__init__(message)
        self.path, self.field = path, field


@dataclass(frozen=True)
class TriadSpec:
    name: str  # as the protocol names it: accelerometer, gyroscope, inclinometer, ...
    kind: str  # specific_force or angular_rate
    unit: str  # output unit of the device for this triad
    # What the station knows before calibrating (a real device needs it for a procedure): the
    # noise (SI: white as VRW/ARW in unit·√s, bias instability in unit, e.g. from `fieldcal
    # allan`), the nominal zero (output units) and sensitivity (output units per SI unit), and
    # the output's quantisation step.
    noise: TriadNoise | None = None
    zero: tuple[float, float, float] = (0.0, 0.0, 0.0)
    sensitivity: tuple[float, float, float] = (1.0, 1.0, 1.0)
    lsb: float = 0.0
    # The scale factors' temperature coefficient, ppm/K (datasheet), for the σ of a recording's
    # Ferraris calibration (fieldcal.recording.ferraris.ScaleDrift); None: a typical one assumed.
    scale_tempco_ppm_per_k: float | None = None


@dataclass(frozen=True)
class SimSettings:
    imu_protocol: str  # wire protocol the simulated device speaks
    seed: int = 1
    speed: float = 1.0  # 1 = real time; 0 = as fast as the reader consumes
    raw_counts: bool = False
    # The simulated unit's flicker: the longest correlation time of its bias process (README,
    # "Bias instability model"); the station's model of the unit follows it.
    flicker_tau_max_s: float = DEFAULT_FLICKER_TAU_MAX_S
    # The unit's temperature profile and its triads' thermal truth (drivers.sim.thermal); None:
    # the unit holds its calibration temperature.
    thermal: SimThermal | None = None


@dataclass(frozen=True)
class DeviceConfig:
    name: str
    protocol: str
    rate_hz: float
    triads: tuple[TriadSpec, ...]
    port: PortSettings | None = None  # None: the simulator serves its own port
    channels: dict | None = None  # delimited text: the channel map, validated by its parser
    sim: SimSettings | None = None
    serial: str | None = None  # the unit's serial number: its calibrations are compared by it


@dataclass(frozen=True)
class TableConfig:
    protocol: str
    port: PortSettings | None  # None: the simulator's virtual table
    max_rate_deg_s: float = 20.0


@dataclass(frozen=True)
class StationConfig:
    path: str
    device: DeviceConfig
    station: Station
    table: TableConfig | None = None
    # Whether the solve fits a thermal model (fieldcal.solvers.methods.THERMAL_MODES); run and tui
    # take it unless --thermal says otherwise.
    thermal: str = "auto"


def _port(r: FieldReader, raw, where: str) -> PortSettings:
    m = r.mapping(raw, where, ("url",), ("baudrate", "bytesize", "parity", "stopbits"))
    url = r.string(m, "url", where)
    baud = r.number(m, "baudrate", where, 1) if "baudrate" in m else 115200
    if baud != int(baud):
        r.fail(f"{where}.baudrate", "a whole number", describe(m["baudrate"]))
    bytesize = m.get("bytesize", 8)
    if bytesize not in (5, 6, 7, 8) or isinstance(bytesize, bool):
        r.fail(f"{where}.bytesize", "5, 6, 7 or 8", describe(bytesize))
    parity = r.string(m, "parity", where, _PARITIES, optional=True) or "N"
    stopbits = m.get("stopbits", 1)
    if stopbits not in (1, 1.5, 2) or isinstance(stopbits, bool):
        r.fail(f"{where}.stopbits", "1, 1.5 or 2", describe(stopbits))
    return PortSettings(url=url, baudrate=int(baud), bytesize=bytesize, parity=parity, stopbits=stopbits)


def _triads(r: FieldReader, raw, where: str) -> tuple[TriadSpec, ...]:
    if not isinstance(raw, dict) or not raw:
        r.fail(where, "a mapping of triad name to {kind, unit}", describe(raw))
    specs = []
    for name, body in raw.items():
        if not isinstance(name, str) or not IDENTIFIER.fullmatch(name):
            r.fail(where, "triad names of ASCII letters, digits and _ (starting with a letter)",
                   describe(name), line_of(raw, name))
        here = f"{where}.{name}"
        m = r.mapping(body, here, ("kind", "unit"), ("noise", "zero", "sensitivity", "lsb", "scale_tempco_ppm_per_k"))
        noise = None
        if "noise" in m:
            n = r.mapping(m["noise"], f"{here}.noise", ("white",), ("bias_instability", "flicker_tau_max_s"))
            noise = TriadNoise(white=r.number(n, "white", f"{here}.noise", 1e-12),
                               bias_instability=r.number(n, "bias_instability", f"{here}.noise", 0)
                               if "bias_instability" in n else 0.0,
                               flicker_tau_max_s=_flicker_tau_max(r, n, f"{here}.noise"))
        specs.append(TriadSpec(name, r.string(m, "kind", here, KINDS), r.string(m, "unit", here),
                               noise=noise, zero=_three(r, m, "zero", here, 0.0, None),
                               sensitivity=_three(r, m, "sensitivity", here, 1.0, 1e-12),
                               lsb=r.number(m, "lsb", here, 0) if "lsb" in m else 0.0,
                               scale_tempco_ppm_per_k=r.number(m, "scale_tempco_ppm_per_k", here, 0)
                               if "scale_tempco_ppm_per_k" in m else None))
    return tuple(specs)


def _three(r: FieldReader, m: dict, key: str, where: str, default: float, minimum) -> tuple:
    """A number for all three axes, or a list of three."""
    value = m.get(key, default)
    here = f"{where}.{key}"
    if isinstance(value, list):
        if len(value) != 3:
            r.fail(here, "a number or a list of three numbers", describe(value))
        return tuple(r.value(v, f"{here}[{i}]", minimum) for i, v in enumerate(value))
    return (r.value(value, here, minimum),) * 3


def _flicker_tau_max(r: FieldReader, m: dict, where: str) -> float:
    if "flicker_tau_max_s" not in m:
        return DEFAULT_FLICKER_TAU_MAX_S
    return r.bounded(m, "flicker_tau_max_s", where, *FLICKER_TAU_MAX_RANGE_S, "s")


def _sim(r: FieldReader, raw, where: str) -> SimSettings:
    m = r.mapping(raw if raw is not None else {}, where, (),
                  ("imu_protocol", "seed", "speed", "raw_counts", "flicker_tau_max_s", "temperature", "thermal"))
    seed = m.get("seed", 1)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        r.fail(f"{where}.seed", "a whole number >= 0", describe(seed))
    raw_counts = m.get("raw_counts", False)
    if not isinstance(raw_counts, bool):
        r.fail(f"{where}.raw_counts", "true or false", describe(raw_counts))
    protocol = r.string(m, "imu_protocol", where, SIM_IMU_PROTOCOLS, optional=True) or "xsens"
    speed = r.number(m, "speed", where, 0) if "speed" in m else 1.0
    thermal = None
    if "thermal" in m or "temperature" in m:
        from drivers.sim.thermal import SimThermal

        if "temperature" not in m:
            r.refuse(f"{where}.temperature", "missing (thermal truth needs a temperature profile)", line_of(m))
        thermal = SimThermal(_profile(r, m["temperature"], f"{where}.temperature"),
                             _thermal_truth(r, m.get("thermal", {}), f"{where}.thermal"))
    return SimSettings(protocol, seed, speed, raw_counts, _flicker_tau_max(r, m, where), thermal)


# What each profile takes besides start_c (drivers.sim.thermal.TemperatureProfile).
_PROFILE_KEYS = {"constant": (), "warmup": ("rise_k", "time_constant_s"),
                 "ramp": ("rise_k", "rate_k_per_s", "soak_s")}
_CHAMBER_C = (-60.0, 150.0)  # a chamber's reach: a temperature outside it is a typo


def _profile(r: FieldReader, raw, where: str) -> TemperatureProfile:
    from drivers.sim.thermal import PROFILES, TemperatureProfile

    kind_map = r.mapping(raw, where, ("profile",), ("start_c", "rise_k", "time_constant_s", "rate_k_per_s", "soak_s"))
    kind = r.string(kind_map, "profile", where, PROFILES)
    m = r.mapping(raw, where, ("profile", "start_c", *_PROFILE_KEYS[kind][:2]), _PROFILE_KEYS[kind][2:])
    low, high = _CHAMBER_C
    start = r.bounded(m, "start_c", where, low, high, "°C")
    rise = r.bounded(m, "rise_k", where, low - high, high - low, "K") if "rise_k" in m else 0.0
    if not low <= start + rise <= high:
        r.fail(f"{where}.rise_k", f"a rise that ends within {low:g} to {high:g} °C", describe(m["rise_k"]))
    tau = r.bounded(m, "time_constant_s", where, 1.0, 1e6, "s") if "time_constant_s" in m else 0.0
    rate = r.bounded(m, "rate_k_per_s", where, 1e-6, 10.0, "K/s") if "rate_k_per_s" in m else 0.0
    soak = r.bounded(m, "soak_s", where, 0.0, 1e6, "s") if "soak_s" in m else 0.0
    return TemperatureProfile(kind, start, rise, tau, rate, soak)


def _thermal_truth(r: FieldReader, raw, where: str) -> dict:
    from drivers.sim.device import paper_mimu
    from drivers.sim.thermal import MAX_ORDER, ThermalTruth

    names = tuple(paper_mimu())
    m = r.mapping(raw, where, (), names)
    truths = {}
    for name, body in m.items():
        here = f"{where}.{name}"
        t = r.mapping(body, here, ("reference_c",), ("bias_coefficients", "scale_drift"))
        reference = r.bounded(t, "reference_c", here, *_CHAMBER_C, "°C")
        rows = t.get("bias_coefficients", [])
        if not isinstance(rows, list) or len(rows) > MAX_ORDER:
            r.fail(f"{here}.bias_coefficients", f"a list of up to {MAX_ORDER} rows [x, y, z] (b1, b2, b3)",
                   describe(rows), line_of(t, "bias_coefficients"))
        terms = []
        for k, row in enumerate(rows):
            if not isinstance(row, list) or len(row) != 3:
                r.fail(f"{here}.bias_coefficients[{k}]", "a list of 3 numbers (x, y, z)", describe(row),
                       line_of(t, "bias_coefficients"))
            terms.append([r.value(v, f"{here}.bias_coefficients[{k}][{i}]") for i, v in enumerate(row)])
        drift = _three(r, t, "scale_drift", here, 0.0, None)
        truths[name] = ThermalTruth(reference, np.array(terms, dtype=float).reshape(-1, 3), drift)
    return truths


def _device(r: FieldReader, raw, where: str) -> DeviceConfig:
    m = r.mapping(raw, where, ("name", "protocol", "rate_hz", "triads"), ("port", "channels", "sim", "serial"))
    protocol = r.string(m, "protocol", where, DEVICE_PROTOCOLS)
    if protocol == "sim":
        port, sim = None, _sim(r, m.get("sim"), f"{where}.sim")
    else:
        if "port" not in m:
            r.fail(f"{where}.port", "a mapping with url (and baudrate, ...)", describe(MISSING))
        port, sim = _port(r, m["port"], f"{where}.port"), None
    channels = m.get("channels")
    if protocol == "delimited":
        from drivers.protocols.delimited import ChannelMap
        try:
            ChannelMap.from_mapping(channels, f"{where}.channels")
        except ValueError as exc:
            raise ConfigError(f"{r.path}: {exc}", r.path, f"{where}.channels") from None
    elif channels is not None:
        r.fail(f"{where}.channels", "no channel map (only delimited text has one)", "a channel map")
    serial = m.get("serial")
    if serial is not None:
        if isinstance(serial, bool) or not isinstance(serial, (str, int)) or not str(serial).strip():
            r.fail(f"{where}.serial", "the unit's serial number (text)", describe(serial))
        serial = str(serial)
    return DeviceConfig(name=r.string(m, "name", where), protocol=protocol, serial=serial,
                        rate_hz=r.number(m, "rate_hz", where, 1e-3), triads=_triads(r, m["triads"], f"{where}.triads"),
                        port=port, channels=channels, sim=sim)


def _table(r: FieldReader, raw, where: str, simulated: bool) -> TableConfig | None:
    if raw is None:
        return None
    m = r.mapping(raw, where, ("protocol",), ("port", "max_rate_deg_s"))
    protocol = r.string(m, "protocol", where, TABLE_PROTOCOLS)
    port = None
    if "port" in m:
        port = _port(r, m["port"], f"{where}.port")
    elif not simulated:
        r.fail(f"{where}.port", "a mapping with url (the device is real, so the table is too)",
               describe(MISSING))
    max_rate = r.number(m, "max_rate_deg_s", where, 1e-3) if "max_rate_deg_s" in m else 20.0
    return TableConfig(protocol, port, max_rate)


def _station(r: FieldReader, raw, where: str) -> Station:
    m = r.mapping(raw, where, ("latitude_deg",), ("height_m", "gravity_m_s2"))
    latitude = r.number(m, "latitude_deg", where)
    if not -90 <= latitude <= 90:
        r.fail(f"{where}.latitude_deg", "a latitude from -90 to 90", describe(m["latitude_deg"]))
    # the range fieldcal.earth.Station accepts, checked here so the error names the file
    height = r.bounded(m, "height_m", where, -500, 9000, "m above the ellipsoid") if "height_m" in m else 0.0
    gravity = None
    if m.get("gravity_m_s2") is not None:
        gravity = r.number(m, "gravity_m_s2", where)
        if not 9.7 < gravity < 9.9:
            r.fail(f"{where}.gravity_m_s2", "a measured gravity from 9.7 to 9.9 m/s^2", describe(gravity))
    return Station(latitude, height, gravity)


def load_config(name_or_path: str | os.PathLike) -> StationConfig:
    """Load a path, or a bare name: NAME.yaml here, else the shipped one (``fieldcal.paths``); a
    bad file is a one-line ConfigError."""
    given = Path(name_or_path)
    path = find_named(given, "config")
    if path is None and not given.suffix and not given.exists():
        raise ConfigError(not_found(given, "config"), str(given))
    path = path or given  # a path given: the reader says what is wrong with it
    doc = read_yaml_file(path, ConfigError, "config")
    r = FieldReader(str(path), ConfigError)
    m = r.mapping(doc, "", ("device", "station"), ("table", "thermal"))
    device = _device(r, m["device"], "device")
    return StationConfig(path=str(path), device=device, station=_station(r, m["station"], "station"),
                         table=_table(r, m.get("table"), "table", device.protocol == "sim"),
                         thermal=_thermal_setting(r, m))


def _thermal_setting(r: FieldReader, m: dict) -> str:
    """The config's ``thermal:`` (auto when absent). YAML 1.1 reads a bare on/off as true/false:
    taken as the words the user wrote."""
    if "thermal" not in m:
        return "auto"
    value = m["thermal"]
    if isinstance(value, bool):
        return "on" if value else "off"
    if value not in THERMAL_SETTINGS:
        close = nearest(value, THERMAL_SETTINGS)
        r.fail("thermal", " or ".join(THERMAL_SETTINGS) + (f" (did you mean {close!r}?)" if close else ""),
               describe(value), line_of(m, "thermal"))
    return value
