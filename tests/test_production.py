"""The production workflow end to end: sessions re-solved in a parallel batch (a bad one reported
and skipped), replays, resumed runs and terminal-UI sessions recorded, and a small simulated
production line (units with serials, some out of spec, one drifting) in the registry, listed by
``units`` and flagged by ``history``."""
import shutil
from pathlib import Path

import numpy as np
import pytest

from drivers.sim.device import paper_mimu
from fieldcal.acceptance import load_spec
from fieldcal.cli.main import main
from fieldcal.model import params_from_k
from fieldcal.paramfile import load
from fieldcal.procedure.positions import load_procedure
from fieldcal.registry import Registry
from fieldcal.registry.simulated_line import DRIFT_MG, OUT_OF_SPEC_BIAS_MG, plan_line, run_line
from brisk_quick import brisk_quick

SPEC = Path(__file__).parents[1] / "configs" / "specs" / "paper-mimu.yaml"


@pytest.fixture(scope="module")
def pristine_session(tmp_path_factory):
    """One completed headless run (the simulated MIMU, the quick procedure with brisk rate
    steps), recorded nowhere."""
    out = tmp_path_factory.mktemp("runs")
    brisk = brisk_quick(tmp_path_factory.mktemp("procedure"))
    assert main(["run", "--headless", "--quiet", "--procedure", str(brisk), "--out", str(out), "--seed", "5",
                 "--registry", str(out / "unused.sqlite")]) == 0
    [session] = [p for p in out.iterdir() if p.is_dir()]
    return session


def _copy(session: Path, where: Path) -> Path:
    shutil.copytree(session, where, ignore=shutil.ignore_patterns("lock"))
    return where


def test_resolve_batch_writes_records_and_skips_a_bad_session(pristine_session, tmp_path, capsys):
    batch = tmp_path / "batch"
    a, b = _copy(pristine_session, batch / "a"), _copy(pristine_session, batch / "b")
    (batch / "bad").mkdir()
    (batch / "bad" / "log.jsonl").write_text('{"seq": 0, "type": "start"\n')  # torn first line
    original = (a / "parameters-001.yaml").read_bytes()
    db = str(tmp_path / "r.sqlite")

    status = main(["resolve", str(batch), "-j", "2", "--method", "lsq", "--registry", db])
    out = capsys.readouterr().out.splitlines()
    assert status == 1  # one session failed; the others were re-solved all the same
    assert out[0] == "re-solving 3 sessions in 2 processes"
    progress = sorted(line.split("] ", 1)[1] for line in out[1:4])
    assert [line.split()[0] for line in out[1:4]] == ["[1/3]", "[2/3]", "[3/3]"]
    assert progress[0].startswith(f"FAILED {batch / 'bad'}: ")
    assert progress[1:] == [f"re-solved {s}: parameters-002.yaml (lsq, 3 triads)" for s in (a, b)]
    assert out[4] == "2 re-solved, 1 failed"
    assert (a / "parameters-001.yaml").read_bytes() == original  # kept
    assert (a / "parameters.yaml").read_bytes() == (a / "parameters-002.yaml").read_bytes()

    resolved = load(a / "parameters-002.yaml")
    assert resolved.provenance.method == "lsq"
    truth = {n: params_from_k(t.K, t.bias) for n, t in paper_mimu().items()}
    # The re-solve is a calibration: its errors against the simulator's truth, in units of its σ,
    # neither beyond 4 nor all shrunk (σ inflated) nor spread wide (σ understated).
    z = np.concatenate([(cal.theta - truth[cal.name]) / cal.sigma for cal in resolved.triads])
    assert len(z) == 27 and np.all(np.abs(z) < 4.0), z
    assert 0.5 < np.sqrt(np.mean(z**2)) < 1.5, z
    with Registry(db) as registry:
        rows = registry.query("SELECT params_path, method, source FROM calibrations ORDER BY params_path")
    assert rows == [(str((s / "parameters-002.yaml").resolve()), "lsq", "resolve") for s in (a, b)]

    # the same re-solve again: the session has that file already, nothing is written
    assert main(["resolve", str(a), "--method", "lsq", "--registry", db]) == 0
    assert f"unchanged {a}: parameters-002.yaml (lsq)" in capsys.readouterr().out
    assert not (a / "parameters-003.yaml").exists()
    # with the spec: the verdict on each line, recorded with the row
    assert main(["resolve", str(b), "--spec", str(SPEC), "--registry", db]) == 0
    assert capsys.readouterr().out.splitlines()[1].endswith(" PASS")
    with Registry(db) as registry:
        assert registry.history("")[-1]["passed"] == 1


