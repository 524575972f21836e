"""Headless runs: the run spec, the simulated bench, and a conductor with the automatic operator.

The operator (``fieldcal.run.operators.ScriptedOperator``) moves the virtual fixture to each
position (a few degrees off, at a random heading, with hand motion on the way), says ready, and,
when the script asks, bumps the unit mid-dwell, places it wrongly first, or skips a position.
The conductor runs the loop; the session recorder captures everything as it happens, and at
every completed step the simulator's state lets ``resume`` continue exactly as an uninterrupted
run would have.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from drivers.noise import DEFAULT_FLICKER_TAU_MAX_S
from drivers.sim import MimuSimulator
from drivers.sim.device import paper_mimu
from drivers.sim.rotations import rotvec_matrix
from drivers.sim.thermal import SimThermal
from fieldcal import __version__
from fieldcal.earth import Station
from fieldcal.procedure.engine import EngineSettings
from fieldcal.model import params_from_k
from fieldcal.procedure.positions import Procedure, parse_procedure
from fieldcal.procedure.stillness import StillnessSettings
from fieldcal.run.conductor import Bench, Conductor, Reporter
from fieldcal.run.operators import OperatorScript, ScriptedOperator
from fieldcal.run.outcome import Outcome
from fieldcal.run.recorder import SessionRecorder
from fieldcal.run.simrun import placed_attitude
from fieldcal.session.record import RunRecord

if TYPE_CHECKING:  # at run time they load scipy.optimize: imported where used, not at start-up
    from fieldcal.run.livedevice import LiveDevice
    from fieldcal.solvers.solve import TriadModel

TABLE_ACCEL_DEG_S2 = 20.0
SIM_DEVICE_NAME = "simulated MIMU (paper Tables 3-4)"


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
    # How the simulator draws its noise (drivers.sim.physics.NOISE_MODELS): sessions recorded
    # before the model was named used "bank", and resume with it.
    sim_noise: str = "innovations"
    operator: str | None = None  # who runs it (--operator), into the parameter file and registry
    # The simulated unit's serial (--unit-serial, a sim config's device.serial); None: recorded
    # without one. A live device's is its LiveDevice's.
    unit_serial: str | None = None
    # The simulated unit's longest flicker correlation time (config device.sim.flicker_tau_max_s);
    # stored in the session only when not the default, which is what sessions before it used.
    flicker_tau_max_s: float = DEFAULT_FLICKER_TAU_MAX_S
    # The simulated unit's temperature profile and thermal truth (the config's device.sim); None:
    # it holds its calibration temperature, as every session before issue 28 did.
    sim_thermal: SimThermal | None = None
    # Whether the solve fits a thermal model (fieldcal.solvers.solve.THERMAL_MODES): stored only
    # when not auto, which is what every session before the setting did.
    thermal: str = "auto"

    def to_metadata(self) -> dict:
        said = {"operator": self.operator} if self.operator is not None else {}  # older sessions: none
        thermal = {"thermal": self.thermal} if self.thermal != "auto" else {}
        return {**self._metadata(), **said, **thermal}

    def _metadata(self) -> dict:
        if self.live is not None:
            return {"software": f"fieldcal {__version__}",
                    "procedure": {"name": self.procedure.name, "yaml": self.procedure.text},
                    "station": {"latitude_deg": self.station.latitude_deg, "height_m": self.station.height_m,
                                "gravity_m_s2": self.station.gravity_m_s2},
                    "device": {**self.live.to_metadata(), "rate_hz": self.rate_hz, "raw_counts": False},
                    "method": self.method, "on_motion": self.on_motion}
        device = self.device()
        flicker = ({"flicker_tau_max_s": self.flicker_tau_max_s}
                   if self.flicker_tau_max_s != DEFAULT_FLICKER_TAU_MAX_S else {})
        return {
            "software": f"fieldcal {__version__}",
            "procedure": {"name": self.procedure.name, "yaml": self.procedure.text},
            "station": {"latitude_deg": self.station.latitude_deg, "height_m": self.station.height_m,
                        "gravity_m_s2": self.station.gravity_m_s2},
            "device": {"name": SIM_DEVICE_NAME, "raw_counts": self.raw_counts,
                       "rate_hz": self.rate_hz, **({"serial": self.unit_serial} if self.unit_serial else {}),
                       **flicker},
            "seed": self.seed, "sim_noise": self.sim_noise, "method": self.method, "on_motion": self.on_motion,
            "script": asdict(self.script),
            "simulation_truth": {name: {"kind": t.kind, "K": t.K.tolist(), "bias": t.bias.tolist(),
                                        "output_unit": t.output_unit} for name, t in device.items()},
            **({"sim_thermal": self.sim_thermal.to_dict()} if self.sim_thermal is not None else {}),
        }

    def session_metadata(self, link: str | None, front_end: str | None = None) -> dict:
        """The start metadata of a session: the spec, how the device was reached, which front
        end ran it, and the numeric environment (a replay elsewhere compares within tolerance)."""
        from fieldcal.run.environment import numeric_environment

        metadata = self.to_metadata()
        if link is not None:
            metadata["device"]["link"] = link
        if front_end is not None:
            metadata["front_end"] = front_end
        metadata["numeric_environment"] = numeric_environment()
        return metadata

    @classmethod
    def from_metadata(cls, meta: dict) -> RunSpec:
        if meta.get("kind") == "recording":
            raise ValueError("this session is an imported recording, not a procedure run: "
                             "calibrate it with `fieldcal calibrate SESSION`")
        common = {"procedure": parse_procedure(meta["procedure"]["yaml"], meta["procedure"]["name"]),
                  "station": Station(**meta["station"]), "rate_hz": meta["device"]["rate_hz"],
                  "method": meta["method"], "on_motion": meta["on_motion"], "operator": meta.get("operator"),
                  "thermal": meta.get("thermal", "auto")}
        if "triads" in meta["device"]:
            from fieldcal.run.livedevice import LiveDevice
            return cls(**common, live=LiveDevice.from_metadata(meta["device"]))
        script = dict(meta["script"])
        script["skip_steps"] = tuple(script["skip_steps"])
        script["bump_at_s"] = tuple(script.get("bump_at_s", ()))  # absent before bump_at_s existed
        return cls(**common, seed=meta["seed"], sim_noise=meta.get("sim_noise", "bank"),
                   raw_counts=meta["device"]["raw_counts"], unit_serial=meta["device"].get("serial"),
                   flicker_tau_max_s=meta["device"].get("flicker_tau_max_s", DEFAULT_FLICKER_TAU_MAX_S),
                   script=OperatorScript(**script),
                   sim_thermal=SimThermal.from_dict(meta["sim_thermal"]) if "sim_thermal" in meta else None)

    def device(self):
        """The simulated device's truth."""
        if self.live is not None:
            raise ValueError(f"{self.live.name} is a real device: it has no simulation truth")
        return paper_mimu(self.raw_counts, self.flicker_tau_max_s)

    @property
    def device_name(self) -> str:
        return SIM_DEVICE_NAME if self.live is None else self.live.name

    @property
    def device_serial(self) -> str | None:
        return self.unit_serial if self.live is None else self.live.serial

    def models(self) -> dict[str, TriadModel]:
        """What the station knows of each triad before calibrating it."""
        from fieldcal.solvers.solve import models_from_truth

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
        from fieldcal.run.livedevice import ANGULAR_RATE_TRIAD, SPECIFIC_FORCE_TRIAD

        live = self.live
        assert live is not None  # (called for a live device's run)
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
                                 seed=noise_seed, noise_model=spec.sim_noise, thermal=spec.sim_thermal)
        self.rng = np.random.default_rng(operator_seed)
        self.attitude = np.eye(3)
        self.target_deg_s = 0.0
        self.chunk_n = int(round(spec.rate_hz))  # one-second chunks

    def next_chunks(self) -> list:
        return [self.next_chunk()]

    def next_chunk(self):
        return self.sim.advance(self.chunk_n, self.attitude, math.radians(self.target_deg_s),
                                math.radians(TABLE_ACCEL_DEG_S2))

    def command_table(self, rate_deg_s: float) -> None:
        self.target_deg_s = rate_deg_s

    def bias_at_end(self) -> dict[str, np.ndarray]:
        """Each triad's true bias at the last sample sent (drivers.sim MimuSimulator.bias_now)."""
        return self.sim.bias_now()

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
        nudged = self.attitude @ rotvec_matrix(self.rng.normal(0, math.radians(0.3), 3))
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


