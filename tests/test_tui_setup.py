"""The setup screen of ``fieldcal tui`` (driven with Textual's Pilot) and the remembered choice."""
from __future__ import annotations

import itertools
from pathlib import Path

import pytest
import yaml
from textual.app import App
from textual.geometry import Region
from textual.widgets import Footer, Input, Select, Static

from tui_pilot import run_async, until
from fieldcal.config import CONFIGS_DIR, load_config
from fieldcal.tui.choices import (
    SetupChoice,
    available_configs,
    available_procedures,
    last_choice_path,
    load_last_choice,
    resolve_choice,
    save_last_choice,
)
from fieldcal.tui.screens.setup import SetupScreen

try:
    import pytest_textual_snapshot  # noqa: F401
    HAVE_SNAPSHOTS = True
except ImportError:  # pragma: no cover
    HAVE_SNAPSHOTS = False

SIZE = (80, 24)


class Host(App):
    """Pushes a SetupScreen and collects what it dismisses with."""

    def __init__(self, initial: SetupChoice | None = None) -> None:
        super().__init__()
        self.initial = initial
        self.results: list = []
        self.setup: SetupScreen | None = None

    def on_mount(self) -> None:
        self.setup = SetupScreen(self.initial)
        self.push_screen(self.setup, self.results.append)


@pytest.fixture(autouse=True)
def xdg(tmp_path, monkeypatch):
    """Every test remembers its choices under its own XDG_CONFIG_HOME."""
    home = tmp_path / "xdg"
    monkeypatch.setenv("XDG_CONFIG_HOME", str(home))
    return home


def text_of(screen, selector: str) -> str:
    return str(screen.query_one(selector, Static).render())


def value_of(screen, selector: str) -> str:
    return screen.query_one(selector, Input).value


async def type_into(pilot, screen, selector: str, text: str) -> None:
    field = screen.query_one(selector, Input)
    field.focus()
    field.value = ""
    await pilot.press(*text)


async def paste_into(pilot, screen, selector: str, text: str) -> None:
    """A long path, as if pasted (a key press costs the Pilot some 80 ms)."""
    field = screen.query_one(selector, Input)
    field.focus()
    field.value = text
    await pilot.pause()


async def choose(pilot, screen, selector: str, value: str) -> None:
    """Choose in a Select as the operator does: open it, type to search, Enter."""
    select = screen.query_one(selector, Select)
    select.focus()
    await pilot.press("enter")
    await pilot.press(*value)
    await pilot.press("enter")
    await until(pilot, lambda: select.value == value)


# --- the remembered choice -----------------------------------------------------------------


def test_the_remembered_choice_lives_under_xdg_config_home(xdg, monkeypatch, tmp_path):
    assert last_choice_path() == xdg / "fieldcal" / "last-setup.yaml"
    monkeypatch.setenv("XDG_CONFIG_HOME", "relative/dir")  # ignored, as the XDG spec says
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert last_choice_path() == tmp_path / "home" / ".config" / "fieldcal" / "last-setup.yaml"
    monkeypatch.delenv("XDG_CONFIG_HOME")
    assert last_choice_path() == tmp_path / "home" / ".config" / "fieldcal" / "last-setup.yaml"


def test_a_saved_choice_reads_back_and_the_write_is_atomic(xdg):
    assert load_last_choice() is None  # nothing remembered yet
    choice = SetupChoice("vn100", "socket://127.0.0.1:4001", "classic-12", -33.9, 12.5)
    path = save_last_choice(choice)
    assert path == xdg / "fieldcal" / "last-setup.yaml"
    assert load_last_choice() == choice
    assert [p.name for p in path.parent.iterdir()] == ["last-setup.yaml"]  # no temporary left
    save_last_choice(SetupChoice("sim", None, "field-18", 40.0, 50.0))
    assert load_last_choice() == SetupChoice("sim", None, "field-18", 40.0, 50.0)


