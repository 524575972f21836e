"""The procedure format read field by field (fieldcal/procedure/positions.py): each direction and
attitude worked by hand, each bound at its edge, each refusal word for word with its field and
line, and the operator's words for a position. Quick: texts parsed in memory, no run."""
from __future__ import annotations

import math

import numpy as np
import pytest

from fieldcal.procedure.positions import (Position, ProcedureError, RateStep, attitude_from_up_and_north,
                                          body_direction_name, compass_side, parse_procedure, position_words)

R2, R3 = math.sqrt(2), math.sqrt(3)


def parsed(text: str, where: str = "p.yaml"):
    return parse_procedure(text, where)


def refusal(text: str, where: str = "p.yaml") -> ProcedureError:
    with pytest.raises(ProcedureError) as caught:
        parse_procedure(text, where)
    return caught.value


def axes(x: str, y: str, z: str) -> str:
    return f"dwell_s: 10\npositions:\n  - id: 1\n    axes:\n      x: {x}\n      y: {y}\n      z: {z}\n"


# -- directions and attitudes ----------------------------------------------------------------

def test_compass_words_give_the_axes_columns_and_two_words_the_diagonal_between_them():
    p = parsed(axes("south-up", "east", "north-up")).positions[0]  # z = x × y: right-handed
    # columns: body axes in ENU (east, north, up)
    assert p.attitude[:, 0] == pytest.approx([0, -1 / R2, 1 / R2], abs=1e-15)
    assert p.attitude[:, 1] == pytest.approx([1, 0, 0], abs=1e-15)
    assert p.attitude[:, 2] == pytest.approx([0, 1 / R2, 1 / R2], abs=1e-15)
    assert p.up_body == pytest.approx([1 / R2, 0, 1 / R2], abs=1e-15)  # the attitude's third row
    p.up_body[:] = 7.0  # a copy: the position's attitude stays as read
    assert p.attitude[2] == pytest.approx([1 / R2, 0, 1 / R2], abs=1e-15)


@pytest.mark.parametrize("x, got, line", [
    ("5", "got 5", 5), ("''", "got ''", 5), ("north-east-up", "got 'north-east-up'", 5), ("nort", "got 'nort'", 5),
    ("[north]", "got a list of 1 item", 5)])
def test_a_word_that_is_no_direction_is_refused_naming_the_axis(x, got, line):
    error = refusal(axes(x, "east", "up"))
    assert str(error) == (f"p.yaml: positions[0].axes.x: expected a direction like 'up', 'north' or "
                          f"'south-up', {got} (line {line})")
    assert (error.path, error.field) == ("p.yaml", "positions[0].axes.x")


def test_two_opposite_words_axes_not_at_right_angles_and_a_mirrored_set_are_refused():
    assert str(refusal(axes("north", "up-down", "east"))) == \
        "p.yaml: positions[0].axes.y: 'up-down' names opposite directions (line 6)"
    assert str(refusal(axes("north", "north-up", "east"))) == \
        "p.yaml: positions[0].axes: the axes are not mutually perpendicular (line 4)"
    assert str(refusal(axes("north", "east", "up"))) == \
        "p.yaml: positions[0].axes: x, y, z form a left-handed set (mirror one horizontal axis) (line 4)"


def test_up_and_north_by_hand():
    # z up, x's horizontal part north: x north, y west (east = north x up)
    assert attitude_from_up_and_north(np.array([0, 0, 2.0]), np.array([3.0, 0, 0])) == pytest.approx(
        np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]]), abs=1e-15)
    # north given with a part along up: only its horizontal part counts
    assert attitude_from_up_and_north(np.array([0, 0, 1.0]), np.array([1.0, 0, 5.0])) == pytest.approx(
        np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]]), abs=1e-15)
    # a body direction -x+y-z reads as (-1, 1, -1)/√3
    p = parsed("dwell_s: 10\npositions:\n  - {id: 1, up: -x+y-z, north: x}\n").positions[0]
    assert p.up_body == pytest.approx([-1 / R3, 1 / R3, -1 / R3], abs=1e-15)


