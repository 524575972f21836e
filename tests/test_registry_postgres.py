"""A registry on a PostgreSQL server: credentials only through libpq's own mechanisms (a password
in the URL is accepted but never printed, never written into a session), and TLS required when
asked for (a server without TLS is refused). Against the server tests/postgres_server.py starts."""
import hashlib

import pytest

from fieldcal.cli.main import main
from fieldcal.registry import Registry, record_safely
from fieldcal.registry.backends import RegistryError, redact
from postgres_server import SUPERUSER, postgres_server, postgres_tls_server  # noqa: F401 -- the fixtures
from brisk_quick import brisk_quick
from test_registry import unit_file


@pytest.mark.parametrize("url, printed", [
    ("postgresql://line:s3cr%40t@db.example:5432/cal", "postgresql://line:***@db.example:5432/cal"),
    ("postgres://line:pw@h1,h2/cal?sslmode=require", "postgres://line:***@h1,h2/cal?sslmode=require"),
    ("postgresql://line@db/cal?password=pw&sslmode=verify-full",
     "postgresql://line@db/cal?password=***&sslmode=verify-full"),
    ("postgresql://db?sslmode=require&password=pw", "postgresql://db?sslmode=require&password=***"),
    ("postgresql://line@db/cal?service=line1", "postgresql://line@db/cal?service=line1"),
    ("postgresql://line:p@ss/w?rd@db:5432/cal", "postgresql://line:***@db:5432/cal"),  # unescaped
    ("postgresql://", "postgresql://"),
    ("/data/registry.sqlite", "/data/registry.sqlite"),
])
def test_a_password_in_the_url_is_redacted_wherever_printed(url, printed):
    assert redact(url) == printed


@pytest.mark.parametrize("url", ["postgresql://u:p%40ss%1@h/db", "postgresql://u@h/db?password=s%3Fcr%zz"])
def test_a_password_libpq_cannot_parse_is_not_in_its_error(url):
    """libpq quotes a bad token as typed (percent escapes and all), not decoded."""
    pytest.importorskip("psycopg")
    from fieldcal.registry.backends import PostgresBackend

    with pytest.raises(RegistryError) as error:
        PostgresBackend(url, 1)
    assert "invalid percent-encoded token" in str(error.value)
    assert not any(secret in str(error.value) for secret in ("p%40ss%1", "p@ss%1", "s%3Fcr%zz", "s?cr%zz"))


@pytest.fixture
def database(postgres_server):
    return postgres_server.new_database()


