"""Issue 25, items 6, 9, 10, 13: what --registry names is what is used, or one line says why not."""
import hashlib
import os
from pathlib import Path

import pytest

from fieldcal.cli.main import main
from fieldcal.registry import Registry
from fieldcal.registry.backends import RegistryError
from brisk_quick import brisk_quick

QUICK = str(Path(__file__).parent / "faults" / "quick.yaml")


@pytest.mark.parametrize("url, nearest", [("postgressql://line@db.plant/fieldcal", "postgresql"),
                                          ("mysql://line@db.plant/fieldcal", "postgresql"),
                                          ("postgres+psycopg://line:s3cret@db.plant/fieldcal", "postgres")])
def test_a_mistyped_url_is_refused_and_makes_no_file(tmp_path, monkeypatch, capsys, url, nearest):
    """It used to become ./postgressql:/line@db.plant/fieldcal, an SQLite file the line never sees."""
    monkeypatch.chdir(tmp_path)
    assert main(["units", "--registry", url]) == 2
    err = capsys.readouterr().err
    assert f"did you mean {nearest}://?" in err and url.split("://")[0] + "://" in err
    assert len(err.splitlines()) == 1 and "s3cret" not in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("url", ["postgresql:///fieldcal", "postgresql://line@/fieldcal?host=/run/postgresql",
                                 "postgresql://line@%2Frun%2Fpostgresql/fieldcal"])
def test_tls_required_over_a_unix_socket_is_refused(url, monkeypatch):
    """libpq ignores sslmode on a unix socket: the README promises such a connection is refused."""
    monkeypatch.delenv("PGHOST", raising=False)
    monkeypatch.delenv("PGHOSTADDR", raising=False)
    monkeypatch.delenv("PGSSLMODE", raising=False)
    with pytest.raises(RegistryError, match="unix socket .* has no TLS"):
        Registry(url, require_tls=True)
    with pytest.raises(RegistryError, match="sslmode=require asks for TLS"):
        Registry(url + ("&" if "?" in url else "?") + "sslmode=require")
    monkeypatch.setenv("PGSSLMODE", "verify-full")
    with pytest.raises(RegistryError, match="sslmode=verify-full asks for TLS"):
        Registry(url)


def test_a_directory_or_fifo_as_registry_is_one_line(tmp_path, capsys):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    for where, what in ((tmp_path, "a directory"), (fifo, "a FIFO")):
        for argv in (["units"], ["registry", "rebuild", str(tmp_path)]):
            assert main([*argv, "--registry", str(where)]) == 2
            err = capsys.readouterr().err
            assert err.startswith(f"fieldcal: registry {where}: is {what}, not an SQLite file") and err.count("\n") == 1


def test_rebuild_does_not_index_a_file_edited_after_calibration(tmp_path, capsys):
    brisk = brisk_quick(tmp_path)  # the quick procedure in half its CPU: the rate steps' speed is not checked here
    assert main(["run", "--headless", "--quiet", "--procedure", str(brisk), "--out", str(tmp_path / "s"),
                 "--seed", "8", "--registry", str(tmp_path / "first.sqlite")]) == 0
    [session] = (tmp_path / "s").iterdir()
    numbered = session / "parameters-001.yaml"
    numbered.write_text(numbered.read_text().replace("device_name:", "device_name: edited", 1)
                        if "device_name:" in numbered.read_text() else numbered.read_text() + "# edited\n")
    capsys.readouterr()
    db = tmp_path / "r.sqlite"
    assert main(["registry", "rebuild", str(tmp_path / "s"), "--registry", str(db)]) == 0
    captured = capsys.readouterr()
    assert "0 calibrations added" in captured.out and "1 edited after calibration (not indexed)" in captured.out
    assert f"{numbered}: not indexed: edited after calibration" in captured.err
    with Registry(db) as registry:
        shas = [r[0] for r in registry.query("SELECT params_sha256 FROM calibrations")]
    assert hashlib.sha256(numbered.read_bytes()).hexdigest() not in shas


