"""The unit registry: calibrations indexed once each, drift between them in σ against the spec,
several processes writing at once losing nothing, a writer killed mid-write leaving no partial
row, and a registry failure never failing a run; on SQLite and on a real PostgreSQL server
(tests/postgres_server.py starts one; without its binaries those variants are skipped)."""
import hashlib
import multiprocessing
import signal
import sqlite3
from pathlib import Path

import pytest

from fieldcal.acceptance import spec_from_document
from fieldcal.cli.main import main
from fieldcal.registry import SCHEMA_VERSION, Registry
from fieldcal.registry.drift import drifts

from postgres_server import postgres_server  # noqa: F401 -- the fixture
# in a module of their own: the writers run in spawned processes (registry_writers says why)
from registry_writers import endless_writer, unit_file, writer
from brisk_quick import brisk_quick

QUICK = str(Path(__file__).parent / "faults" / "quick.yaml")

SPEC = spec_from_document({"schema": "fieldcal-spec/1", "product": "MIMU-9", "triads": {
    "accelerometer": {"bias": {"unit": "mg", "max_drift": 1.0}}}}, "spec.yaml")


@pytest.fixture(params=["sqlite", "postgresql"])
def registry_at(request, tmp_path) -> str:
    """A new, empty registry's location: an SQLite file, or a new database on the test server."""
    if request.param == "sqlite":
        return str(tmp_path / "r.sqlite")
    server = request.getfixturevalue("postgres_server")
    return server.url(server.new_database())


