"""Rate steps where they pay: a position may have no rate step (``rate_step: none``) or one of its
own rate and turns; such a procedure validates, runs headless through the conductor and in the
TUI, replays byte for byte, and the gyro still solves."""
from __future__ import annotations

import re

import numpy as np
import pytest

from fieldcal.earth import Station
from fieldcal.procedure.positions import ProcedureError, RateStep, load_procedure, parse_procedure

STATION = Station(40.0, 50.0)
SHORT_TEXT = (load_procedure("field-18").text.replace("dwell_s: 200", "dwell_s: 20")
              .replace("rate_deg_s: 10", "rate_deg_s: 30"))


def with_position_steps(text: str, steps: dict[int, str]) -> str:
    """``text`` with ``rate_step: VALUE`` written into the positions of the given ids."""
    def put(match):
        ident = int(match.group(1))
        return match.group(0) + (f" rate_step: {steps[ident]}," if ident in steps else "")
    return re.sub(r"  - \{id: (\d+),", put, text)


# field-18 (20 s dwells, ±30 °/s, one turn) turning at 9 of its 18 positions: the odd ones, which
# put the table axis along +z, −z, +y, −y, +x, −x and three of the 45° directions. Four of them
# turn at their own rate and turns, so the windows carry two rates.
OWN = "{rate_deg_s: 20, turns: 2}"
HALF_TEXT = with_position_steps(SHORT_TEXT, {**{i: "none" for i in range(2, 19, 2)},
                                             **{i: OWN for i in (3, 7, 11, 15)}})


def test_positions_take_no_step_their_own_or_the_procedures():
    half = parse_procedure(HALF_TEXT, "half.yaml")
    default = RateStep(30.0, 1, 2.0, 1.0)
    own = RateStep(20.0, 2, 2.0, 1.0)  # ramp and settle from the procedure's step
    expected = {1: default, 3: own, 5: default, 7: own, 9: default, 11: own, 13: default, 15: own, 17: default}
    assert [half.rate_step_at(i) for i in range(18)] == [expected.get(p.id) for p in half.positions]
    assert half.rate_steps == (own, default)  # slowest first
    plain = parse_procedure(SHORT_TEXT, "short.yaml")
    assert plain.position_steps == () and plain.rate_step_at(17) == default  # as before


STATIC_TWO = """\
name: two
dwell_s: 20
positions:
  - {id: 1, axes: {x: south, y: east, z: up}}
  - {id: 2, axes: {x: north, y: west, z: up}}
"""


def test_a_static_procedure_may_turn_at_some_positions_with_full_steps():
    text = with_position_steps(STATIC_TWO, {1: "{rate_deg_s: 15, turns: 1, ramp_s: 3, settle_s: 2}"})
    procedure = parse_procedure(text, "c.yaml")
    assert procedure.rate_step is None
    assert procedure.rate_step_at(0) == RateStep(15.0, 1, 3.0, 2.0) and procedure.rate_step_at(1) is None


@pytest.mark.parametrize("text, message", [
    (with_position_steps(SHORT_TEXT, {2: "nothing"}),
     "positions[1].rate_step: expected 'none' or a mapping {rate_deg_s, turns}, got 'nothing'"),
    (with_position_steps(SHORT_TEXT, {2: "{rate_deg_s: 500, turns: 1}"}),
     "positions[1].rate_step.rate_deg_s: expected a number from 0.1 to 400 °/s, got 500"),
    (with_position_steps(SHORT_TEXT, {2: "{rate_deg_s: 20}"}), "positions[1].rate_step.turns: missing"),
    (with_position_steps(SHORT_TEXT, {2: "{rate_deg_s: 20, turns: 1, spin: 2}"}),
     "positions[1].rate_step.spin: unknown key 'spin'"),
    (with_position_steps(STATIC_TWO, {1: "{rate_deg_s: 15, turns: 1}"}),
     "positions[0].rate_step.ramp_s: missing"),
])
def test_a_bad_position_step_is_one_line_naming_it(text, message):
    with pytest.raises(ProcedureError) as exc_info:
        parse_procedure(text, "bad.yaml")
    said = str(exc_info.value)
    assert "\n" not in said and said.startswith("bad.yaml: ") and message in said, said


@pytest.fixture(scope="module")
def half_run(tmp_path_factory):
    from fieldcal.run.runner import RunSpec, run_headless

    spec = RunSpec(parse_procedure(HALF_TEXT, "half.yaml"), STATION, seed=5)
    return spec, run_headless(spec, tmp_path_factory.mktemp("half") / "session")


