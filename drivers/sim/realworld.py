"""What a real MEMS unit and its logger add to an ideal simulated recording (``RealWorld``).

Used by ``drivers.sim.handheld.simulate_handheld(real_world=...)``. Every effect is off at zero,
so a test switches on the one it is about. The effects, in the order they act:

* sensor, on the true input: gyro g-sensitivity (rate reads G·specific force more), a gyro bias
  that settles after switch-on (warm-up), a gyro bias random walk, a temperature ramp acting on
  both triads' biases and scale factors, a hand tremor while a pose is held (the unit wobbles a
  little, so the rate and the specific force both see it, attitude kept exact), and a turn-on
  bias (this switch-on's bias differs from the nominal one by a random offset);
* converter: saturation at the gyro's range (a fast turn clips);
* logger: timestamp jitter, dropped samples, and a log that starts late (no initial rest: the
  first samples are part of the first hand motion).

The truth a calibration is judged against, when a parameter varies in time, is its mean over
the recording: the warm-up, the temperature ramp and the random walk are centred on it (a
recording shorter than the warm-up cannot tell the settled bias from the warm one; what it can
tell is the bias it had, and how much that moved). Nothing here changes what ``TriadTruth``
says except the turn-on bias, which is part of the truth.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from drivers.sim.device import DEG, MG, STANDARD_GRAVITY


@dataclass(frozen=True)
class RealWorld:
    """The effects of the module doc, all off at zero.

    ``g_sensitivity_deg_s_per_g``: 1σ of each entry of the gyro's g-sensitivity matrix G.
    ``warm_up_deg_s`` / ``warm_up_tau_s``: a gyro bias offset that decays exponentially after
    switch-on (centred on its mean over the recording, see the module doc). ``temperature_ramp_k``: the temperature change over the recording (centred on its
    mean), acting through ``bias_tempco_deg_s_per_k`` (gyro bias), ``acc_bias_tempco_mg_per_k``
    and ``scale_tempco_ppm_per_k`` (both triads), each axis a random sign.
    ``bias_random_walk_deg_s_per_sqrt_s``: gyro bias random walk (rate random walk).
    ``pose_tremor_deg_s``: peak rate of a hand tremor (8-12 Hz) while a pose is held, on a random
    ``pose_tremor_share`` of the poses; the wobble's acceleration follows from it.
    ``turn_on_bias_deg_s`` / ``turn_on_bias_mg``: 1σ of this switch-on's bias offset per axis.
    ``gyro_range_deg_s``: the gyro's full scale (None: wide enough); beyond it the output clips.
    ``jitter_s``: 1σ timestamp jitter (kept increasing). ``drop_fraction``: samples lost by the
    logger at random (the time column says so). ``late_start``: the log starts during the first
    hand motion, so there is no initial rest. Deterministic for the recording's seed."""

    g_sensitivity_deg_s_per_g: float = 0.1
    warm_up_deg_s: float = 0.05
    warm_up_tau_s: float = 60.0
    temperature_ramp_k: float = 5.0
    bias_tempco_deg_s_per_k: float = 0.005
    jitter_s: float = 2e-4
    drop_fraction: float = 0.002
    acc_bias_tempco_mg_per_k: float = 0.0
    scale_tempco_ppm_per_k: float = 0.0
    bias_random_walk_deg_s_per_sqrt_s: float = 0.0
    pose_tremor_deg_s: float = 0.0
    pose_tremor_share: float = 0.5
    turn_on_bias_deg_s: float = 0.0
    turn_on_bias_mg: float = 0.0
    gyro_range_deg_s: float | None = None
    late_start: bool = False


def turn_on(truth: dict, rw: RealWorld, rng: np.random.Generator) -> dict:
    """The truth with this switch-on's bias: each triad's bias moved by a random input offset
    (through its K: raw = K·(input + offset) + bias)."""
    sigma = {"gyroscope": rw.turn_on_bias_deg_s * DEG, "accelerometer": rw.turn_on_bias_mg * MG}
    out = dict(truth)
    for name, s in sigma.items():
        if s and name in truth:
            out[name] = replace(truth[name], bias=truth[name].bias + truth[name].K @ rng.normal(0.0, s, 3))
    return out


