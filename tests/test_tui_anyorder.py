"""The terminal UI on a procedure taken in any order: positions gravity cannot tell apart are
asked about in the banner, and a digit key answers which one the unit is in (Pilot, virtual
wall clock: the run moves only when the test advances it)."""
from fieldcal.earth import Station
from fieldcal.procedure import events as ev
from fieldcal.procedure.positions import parse_procedure
from fieldcal.run.operators import OperatorScript
from fieldcal.run.runner import RunSpec, open_run
from fieldcal.run.replay import replay
from tui_pilot import run_async
from test_tui import VirtualClock, run_until

# Positions 1 and 2 differ by heading only (z up): gravity cannot tell them apart.
TWINS = """name: twins
dwell_s: 20
any_order: true
positions:
  - {id: 1, axes: {x: east, y: north, z: up}}
  - {id: 2, axes: {x: north, y: west, z: up}}
  - {id: 3, axes: {x: up, y: north, z: west}}
"""


@run_async
async def test_the_banner_asks_which_of_two_alike_positions_and_a_digit_answers(tmp_path):
    from fieldcal.tui import FieldcalApp

    spec = RunSpec(parse_procedure(TWINS, "twins.yaml"), Station(latitude_deg=45.0, height_m=0.0), seed=2)
    clock = VirtualClock()
    app = FieldcalApp(spec, speed=10, session_dir=tmp_path / "tui", clock=clock, hands=OperatorScript())
    async with app.run_test(size=(100, 40)) as pilot:
        await run_until(pilot, clock, lambda: bool(app.view.alike), step_s=0.05)
        banner = app.view.banner(sim=True)[0]
        assert "Positions 1, 2 look the same to gravity; taken as position 1" in banner and "2: position 2" in banner
        await pilot.press("2")
        await run_until(pilot, clock, lambda: any(isinstance(e, ev.PositionRecognised) and e.chosen
                                                  for e in app.events), step_s=0.05)
        assert not app.view.alike and "look the same" not in app.view.banner(sim=True)[0]
        await run_until(pilot, clock, lambda: app.outcome is not None, step_s=1.0)
    completed = [(e.step, e.position_id) for e in app.events if isinstance(e, ev.StepComplete)]
    assert completed[0] == (1, 2) and sorted(completed) == [(0, 1), (1, 2), (2, 3)]
    record = open_run(app.outcome.session)
    assert [d.get("data", d).get("action") for d in record.documents("action")] == ["choose"]
    # The choice replays: the same steps of the same positions (replay checks every step's
    # averages against the session's; three positions solve nothing, so there is no file).
    events = []
    replayed = replay(record, report=events.append)
    assert [(e.step, e.position_id) for e in events if isinstance(e, ev.StepComplete)] == completed
    assert replayed.status == "completed" and replayed.parameter_file is None
