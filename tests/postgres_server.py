"""A throwaway PostgreSQL server for the registry tests, started by the test suite itself.

``initdb`` and ``pg_ctl`` (Debian's postgresql package) on a fresh temporary directory; the
server listens on a unix socket in that directory (trust: the tests' own connections) and on
127.0.0.1 at a free port (password only: what a remote station does). Each pytest-xdist worker
starts its own, so parallel runs never share a port, a directory or a database. As root, the
server runs as the ``postgres`` user (PostgreSQL refuses to run as root).

A machine without the server binaries (or without psycopg) skips these tests with the reason;
``FIELDCAL_REQUIRE_POSTGRES=1`` (set by .ci/run) turns that skip into a failure, so CI never
passes without having run them.
"""
from __future__ import annotations

import glob
import itertools
import os
import pwd
import secrets
import shutil
import socket
import subprocess
import tempfile
from pathlib import Path

import pytest

SERVER_USER = "postgres"  # the account Debian's package creates; used only when we are root
SUPERUSER = "fieldcal"


def server_binaries() -> Path | None:
    """The directory holding initdb and pg_ctl: on the PATH, or Debian's versioned one."""
    found = shutil.which("pg_ctl")
    candidates = ([Path(found).resolve().parent] if found else []) + \
        [Path(d) for d in sorted(glob.glob("/usr/lib/postgresql/*/bin"), reverse=True)]
    for d in candidates:
        if (d / "initdb").is_file() and (d / "pg_ctl").is_file():
            return d
    return None


def unavailable(reason: str):
    if os.environ.get("FIELDCAL_REQUIRE_POSTGRES"):
        pytest.fail(f"FIELDCAL_REQUIRE_POSTGRES is set but {reason}")
    pytest.skip(reason)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def self_signed_certificate(directory: Path, name: str) -> tuple[Path, Path]:
    """(certificate, key) for 127.0.0.1, made with openssl; it is its own CA."""
    crt, key = directory / f"{name}.crt", directory / f"{name}.key"
    subprocess.run(["openssl", "req", "-new", "-x509", "-days", "2", "-nodes", "-subj", "/CN=127.0.0.1",
                    "-addext", "subjectAltName=IP:127.0.0.1", "-keyout", str(key), "-out", str(crt)],
                   check=True, capture_output=True, timeout=60)
    key.chmod(0o600)
    return crt, key


class PostgresServer:
    def __init__(self, bindir: Path, tls: bool = False) -> None:
        self.bindir = bindir
        self.tls = tls
        self.certificate = None
        self.root = Path(tempfile.mkdtemp(prefix="fieldcal-pg-"))
        self.data = self.root / "data"
        self.password = secrets.token_hex(16)
        self.port = 0
        self._names = itertools.count(1)
        self.run_as = None
        if os.geteuid() == 0:
            try:
                account = pwd.getpwnam(SERVER_USER)
            except KeyError:
                shutil.rmtree(self.root)
                unavailable(f"running as root and there is no {SERVER_USER!r} user to run PostgreSQL as")
            os.chown(self.root, account.pw_uid, account.pw_gid)
            self.run_as = SERVER_USER

    def _run(self, *argv: str) -> None:
        done = subprocess.run([str(self.bindir / argv[0]), *argv[1:]], cwd=self.root, user=self.run_as,
                              capture_output=True, text=True, timeout=120)
        if done.returncode != 0:
            raise RuntimeError(f"{' '.join(argv[:2])} failed ({done.returncode}): {done.stdout}{done.stderr}")

    def start(self) -> PostgresServer:
        pwfile = self.root / "pwfile"
        pwfile.write_text(self.password + "\n")
        if self.run_as:
            shutil.chown(pwfile, self.run_as)
        self._run("initdb", "-D", str(self.data), "-U", SUPERUSER, "-E", "UTF8", "--no-sync",
                  "--auth-local=trust", "--auth-host=scram-sha-256", f"--pwfile={pwfile}")
        pwfile.unlink()
        with open(self.data / "postgresql.conf", "a") as conf:
            # fsync off: the tests kill clients, never this server; it goes with its directory
            conf.write(f"\nlisten_addresses = '127.0.0.1'\nunix_socket_directories = '{self.root}'\n"
                       "fsync = off\nmax_connections = 40\nshared_buffers = 16MB\n")
            if self.tls:
                self.certificate, key = self_signed_certificate(self.root, "server")
                if self.run_as:
                    shutil.chown(key, self.run_as)
                conf.write(f"ssl = on\nssl_cert_file = '{self.certificate}'\nssl_key_file = '{key}'\n")
        for attempt in range(5):  # another worker may take the free port first: try another
            self.port = _free_port()
            try:
                self._run("pg_ctl", "-D", str(self.data), "-l", str(self.root / "server.log"), "-w",
                          "-t", "60", "-o", f"-p {self.port}", "start")
                return self
            except RuntimeError:
                if attempt == 4:
                    raise

    def stop(self) -> None:
        try:
            if self.port:
                self._run("pg_ctl", "-D", str(self.data), "-m", "immediate", "-w", "stop")
        finally:
            shutil.rmtree(self.root, ignore_errors=True)

    def url(self, dbname: str) -> str:
        """Over the unix socket: no password (trust), no TLS."""
        return f"postgresql://{SUPERUSER}@/{dbname}?host={self.root}&port={self.port}"

    def tcp_url(self, dbname: str, password: str | None = None) -> str:
        """Over TCP on 127.0.0.1, as a remote station: the password is required."""
        secret = f":{password}" if password is not None else ""
        return f"postgresql://{SUPERUSER}{secret}@127.0.0.1:{self.port}/{dbname}"

    def new_database(self) -> str:
        """A new empty database's name (each test its own: migrations start from nothing)."""
        import psycopg

        name = f"t{os.getpid()}_{next(self._names)}"
        with psycopg.connect(self.url("postgres"), autocommit=True) as admin:
            admin.execute(f"CREATE DATABASE {name}")
        return name


def _started(tls: bool = False):
    try:
        import psycopg  # noqa: F401
    except ImportError:
        unavailable("psycopg is not installed (pip install -e '.[test]')")
    bindir = server_binaries()
    if bindir is None:
        unavailable("no PostgreSQL server binaries (initdb, pg_ctl): apt-get install postgresql, "
                    "or run .ci/run, to run the PostgreSQL registry tests")
    if tls and shutil.which("openssl") is None:
        unavailable("no openssl to make the TLS server's certificate")
    server = PostgresServer(bindir, tls)
    try:
        server.start()
    except BaseException:
        server.stop()
        raise
    return server


@pytest.fixture(scope="session")
def postgres_server():
    """A server without TLS (a test shows TLS-required connections refuse it)."""
    server = _started()
    yield server
    server.stop()


@pytest.fixture
def postgres_tls_server():
    """A server offering TLS with a self-signed certificate for 127.0.0.1 (``.certificate``)."""
    server = _started(tls=True)
    yield server
    server.stop()
