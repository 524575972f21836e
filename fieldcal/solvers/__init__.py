"""Pure solvers: per-position averages in, a ``fieldcal.calibration.Calibration`` out."""
from fieldcal.solvers.classic import solve_classic
from fieldcal.solvers.norm import CalibrationError, solve_norm
from fieldcal.solvers.problems import RateNormProblem, StaticNormProblem

__all__ = ["CalibrationError", "RateNormProblem", "StaticNormProblem", "solve_classic", "solve_norm"]
