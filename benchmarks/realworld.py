"""Real-world Monte Carlo of `fieldcal calibrate` on simulated recordings (issue 11).

Each recording draws its own mix of what real MEMS units and loggers do (drivers.sim.realworld):
gyro g-sensitivity, bias random walk, warm-up, a temperature ramp acting on biases and scale
factors, a turn-on bias, a gyro range that fast turns clip, timestamp jitter and dropped samples,
a trembling hand on some poses, a long, short or missing initial rest, consumer or good noise,
raw counts or SI units; most are hand-held pose sequences, some Ferraris sessions (six faces and
three turntable turns), a few with too few poses for any method. Calibrated as a user would:
no noise model, no --rest, the place known.

Printed: the date, N and seed; the share calibrated among the recordings that hold the poses
their method needs (hand-held: at least 9 distinct, well-spread ups among the true poses;
Ferraris: all six faces and the three turns); per triad and protocol the RMS over recordings of
(solved − true) / σ for every parameter, and the share beyond 3σ; the refusals' reasons tallied.
Truth for a parameter that varies in time is the simulator's (see drivers/sim/realworld.py).

    python benchmarks/realworld.py [--runs N] [--seed S] [--verbose]
"""
from __future__ import annotations

import argparse
import datetime
import re
import time
from collections import Counter
from dataclasses import dataclass

import fieldcal  # noqa: F401  (first: its one-BLAS-thread default applies only before numpy loads)
import numpy as np

from drivers.sim.device import PAPER_NOISE
from drivers.sim.handheld import CONSUMER_NOISE, RealWorld, handheld_truth, simulate_handheld
from fieldcal.earth import Station
from fieldcal.model import params_from_k
from fieldcal.recording import Recording
from fieldcal.recording.calibrate import RecordingSettings, calibrate_recording
from fieldcal.recording.detect import DetectorSettings, check_spread, distinct_poses
from fieldcal.solvers import CalibrationError

FACES = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
_TERMS = ((0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1))


@dataclass(frozen=True)
class Scenario:
    kind: str  # "hand-held", "Ferraris" or "sparse" (too few poses)
    real_world: RealWorld
    kwargs: dict
    effects: tuple[str, ...]  # what is switched on, for the verbose listing


def draw_scenario(rng: np.random.Generator, only: tuple[str, ...] | None = None,
                  protocol: str | None = None) -> Scenario:
    """One recording's protocol and real-world mix, each effect on with probability ½ (``only``:
    the effects allowed, by any part of their field names; the others stay off; ``protocol``:
    every recording of this kind, e.g. "Ferraris", instead of the mix)."""
    on = lambda: rng.random() < 0.5  # noqa: E731
    fx = {}
    if on():
        fx["g_sensitivity_deg_s_per_g"] = rng.uniform(0.02, 0.15)
    if on():
        fx["warm_up_deg_s"], fx["warm_up_tau_s"] = rng.uniform(0.02, 0.1), rng.uniform(30.0, 120.0)
    if on():
        fx["temperature_ramp_k"] = rng.uniform(1.0, 5.0)
        fx["bias_tempco_deg_s_per_k"] = rng.uniform(0.002, 0.01)
        fx["acc_bias_tempco_mg_per_k"] = rng.uniform(0.02, 0.2)
        fx["scale_tempco_ppm_per_k"] = rng.uniform(20.0, 150.0)
    if on():
        fx["bias_random_walk_deg_s_per_sqrt_s"] = rng.uniform(2e-4, 1e-3)
    if on():
        fx["turn_on_bias_deg_s"], fx["turn_on_bias_mg"] = 0.5, 20.0
    if on():
        fx["gyro_range_deg_s"] = float(rng.choice([125.0, 250.0]))
    if on():
        fx["jitter_s"], fx["drop_fraction"] = rng.uniform(1e-4, 2e-3), rng.uniform(0.0, 0.01)
    if on():
        fx["pose_tremor_deg_s"], fx["pose_tremor_share"] = rng.uniform(0.05, 0.3), rng.uniform(0.2, 0.5)
    rest = rng.choice(["long", "short", "none"], p=[0.3, 0.4, 0.3])
    if rest == "none":
        fx["late_start"] = True
    if only is not None:  # the draws above are made all the same: a seed's recordings keep their poses
        fx = {k: v for k, v in fx.items() if any(o in k for o in only)}
        rest = "none" if fx.get("late_start") else rest if rest != "none" else "short"
    off = dict(g_sensitivity_deg_s_per_g=0.0, warm_up_deg_s=0.0, temperature_ramp_k=0.0,
               bias_tempco_deg_s_per_k=0.0, jitter_s=0.0, drop_fraction=0.0)
    rw = RealWorld(**{**off, **fx})
    noise = PAPER_NOISE if rng.random() < 0.5 else CONSUMER_NOISE
    raw_counts = bool(rng.random() < 0.5)
    kwargs = dict(truth=handheld_truth(raw_counts, noise), raw_counts=raw_counts,
                  initial_rest_s=30.0 if rest == "long" else float(rng.uniform(2.0, 8.0)),
                  latitude_deg=float(rng.uniform(-60, 60)), gravity=float(rng.uniform(9.78, 9.83)))
    kind = str(rng.choice(["hand-held", "Ferraris", "sparse"], p=[0.75, 0.2, 0.05]))
    kind = protocol or kind  # drawn all the same: the draws after it stay as they were
    if kind == "Ferraris":
        sign = rng.choice([-1.0, 1.0], 3)
        kwargs.update(n_poses=6, directions=FACES, initial_rest_s=max(kwargs["initial_rest_s"], 4.0),
                      # A full turn (2 s ramps, the rest held), stopped by hand within ~0.5° of 360°.
                      table_turns=tuple((p, s * rate, (360.0 + rng.normal(0.0, 0.5)) / rate - 2.0)
                                        for p, s, rate in zip((0, 2, 4), sign, rng.uniform(20.0, 60.0, 3))))
    elif kind == "sparse":
        kwargs["n_poses"] = int(rng.integers(5, 9))
    else:
        kwargs["n_poses"] = int(rng.integers(12, 30))
    effects = tuple(sorted(k for k in fx if not k.endswith(("tau_s", "share", "drop_fraction"))))
    effects += (f"rest {rest}", "consumer noise" if noise is CONSUMER_NOISE else "paper noise",
                "counts" if raw_counts else "SI")
    return Scenario(kind, rw, kwargs, effects)