def test_turning_at_half_the_positions_runs_headless_and_the_gyro_still_solves(half_run):
    """Through the conductor: 9 +ω/−ω pairs at the positions that turn, at their own rates, and
    every parameter of every triad within 4σ of the truth (27 parameters: 1 in 600 by chance)."""
    spec, result = half_run
    assert result.status == "completed" and not result.unit.failures
    gyro = result.unit.problems["gyroscope"]
    assert sorted(np.round(np.degrees(gyro.table_rate), 6)) == [20.0] * 4 + [30.0] * 5
    assert [label.split()[1] for label in gyro.step_labels] == [str(i) for i in range(1, 18, 2)]
    for name, sol in result.unit.solutions.items():
        z = (sol.theta - result.truth[name]) / sol.sigma
        assert np.all(np.abs(z) < 4.0), (name, z)


def test_its_reported_sigma_is_the_bound_of_its_own_windows(half_run):
    """The gyro's reported σ (the solver's) against the Cramér-Rao bound of the same windows at
    the nominal positions (the bound a planner and the TUI's tracker use, now with rate steps at
    some positions only): within 10 % for the scale factors and misalignments."""
    from fieldcal.planning.design import window_sigmas
    from fieldcal.procedure.windows import Window

    spec, result = half_run
    from fieldcal.run.runner import open_run

    steps = [document.record for document in open_run(result.session).steps]
    windows = [Window(w.kind, s.step, w.start, w.duration, np.radians(abs(w.rate_deg_s)))
               for s in steps for w in s.windows]
    attitudes = np.array([p.attitude for p in spec.procedure.positions])
    bound = window_sigmas(windows, attitudes, 30.0, {"gyroscope": spec.models()["gyroscope"]},
                          STATION, spec.rate_hz)["gyroscope"]
    reported = result.unit.solutions["gyroscope"].sigma
    np.testing.assert_allclose(reported[3:], bound[3:], rtol=0.10)


def test_it_replays_byte_for_byte(half_run):
    from fieldcal.paramfile import dump
    from fieldcal.run.replay import recorded_parameters, replay
    from fieldcal.run.runner import open_run

    _, result = half_run
    replayed = replay(open_run(result.session))
    assert dump(replayed.parameter_file).encode() == recorded_parameters(open_run(result.session))


def test_the_time_to_go_counts_each_positions_own_step():
    """Worked by hand: position 1 turns at ±10 °/s once (2 + 1 + 36 = 39 s up to +10 °/s, the
    reversal ramping twice as far: 4 + 1 + 36 = 41 s), position 2 not at all, position 3 at 20 °/s
    twice (39 s and 41 s again): 20 s dwells, a placement each."""
    from fieldcal.procedure import events as ev
    from fieldcal.tui.view import PLACING_GUESS_S, RunView

    text = """\
name: three
dwell_s: 20
rate_step: {rate_deg_s: 10, turns: 1, ramp_s: 2, settle_s: 1}
positions:
  - {id: 1, axes: {x: south, y: east, z: up}}
  - {id: 2, rate_step: none, axes: {x: north, y: west, z: up}}
  - {id: 3, rate_step: {rate_deg_s: 20, turns: 2}, axes: {x: north, y: east, z: down}}
"""
    view = RunView(parse_procedure(text, "three.yaml"))
    view.apply(ev.StepStarted(0.0, 0, 1, "z-upward", 3))
    placing = PLACING_GUESS_S
    assert view.remaining_s() == pytest.approx((20 + 80 + placing) + (20 + placing) + (20 + 80 + placing))


def test_the_tui_runs_it_as_the_headless_run_does(tmp_path, half_run):
    """The same seed and the same keys (r at each position) in the TUI through Textual's Pilot:
    the same parameter file, byte for byte, and the same events."""
    from tui_pilot import run_async, until, waiting_at

    from fieldcal.session.capture import SessionReader
    from fieldcal.tui import FieldcalApp
    from fieldcal.tui.screens.results import ResultsScreen

    spec, headless = half_run

    @run_async
    async def drive():
        app = FieldcalApp(spec, speed=0, session_dir=tmp_path / "session")
        async with app.run_test(size=(80, 24)) as pilot:
            for step in range(len(spec.procedure.positions)):
                await until(pilot, lambda step=step: waiting_at(app, step))
                await pilot.press("r")
            await until(pilot, lambda: app.outcome is not None and isinstance(app.screen, ResultsScreen))
        return app

    app = drive()
    assert app.outcome.status == "completed" and not app.outcome.unit.failures
    assert app.outcome.parameters.read_bytes() == headless.parameters.read_bytes()
    assert [e.kind for e in app.events] == [e["event"] for e in SessionReader(headless.session).events()]


