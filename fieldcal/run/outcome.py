"""How a run ended and what it produced: the one result every front end reads."""
from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING

from fieldcal.procedure.positions import Procedure

if TYPE_CHECKING:  # the solvers load scipy: typed here, imported where a run concludes
    from fieldcal.paramfile import ParameterFile
    from fieldcal.session.history import PreviousCalibration
    from fieldcal.solvers.solve import UnitSolution


class Status(StrEnum):
    COMPLETED = "completed"
    ABORTED = "aborted"
    STOPPED = "stopped"  # quit before the end: the session can be resumed
    INCOMPLETE = "incomplete"  # a replayed capture ends before the procedure does
    ERROR = "error"


@dataclass
class Outcome:
    status: Status
    procedure: Procedure
    unit: UnitSolution | None = None
    truth: dict = field(default_factory=dict)  # triad -> true parameters (simulation)
    # triad -> the simulated unit's bias at the last sample of the run, output units: the value
    # the unit is used with, against which a benchmark judges the solved bias (DESIGN 12)
    bias_at_end: dict = field(default_factory=dict)
    thermal_truth: dict = field(default_factory=dict)  # triad -> its ThermalTruth (a warming simulation)
    session: Path | None = None
    parameters: Path | None = None  # the parameter file written (or, in a replay, the recorded one)
    parameter_file: ParameterFile | None = None  # solved in this run
    replay_of: Path | None = None
    identical: bool | None = None  # replay: the parameter file equals the recorded one
    comparison: str = ""  # replay: how the parameter files were compared, and the verdict
    completed: int = 0
    skipped: int = 0
    message: str = ""
    previous: PreviousCalibration | None = None  # the same unit's last calibration
    samples: int = 0  # fed to the engine (a replay: the samples replayed)

    @property
    def solved(self) -> bool:
        return self.unit is not None and bool(self.unit.solutions)

    @property
    def aborted(self) -> bool:
        return self.status != Status.COMPLETED
