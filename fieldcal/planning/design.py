"""A candidate procedure's timeline, operator time and exact Cramér-Rao bound.

A design is a list of positions (their fixture attitudes), one static dwell per position, and a
rate step (rate and whole turns, each way) per position. Its timeline follows the operator model:
carry and place the unit, wait for stillness and the orientation check, dwell, then ramp the
table to +ω, let the rate settle, average whole turns, the same at −ω, and stop the table. The
bound is the one ``fieldcal.solvers.crb`` computes for the windows of that timeline (the noise
of every window average correlated with every other's through the triad's bias instability),
at the nominal parameters (no errors) and the nominal attitudes.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from fieldcal.earth import EARTH_RATE, Station
from fieldcal.model import ANGULAR_RATE, SPECIFIC_FORCE, params_from_k
from fieldcal.procedure.engine import EngineSettings
from fieldcal.procedure.stillness import StillnessSettings
from fieldcal.procedure.windows import MINUS, PLUS, STATIC, Window
from fieldcal.run.operators import OperatorScript
from fieldcal.run.runner import TABLE_ACCEL_DEG_S2
from fieldcal.solvers.crb import KroneckerCovariance, angular_rate_bound, end_bias_terms, specific_force_bound
from fieldcal.solvers.solve import TriadModel, average_covariance


def _default(cls, name: str) -> float:
    return next(f.default for f in dataclasses.fields(cls) if f.name == name)


@dataclass(frozen=True)
class OperatorModel:
    """Seconds the procedure spends outside the averaging windows.

    The defaults are the headless run's own: the scripted operator's handling time, the stillness
    detector's window plus the engine's orientation check before a dwell, the detector's window
    again before a rate is averaged, and the simulated table's acceleration.
    """

    place_s: float = _default(OperatorScript, "handling_s")
    settle_s: float = _default(StillnessSettings, "window_s") + _default(EngineSettings, "check_s")
    rate_settle_s: float = _default(StillnessSettings, "window_s")
    table_accel_deg_s2: float = TABLE_ACCEL_DEG_S2

    def ramp_s(self, change_deg_s: float) -> float:
        return abs(change_deg_s) / self.table_accel_deg_s2


@dataclass(frozen=True)
class Design:
    attitudes: tuple[np.ndarray, ...]  # body -> ENU per position
    dwell_s: float
    rate_deg_s: float
    turns: int
    # Which positions make the rate step (None: every one); the others are a static dwell only.
    turning: tuple[bool, ...] | None = None

    @property
    def turn_s(self) -> float:
        return self.turns * 360.0 / self.rate_deg_s

    def turns_at(self, index: int) -> bool:
        return self.turning is None or self.turning[index]


def timeline(design: Design, operator: OperatorModel) -> tuple[list[Window], float]:
    """The averaging windows (static, +, − per position, in time order) and the total time (s)."""
    windows, t = [], 0.0
    rate = design.rate_deg_s
    for index in range(len(design.attitudes)):
        t += operator.place_s + operator.settle_s
        windows.append(Window(STATIC, index, t, design.dwell_s))
        if not design.turns_at(index):  # a static dwell only
            t += design.dwell_s
            continue
        t += design.dwell_s + operator.ramp_s(rate) + operator.rate_settle_s
        windows.append(Window(PLUS, index, t, design.turn_s, np.radians(rate)))
        t += design.turn_s + operator.ramp_s(2 * rate) + operator.rate_settle_s
        windows.append(Window(MINUS, index, t, design.turn_s, np.radians(rate)))
        t += design.turn_s + operator.ramp_s(rate)
    return windows, t


def operator_time(design: Design, operator: OperatorModel) -> float:
    return timeline(design, operator)[1]


def bound_sigmas(design: Design, operator: OperatorModel, models: dict[str, TriadModel],
                 station: Station, rate_hz: float, bias_at_end: bool = False) -> dict[str, np.ndarray]:
    """Per triad, the CRB standard deviation of its 9 parameters (solver units). ``bias_at_end``:
    the biases' σ are those of the error against the bias at the end of the calibration (the
    design's last second) of the solver's ``bias_at_end``, the best linear unbiased predictor from
    the same windows (DESIGN 12; ``fieldcal.solvers.endbias``)."""
    windows, seconds = timeline(design, operator)
    attitudes = np.array(design.attitudes)
    if not bias_at_end:
        return window_sigmas(windows, attitudes, design.rate_deg_s, models, station, rate_hz)
    out = {}
    for name, model in models.items():
        try:
            sigmas, ends = triad_sigmas(model, windows, attitudes, design.rate_deg_s, station, rate_hz, seconds)
        except np.linalg.LinAlgError:  # too few positions to tell the parameters apart
            out[name] = np.full(9, np.inf)
            continue
        with np.errstate(invalid="ignore"):
            sigmas[:3] = np.sqrt(np.diag(ends.predicted))
        out[name] = sigmas
    return out


def window_sigmas(windows: list[Window], attitudes: np.ndarray, rate_deg_s: float,
                  models: dict[str, TriadModel], station: Station, rate_hz: float) -> dict[str, np.ndarray]:
    """Per triad, the CRB σ (solver units) of windows averaged at ``attitudes`` (one static, one
    +ω and one −ω window per position, each window's position an index into ``attitudes``);
    inf where the windows cannot tell the parameters apart (too few positions)."""
    out = {}
    for name, model in models.items():
        try:
            out[name] = triad_sigmas(model, windows, attitudes, rate_deg_s, station, rate_hz)
        except np.linalg.LinAlgError:  # too few positions to tell the parameters apart
            out[name] = np.full(9, np.inf)
    return out


def end_bias_sigmas(windows: list[Window], attitudes: np.ndarray, rate_deg_s: float,
                    models: dict[str, TriadModel], station: Station, rate_hz: float,
                    end_s: float | None = None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per triad, the σ (solver units, per axis) of the bias at the end of the calibration
    (``end_s``; default: the end of the last window), the value the unit is used with (DESIGN 12):
    (as predicted from the windows, the best linear unbiased predictor; as the turn-on
    constant's estimate, what a solver reporting the constant delivers). inf (or nan) where the
    windows cannot tell the parameters apart (``fieldcal.solvers.crb``'s rank rule)."""
    end_s = max(w.start + w.duration for w in windows) if end_s is None else end_s
    out = {}
    for name, model in models.items():
        try:
            ends = triad_sigmas(model, windows, attitudes, rate_deg_s, station, rate_hz, end_s)[1]
        except np.linalg.LinAlgError:
            out[name] = (np.full(3, np.nan), np.full(3, np.nan))
            continue
        with np.errstate(invalid="ignore"):
            out[name] = (np.sqrt(np.diag(ends.predicted)), np.sqrt(np.diag(ends.constant)))
    return out


def triad_sigmas(model: TriadModel, windows: list[Window], attitudes: np.ndarray, rate_deg_s: float,
                 station: Station, rate_hz: float, end_s: float | None = None, thermal=None):
    """The 9 σ of a triad's bound; with ``end_s``, (those σ, EndBiasBound at end_s). ``thermal``:
    a function of the windows used, in the solver's data order, to the ``ThermalTerms`` the bound
    also covers (their σ follow the nine)."""
    up_body = attitudes[:, 2, :]
    theta = params_from_k(model.sensitivity, np.zeros(3))

    def end(used):
        if end_s is None:
            return None
        return end_bias_terms(model.noise, model.sensitivity, [w.start for w in used],
                              [w.duration for w in used], end_s)

    def covariance(used):
        """``average_covariance``, as its Kronecker factors where it has them (no quantisation)."""
        if model.lsb:
            return average_covariance(model, used, rate_hz)
        return KroneckerCovariance(model.noise.window_covariance([w.start for w in used], [w.duration for w in used]),
                                   model.sensitivity @ model.sensitivity.T)

    if model.kind == SPECIFIC_FORCE:
        static = [w for w in windows if w.kind == STATIC]
        cov = covariance(static)
        bound = specific_force_bound(theta, up_body, station.gravity, cov, end(static),
                                     thermal=thermal(static) if thermal else None)
    elif model.kind == ANGULAR_RATE:
        # The solver's data order: every +ω window, every −ω window, every static one.
        ordered = [w for kind in (PLUS, MINUS, STATIC) for w in windows if w.kind == kind]
        cov = covariance(ordered)
        # Table angle zero at each static dwell: the heading is a nuisance of the bound.
        north_body = attitudes[:, 1, :]
        plus = [w for w in windows if w.kind == PLUS]  # the positions that turn, at their rates
        if not plus:
            raise np.linalg.LinAlgError("no rate step: the scale factors are not determined")
        rates = [w.table_rate or np.radians(rate_deg_s) for w in plus]
        bound = angular_rate_bound(theta, up_body, np.array(rates), north_body, EARTH_RATE,
                                   station.latitude_rad, cov, [w.position for w in plus], end(ordered),
                                   thermal=thermal(ordered) if thermal else None)
    else:
        raise ValueError(f"unknown triad kind {model.kind!r}")
    ends = None
    if end_s is not None:
        bound, ends = bound
    with np.errstate(invalid="ignore"):  # undetermined: inf by crb's rank rule (nan: a negative variance)
        sigmas = np.sqrt(np.diag(bound))
    return sigmas if end_s is None else (sigmas, ends)


def time_breakdown(design: Design, operator: OperatorModel) -> dict[str, float]:
    """Seconds of the design's operator time spent placing and settling, dwelling, in rate steps."""
    n = len(design.attitudes)
    placing, dwelling = n * (operator.place_s + operator.settle_s), n * design.dwell_s
    return {"placing": placing, "dwells": dwelling,
            "rate steps": operator_time(design, operator) - placing - dwelling}


FLOOR_PIECE_S = 10.0  # the weights of the floor's average are constant over pieces this long,
FLOOR_PIECES = 300  # or over this many pieces of a longer span (a bounded solve)


def bias_floor(noise, span_s: float) -> float:
    """σ (input units) of the best weighted average of one axis's noise over ``span_s`` seconds.

    A bias is estimated by some average of the window means whose weights add up to one, so no
    procedure whose averaging windows all lie within ``span_s`` can estimate it better than this:
    with bias instability (correlated over hundreds of seconds) it is the span of the run, not
    each dwell's length, that sets the bias σ. Weights constant over FLOOR_PIECE_S pieces, at most
    FLOOR_PIECES of them (the generalised least-squares mean of the pieces), which is within about
    1 % of the continuous optimum for the noise models here.
    """
    n = min(FLOOR_PIECES, max(1, int(np.ceil(span_s / FLOOR_PIECE_S))))
    piece = span_s / n
    C = noise.window_covariance(np.arange(n) * piece, np.full(n, piece))
    ones = np.ones(n)
    return float(np.sqrt(1.0 / (ones @ np.linalg.solve(C, ones))))


def shortest_span(noise, sigma: float, longest_s: float = 4 * 3600.0) -> float:
    """The shortest span (s, to 1 %) whose bias floor reaches ``sigma``; inf beyond ``longest_s``."""
    if bias_floor(noise, longest_s) > sigma:
        return float("inf")
    lo, hi = 1.0, longest_s
    while hi / lo > 1.01:
        mid = float(np.sqrt(lo * hi))
        lo, hi = (lo, mid) if bias_floor(noise, mid) <= sigma else (mid, hi)
    return hi