def test_the_bound_gains_from_every_window_and_a_design_may_turn_at_some_positions():
    """With white noise alone (window times do not matter), information only adds: field-18's 18
    positions all turning bound every gyro σ at most as the same 18 with rate steps at 9 only, and
    those at most as the 9 turning positions alone (their 9 static dwells add the Earth rate at
    free directions, which the bound must take as such, finite). The timeline of a design that
    turns at 9 of 18 positions saves exactly 9 positions' rate steps."""
    from dataclasses import replace

    from drivers.sim.device import paper_mimu
    from fieldcal.planning.design import Design, OperatorModel, bound_sigmas, end_bias_sigmas, timeline
    from fieldcal.solvers.solve import models_from_truth

    device = {n: replace(t, noise=replace(t.noise, bias_instability=0.0)) for n, t in paper_mimu().items()}
    gyro = {"gyroscope": models_from_truth(device)["gyroscope"]}
    attitudes = tuple(p.attitude for p in load_procedure("field-18").positions)
    odd = tuple(i % 2 == 0 for i in range(18))
    operator = OperatorModel()
    every = Design(attitudes, 20.0, 20.0, 1)
    half = Design(attitudes, 20.0, 20.0, 1, odd)
    nine = Design(attitudes[::2], 20.0, 20.0, 1)
    sigmas = [bound_sigmas(d, operator, gyro, STATION, 250.0)["gyroscope"] for d in (every, half, nine)]
    assert all(np.all(np.isfinite(s)) for s in sigmas)
    assert np.all(sigmas[0] <= sigmas[1] * (1 + 1e-6)) and np.all(sigmas[1] <= sigmas[2] * (1 + 1e-6))
    assert np.any(sigmas[1] < 0.99 * sigmas[2])  # the static dwells do add
    windows, seconds = timeline(half, operator)
    full_windows, full_seconds = timeline(every, operator)
    assert len(windows) == 18 + 2 * 9 and len(full_windows) == 3 * 18
    rate_step = 2 * half.turn_s + operator.ramp_s(20.0) * 4 + 2 * operator.rate_settle_s
    assert full_seconds - seconds == pytest.approx(9 * rate_step)
    # With the paper's flicker, the bias at the end for such a design: the predictor no worse
    # than the constant, and the constant's error no larger than its own σ plus the process's
    # spread (the triangle inequality for standard deviations).
    models = models_from_truth(paper_mimu())
    ends = end_bias_sigmas(windows, np.array(attitudes), 20.0, models, STATION, 250.0)
    turn_on = bound_sigmas(half, operator, models, STATION, 250.0)
    for name, (predicted, constant) in ends.items():
        spread = np.sqrt(models[name].noise.bias_variance()) * np.abs(np.diag(models[name].sensitivity))
        assert np.all(predicted <= constant * (1 + 1e-6)), name
        assert np.all(constant <= turn_on[name][:3] + spread), name


def test_the_planner_leaves_out_the_rate_steps_the_target_does_not_need():
    """A gyro allowed twice field-18-at-20-s's scale and misalignment σ: rate steps are left out
    while the target holds, the time falls by exactly the steps left out, and leaving out any one
    more would miss it; a target with nothing to spare keeps every step."""
    from drivers.sim.device import paper_mimu
    from fieldcal.planning.design import Design, OperatorModel, bound_sigmas, operator_time
    from fieldcal.planning.search import Plan, Planner
    from fieldcal.solvers.solve import models_from_truth

    gyro = {"gyroscope": models_from_truth(paper_mimu())["gyroscope"]}
    operator = OperatorModel()
    design = Design(tuple(p.attitude for p in load_procedure("field-18").positions), 20.0, 20.0, 1)
    sigmas = bound_sigmas(design, operator, gyro, STATION, 250.0)
    plan = Plan((), design, operator_time(design, operator), sigmas)
    loose = Planner(gyro, STATION, 250.0, operator, {"gyroscope": np.r_[np.full(3, np.inf), 2 * sigmas["gyroscope"][3:]]}, 20.0)
    pruned = loose.turn_where_it_pays(plan)
    kept = [i for i in range(18) if pruned.design.turns_at(i)]
    assert 3 <= len(kept) < 18 and loose.worst_ratio(pruned.design) <= 1.0
    rate_step = 2 * design.turn_s + 4 * operator.ramp_s(20.0) + 2 * operator.rate_settle_s
    assert plan.seconds - pruned.seconds == pytest.approx((18 - len(kept)) * rate_step)
    for i in kept:
        fewer = tuple(pruned.design.turns_at(j) and j != i for j in range(18))
        assert loose.worst_ratio(Design(design.attitudes, 20.0, 20.0, 1, fewer)) > 1.0
    tight = Planner(gyro, STATION, 250.0, operator, {"gyroscope": sigmas["gyroscope"] * (1 + 1e-9)}, 20.0)
    assert tight.turn_where_it_pays(plan) is plan
