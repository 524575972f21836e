"""Kinematics of a MIMU on a single-axis table, with per-triad errors, noise and quantisation.

Frames: ENU local level (x east, y north, z up); body = the cube fixture. A segment holds the
fixture at one attitude on the table while the table runs at a constant rate (zero for a static
dwell), reached by a constant angular acceleration over ``ramp_s`` from the previous rate.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterator, Mapping

import numpy as np

from drivers.chunk import SampleChunk
from drivers.noise import TriadNoise
from drivers.sim.noise import InnovationNoise, NoiseGenerator
from drivers.sim.rotations import matrix_rotvec, rotvec_matrix
from drivers.sim.thermal import SimThermal

SPECIFIC_FORCE = "specific_force"
ANGULAR_RATE = "angular_rate"
# How the noise is drawn: "innovations" (one normal number per sample and axis, InnovationNoise)
# or "bank" (one per Gauss-Markov process, NoiseGenerator: the simulator before issue 12's speed
# work, kept so that the sessions it wrote resume as they began). The same noise in law.
NOISE_MODELS = ("innovations", "bank")


def lower_triangular_k(scale, misalignment) -> np.ndarray:
    """K of paper eq. 16 from scale factors (kx, ky, kz) and angles (Δyz, Δzy, Δzx) in rad."""
    kx, ky, kz = scale
    dyz, dzy, dzx = misalignment
    return np.array([[kx, 0.0, 0.0], [-dyz * ky, ky, 0.0], [dzy * kz, -dzx * kz, kz]])


@dataclass(frozen=True)
class TriadTruth:
    """True errors of one triad: raw = K·(true + noise) + bias, then quantised to ``lsb``."""

    kind: str
    K: np.ndarray
    bias: np.ndarray
    noise: TriadNoise
    lsb: float = 0.0
    output_unit: str = ""


@dataclass(frozen=True)
class Segment:
    """A stretch of constant fixture attitude; the table ramps to ``table_rate`` then holds it."""

    duration_s: float
    attitude: np.ndarray  # body -> ENU at table angle zero
    table_rate: float = 0.0  # rad/s about the table axis (ENU up), sign = direction
    ramp_s: float = 0.0
    label: str = ""


@dataclass
class MimuSimulator:
    """Generates sample chunks much faster than real time; deterministic for a given seed."""

    triads: Mapping[str, TriadTruth]
    gravity: float  # m/s²
    latitude_rad: float
    earth_rate: float = 7.292115e-5  # rad/s
    rate_hz: float = 250.0
    lever_arm: np.ndarray = field(default_factory=lambda: np.array([0.03, 0.02, 0.01]))  # m, body
    seed: int | np.random.SeedSequence = 0  # (anything numpy's default_rng takes)
    noise_model: str = "innovations"  # one of NOISE_MODELS
    # The unit's temperature and its triads' thermal terms (drivers.sim.thermal); None: the
    # unit stays at its calibration temperature and its chunks carry none.
    thermal: SimThermal | None = None

    def __post_init__(self) -> None:
        if self.thermal is not None and set(self.thermal.triads) - set(self.triads):
            unknown = sorted(set(self.thermal.triads) - set(self.triads))
            raise ValueError(f"thermal: no triad named {', '.join(unknown)} (have {', '.join(self.triads)})")
        self._rng = np.random.default_rng(self.seed)
        self._make_noise(self.noise_model)
        self._rest_cache: tuple = (None, None)
        self._stack_cache: tuple = (None, None)
        truths = list(self.triads.values())
        self._kinds = [t.kind for t in truths]
        self._k_t = np.array([t.K.T for t in truths]).reshape(-1, 3, 3)
        self._bias = np.array([t.bias for t in truths], dtype=float).reshape(-1, 1, 3)
        self._quantised = [(i, t.lsb) for i, t in enumerate(truths) if t.lsb]
        self._sample = 0  # index of the next sample
        self._angle = 0.0  # table angle, rad
        self._rate = 0.0  # table rate, rad/s

    @property
    def time(self) -> float:
        return self._sample / self.rate_hz

    @property
    def table_angle(self) -> float:
        return self._angle

    @property
    def table_rate(self) -> float:
        return self._rate

    def handle(self, n: int, start: np.ndarray, end: np.ndarray, shake: float = 0.3) -> SampleChunk:
        """n samples of the fixture carried by hand from attitude ``start`` to ``end`` (body ->
        ENU at table angle zero) on a stopped table: a smooth rotation (zero rate at both ends)
        plus hand shake of about ``shake`` m/s² and a tenth as many rad/s."""
        if self._rate != 0.0:
            raise ValueError("the table must be stopped before the unit is moved")
        tau = np.arange(1, n + 1) / n
        s = tau * tau * (3 - 2 * tau)  # smoothstep: starts and ends at rest
        ds = 6 * tau * (1 - tau) * self.rate_hz / n  # d s / d t
        rotvec = matrix_rotvec(start.T @ end)  # in body axes
        attitudes = start @ rotvec_matrix(np.outer(s, rotvec))
        c, si = np.cos(self._angle), np.sin(self._angle)
        table = np.array([[c, -si, 0.0], [si, c, 0.0], [0.0, 0.0, 1.0]])
        to_body = np.einsum("ij,njk->nki", table, attitudes)  # (C_table · A)ᵀ per sample
        enu_force = np.array([0.0, 0.0, self.gravity])
        enu_omega = self.earth_rate * np.array([0.0, np.cos(self.latitude_rad), np.sin(self.latitude_rad)])
        hand = self._rng.standard_normal((2, 3)) * shake
        wobble = np.sin(2 * np.pi * 3.0 * tau * n / self.rate_hz)[:, None] * np.sin(np.pi * tau)[:, None]
        force = np.einsum("nij,j->ni", to_body, enu_force) + wobble * hand[0]
        omega = np.einsum("nij,j->ni", to_body, enu_omega) + ds[:, None] * rotvec + 0.1 * wobble * hand[1]
        first = self._sample
        self._sample += n
        return self._sample_chunk(first, force, omega)

    def _make_noise(self, model: str) -> None:
        if model not in NOISE_MODELS:
            raise ValueError(f"noise_model: expected one of {', '.join(NOISE_MODELS)}, got {model!r}")
        self.noise_model = model
        if model == "bank":
            self._noise = {n: NoiseGenerator(t.noise, self.rate_hz, self._rng) for n, t in self.triads.items()}
        else:
            self._noise = InnovationNoise([t.noise for t in self.triads.values()], self.rate_hz, self._rng)

    def get_state(self) -> dict:
        """Everything needed to continue bit for bit (JSON-able), e.g. after a crash."""
        if self.noise_model == "bank":
            noise = {name: gen.get_state() for name, gen in self._noise.items()}
        else:
            noise = self._noise.get_state()  # its "innovations" key tells the model
        return {"sample": self._sample, "angle": self._angle, "rate": self._rate,
                "rng": self._rng.bit_generator.state, "noise": noise}

    def set_state(self, state: dict) -> None:
        """Continue from ``get_state``'s dict, with the noise model it was drawn with."""
        model = "innovations" if "innovations" in state["noise"] else "bank"
        if model != self.noise_model:
            self._make_noise(model)
        self._sample, self._angle, self._rate = int(state["sample"]), float(state["angle"]), float(state["rate"])
        self._rng.bit_generator.state = state["rng"]
        if model == "bank":
            for name, gen in self._noise.items():
                gen.set_state(state["noise"][name])
        else:
            self._noise.set_state(state["noise"])

    def bias_now(self) -> dict[str, np.ndarray]:
        """Each triad's bias at the last sample drawn, in its output units: the constant bias
        plus K times the bias process (flicker bank and rate random walk, not white noise) —
        the value a unit calibrated now would be used with. Exact for the "bank" noise model;
        for "innovations" a draw from its exact law given the samples so far
        (``InnovationNoise.bias_now``). Asking does not change the samples that follow."""
        if self.noise_model == "bank":
            process = {name: gen.bias_now() for name, gen in self._noise.items()}
        else:
            process = dict(zip(self.triads, self._noise.bias_now()))
        return {name: t.bias + t.K @ process[name] for name, t in self.triads.items()}

    def advance(self, n: int, attitude: np.ndarray, target_rate: float, max_accel: float) -> SampleChunk:
        """The next n samples with the table driven toward ``target_rate`` (rad/s) at up to
        ``max_accel`` (rad/s²): the step a live, commanded table takes."""
        if target_rate == 0.0 and self._rate == 0.0 and n > 0:  # at rest: most of a run
            first, self._sample, self._rate = self._sample, self._sample + n, float(target_rate)
            return self._sample_chunk(first, *self._at_rest(attitude, self._angle), n=n)
        ramp = abs(target_rate - self._rate) / max_accel if max_accel > 0 else 0.0
        segment = Segment(n / self.rate_hz, attitude, target_rate, ramp)
        return next(self.run_segment(segment, chunk_len=max(n, 1)))

    def run(self, segments, chunk_len: int = 25_000) -> Iterator[SampleChunk]:
        for seg in segments:
            yield from self.run_segment(seg, chunk_len)

    def run_segment(self, seg: Segment, chunk_len: int = 25_000) -> Iterator[SampleChunk]:
        n_total = int(round(seg.duration_s * self.rate_hz))
        rate0, angle0, start = self._rate, self._angle, self._sample
        ramp = max(seg.ramp_s, 0.0)
        accel = (seg.table_rate - rate0) / ramp if ramp > 0 else 0.0

        def table(tau):
            """Rate, angular acceleration and angle at time tau into the segment."""
            in_ramp = tau < ramp
            ramped = np.minimum(tau, ramp)
            angle = angle0 + rate0 * ramped + 0.5 * accel * ramped**2 \
                + seg.table_rate * np.maximum(tau - ramp, 0.0)
            return (np.where(in_ramp, rate0 + accel * tau, seg.table_rate),
                    np.where(in_ramp, accel, 0.0), angle)

        # The end state is known now; a caller that stops early still leaves time consistent.
        end = n_total / self.rate_hz
        ramped = min(end, ramp)
        end_angle = angle0 + rate0 * ramped + 0.5 * accel * ramped**2 + seg.table_rate * max(end - ramp, 0.0)
        end_rate = rate0 + accel * end if end < ramp else seg.table_rate
        self._rate, self._angle, self._sample = float(end_rate), float(end_angle), start + n_total
        for done in range(0, n_total, chunk_len):
            if seg.table_rate == 0.0 and done / self.rate_hz >= ramp:
                # At rest (most of a run): one attitude for the whole chunk.
                n = min(done + chunk_len, n_total) - done
                yield self._sample_chunk(start + done, *self._at_rest(seg.attitude, end_angle), n=n)
                continue
            tau = np.arange(done, min(done + chunk_len, n_total)) / self.rate_hz
            rate, alpha, angle = table(tau)
            yield self._chunk(start + done, seg.attitude, angle, rate, alpha)

    def _stacked(self, force: np.ndarray, omega: np.ndarray) -> np.ndarray:
        """(T, n, 3): each triad's true input; the rows at rest are stacked once per dwell."""
        if self._stack_cache[0] is force:
            return self._stack_cache[1]
        true = np.stack([force if kind == SPECIFIC_FORCE else omega for kind in self._kinds])
        if len(force) == 1:
            self._stack_cache = force, true
        return true

    def _at_rest(self, attitude, angle: float) -> tuple[np.ndarray, np.ndarray]:
        """``true_inputs`` of a table at rest at ``angle``: one (1, 3) row each (a dwell asks
        the same many times over)."""
        key = (np.asarray(attitude, dtype=float).tobytes(), angle)
        if self._rest_cache[0] != key:
            c, s = np.array([math.cos(angle)]), np.array([math.sin(angle)])
            zero = np.zeros(1)
            self._rest_cache = key, self.true_inputs(attitude, np.array([angle]), zero, zero, c=c, s=s)
        return self._rest_cache[1]

    def true_inputs(self, attitude, angle, rate, alpha, c=None, s=None) -> tuple[np.ndarray, np.ndarray]:
        """Specific force (m/s²) and angular rate (rad/s) in body axes, (n, 3) each."""
        if c is None:
            c, s = np.cos(angle), np.sin(angle)
        # C_bn(t) = Rz(angle) · attitude; rows of its transpose give ENU -> body.
        lever_enu = attitude @ self.lever_arm
        # Acceleration of the sensor: d²/dt² [Rz(angle) · lever_enu] (the table axis is fixed).
        lx, ly = lever_enu[0], lever_enu[1]
        acc = np.empty((len(angle), 3))
        acc[:, 0] = -rate**2 * (c * lx - s * ly) + alpha * (-s * lx - c * ly)
        acc[:, 1] = -rate**2 * (s * lx + c * ly) + alpha * (c * lx - s * ly)
        acc[:, 2] = 0.0
        force_enu = acc + np.array([0.0, 0.0, self.gravity])
        omega_enu = np.empty_like(acc)
        omega_enu[:, 0] = 0.0
        omega_enu[:, 1] = self.earth_rate * np.cos(self.latitude_rad)
        omega_enu[:, 2] = self.earth_rate * np.sin(self.latitude_rad) + rate
        return _enu_to_body(force_enu, attitude, c, s), _enu_to_body(omega_enu, attitude, c, s)

    def _chunk(self, first: int, attitude, angle, rate, alpha) -> SampleChunk:
        return self._sample_chunk(first, *self.true_inputs(attitude, angle, rate, alpha))

    def _sample_chunk(self, first: int, force: np.ndarray, omega: np.ndarray, n: int | None = None) -> SampleChunk:
        """``n`` samples (default: as many as rows of force and omega; one row serves them all)."""
        t = (first + np.arange(len(force) if n is None else n)) / self.rate_hz
        temperature, warmed = self._thermal_terms(t)
        if self.noise_model == "innovations":
            # All triads at once: (T, n, 3) noise, each triad's true input, K and bias stacked.
            true = self._stacked(force, omega)
            raw = np.matmul(self._noise.draw(len(t)) + true, self._k_t)
            raw += self._bias
            for i, (offset, ratio) in warmed.items():
                raw[i] = (raw[i] - self._bias[i]) * ratio + self._bias[i] + offset
            for i, lsb in self._quantised:
                raw[i] = np.round(raw[i] / lsb) * lsb
            return SampleChunk(t=t, triads=dict(zip(self.triads, raw)), temperature=temperature)
        out = {}
        noise = {name: gen.draw(len(t)) for name, gen in self._noise.items()}
        for i, (name, truth) in enumerate(self.triads.items()):
            raw = noise[name]
            raw += force if truth.kind == SPECIFIC_FORCE else omega
            raw = raw @ truth.K.T
            if i in warmed:
                offset, ratio = warmed[i]
                raw = raw * ratio + offset
            raw += truth.bias
            if truth.lsb:
                raw = np.round(raw / truth.lsb) * truth.lsb
            out[name] = raw
        return SampleChunk(t=t, triads=out, temperature=temperature)

    def _thermal_terms(self, t: np.ndarray) -> tuple[np.ndarray | None, dict]:
        """The temperature at ``t`` and, per warmed triad's index, its (bias offset, K row ratio)."""
        if self.thermal is None:
            return None, {}
        temperature = self.thermal.profile.at(t)
        return temperature, {i: self.thermal.triads[name].offset_and_ratio(temperature)
                             for i, name in enumerate(self.triads) if name in self.thermal.triads}


def _enu_to_body(v_enu: np.ndarray, attitude: np.ndarray, c: np.ndarray, s: np.ndarray) -> np.ndarray:
    # v_body = attitudeᵀ · Rz(angle)ᵀ · v_enu, vectorised over samples.
    rotated = np.empty_like(v_enu)
    rotated[:, 0] = c * v_enu[:, 0] + s * v_enu[:, 1]
    rotated[:, 1] = -s * v_enu[:, 0] + c * v_enu[:, 1]
    rotated[:, 2] = v_enu[:, 2]
    return rotated @ attitude
