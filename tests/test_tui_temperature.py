"""The unit's temperature on the live panel (issue 28): where the device reports one, the latest
and the span seen so far, on the panel's bottom edge (every row still shown at 80×24); nothing
where it reports none."""
from __future__ import annotations

import numpy as np

from drivers.chunk import SampleChunk
from drivers.sim.thermal import SimThermal, TemperatureProfile, ThermalTruth
from fieldcal.earth import Station
from fieldcal.procedure.positions import parse_procedure
from fieldcal.run.runner import RunSpec
from fieldcal.tui import FieldcalApp
from fieldcal.tui.readings import RecentSamples, Telemetry
from fieldcal.tui.view import RunView
from fieldcal.tui.widgets.live import ROWS, temperature_text
from test_tui_layout import THREE_WITH_TURNS
from tui_pilot import run_async, until, waiting_at

STATION = Station(40.0, 50.0)


def _chunk(n: int, temperature=None) -> SampleChunk:
    return SampleChunk(t=np.arange(n) * 0.01, triads={"accelerometer": np.tile([0.0, 0.0, 9.8], (n, 1)),
                                                      "gyroscope": np.zeros((n, 3))},
                       temperature=None if temperature is None else np.asarray(temperature, float))


def test_the_span_is_every_temperature_seen_and_the_latest_the_last():
    spec = RunSpec(parse_procedure(THREE_WITH_TURNS, "three.yaml"), STATION, seed=3)
    recent = RecentSamples(spec.engine_settings())
    recent.add(_chunk(3))
    assert "temperature_c" not in recent.readings(None)  # a device that reports none: nothing said
    recent.add(_chunk(4, [21.0, 20.5, 22.0, 21.5]))
    recent.add(_chunk(2))  # a chunk without one changes nothing
    recent.add(_chunk(3, [23.0, np.nan, 22.8]))  # a NaN is no temperature
    readings = recent.readings(None)
    assert readings["temperature_c"] == 22.8 and readings["temperature_span_c"] == (20.5, 23.0)
    view = RunView(spec.procedure)
    view.set_telemetry(Telemetry(1.0, 0, "place", True, 12, **readings))
    assert temperature_text(view) == "22.8 °C · span 20.5 to 23.0 °C (2.5 K)"
    view.set_telemetry(Telemetry(1.0, 0, "place", True, 12))
    assert temperature_text(view) == ""


@run_async
async def test_a_warming_unit_shows_its_temperature_on_the_live_panel_at_80x24():
    # a chamber's ramp, 20 °C and 2 K/s: the unit warms through the first dwell
    thermal = SimThermal(TemperatureProfile("ramp", start_c=20.0, rise_k=10.0, rate_k_per_s=2.0),
                         {"accelerometer": ThermalTruth(25.0, np.zeros((1, 3)), np.zeros(3))})
    spec = RunSpec(parse_procedure(THREE_WITH_TURNS, "three.yaml"), STATION, seed=3, sim_thermal=thermal)
    app = FieldcalApp(spec, speed=0, session_dir=None)
    async with app.run_test(size=(80, 24)) as pilot:
        def warmed() -> bool:
            t = app.telemetry
            return t is not None and t.temperature_span_c is not None and t.temperature_span_c[1] > 21.0
        await until(pilot, lambda: waiting_at(app, 0))
        await pilot.press("r")
        await until(pilot, warmed)
        await pilot.pause()
        live = app.screen.query_one("#live")
        tel = app.telemetry
        subtitle = str(live.border_subtitle)
        low, high = tel.temperature_span_c
        assert low == 20.0  # the ramp's start: the first sample's temperature
        assert subtitle.endswith(f" °C · span 20.0 to {high:.1f} °C ({high - low:.1f} K)"), subtitle
        assert len(subtitle) + 4 <= live.region.width  # all of it on the edge
        for name in ROWS:  # and every row still there, within the panel
            row = app.screen.query_one(f"#live-{name}").region
            assert row.height == 1 and live.region.y < row.y < live.region.bottom - 1