def test_credentials_come_from_libpq_pgpassword_pgpass_service_file_or_the_url(
        postgres_server, database, tmp_path, monkeypatch):
    for name in ("PGPASSWORD", "PGPASSFILE", "PGSERVICE", "PGSERVICEFILE", "PGSSLMODE"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("PGPASSFILE", str(tmp_path / "none"))  # never the developer's ~/.pgpass
    url = postgres_server.tcp_url(database)
    with pytest.raises(RegistryError, match="cannot connect") as refused:  # TCP: a password is required
        Registry(url)
    assert str(refused.value).startswith(f"registry {url}: cannot connect:")

    monkeypatch.setenv("PGPASSWORD", postgres_server.password)
    with Registry(url) as registry:
        assert registry.record(unit_file(tmp_path / "a.yaml", "A", [1.0, 0.0, 0.0]))
    monkeypatch.delenv("PGPASSWORD")

    pgpass = tmp_path / "pgpass"
    pgpass.write_text(f"127.0.0.1:{postgres_server.port}:{database}:fieldcal:{postgres_server.password}\n")
    pgpass.chmod(0o600)  # libpq ignores a .pgpass others can read
    monkeypatch.setenv("PGPASSFILE", str(pgpass))
    with Registry(url) as registry:
        assert [u[0] for u in registry.units()] == ["A"]

    # a service file names the server and the database; the password from .pgpass: the URL is bare
    services = tmp_path / "pg_service.conf"
    services.write_text(f"[line]\nhost=127.0.0.1\nport={postgres_server.port}\ndbname={database}\n"
                        "user=fieldcal\n")
    monkeypatch.setenv("PGSERVICEFILE", str(services))
    monkeypatch.setenv("PGSERVICE", "line")
    with Registry("postgresql://") as registry:
        assert [u[0] for u in registry.units()] == ["A"]
    monkeypatch.delenv("PGSERVICE")
    monkeypatch.setenv("PGPASSFILE", str(tmp_path / "none"))

    with_password = postgres_server.tcp_url(database, postgres_server.password)
    with Registry(with_password) as registry:
        assert postgres_server.password not in registry.where and ":***@" in registry.where
    wrong = postgres_server.tcp_url(database, "not-the-password-7f3a")
    with pytest.raises(RegistryError) as refused:
        Registry(wrong)
    assert "not-the-password-7f3a" not in str(refused.value) and "***" in str(refused.value)
    warnings = []
    assert not record_safely(tmp_path / "a.yaml", None, wrong, warn=warnings.append)
    assert len(warnings) == 1 and "not-the-password-7f3a" not in warnings[0]
    assert "`fieldcal registry rebuild` will index it" in warnings[0]


def test_a_run_with_a_password_in_the_url_writes_it_nowhere(postgres_server, database, tmp_path, capsys,
                                                            monkeypatch):
    monkeypatch.delenv("PGPASSWORD", raising=False)
    url = postgres_server.tcp_url(database, postgres_server.password)
    out = tmp_path / "sessions"
    brisk = str(brisk_quick(tmp_path))  # quick.yaml with brisk rate steps: none of this checks their speed
    assert main(["run", "--headless", "--quiet", "--procedure", brisk, "--out", str(out), "--seed", "3",
                 "--registry", url]) == 0
    printed = capsys.readouterr()
    assert main(["units", "--registry", url]) == 0
    assert "(none)" in capsys.readouterr().out  # the simulated MIMU has no serial: recorded
    secret = postgres_server.password.encode()
    assert secret not in (printed.out + printed.err).encode()
    written = [p for p in out.rglob("*") if p.is_file()]
    assert written and all(secret not in p.read_bytes() for p in written)
    with Registry(url) as registry:
        [(source, path)] = registry.query("SELECT source, params_path FROM calibrations")
    assert source == "run" and path.startswith(str(out.resolve()))


def test_tls_required_refuses_a_server_without_it(postgres_server, database, tmp_path, monkeypatch, capsys):
    # the test server has no certificate: over TCP it offers no TLS
    monkeypatch.setenv("PGPASSWORD", postgres_server.password)
    monkeypatch.delenv("PGSSLMODE", raising=False)
    url = postgres_server.tcp_url(database)
    with Registry(url) as registry:  # sslmode's default (prefer) takes what there is
        assert registry.backend.tls is False
    with pytest.raises(RegistryError, match="SSL"):
        Registry(url, require_tls=True)
    with pytest.raises(RegistryError, match="SSL"):  # sslmode in the URL, libpq's own
        Registry(f"{url}?sslmode=require")
    assert main(["units", "--registry", url, "--registry-require-tls"]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "SSL" in err
    monkeypatch.setenv("PGSSLMODE", "require")  # or in the environment
    with pytest.raises(RegistryError, match="SSL"):
        Registry(url)
    with pytest.raises(RegistryError, match="for a PostgreSQL server"):
        Registry(str(tmp_path / "r.sqlite"), require_tls=True)


def test_a_server_lost_mid_use_is_one_line_not_a_traceback(postgres_server, database, tmp_path):
    import psycopg

    with Registry(postgres_server.url(database)) as registry:
        pid = registry.db.info.backend_pid
        with psycopg.connect(postgres_server.url("postgres"), autocommit=True) as admin:
            admin.execute("SELECT pg_terminate_backend(%s)", (pid,))  # what a server restart does
        with pytest.raises(RegistryError) as lost:
            registry.record(unit_file(tmp_path / "a.yaml", "A", [1.0, 0.0, 0.0]))
    assert str(lost.value).startswith(f"registry {postgres_server.url(database)}: terminating connection")
    assert "\n" not in str(lost.value)
    with Registry(postgres_server.url(database)) as registry:  # nothing half-written
        assert registry.units() == []


def test_tls_required_connects_to_a_server_with_tls_and_checks_its_certificate(postgres_tls_server, tmp_path,
                                                                                monkeypatch):
    from postgres_server import self_signed_certificate

    server = postgres_tls_server
    monkeypatch.setenv("PGPASSWORD", server.password)
    monkeypatch.delenv("PGSSLMODE", raising=False)
    url = server.tcp_url(server.new_database())
    with Registry(url, require_tls=True) as registry:
        assert registry.backend.tls is True
        assert registry.record(unit_file(tmp_path / "a.yaml", "A", [1.0, 0.0, 0.0]))
    with Registry(f"{url}?sslmode=verify-full&sslrootcert={server.certificate}", require_tls=True) as registry:
        assert registry.backend.tls is True and [u[0] for u in registry.units()] == ["A"]
    other_ca, _ = self_signed_certificate(tmp_path, "impostor")  # a certificate from another CA
    with pytest.raises(RegistryError, match="certificate verify failed"):
        Registry(f"{url}?sslmode=verify-full&sslrootcert={other_ca}")


def test_a_station_holding_the_lock_makes_another_give_up_after_its_timeout(postgres_server, database,
                                                                            tmp_path):
    params = unit_file(tmp_path / "a.yaml", "A", [1.0, 0.0, 0.0])
    with Registry(postgres_server.url(database)) as stuck:
        stuck.backend.begin()  # a station stopped (not killed) inside its transaction
        stuck.backend.execute(
            "INSERT INTO calibrations (serial, model, station, procedure, method, time, params_sha256, "
            "params_path, passed) SELECT 'A', 'm', 's', 'p', 'powell', 't', ?, ?, NULL",
            (hashlib.sha256(params.read_bytes()).hexdigest(), str(params.resolve())))
        with Registry(postgres_server.url(database), timeout_s=0.5) as other:
            with pytest.raises(RegistryError, match="lock timeout"):
                other.record(params)  # waits for the same key, then gives up: never hangs
        stuck.backend.rollback()
    with Registry(postgres_server.url(database)) as registry:
        assert registry.record(params) and registry.query("SELECT COUNT(*) FROM parameters")[0][0] == 9


def test_a_station_role_that_may_only_read_and_write_rows_records(postgres_server, database, tmp_path):
    """Production lines give stations a role without CREATE: once the schema is there (made by
    an administrator, or the first station with rights), recording needs no DDL."""
    import psycopg

    with Registry(postgres_server.url(database)):
        pass  # the administrator's first open creates the schema
    with psycopg.connect(postgres_server.url(database), autocommit=True) as admin:
        admin.execute("CREATE ROLE station LOGIN")
        admin.execute("REVOKE CREATE ON SCHEMA public FROM PUBLIC")
        admin.execute("GRANT USAGE ON SCHEMA public TO station")
        admin.execute("GRANT SELECT, INSERT, UPDATE ON ALL TABLES IN SCHEMA public TO station")
        admin.execute("GRANT USAGE ON ALL SEQUENCES IN SCHEMA public TO station")
    station_url = postgres_server.url(database).replace(f"postgresql://{SUPERUSER}@", "postgresql://station@")
    unit_file(tmp_path / "a.yaml", "SN-7", [1.0, 0.0, 0.0])
    with Registry(station_url) as registry:
        assert registry.record(tmp_path / "a.yaml", True, "run")
        assert [u[0] for u in registry.query("SELECT serial FROM calibrations")] == ["SN-7"]
