"""The workflow around a recording: `resolve` calibrates imported recordings again (it reported
them FAILED, exit 1), and a refused `calibrate` or `import` leaves no session directory behind."""
from __future__ import annotations

from dataclasses import replace

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
    assert code == 1  # read whole, nothing to calibrate from (the README's exit statuses)
    assert "distinct poses" in capsys.readouterr().err
    assert list(out.iterdir()) == []



@pytest.mark.parametrize("command", ["import", "calibrate"])
@pytest.mark.parametrize("name", ["log.bin", "log.ulg", "log.bag", "acc.txt"])
def test_nuls_fed_to_import_or_calibrate_leave_nothing_at_the_out_path_or_through_a_link(tmp_path, capsys,
                                                                                          command, name):
    """A file of NULs, refused in one line (exit 2): nothing is made at a new nested --out (not its
    parents either), and a link planted at --out is not followed: the folder it points at stays
    empty and the link stays as it was (issue 25)."""
    nuls = tmp_path / name
    nuls.write_bytes(bytes(65536))
    given = [str(nuls)] + (["--map", "imu_tk"] if name.endswith(".txt") else [])
    if name.endswith(".txt"):  # the map's two files: both NULs
        (tmp_path / "gyro.txt").write_bytes(bytes(65536))
        given.insert(1, str(tmp_path / "gyro.txt"))
    target = tmp_path / "elsewhere"
    target.mkdir()
    link = tmp_path / "planted"
    link.symlink_to(target, target_is_directory=True)
    for out in (tmp_path / "new" / "deeper" / "out", link):
        assert main([command, *given, "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and err.startswith("fieldcal: "), err
    assert not (tmp_path / "new").exists()
    assert link.is_symlink() and link.readlink() == target and list(target.iterdir()) == []


def impossible_join(tmp_path):
    """A recording joined to its time-reversed copy whose gyro was not negated (as a careless join
    makes it): the second half's rotations turn the wrong way, which no calibration can fit."""
    sim = simulate_handheld(6)
    t = np.r_[sim.t, sim.t[-1] + 1.0 / sim.rate_hz + (sim.t - sim.t[0])]
    joined = replace(sim, t=t, accelerometer=np.vstack([sim.accelerometer, sim.accelerometer[::-1]]),
                     gyroscope=np.vstack([sim.gyroscope, sim.gyroscope[::-1]]))
    return to_text(joined, tmp_path / "joined")


def test_an_impossible_join_is_refused_for_its_misfit_not_its_axes(tmp_path, capsys):
    """Before: 'the motions do not span enough rotation axes' (σ grown by χ²/dof in the millions)."""
    files = impossible_join(tmp_path)
    code = main(["calibrate", *map(str, files), "--map", "imu_tk", "--latitude", "40", "--out", str(tmp_path / "s")])
    out = capsys.readouterr().out
    assert code == 1  # the accelerometer calibrated, the gyro not
    line = next(l for l in out.splitlines() if l.startswith("gyroscope: not calibrated"))
    assert "the rotations do not fit the motions: χ²/dof" in line and "not still" in line
    assert "span enough rotation axes" not in line


def misfit_recording(tmp_path):
    """The last three motions read 2 % fast (as if the gyro's range switched mid-recording): a fit
    still possible, its χ²/dof hundreds of times what the noise allows."""
    sim = simulate_handheld(6)
    gyro, bias = sim.gyroscope.copy(), sim.truth["gyroscope"].bias
    start = sim.static[-4, 1]
    gyro[start:] = np.round(bias + 1.02 * (gyro[start:] - bias))
    return to_text(replace(sim, gyroscope=gyro), tmp_path / "misfit")


def test_a_fit_far_beyond_the_noise_is_refused_or_kept_with_a_warning(tmp_path, capsys):
    files = misfit_recording(tmp_path)
    out = tmp_path / "sessions"
    out.mkdir()
    code = main(["calibrate", *map(str, files), "--map", "imu_tk", "--latitude", "40", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and "gyroscope fits with χ²/dof" in err and "--accept-misfit" in err
    assert "not still" in err and "wrong map" in err
    assert list(out.iterdir()) == []  # nothing written
    code = main(["calibrate", *map(str, files), "--map", "imu_tk", "--latitude", "40", "--out", str(out),
                 "--accept-misfit"])
    text = capsys.readouterr().out
    assert code == 0
    assert "WARNING: kept (--accept-misfit): gyroscope fits with χ²/dof" in text
    ratio = float(text.split("gyroscope fits with χ²/dof ")[1].split()[0])
    assert ratio > 100


def test_a_plausible_fit_passes_the_gate(tmp_path, text_files, capsys):
    assert main(["calibrate", *map(str, text_files), "--map", "imu_tk", "--latitude", "40",
                 "--out", str(tmp_path / "s")]) == 0
    assert "accept-misfit" not in capsys.readouterr().out
