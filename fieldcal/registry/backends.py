"""Where the registry lives: an SQLite file (one station), or a PostgreSQL server that every
station of a line points at (``--registry postgresql://user@host/db``). Both are plain DB-API
connections behind the same four operations, so the registry's SQL and migrations are written
once: statements use ``?`` placeholders and two type names that differ (``{id}``, ``{float}``).

Credentials are libpq's business: a password comes from PGPASSWORD, ~/.pgpass (PGPASSFILE) or a
service file (PGSERVICE), never from fieldcal's own files. A password written into the URL is
accepted but redacted wherever the location is printed (``redact``), and a connection error's
text is scrubbed of it too. TLS: libpq's ``sslmode`` from the URL (``?sslmode=require``) or
PGSSLMODE is honoured; ``require_tls`` makes a connection without TLS fail.
"""
from __future__ import annotations

import os
import re
import sqlite3
import stat
import time
from pathlib import Path
from urllib.parse import quote, unquote

POSTGRES_SCHEMES = ("postgresql", "postgres")
# sslmode values that refuse a connection without TLS (libpq's own words)
TLS_MODES = ("require", "verify-ca", "verify-full")
# one key for the advisory lock under which a station migrates a PostgreSQL registry
_MIGRATION_LOCK = 0x6669656C6463616C  # "fieldcal"
HIDDEN = "***"
# "scheme://": a URL, never a file name (a mistyped scheme must not become ./scheme:/host/db)
_URL = re.compile(r"[A-Za-z][A-Za-z0-9+.\-]*://")


class RegistryError(ValueError):
    """The registry cannot be opened or written (one line, never holding a password)."""


def is_postgres(location) -> bool:
    return isinstance(location, str) and location.split("://", 1)[0].lower() in POSTGRES_SCHEMES \
        and "://" in location


def redact(location) -> str:
    """The registry location as it may be printed: a password in a postgresql:// URL (in
    ``user:PASSWORD@`` or ``?password=``) replaced by ``***``; a file path as it is.

    The user information ends at the URL's last "@", so a password holding "@", "/" or "?"
    unescaped is hidden whole (an "@" in a query value may hide more than the password: never
    less)."""
    text = str(location)
    if not is_postgres(text):
        return text
    scheme, rest = text.split("://", 1)
    userinfo, at, after = rest.rpartition("@")
    if at and ":" in userinfo:
        userinfo = f"{userinfo.split(':', 1)[0]}:{HIDDEN}"
    rest = f"{userinfo}{at}{after}"
    main, question, query = rest.partition("?")
    query = re.sub(r"(^|&)(password=)[^&#]*", rf"\g<1>\g<2>{HIDDEN}", query)
    return f"{scheme}://{main}{question}{query}"


def url_password(location: str) -> tuple[str, ...]:
    """Every form the password of a postgresql:// URL is written in (as typed, percent-decoded),
    longest first, to scrub from error texts: libpq quotes the token as typed, others decoded."""
    typed = []
    userinfo = location.split("://", 1)[-1].rpartition("@")[0]
    if ":" in userinfo:
        typed.append(userinfo.split(":", 1)[1])
    typed += re.findall(r"(?:[?&])password=([^&#]*)", location)
    forms = {form for raw in typed if raw for form in (raw, unquote(raw))}
    return tuple(sorted(forms, key=len, reverse=True))


def _scrub(text: str, secrets: tuple[str, ...]) -> str:
    for secret in secrets:
        text = text.replace(secret, HIDDEN)
    return text


def _refuse_links(path: Path) -> None:
    """The registry file and the journals SQLite writes beside it: never a link (SQLite would
    write through it), never a FIFO or device (fieldcal.atomic's rule)."""
    from fieldcal.atomic import check_appendable

    for name in (path, *(path.with_name(path.name + end) for end in ("-journal", "-wal", "-shm"))):
        try:
            check_appendable(name)
        except ValueError as exc:
            raise RegistryError(f"registry {path}: {exc}") from None


def check_url_scheme(location: str) -> None:
    """A registry given as ``scheme://...`` must be a scheme fieldcal speaks; else one line naming
    the nearest one (a typo must not quietly make a local SQLite file the line never sees)."""
    import difflib

    scheme, rest = location.split("://", 1)
    if scheme in POSTGRES_SCHEMES:  # libpq takes these in lower case only ("PostgreSQL://": a raw parse error)
        return
    nearest = (difflib.get_close_matches(scheme.lower(), POSTGRES_SCHEMES, n=1, cutoff=0.0) or ["postgresql"])[0]
    shown = scheme + redact(f"postgresql://{rest}")[len("postgresql"):]  # a password in it hidden
    raise RegistryError(f"registry {shown}: {scheme}:// is not a registry fieldcal speaks (did you mean "
                        f"{nearest}://?); give postgresql://USER@HOST/DB or an SQLite file path")


