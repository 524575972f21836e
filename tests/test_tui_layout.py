"""The terminal UI's layout: the results summary first, the screens at 60×18 (too small, said so)
and 120×40 (the room goes to the cube and the bars), and snapshots of the procedure and
results screens at 80×24 and 120×40 in states that hold no fitted number."""
from __future__ import annotations

import re

import pytest

from tui_pilot import log_settled, run_async, until, waiting_at
from fieldcal.earth import Station
from fieldcal.procedure.positions import parse_procedure
from fieldcal.run.runner import RunSpec
from fieldcal.tui import FieldcalApp
from fieldcal.tui.screens.results import ResultsScreen, position_list

try:
    import pytest_textual_snapshot  # noqa: F401
    HAVE_SNAPSHOTS = True
except ImportError:  # pragma: no cover
    HAVE_SNAPSHOTS = False

STATION = Station(40.0, 50.0)
THREE_WITH_TURNS = """\
name: three
title: three positions, 20 s dwells, one turn each way
dwell_s: 20
positions:
  - {id: 1, description: "z-upward, x-south, y-east", axes: {x: south, y: east, z: up}}
  - {id: 2, description: "z-upward, x-north, y-west", axes: {x: north, y: west, z: up}}
  - {id: 3, description: "z-downward, x-north, y-east", axes: {x: north, y: east, z: down}}
rate_step: {rate_deg_s: 10, turns: 1, ramp_s: 2, settle_s: 1}
"""








def three_app() -> FieldcalApp:
    spec = RunSpec(parse_procedure(THREE_WITH_TURNS, "three.yaml"), STATION, seed=3)
    return FieldcalApp(spec, speed=0, session_dir=None)


async def skip_the_second_and_finish(pilot, app) -> None:
    await until(pilot, lambda: waiting_at(app, 0))
    await pilot.press("r")
    await until(pilot, lambda: waiting_at(app, 1))
    await pilot.press("s", "y")
    await until(pilot, lambda: waiting_at(app, 2))
    await pilot.press("r")
    await until(pilot, lambda: isinstance(app.screen, ResultsScreen) and bool(app.screen.query("#verdicts")))
    await pilot.pause()


def test_positions_are_listed_with_ranges():
    assert position_list([2]) == "2" and position_list([1, 2]) == "1, 2"
    assert position_list([1, 4, 5, 6, 9]) == "1, 4–6, 9"


@run_async
async def test_the_results_say_the_verdicts_and_the_skipped_positions_first():
    app = three_app()
    async with app.run_test(size=(80, 24)) as pilot:
        await skip_the_second_and_finish(pilot, app)
        verdicts = app.screen.query_one("#verdicts")
        text = str(verdicts.render())
        assert "skipped: position 2" in text
        failures = app.outcome.unit.failures
        assert failures and not app.outcome.unit.solutions  # two positions calibrate nothing
        for name, why in failures.items():
            assert re.search(rf"^{name} +refused +{re.escape(why.removeprefix(name + ': ')[:20])}", text, re.M)
        assert verdicts.region.bottom <= 24 - 2  # on the first page, above the footer


