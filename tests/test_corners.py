"""Corner positions (gravity along a body diagonal): written as ``up: x+y+z, north: x``, checked
strictly, guided in the operator's words, run headless and replayed, and offered to the planner."""
import math

import numpy as np
import pytest
import yaml

from drivers.sim.device import paper_mimu
from fieldcal.earth import Station
from fieldcal.paramfile import dump
from fieldcal.planning.design import Design, OperatorModel, bound_sigmas
from fieldcal.planning.search import candidates
from fieldcal.procedure.positions import ProcedureError, parse_procedure
from fieldcal.run.replay import recorded_parameters, replay
from fieldcal.run.runner import RunSpec, open_run, run_headless
from fieldcal.solvers.solve import models_from_truth
from fieldcal.tui.guidance import placement

STATION = Station(40.0, 50.0)
ELEVATION = math.asin(1 / math.sqrt(3))  # 35.26°: a body axis above the horizontal on a corner


def one(position: str):
    return parse_procedure(f"dwell_s: 10\npositions:\n  - {position}\n", "p.yaml").positions[0]


def test_a_corner_puts_every_axis_35_degrees_up_with_x_towards_north():
    p = one("{id: 1, up: x+y+z, north: x}")
    assert p.up_body == pytest.approx(np.ones(3) / math.sqrt(3))
    # Body x in ENU, worked by hand: no east part, cos 35.26° north, sin 35.26° up.
    assert p.attitude[:, 0] == pytest.approx([0.0, math.cos(ELEVATION), math.sin(ELEVATION)])
    assert np.linalg.det(p.attitude) == pytest.approx(1.0)
    assert p.attitude.T @ p.attitude == pytest.approx(np.eye(3))
    low = one("{id: 2, up: -x-y-z, north: y}")
    assert low.up_body == pytest.approx(-np.ones(3) / math.sqrt(3))
    assert low.attitude[:, 1][:2] == pytest.approx([0.0, math.cos(ELEVATION)])  # y down towards north


def test_up_and_north_write_a_face_as_the_compass_words_do():
    assert one("{id: 1, up: z, north: x}").attitude == pytest.approx(
        one("{id: 1, axes: {x: north, y: west, z: up}}").attitude)
    assert one("{id: 1, up: x-z, north: y}").attitude == pytest.approx(
        one("{id: 1, axes: {x: west-up, y: north, z: west-down}}").attitude)


@pytest.mark.parametrize("position, field, message", [
    ("{id: 1, up: x+y+z, nort: x}", "positions[0].nort", "did you mean 'north'?"),
    ("{id: 1, up: x+y+z}", "positions[0].north", "missing (north)"),
    ("{id: 1, north: x}", "positions[0].up", "missing (up)"),
    ("{id: 1}", "positions[0].axes", "missing (axes, or up and north)"),
    ("{id: 1, up: z, north: x, axes: {x: north, y: west, z: up}}", "positions[0].up", "either axes or up"),
    ("{id: 1, up: x+x, north: y}", "positions[0].up", "each axis at most once"),
    ("{id: 1, up: x+w, north: y}", "positions[0].up", "a body direction"),
    ("{id: 1, up: 3, north: y}", "positions[0].up", "a body direction"),
    ("{id: 1, up: x+y+z, north: -x-y-z}", "positions[0].north", "no horizontal part"),
])
def test_a_bad_corner_is_a_one_line_error_naming_the_field(position, field, message):
    with pytest.raises(ProcedureError) as caught:
        one(position)
    text = str(caught.value)
    assert text.startswith(f"p.yaml: {field}: ") and message in text and "\n" not in text
    assert caught.value.field == field


def test_the_operator_is_told_each_axis_elevation_and_compass_side():
    face = one("{id: 1, axes: {x: north, y: west, z: up}}")
    corner = one("{id: 2, up: x+y+z, north: x}")
    # From z up to the diagonal: a tip of acos(1/√3) = 55°; y and z's horizontal parts lie 120°
    # either side of x's (north): south-west and south-east.
    assert placement(face, corner).text == ("tip it 55° over onto a corner: x 35° up towards north, "
                                            "y 35° up towards south-west, z 35° up towards south-east")
    below = one("{id: 3, up: -x-y-z, north: x}")
    assert placement(corner, below).text.startswith("turn it over onto a corner: x 35° down towards")


CORNERS = """name: corners
dwell_s: 20
rate_step: {rate_deg_s: 20, turns: 1, ramp_s: 1, settle_s: 1}
positions:
""" + "".join(f"  - {{id: {i}, description: corner {up}, up: '{up}', north: x}}\n"
              for i, up in enumerate(("x+y+z", "-x-y-z", "x-y+z", "-x+y-z", "x+y-z", "-x-y+z",
                                      "-x+y+z", "x-y-z"), start=1)) + \
    "".join(f"  - {{id: {9 + i}, up: '{up}', north: {north}}}\n"
            for i, (up, north) in enumerate((("z", "x"), ("-z", "x"), ("x", "y"), ("-x", "y"))))