@pytest.mark.parametrize("sine, usable", [(0.099, False), (0.101, True)])
def test_north_needs_a_horizontal_part_of_a_tenth(sine, usable):
    """Unit vectors whose horizontal part is `sine` long: below 0.1 north is too ill-defined."""
    toward = np.array([sine, 0.0, math.sqrt(1 - sine ** 2)])
    attitude = attitude_from_up_and_north(np.array([0, 0, 1.0]), toward)
    assert (attitude is not None) is usable
    if usable:
        assert attitude[1] == pytest.approx([1, 0, 0], abs=1e-12)  # north row: body x, made unit


def test_a_horizontal_part_of_exactly_a_tenth_is_enough_and_any_length_of_north_will_do():
    # (1, 0, √99) is 10 long: its unit vector's horizontal part is 1/10 exactly
    level = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]])
    assert attitude_from_up_and_north(np.array([0, 0, 1.0]), np.array([1.0, 0, math.sqrt(99)])) == \
        pytest.approx(level, abs=1e-15)
    # a short one (0.22 long) mostly horizontal, and a long one: only the direction counts
    assert attitude_from_up_and_north(np.array([0, 0, 1.0]), np.array([0.2, 0, 0.1])) == pytest.approx(level, abs=1e-15)
    assert attitude_from_up_and_north(np.array([0, 0, 1.0]), np.array([40.0, 0, 300.0])) == \
        pytest.approx(level, abs=1e-15)


# -- texts, steps, bounds ---------------------------------------------------------------------

def test_a_title_and_a_description_are_text_of_at_most_200_characters():
    ok = parsed(f"title: {'t' * 200}\ndwell_s: 10\npositions:\n  - {{id: 1, up: z, north: x, description: "
                f"{'d' * 200}}}\n")
    assert ok.title == "t" * 200 and ok.positions[0].description == "d" * 200
    assert parsed("dwell_s: 10\npositions:\n  - {id: 1, up: z, north: x}\n").title == ""
    error = refusal(f"dwell_s: 10\ntitle: {'t' * 201}\npositions:\n  - {{id: 1, up: z, north: x}}\n")
    assert str(error) == f"p.yaml: title: expected text of at most 200 characters, got '{'t' * 57}'... (line 2)"
    assert error.field == "title"
    error = refusal("dwell_s: 10\npositions:\n  - id: 1\n    up: z\n    north: x\n    description: [a]\n")
    assert str(error) == ("p.yaml: positions[0].description: expected text of at most 200 characters, "
                          "got a list of 1 item (line 6)")


def test_the_name_is_the_files_stem_or_a_plain_file_name_of_64_characters():
    body = "dwell_s: 10\npositions:\n  - {id: 1, up: z, north: x}\n"
    assert parsed(body, "some/dir/my-run.yaml").name == "my-run"
    assert parsed(body + f"name: {'a' * 64}\n").name == "a" * 64
    for name, got in (("b" * 65, f"'{'b' * 57}'..."), ("'.hidden'", "'.hidden'"), ("'../x'", "'../x'")):
        assert str(refusal(body + f"name: {name}\n")) == (
            "p.yaml: name: expected a plain file name: up to 64 letters, digits, '.', '_' or '-', not "
            f"starting with '.' (it names the session directory), got {got} (line 4)")


@pytest.mark.parametrize("dwell, ok", [(1, True), (86400, True), (0.99, False), (86401, False)])
def test_a_dwell_is_from_1_s_to_a_day(dwell, ok):
    text = f"positions:\n  - {{id: 1, up: z, north: x}}\ndwell_s: {dwell}\n"
    if ok:
        assert parsed(text).dwell_s == dwell
    else:
        assert str(refusal(text)) == f"p.yaml: dwell_s: expected a number from 1 to 86400 s, got {dwell} (line 3)"


def test_the_switches_are_false_unless_set_and_the_text_is_kept():
    text = "dwell_s: 10\npositions:\n  - {id: 1, up: z, north: x}\n"
    p = parsed(text)
    assert (p.aligned, p.adaptive_dwell, p.any_order, p.text, p.rate_step, p.targets) == \
        (False, False, False, text, None, ())
    on = parsed("aligned: true\nadaptive_dwell: true\nany_order: true\n" + text)
    assert (on.aligned, on.adaptive_dwell, on.any_order) == (True, True, True)