def test_units_and_history_with_drift_in_sigma_flagged_beyond_the_spec(tmp_path, capsys, registry_at):
    db = registry_at
    with Registry(db) as registry:
        assert registry.version == SCHEMA_VERSION
        assert registry.record(unit_file(tmp_path / "a1.yaml", "A", [2.0, 3.0, -1.0], 0.03))
        assert registry.record(unit_file(tmp_path / "a2.yaml", "A", [5.0, 3.5, -1.0], 0.04), passed=False)
        assert registry.record(unit_file(tmp_path / "b1.yaml", "B", [0.0, 0.0, 0.0]), passed=True)
        assert not registry.record(tmp_path / "a1.yaml")  # indexed once
        history = registry.history("A")
    assert [h["path"] for h in history] == [str(tmp_path / "a1.yaml"), str(tmp_path / "a2.yaml")]
    # in the file's order, with the file's values in operator units (mg; scale factors as 1)
    assert list(history[0]["parameters"])[:4] == [("accelerometer", n) for n in
                                                  ("bias_x", "bias_y", "bias_z", "scale_x")]
    value, sigma, unit = history[1]["parameters"]["accelerometer", "bias_x"]
    assert (value, sigma, unit) == (pytest.approx(5.0), pytest.approx(0.04), "mg")
    assert [h["passed"] for h in history] == [None, 0]
    found = {(d.parameter, d.index): d for d in drifts(history, SPEC)}
    x, y = found["bias_x", 1], found["bias_y", 1]
    assert x.drift == pytest.approx(3.0) and x.in_sigma == pytest.approx(3.0 / 0.05) and x.exceeded
    assert y.drift == pytest.approx(0.5) and not y.exceeded
    assert not found["scale_x", 1].exceeded  # the spec sets no limit on it

    assert main(["units", "--registry", str(db)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[1].split() == ["A", "MIMU-9", "2", *out[1].split()[3:4], "FAIL"]
    assert out[2].split()[:3] == ["B", "MIMU-9", "1"] and out[2].split()[-1] == "PASS"
    (tmp_path / "spec.yaml").write_text("schema: fieldcal-spec/1\nproduct: MIMU-9\ntriads:\n"
                                        "  accelerometer: {bias: {unit: mg, max_drift: 1.0}}\n")
    assert main(["history", "A", "--registry", str(db), "--spec", str(tmp_path / "spec.yaml")]) == 0
    out = capsys.readouterr().out
    assert "#2 drifted +3 mg > 1" in out and "(+60.0σ)" in out
    assert "1 parameter drifted beyond" in out
    assert main(["history", "A", "--registry", str(db), "--plot", str(tmp_path / "plots")]) == 0
    png = tmp_path / "plots" / "A-accelerometer-history.png"
    assert f"plot: {png}" in capsys.readouterr().out and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["history", "Z", "--registry", str(db)]) == 2


def test_a_newer_schema_is_refused_by_name(tmp_path):
    db = tmp_path / "r.sqlite"
    Registry(db).close()
    with sqlite3.connect(db) as raw:
        raw.execute("INSERT INTO migrations VALUES (7, 'later')")
    with pytest.raises(ValueError, match="schema version 7 is newer"):
        Registry(db)


def test_a_file_that_is_no_registry_is_one_line(tmp_path, capsys):
    (tmp_path / "notes.txt").write_text("not a database, but a file given by mistake\n" * 100)
    assert main(["units", "--registry", str(tmp_path / "notes.txt")]) == 2
    assert capsys.readouterr().err == f"fieldcal: registry {tmp_path / 'notes.txt'}: file is not a database\n"


def _calibration_rows(registry) -> dict[str, tuple]:
    """{parameter file: (its bias_x in mg, parameter rows, triad rows)} of every calibration."""
    return {path: (bias_x, n_params, n_triads) for path, bias_x, n_params, n_triads in registry.query(
        "SELECT c.params_path, (SELECT value FROM parameters p WHERE p.calibration_id = c.id AND "
        "p.name = 'bias_x'), (SELECT COUNT(*) FROM parameters p WHERE p.calibration_id = c.id), "
        "(SELECT COUNT(*) FROM triads t WHERE t.calibration_id = c.id) FROM calibrations c")}


def test_processes_writing_at_once_lose_nothing(tmp_path, registry_at):
    shared = [unit_file(tmp_path / f"shared-{i}.yaml", f"X{i}", [i, -1.0, 0.0]) for i in range(5)]
    files = [[unit_file(tmp_path / f"{w}-{i}.yaml", f"S{w}-{i}", [i, w, 0.0]) for i in range(15)] + shared
             for w in range(4)]  # every writer also records the same five files: each kept once
    ctx = multiprocessing.get_context("spawn")
    go = ctx.Event()
    procs = [ctx.Process(target=writer, args=(registry_at, f, go)) for f in files]
    for p in procs:
        p.start()
    go.set()  # all open the empty registry, migrate it and write together
    for p in procs:
        p.join(120)
        assert p.exitcode == 0
    with Registry(registry_at) as registry:
        assert len(registry.units()) == 4 * 15 + 5
        rows = _calibration_rows(registry)
        assert registry.query("SELECT version FROM migrations ORDER BY version") == \
            [(v,) for v in range(1, SCHEMA_VERSION + 1)]  # migrated once, by one of them
        if registry.backend.kind == "sqlite":
            assert registry.query("PRAGMA integrity_check")[0][0] == "ok"
    expected = {str(f.resolve()): (pytest.approx(float(i)), 9, 1) for w in range(4)
                for i, f in enumerate(files[w][:15])}
    expected |= {str(f.resolve()): (pytest.approx(float(i)), 9, 1) for i, f in enumerate(shared)}
    assert rows == expected


def test_a_writer_killed_mid_write_leaves_no_partial_calibration(tmp_path, registry_at):
    # The writer never ends by itself (100 files, then new ones), so the kill lands while it
    # writes; 300 files made in advance spent 10 s of wall on files it never reached.
    files = [unit_file(tmp_path / f"k-{i}.yaml", f"K{i}", [i, 0.0, 0.0]) for i in range(100)]
    ctx = multiprocessing.get_context("spawn")
    first_done = ctx.Event()
    proc = ctx.Process(target=endless_writer, args=(registry_at, files, first_done))
    proc.start()
    assert first_done.wait(120)
    proc.kill()  # SIGKILL, wherever it is: between or inside transactions
    proc.join(60)
    assert proc.exitcode == -signal.SIGKILL  # it was still writing: the kill ended it
    with Registry(registry_at) as registry:  # opens (SQLite: recovers the WAL) and can be written
        if registry.backend.kind == "sqlite":
            assert registry.query("PRAGMA integrity_check")[0][0] == "ok"
        rows = _calibration_rows(registry)
        assert len(rows) >= 5  # the five it said it had recorded, at least
        # each whole and right (file k-i holds bias i), none partial
        assert rows == {path: (pytest.approx(float(Path(path).stem.split("-")[1])), 9, 1) for path in rows}
        # still writable: a few files the killed writer did not reach and a new one are recorded
        # now (recording all 300 of the earlier version, one transaction each, spent 12 s of wall)
        later = [f for f in files if str(f.resolve()) not in rows][:3] + [
            unit_file(tmp_path / "after.yaml", "AFTER", [7.0, 0.0, 0.0])]
        assert all(registry.record(f) for f in later)
        assert registry.query("SELECT COUNT(*) FROM calibrations")[0][0] == len(rows) + len(later)


def test_an_older_registry_is_migrated_keeping_its_calibrations(tmp_path, registry_at, monkeypatch):
    import fieldcal.registry as registry_module

    old = unit_file(tmp_path / "old.yaml", "OLD", [1.0, 2.0, 3.0])
    with monkeypatch.context() as m:  # a registry made by the fieldcal of schema version 1
        m.setattr(registry_module, "_MIGRATIONS", registry_module._MIGRATIONS[:1])
        m.setattr(registry_module, "SCHEMA_VERSION", 1)
        with Registry(registry_at) as registry:
            assert registry.version == 1
            registry.backend.begin()
            registry.backend.execute(  # what version 1 wrote (no source, no position)
                "INSERT INTO calibrations (serial, model, station, procedure, method, time, params_sha256, "
                "params_path, passed) VALUES ('OLD', 'MIMU-9', 's', 'field-18', 'powell', "
                "'2026-01-01T00:00:00+00:00', 'abc', 'old.yaml', 1)")
            registry.backend.commit()
    with Registry(registry_at) as registry:
        assert registry.version == SCHEMA_VERSION
        [(source, passed)] = registry.query("SELECT source, passed FROM calibrations")
        assert (source, passed) == ("", 1)
        assert registry.record(old, source="replay")
        assert [h["source"] for h in registry.history("OLD")] == ["", "replay"]
def test_a_broken_registry_warns_and_rebuild_indexes_the_session(tmp_path, capsys):
    broken = tmp_path / "registry.sqlite"  # a regular file, so not refused up front; no database
    broken.write_text("not a database\n" * 100)
    brisk = str(brisk_quick(tmp_path))  # quick.yaml with brisk rate steps: none of this checks their speed
    argv = ["run", "--headless", "--quiet", "--procedure", brisk, "--out", str(tmp_path / "s"), "--seed", "8",
            "--registry", str(broken)]
    assert main(argv) == 0  # the run is complete; only the registry failed
    err = capsys.readouterr().err
    assert "warning: the unit registry" in err and "registry rebuild" in err
    [session] = (tmp_path / "s").iterdir()
    numbered = session / "parameters-001.yaml"
    db = tmp_path / "r.sqlite"
    assert main(["registry", "rebuild", str(tmp_path / "s"), "--registry", str(db)]) == 0
    assert "1 calibrations added" in capsys.readouterr().out
    assert main(["registry", "rebuild", str(session), "--registry", str(db)]) == 0
    assert "0 calibrations added, 1 already there" in capsys.readouterr().out
    with Registry(db) as registry:
        [(sha, path)] = registry.db.execute("SELECT params_sha256, params_path FROM calibrations").fetchall()
    assert path == str(numbered.resolve())
    assert sha == hashlib.sha256(numbered.read_bytes()).hexdigest()
    # a run with a working registry records its calibration as it finishes
    argv[-1] = str(tmp_path / "live.sqlite")
    argv[argv.index("8")] = "9"
    assert main(argv) == 0
    with Registry(tmp_path / "live.sqlite") as registry:
        assert registry.db.execute("SELECT COUNT(*) FROM calibrations").fetchone()[0] == 1


def test_a_registry_that_stops_answering_does_not_hold_the_station(tmp_path, monkeypatch):
    """A server that accepts the connection and then never answers (a dropped network, a stalled
    host): the station warns once its deadline passes and goes on; the session stays complete."""
    import threading

    from fieldcal.registry import record_safely

    unit_file(tmp_path / "a.yaml", "SN-1", [1.0, 0.0, 0.0])
    answer = threading.Event()
    monkeypatch.setattr(Registry, "record", lambda self, *a, **k: answer.wait())  # a server that never replies
    warnings = []
    try:
        assert not record_safely(tmp_path / "a.yaml", None, str(tmp_path / "r.sqlite"), warn=warnings.append,
                                 deadline_s=0.2)
    finally:
        answer.set()  # lets the abandoned record end
    [warning] = warnings
    assert "did not answer within 0.2 s" in warning and "registry rebuild" in warning