@run_async
async def test_the_results_summary_of_a_solved_run_names_the_worst_residual(tmp_path):
    """field-18 (test_tui's golden-mini: 3 s dwells at 20 Hz): each triad solved, with its worst
    position's residual. The run headless, its results screen that of its replay: the same
    screen as at the end of the live run (FieldcalApp.show_results), without the 18 steps' keys
    and frames. (20 s dwells at 250 Hz, run and replayed, took 2.1 s of CPU for the same screen.)"""
    from fieldcal.run.runner import open_run, run_headless
    from fieldcal.tui.widgets.residuals import per_position
    from tests.test_tui import _golden_mini_spec

    run = run_headless(_golden_mini_spec(5), tmp_path / "session")
    app = FieldcalApp(None, speed=0, replay=open_run(run.session))
    async with app.run_test(size=(120, 40)) as pilot:
        await until(pilot, lambda: isinstance(app.screen, ResultsScreen) and bool(app.screen.query("#verdicts")))
        await pilot.pause()
        text = str(app.screen.query_one("#verdicts").render())
        bodies = list(app.screen.query(".triad-body"))
        assert bodies and all(b.has_class("wide") for b in bodies)  # residuals beside the table
        assert len({b.query_one(".residuals").region.x for b in bodies}) == 1
        assert all(b.query_one(".residuals").region.x > b.query_one(".table").region.right for b in bodies)
    assert set(app.outcome.unit.solutions) == {"accelerometer", "gyroscope", "inclinometer"}
    for name, sol in app.outcome.unit.solutions.items():
        rows, unit = per_position(sol)
        worst = max(rows, key=lambda r: abs(r[1]))[0]
        line = next(line for line in text.splitlines() if line.startswith(name))
        assert re.search(rf"{name} +solved +worst residual [0-9.e-]+ {re.escape(unit)} \({worst}\)", line)
        assert re.search(r"truth within [0-9.]+σ$", line)
    assert "skipped: none" in text


@run_async
async def test_below_80x24_the_screen_says_it_is_too_small_and_the_run_goes_on():
    app = three_app()
    async with app.run_test(size=(60, 18)) as pilot:
        await until(pilot, lambda: waiting_at(app, 0))
        notice = app.screen.query_one("#too-small")
        assert notice.display and "60×18" in str(notice.render()) and "80×24" in str(notice.render())
        assert notice.region.width == 60 and notice.region.height == 18  # over everything
        await pilot.press("r")
        await until(pilot, lambda: waiting_at(app, 1))
        await pilot.resize_terminal(80, 24)
        await pilot.pause()
        assert not app.screen.query_one("#too-small").display
        tiles = list(app.screen.query(".tile"))
        assert all(0 <= t.region.right <= 80 and t.region.height == 1 for t in tiles)


@run_async
async def test_at_120x40_the_cube_and_the_bars_grow():
    app = three_app()
    async with app.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: waiting_at(app, 0))
        small_cube = app.screen.query_one("#cube").region
        small_dwell = len(app.screen.query_one("#live-dwell").render().plain.split()[1])
        await pilot.resize_terminal(120, 40)
        await pilot.pause()
        await pilot.pause()
        big_cube = app.screen.query_one("#cube").region
        big_dwell = len(app.screen.query_one("#live-dwell").render().plain.split()[1])
        assert big_cube.height > small_cube.height and big_cube.width > small_cube.width
        assert big_dwell == 2 * small_dwell  # the dwell bar is twice as long
        assert app.screen.query_one("#live").region.height >= 16


def procedure_state(app):
    """Position 1 skipped, waiting for the unit in position 2: no sample fed yet, so nothing on
    screen depends on the floating point of the simulator or the solver."""
    async def run_before(pilot):
        await until(pilot, lambda: waiting_at(app, 0))
        await pilot.press("s", "y")
        await until(pilot, lambda: waiting_at(app, 1))
        await until(pilot, lambda: log_settled(app, "step 2/3"))
        await pilot.pause()
    return run_before


@pytest.mark.skipif(not HAVE_SNAPSHOTS, reason="pytest-textual-snapshot is not installed")
@pytest.mark.parametrize("size", [(80, 24), (120, 40)])
def test_snapshot_procedure_screen_sizes(snap_compare, size):
    app = three_app()
    assert snap_compare(app, terminal_size=size, run_before=procedure_state(app))


@pytest.mark.skipif(not HAVE_SNAPSHOTS, reason="pytest-textual-snapshot is not installed")
@pytest.mark.parametrize("size", [(80, 24), (120, 40)])
def test_snapshot_results_screen_sizes(snap_compare, size):
    """A run that calibrates nothing (two positions done, one skipped): verdicts, no fit."""
    app = three_app()

    async def run_before(pilot):
        await skip_the_second_and_finish(pilot, app)

    assert snap_compare(app, terminal_size=size, run_before=run_before)