@pytest.mark.parametrize("ident, ok", [(0, True), (1000000, True), (-1, False), (1000001, False)])
def test_a_position_id_is_a_whole_number_up_to_a_million(ident, ok):
    text = f"dwell_s: 10\npositions:\n  - up: z\n    north: x\n    id: {ident}\n"
    if ok:
        assert parsed(text).positions[0].id == ident
    else:
        assert str(refusal(text)) == \
            f"p.yaml: positions[0].id: expected a whole number from 0 to 1000000, got {ident} (line 5)"


def test_the_positions_must_be_a_non_empty_list():
    assert str(refusal("dwell_s: 10\npositions: []\n")) == \
        "p.yaml: positions: expected a non-empty list, got an empty list (line 2)"
    assert str(refusal("dwell_s: 10\npositions: {id: 1}\n")) == \
        "p.yaml: positions: expected a non-empty list, got a mapping (line 2)"


STEPPED = ("dwell_s: 10\nrate_step:\n  rate_deg_s: {rate}\n  turns: {turns}\n  ramp_s: {ramp}\n  settle_s: {settle}\n"
           "positions:\n  - {{id: 1, up: z, north: x}}\n")  # each key on its own line: 3 to 6


def test_a_rate_step_at_its_edges_and_beyond():
    p = parsed(STEPPED.format(rate=0.1, turns=1, ramp=0, settle=600))
    assert p.rate_step == RateStep(0.1, 1, 0.0, 600.0)
    assert parsed(STEPPED.format(rate=400, turns=100, ramp=600, settle=0)).rate_step == RateStep(400.0, 100, 600.0, 0.0)
    for values, message in (
            (dict(rate=0.09, turns=1, ramp=1, settle=1), "rate_step.rate_deg_s: expected a number from 0.1 to 400 °/s, got 0.09 (line 3)"),
            (dict(rate=401, turns=1, ramp=1, settle=1), "rate_step.rate_deg_s: expected a number from 0.1 to 400 °/s, got 401 (line 3)"),
            (dict(rate=10, turns=0, ramp=1, settle=1), "rate_step.turns: expected a whole number from 1 to 100, got 0 (line 4)"),
            (dict(rate=10, turns=101, ramp=1, settle=1), "rate_step.turns: expected a whole number from 1 to 100, got 101 (line 4)"),
            (dict(rate=10, turns=1, ramp=601, settle=1), "rate_step.ramp_s: expected a number from 0 to 600 s, got 601 (line 5)"),
            (dict(rate=10, turns=1, ramp=1, settle=-1), "rate_step.settle_s: expected a number from 0 to 600 s, got -1 (line 6)")):
        assert str(refusal(STEPPED.format(**values))) == f"p.yaml: {message}"


def test_a_position_takes_the_procedures_ramp_and_settle_unless_it_gives_its_own():
    text = ("dwell_s: 10\nrate_step: {rate_deg_s: 10, turns: 1, ramp_s: 3, settle_s: 4}\npositions:\n"
            "  - {id: 1, up: z, north: x, rate_step: {rate_deg_s: 20, turns: 2}}\n"
            "  - {id: 2, up: -z, north: x, rate_step: {rate_deg_s: 5, turns: 3, ramp_s: 7, settle_s: 8}}\n"
            "  - {id: 3, up: x, north: y, rate_step: none}\n"
            "  - {id: 4, up: -x, north: y}\n")
    p = parsed(text)
    assert p.position_steps == (RateStep(20.0, 2, 3.0, 4.0), RateStep(5.0, 3, 7.0, 8.0), None,
                                RateStep(10.0, 1, 3.0, 4.0))
    assert [p.rate_step_at(i) for i in range(4)] == list(p.position_steps)
    # distinct, slowest first
    assert p.rate_steps == (RateStep(5.0, 3, 7.0, 8.0), RateStep(10.0, 1, 3.0, 4.0), RateStep(20.0, 2, 3.0, 4.0))


