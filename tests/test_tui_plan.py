"""Issue 23 item 7: a planned procedure in the terminal UI (`fieldcal plan` writes up to 30
positions, described by the face that is down, and σ targets): every tile shows at 80 columns,
the banner names the heading, and the results say per triad whether the plan's target was met."""
from __future__ import annotations

import re

import numpy as np

from tui_pilot import run_async, until, waiting_at
from fieldcal.earth import Station
from fieldcal.procedure.positions import parse_procedure
from fieldcal.run.runner import RunSpec
from fieldcal.tui import FieldcalApp
from fieldcal.tui.widgets.tiles import tile_rows

STATION = Station(40.0, 50.0)


def planned_30(dwell_s: float = 5.0) -> str:
    """30 positions as `fieldcal plan` writes them: described only by the face up or down
    ("y-down"), the heading in the axes; a target each triad can meet and one it cannot."""
    lines = ["name: planned-30", "title: thirty positions as a plan writes them", f"dwell_s: {dwell_s}",
             "rate_step: {rate_deg_s: 20.0, turns: 1, ramp_s: 1.0, settle_s: 1.0}",
             "targets:", "  accelerometer: {bias_x: 5.0, bias_y: 5.0}", "  gyroscope: {scale_x: 1.0e-9}",
             "positions:"]
    others = {"x": "y", "y": "z", "z": "x"}
    i = 0
    for up in ("x", "y", "z", "-x", "-y", "-z"):
        axis = up.lstrip("-")
        for north in (others[axis], "-" + others[axis], others[others[axis]], "-" + others[others[axis]]):
            i += 1
            lines.append(f"  - {{id: {i}, description: {axis}-{'down' if up.startswith('-') else 'up'}, "
                         f"up: '{up}', north: '{north}'}}")
    for up in ("x+y+z", "-x+y+z", "x-y+z", "x+y-z", "-x-y+z", "-x+y-z"):
        i += 1
        lines.append(f"  - {{id: {i}, description: {up} corner, up: '{up}', north: x}}")
    return "\n".join(lines) + "\n"


def planned():
    return parse_procedure(planned_30(), "planned-30.yaml")


def test_tiles_take_one_row_while_they_fit_then_even_rows():
    assert tile_rows(18) == (18, False)  # field-18: 4 cells each, 72 columns
    assert tile_rows(24) == (24, True)  # 3 cells each, 72 columns
    assert tile_rows(30) == (15, False)  # two rows of 15 with gaps, 60 columns
    assert tile_rows(40) == (14, False)  # three rows


@run_async
async def test_thirty_tiles_show_at_80_columns_and_the_banner_names_the_heading(tmp_path):
    procedure = planned()
    assert len(procedure.positions) == 30
    app = FieldcalApp(RunSpec(procedure, STATION, seed=3), speed=0, session_dir=None)
    async with app.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: waiting_at(app, 0))
        await pilot.pause()
        tiles = list(app.screen.query(".tile"))
        assert len(tiles) == 30
        regions = [t.region for t in tiles]
        assert all(r.width > 0 and r.height == 1 and 0 <= r.x and r.right <= 80 for r in regions)
        assert len({(r.x, r.y) for r in regions}) == 30  # none hidden under another
        assert [str(t.render()) for t in tiles][-1] == "·30"
        # position 1 is "x-up" in the file; its y axis points north (the heading)
        first = procedure.positions[0]
        assert np.allclose(first.attitude[:, 1], [0, 1, 0])
        banner = str(app.screen.query_one("#banner").render())
        step = str(app.screen.query_one("#step").render())
        assert "north" in banner and "x must point up" in banner, banner
        assert step.startswith("step 1 of 30 · position 1: x-up (x-upward, y-north, z-west)"), step
        await pilot.press("q", "y")


def test_the_results_say_per_triad_whether_the_plans_target_was_met(tmp_path):
    from fieldcal.run.runner import run_headless
    from fieldcal.tui.screens.results import summary
    from fieldcal.units import display_scale

    outcome = run_headless(RunSpec(planned(), STATION, seed=3), tmp_path / "s")
    assert outcome.status == "completed"
    acc, gyro = outcome.unit.solutions["accelerometer"], outcome.unit.solutions["gyroscope"]
    # the independent check: a 5 mg bias target is far above what 30 positions give, 1e-9 far below
    acc_sigma_mg = acc.sigma[:2] * display_scale(acc.kind, acc.output_unit, 0)
    assert np.all(acc_sigma_mg < 5.0) and gyro.sigma[3] > 1e-9
    text = summary(outcome, [], []).plain
    assert re.search(r"^plan · accelerometer: ✓ target met \(worst: bias_[xy] σ [0-9.e-]+ of 5 mg\)$", text, re.M), text
    assert re.search(r"^plan · gyroscope: ✗ target not met \(worst: scale_x σ [0-9.e-]+ of 1e-09\)$", text, re.M), text
