"""Headless runs: the procedure engine, an automatic operator and the simulated device.

The operator moves the virtual fixture to each position (a few degrees off, at a random heading,
with hand motion on the way), says ready, and, when the script asks, bumps the unit mid-dwell,
places it wrongly first, or skips a position. Everything is captured in the session as it
happens; at every completed step a checkpoint of the simulator and operator lets ``resume``
continue exactly as an uninterrupted run would have.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from drivers.sim import MimuSimulator
from drivers.sim.device import paper_mimu
from fieldcal import __version__
from fieldcal.procedure import events as ev
from fieldcal.earth import Station
from fieldcal.procedure.engine import Engine, EngineSettings
from fieldcal.run.livedevice import ANGULAR_RATE_TRIAD, SPECIFIC_FORCE_TRIAD, LiveDevice
from fieldcal.model import params_from_k
from fieldcal.paramfile import ParameterFile, hash_inputs
from fieldcal.procedure.positions import Procedure, parse_procedure
from fieldcal.session.capture import SessionReader, SessionWriter
from fieldcal.run.simrun import placed_attitude
from fieldcal.solvers.solve import TriadModel, UnitSolution, models_from_truth, resolve_method, solve_unit
from fieldcal.procedure.stillness import StillnessSettings

TABLE_ACCEL_DEG_S2 = 20.0
SIM_DEVICE_NAME = "simulated MIMU (paper Tables 3-4)"


@dataclass(frozen=True)
class OperatorScript:
    placement_sigma_deg: float = 3.0
    handling_s: float = 4.0
    bump_step: int | None = None  # bump the unit halfway through this step's dwell (0-based)
    wrong_step: int | None = None  # first put the unit in a wrong position at this step
    skip_steps: tuple[int, ...] = ()
    # Bump after the first chunk that ends at or after each of these sample times (s): how a
    # headless run repeats the bumps an operator gave in the terminal UI.
    bump_at_s: tuple[float, ...] = ()


@dataclass(frozen=True)
class RunSpec:
    """All a headless run needs; stored in the session so resume and replay rebuild it."""

    procedure: Procedure
    station: Station
    seed: int = 1
    rate_hz: float = 250.0
    raw_counts: bool = False
    method: str = "auto"
    on_motion: str = "restart"
    script: OperatorScript = field(default_factory=OperatorScript)
    live: LiveDevice | None = None  # a real device on a port; None: the simulated MIMU

    def to_metadata(self) -> dict:
        if self.live is not None:
            return {"software": f"fieldcal {__version__}",
                    "procedure": {"name": self.procedure.name, "yaml": self.procedure.text},
                    "station": {"latitude_deg": self.station.latitude_deg, "height_m": self.station.height_m,
                                "gravity_m_s2": self.station.gravity_m_s2},
                    "device": {**self.live.to_metadata(), "rate_hz": self.rate_hz, "raw_counts": False},
                    "method": self.method, "on_motion": self.on_motion}
        device = paper_mimu(self.raw_counts)
        return {
            "software": f"fieldcal {__version__}",
            "procedure": {"name": self.procedure.name, "yaml": self.procedure.text},
            "station": {"latitude_deg": self.station.latitude_deg, "height_m": self.station.height_m,
                        "gravity_m_s2": self.station.gravity_m_s2},
            "device": {"name": SIM_DEVICE_NAME, "raw_counts": self.raw_counts,
                       "rate_hz": self.rate_hz},
            "seed": self.seed, "method": self.method, "on_motion": self.on_motion,
            "script": asdict(self.script),
            "simulation_truth": {name: {"kind": t.kind, "K": t.K.tolist(), "bias": t.bias.tolist(),
                                        "output_unit": t.output_unit} for name, t in device.items()},
        }

    @classmethod
    def from_metadata(cls, meta: dict) -> RunSpec:
        if meta.get("kind") == "recording":
            raise ValueError("this session is an imported recording, not a procedure run: "
                             "calibrate it with `fieldcal calibrate SESSION`")
        common = {"procedure": parse_procedure(meta["procedure"]["yaml"], meta["procedure"]["name"]),
                  "station": Station(**meta["station"]), "rate_hz": meta["device"]["rate_hz"],
                  "method": meta["method"], "on_motion": meta["on_motion"]}
        if "triads" in meta["device"]:
            return cls(**common, live=LiveDevice.from_metadata(meta["device"]))
        script = dict(meta["script"])
        script["skip_steps"] = tuple(script["skip_steps"])
        script["bump_at_s"] = tuple(script.get("bump_at_s", ()))  # absent before bump_at_s existed
        return cls(**common, seed=meta["seed"], raw_counts=meta["device"]["raw_counts"],
                   script=OperatorScript(**script))

    def device(self):
        """The simulated device's truth."""
        if self.live is not None:
            raise ValueError(f"{self.live.name} is a real device: it has no simulation truth")
        return paper_mimu(self.raw_counts)

    @property
    def device_name(self) -> str:
        return SIM_DEVICE_NAME if self.live is None else self.live.name

    @property
    def device_serial(self) -> str | None:
        return None if self.live is None else self.live.serial

    def models(self) -> dict[str, TriadModel]:
        """What the station knows of each triad before calibrating it."""
        return models_from_truth(self.device()) if self.live is None else dict(self.live.models)

    def truth(self) -> dict[str, np.ndarray]:
        """The true parameters per triad (simulation), or nothing (a real device)."""
        if self.live is not None:
            return {}
        return {n: params_from_k(t.K, t.bias) for n, t in self.device().items()}

    def engine_settings(self) -> EngineSettings:
        if self.live is not None:
            return self._live_engine_settings()
        device = self.device()
        acc, gyro = device["accelerometer"], device["gyroscope"]
        sens_sf, sens_rate = np.diag(acc.K), np.diag(gyro.K)
        return EngineSettings(
            rate_hz=self.rate_hz, on_motion=self.on_motion,
            stillness=StillnessSettings.from_noise(acc.noise.white, gyro.noise.white, self.rate_hz,
                                                   acc.K, gyro.K, acc.lsb, gyro.lsb),
            # Nominal zero and sensitivity: what a datasheet gives for a device reporting counts.
            sf_zero=tuple(np.round(acc.bias, -2) if self.raw_counts else (0.0,) * 3),
            sf_sensitivity=tuple(np.round(sens_sf, 0) if self.raw_counts else (1.0,) * 3),
            rate_zero=tuple(np.round(gyro.bias, -2) if self.raw_counts else (0.0,) * 3),
            rate_sensitivity=tuple(np.round(sens_rate, 0) if self.raw_counts else (1.0,) * 3))

    def _live_engine_settings(self) -> EngineSettings:
        live = self.live
        acc, gyro = live.models[SPECIFIC_FORCE_TRIAD], live.models[ANGULAR_RATE_TRIAD]
        return EngineSettings(
            rate_hz=self.rate_hz, on_motion=self.on_motion,
            stillness=StillnessSettings.from_noise(acc.noise.white, gyro.noise.white, self.rate_hz,
                                                   acc.sensitivity, gyro.sensitivity, acc.lsb, gyro.lsb),
            sf_zero=live.zeros[SPECIFIC_FORCE_TRIAD], sf_sensitivity=tuple(np.diag(acc.sensitivity)),
            rate_zero=live.zeros[ANGULAR_RATE_TRIAD], rate_sensitivity=tuple(np.diag(gyro.sensitivity)))


