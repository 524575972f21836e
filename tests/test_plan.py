"""`fieldcal plan`: a planned procedure is an ordinary one, meets its target on the real engine's
timeline (the bound computed here from the headless run's own windows), and takes less time."""
import re

import numpy as np
import pytest

from drivers.sim.device import paper_mimu
from fieldcal.cli.main import main
from fieldcal.earth import EARTH_RATE
from fieldcal.model import PARAM_NAMES, SPECIFIC_FORCE, params_from_k
from fieldcal.planning.command import GROUPS
from fieldcal.planning.design import Design, OperatorModel, bound_sigmas, operator_time
from fieldcal.planning.search import candidates
from fieldcal.procedure import events as ev
from fieldcal.procedure.positions import load_procedure
from fieldcal.run.conductor import Conductor, Subscriber
from fieldcal.run.operators import ScriptedOperator
from fieldcal.paramfile import dump
from fieldcal.run.replay import recorded_parameters, replay
from fieldcal.run.runner import OperatorScript, RunSpec, SimulatedBench, open_run, run_headless
from fieldcal.run.simcal import DEFAULT_STATION
from fieldcal.solvers.solve import models_from_truth
from fieldcal.solvers.crb import angular_rate_bound, specific_force_bound
from fieldcal.units import display_scale

# Operator-unit targets loose enough for a short plan and a short headless run.
TARGETS = {("accelerometer", "bias"): 0.12, ("accelerometer", "scale"): 1e-4,
           ("accelerometer", "misalignment"): 0.2, ("gyroscope", "bias"): 0.8,
           ("gyroscope", "scale"): 1e-4, ("gyroscope", "misalignment"): 0.2}


class Witness(Subscriber):
    """Each dwell's true attitude and table angle, which only the bench knows."""

    def __init__(self, bench):
        self.bench, self.attitudes, self.angles, self.events = bench, [], [], []

    def event(self, e, run) -> None:
        self.events.append(e)
        if isinstance(e, ev.DwellComplete):
            self.attitudes.append(self.bench.attitude.copy())
            self.angles.append(self.bench.sim.table_angle)


@pytest.fixture(scope="module", autouse=True)
def one_turn_per_rate_step():
    """The searches here try one whole turn per rate step only (search.MAX_TURNS = 1), what their
    assertions need: each number of turns is searched alone, and for TARGETS one turn gives the
    least time anyway (630 s of operator time, against 1062 s and 1494 s with two and three
    turns), so the plan is the same, found in a third of the time."""
    from fieldcal.planning import search

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(search, "MAX_TURNS", 1)
        yield


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    out = tmp_path_factory.mktemp("plan") / "quick.yaml"
    target = ",".join(f"{t}.{g}={v:g}" for (t, g), v in TARGETS.items())
    assert main(["plan", "--config", "sim", "--target", target, "--out", str(out)]) == 0
    procedure = load_procedure(out)
    spec = RunSpec(procedure, DEFAULT_STATION, seed=5)
    bench = SimulatedBench(spec)
    witness = Witness(bench)
    conductor = Conductor(spec, bench, ScriptedOperator(spec.script, procedure), [witness])
    return procedure, conductor, conductor.run(), witness


def test_the_planned_procedure_loads_and_every_triad_solves(planned):
    procedure, _, outcome, _ = planned
    assert procedure.rate_step is not None and len(procedure.positions) >= 3
    assert procedure.adaptive_dwell
    assert not outcome.unit.failures
    assert set(outcome.unit.solutions) == {"accelerometer", "gyroscope", "inclinometer"}