def has_needed_poses(kind: str, sim) -> bool:
    """The true poses are enough for the method: six faces and three turns (Ferraris), else at
    least 9 distinct well-spread ups (the norm method)."""
    if kind == "Ferraris":
        return len(sim.static) >= 9 and len(sim.turns) == 3
    return check_spread(sim.up[distinct_poses(sim.up, DetectorSettings().min_separation_deg)], 9).ok


def z_scores(cal, sim) -> dict[str, tuple[tuple[str, ...], np.ndarray]]:
    """Per "triad (protocol)": parameter names and (solved − true) / σ."""
    out = {}
    protocol = "aligned" if cal.protocol.startswith("Ferraris") else "norm"
    for name, c in cal.specific_force.items():
        truth = sim.truth[name]
        z = (c.file_theta - params_from_k(truth.K, truth.bias)) / c.file_sigma
        out[f"{name} ({protocol})"] = (("bias x", "bias y", "bias z", "scale x", "scale y", "scale z",
                                         "Δyz", "Δzy", "Δzx"), z)
    for name, c in cal.angular_rate.items():
        truth = sim.truth[name]
        if protocol == "aligned":
            z = (c.file_theta - params_from_k(truth.K, truth.bias, full=True)) / c.file_sigma
            out[f"{name} (turns)"] = (("bias x", "bias y", "bias z", "scale x", "scale y", "scale z",
                                       "Δyz", "Δzy", "Δzx"), z)
        else:
            k = np.diag(truth.K)
            M = truth.K / k[:, None] - np.eye(3)
            true = np.r_[truth.bias, k, [M[i, j] for i, j in _TERMS]]
            out[f"{name} (rotations)"] = (tuple(c.parameter_names), (c.theta - true) / c.sigma)
    return out


def reason_key(message: str) -> str:
    """A refusal's reason with its numbers taken out, so that alike ones tally together."""
    return re.sub(r"-?\d+(\.\d+)?(e-?\d+)?", "#", message)[:160]


