"""Issue 25 item 12: `plan` checks every numeric option before its search, and refuses a plan
that leaves a parameter undetermined instead of writing it."""
import numpy as np
import pytest

from fieldcal.cli.main import main


@pytest.mark.parametrize("option, value", [("--place-s", "-1"), ("--place-s", "nan"), ("--settle-s", "inf"),
                                           ("--settle-s", "-0.5"), ("--place-s", "1e9"), ("--slack", "inf"),
                                           ("--slack", "nan"), ("--slack", "-0.1")])
def test_a_bad_number_is_refused_before_the_search(tmp_path, capsys, option, value):
    out = tmp_path / "p.yaml"
    assert main(["plan", "--config", "sim", option, value, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"fieldcal: {option}: expected ") and f"got {float(value)!r}" in err
    assert err.count("\n") == 1 and "planning for" not in err and not out.exists()  # no search began


def test_a_plan_leaving_a_parameter_undetermined_is_refused():
    """--slack inf wrote a plan whose inclinometer misalignment σ was 2e6 mrad: the check that
    refuses it, against field-18's σ (the reference the planner computes), in operator units."""
    from fieldcal.config import load_config
    from fieldcal.planning.command import UNDETERMINED, refuse_undetermined, station_models

    models = station_models(load_config("sim"))
    reference = {name: np.full(9, 1e-4) for name in models}
    fine = {name: s * UNDETERMINED for name, s in reference.items()}
    refuse_undetermined(fine, reference, models)  # 100× field-18's: poor, but determined
    worse = {name: s.copy() for name, s in fine.items()}
    worse["inclinometer"][7] = 1e-4 * 2e4  # delta_zy, 2e4× field-18's
    worse["gyroscope"][3] = np.inf  # scale_x not determined at all: the worst
    with pytest.raises(ValueError, match=r"leaves gyroscope scale_x undetermined \(σ inf 1, inf× field-18's\)"):
        refuse_undetermined(worse, reference, models)
    worse["gyroscope"][3] = 1e-4
    with pytest.raises(ValueError, match=r"leaves inclinometer delta_zy undetermined \(σ 2e\+03 mrad, 2e\+04×"):
        refuse_undetermined(worse, reference, models)