def headless_time_to_go(spec: RunSpec):
    """The time to go of a run by the scripted operator: its placements reckoned, until timed, as
    its hands' time, the stillness detector's window and the orientation check."""
    from fieldcal.run.timetogo import TimeToGo

    settings = spec.engine_settings()
    return TimeToGo(spec.procedure, spec.script.handling_s + settings.stillness.window_s + settings.check_s)


def run_headless(spec: RunSpec, out: Path, report=lambda e: None, serial: bool = False) -> Outcome:
    """``serial``: reach the simulated device only through bytes on a pty, as hardware would be."""
    settings = spec.engine_settings()  # bad settings fail before any file
    recorder = SessionRecorder.create(out, spec.session_metadata("pty" if serial else "in-process"))
    bench: Bench
    if serial:
        from fieldcal.run.serialbench import SerialBench
        bench = SerialBench(spec, tap=recorder.raw)
    else:
        bench = SimulatedBench(spec)
    conductor = Conductor(spec, bench, ScriptedOperator(spec.script, spec.procedure),
                          [recorder, Reporter(report)], session=out, settings=settings)
    return conductor.run()


def open_run(directory: str | Path, *, log_only: bool = False, recordings: bool = False) -> RunRecord:
    """A procedure run's session, read once, with its spec rebuilt (``RunRecord.open``).
    ``recordings``: an imported recording is opened too (its record has no spec), not refused."""
    def spec_from(metadata: dict) -> RunSpec | None:
        if recordings and metadata.get("kind") == "recording":
            return None
        return RunSpec.from_metadata(metadata)

    return RunRecord.open(directory, log_only=log_only, spec_from=spec_from)


def resume_headless(record: RunRecord, report=lambda e: None) -> Outcome:
    """Continue a run (headless, or the terminal UI's simulator) after its last completed step.

    Everything up to the last completed step is kept; what came after it (a partial step, a
    skip) is done again, exactly as the uninterrupted run did it.
    """
    from fieldcal.run.resume import resume_conductor

    spec = record.spec
    return resume_conductor(record, SimulatedBench(spec), ScriptedOperator(spec.script, spec.procedure),
                            [Reporter(report)]).run()