@pytest.mark.parametrize("content", [
    b"config: [unclosed\n",  # not YAML
    b"\xff\xfe not text",  # not UTF-8
    b"- just\n- a list\n",
    b"config: sim\nport: null\nprocedure: field-18\nlatitude_deg: 45\n",  # height missing
    b"config: sim\nport: null\nprocedure: field-18\nlatitude_deg: north\nheight_m: 1\n",
    b"config: sim\nport: null\nprocedure: field-18\nlatitude_deg: 123\nheight_m: 1\n",
    b"config: sim\nport: 7\nprocedure: field-18\nlatitude_deg: 45\nheight_m: 1\n",
    b"config: ''\nport: null\nprocedure: field-18\nlatitude_deg: 45\nheight_m: 1\n",
    b"config: sim\nport: null\nprocedure: field-18\nlatitude_deg: .nan\nheight_m: 1\n",
    b"config: sim\nport: null\nprocedure: field-18\nlatitude_deg: true\nheight_m: 1\n",
    b"",
])
def test_a_damaged_last_setup_file_is_ignored(xdg, content):
    path = xdg / "fieldcal" / "last-setup.yaml"
    path.parent.mkdir(parents=True)
    path.write_bytes(content)
    assert load_last_choice() is None


def test_an_unreadable_last_setup_file_is_ignored(xdg):
    (xdg / "fieldcal" / "last-setup.yaml").mkdir(parents=True)  # a directory where the file goes
    assert load_last_choice() is None


def test_the_shipped_configs_and_procedures_are_offered():
    assert {"sim", "vn100", "mti"} <= set(available_configs())
    assert {"field-18", "classic-12", "allan"} <= set(available_procedures())


# --- resolve_choice ---------------------------------------------------------------------------


def test_resolve_applies_the_port_override_and_the_station():
    config, procedure = resolve_choice(SetupChoice("vn100", "socket://127.0.0.1:4001", "classic-12", 45.5, 120.0))
    assert config.device.port.url == "socket://127.0.0.1:4001"
    assert config.device.port.baudrate == 115200  # only the URL is overridden
    assert (config.station.latitude_deg, config.station.height_m) == (45.5, 120.0)
    assert procedure.name == "classic-12"
    config, _ = resolve_choice(SetupChoice("vn100", None, "field-18", 40.0, 50.0))
    assert config.device.port.url.startswith("/dev/serial/by-id/")


@pytest.mark.parametrize("choice, words", [
    (SetupChoice("nonesuch", None, "field-18", 40, 50), ("config", "nonesuch", "sim")),
    (SetupChoice("sim", None, "nonesuch", 40, 50), ("procedure", "nonesuch", "field-18")),
    (SetupChoice("sim", None, "field-18", 123, 50), ("latitude", "-90", "90", "123")),
    (SetupChoice("sim", None, "field-18", float("nan"), 50), ("latitude", "nan")),
    (SetupChoice("sim", None, "field-18", 40, 12000), ("height", "-500", "9000", "12000")),
    (SetupChoice("sim", "/dev/ttyUSB0", "field-18", 40, 50), ("port", "simulated")),
    (SetupChoice("vn100", "/dev/tty USB0", "field-18", 40, 50), ("port", "URL")),
])
def test_resolve_rejects_a_bad_choice_in_one_line(choice, words):
    with pytest.raises(ValueError) as info:
        resolve_choice(choice)
    message = str(info.value)
    assert "\n" not in message
    for word in words:
        assert word in message