def test_the_bound_at_the_runs_own_windows_meets_the_target(planned):
    procedure, conductor, outcome, witness = planned
    windows = conductor.engine.windows_and_averages()[0]
    attitudes = np.array(witness.attitudes)
    up_body = attitudes[:, 2, :]
    angle = np.array(witness.angles)
    north_body = np.einsum("nij,ni->nj", attitudes,
                           np.column_stack([np.sin(angle), np.cos(angle), np.zeros_like(angle)]))
    device = paper_mimu()
    for (triad, group), sigma in TARGETS.items():
        truth = device[triad]
        theta = params_from_k(truth.K, truth.bias)
        cov = outcome.unit.covariances[triad]
        if truth.kind == SPECIFIC_FORCE:
            bound = specific_force_bound(theta, up_body, DEFAULT_STATION.gravity, cov)
        else:
            bound = angular_rate_bound(theta, up_body, np.radians(procedure.rate_step.rate_deg_s),
                                       north_body, EARTH_RATE, DEFAULT_STATION.latitude_rad, cov)
        for j in GROUPS[group]:
            shown = np.sqrt(bound[j, j]) * display_scale(truth.kind, truth.output_unit, j)
            # The run's placements are 3° off nominal and its timeline is the engine's, not the
            # planner's model: a few percent of slack.
            assert shown <= 1.05 * sigma, (triad, group, j, shown, sigma)
    assert len(windows) == 3 * len(procedure.positions)


def test_the_plan_takes_less_time_than_field_18_and_the_model_matches_the_engine(planned):
    procedure, conductor, _, _ = planned
    step = procedure.rate_step
    operator = OperatorModel()
    planned_s = operator_time(Design(tuple(p.attitude for p in procedure.positions), procedure.dwell_s,
                                     step.rate_deg_s, step.turns), operator)
    field = load_procedure("field-18")
    field_s = operator_time(Design(tuple(p.attitude for p in field.positions), field.dwell_s,
                                   field.rate_step.rate_deg_s, field.rate_step.turns), operator)
    assert planned_s < field_s
    # The operator model is the headless run's timeline: sample time at the end of the run.
    assert conductor.engine.t == pytest.approx(planned_s, rel=0.05)


def test_candidates_are_proper_rotations_with_distinct_gravity_directions():
    pool = candidates(corners=True)
    ups = np.array([c.attitude[2] for c in pool])
    assert len(pool) == 26  # 6 faces, 12 edges and 8 corners
    for c in pool:
        assert np.allclose(c.attitude.T @ c.attitude, np.eye(3)) and np.linalg.det(c.attitude) > 0
    assert len({tuple(np.round(u, 6)) for u in ups}) == 26


def test_a_longer_dwell_does_not_loosen_the_bound():
    models = {n: m for n, m in models_from_truth(paper_mimu()).items() if n != "inclinometer"}
    every = tuple(c.attitude for c in candidates())
    short, long = (bound_sigmas(Design(every, T, 20.0, 1), OperatorModel(), models, DEFAULT_STATION, 250.0)
                   for T in (20.0, 80.0))
    for name in models:
        assert np.all(np.isfinite(short[name]))
        # Up to finite-difference noise (the rate windows move later in time, too): the dwell
        # search's bisection relies on this.
        assert np.all(long[name] <= short[name] * (1 + 1e-5))


@pytest.mark.parametrize("target, message", [
    ("magnetometer.bias=1", "TRIAD.GROUP"), ("accelerometer.offset=1", "TRIAD.GROUP"),
    ("accelerometer.bias=-1", "σ > 0"), ("", "no σ given")])