def test_without_a_procedure_step_a_positions_own_needs_every_key():
    text = "dwell_s: 10\npositions:\n  - id: 1\n    up: z\n    north: x\n    rate_step: 5\n"
    assert str(refusal(text)) == ("p.yaml: positions[0].rate_step: expected 'none' or a mapping {rate_deg_s, "
                                  "turns, ramp_s, settle_s}, got 5 (line 6)")
    same = parsed("dwell_s: 10\nrate_step: {rate_deg_s: 10, turns: 1, ramp_s: 3, settle_s: 4}\npositions:\n"
                  "  - {id: 1, up: z, north: x, rate_step: {rate_deg_s: 10, turns: 1}}\n")
    assert same.position_steps == ()  # every position as the procedure: the plain form
    assert same.rate_steps == (RateStep(10.0, 1, 3.0, 4.0),) and same.rate_step_at(0) == RateStep(10.0, 1, 3.0, 4.0)
    static = parsed("dwell_s: 10\npositions:\n  - {id: 1, up: z, north: x}\n")
    assert static.rate_steps == () and static.rate_step_at(0) is None


def test_targets_are_a_sigma_above_zero_per_triad_and_parameter():
    body = "dwell_s: 10\npositions:\n  - {id: 1, up: z, north: x}\n"
    p = parsed(body + "targets:\n  accelerometer: {bias_x: 0.002, scale_y: 1.0e-4}\n  gyroscope: {delta_yz: 3}\n")
    assert p.targets == (("accelerometer", "bias_x", 0.002), ("accelerometer", "scale_y", 1.0e-4),
                         ("gyroscope", "delta_yz", 3.0))
    assert parsed(body + "targets: null\n").targets == ()
    assert str(refusal(body + "targets:\n  accelerometer: {bias_x: 0}\n")) == \
        "p.yaml: targets.accelerometer.bias_x: expected a σ > 0, got 0 (line 5)"
    assert str(refusal(body + "targets: [1]\n")) == \
        "p.yaml: targets: expected a mapping of triad names to {parameter: σ}, got a list of 1 item (line 4)"
    assert str(refusal(body + "targets: {1: {bias_x: 1}}\n")) == \
        "p.yaml: targets: expected a mapping of triad names to {parameter: σ}, got a mapping (line 4)"


def test_a_file_level_error_names_the_file_and_no_field():
    error = refusal("dwell_s: [\n")
    assert error.path == "p.yaml" and error.field == ""


# -- the operator's words ---------------------------------------------------------------------

@pytest.mark.parametrize("v, name", [
    ((2, 0, 0), "x"), ((0, -1, 0), "-y"), ((1, 0, 1), "x+z"), ((0, 1, -1), "y-z"), ((-1, -1, -1), "-x-y-z"),
    ((1, math.tan(math.radians(9.9)), 0), "x"), ((1, math.tan(math.radians(10.1)), 0), None)])
def test_a_body_direction_is_named_as_the_format_writes_it_within_ten_degrees(v, name):
    assert body_direction_name(v) == name


def test_the_tolerance_of_a_body_direction_name_is_the_callers():
    tilted = (1, math.tan(math.radians(15)), 0)
    assert body_direction_name(tilted) is None
    assert body_direction_name(tilted, tolerance_deg=16) == "x"


@pytest.mark.parametrize("v, side", [
    ((0, 1, 0), "north"), ((0, -2, 7), "south"), ((1, 1, 0), "north-east"), ((-1, -1, 5), "south-west"),
    ((-3, 0, 0), "west"), ((0.2, 1, 0), "north"), ((0.35, 1, 0), "north-east"), ((0, 0, 1), "")])
def test_the_compass_side_counts_a_part_over_three_tenths(v, side):
    """(0.2, 1): its east part is 0.2/1.02 = 0.196 of its length; (0.35, 1): 0.35/1.06 = 0.33."""
    assert compass_side(v) == side


