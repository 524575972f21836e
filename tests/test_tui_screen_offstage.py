"""The procedure screen fed while its widgets are not there: before it is mounted, and once the
app is closing (a run's last messages can still arrive then: under load CI saw one raise
NoMatches for PositionTiles at exit). The view takes every item either way, and the log lines
are shown when the screen mounts."""
from __future__ import annotations

from fieldcal.earth import Station
from fieldcal.procedure import events as ev
from fieldcal.procedure.positions import parse_procedure
from fieldcal.tui.readings import Telemetry
from fieldcal.tui.screens.procedure import ProcedureScreen
from fieldcal.tui.view import RunView
from test_tui_layout import THREE_WITH_TURNS

STATION = Station(40.0, 50.0)


def test_items_readings_and_the_end_reach_the_view_of_a_screen_not_on_show():
    procedure = parse_procedure(THREE_WITH_TURNS, "three.yaml")
    view = RunView(procedure)
    screen = ProcedureScreen(view, "three", "sim")  # never mounted: no widgets, no app
    started = ev.StepStarted(0.0, 1, procedure.positions[1].id, "x", len(procedure.positions))
    screen.add_items((started,), Telemetry(2.0, 1, "settling", False, 40))
    screen.set_telemetry(Telemetry(3.0, 1, "dwell", False, 60))
    screen.finished("stopped")
    assert view.step == 1 and view.telemetry.t == 3.0 and view.finished == "stopped"
    # what the log will show once mounted is kept, in order
    line = RunView(procedure).apply(started)
    assert screen._unfed == [started] and screen._unshown == ([] if line is None else [line])