def test_a_replay_is_recorded(pristine_session, tmp_path, capsys):
    session = _copy(pristine_session, tmp_path / "s")
    db = str(tmp_path / "r.sqlite")
    assert main(["replay", str(session), "--quiet", "--registry", db, "--out", str(tmp_path / "re.yaml")]) == 0
    capsys.readouterr()
    with Registry(db) as registry:
        rows = registry.query("SELECT params_path, source FROM calibrations ORDER BY source")
    # the replay's own file, and the session's calibration it confirmed
    assert rows == [(str((tmp_path / "re.yaml").resolve()), "replay"),
                    (str((session / "parameters-001.yaml").resolve()), "run")]


def test_a_replay_whose_parameter_file_differs_exits_1_and_confirms_nothing(pristine_session, tmp_path, capsys):
    """The recorded file moved by half a σ in one parameter (still a valid file): the replay says
    DIFFERS, exits 1, and does not index the session's calibration as confirmed."""
    import dataclasses

    from fieldcal.paramfile import save

    session = _copy(pristine_session, tmp_path / "s")
    noted = session / "parameters-001.yaml"
    pf = load(noted)
    acc = pf["accelerometer"]
    moved = dataclasses.replace(acc, bias=acc.bias + [0.5 * acc.sigma[0], 0.0, 0.0])
    save(dataclasses.replace(pf, triads=tuple(moved if t.name == acc.name else t for t in pf.triads)), noted)
    db = str(tmp_path / "r.sqlite")
    assert main(["replay", str(session), "--quiet", "--registry", db]) == 1
    out = capsys.readouterr().out
    assert "parameter file DIFFERS from the run's parameters-001.yaml" in out
    with Registry(db) as registry:
        assert registry.query("SELECT params_path FROM calibrations WHERE source = 'run'") == []


def test_a_resumed_run_is_recorded(pristine_session, tmp_path, capsys):
    from crashes import cut_before_step_record

    session = _copy(pristine_session, tmp_path / "s")
    cut_before_step_record(session, 12)  # killed before step 13's record: resumed from there
    db = str(tmp_path / "r.sqlite")
    assert main(["resume", str(session), "--quiet", "--registry", db]) == 0
    capsys.readouterr()
    recorded = (pristine_session / "parameters-001.yaml").read_bytes()
    assert (session / "parameters-001.yaml").read_bytes() == recorded  # what the run would have made
    with Registry(db) as registry:
        assert registry.query("SELECT params_path, source FROM calibrations") == \
            [(str((session / "parameters-001.yaml").resolve()), "run")]


def test_the_terminal_ui_records_its_sessions_calibrations_when_it_closes(pristine_session, tmp_path):
    from argparse import Namespace

    from crashes import cut_before_step_record
    from fieldcal.cli.tui import record_sessions

    calibrated = _copy(pristine_session, tmp_path / "calibrated")
    quit_early = _copy(pristine_session, tmp_path / "quit")
    cut_before_step_record(quit_early, 3)  # the operator quit after three steps: no calibration
    db = str(tmp_path / "r.sqlite")
    record_sessions(Namespace(registry=db, registry_require_tls=False), [calibrated, quit_early, None])
    with Registry(db) as registry:
        assert registry.query("SELECT params_path, source FROM calibrations") == \
            [(str((calibrated / "parameters-001.yaml").resolve()), "run")]