@pytest.mark.parametrize("argv", [["units"], ["history", "A"]])
def test_a_read_only_command_creates_no_registry(tmp_path, capsys, argv):
    """Issue 25 (last review, item 5): `units --registry new.sqlite` created an empty database
    (and its folder) and said "no units"; a mistyped path thus grew registries. Now: one line,
    nothing created; an existing registry is opened read-only and left byte for byte."""
    new = tmp_path / "typo" / "new.sqlite"
    assert main([*argv, "--registry", str(new)]) == 2
    assert capsys.readouterr().err == (
        f"fieldcal: registry {new}: no such registry (nothing created: a calibration with --registry, "
        "or `fieldcal registry rebuild DIR`, makes one)\n")
    assert not new.parent.exists()
    empty = tmp_path / "empty.sqlite"
    empty.touch()  # a file, no tables: no registry either, and left empty
    assert main([*argv, "--registry", str(empty)]) == 2
    assert "no such registry (an empty database" in capsys.readouterr().err
    assert empty.read_bytes() == b""
    db = tmp_path / "r.sqlite"
    Registry(db).close()
    before = db.read_bytes()
    assert main([*argv, "--registry", str(db)]) in (0, 2)  # no units / no unit A: said, not a new file
    assert db.read_bytes() == before


def _bad_registries(tmp_path):
    """Registry locations that cannot take the record, each with what the refusal must say."""
    fifo = tmp_path / "fifo.sqlite"
    os.mkfifo(fifo)
    victim = tmp_path / "victim.sqlite"
    victim.write_bytes(b"")
    link = tmp_path / "link.sqlite"
    link.symlink_to(victim)
    return [("mysql://a@b/c", "did you mean postgresql://?"),
            ("PostgreSQL://line@db.plant/fieldcal", "did you mean postgresql://?"),
            (str(tmp_path), "is a directory, not an SQLite file"),
            (str(fifo), "is a FIFO, not an SQLite file"),
            (str(link), "link"),
            ("postgresql://line@/fieldcal?host=/run/postgresql&sslmode=require", "unix socket"),
            ("file:x.db", "an SQLite URI is not a registry location: give the file's path (x.db)"),
            (str(victim / "registry.sqlite"), f"{victim} is a file, not a directory")]


@pytest.mark.parametrize("command", ["run", "calibrate"])
def test_a_bad_registry_is_refused_before_the_run(tmp_path, monkeypatch, capsys, command):
    """Issue 25, round 4, item 1: these were found only after the whole run ("warning: the unit
    registry (...) was not updated", exit 0); now one line, exit 2, and no device work: no session
    made, nothing calibrated, no ./x.db."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("PGHOST", raising=False)
    monkeypatch.delenv("PGHOSTADDR", raising=False)
    session = None
    if command == "calibrate":  # a finished session, calibrated again in place
        brisk = str(brisk_quick(tmp_path))  # quick.yaml with brisk rate steps: their speed is not checked here
        assert main(["run", "--headless", "--quiet", "--procedure", brisk, "--out", str(tmp_path / "done"),
                     "--seed", "3"]) == 0
        [session] = (tmp_path / "done").iterdir()
        before = sorted(p.name for p in session.iterdir())
        capsys.readouterr()
    (tmp_path / "places").mkdir()
    for registry, said in _bad_registries(tmp_path / "places"):
        out = tmp_path / "sessions"
        argv = (["run", "--headless", "--quiet", "--procedure", QUICK, "--out", str(out), "--seed", "3"]
                if command == "run" else ["calibrate", str(session)])
        assert main([*argv, "--registry", registry]) == 2, registry
        captured = capsys.readouterr()
        assert captured.err.startswith("fieldcal: registry ") and said in captured.err, captured.err
        assert captured.err.count("\n") == 1 and captured.out == ""
        assert not out.exists()
        if session is not None:
            assert sorted(p.name for p in session.iterdir()) == before
    assert not (tmp_path / "x.db").exists()
    assert (tmp_path / "places" / "victim.sqlite").read_bytes() == b""


def test_a_capitalised_scheme_names_the_nearest_one():
    """`PostgreSQL://...` reached libpq, whose answer was a raw `missing "=" after ...`."""
    with pytest.raises(RegistryError, match=r"PostgreSQL:// is not a registry fieldcal speaks \(did you mean "
                                            r"postgresql://\?\)"):
        Registry("PostgreSQL://line:s3cret@db.plant/fieldcal")


def test_an_sqlite_uri_makes_no_file(tmp_path, monkeypatch):
    """`file:x.db` was taken by SQLite as a URI and quietly made ./x.db."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(RegistryError, match=r"give the file's path \(x.db\)"):
        Registry("file:x.db")
    assert list(tmp_path.iterdir()) == []