class SimulatedBench:
    """The in-process simulator on its table, and the automatic operator's hands."""

    def __init__(self, spec: RunSpec):
        self.spec = spec
        noise_seed, operator_seed = np.random.SeedSequence(spec.seed).spawn(2)
        self.sim = MimuSimulator(spec.device(), gravity=spec.station.gravity,
                                 latitude_rad=spec.station.latitude_rad, rate_hz=spec.rate_hz,
                                 seed=noise_seed)
        self.rng = np.random.default_rng(operator_seed)
        self.attitude = np.eye(3)
        self.target_deg_s = 0.0
        self.chunk_n = int(round(spec.rate_hz))  # one-second chunks

    def next_chunk(self):
        return self.sim.advance(self.chunk_n, self.attitude, math.radians(self.target_deg_s),
                                math.radians(TABLE_ACCEL_DEG_S2))

    def command_table(self, rate_deg_s: float) -> None:
        self.target_deg_s = rate_deg_s

    def close(self) -> None:
        pass

    def move_to(self, nominal: np.ndarray) -> list:
        """Stop-and-carry: wait for the table to stop, then carry the unit to its new place."""
        chunks = []
        while self.sim.table_rate != 0.0:
            chunks.append(self.next_chunk())
        target = nominal if self.spec.procedure.aligned else \
            placed_attitude(nominal, self.rng, self.spec.script.placement_sigma_deg)
        n = int(round(self.spec.script.handling_s * self.spec.rate_hz))
        chunks.append(self.sim.handle(n, self.attitude, target))
        self.attitude = target
        return chunks

    def bump(self) -> list:
        """A knock on the fixture: a 0.3 s jolt that leaves it within a fraction of a degree."""
        nudged = self.attitude @ Rotation.from_rotvec(self.rng.normal(0, math.radians(0.3), 3)).as_matrix()
        chunk = self.sim.handle(int(round(0.3 * self.spec.rate_hz)), self.attitude, nudged, shake=3.0)
        self.attitude = nudged
        return [chunk]

    def get_state(self) -> dict:
        return {"sim": self.sim.get_state(), "rng": self.rng.bit_generator.state,
                "attitude": self.attitude.tolist(), "target_deg_s": self.target_deg_s}

    def set_state(self, state: dict) -> None:
        self.sim.set_state(state["sim"])
        self.rng.bit_generator.state = state["rng"]
        self.attitude = np.array(state["attitude"])
        self.target_deg_s = float(state["target_deg_s"])