def test_a_small_production_line_in_the_registry(tmp_path, capsys):
    builds = plan_line(6, out_of_spec=2, seed=3)
    assert [b.serial for b in builds] == [f"FC-000{i}" for i in range(1, 7)]
    [drifting] = [b for b in builds if b.drifting]
    out_of_spec = {b.serial for b in builds if b.out_of_spec}
    assert len(out_of_spec) == 2 and drifting.serial not in out_of_spec
    db = str(tmp_path / "line.sqlite")
    brisk = load_procedure(brisk_quick(tmp_path))  # its calibrations are checked, not the turns' speed
    done = run_line(tmp_path / "line", db, load_spec(SPEC), builds, brisk, rate_hz=50.0, seed=3)

    assert len(done) == 7  # six units, the drifting one twice
    verdicts = {(c.serial, c.params.name): c for c in done}
    for b in builds:
        first = verdicts[b.serial, "calibration-1.yaml"]
        assert first.passed == (not b.out_of_spec), (b.serial, first.reasons)
        if b.out_of_spec:  # the built-in fault, found through calibration and noise
            assert [r.split(":")[0] for r in first.reasons] == ["accelerometer bias_x"]
            value = load(first.params).triads[0].bias[0] / (9.80665e-3)
            assert value == pytest.approx(OUT_OF_SPEC_BIAS_MG, abs=0.5)
    second = verdicts[drifting.serial, "calibration-2.yaml"]
    assert not second.passed and len(second.reasons) == 1 and "drifted" in second.reasons[0]

    assert main(["units", "--registry", db]) == 0
    rows = [line.split() for line in capsys.readouterr().out.splitlines()[1:]]
    assert [(r[0], r[-3], r[-1]) for r in rows] == [
        (b.serial, "2" if b.drifting else "1", "FAIL" if b.out_of_spec or b.drifting else "PASS")
        for b in builds]
    assert main(["history", drifting.serial, "--registry", db, "--spec", str(SPEC)]) == 0
    history = capsys.readouterr().out
    [flagged] = [line for line in history.splitlines() if "drifted" in line and "bias x" in line]
    assert flagged.split()[:2] == ["accelerometer", "bias"] and "> 1" in flagged
    drift = float(flagged.split("drifted ")[1].split()[0])
    assert drift == pytest.approx(DRIFT_MG, abs=0.5)  # the simulated drift, recovered
    assert "1 parameter drifted beyond" in history
    assert history.splitlines()[1].startswith("#2 2026-07-04T") and " [run] (FAIL): " in history  # 180 days on


def test_resolve_leaves_unfinished_runs_to_resume_names_each_session_once_and_survives_a_bad_spec(
        pristine_session, tmp_path, capsys):
    from crashes import cut_before_step_record

    batch = tmp_path / "batch"
    done, cut = _copy(pristine_session, batch / "done"), _copy(pristine_session, batch / "cut")
    cut_before_step_record(cut, 1)  # killed after its first step: an unfinished run
    db = str(tmp_path / "r.sqlite")
    # the same session under three names is re-solved once; the unfinished one is not re-solved
    status = main(["resolve", str(batch), str(done), str(tmp_path / "batch" / ".." / "batch" / "done"),
                   "-j", "2", "--method", "lsq", "--registry", db])
    out = capsys.readouterr().out.splitlines()
    assert status == 1 and out[0] == "re-solving 2 sessions in 2 processes"
    assert any(line.endswith(f"FAILED {cut}: not re-solved: its run did not finish (resume it first)")
               for line in out)
    assert not list(cut.glob("parameters*.yaml"))  # nothing written into the unfinished session
    with Registry(db) as registry:
        assert [r[0] for r in registry.query("SELECT params_path FROM calibrations")] == \
            [str((done / "parameters-002.yaml").resolve())]

    # a spec that does not fit the unit: said on the session's line, the batch still ends normally
    bad_spec = tmp_path / "bad.yaml"
    bad_spec.write_text(SPEC.read_text().replace("bias: {unit: mg, min: -10, max: 10, max_sigma: 0.5",
                                                 "bias: {unit: °/h, min: -10, max: 10, max_sigma: 0.5", 1))
    status = main(["resolve", str(done), "--method", "lsq", "--spec", str(bad_spec), "--registry", db])
    out = capsys.readouterr().out.splitlines()
    assert status == 3 and "SPEC ERROR: " in out[1] and out[-1].startswith("1 re-solved, 0 failed, 1 failed")
    with Registry(db) as registry:  # recorded all the same, with no verdict
        assert registry.history("")[-1]["passed"] is None