def tremor(attitude: np.ndarray, n: int, rate_hz: float, peak_rate: float, gravity_enu: np.ndarray,
           earth_enu: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A pose held by a trembling hand: n samples of specific force and rate (body axes).

    The unit wobbles about a random body axis by θ(t) = a·e(t)·sin(2πft + φ), e a sin² envelope
    that is zero at both ends, so the pose starts and ends exactly at ``attitude`` and the rate
    is θ̇ exactly; the wobble's centre sits ~5 cm from the sensor, which adds its tangential
    acceleration to the specific force."""
    f = rng.uniform(8.0, 12.0)
    w = 2 * math.pi * f
    a = peak_rate / w
    axis = rng.standard_normal(3)
    axis /= np.linalg.norm(axis)
    phase = rng.uniform(0, 2 * math.pi)
    T = n / rate_hz
    s = (np.arange(n) + 0.5) / rate_hz
    env = np.sin(math.pi * s / T) ** 2
    d_env = math.pi / T * np.sin(2 * math.pi * s / T)
    dd_env = 2 * (math.pi / T) ** 2 * np.cos(2 * math.pi * s / T)
    sin, cos = np.sin(w * s + phase), np.cos(w * s + phase)
    theta = a * env * sin
    d_theta = a * (d_env * sin + env * w * cos)
    dd_theta = a * (dd_env * sin + 2 * d_env * w * cos - env * w * w * sin)
    wobble = Rotation.from_rotvec(np.outer(theta, axis)).as_matrix()  # body(t) -> body at rest
    att = attitude @ wobble
    lever = 0.05 * np.cross(axis, rng.standard_normal(3))
    accel_body = np.outer(dd_theta, np.cross(axis, lever))  # tangential, in the rest body frame
    accel_enu = accel_body @ attitude.T
    force = np.einsum("nji,nj->ni", att, accel_enu + gravity_enu)
    rate = np.outer(d_theta, axis) + np.einsum("nji,j->ni", att, earth_enu)
    return force, rate


@dataclass(frozen=True)
class SensorEffects:
    """Per triad: extra input (n, 3) in SI units added to the true input, and a per-axis scale
    (n, 3) multiplying it."""

    offset: dict
    scale: dict


def sensor_effects(t: np.ndarray, force: np.ndarray, rw: RealWorld, legacy: np.random.Generator,
                   rng: np.random.Generator) -> SensorEffects:
    """The gyro's g-sensitivity, warm-up, temperature and random walk, and the accelerometer's
    temperature terms. ``legacy`` draws G, warm-up and the gyro tempco (their draws come first,
    as they always have); ``rng`` draws the rest."""
    G = legacy.normal(0.0, rw.g_sensitivity_deg_s_per_g * DEG / STANDARD_GRAVITY, (3, 3))
    warm = rw.warm_up_deg_s * DEG * legacy.choice([-1.0, 1.0], 3)
    tempco = rw.bias_tempco_deg_s_per_k * DEG * legacy.choice([-1.0, 1.0], 3)
    span = max(t[-1] - t[0], 1e-9)
    ramp = (rw.temperature_ramp_k * ((t - t[0]) / span - 0.5))[:, None]  # K from the mean temperature
    settle = np.exp(-(t - t[0]) / rw.warm_up_tau_s)
    gyro = force @ G.T + (settle - settle.mean())[:, None] * warm + ramp * tempco
    acc = np.zeros_like(force)
    scale = {}
    if rw.bias_random_walk_deg_s_per_sqrt_s:
        dt = np.diff(t, prepend=t[0])[:, None]
        walk = np.cumsum(rng.standard_normal(force.shape) * np.sqrt(dt), axis=0)
        gyro += rw.bias_random_walk_deg_s_per_sqrt_s * DEG * (walk - walk.mean(axis=0))
    if rw.acc_bias_tempco_mg_per_k:
        acc += ramp * rw.acc_bias_tempco_mg_per_k * MG * rng.choice([-1.0, 1.0], 3)
    if rw.scale_tempco_ppm_per_k:
        for name in ("accelerometer", "gyroscope"):
            scale[name] = 1.0 + ramp * rw.scale_tempco_ppm_per_k * 1e-6 * rng.choice([-1.0, 1.0], 3)
    return SensorEffects(offset={"gyroscope": gyro, "accelerometer": acc}, scale=scale)


def saturate(raw: np.ndarray, rw: RealWorld, zero: float, per_rad_s: float) -> np.ndarray:
    """The gyro output clipped at its range (``zero``: output at zero rate; ``per_rad_s``: the
    nominal output units per rad/s), as a converter does."""
    if rw.gyro_range_deg_s is None:
        return raw
    full = rw.gyro_range_deg_s * DEG * per_rad_s
    return np.clip(raw, zero - full, zero + full)


def first_kept(static: np.ndarray, rw: RealWorld, rng: np.random.Generator) -> int:
    """The first sample the log keeps: 0, or with ``late_start`` one inside the first motion."""
    if not rw.late_start or len(static) < 2:
        return 0
    return int(rng.integers(static[0, 1], static[1, 0]))


def logged(n: int, rate_hz: float, rw: RealWorld, start: int, rng: np.random.Generator,
           legacy: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The samples the logger keeps (indices from ``start``) and their timestamp jitter (s)."""
    keep = np.flatnonzero(legacy.random(n) >= rw.drop_fraction)
    keep = keep[keep >= start]
    jitter = np.clip(legacy.normal(0.0, rw.jitter_s, len(keep)), -0.4 / rate_hz, 0.4 / rate_hz)
    return keep, jitter