def _wrong_position(procedure: Procedure, step: int):
    """A position whose gravity direction is far from the expected one (a plausible mix-up)."""
    expected = procedure.positions[step].up_body
    return max(procedure.positions, key=lambda p: -abs(float(p.up_body @ expected)) - 0.01 * p.id)


@dataclass
class RunResult:
    session: Path
    unit: UnitSolution | None
    parameters: Path | None
    truth: dict
    aborted: bool = False


def _solve(spec: RunSpec, engine: Engine) -> tuple[UnitSolution, ParameterFile | None]:
    windows, averages = engine.windows_and_averages()
    models = {n: m for n, m in spec.models().items() if n in averages}
    unit = solve_unit(spec.procedure, windows, averages, models, spec.station, spec.rate_hz, spec.method)
    if not unit.solutions:
        return unit, None
    pf = ParameterFile.build(
        triads=tuple(unit.solutions.values()),
        procedure=spec.procedure.name, method=resolve_method(spec.procedure, spec.method),
        station=spec.station,
        input_sha256=hash_inputs(*unit.inputs.values()), device_name=spec.device_name,
        device_serial=spec.device_serial, simulation=spec.live is None)
    return unit, pf


def _drive(spec: RunSpec, engine: Engine, bench: SimulatedBench, session: SessionWriter,
           events: list, report) -> bool:
    """Run until the procedure completes or is aborted; False if aborted."""
    script = spec.script
    bumped = wrong_done = False
    bumps_due = sorted(t for t in script.bump_at_s if t > engine.t)
    bump_now = False
    # A step normally takes its dwell, its rate steps and the handling; ten times that with no
    # step completed means the run cannot make progress (say the unit never settles).
    step = spec.procedure.rate_step
    per_step = spec.procedure.dwell_s + script.handling_s + (
        2 * (step.turns * 360.0 / step.rate_deg_s + step.ramp_s + step.settle_s) if step else 0.0)
    deadline = engine.t + 10 * per_step
    while True:
        moves = []
        for e in events:
            session.event(e.to_dict())
            report(e)
            if isinstance(e, (ev.StepComplete, ev.StepSkipped)):
                deadline = e.t + 10 * per_step
            if isinstance(e, ev.CommandTable):
                bench.command_table(e.rate_deg_s)
            elif isinstance(e, ev.StepComplete):
                # One document, so a crash cannot separate a step's averages from the state
                # that resuming after it needs.
                session.step({**engine.records[e.step], "skipped": sorted(engine.skipped),
                              "bench": bench.get_state()})
            elif isinstance(e, ev.PlaceUnit):
                step = engine.step
                if step in script.skip_steps:
                    moves.append(("act", ev.Action(ev.SKIP)))
                    continue
                if step == script.wrong_step and not wrong_done:
                    wrong_done = True
                    moves.append(("move", _wrong_position(spec.procedure, step).attitude))
                else:
                    moves.append(("move", engine.position.attitude))
                moves.append(("act", ev.Action(ev.READY)))
            elif isinstance(e, ev.WrongOrientation):
                moves.append(("move", engine.position.attitude))
            elif isinstance(e, ev.DwellProgress):
                if engine.step == script.bump_step and not bumped and e.done_s >= e.total_s / 2:
                    bumped = True
                    moves.append(("bump", None))
            elif isinstance(e, (ev.ProcedureComplete, ev.Aborted)):
                return isinstance(e, ev.ProcedureComplete)
        if bump_now:
            moves.append(("bump", None))
            bump_now = False
        events = []
        for what, arg in moves:
            if what == "act":
                session.action(arg.to_dict())
                events += engine.act(arg)
                continue
            for chunk in bench.move_to(arg) if what == "move" else bench.bump():
                session.chunk(chunk)
                events += engine.feed(chunk)
        if not moves:
            chunk = bench.next_chunk()
            session.chunk(chunk)
            events = engine.feed(chunk)
            if bumps_due and engine.t >= bumps_due[0]:
                bumps_due.pop(0)
                bump_now = True  # after this chunk's events, as the terminal UI does a key
            if chunk.t[-1] > deadline:
                events += engine.act(ev.Action(ev.ABORT))
                report(ev.Aborted(float(chunk.t[-1]), f"no step completed in {10 * per_step:.0f} s of "
                                  f"samples (phase {engine.phase}): the run cannot make progress"))


