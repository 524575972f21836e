"""Hand-held calibration recordings (imu_tk style, Tedaldi et al. ICRA 2014), simulated.

The unit rests for ``initial_rest_s``, then is picked up, turned and set down by hand in a series
of poses, each held still for a few seconds. Truth follows ``drivers.sim.physics``: ENU frame
(x east, y north, z up), attitude = body -> ENU matrix, raw = K·(true + noise) + bias, quantised
to ``lsb``. The accelerometer K is lower-triangular (its axes define the body frame); the gyroscope
K is full (``diag(scale)·(I + M)``, M the gyro-to-body misalignment), as on a real unit.

A hand motion from attitude A0 to A1 (:class:`HandMotion`) is two overlapping turns about
different body axes, attitude(t) = A0·exp(s1(t)·v1)·exp(s2(t)·v2) with exp(v1)·exp(v2) = A0ᵀ·A1,
so the rotation does not commute and a gyro calibration must integrate it properly. s1 and s2 are
quintic smoothsteps (zero rate and zero angular acceleration at both ends) over different parts
of the motion; the body rate is their analytic derivative, exp(s2·v2)ᵀ·ṡ1·v1 + ṡ2·v2. The sensor
is also lifted and set down (a few cm to 0.2 m, peaks 1-3 m/s²) and carried sideways, and a small
hand tremor is added to the specific force only (tremor on the rate would break the exact
attitude bookkeeping). Earth rate is in the true rate everywhere. The first turn starts the
motion and the second ends it, so every sample between two poses moves, and the onset is gentle:
a turn about the vertical is invisible to the accelerometer until the lift, a detector needs the
gyro to place such an edge.

Noise: ``PAPER_NOISE`` (paper Table 4) by default; ``CONSUMER_NOISE`` for a cheap MEMS unit.

Everything is vectorised over samples; a loop runs over poses only.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from drivers.sim.device import COUNTS_PER_M_S2, COUNTS_PER_RAD_S, COUNTS_ZERO, DEG, MG, PAPER_NOISE
from drivers.noise import TriadNoise
from drivers.sim.noise import NoiseGenerator
from drivers.sim.physics import ANGULAR_RATE, SPECIFIC_FORCE, TriadTruth, lower_triangular_k
from drivers.sim import realworld as _rw
from drivers.sim.realworld import RealWorld

EARTH_RATE = 7.292115e-5  # rad/s
MAX_TURN_RATE = 220.0 * DEG  # peak rate of one turn; a long turn is slowed down to this

# A consumer-grade alternative to PAPER_NOISE (MPU-6050-like datasheet figures): accelerometer
# 400 µg/√Hz, gyroscope 0.005 °/s/√Hz, bias instabilities 0.1 mg and 10 °/h.
CONSUMER_NOISE = {
    "accelerometer": TriadNoise(white=400e-6 * 9.80665, bias_instability=0.1 * MG),
    "gyroscope": TriadNoise(white=0.005 * DEG, bias_instability=10.0 * DEG / 3600.0),
}

_D = 1.0 / math.sqrt(3.0)
# Default gravity directions (body up vectors): the six axes and the eight cube diagonals, ordered
# so that consecutive poses are at most about 90° apart, the way a hand turns a unit.
SPREAD_UP = np.array([
    [0, 0, 1], [_D, _D, _D], [1, 0, 0], [_D, -_D, _D], [0, -1, 0], [-_D, -_D, _D], [-1, 0, 0],
    [-_D, _D, _D], [0, 1, 0], [_D, _D, -_D], [_D, -_D, -_D], [0, 0, -1], [-_D, -_D, -_D],
    [-_D, _D, -_D],
], dtype=float)


def handheld_truth(raw_counts: bool = True, noise: dict | None = None) -> dict[str, TriadTruth]:
    """The default unit: paper-like accelerometer errors, a gyro with a full 3x3 K.

    ``noise``: triad name -> TriadNoise (default PAPER_NOISE; CONSUMER_NOISE is the cheap one).
    """
    noise = PAPER_NOISE if noise is None else noise
    acc_k = lower_triangular_k(1.0 + np.array([3e-4, -6e-4, 9e-4]), [2e-4, -4e-4, 3e-4])
    acc_bias = np.array([2.5, -1.5, 4.0]) * MG
    # Gyro-to-accelerometer misalignment: all six terms, 1.5-4 mrad, as on real units.
    m = np.array([[0.0, 2.0e-3, -3.5e-3], [-1.5e-3, 0.0, 4.0e-3], [3.0e-3, -2.5e-3, 0.0]])
    gyro_k = np.diag(1.0 + np.array([4e-3, -6e-3, 1.5e-3])) @ (np.eye(3) + m)
    gyro_bias = np.array([0.2, -0.35, 0.45]) * DEG
    spec = {"accelerometer": (SPECIFIC_FORCE, acc_k, acc_bias, COUNTS_PER_M_S2, "m/s^2"),
            "gyroscope": (ANGULAR_RATE, gyro_k, gyro_bias, COUNTS_PER_RAD_S, "rad/s")}
    truth = {}
    for name, (kind, k, bias, sensitivity, unit) in spec.items():
        lsb = 0.0
        if raw_counts:
            k, bias, unit, lsb = k * sensitivity, bias * sensitivity + COUNTS_ZERO, "count", 1.0
        truth[name] = TriadTruth(kind=kind, K=k, bias=bias, noise=noise[name], lsb=lsb, output_unit=unit)
    return truth


def _smoothstep(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Quintic smoothstep of x clipped to [0, 1], with its first and second derivatives in x."""
    x = np.clip(x, 0.0, 1.0)
    return (x**3 * (10 - 15 * x + 6 * x * x), 30 * x * x * (1 - x) ** 2,
            60 * x - 180 * x * x + 120 * x**3)