def run(runs: int, seed: int, verbose: bool, only: tuple[str, ...] | None = None, config: bool = False,
        protocol: str | None = None, temperature: bool = False) -> None:
    master = np.random.default_rng(seed)
    z: dict[str, list[np.ndarray]] = {}
    names: dict[str, tuple[str, ...]] = {}
    eligible = calibrated = 0
    reasons: Counter = Counter()
    wrongly: list[str] = []
    started = time.perf_counter()
    for i in range(runs):
        scenario = draw_scenario(master, only, protocol)
        sim_seed = int(master.integers(1 << 31))
        sim = simulate_handheld(sim_seed, real_world=scenario.real_world, **scenario.kwargs)
        needed = has_needed_poses(scenario.kind, sim)
        eligible += needed
        # With --temperature the logger writes the unit's temperature: the simulator's ramp, on
        # the clock of the whole simulated session (its t starts at 0).
        recorded = (scenario.real_world.temperature_ramp_k * (sim.t / sim.t[-1] - 0.5)) if temperature else None
        recording = Recording(sim.t, sim.triads, sim.kinds, sim.units, temperature=recorded)
        station = Station(sim.latitude_deg, 0.0, sim.gravity)
        label = f"#{i} seed {sim_seed} {scenario.kind}: {', '.join(scenario.effects)}"
        try:
            # With --config the user's device config gives the triads' noise (the datasheet's) and
            # scale temperature coefficient.
            noise = {name: truth.noise for name, truth in sim.truth.items()} if config else {}
            tempco = {name: scenario.real_world.scale_tempco_ppm_per_k for name in sim.truth} if config else {}
            cal = calibrate_recording(recording, station, RecordingSettings(noise=noise, scale_tempco_ppm_per_k=tempco))
        except (ValueError, CalibrationError) as exc:  # DetectionError is a ValueError
            reasons[reason_key(str(exc))] += 1
            if needed:
                wrongly.append(f"{label}\n    refused: {exc}")
            continue
        if cal.failures:
            for triad, message in cal.failures.items():
                reasons[f"{triad}: {reason_key(message)}"] += 1
            if needed:
                wrongly.append(f"{label}\n    failed: {cal.failures}")
            continue
        calibrated += needed
        for key, (labels, values) in z_scores(cal, sim).items():
            names[key] = labels
            z.setdefault(key, []).append(values)
            if verbose and np.any(np.abs(values) > 3):
                worst = int(np.argmax(np.abs(values)))
                print(f"  {label}\n    {key}: {labels[worst]} z {values[worst]:+.1f}")
        if not needed:
            wrongly.append(f"{label}\n    calibrated although the poses are not enough")
    elapsed = time.perf_counter() - started
    print(f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC: {runs} recordings, "
          f"seed {seed}, {elapsed:.0f} s")
    share = 100.0 * calibrated / max(eligible, 1)
    print(f"calibrated {calibrated} of the {eligible} that hold the poses their method needs "
          f"({share:.1f} %); {runs - eligible} without them")
    print("RMS of (solved − true)/σ per parameter, share beyond 3σ:")
    for key in sorted(z):
        values = np.array(z[key])
        rms = np.sqrt(np.nanmean(values**2, axis=0))
        print(f"  {key}, {len(values)} recordings: " + ", ".join(f"{n} {r:.2f}" for n, r in zip(names[key], rms))
              + f"; beyond 3σ {100 * np.mean(np.abs(values) > 3):.1f} %")
    print("refusals and failures by reason:")
    for reason, count in reasons.most_common():
        print(f"  {count:4d}  {reason}")
    if wrongly:
        print("wrongly refused or calibrated:")
        for line in wrongly:
            print(f"  {line}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20, help="simulated recordings (the issue asks ≥ 200)")
    parser.add_argument("--seed", type=int, default=11, help="the Monte Carlo's seed")
    parser.add_argument("--verbose", action="store_true", help="list every parameter beyond 3σ")
    parser.add_argument("--only", help="comma-separated effects allowed (parts of RealWorld's field names, "
                        "e.g. tremor,late_start); the others stay off: to see what one of them does")
    parser.add_argument("--config", action="store_true",
                        help="calibrate as with a device config that gives the noise model and the scale "
                        "temperature coefficient (else none)")
    parser.add_argument("--temperature", action="store_true",
                        help="the logger writes the unit's temperature (else the recordings have none)")
    parser.add_argument("--protocol", choices=("hand-held", "Ferraris", "sparse"),
                        help="every recording of this protocol (else the mix: 75 %% hand-held, 20 %% Ferraris, "
                        "5 %% sparse)")
    args = parser.parse_args()
    run(args.runs, args.seed, args.verbose, None if args.only is None else tuple(args.only.split(",")),
        args.config, args.protocol, args.temperature)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