def test_a_procedure_with_corners_runs_headless_within_four_sigma_and_replays_byte_for_byte(tmp_path):
    procedure = parse_procedure(CORNERS, "corners.yaml")
    result = run_headless(RunSpec(procedure, STATION, seed=4), tmp_path / "s")
    assert not result.unit.failures
    for name, sol in result.unit.solutions.items():
        z = (sol.theta - result.truth[name]) / sol.sigma
        assert np.all(np.abs(z) < 4.0), (name, z)
    replayed = replay(open_run(result.session))
    pf = replayed.parameter_file
    assert dump(pf).encode() == recorded_parameters(open_run(result.session))


def test_the_planner_offers_the_8_corners_and_writes_them_as_the_format_reads_them():
    pool = candidates(corners=True)
    corners = [c for c in pool if c.corner]
    assert len(pool) == 26 and len(corners) == 8
    assert {tuple(np.sign(c.attitude[2])) for c in corners} == {
        (a, b, c) for a in (1, -1) for b in (1, -1) for c in (1, -1)}
    assert len(candidates()) == 18  # not offered unless asked for
    for c in pool:
        text = yaml.safe_dump({"dwell_s": 10, "positions": [{"id": 1, "description": c.name, **c.fields}]})
        assert parse_procedure(text, "c.yaml").positions[0].attitude == pytest.approx(c.attitude)


def test_faces_and_corners_together_tell_all_nine_parameters_apart_and_neither_alone():
    """The norm method sees gravity's direction only through u uᵀ: on the faces it has no
    cross terms (the misalignments are undetermined), on the corners every diagonal term is 1/3
    (the scale factors are). The bound (crb.py) says the same; faces and corners together
    determine all nine, as faces and edges do."""
    models = {"accelerometer": models_from_truth(paper_mimu())["accelerometer"]}
    pool = candidates(corners=True)
    faces = tuple(c.attitude for c in pool if np.count_nonzero(np.abs(c.attitude[2]) > 1e-9) == 1)
    corners = tuple(c.attitude for c in pool if c.corner)
    assert len(faces) == 6

    def sigmas(attitudes):
        return bound_sigmas(Design(attitudes, 60.0, 20.0, 1), OperatorModel(), models, STATION, 250.0)[
            "accelerometer"]

    def determined(s):  # a σ below 1e-3 (scale factors, radians, m/s²): not a singular direction
        return np.isfinite(s) & (s < 1e-3)

    assert not np.any(determined(sigmas(faces)[6:]))
    assert not np.any(determined(sigmas(corners)[3:6]))
    assert np.all(determined(sigmas(faces + corners)))


def test_a_position_without_a_description_is_placed_by_its_attitude_at_the_first_step():
    # Before this, placement(None, p) said 'place it ' for a position the file did not describe.
    corner = one("{id: 1, up: x+y+z, north: x}")
    assert placement(None, corner).text == ("place it on a corner: x 35° up towards north, "
                                            "y 35° up towards south-west, z 35° up towards south-east")
    assert placement(None, one("{id: 1, up: z, north: x}")).text == "place it: z must point up, x north"
    # a description without a heading would leave the operator guessing where x goes (issue 23):
    # the attitude says it; one that names the heading is said as written
    assert placement(None, one("{id: 1, description: on its back, up: -z, north: x}")).text == \
        "place it: z must point down, x north"
    assert placement(None, one("{id: 1, description: 'on its back, x north', up: -z, north: x}")).text == \
        "place it on its back, x north"


def test_a_wrong_corner_is_named_in_the_procedure_format_words(tmp_path, capsys):
    from fieldcal.cli.main import main

    procedure = tmp_path / "three-corners.yaml"
    procedure.write_text("dwell_s: 10\npositions:\n" + "".join(
        f"  - {{id: {i}, up: '{up}', north: x}}\n" for i, up in enumerate(("x+y+z", "-x-y-z", "x-y+z"), 1)))
    main(["run", "--headless", "--procedure", str(procedure), "--out", str(tmp_path / "s"),
          "--seed", "3", "--wrong-step", "2"])
    out = capsys.readouterr()
    assert "step 1/3: position 1 (x+y+z upward, x towards north)" in out.out  # not 'position 1 ()'
    wrong = [line for line in (out.out + out.err).splitlines() if "WRONG POSITION" in line]
    assert wrong, out.out + out.err
    # Position 2's gravity is along -x-y-z: the file's own words, not its components.
    assert "position 2 expects -x-y-z upward, x towards north, but" in wrong[0]
    assert wrong[0].endswith("until -x-y-z points up") and "(-0.58" not in wrong[0]


def test_the_run_screen_names_an_undescribed_corner_and_places_it_at_the_first_step():
    from fieldcal.procedure import events as ev
    from fieldcal.tui.readings import Telemetry
    from fieldcal.tui.view import RunView

    view = RunView(parse_procedure(CORNERS.replace("description: corner x+y+z, ", ""), "corners.yaml"))
    view.apply(ev.StepStarted(0.0, 0, 1, "", 12))
    view.telemetry = Telemetry(0.0, 0, "place", True, 0)
    assert view.step_text() == "step 1 of 12 · position 1: x+y+z upward, x towards north"
    assert view.banner(sim=False)[0] == ("Position 1: place it on a corner: x 35° up towards north, y 35° up "
                                         "towards south-west, z 35° up towards south-east, then press r")