def test_a_position_in_words():
    def position(attitude, description=""):
        return Position(id=1, description=description, attitude=np.array(attitude, dtype=float))

    level = np.eye(3)  # x east, y north, z up
    assert position_words(position(level)) == "z-upward, x-east, y-north"
    assert position_words(position(level, "on its back")) == "on its back"
    upside_down = np.array([[1, 0, 0], [0, -1, 0], [0, 0, -1]])  # x east, y south, z down
    assert position_words(position(upside_down)) == "z-downward, x-east, y-south"
    corner = parsed("dwell_s: 10\npositions:\n  - {id: 1, up: x+y+z, north: x}\n").positions[0]
    assert position_words(corner) == "x+y+z upward, x towards north"
    c, s = math.cos(math.radians(20)), math.sin(math.radians(20))
    # up 20° from z towards y: no named direction within 10°; only x is level
    assert position_words(position([[1, 0, 0], [0, c, -s], [0, s, c]])) == "(0.00, 0.34, 0.94) upward, x-east"
    # body x 45° up towards east, z 45° up towards west: y level (north), x and z not
    tilted = np.array([[1 / R2, 0, -1 / R2], [0, 1, 0], [1 / R2, 0, 1 / R2]])
    assert position_words(position(tilted)) == "x+z upward, y-north"


def test_the_top_level_is_a_mapping_of_the_formats_keys():
    assert str(refusal("- 1\n")) == \
        "p.yaml: expected a procedure: a mapping with keys dwell_s, positions, got a list of 1 item"
    assert str(refusal("positions:\n  - {id: 1, up: z, north: x}\n")) == \
        "p.yaml: dwell_s: missing (a required key) (line 1)"
    assert str(refusal("dwell_s: 10\npositions:\n  - {id: 1, up: z, north: x}\nspeed: 3\n")) == (
        "p.yaml: speed: unknown key 'speed'; the keys are dwell_s, positions, name, title, rate_step, aligned, "
        "adaptive_dwell, targets, any_order (line 4)")


def test_an_unknown_procedure_name_is_the_errors_path(tmp_path, monkeypatch):
    from fieldcal.procedure.positions import load_procedure

    monkeypatch.chdir(tmp_path)
    with pytest.raises(ProcedureError) as caught:
        load_procedure("no-such-procedure")
    assert (caught.value.path, caught.value.field) == ("no-such-procedure", "")
    (tmp_path / "mine.yaml").write_text("dwell_s: 10\npositions:\n  - {id: 1, up: z, north: x}\n")
    assert load_procedure("mine").name == "mine"  # NAME.yaml here, found by its bare name
    assert load_procedure(tmp_path / "mine.yaml").dwell_s == 10


@pytest.mark.parametrize("up, got", [("x+w", "'x+w'"), ("x+x", "'x+x'"), ("3", "3"), ("'-x-y-z-x'", "'-x-y-z-x'")])
def test_a_body_direction_that_is_no_signed_sum_of_distinct_axes_is_refused(up, got):
    # block style: up's own line (4) is not the position's (3)
    assert str(refusal(f"dwell_s: 10\npositions:\n  - id: 1\n    up: {up}\n    north: y\n")) == (
        "p.yaml: positions[0].up: expected a body direction like 'z', '-x', 'x-y' or 'x+y+z' (each axis at "
        f"most once), got {got} (line 4)")


def test_north_is_refused_by_its_own_field_and_line():
    text = "dwell_s: 10\npositions:\n  - id: 1\n    up: z\n    north: {north}\n"
    assert str(refusal(text.format(north="w"))) == (
        "p.yaml: positions[0].north: expected a body direction like 'z', '-x', 'x-y' or 'x+y+z' (each axis at "
        "most once), got 'w' (line 5)")
    assert str(refusal(text.format(north="-z"))) == (
        "p.yaml: positions[0].north: '-z' is along up ('z'), so it has no horizontal part to point north; "
        "name another body direction (line 5)")


def test_a_rate_step_that_is_no_mapping_is_refused_at_its_line():
    text = "dwell_s: 10\npositions:\n  - {id: 1, up: z, north: x}\nrate_step: 5\n"
    assert str(refusal(text)) == \
        "p.yaml: rate_step: expected a mapping with keys rate_deg_s, turns, ramp_s, settle_s, got 5 (line 4)"


@pytest.mark.parametrize("key", ["aligned", "adaptive_dwell", "any_order"])
def test_a_switch_is_true_or_false_unquoted(key):
    text = f"dwell_s: 10\npositions:\n  - {{id: 1, up: z, north: x}}\n{key}: 'yes'\n"
    assert str(refusal(text)) == f"p.yaml: {key}: expected true or false (unquoted), got 'yes' (line 4)"


