"""A synthetic PX4 thermal-calibration ULog: a still board warming from a cold soak, its bias
following the simulator's thermal truth (drivers.sim.thermal), written in the ULog format
(docs.px4.io "ULog File Format": header, format 'F', subscription 'A', data 'D' messages) with
the topics and fields PX4's Tools/process_sensor_caldata.py reads (sensor_accel, sensor_gyro
with temperature and device_id; sensor_baro, which that script requires).

No public PX4 thermal-calibration log was found (where we looked: "why_synthetic" in
tests/data/px4_thermal_oracle.json), so this log, deterministic for its seed, is what PX4's
script was run on for that stored oracle (its "how", "command" and "source" say how).
"""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from drivers.sim.thermal import TemperatureProfile, ThermalTruth

GRAVITY = 9.80665
RATE_HZ = 25.0
DURATION_S = 1800.0
# A cold-soaked board (−10 °C) warming by 50 K with a 10-minute time constant.
PROFILE = TemperatureProfile("warmup", start_c=-10.0, rise_k=50.0, time_constant_s=600.0)
# Bias terms (per K, K², K³) about 15 °C: 0.3 mg/K, a curvature, no cubic for the accelerometer;
# 0.03 °/s/K with a cubic for the gyro: the magnitudes issue 28 names.
ACCEL_TRUTH = ThermalTruth(reference_c=15.0, bias_terms=np.array([[3e-3, -2e-3, 1.5e-3], [4e-5, 3e-5, -5e-5]]),
                           scale_drift=np.zeros(3))
GYRO_TRUTH = ThermalTruth(reference_c=15.0, bias_terms=np.array([[5e-4, -3e-4, 2e-4], [1e-5, -1e-5, 5e-6],
                                                                 [3e-7, 2e-7, -4e-7]]),
                          scale_drift=np.zeros(3))
ACCEL_NOISE = 0.02  # m/s² per sample (about 2 mg at 25 Hz)
GYRO_NOISE = 0.002  # rad/s per sample
ACCEL_AT_REST = np.array([0.05, -0.08, -GRAVITY + 0.1])  # FRD, level: z reads −g, plus a bias
GYRO_AT_REST = np.array([0.004, -0.002, 0.001])  # the bias at reference_c (and the Earth rate)

def imu_fields() -> list[tuple[str, str]]:
    """sensor_accel's and sensor_gyro's fields as PX4 logs them (the ones read here)."""
    return [("uint64_t", "timestamp"), ("uint64_t", "timestamp_sample"), ("uint32_t", "device_id"),
            ("float", "x"), ("float", "y"), ("float", "z"), ("float", "temperature")]


_HEADER = b"ULog\x01\x12\x35" + bytes([1]) + struct.pack("<Q", 0)
_FIELDS = {"uint64_t": "u8", "uint32_t": "u4", "float": "f4"}


def _message(kind: bytes, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), kind[0]) + payload


def _data(msg_id: int, fields: list[tuple[str, str]], columns: dict) -> bytes:
    """Every sample of one subscription as 'D' messages, in one numpy buffer (no per-sample loop)."""
    dtype = np.dtype([("size", "<u2"), ("type", "u1"), ("id", "<u2")]
                     + [(name, "<" + _FIELDS[kind]) for kind, name in fields])
    n = len(next(iter(columns.values())))
    records = np.zeros(n, dtype=dtype)
    records["size"], records["type"], records["id"] = dtype.itemsize - 3, ord("D"), msg_id
    for name, values in columns.items():
        records[name] = values
    return records.tobytes()


def write_ulog(path: Path, topics: dict) -> Path:
    """``topics``: name -> (fields [(type, name)], columns {name: array}); instance 0 each."""
    out = bytearray(_HEADER)
    out += _message(b"B", bytes(40))  # flag bits: none set
    for name, (fields, _) in topics.items():
        out += _message(b"F", f"{name}:{''.join(f'{t} {f};' for t, f in fields)}".encode())
    for msg_id, name in enumerate(topics):
        out += _message(b"A", struct.pack("<BH", 0, msg_id) + name.encode())
    for msg_id, (fields, columns) in enumerate(topics.values()):
        out += _data(msg_id, fields, columns)
    path.write_bytes(bytes(out))
    return path


def thermal_log(path: Path, seed: int = 1, duration_s: float = DURATION_S) -> Path:
    """The synthetic warm-up log at ``path`` (see the module docstring)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, 1.0 / RATE_HZ)
    stamp = (t * 1e6).astype(np.uint64) + 1_000_000
    temperature = PROFILE.at(t)
    accel = ACCEL_AT_REST + ACCEL_TRUTH.offset_and_ratio(temperature)[0] + rng.normal(0, ACCEL_NOISE, (len(t), 3))
    gyro = GYRO_AT_REST + GYRO_TRUTH.offset_and_ratio(temperature)[0] + rng.normal(0, GYRO_NOISE, (len(t), 3))
    imu = imu_fields()
    baro = [("uint64_t", "timestamp"), ("uint32_t", "device_id"), ("float", "pressure"), ("float", "temperature")]

    def triad(values, device_id):
        return {"timestamp": stamp, "timestamp_sample": stamp, "device_id": np.full(len(t), device_id),
                "x": values[:, 0], "y": values[:, 1], "z": values[:, 2], "temperature": temperature}

    slow = slice(None, None, 5)  # the barometer at 5 Hz: PX4's script fits it, fieldcal does not
    return write_ulog(path, {
        "sensor_accel": (imu, triad(accel, 2359306)),
        "sensor_gyro": (imu, triad(gyro, 2359306)),
        "sensor_baro": (baro, {"timestamp": stamp[slow], "device_id": np.full(len(t[slow]), 4653065),
                               "pressure": np.full(len(t[slow]), 1013.25), "temperature": temperature[slow]}),
    })