def test_resolve_names_the_file_of_a_bad_config_or_procedure(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("device: {name: x}\n")
    with pytest.raises(ValueError, match=r"^config: .*bad\.yaml"):
        resolve_choice(SetupChoice(str(bad), None, "field-18", 40, 50))
    with pytest.raises(ValueError, match=r"^procedure: .*bad\.yaml"):
        resolve_choice(SetupChoice("sim", None, str(bad), 40, 50))


# --- the screen -----------------------------------------------------------------------------


@run_async
async def test_start_returns_the_choice_remembers_it_and_the_next_screen_shows_it(xdg):
    app = Host(SetupChoice("vn100", None, "classic-12", 10.0, 0.0))
    async with app.run_test(size=SIZE) as pilot:
        screen = app.setup
        await choose(pilot, screen, "#config", "sim")
        await until(pilot, lambda: value_of(screen, "#port") == "simulated")
        assert screen.query_one("#port", Input).disabled
        await choose(pilot, screen, "#procedure", "field-18")
        await type_into(pilot, screen, "#latitude", "45.5")
        await type_into(pilot, screen, "#height", "120")
        await pilot.click("#start")
        await until(pilot, lambda: app.results)
    expected = SetupChoice("sim", None, "field-18", 45.5, 120.0)
    assert app.results == [expected]
    path = xdg / "fieldcal" / "last-setup.yaml"
    assert yaml.safe_load(path.read_text()) == {"config": "sim", "port": None, "table_port": None,
                                                 "procedure": "field-18", "latitude_deg": 45.5,
                                                 "height_m": 120.0}

    again = Host(load_last_choice())
    async with again.run_test(size=SIZE) as pilot:
        screen = again.setup
        await pilot.pause()
        assert screen.query_one("#config", Select).value == "sim"
        assert screen.query_one("#procedure", Select).value == "field-18"
        assert value_of(screen, "#latitude") == "45.5"
        assert value_of(screen, "#height") == "120"  # not the config's 40° / 50 m
        assert value_of(screen, "#port") == "simulated"
        await pilot.press("ctrl+s")
        await until(pilot, lambda: again.results)
    assert again.results == [expected]


@run_async
async def test_a_bad_latitude_is_named_with_its_range_and_the_screen_stays(xdg):
    app = Host()
    async with app.run_test(size=SIZE) as pilot:
        screen = app.setup
        await pilot.pause()
        assert value_of(screen, "#latitude") == "40"  # the sim config's station
        await type_into(pilot, screen, "#latitude", "123")
        await pilot.press("ctrl+s")
        await until(pilot, lambda: text_of(screen, "#error") != "")
        error = text_of(screen, "#error")
        assert "latitude" in error and "-90" in error and "90°" in error and "123" in error
        assert screen.query_one("#error").display
        assert app.screen is screen and app.results == []
        # a number that does not parse is named too
        await type_into(pilot, screen, "#latitude", "45")
        assert text_of(screen, "#error") == "" or not screen.query_one("#error").display
        await type_into(pilot, screen, "#height", "-")
        await pilot.press("ctrl+s")
        await until(pilot, lambda: "height" in text_of(screen, "#error"))
        assert app.screen is screen and app.results == []
        await type_into(pilot, screen, "#height", "9001")
        await pilot.press("ctrl+s")
        await until(pilot, lambda: "9000" in text_of(screen, "#error"))
        assert app.screen is screen and app.results == []
    assert not (xdg / "fieldcal" / "last-setup.yaml").exists()  # nothing remembered


@run_async
async def test_choosing_vn100_prefills_its_port_and_station_and_an_override_reaches_the_config(xdg):
    vn100 = load_config("vn100")
    app = Host(SetupChoice("sim", None, "field-18", 45.5, 120.0))
    async with app.run_test(size=SIZE) as pilot:
        screen = app.setup
        await pilot.pause()
        assert "simulated MIMU" in text_of(screen, "#config-summary")
        await choose(pilot, screen, "#config", "vn100")
        await until(pilot, lambda: "VectorNav" in text_of(screen, "#config-summary"))
        summary = text_of(screen, "#config-summary")
        assert "VectorNav VN-100" in summary and "vectornav" in summary and "200 Hz" in summary
        assert "table grbl" in summary
        port = screen.query_one("#port", Input)
        assert not port.disabled
        assert port.value == vn100.device.port.url
        assert (float(value_of(screen, "#latitude")), float(value_of(screen, "#height"))) == \
            (vn100.station.latitude_deg, vn100.station.height_m) != (45.5, 120.0)
        await paste_into(pilot, screen, "#port", "socket://127.0.0.1:4001")
        await pilot.press("ctrl+s")
        await until(pilot, lambda: app.results)
        config, procedure = screen.resolved
    assert app.results == [SetupChoice("vn100", "socket://127.0.0.1:4001", "field-18",
                                       vn100.station.latitude_deg, vn100.station.height_m)]
    assert config.device.port.url == "socket://127.0.0.1:4001"
    assert config.device.port.baudrate == vn100.device.port.baudrate
    assert procedure.name == "field-18"
    assert load_last_choice() == app.results[0]


@run_async
async def test_the_configs_own_port_is_no_override_and_numbers_keep_every_digit(xdg):
    initial = SetupChoice("vn100", None, "field-18", 45.123456789, -12.25)
    app = Host(initial)
    async with app.run_test(size=SIZE) as pilot:
        await pilot.pause()
        assert value_of(app.setup, "#latitude") == "45.123456789"
        await pilot.press("ctrl+s")
        await until(pilot, lambda: app.results)
    assert app.results == [initial]


@run_async
async def test_a_config_path_is_loaded_and_a_list_choice_replaces_it(xdg, tmp_path):
    path = tmp_path / "bench.yaml"
    path.write_text((CONFIGS_DIR / "mti.yaml").read_text().replace("latitude_deg: 40.0", "latitude_deg: 61.5")
                    .replace("name: Xsens MTi", "name: Bench MTi"))
    app = Host()
    async with app.run_test(size=SIZE) as pilot:
        screen = app.setup
        await paste_into(pilot, screen, "#config-path", str(tmp_path / "nope.yaml"))
        await until(pilot, lambda: "nope.yaml" in text_of(screen, "#config-summary"))
        assert screen.query_one("#config-summary").has_class("bad")
        await pilot.press("ctrl+s")
        await until(pilot, lambda: text_of(screen, "#error").startswith("config:"))
        await paste_into(pilot, screen, "#config-path", str(path))
        await until(pilot, lambda: "Bench MTi" in text_of(screen, "#config-summary"))
        assert value_of(screen, "#latitude") == "61.5"
        assert value_of(screen, "#port") == "/dev/ttyUSB0"
        await choose(pilot, screen, "#config", "mti")
        await until(pilot, lambda: value_of(screen, "#config-path") == "")
        await until(pilot, lambda: "Xsens MTi" in text_of(screen, "#config-summary"))
        assert value_of(screen, "#latitude") == "40"
        await paste_into(pilot, screen, "#config-path", str(path))
        await until(pilot, lambda: "Bench MTi" in text_of(screen, "#config-summary"))
        await pilot.press("ctrl+s")
        await until(pilot, lambda: app.results)
    assert app.results == [SetupChoice(str(path.resolve()), None, "field-18", 61.5, 50.0)]


@run_async
async def test_an_initial_config_path_stays_in_the_path_field(xdg, tmp_path):
    path = tmp_path / "bench.yaml"
    path.write_text((CONFIGS_DIR / "mti.yaml").read_text().replace("name: Xsens MTi", "name: Bench MTi"))
    initial = SetupChoice(str(path), "socket://127.0.0.1:4001", "field-18", 12.0, 3.0)
    app = Host(initial)
    async with app.run_test(size=SIZE) as pilot:
        screen = app.setup
        await pilot.pause()
        await pilot.pause()
        assert value_of(screen, "#config-path") == str(path)
        assert "Bench MTi" in text_of(screen, "#config-summary")
        assert value_of(screen, "#port") == "socket://127.0.0.1:4001"
        await pilot.press("ctrl+s")
        await until(pilot, lambda: app.results)
    assert app.results == [initial]


@run_async
async def test_escape_and_q_quit_but_q_in_a_field_is_typed(xdg):
    app = Host()
    async with app.run_test(size=SIZE) as pilot:
        screen = app.setup
        await type_into(pilot, screen, "#config-path", "q")
        assert value_of(screen, "#config-path") == "q" and app.results == []
        screen.query_one("#procedure").focus()  # (the Start button takes no focus: Enter cannot start)
        await pilot.press("q")
        await until(pilot, lambda: app.results)
    assert app.results == [None]
    app = Host()
    async with app.run_test(size=SIZE) as pilot:
        await pilot.pause()
        await pilot.press("escape")
        await until(pilot, lambda: app.results)
    assert app.results == [None]
    assert not (Path(last_choice_path())).exists()


@pytest.mark.parametrize("long_path", [False, True])
@run_async
async def test_every_widget_fits_an_80x24_screen_even_with_an_error(xdg, tmp_path, long_path):
    app = Host(SetupChoice("vn100", None, "field-18", 40.0, 50.0))
    async with app.run_test(size=SIZE) as pilot:
        screen = app.setup
        if long_path:  # two-line messages in the summary and the error line
            await paste_into(pilot, screen, "#config-path", str(tmp_path / ("x" * 70) / "nope.yaml"))
        else:
            await type_into(pilot, screen, "#height", "99999")
        await pilot.press("ctrl+s")
        await until(pilot, lambda: text_of(screen, "#error") != "")
        await pilot.pause()
        if long_path:
            assert screen.query_one("#config-summary").region.height == 2
            error = screen.query_one("#error")  # the whole line, wrapped, not cut
            assert error.region.height == -(-len(text_of(screen, "#error")) // (SIZE[0] - 2)) == 3
        whole = Region(0, 0, *SIZE)
        shown = [w for w in screen.query("*") if w.display and w.region.area]
        names = {w.id for w in shown}
        assert {"config", "config-path", "config-summary", "port", "procedure", "procedure-summary",
                "latitude", "height", "error", "start"} <= names
        for widget in shown:
            assert whole.contains_region(widget.region), widget
        # nothing overlaps: the rows are stacked top to bottom, and the footer stays below them
        rows = [screen.query_one(f"#{i}").region for i in ("config", "port", "procedure", "latitude", "error",
                                                            "start")]
        assert all(a.bottom <= b.y for a, b in itertools.pairwise(rows))
        assert rows[-1].bottom <= screen.query_one(Footer).region.y


@pytest.mark.skipif(not HAVE_SNAPSHOTS, reason="pytest-textual-snapshot is not installed")
def test_snapshot_setup_screen(snap_compare, monkeypatch):
    from types import SimpleNamespace

    from serial.tools import list_ports

    # The ports of the machine the test runs on must not show: two made-up ones instead.
    monkeypatch.setattr(list_ports, "comports", lambda: [
        SimpleNamespace(device="/dev/ttyUSB0", description="FT232R USB UART"),
        SimpleNamespace(device="/dev/ttyACM0", description="Arduino Uno")])
    app = Host(SetupChoice("vn100", None, "field-18", 40.0, 50.0))

    async def with_an_error(pilot):
        await until(pilot, lambda: app.setup is not None and app.setup.is_mounted)
        await type_into(pilot, app.setup, "#latitude", "123")
        await paste_into(pilot, app.setup, "#unit-serial", "SN-0001")  # (not the shipped config's)
        await paste_into(pilot, app.setup, "#operator", "AB")
        await pilot.press("ctrl+s")
        await until(pilot, lambda: text_of(app.setup, "#error") != "")
        # The focused field's cursor blinks every 0.5 s of the wall clock: on a loaded machine the
        # picture was taken in either phase (a failed make test, 2026-11-27). A steady cursor
        # shows it always.
        for field in app.setup.query(Input):
            field.cursor_blink = False
        await pilot.pause()

    assert snap_compare(app, terminal_size=SIZE, run_before=with_an_error)


def test_a_table_port_override_reaches_the_config_and_old_files_without_one_still_load(xdg):
    config, _ = resolve_choice(SetupChoice("vn100", None, "field-18", 40.0, 50.0, table_port="/dev/ttyACM7"))
    assert config.table.port.url == "/dev/ttyACM7"
    assert config.table.port.baudrate == load_config("vn100").table.port.baudrate
    with pytest.raises(ValueError, match="^table port: .* simulated table"):
        resolve_choice(SetupChoice("sim", None, "field-18", 40.0, 50.0, table_port="/dev/ttyACM7"))
    path = last_choice_path()
    path.parent.mkdir(parents=True)
    path.write_text("config: vn100\nport: null\nprocedure: field-18\nlatitude_deg: 40\nheight_m: 50\n")
    assert load_last_choice() == SetupChoice("vn100", None, "field-18", 40.0, 50.0, None)


@run_async
async def test_both_ports_are_shown_and_a_port_that_cannot_open_is_named_before_any_session(xdg, tmp_path):
    """A VN-100 whose IMU port opens (a pty) and whose table port does not: one line on the
    setup screen names the table's port and why; the output directory stays empty."""
    import os

    from fieldcal.cli.main import build_parser
    from fieldcal.cli.tui import run_maker
    from fieldcal.tui import FieldcalApp

    leader, follower = os.openpty()
    try:
        imu = os.ttyname(follower)
        out = tmp_path / "sessions"
        args = build_parser().parse_args(["tui", "--out", str(out)])
        missing = str(tmp_path / "no-such-table")
        app = FieldcalApp(setup=(SetupChoice("vn100", imu, "field-18", 40.0, 50.0, table_port=missing),
                                 run_maker(args)))
        async with app.run_test(size=SIZE) as pilot:
            screen = app.screen
            assert isinstance(screen, SetupScreen)
            assert value_of(screen, "#port") == imu and value_of(screen, "#table-port") == missing
            assert text_of(screen, "#ports").startswith("serial ports here: ")
            await pilot.press("ctrl+s")
            await until(pilot, lambda: text_of(app.screen, "#error") != "")
            assert text_of(app.screen, "#error") == \
                f"table port {missing}: cannot open it: No such file or directory"
            await paste_into(pilot, app.screen, "#port", str(tmp_path / "no-imu"))
            await pilot.press("ctrl+s")
            await until(pilot, lambda: text_of(app.screen, "#error").startswith("IMU port"))
            assert text_of(app.screen, "#error") == \
                f"IMU port {tmp_path / 'no-imu'}: cannot open it: No such file or directory"
        assert not out.exists() or not any(out.iterdir())  # no empty session directory
    finally:
        os.close(leader)
        os.close(follower)


def test_the_serial_ports_line_gives_usb_descriptions(monkeypatch):
    from types import SimpleNamespace

    from serial.tools import list_ports

    from fieldcal.tui.screens.setup import serial_ports_text

    found = [SimpleNamespace(device="/dev/ttyUSB0", description="FT232R USB UART"),
             SimpleNamespace(device="/dev/ttyACM0", description="n/a")]
    monkeypatch.setattr(list_ports, "comports", lambda: found)
    assert serial_ports_text() == "serial ports here: /dev/ttyACM0, /dev/ttyUSB0 (FT232R USB UART)"
    monkeypatch.setattr(list_ports, "comports", lambda: [])
    assert serial_ports_text() == "serial ports here: none found"


# --- issue 23: Enter moves on, ctrl+s starts; operator, unit serial, sessions, spec, duration ---


@run_async
async def test_enter_in_a_field_moves_to_the_next_field_and_never_starts(xdg):
    app = Host(SetupChoice("sim", None, "field-18", 40.0, 50.0))
    async with app.run_test(size=SIZE) as pilot:
        screen = app.setup
        await type_into(pilot, screen, "#latitude", "45")
        await pilot.press("enter")
        assert screen.focused is screen.query_one("#height")
        await type_into(pilot, screen, "#operator", "AB")
        await pilot.press("enter")
        assert screen.focused is screen.query_one("#unit-serial")
        await pilot.press(*"SN-7", "enter", "enter", "enter", "enter")  # past the last field, round again
        assert app.results == [] and app.screen is screen  # nothing started
        assert screen.focused is not None and screen.focused.id != "start"
        await pilot.press("ctrl+s")
        await until(pilot, lambda: app.results)
    assert app.results == [SetupChoice("sim", None, "field-18", 45.0, 50.0, operator="AB", unit_serial="SN-7",
                                       out=None, spec=None)]
    config, _ = screen.resolved
    assert config.device.serial == "SN-7"  # the config's device.serial, as --unit-serial sets it
    remembered = yaml.safe_load((xdg / "fieldcal" / "last-setup.yaml").read_text())
    assert remembered["operator"] == "AB" and "unit_serial" not in remembered  # the next unit is another


@run_async
async def test_a_bad_spec_or_operator_is_one_line_and_nothing_starts(xdg, tmp_path):
    app = Host(SetupChoice("sim", None, "field-18", 40.0, 50.0))
    async with app.run_test(size=SIZE) as pilot:
        screen = app.setup
        await paste_into(pilot, screen, "#spec", str(tmp_path / "none.yaml"))
        await pilot.press("ctrl+s")
        await until(pilot, lambda: text_of(screen, "#error") != "")
        assert text_of(screen, "#error").startswith(f"spec: {tmp_path / 'none.yaml'}")
        await paste_into(pilot, screen, "#spec", "")
        await paste_into(pilot, screen, "#operator", "x" * 200)
        await pilot.press("ctrl+s")
        await until(pilot, lambda: text_of(screen, "#error").startswith("operator: expected a name"))
        assert app.results == []


def test_the_whole_jobs_duration_is_its_positions_steps():
    from fieldcal.procedure.positions import load_procedure
    from fieldcal.tui.screens.setup import duration_summary

    field18 = load_procedure("field-18")  # 18 positions, 200 s dwells, ±10 °/s for 1 turn, 2 s ramp, 1 s settle
    step = 30 + 200 + 2 * (2 + 1 + 360 / 10)  # placing (the run's first guess), dwell, each way's turn
    assert 18 * step == 5544  # 1 h 32 min
    assert duration_summary(field18) == ("whole job ≈ 1 h 32 min: 18 × (≈30 s placing + 200 s dwell + "
                                         "2 × 39 s turning)")


@run_async
async def test_the_setup_fields_reach_the_run(xdg, tmp_path):
    from fieldcal.cli.main import build_parser
    from fieldcal.cli.tui import run_maker
    from fieldcal.tui import FieldcalApp
    from fieldcal.tui.screens.procedure import ProcedureScreen

    args = build_parser().parse_args(["tui", "--out", str(tmp_path / "default-out")])
    spec_file = sorted(Path("configs/specs").glob("*.yaml"))[0]
    app = FieldcalApp(setup=(SetupChoice("sim", None, "classic-12", 40.0, 50.0, spec=str(spec_file)),
                             run_maker(args)))
    async with app.run_test(size=SIZE) as pilot:
        screen = app.screen
        assert value_of(screen, "#spec") == str(spec_file)
        await type_into(pilot, screen, "#operator", "AB")
        await paste_into(pilot, screen, "#out", str(tmp_path / "here"))
        await pilot.press("ctrl+s")
        await until(pilot, lambda: isinstance(app.screen, ProcedureScreen))
        assert app.spec.operator == "AB"
        assert app.product_spec is not None and app.product_spec.path == str(spec_file)
        assert app.source.session_dir.parent == tmp_path / "here"
        await pilot.press("q", "y")
    assert app.source.done.wait(60.0)


def test_a_live_session_is_resumed_on_its_own_devices_config():
    import dataclasses

    from fieldcal.run.livedevice import LiveDevice
    from fieldcal.tui.choices import config_for_session

    recorded = dataclasses.replace(LiveDevice.from_config(load_config("vn100")), serial="SN-9", url="/dev/ttyUSB3")
    config = config_for_session(recorded, load_config("sim"))  # the setup still shows the simulator
    assert (config.device.name, config.device.serial, config.device.port.url) == \
        ("VectorNav VN-100", "SN-9", "/dev/ttyUSB3")
    chosen = load_config("vn100")  # chosen above: its ports are the operator's
    assert config_for_session(recorded, chosen).device.port.url == chosen.device.port.url
    unknown = dataclasses.replace(recorded, name="bench MTi", protocol="xsens")
    with pytest.raises(ValueError) as refused:
        config_for_session(unknown, load_config("sim"))
    assert "bench MTi (xsens)" in str(refused.value) and len(str(refused.value)) <= 3 * 78


def test_the_command_lines_operator_spec_and_sessions_directory_fill_the_setup(xdg, tmp_path):
    from fieldcal.cli.main import build_parser
    from fieldcal.cli.tui import _initial_choice

    save_last_choice(SetupChoice("sim", None, "classic-12", 10.0, 0.0, operator="old", spec="old.yaml"))
    args = build_parser().parse_args(["tui", "--out", str(tmp_path), "--operator", "AB"])
    choice = _initial_choice(args)
    assert (choice.procedure, choice.operator, choice.out, choice.spec) == ("classic-12", "AB", str(tmp_path), "old.yaml")
    args.unit_serial = "SN-3"  # as the bench's --unit-serial sets it
    assert _initial_choice(args).unit_serial == "SN-3"


@run_async
async def test_clearing_the_configs_serial_runs_the_unit_without_one(xdg, tmp_path):
    """A config's serial belongs to one unit: cleared on the setup screen, the run has none (it
    is never compared for drift) instead of silently keeping the config's."""
    raw = yaml.safe_load((CONFIGS_DIR / "vn100.yaml").read_text())
    raw["device"]["serial"] = "SN-1"
    path = tmp_path / "one-unit.yaml"
    path.write_text(yaml.safe_dump(raw))
    app = Host(SetupChoice(str(path), None, "field-18", 40.0, 50.0))
    async with app.run_test(size=SIZE) as pilot:
        screen = app.setup
        await until(pilot, lambda: value_of(screen, "#unit-serial") == "SN-1")
        await paste_into(pilot, screen, "#unit-serial", "")
        await pilot.press("ctrl+s")
        await until(pilot, lambda: app.results)
    assert app.results[0].unit_serial == ""
    assert screen.resolved[0].device.serial is None