def unix_socket_hosts(given: dict) -> list[str]:
    """The unix-socket directories a libpq connection would use (no TLS on them): a host that is
    a path (or empty: libpq's default socket), unless a hostaddr makes it TCP."""
    if given.get("hostaddr") or os.environ.get("PGHOSTADDR"):
        return []
    hosts = (given.get("host") or os.environ.get("PGHOST") or "").split(",")
    return [h or "(the default socket)" for h in hosts if not h or h.startswith(("/", "@"))]


class SqliteBackend:
    """One SQLite file in WAL mode; writers wait for each other up to the busy timeout."""
    kind = "sqlite"
    types = {"id": "INTEGER PRIMARY KEY", "float": "REAL"}

    def __init__(self, path: Path, timeout_s: float, read_only: bool = False) -> None:
        self.path = path
        self.where = str(path)
        _require_database_file(path)
        if read_only and not (path.exists() or path.is_symlink()):  # a command that only reads makes none
            raise RegistryError(f"registry {path}: no such registry (nothing created: a calibration with "
                                "--registry, or `fieldcal registry rebuild DIR`, makes one)")
        try:
            if not read_only:
                path.parent.mkdir(parents=True, exist_ok=True)
            _refuse_links(path)
            if read_only:  # SQLite's own read-only open: never creates nor changes the database
                uri = f"file:{quote(os.path.abspath(path))}?mode=ro"
                self.db = sqlite3.connect(uri, uri=True, timeout=timeout_s, isolation_level=None)
            else:
                # absolute: SQLite built with URI names would read "file:..." as a URI
                self.db = sqlite3.connect(os.path.abspath(path), timeout=timeout_s, isolation_level=None)
        except (OSError, sqlite3.Error) as exc:
            raise RegistryError(f"registry {self.where}: cannot open it ({getattr(exc, 'strerror', None) or exc})") from None
        try:
            self.db.execute(f"PRAGMA busy_timeout = {int(timeout_s * 1000)}")
            if read_only:
                self.db.execute("SELECT 1 FROM sqlite_master LIMIT 1")  # "file is not a database" now
            else:
                self._wal(timeout_s)
            self.db.execute("PRAGMA foreign_keys = ON")
        except sqlite3.Error as exc:  # not a database, unreadable
            self.db.close()
            raise RegistryError(f"registry {self.where}: {exc}") from None

    def _wal(self, timeout_s: float) -> None:
        """Switch to WAL. The switch needs the database to itself and SQLite answers "locked" at
        once, without its busy handler, while another station opens the same new file: wait and
        try again, as the busy timeout would."""
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                self.db.execute("PRAGMA journal_mode = WAL")
                return
            except sqlite3.OperationalError as exc:
                if "locked" not in str(exc) or time.monotonic() > deadline:
                    raise
                time.sleep(0.01)

    def execute(self, sql: str, params=()):
        try:
            return self.db.execute(sql, params)
        except sqlite3.Error as exc:  # locked past the timeout, disk full, not a database
            raise RegistryError(f"registry {self.where}: {exc}") from None

    def begin(self, migrating: bool = False) -> None:
        # IMMEDIATE: the write lock now, so two stations never both read then both write
        self.execute("BEGIN IMMEDIATE")

    def commit(self) -> None:
        self.execute("COMMIT")

    def rollback(self) -> None:
        self.execute("ROLLBACK")

    def close(self) -> None:
        self.db.close()


def _postgres_tls_mode(url: str, require_tls: bool) -> str | None:
    """The sslmode a PostgreSQL URL asks for, once the URL is known to parse and its TLS rule to
    hold for its transport (no connection made)."""
    where, secret = redact(url), url_password(url)
    try:
        import psycopg
        from psycopg.conninfo import conninfo_to_dict
    except ImportError:
        raise RegistryError(f"registry {where}: PostgreSQL needs psycopg: "
                            "pip install 'fieldcal[postgres]'") from None
    try:
        given = conninfo_to_dict(url)
    except psycopg.Error as exc:
        raise RegistryError(f"registry {where}: not a PostgreSQL URL: "
                            f"{_scrub(str(exc), secret).splitlines()[0]}") from None
    mode = given.get("sslmode") or os.environ.get("PGSSLMODE")
    sockets = unix_socket_hosts(given)
    if (require_tls or mode in TLS_MODES) and sockets:  # libpq would connect without TLS
        why = "--registry-require-tls" if require_tls else f"sslmode={mode}"
        raise RegistryError(f"registry {where}: {why} asks for TLS, but the connection would go "
                            f"through the unix socket {sockets[0]}, which has no TLS: give a TCP host "
                            "(postgresql://USER@HOST/DB), or drop the TLS requirement for a local socket")
    return mode


