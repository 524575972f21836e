"""The verdict as the operator reads it (``verdict_lines``), where a spec is looked for
(``load_spec``) and what a SpecError names: a hand-built verdict laid out column by column, the
shipped, missing and misnamed spec files with the one line each gives. Asked for by mutation
testing (issue 26): every cell and branch of the table survived a mutant before."""
import pytest

from fieldcal.acceptance import Check, SpecError, Verdict, evaluate, load_spec, verdict_lines
from fieldcal.paths import SPECS_DIR
from test_acceptance import accelerometer, parameter_file, spec

SHIPPED_SPECS = ", ".join(sorted(p.stem for p in SPECS_DIR.glob("*.yaml")))

FAILED_BIAS = ("5 mg above the maximum 4 mg", "drifted 3 mg since the previous calibration, more than 1 mg")
MISSING_TRIAD = "not in the parameter file (it has accelerometer)"


def test_the_verdict_table_shows_each_cell_only_where_it_has_a_value():
    verdict = Verdict("test unit", (
        Check("accelerometer", "bias_x", 1.5, 0.25, "mg"),
        Check("accelerometer", "bias_y", 5.0, 0.25, "mg", FAILED_BIAS, drift=3.0, drift_sigma=12.0),
        Check("accelerometer", "bias_z", -1.0, 0.25, "mg", drift=0.5),  # no σ for the drift
        Check("accelerometer", "scale_x", 1.0001, None, "1", calibrated=False),
        Check("gyroscope", "triad", None, None, "", (MISSING_TRIAD,)),
    ), notes=("drift not checked: no previous calibration of this unit",))
    # columns laid out by hand: the labels left, the numbers right, each as wide as its widest cell
    assert verdict_lines(verdict) == [
        "  triad         parameter  value      1σ         drift    result\n"
        "  accelerometer bias x       1.5 mg 0.25 mg               PASS\n"
        "  accelerometer bias y         5 mg 0.25 mg 3 (+12.0σ) mg FAIL: " + "; ".join(FAILED_BIAS) + "\n"
        "  accelerometer bias z        -1 mg 0.25 mg        0.5 mg PASS\n"
        "  accelerometer scale x   1.0001 1                        not calibrated (no limit)\n"
        "  gyroscope     triad                                     FAIL: " + MISSING_TRIAD,
        "note: drift not checked: no previous calibration of this unit",
        "test unit: FAIL (2 of 5 checks failed)",
    ]


def test_a_passing_verdict_says_pass_with_no_check_failed():
    verdict = Verdict("test unit", (Check("accelerometer", "bias_x", 1.5, 0.25, "mg"),))
    assert verdict_lines(verdict)[-1] == "test unit: PASS (0 of 1 checks failed)"


def test_a_bare_name_is_the_shipped_spec_when_no_file_here_has_it(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    shipped = load_spec("paper-mimu")
    assert shipped.path == str(SPECS_DIR / "paper-mimu.yaml")
    assert shipped.product == "paper MIMU (simulated)"  # the shipped file's own product line
    (tmp_path / "paper-mimu.yaml").write_text("schema: fieldcal-spec/1\nproduct: mine\n"
                                             "triads: {accelerometer: {bias: {unit: mg}}}\n")
    assert load_spec("paper-mimu").product == "mine"  # the user's own file wins


def test_a_bare_name_found_nowhere_says_where_it_was_looked_for(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SpecError) as info:
        load_spec("no-such-spec")
    assert str(info.value) == (f"no-such-spec: no such product spec (not a file, nor no-such-spec.yaml here, "
                               f"nor in {SPECS_DIR}; the shipped product specs: {SHIPPED_SPECS})")
    assert (info.value.path, info.value.field) == ("no-such-spec", "")  # the whole file: no field


def test_a_missing_path_is_the_readers_one_line_not_a_search(tmp_path):
    missing = tmp_path / "spec.yaml"
    with pytest.raises(SpecError) as info:
        load_spec(missing)
    assert str(info.value) == f"{missing}: cannot read product spec (No such file or directory)"
    assert info.value.path == str(missing)


@pytest.mark.parametrize("serial_now, serial_then, why", [
    (None, "A1", "this calibration's unit has no serial (give --unit-serial)"),
    ("A1", None, "the previous calibration's unit has no serial"),
    ("A1", "B2", "the previous calibration is of unit 'B2', this one of 'A1'"),
])
def test_drift_is_not_taken_across_units_and_the_note_says_why(serial_now, serial_then, why):
    limits = spec(bias={"unit": "mg", "max_drift": 1.0})
    today = parameter_file(accelerometer([5.0, 0.0, 0.0]), serial=serial_now)
    previous = parameter_file(accelerometer([0.0, 0.0, 0.0]), serial=serial_then)
    verdict = evaluate(limits, today, previous)
    assert verdict.notes == (f"drift not checked: {why}",)
    assert verdict.passed and all(c.drift is None for c in verdict.checks)  # 5 mg apart, not compared


def test_a_spec_in_another_unit_names_the_spec_file_and_the_entry():
    counts = parameter_file(accelerometer([1, 1, 1], unit="count", per_unit=1000.0))
    with pytest.raises(SpecError) as info:
        evaluate(spec(bias={"unit": "mg", "max": 4}), counts)
    assert (info.value.path, info.value.field) == ("spec.yaml", "triads.accelerometer.bias")
