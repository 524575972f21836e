"""The least-time procedure that meets a target σ per parameter: an optimal-design search.

Candidates are attitudes the procedure format can write: one per gravity direction in body axes
(the 6 faces, the 12 edges, 45° between two axes, and on request the 8 corners, gravity along a
body diagonal, written as ``up: x+y+z, north: x``), plus any given procedure's own (field-18 has
every face twice, at two headings). Faces alone cannot tell the misalignments apart, corners alone
the scale factors (the norm method sees gravity's direction only through u uᵀ); edges can, and
faces with corners. Corners are not offered by default: for the paper's unit the biases, which
the span of the run sets, bind the time, and corners save about 1 % of it (the bound with and
without them) while the search takes twice as long.

Positions come and go in antipodal pairs (a face and its opposite, an edge and its opposite),
which keep each axis's bias separable from its scale factor. For each number of whole turns per
rate step (1 to MAX_TURNS), the search starts from every pair, finds the shortest whole-second
dwell that meets the target (the bound falls monotonically with the dwell), then repeatedly drops
the pair whose loss the others make up best (smallest worst σ/target at the current dwell),
lengthening the dwell as needed, and keeps the design with the least operator time (stopping
after PATIENCE drops in a row save nothing). The table runs at its fastest rate: a faster rate
gives a larger scale-factor signal in less time. One dwell for every position, as the format
has it: the parameters that bind (the biases) depend on the span the averages cover more than on
the dwells, which are about a tenth of a planned run for the paper's unit, so a dwell per
position could save at most that tenth.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, replace

import numpy as np

from fieldcal.earth import Station
from fieldcal.planning.design import Design, OperatorModel, bound_sigmas, operator_time
from fieldcal.procedure.positions import _WORDS, attitude_from_up_and_north
from fieldcal.solvers.solve import TriadModel

MIN_DWELL_S = 5.0  # a dwell needs a few stillness windows to be recognised as one
MAX_DWELL_S = 1200.0
MAX_TURNS = 3
PATIENCE = 2  # pair removals in a row that save no time before the search stops dropping
ABOVE_ONE = float(np.nextafter(1.0, 2.0))  # a worst ratio reaching it misses the target (> 1)


@dataclass(frozen=True)
class Candidate:
    name: str  # e.g. "x-up", "x-up z-up edge" or "x-up y-down z-up corner"
    fields: dict  # how a procedure file writes it: {"axes": {x, y, z words}} or {"up", "north"}
    attitude: np.ndarray

    @property
    def corner(self) -> bool:
        return bool(np.all(np.abs(self.attitude[2]) > 1e-9))


def _words() -> dict[str, np.ndarray]:
    single = {w: np.array(v, float) for w, v in _WORDS.items()}
    pairs = {}
    for a, b in itertools.combinations(_WORDS, 2):
        v = single[a] + single[b]
        if np.linalg.norm(v) > 0:
            # Horizontal first, as the procedure files write them ("north-up").
            first, second = (b, a) if a in ("up", "down") else (a, b)
            pairs[f"{first}-{second}"] = v / np.linalg.norm(v)
    return {**single, **pairs}


def candidates(extra=(), corners: bool = False) -> list[Candidate]:
    """One writable proper attitude per gravity direction (faces, edges, then with ``corners``
    the corners), then ``extra`` (positions of a procedure file) whose attitude differs from all
    before and that compass words can write."""
    words = _words()
    found: dict[tuple, Candidate] = {}
    # Every triple of words at once (5,832 for 18 words): proper rotations only, in product order.
    names = list(itertools.product(words, repeat=3))
    vectors = np.array(list(words.values()))
    index = np.array(list(itertools.product(range(len(words)), repeat=3)))
    stacked = vectors[index].transpose(0, 2, 1)  # (triples, 3, 3): the words are the columns
    gram = stacked.transpose(0, 2, 1) @ stacked
    eye = np.eye(3)
    proper = np.all(np.abs(gram - eye) <= 1e-9 + 1e-5 * eye, axis=(1, 2))  # np.allclose's test
    proper[proper] = np.linalg.det(stacked[proper]) >= 0
    for (wx, wy, wz), A in zip((names[i] for i in np.flatnonzero(proper)), stacked[proper]):
        key = tuple(np.round(A[2], 6))
        if key not in found:
            found[key] = Candidate(_describe(A), {"axes": dict(zip("xyz", (wx, wy, wz)))}, A)
    if corners:
        for signs in itertools.product((1, -1), repeat=3):
            up = "".join(f"{'+' if s > 0 else '-'}{a}" for s, a in zip(signs, "xyz")).lstrip("+")
            A = corner_attitude(np.array(signs, float))
            found[tuple(np.round(A[2], 6))] = Candidate(_describe(A), {"up": up, "north": "x"}, A)
    pool = sorted(found.values(), key=lambda c: (np.count_nonzero(np.abs(c.attitude[2]) > 1e-9), c.name))
    for position in extra:
        if not any(np.allclose(c.attitude, position.attitude) for c in pool):
            axes = [_word_of(position.attitude[:, i], words) for i in range(3)]
            if None in axes:  # not a face or edge at a compass heading: written as it was given
                continue
            pool.append(Candidate(f"{_describe(position.attitude)} (heading of {position.description})",
                                  {"axes": dict(zip("xyz", axes))}, position.attitude))
    return pool


def corner_attitude(up_body: np.ndarray) -> np.ndarray:
    """Body -> ENU with local up along ``up_body`` (a body diagonal) and body x's horizontal part
    towards north, as ``up: ±x±y±z, north: x`` in a procedure file."""
    return attitude_from_up_and_north(up_body, np.array([1.0, 0.0, 0.0]))


def _describe(A: np.ndarray) -> str:
    up = A[2]
    names = [f"{n}-{'up' if c > 0 else 'down'}" for n, c in zip("xyz", up) if abs(c) > 1e-9]
    return names[0] if len(names) == 1 else " ".join(names) + (" edge" if len(names) == 2 else " corner")


def _word_of(direction: np.ndarray, words: dict[str, np.ndarray]) -> str | None:
    return next((w for w, v in words.items() if np.allclose(v, direction, atol=1e-9)), None)


def antipodal_pairs(pool: list[Candidate]) -> list[tuple[Candidate, ...]]:
    """The pool grouped into pairs with opposite gravity directions (a lone one stays alone)."""
    left, pairs = list(pool), []
    while left:
        first = left.pop(0)
        match = next((c for c in left if np.allclose(c.attitude[2], -first.attitude[2])), None)
        if match is not None:
            left.remove(match)
        pairs.append((first,) if match is None else (first, match))
    return pairs


@dataclass(frozen=True)
class Plan:
    positions: tuple[Candidate, ...]
    design: Design
    seconds: float
    sigmas: dict[str, np.ndarray]


class Planner:
    def __init__(self, models: dict[str, TriadModel], station: Station, rate_hz: float,
                 operator: OperatorModel, targets: dict[str, np.ndarray], max_rate_deg_s: float,
                 bias_at_end: bool = False):
        self.models, self.station, self.rate_hz = models, station, rate_hz
        self.operator, self.targets, self.rate = operator, targets, max_rate_deg_s
        self.bias_at_end = bias_at_end  # biases judged against the bias at the end (design.bound_sigmas)
        # The bound of each design evaluated, per triad: the search asks again for some (a dwell
        # found by the bisection, then its plan; a design the drops and the turn choice both
        # reach), and a comparison may need only some triads' (``worst_ratio``'s ``enough``).
        self._bounds: dict[tuple, dict[str, np.ndarray]] = {}
        self._lead: str | None = None  # the triad that last decided a comparison: asked first

    def _bounded(self, design: Design, names) -> dict[str, np.ndarray]:
        """The cached σ of ``names`` (triads) for ``design``, bounding those not yet known."""
        key = (tuple(np.asarray(a, dtype=float).tobytes() for a in design.attitudes), design.dwell_s, design.rate_deg_s,
               design.turns, design.turning)
        known = self._bounds.setdefault(key, {})
        missing = {name: self.models[name] for name in names if name not in known}
        if missing:
            known.update(bound_sigmas(design, self.operator, missing, self.station, self.rate_hz, self.bias_at_end))
        return known

    def sigmas(self, design: Design) -> dict[str, np.ndarray]:
        known = self._bounded(design, self.models)
        return {name: known[name].copy() for name in self.models}

    def worst_ratio(self, design: Design, enough: float = np.inf) -> float:
        """The largest σ/target over every parameter of every triad (nan counts as infinite: an
        undetermined parameter, σ inf, fails even an untargeted one's target of inf); or, as soon
        as one triad's reaches ``enough``, that triad's largest, a value ≥ ``enough`` that is all a
        caller asking "below ``enough``?" needs: the other triads' bounds are not taken. The
        triad that was the worst last time is asked first (the same one binds design after
        design)."""
        names = list(self.targets)
        if self._lead in self.targets:
            names.remove(self._lead)
            names.insert(0, self._lead)
        worst, worst_name = -np.inf, names[0]
        for name in names:
            with np.errstate(invalid="ignore"):  # inf / inf
                ratios = self._bounded(design, (name,))[name] / self.targets[name]
            ratio = float(np.max(np.nan_to_num(ratios, nan=np.inf)))
            if ratio > worst:
                worst, worst_name = ratio, name
            if worst >= enough:
                break
        self._lead = worst_name
        return worst

    def _least(self, designs, enough: float = np.inf) -> tuple[int, float]:
        """(index, worst ratio) of the first of ``designs`` with the smallest worst ratio, as
        ``min`` would pick it: each design is bounded only as far as it can still beat the best so
        far (nor past ``enough``, when a best at or above it is of no use to the caller)."""
        best_index, best = 0, np.inf
        for index, design in enumerate(designs):
            ratio = self.worst_ratio(design, min(best, enough))
            if ratio < best:
                best_index, best = index, ratio
        return best_index, best

    def _design(self, positions, dwell: float, turns: int) -> Design:
        return Design(tuple(p.attitude for p in positions), float(dwell), self.rate, turns)

    def shortest(self, positions, turns: int, at_least: float = MIN_DWELL_S) -> Plan | None:
        """The shortest whole-second dwell (not below ``at_least``) at which ``positions`` meet
        the target, if any within MAX_DWELL_S."""
        def meets(dwell):
            return bool(positions) and self.worst_ratio(self._design(positions, dwell, turns), ABOVE_ONE) <= 1.0
        lo = max(MIN_DWELL_S, float(np.floor(at_least)))
        if meets(lo):
            hi = lo
        else:
            hi = lo
            while not meets(hi):  # grow the bracket from below: dwells only lengthen in a search
                if hi >= MAX_DWELL_S:
                    return None
                lo, hi = hi, min(MAX_DWELL_S, 2 * hi)
        while hi - lo > 1.0:
            mid = float(np.floor((lo + hi) / 2))
            lo, hi = (lo, mid) if meets(mid) else (mid, hi)
        best = self._design(positions, np.ceil(hi), turns)
        return Plan(tuple(positions), best, operator_time(best, self.operator), self.sigmas(best))

    def turn_where_it_pays(self, plan: Plan) -> Plan:
        """``plan`` with rate steps left out, one position at a time, while the target still
        holds at its dwell: each time the position whose step costs the least in the worst σ
        ratio. A gyro with σ to spare (the paper's unit's scale factors and misalignments come
        out at half field-18's) then turns only where its turns pay."""
        design = plan.design
        turning = list(design.turning or (True,) * len(design.attitudes))
        while sum(turning) > 1:
            def without(i):
                return replace(design, turning=tuple(t and j != i for j, t in enumerate(turning)))
            stepping = [i for i, t in enumerate(turning) if t]
            least, ratio = self._least([without(i) for i in stepping], ABOVE_ONE)
            if ratio > 1.0:
                break
            drop = stepping[least]
            turning[drop] = False
            design = without(drop)
        if design is plan.design:
            return plan
        return Plan(plan.positions, design, operator_time(design, self.operator), self.sigmas(design))

    def search(self, pool: list[Candidate]) -> Plan:
        """The least-time design over every number of whole turns per rate step: a turn is also
        gyroscope averaging time, so more turns can buy shorter dwells and fewer positions."""
        plans = [self._search(pool, turns) for turns in range(1, MAX_TURNS + 1)]
        found = [p for p in plans if p is not None]
        if not found:
            raise ValueError("plan: no procedure from the candidate positions meets the target "
                             f"within a {MAX_DWELL_S:g} s dwell; relax the target")
        return min(found, key=lambda p: p.seconds)

    def _search(self, pool: list[Candidate], turns: int) -> Plan | None:
        pairs = antipodal_pairs(pool)
        current = self.shortest([c for pair in pairs for c in pair], turns)
        if current is None:
            return None
        best, idle = current, 0
        while len(pairs) > 1 and idle < PATIENCE:
            drop, _ = self._least([self._design([c for j, pair in enumerate(pairs) if j != i for c in pair],
                                                current.design.dwell_s, turns) for i in range(len(pairs))])
            pairs = pairs[:drop] + pairs[drop + 1:]
            current = self.shortest([c for pair in pairs for c in pair], turns, current.design.dwell_s)
            if current is None:
                break
            idle = 0 if current.seconds < best.seconds else idle + 1
            if current.seconds < best.seconds:
                best = current
        return best