def test_a_procedure_file_without_a_suffix_is_read_where_it_is(tmp_path, monkeypatch):
    from fieldcal.procedure.positions import load_procedure

    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine").write_text("dwell_s: 12\npositions:\n  - {id: 1, up: z, north: x}\n")
    assert load_procedure("mine").dwell_s == 12  # the file named, not a search for mine.yaml
    with pytest.raises(ProcedureError) as caught:
        load_procedure("gone.yaml")  # a suffix: a path, never a shipped name
    assert (str(caught.value), caught.value.path) == ("gone.yaml: cannot read procedure (No such file or directory)",
                                                      "gone.yaml")


def test_axes_with_up_and_north_is_refused_at_the_first_of_them():
    text = "dwell_s: 10\npositions:\n  - id: 1\n    axes: {x: north, y: west, z: up}\n    up: z\n    north: x\n"
    assert str(refusal(text)) == "p.yaml: positions[0].up: give either axes or up and north, not both (line 5)"


def test_a_triads_targets_are_a_mapping_of_its_parameters():
    body = "dwell_s: 10\npositions:\n  - {id: 1, up: z, north: x}\ntargets:\n"
    assert str(refusal(body + "  accelerometer:\n    scael_x: 1\n")) == (
        "p.yaml: targets.accelerometer.scael_x: unknown key 'scael_x'; did you mean 'scale_x'? (line 6)")
    assert str(refusal(body + "  gyroscope: {bias_x: 1}\n  accelerometer: 5\n")) == (
        "p.yaml: targets.accelerometer: expected a mapping with keys bias_x, bias_y, bias_z, scale_x, scale_y, "
        "scale_z, delta_yz, delta_zy, delta_zx, got 5 (line 6)")


def test_a_position_without_axes_or_up_and_north_is_refused_at_its_line():
    text = "dwell_s: 10\npositions:\n  - {id: 1, up: z, north: x}\n  - {id: 2}\n"
    assert str(refusal(text)) == "p.yaml: positions[1].axes: missing (axes, or up and north) (line 4)"


def test_axes_that_are_no_mapping_of_x_y_z_are_refused_at_their_line():
    base = "dwell_s: 10\npositions:\n  - id: 1\n    axes: {axes}\n"
    assert str(refusal(base.format(axes="5"))) == \
        "p.yaml: positions[0].axes: expected a mapping with keys x, y, z, got 5 (line 4)"
    assert str(refusal(base.format(axes="{x: north, y: west, w: up}"))) == \
        "p.yaml: positions[0].axes.w: unknown key 'w'; the keys are x, y, z (line 4)"


def test_a_sigma_target_is_a_number_above_zero_at_its_own_line():
    body = "dwell_s: 10\npositions:\n  - {id: 1, up: z, north: x}\ntargets:\n  accelerometer:\n    scale_x: 1\n"
    assert str(refusal(body + "    bias_x: a\n")) == \
        "p.yaml: targets.accelerometer.bias_x: expected a number >= 0, got 'a' (line 7)"
    assert str(refusal(body + "    bias_x: -1\n")) == \
        "p.yaml: targets.accelerometer.bias_x: expected a number >= 0, got -1 (line 7)"
    assert str(refusal(body + "    bias_x: 0\n")) == "p.yaml: targets.accelerometer.bias_x: expected a σ > 0, got 0 (line 7)"


def test_a_name_that_is_no_text_is_refused():
    body = "dwell_s: 10\npositions:\n  - {id: 1, up: z, north: x}\n"
    assert str(refusal(body + "name: 5\n")) == "p.yaml: name: expected a non-empty string (quote it), got 5 (line 4)"


@pytest.mark.parametrize("v, side", [((3, 10, 0), "north"), ((0.02, 0.1, 0), "north"), ((0.05, 0.1, 0), "north-east")])
def test_the_compass_side_is_of_the_direction_whatever_its_length(v, side):
    """(3, 10) and (0.02, 0.1): an east part 0.29 and 0.196 of the length; (0.05, 0.1): 0.45."""
    assert compass_side(v) == side
