"""Issue 15 items 6, 7 and 9 through the running UI (the folding itself: tests/test_tui_parts.py):
the whole job under the tiles, symbols on the tiles, the placement and the correction of a wrong
one said in the banner, in the operator's words, with the key to press; and, after an abort
mid-dwell, nothing on the live panel that still looks current."""
from __future__ import annotations

import re

from tui_pilot import ask, press_and_go_on, run_async, until, waiting_at
from fieldcal.earth import Station
from fieldcal.run.runner import RunSpec
from fieldcal.tui import FieldcalApp
from tests.test_tui import TWO_WITH_TURNS, VirtualClock, field18_short, on_results, run_until, two_positions

STATION = Station(40.0, 50.0)


def shown(app, selector: str) -> str:
    return str(app.screen.query_one(selector).render())


@run_async
async def test_the_job_the_tile_symbols_and_the_banners_instructions_on_screen():
    app = FieldcalApp(RunSpec(field18_short(), STATION, seed=6), speed=0, session_dir=None)
    async with app.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: waiting_at(app, 0))
        assert shown(app, "#banner").startswith("Position 1: place it z-upward, x-south, y-east; "
                                                "r: the simulator does it")
        await pilot.press("r")
        await until(pilot, lambda: waiting_at(app, 1))
        # Item 6: symbols as well as colours, and the whole job's time.
        tiles = [shown(app, f"#tile-{i}") for i in range(18)]
        assert tiles[:3] == ["✓ 1", "▶ 2", "· 3"] and all(t.startswith("·") for t in tiles[2:])
        job = shown(app, "#job")
        assert re.fullmatch(r"✓1 done  –0 skipped  ▶ now  ·16 to do   \d+:\d\d elapsed, ≈\d+ min to go", job)
        # Item 7: how to move it, the key to press, and the heading the check cannot see.
        banner = shown(app, "#banner")
        assert banner == ("Position 2: rotate it 180° about the vertical so that x points north; r: the "
                          "simulator does it\nOnly the heading changes, which the check cannot see: "
                          "check it by eye")
        await pilot.press("w")  # the simulator places it wrong, on purpose
        await until(pilot, lambda: app.telemetry.phase == "wrong")
        await until(pilot, lambda: shown(app, "#banner").startswith("WRONG POSITION"))
        wrong = shown(app, "#banner")
        assert re.fullmatch(r"WRONG POSITION: it looks like position \d+; [^;]+; r: the simulator corrects it",
                            wrong.replace("\n", " "))
        assert "(see the log)" not in wrong
        await pilot.press("r")
        await until(pilot, lambda: waiting_at(app, 2))  # corrected, measured: on to position 3
        assert shown(app, "#tile-1") == "✓ 2"
        assert shown(app, "#banner").startswith("Position 3: turn it over: z must point down, x north")
        await pilot.press("q", "y")


@run_async
async def test_after_an_abort_mid_dwell_the_panel_holds_nothing_that_looks_current(tmp_path):
    from fieldcal.tui.widgets.live import rows

    # 20x on a virtual clock (test_tui's): the run moves only as the test advances the clock, so
    # the abort lands mid-dwell however slow the machine is (in real time it idled 5 s of its 6).
    clock = VirtualClock()
    app = FieldcalApp(RunSpec(two_positions(tmp_path, TWO_WITH_TURNS), STATION, seed=2), speed=20,
                      session_dir=None, clock=clock)
    async with app.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: waiting_at(app, 0))
        await press_and_go_on(pilot, "r")
        await run_until(pilot, clock, lambda: app.telemetry.phase == "dwell", step_s=0.05)
        await ask(pilot, "a")
        await press_and_go_on(pilot, "a")
        await run_until(pilot, clock, lambda: on_results(app), step_s=0.05)
        await pilot.press("escape")  # back to the run (ended: the process goes idle)
        await until(pilot, lambda: not on_results(app))
        lines = {name: text.plain for name, text in rows(app.screen.view).items()}
        assert lines["dwell"].endswith("— (run aborted)") and "left" not in lines["dwell"]
        assert lines["still"].endswith("— (the run has ended)")
        assert lines["table"].endswith("stopped") and lines["turns"].endswith("—")
        assert shown(app, "#banner") == "Aborted: the session is kept"