@dataclass(frozen=True)
class HandMotion:
    """One hand motion of ``duration_s`` from attitude ``start`` (body -> ENU), see module doc.

    ``turn1`` / ``turn2``: (begin, end) of s1 / s2 as fractions of the duration; s1 starts at 0
    and s2 ends at 1 so that every instant inside is moving. Lifted ``lift_m`` over ``lift_s``
    from fraction ``lift[0]``, set down over ``lift_s`` ending at fraction ``lift[1]``;
    ``shift_m`` (ENU east, north) over the fractions ``shift``; tremor ``tremor_m_s2`` (3,) ENU at
    ``tremor_hz`` with phases ``tremor_phase``, fading in and out with the motion.
    """

    start: np.ndarray
    v1: np.ndarray
    v2: np.ndarray
    duration_s: float
    turn1: tuple[float, float]
    turn2: tuple[float, float]
    lift_m: float
    lift_s: float
    lift: tuple[float, float]
    shift_m: np.ndarray
    shift: tuple[float, float]
    tremor_m_s2: np.ndarray
    tremor_hz: float
    tremor_phase: np.ndarray

    @property
    def end(self) -> np.ndarray:
        return self.start @ Rotation.from_rotvec(self.v1).as_matrix() @ Rotation.from_rotvec(self.v2).as_matrix()

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """At times ``t`` (s, 0..duration_s) into the motion: attitude (n, 3, 3) body -> ENU, body
        rate relative to ENU (n, 3) rad/s (add Earth rate for a gyro), and acceleration of the
        sensor in ENU (n, 3) m/s² including tremor (add gravity for the specific force)."""
        t = np.asarray(t, dtype=float)
        T = self.duration_s
        (b1, e1), (b2, e2) = self.turn1, self.turn2
        s1, ds1, _ = _smoothstep((t / T - b1) / (e1 - b1))
        s2, ds2, _ = _smoothstep((t / T - b2) / (e2 - b2))
        r2 = Rotation.from_rotvec(np.outer(s2, self.v2)).as_matrix()
        attitude = self.start @ Rotation.from_rotvec(np.outer(s1, self.v1)).as_matrix() @ r2
        w1 = np.outer(ds1 / ((e1 - b1) * T), self.v1)
        omega = np.einsum("nji,nj->ni", r2, w1) + np.outer(ds2 / ((e2 - b2) * T), self.v2)
        # Lifted over lift_s from lift[0]·T, set down over lift_s ending at lift[1]·T.
        up = (_smoothstep((t - self.lift[0] * T) / self.lift_s)[2]
              - _smoothstep((t - self.lift[1] * T + self.lift_s) / self.lift_s)[2])
        c0, c1 = self.shift
        side = _smoothstep((t / T - c0) / (c1 - c0))[2] / ((c1 - c0) * T) ** 2
        accel = np.zeros((len(t), 3))
        accel[:, :2] = np.outer(side, self.shift_m)
        accel[:, 2] = self.lift_m / self.lift_s**2 * up
        envelope = np.sin(np.pi * np.clip(t / T, 0.0, 1.0)) ** 2
        accel += (envelope[:, None] * self.tremor_m_s2
                  * np.sin(2 * np.pi * self.tremor_hz * t[:, None] + self.tremor_phase))
        return attitude, omega, accel


