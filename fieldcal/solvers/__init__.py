"""Pure solvers: per-position averages in, calibration with uncertainty out."""
from fieldcal.solvers.classic import ClassicSolution, solve_classic
from fieldcal.solvers.norm import CalibrationError, TriadSolution, solve_norm
from fieldcal.solvers.problems import RateNormProblem, StaticNormProblem

__all__ = ["CalibrationError", "ClassicSolution", "RateNormProblem", "StaticNormProblem",
           "TriadSolution", "solve_classic", "solve_norm"]