def test_a_bad_target_is_a_one_line_error(tmp_path, capsys, target, message):
    out = tmp_path / "p.yaml"
    assert main(["plan", "--config", "sim", "--target", target, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1 and not out.exists()


def test_a_planned_adaptive_run_replays_byte_for_byte(planned, tmp_path):
    # A wrong placement first at step 2, so the replay has an operator mishap to repeat too.
    procedure = planned[0]
    events = []
    result = run_headless(RunSpec(procedure, DEFAULT_STATION, seed=8, script=OperatorScript(wrong_step=1)),
                          tmp_path / "s", events.append)
    assert not result.unit.failures
    assert any(e.kind == "wrong_orientation" for e in events)
    replayed = replay(open_run(result.session))
    pf = replayed.parameter_file
    assert dump(pf).encode() == recorded_parameters(open_run(result.session))


def test_the_bias_floor_of_white_noise_is_the_plain_mean_and_grows_with_bias_instability():
    from drivers.noise import TriadNoise
    from fieldcal.planning.design import bias_floor, shortest_span

    white = TriadNoise(white=1e-3)
    # White noise: the best average is the plain mean, σ = N / √T.
    assert bias_floor(white, 400.0) == pytest.approx(1e-3 / np.sqrt(400.0), rel=1e-9)
    assert shortest_span(white, 1e-3 / np.sqrt(900.0)) == pytest.approx(900.0, rel=0.02)
    flicker = TriadNoise(white=1e-3, bias_instability=2e-4)
    # Correlated noise averages down more slowly than 1/√T, and never below its own white part.
    assert bias_floor(flicker, 400.0) > 1e-3 / np.sqrt(400.0)
    assert bias_floor(flicker, 1600.0) > bias_floor(flicker, 400.0) / 2
    assert bias_floor(flicker, 1600.0) < bias_floor(flicker, 400.0)


def test_no_design_beats_the_bias_floor_of_its_own_span():
    """The floor is a bound: field-18's CRB for each bias is at least the floor over its time."""
    from fieldcal.planning.design import bias_floor, shortest_span

    models = models_from_truth(paper_mimu())
    procedure = load_procedure("field-18")
    step = procedure.rate_step
    design = Design(tuple(p.attitude for p in procedure.positions), procedure.dwell_s,
                    step.rate_deg_s, step.turns)
    operator = OperatorModel()
    span = operator_time(design, operator)
    sigmas = bound_sigmas(design, operator, models, DEFAULT_STATION, 250.0)
    for name, model in models.items():
        floor = bias_floor(model.noise, span)
        assert np.all(sigmas[name][:3] >= floor * 0.99), name
        # And so the span the floor asks for field-18's own σ is one field-18 does not exceed.
        assert shortest_span(model.noise, float(sigmas[name][:3].min())) <= span * 1.01, name
    # The gyroscope's averages fill most of the run: its bias is within 10 % of the floor.
    assert np.all(sigmas["gyroscope"][:3] <= 1.1 * bias_floor(models["gyroscope"].noise, span))


def test_the_tracker_folds_the_engines_own_windows_and_its_sigma_falls_to_the_target(planned):
    from fieldcal.planning.tracker import TargetTracker

    procedure, conductor, _, witness = planned
    assert procedure.targets  # the planner wrote them, in operator units
    tracker = TargetTracker(procedure, models_from_truth(paper_mimu()), DEFAULT_STATION, 250.0)
    ratios = []
    for e in witness.events:
        if tracker.apply(e):
            ratios.append(max(s.ratio for s in tracker.standings()))
    engine_windows = conductor.engine.windows_and_averages()[0]
    folded = [w for step in sorted(tracker.completed) for w in tracker.completed[step]]
    key = lambda w: (w.position, str(w.kind))  # noqa: E731
    for mine, theirs in zip(sorted(folded, key=key), sorted(engine_windows, key=key), strict=True):
        assert mine.kind == theirs.kind and mine.position == theirs.position
        assert mine.start == pytest.approx(theirs.start, abs=0.01)
        assert mine.duration == pytest.approx(theirs.duration, abs=0.01)
    assert ratios[0] == np.inf and ratios[1] == np.inf  # two positions tell nothing apart
    assert all(b <= a * (1 + 1e-9) for a, b in zip(ratios, ratios[1:]))  # information only grows
    # At the end every targeted parameter is met (nominal attitudes: the planner's own bound).
    final = tracker.standings()
    assert {s.triad for s in final} == {t for t, _ in TARGETS}
    assert all(s.sigma <= 1.05 * s.target for s in final), final


@pytest.mark.parametrize("targets, message", [
    ("{accelerometer: {bias_q: 0.1}}", "bias_"),  # an unknown parameter: the nearest valid name
    ("{accelerometer: {bias_x: 0}}", "a σ > 0"),
    ("{accelerometer: {bias_x: fast}}", "targets.accelerometer.bias_x"),
    ("[0.1]", "a mapping of triad names"),
])
def test_bad_targets_in_a_procedure_are_one_line_errors(targets, message):
    from fieldcal.procedure.positions import ProcedureError, parse_procedure

    text = load_procedure("field-18").text + f"targets: {targets}\n"
    with pytest.raises(ProcedureError) as caught:
        parse_procedure(text, "p.yaml")
    assert message in str(caught.value) and "\n" not in str(caught.value)


def test_a_planned_run_in_the_tui_shows_its_sigma_against_the_targets_and_equals_the_headless_run(
        planned, tmp_path):
    """Pilot: the plan panel is on the procedure screen, says nothing is determined at first and
    every target met at the end; the TUI's parameter file is the headless run's, byte for byte,
    and its session replays to the same bytes."""
    import asyncio

    from tui_pilot import until, waiting_at
    from fieldcal.tui import FieldcalApp
    from fieldcal.tui.widgets.plan import PlanPanel

    procedure = planned[0]
    spec = RunSpec(procedure, DEFAULT_STATION, seed=3)
    headless = run_headless(spec, tmp_path / "headless")

    async def body():
        app = FieldcalApp(spec, speed=0, session_dir=tmp_path / "tui")
        async with app.run_test(size=(100, 40)) as pilot:
            await until(pilot, lambda: waiting_at(app, 0))
            panel = app.screen.query_one(PlanPanel)
            first = str(panel.render())
            for step in range(len(procedure.positions)):
                await until(pilot, lambda step=step: waiting_at(app, step), timeout_s=120)
                await pilot.press("r")
            await until(pilot, lambda: app.outcome is not None, timeout_s=120)
            return app.outcome, first, [s for s in panel.tracker.standings()]

    outcome, first, final = asyncio.run(body())
    assert "left" in first and first.count("not yet determined") == len({t for t, _ in TARGETS})
    assert final and all(s.met or s.sigma <= 1.05 * s.target for s in final), final
    assert outcome.parameters.read_bytes() == headless.parameters.read_bytes()
    replayed = replay(open_run(outcome.session))
    pf = replayed.parameter_file
    assert dump(pf).encode() == recorded_parameters(open_run(outcome.session))


def test_the_simulators_window_means_have_the_covariance_the_bound_uses():
    """The plan optimises the errors the runs make only if the bound's noise is the simulator's:
    window means of drawn noise (bias instability included) are correlated across windows
    exactly as TriadNoise.window_covariance says, not as white noise would be. Drawn as the
    simulator draws (InnovationNoise, drivers/sim/physics.py), 300 independent copies of the
    gyroscope in one generator: the same 900 rows as 300 seeded generators of the bank, in a
    sixth of the CPU (0.5 s, not 2.9 s)."""
    from drivers.sim.device import PAPER_NOISE
    from drivers.sim.noise import InnovationNoise

    noise, rate, copies = PAPER_NOISE["gyroscope"], 5.0, 300
    starts, duration = np.array([0.0, 300.0, 900.0]), 200.0
    cells = (starts[:, None] * rate + np.arange(int(duration * rate))).astype(int)
    x = InnovationNoise([noise] * copies, rate, np.random.default_rng(0)).draw(int(1100 * rate))
    means = x[:, cells].mean(axis=2)  # (copies, windows, axes)
    means = np.concatenate(np.transpose(means, (2, 0, 1)))  # 900 independent (axis, copy) rows
    drawn = np.cov(means.T)
    model = noise.window_covariance(starts, np.full(3, duration))
    assert np.diag(drawn) == pytest.approx(np.diag(model), rel=0.15)
    corr = lambda c: c / np.sqrt(np.outer(np.diag(c), np.diag(c)))  # noqa: E731
    assert np.abs(corr(drawn) - corr(model)).max() < 0.1
    assert corr(model)[0, 1] > 0.2  # far from white: the bound must not treat the windows as independent


def test_no_design_in_a_third_of_field_18s_time_beats_the_best_bias_ratio_printed():
    """The best ratio `fieldcal plan` prints for a share of field-18's time is a bound: designs of
    that operator time or less (few positions, short dwells, one turn) never reach below it in
    crb.py's bound, and it grows as the time shrinks."""
    from fieldcal.planning.command import best_bias_ratios

    models = models_from_truth(paper_mimu())
    operator = OperatorModel()
    field = load_procedure("field-18")
    reference = Design(tuple(p.attitude for p in field.positions), field.dwell_s,
                       field.rate_step.rate_deg_s, field.rate_step.turns)
    ref_sigmas = bound_sigmas(reference, operator, models, DEFAULT_STATION, 250.0)
    ref_seconds = operator_time(reference, operator)
    third = best_bias_ratios(models, ref_sigmas, ref_seconds / 3)
    fifth = best_bias_ratios(models, ref_sigmas, ref_seconds / 5)
    whole = best_bias_ratios(models, ref_sigmas, ref_seconds)
    for name in models:
        assert whole[name] <= 1.0 + 1e-9 < third[name] < fifth[name]
    every = tuple(c.attitude for c in candidates())
    tried = 0
    for positions in (every, every[:6] + every[6:12:2]):
        for dwell in (10.0, 60.0):
            design = Design(positions, dwell, 20.0, 1)
            if operator_time(design, operator) > ref_seconds / 3:
                continue
            tried += 1
            sigmas = bound_sigmas(design, operator, models, DEFAULT_STATION, 250.0)
            for name in models:
                ratio = np.max(sigmas[name][:3] / ref_sigmas[name][:3])
                assert ratio >= third[name] * 0.99, (name, len(positions), dwell, ratio, third[name])
    assert tried >= 2


def test_a_margin_plans_every_bound_under_the_target_it_writes(tmp_path, capsys):
    """--margin: the written procedure's own bound (recomputed here from the file) is at least the
    margin under every target, and the targets written for the TUI are the unmargined ones."""
    out = tmp_path / "margin.yaml"
    target = ",".join(f"{t}.{g}={v:g}" for (t, g), v in TARGETS.items())
    assert main(["plan", "--config", "sim", "--target", target, "--margin", "0.2", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "20% under" in printed
    # The infeasibility of the 1/3 and its aim 1/5, said with numbers.
    assert "in 1/3 of field-18's time" in printed and "in 1/5 of field-18's time" in printed
    procedure = load_procedure(out)
    step = procedure.rate_step
    design = Design(tuple(p.attitude for p in procedure.positions), procedure.dwell_s,
                    step.rate_deg_s, step.turns)
    models = models_from_truth(paper_mimu())
    sigmas = bound_sigmas(design, OperatorModel(), models, DEFAULT_STATION, 250.0)
    written = {(t, p): s for t, p, s in procedure.targets}
    for (triad, group), sigma in TARGETS.items():
        model = models[triad]
        for j in GROUPS[group]:
            name = PARAM_NAMES[j]
            assert written[(triad, name)] == pytest.approx(sigma, rel=1e-3)
            shown = sigmas[triad][j] * display_scale(model.kind, model.output_unit, j)
            assert shown <= sigma / 1.2 * (1 + 1e-9), (triad, name, shown, sigma)


@pytest.mark.parametrize("margin", ["-0.1", "1", "nan"])
def test_a_bad_margin_is_a_one_line_error(tmp_path, capsys, margin):
    out = tmp_path / "p.yaml"
    assert main(["plan", "--config", "sim", "--target", "gyroscope.bias=1", "--margin", margin,
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "--margin" in err and len(err.splitlines()) == 1 and not out.exists()


def test_a_margin_that_only_a_longer_plan_meets_says_so_and_suggests_slack(tmp_path, capsys):
    """field-18's gyroscope bias σ is 0.389-0.397 °/h, under a 0.4 °/h target but not under it
    5% tightened (0.381 °/h); its span is what averages the bias instability, so nothing shorter
    reaches that either. The plan written is then longer than field-18, and the operator is told."""
    out = tmp_path / "m.yaml"
    assert main(["plan", "--config", "sim", "--target", "gyroscope.bias=0.4", "--margin", "0.05",
                 "--out", str(out)]) == 0
    captured = capsys.readouterr()
    said = [line for line in captured.err.splitlines() if line.startswith("no procedure shorter than field-18")]
    assert len(said) == 1, captured.err
    assert "with --margin" in said[0] and "--slack 0.05" in said[0]
    ratio = float(re.search(r"takes ([0-9.]+)× field-18's time", said[0]).group(1))
    printed = re.search(r"\(([0-9.]+)×\); written to", captured.out)
    assert ratio >= 1 and printed and float(printed.group(1)) == ratio
    assert load_procedure(out).positions  # the longer plan is still written, and loads


def test_a_planned_run_placed_in_a_shuffled_order_needs_no_ready_and_replays_byte_for_byte(planned, tmp_path):
    """The scripted operator places the positions in a seeded shuffled order: the engine takes
    each where it is, with no action at all from the operator; each step keeps its own position,
    and the session replays to the same parameter file, byte for byte."""
    from fieldcal.run.operators import placing_order

    procedure = planned[0]
    assert procedure.any_order and procedure.adaptive_dwell  # fieldcal plan's defaults
    script = OperatorScript(shuffle_seed=3)
    order = [procedure.positions[k].id for k in placing_order(procedure, 3)]
    assert order != sorted(order)
    events = []
    result = run_headless(RunSpec(procedure, DEFAULT_STATION, seed=8, script=script), tmp_path / "s", events.append)
    assert result.status == "completed" and not result.unit.failures
    assert [e.position_id for e in events if isinstance(e, ev.PositionRecognised)] == order
    assert [e.position_id for e in events if isinstance(e, ev.StepComplete)] == order
    assert not any(isinstance(e, ev.WrongOrientation) for e in events)
    record = open_run(result.session)
    assert list(record.documents("action")) == []
    assert all(r.position_id == procedure.positions[r.step].id for r in record.completed)
    replayed = replay(record)
    assert dump(replayed.parameter_file).encode() == recorded_parameters(open_run(result.session))


def test_the_time_to_go_is_within_ten_percent_of_the_remaining_sample_time_at_every_step(planned):
    """The terminal UI's time to go (RunView.remaining_s) and the headless log's, folded from a
    shuffled planned run's events, against the sample time the run actually still took: at each
    step's start and at each dwell's start. (The former estimate started 42 % high here.)"""
    import io

    from fieldcal.run.progress import printer
    from fieldcal.run.runner import headless_time_to_go
    from fieldcal.tui.view import RunView

    procedure = planned[0]
    spec = RunSpec(procedure, DEFAULT_STATION, seed=11, script=OperatorScript(shuffle_seed=5))
    view = RunView(procedure, placing_prior_s=headless_time_to_go(spec).placing_prior_s)
    log = io.StringIO()
    printed = printer(log, time_to_go=headless_time_to_go(spec))

    class Estimates(Subscriber):
        def __init__(self):
            self.rows, self.finish_t = [], None

        def event(self, e, run):
            view.apply(e)
            printed(e)
            if isinstance(e, (ev.StepStarted, ev.Still)):
                self.rows.append((e.t, view.remaining_s()))
            if isinstance(e, ev.ProcedureComplete):
                self.finish_t = e.t

    estimates = Estimates()
    outcome = Conductor(spec, SimulatedBench(spec), ScriptedOperator(spec.script, procedure), [estimates]).run()
    assert outcome.status == "completed" and estimates.finish_t is not None
    assert len(estimates.rows) == 2 * len(procedure.positions)
    for t, estimate in estimates.rows:
        assert estimate == pytest.approx(estimates.finish_t - t, rel=0.10), (t, estimate, estimates.finish_t - t)
    # The log's "≈N min to go" after each completed step but the last, to its rounding.
    said = re.findall(r"\[ *([0-9.]+) s\]   position \d+ done: ≈(\d+) (min|s) to go", log.getvalue())
    assert len(said) == len(procedure.positions) - 1
    for t, amount, unit in said:
        remaining = estimates.finish_t - float(t)
        assert float(amount) * (60 if unit == "min" else 1) == pytest.approx(remaining, rel=0.10, abs=30)


def test_in_the_tui_a_planned_run_placed_in_a_shuffled_order_needs_no_key_and_rings_at_each_step_end(
        planned, tmp_path):
    """Pilot, at 100× virtual real time: the simulator's hands place the unit in a shuffled order
    and no key is pressed from start to results; the station takes each position where it is,
    the tiles end all done, the bell rings once per completed step (each step end comes in its
    own update: 50 s of samples apart, updates every 10 s), and the parameter file is the
    headless run's of the same seed and script, byte for byte."""
    import asyncio

    from test_tui import VirtualClock, run_until
    from fieldcal.run.operators import placing_order
    from fieldcal.tui import FieldcalApp

    procedure = planned[0]
    script = OperatorScript(shuffle_seed=7)
    spec = RunSpec(procedure, DEFAULT_STATION, seed=4, script=script)
    headless = run_headless(spec, tmp_path / "headless")
    clock = VirtualClock()
    bells = []

    async def body():
        app = FieldcalApp(spec, speed=100, session_dir=tmp_path / "tui", clock=clock, hands=script)
        app.bell = lambda: bells.append(sum(isinstance(e, ev.StepComplete) for e in app.events))
        async with app.run_test(size=(100, 40)) as pilot:
            await run_until(pilot, clock, lambda: app.outcome is not None, step_s=0.05, timeout_s=240)
            return app, list(app.view.tiles)

    app, tiles = asyncio.run(body())
    order = [procedure.positions[k].id for k in placing_order(procedure, 7)]
    assert app.outcome.status == "completed" and tiles == ["done"] * len(procedure.positions)
    assert [e.position_id for e in app.events if isinstance(e, ev.PositionRecognised)] == order
    assert bells == list(range(1, len(procedure.positions) + 1))  # one ring at each step's end
    assert app.outcome.parameters.read_bytes() == headless.parameters.read_bytes()


def test_a_shuffled_planned_run_resumed_after_a_crash_matches_the_whole_run(planned, tmp_path):
    """Cut after its fourth step record, the session of a run placed in a shuffled order
    resumes (the engine waits for the unit to leave the last measured position, the operator
    goes on with its order) to the whole run's parameter file, byte for byte."""
    import shutil

    from test_headless import cut_before_step_record
    from fieldcal.run.runner import resume_headless

    spec = RunSpec(planned[0], DEFAULT_STATION, seed=12, script=OperatorScript(shuffle_seed=9))
    whole = run_headless(spec, tmp_path / "whole")
    crashed = tmp_path / "crashed"
    shutil.copytree(whole.session, crashed)
    cut_before_step_record(crashed, 4)
    resumed = resume_headless(open_run(crashed))
    assert resumed.parameters.read_bytes() == whole.parameters.read_bytes()