@dataclass(frozen=True)
class TableTurn:
    """The unit on a turntable: about ENU up at ``rate`` (rad/s, signed), reached by a constant
    angular acceleration over ``ramp_s``, held ``hold_s``, stopped over ``ramp_s``."""

    start: np.ndarray
    rate: float
    ramp_s: float
    hold_s: float

    @property
    def duration_s(self) -> float:
        return 2 * self.ramp_s + self.hold_s

    def _angle(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r, a, T = self.ramp_s, self.rate / self.ramp_s, self.duration_s
        up = np.clip(t, 0, r)
        down = np.clip(t - r - self.hold_s, 0, r)
        angle = 0.5 * a * up**2 + self.rate * np.clip(t - r, 0, self.hold_s) + self.rate * down - 0.5 * a * down**2
        rate = np.where(t < r, a * t, np.where(t > T - r, a * (T - t), self.rate))
        return angle, np.clip(rate, min(0.0, self.rate), max(0.0, self.rate))

    @property
    def end(self) -> np.ndarray:
        angle = self._angle(np.array([self.duration_s]))[0][0]
        return Rotation.from_rotvec([0.0, 0.0, angle]).as_matrix() @ self.start

    @property
    def steady(self) -> tuple[float, float]:
        """Start and end (s into the turn) of the constant rate."""
        return self.ramp_s, self.ramp_s + self.hold_s

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """As :meth:`HandMotion.evaluate`: attitude, body rate relative to ENU, acceleration (none:
        the sensor sits on the axis)."""
        angle, rate = self._angle(np.asarray(t, dtype=float))
        attitude = Rotation.from_rotvec(np.outer(angle, [0.0, 0.0, 1.0])).as_matrix() @ self.start
        omega = np.outer(rate, self.start.T @ np.array([0.0, 0.0, 1.0]))  # the axis is fixed in body
        return attitude, omega, np.zeros((len(angle), 3))


@dataclass(frozen=True)
class HandheldRecording:
    """A simulated hand-held recording and its truth.

    ``t`` (n,) s; ``accelerometer`` / ``gyroscope`` (n, 3) in output units; ``static`` (m, 2)
    [start, stop) sample indices of every static interval in order (the first is the initial
    rest); ``attitudes`` (m, 3, 3) body -> ENU per pose; ``motions`` the m - 1 hand motions
    (motion i runs from sample static[i, 1] - 1 to static[i + 1, 0]); ``true_rate`` (rad/s) and
    ``true_force`` (m/s²) noise-free, in body axes.
    """

    t: np.ndarray
    accelerometer: np.ndarray
    gyroscope: np.ndarray
    truth: dict[str, TriadTruth]
    static: np.ndarray
    attitudes: np.ndarray
    motions: tuple[HandMotion, ...]
    rate_hz: float
    latitude_deg: float
    gravity: float
    true_rate: np.ndarray | None = None
    true_force: np.ndarray | None = None
    turns: np.ndarray | None = None  # (k, 2) [start, stop) samples of each turntable turn's steady rate
    turn_rates: np.ndarray | None = None  # (k,) their rates, rad/s about ENU up

    @property
    def triads(self) -> dict[str, np.ndarray]:
        return {"accelerometer": self.accelerometer, "gyroscope": self.gyroscope}

    @property
    def kinds(self) -> dict[str, str]:
        return {name: truth.kind for name, truth in self.truth.items()}

    @property
    def units(self) -> dict[str, str]:
        return {name: truth.output_unit for name, truth in self.truth.items()}

    @property
    def up(self) -> np.ndarray:
        """(m, 3) true gravity direction (up) in body axes per pose."""
        return self.attitudes[:, 2, :]

    @property
    def earth_rate_enu(self) -> np.ndarray:
        lat = math.radians(self.latitude_deg)
        return EARTH_RATE * np.array([0.0, math.cos(lat), math.sin(lat)])


def pose_attitudes(up: np.ndarray, heading: np.ndarray) -> np.ndarray:
    """Body -> ENU matrices (m, 3, 3) whose body up vector is ``up`` (m, 3), turned by ``heading``
    (m,) rad about the vertical."""
    up = up / np.linalg.norm(up, axis=1, keepdims=True)
    helper = np.where(np.abs(up[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = np.cross(up, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    level = np.stack([e1, np.cross(up, e1), up], axis=1)  # rows e1, e2, up; e1 × e2 = up
    return Rotation.from_rotvec(np.outer(heading, [0.0, 0.0, 1.0])).as_matrix() @ level


def _default_ups(n_poses: int, rng: np.random.Generator) -> np.ndarray:
    """SPREAD_UP cycled, each tilted 10-20° in a random direction."""
    up = SPREAD_UP[np.arange(n_poses) % len(SPREAD_UP)]
    axis = np.cross(up, rng.standard_normal((n_poses, 3)))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    tilt = rng.uniform(10.0, 20.0, n_poses) * DEG
    return Rotation.from_rotvec(axis * tilt[:, None]).apply(up)


def _hand_motion(start, end, duration_s, rng) -> HandMotion:
    """A random, non-commuting motion from ``start`` to ``end`` lasting at least ``duration_s``."""
    turn = Rotation.from_matrix(start.T @ end).as_rotvec()  # body axes
    sideways = np.cross(turn if np.linalg.norm(turn) > 1e-6 else [0.0, 0.0, 1.0], rng.standard_normal(3))
    sideways *= rng.uniform(15.0, 35.0) * DEG / np.linalg.norm(sideways)
    v1 = rng.uniform(0.3, 0.7) * turn + sideways
    v2 = (Rotation.from_rotvec(v1).inv() * Rotation.from_rotvec(turn)).as_rotvec()
    # Two overlapping turns: a brisk first one (35-50 % of the motion), then one to the end. The
    # turns start and end the motion with a gentle (cubic) change of gravity direction, the hard
    # case for a detector; the lift, whose acceleration starts linearly, comes a little later.
    e1 = rng.uniform(0.35, 0.5)
    turn1, turn2 = (0.0, e1), (e1 - rng.uniform(0.1, 0.2), 1.0)
    # Peak of a quintic smoothstep's rate is 1.875/duration: slow a long turn down.
    needed = max(np.linalg.norm(v1) / (turn1[1] - turn1[0]), np.linalg.norm(v2) / (turn2[1] - turn2[0]))
    T = max(duration_s, 1.875 * needed / MAX_TURN_RATE)
    lift = rng.uniform(0.03, 0.2)
    lift_at = (rng.uniform(0.0, 0.15), 1.0 - rng.uniform(0.0, 0.15))
    lift_s = min(math.sqrt(5.77 * lift / rng.uniform(1.0, 3.0)),  # peak 5.77·h/lift_s²
                 0.45 * (lift_at[1] - lift_at[0]) * T)
    heading = rng.uniform(0, 2 * np.pi)
    c0 = rng.uniform(0.15, 0.35)
    return HandMotion(start=start, v1=v1, v2=v2, duration_s=T, turn1=turn1, turn2=turn2,
                      lift_m=lift, lift_s=lift_s, lift=lift_at,
                      shift_m=rng.uniform(0.0, 0.15) * np.array([np.cos(heading), np.sin(heading)]),
                      shift=(c0, c0 + rng.uniform(0.3, 0.5)),
                      tremor_m_s2=rng.uniform(0.05, 0.2, 3), tremor_hz=rng.uniform(4.0, 10.0),
                      tremor_phase=rng.uniform(0, 2 * np.pi, 3))


def simulate_handheld(seed: int, *, n_poses: int = 20, rate_hz: float = 100.0, raw_counts: bool = True,
                      initial_rest_s: float = 30.0, static_s=(3.0, 6.0), motion_s=(2.0, 4.0),
                      latitude_deg: float = 40.0, gravity: float = 9.80,
                      truth: dict[str, TriadTruth] | None = None,
                      directions: np.ndarray | None = None,
                      table_turns: tuple = (), real_world: RealWorld | None = None) -> HandheldRecording:
    """A hand-held recording: initial rest (pose 0), then n_poses - 1 poses joined by hand motions.

    ``directions``: (n_poses, 3) body up vectors to use as they are (default: SPREAD_UP cycled
    with random 10-20° tilts); headings are random either way. ``truth`` overrides
    ``handheld_truth(raw_counts)``. Motions last ``motion_s`` unless a long turn needs more time
    to keep its peak rate under MAX_TURN_RATE. Deterministic for a given seed.

    ``table_turns``: ``(pose, rate_deg_s, hold_s)`` each: after that pose's rest the unit, on a
    turntable, turns about the vertical (2 s ramps, ``hold_s`` at the rate), then rests 4 s at its
    new heading (a static interval of its own) before the hand takes it to the next pose.

    ``real_world``: the effects of :class:`RealWorld` on top (g-sensitivity, warm-up and
    temperature drift of the gyro bias, timestamp jitter, dropped samples); ``static`` and
    ``turns`` then index the samples kept.
    """
    rng = np.random.default_rng(seed)
    truth = handheld_truth(raw_counts) if truth is None else truth
    if directions is None:
        up = _default_ups(n_poses, rng)
    else:
        up = np.asarray(directions, dtype=float)
        if up.shape != (n_poses, 3):
            raise ValueError(f"directions: expected shape ({n_poses}, 3), got {up.shape}")
    attitudes = pose_attitudes(up, rng.uniform(0, 2 * np.pi, n_poses))
    lat = math.radians(latitude_deg)
    earth = EARTH_RATE * np.array([0.0, math.cos(lat), math.sin(lat)])
    gravity_enu = np.array([0.0, 0.0, gravity])

    static_n = np.round(np.r_[initial_rest_s, rng.uniform(*static_s, n_poses - 1)] * rate_hz).astype(int)
    turns_after = {int(p): (math.radians(r), h) for p, r, h in table_turns}
    motions, forces, rates, static, held, turns, turn_rates = [], [], [], [], [], [], []
    first = 0

    # The real world's own draws come from a stream of their own: a recording with none of its
    # new effects is the same as before they existed.
    extra = np.random.default_rng([seed, 11])
    rw = real_world

    def rest(a, n):
        nonlocal first
        if rw is not None and rw.pose_tremor_deg_s and extra.random() < rw.pose_tremor_share:
            force_n, rate_n = _rw.tremor(a, n, rate_hz, rw.pose_tremor_deg_s * DEG, gravity_enu, earth, extra)
            forces.append(force_n)
            rates.append(rate_n)
        else:
            forces.append(np.broadcast_to(a.T @ gravity_enu, (n, 3)))
            rates.append(np.broadcast_to(a.T @ earth, (n, 3)))
        static.append((first, first + n))
        held.append(a)
        first += n

    def move(motion):
        nonlocal first
        # The motion spans from the last static sample to the next pose's first one, exclusive:
        # every sample strictly inside is moving, however slightly.
        n_moving = max(1, round(motion.duration_s * rate_hz) - 1)
        if isinstance(motion, HandMotion):
            motion = replace(motion, duration_s=(n_moving + 1) / rate_hz)
        tau = np.arange(1, n_moving + 1) / rate_hz
        att, omega, accel = motion.evaluate(tau)
        forces.append(np.einsum("nji,nj->ni", att, accel + gravity_enu))
        rates.append(omega + np.einsum("nji,j->ni", att, earth))
        motions.append(motion)
        if isinstance(motion, TableTurn):
            b, e = motion.steady
            inside = np.flatnonzero((tau >= b) & (tau <= e))
            turns.append((first + inside[0], first + inside[-1] + 1))
            turn_rates.append(motion.rate)
        first += n_moving
        return motion.end

    for i in range(n_poses):
        a = attitudes[i]
        rest(a, static_n[i])
        if i in turns_after:
            rate, hold = turns_after[i]
            a = move(TableTurn(a, rate, 2.0, hold))
            rest(a, round(4.0 * rate_hz))
        if i == n_poses - 1:
            break
        move(_hand_motion(a, attitudes[i + 1], rng.uniform(*motion_s), rng))
    force, rate = np.concatenate(forces), np.concatenate(rates)
    t = np.arange(len(force)) / rate_hz

    effects = None
    if rw is not None:
        truth = _rw.turn_on(truth, rw, extra)
        effects = _rw.sensor_effects(t, force, rw, rng, extra)
    out = {}
    for name, triad in truth.items():
        true = force if triad.kind == SPECIFIC_FORCE else rate
        if effects is not None:
            true = true * effects.scale.get(name, 1.0) + effects.offset.get(name, 0.0)
        raw = (true + NoiseGenerator(triad.noise, rate_hz, rng).draw(len(t))) @ triad.K.T + triad.bias
        if effects is not None and triad.kind == ANGULAR_RATE:
            counts = triad.output_unit == "count"
            raw = _rw.saturate(raw, rw, COUNTS_ZERO if counts else 0.0, float(np.mean(np.diag(triad.K))))
        if triad.lsb:
            raw = np.round(raw / triad.lsb) * triad.lsb
        if triad.output_unit == "count":
            raw = np.clip(raw, 0.0, 65535.0)  # a 16-bit converter saturates
        out[name] = raw
    static = np.array(static, dtype=int)
    turns = np.array(turns, dtype=int).reshape(-1, 2)
    held = np.array(held)
    if rw is not None:
        start = _rw.first_kept(static, rw, extra)
        keep, jitter = _rw.logged(len(t), rate_hz, rw, start, extra, rng)
        t = t[keep] + jitter
        out = {name: v[keep] for name, v in out.items()}
        force, rate = force[keep], rate[keep]
        whole = static[:, 0] >= start  # a late start loses the initial rest
        static, held = static[whole], held[whole]
        motions = motions[int((~whole).sum()):]  # and the motion it was cut in
        turn_rates = np.asarray(turn_rates)[turns[:, 0] >= start]
        turns = turns[turns[:, 0] >= start]
        static, turns = np.searchsorted(keep, static), np.searchsorted(keep, turns)  # the kept samples' indices
    return HandheldRecording(t=t, accelerometer=out["accelerometer"], gyroscope=out["gyroscope"],
                             truth=dict(truth), static=static, attitudes=held,
                             motions=tuple(motions), rate_hz=float(rate_hz), latitude_deg=latitude_deg,
                             gravity=gravity, true_rate=rate, true_force=force,
                             turns=turns, turn_rates=np.array(turn_rates))


def to_text(rec: HandheldRecording, directory) -> tuple[Path, Path]:
    """Write ``acc.txt`` and ``gyro.txt`` (imu_tk layout: ``timestamp x y z`` per line, seconds;
    integers for raw counts, else %.9g). Returns the two paths."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for file, name in (("acc.txt", "accelerometer"), ("gyro.txt", "gyroscope")):
        values = rec.triads[name]
        fmt = "%d" if rec.truth[name].output_unit == "count" else "%.9g"
        path = directory / file
        np.savetxt(path, np.column_stack([rec.t, values]), fmt=["%.6f", fmt, fmt, fmt], delimiter=" ")
        paths.append(path)
    return paths[0], paths[1]