def test_the_operator_is_kept_in_the_session_the_parameter_file_and_the_registry(tmp_path, capsys, monkeypatch):
    """--operator (or $FIELDCAL_OPERATOR) names who calibrated: in the session's metadata, so a
    replay or re-solve writes it again; in the parameter file; in the registry and `history`."""
    out, db = tmp_path / "runs", str(tmp_path / "r.sqlite")
    brisk = str(brisk_quick(tmp_path))  # quick.yaml with brisk rate steps: none of this checks their speed
    argv = ["run", "--headless", "--quiet", "--procedure", brisk, "--out", str(out), "--seed", "6",
            "--registry", db, "--operator", "A. Ng"]
    assert main(argv) == 0
    [session] = out.iterdir()
    assert load(session / "parameters.yaml").provenance.operator == "A. Ng"
    assert main(["replay", str(session), "--quiet", "--registry", db, "--out", str(tmp_path / "re.yaml")]) == 0
    assert (tmp_path / "re.yaml").read_bytes() == (session / "parameters.yaml").read_bytes()
    capsys.readouterr()
    assert main(["history", "", "--registry", db]) == 0  # the simulated MIMU has no serial
    assert " by A. Ng " in capsys.readouterr().out
    with Registry(db) as registry:
        assert {r[0] for r in registry.query("SELECT operator FROM calibrations")} == {"A. Ng"}

    monkeypatch.setenv("FIELDCAL_OPERATOR", "B. Osei")  # a station's login sets it once
    assert main(argv[:-2] + ["--out", str(tmp_path / "env")]) == 0
    [session] = (tmp_path / "env").iterdir()
    assert load(session / "parameters.yaml").provenance.operator == "B. Osei"
    # a name that could not be printed on one line is refused before anything runs
    assert main(argv[:-1] + ["A.\nNg"]) == 2
    assert capsys.readouterr().err.startswith("fieldcal: --operator: expected a name of 1 to 100")


class DeadServer:
    """A TCP port on 127.0.0.1 that takes each connection and hangs up at once (a server going
    down), counting the connections a client makes."""

    def __init__(self):
        import socket
        import threading

        self.socket = socket.create_server(("127.0.0.1", 0))
        self.port = self.socket.getsockname()[1]
        self.connections = 0
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self):
        while True:
            try:
                client, _ = self.socket.accept()
            except OSError:  # closed
                return
            self.connections += 1
            client.close()

    def close(self):
        self.socket.close()


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _registry_lines(err: str) -> list[str]:
    return [line for line in err.splitlines() if "unit registry" in line]


