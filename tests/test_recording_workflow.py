"""The workflow around a recording: `resolve` calibrates imported recordings again (it reported
them FAILED, exit 1), and a refused `calibrate` leaves no session directory behind."""
from __future__ import annotations

import numpy as np
import pytest

from drivers.sim.handheld import simulate_handheld, to_text
from fieldcal.cli.main import main
from fieldcal.earth import normal_gravity
from fieldcal.paramfile import load


@pytest.fixture(scope="module")
def text_files(tmp_path_factory):
    return to_text(simulate_handheld(6), tmp_path_factory.mktemp("text"))


def _session(root):
    sessions = [p for p in root.iterdir() if p.is_dir()]
    assert len(sessions) == 1, sessions
    return sessions[0]


def test_resolve_calibrates_a_calibrated_recording_again_at_its_place(tmp_path, text_files, capsys):
    out = tmp_path / "sessions"
    assert main(["calibrate", *map(str, text_files), "--map", "imu_tk", "--latitude", "40", "--out", str(out)]) == 0
    session = _session(out)
    capsys.readouterr()
    registry = ["--registry", str(tmp_path / "registry.sqlite")]
    # The same solver at the same place: the very bytes, nothing written.
    assert main(["resolve", str(session), *registry]) == 0
    assert "unchanged" in capsys.readouterr().out
    assert sorted(p.name for p in session.glob("parameters-*.yaml")) == ["parameters-001.yaml"]
    assert main(["resolve", str(session), "--method", "lsq", *registry]) == 0
    assert "re-solved" in capsys.readouterr().out
    powell, lsq = load(session / "parameters-001.yaml"), load(session / "parameters-002.yaml")
    assert lsq.provenance.latitude_deg == 40 and lsq.provenance.gravity_m_s2 == pytest.approx(normal_gravity(40))
    for a, b in zip(powell.triads, lsq.triads):  # one minimum, two searches
        assert np.all(np.abs(a.theta - b.theta) < 0.05 * a.sigma)


def test_resolve_calibrates_a_recording_only_imported(tmp_path, text_files, capsys):
    session = tmp_path / "imported"
    assert main(["import", *map(str, text_files), "--map", "imu_tk", "--out", str(session)]) == 0
    capsys.readouterr()
    assert main(["resolve", str(session), "--registry", str(tmp_path / "registry.sqlite")]) == 0
    out = capsys.readouterr().out
    assert "FAILED" not in out and "re-solved" in out
    pf = load(session / "parameters.yaml")  # no place known: the stated default, never the sensor's norm
    assert pf.provenance.gravity_m_s2 == pytest.approx(normal_gravity(45.0))
    assert {t.name for t in pf.triads} == {"accelerometer", "gyroscope"}


def test_a_refused_calibrate_leaves_no_session_behind(tmp_path, capsys):
    few = to_text(simulate_handheld(2, n_poses=5), tmp_path / "few")
    out = tmp_path / "sessions"
    out.mkdir()
    code = main(["calibrate", *map(str, few), "--map", "imu_tk", "--latitude", "40", "--out", str(out)])
    assert code == 2
    assert "distinct poses" in capsys.readouterr().err
    assert list(out.iterdir()) == []