def run_headless(spec: RunSpec, out: Path, report=lambda e: None, serial: bool = False) -> RunResult:
    """``serial``: reach the simulated device only through bytes on a pty, as hardware would be."""
    engine = Engine(spec.procedure, spec.engine_settings())  # bad settings fail before any file
    metadata = spec.to_metadata()
    metadata["device"]["link"] = "pty" if serial else "in-process"
    session = SessionWriter.create(out, metadata)
    if serial:
        from fieldcal.run.serialbench import SerialBench
        bench = SerialBench(spec, tap=lambda t, data: session.write_raw("imu", t, data))
    else:
        bench = SimulatedBench(spec)
    try:
        completed = _drive(spec, engine, bench, session, engine.start(), report)
    finally:
        bench.close()
    return _finish(spec, engine, session, completed, out)


def resume_headless(directory: Path, report=lambda e: None) -> RunResult:
    """Continue a killed headless run after its last completed step."""
    reader = SessionReader(directory)
    spec = RunSpec.from_metadata(reader.start)
    engine = Engine(spec.procedure, spec.engine_settings())
    bench = SimulatedBench(spec)
    steps = reader.steps()
    # Everything up to the last completed step; what came after it (a partial step, a skip) is
    # done again, exactly as the uninterrupted run did it.
    skipped = steps[-1]["skipped"] if steps else []
    engine.restore(steps, skipped)
    if steps:
        bench.set_state(steps[-1]["bench"])
    session = SessionWriter.append_to(directory)
    session.resume({"completed_steps": sorted(engine.records), "skipped": list(skipped)})
    return _finish(spec, engine, session, _drive(spec, engine, bench, session, engine.start(), report),
                   Path(directory))


def _finish(spec: RunSpec, engine: Engine, session: SessionWriter, completed: bool, out: Path) -> RunResult:
    truth = spec.truth()
    if engine.records:
        truth = {n: v for n, v in truth.items() if n in engine.windows_and_averages()[1]}
    if not completed:
        session.stop("aborted")
        session.close()
        return RunResult(Path(out), None, None, truth, aborted=True)
    unit, pf = _solve(spec, engine)
    solved = ev.Solved(engine.t, tuple(unit.solutions), dict(unit.failures))
    session.event(solved.to_dict())
    path = None
    if pf is not None:
        session.write_parameters(pf)
        path = Path(out) / "parameters.yaml"
    session.stop("completed")
    session.close()
    return RunResult(Path(out), unit, path, truth)