def test_resolve_with_a_registry_nobody_answers_says_it_once_and_re_solves_every_session(
        pristine_session, tmp_path, capsys):
    """A PostgreSQL URL whose port has no server: one line says so (the password hidden), every
    session is re-solved all the same, and the end names the rebuild that indexes them."""
    pytest.importorskip("psycopg")
    batch = tmp_path / "batch"
    sessions = [_copy(pristine_session, batch / name) for name in "abc"]
    url = f"postgresql://fieldcal:s3cret@127.0.0.1:{_free_port()}/line"
    hidden = url.replace("s3cret", "***")

    status = main(["resolve", str(batch), "-j", "2", "--method", "lsq", "--registry", url])
    out, err = capsys.readouterr()
    assert status == 0 and out.splitlines()[-1] == "3 re-solved, 0 failed"
    assert all((s / "parameters-002.yaml").is_file() for s in sessions)
    warning, summary = _registry_lines(err)
    assert warning.startswith(f"warning: the unit registry ({hidden}) was not updated: RegistryError: "
                              "cannot connect: ")
    rebuild = f"fieldcal registry rebuild {batch} --registry '{hidden}'"  # quoted: *** is a glob
    assert f"`{rebuild}` will index them" in warning
    assert summary == f"3 calibrations not in the unit registry ({hidden}): index them with `{rebuild}`"
    assert "s3cret" not in out + err


def test_resolve_tries_a_registry_that_hangs_up_once_not_once_per_session(pristine_session, tmp_path, capsys):
    """The server takes the connection and drops it: as many connections as one record makes,
    however many sessions the batch has; and the sessions index later with the rebuild named."""
    pytest.importorskip("psycopg")
    from fieldcal.registry import record_safely

    batch = tmp_path / "batch"
    for name in "abc":
        _copy(pristine_session, batch / name)
    server = DeadServer()
    try:
        url = f"postgresql://fieldcal@127.0.0.1:{server.port}/line"
        assert not record_safely(batch / "a" / "parameters-001.yaml", None, url, warn=lambda text: None)
        one_record = server.connections
        assert one_record >= 1
        assert main(["resolve", str(batch), "--registry", url]) == 0
        err = capsys.readouterr().err
        assert server.connections == 2 * one_record
    finally:
        server.close()
    warning, summary = _registry_lines(err)
    assert warning.startswith(f"warning: the unit registry ({url}) was not updated: RegistryError: ")
    assert summary.startswith(f"3 calibrations not in the unit registry ({url})")
    db = tmp_path / "r.sqlite"  # the rebuild it names, on a registry that works
    assert main(["registry", "rebuild", str(batch), "--registry", str(db)]) == 0
    with Registry(db) as registry:
        assert registry.query("SELECT COUNT(*) FROM calibrations")[0][0] == 3  # each re-solve: unchanged


def test_resolve_with_a_registry_server_stopped_mid_batch_says_it_once(pristine_session, tmp_path, capsys,
                                                                      monkeypatch):
    """A real PostgreSQL server records the first session's calibration and is stopped: the next
    record fails, is said once, and the rest of the batch is re-solved without trying again."""
    from postgres_server import SUPERUSER, _started

    from fieldcal.registry import BatchRecorder

    batch = tmp_path / "batch"
    for name in "abc":
        _copy(pristine_session, batch / name)
    server = _started()
    try:
        url = server.url("postgres")
        tries = []
        record = BatchRecorder.record

        def record_then_stop_the_server(self, params, passed=None):
            tries.append(params)
            done = record(self, params, passed)
            if len(tries) == 1:
                assert done  # the first is in the registry
                server.stop()
                server.port = 0  # (stopped: nothing left for the finally to stop)
            return done
        monkeypatch.setattr(BatchRecorder, "record", record_then_stop_the_server)
        assert main(["resolve", str(batch), "--method", "lsq", "--registry", url]) == 0
    finally:
        server.stop()
    out, err = capsys.readouterr()
    assert out.splitlines()[-1] == "3 re-solved, 0 failed" and len(tries) == 3
    warning, summary = _registry_lines(err)
    assert warning.startswith(f"warning: the unit registry ({url}) was not updated: RegistryError: cannot connect")
    assert summary.startswith(f"2 calibrations not in the unit registry ({url}): index them with "
                              f"`fieldcal registry rebuild {batch} --registry ")
    assert SUPERUSER in url