class PostgresBackend:
    """A PostgreSQL server through psycopg 3 (libpq): explicit transactions, READ COMMITTED;
    concurrent stations are serialised by the unique key (INSERT ... ON CONFLICT) and, while
    migrating, by an advisory lock."""
    kind = "postgresql"
    types = {"id": "BIGINT GENERATED BY DEFAULT AS IDENTITY PRIMARY KEY", "float": "DOUBLE PRECISION"}

    def __init__(self, url: str, timeout_s: float, require_tls: bool = False) -> None:
        self.where = redact(url)
        secret = url_password(url)
        mode = _postgres_tls_mode(url, require_tls)  # psycopg there, the URL parsed, TLS possible
        import psycopg

        self._errors = psycopg.Error
        options = {"connect_timeout": max(1, round(timeout_s)), "application_name": "fieldcal",
                   # a TCP peer gone silent is found in about 25 s instead of the system's 2 h
                   "keepalives": 1, "keepalives_idle": 10, "keepalives_interval": 5, "keepalives_count": 3}
        if require_tls and mode not in TLS_MODES:
            options["sslmode"] = "require"  # a stricter mode the user gave (verify-*) is kept
        try:
            self.db = psycopg.connect(url, autocommit=True, **options)
        except psycopg.Error as exc:
            lines = [line.strip() for line in _scrub(str(exc), secret).splitlines() if line.strip()]
            raise RegistryError(f"registry {self.where}: cannot connect: {' '.join(lines)[:300]}") from None
        self.tls = self.db.info.pgconn.ssl_in_use
        self._secret = secret
        # As SQLite's busy timeout: a station waits this long for another's lock, then gives up
        # (a warning; the session is complete); and a station stuck inside a transaction has it
        # ended by the server instead of holding its locks for ever.
        milliseconds = max(1, round(timeout_s * 1000))
        self.execute(f"SET lock_timeout = {milliseconds}")
        self.execute(f"SET idle_in_transaction_session_timeout = {6 * milliseconds}")

    def execute(self, sql: str, params=()):
        try:
            return self.db.execute(sql.replace("?", "%s"), params)
        except self._errors as exc:  # the server gone, a statement refused: one line
            text = " ".join(line.strip() for line in _scrub(str(exc), self._secret).splitlines())
            raise RegistryError(f"registry {self.where}: {text[:300]}") from None

    def begin(self, migrating: bool = False) -> None:
        self.execute("BEGIN")
        if migrating:  # one station migrates; the others wait here, then find it done
            self.execute("SELECT pg_advisory_xact_lock(?)", (_MIGRATION_LOCK,))

    def commit(self) -> None:
        self.execute("COMMIT")

    def rollback(self) -> None:
        if not self.db.closed:
            self.execute("ROLLBACK")

    def close(self) -> None:
        self.db.close()


def _require_database_file(path: Path) -> None:
    """An existing registry path must be a regular file: a directory, a FIFO or a device is
    refused in one line (SQLite's own error is a traceback-bound OperationalError, and a FIFO
    could block it)."""
    try:
        mode = path.stat().st_mode
    except OSError:
        return  # none yet: created
    if not stat.S_ISREG(mode):
        what = "a directory" if stat.S_ISDIR(mode) else "a FIFO" if stat.S_ISFIFO(mode) else "not a regular file"
        raise RegistryError(f"registry {path}: is {what}, not an SQLite file: name the registry file "
                            f"(e.g. {path / 'registry.sqlite' if stat.S_ISDIR(mode) else 'registry.sqlite'})")


def _check_kind(location, require_tls: bool) -> None:
    """What every opening checks first: a URL of a scheme fieldcal speaks, no SQLite URI taken
    for a path, --registry-require-tls only for a server."""
    if isinstance(location, str) and _URL.match(location):
        check_url_scheme(location)
    if is_postgres(location):
        return
    if str(location).startswith("file:"):  # SQLite (built with URI names) would open ./x.db for file:x.db
        raise RegistryError(f"registry {location}: an SQLite URI is not a registry location: give the "
                            f"file's path ({str(location)[len('file:'):].split('?')[0] or 'registry.sqlite'})")
    if require_tls:
        raise RegistryError(f"registry {location}: --registry-require-tls is for a PostgreSQL server "
                            "(postgresql://...); an SQLite file has no connection to protect")


def check_location(location, require_tls: bool = False) -> None:
    """Everything about a registry location that can be known without connecting to it, for a
    command to refuse before its long work: the scheme, the URL and its TLS rule, the kind of the
    SQLite file, links at it or at its journals, and a folder it could be made in."""
    _check_kind(location, require_tls)
    if is_postgres(location):
        _postgres_tls_mode(location, require_tls)
        return
    path = Path(location)
    for folder in path.parents:  # the nearest existing one: where the file (or its folder) is made
        if folder.exists() or folder.is_symlink():
            if not folder.is_dir():
                raise RegistryError(f"registry {path}: {folder} is a file, not a directory")
            break
    _require_database_file(path)
    _refuse_links(path)


def open_backend(location, timeout_s: float, require_tls: bool = False, read_only: bool = False):
    _check_kind(location, require_tls)
    if is_postgres(location):
        return PostgresBackend(location, timeout_s, require_tls)
    return SqliteBackend(Path(location), timeout_s, read_only)
