"""The unit registry: every calibration of every unit, in SQLite or PostgreSQL, indexed from
the sessions.

The session directory stays the source of truth; the registry is an index of it that
``fieldcal registry rebuild`` can always re-create. So writing it must never endanger or stop
a calibration: ``record_safely`` turns any failure into a warning.

One row per parameter file (serial, model, station, procedure, method, what made it, the file's
time, SHA-256 and path, pass/fail when a spec was applied), one per triad (its residual), one per
parameter (value and 1σ in operator units, with the unit). A file is recorded once: recording it
again (a rebuild) changes nothing. Each record is one transaction, so a station killed mid-write
leaves nothing half-written, and concurrent stations wait for each other instead of failing or
losing a row (SQLite: WAL, BEGIN IMMEDIATE, a busy timeout; PostgreSQL: the unique key with
INSERT ... ON CONFLICT). The schema is versioned in a ``migrations`` table, the same migrations
for both backends (``backends`` holds the few words that differ).
"""
from __future__ import annotations

import datetime
import hashlib
import os
from pathlib import Path

from fieldcal.registry.backends import RegistryError, open_backend, redact

BUSY_TIMEOUT_S = 10.0
# Each migration: statements separated by ";", with {id} and {float} the backend's words; a
# statement prefixed "sqlite:" runs on SQLite only.
_MIGRATIONS = (
    # version 1
    """
    CREATE TABLE calibrations (
        id {id},
        serial TEXT NOT NULL, model TEXT NOT NULL, station TEXT NOT NULL,
        procedure TEXT NOT NULL, method TEXT NOT NULL, time TEXT NOT NULL,
        params_sha256 TEXT NOT NULL, params_path TEXT NOT NULL, passed INTEGER,
        UNIQUE (params_path, params_sha256));
    CREATE INDEX calibrations_unit ON calibrations (serial, model, time);
    CREATE TABLE triads (
        calibration_id INTEGER NOT NULL REFERENCES calibrations (id) ON DELETE CASCADE,
        triad TEXT NOT NULL, kind TEXT NOT NULL, output_unit TEXT NOT NULL,
        residual_rms {float} NOT NULL, residual_unit TEXT NOT NULL,
        PRIMARY KEY (calibration_id, triad));
    CREATE TABLE parameters (
        calibration_id INTEGER NOT NULL REFERENCES calibrations (id) ON DELETE CASCADE,
        triad TEXT NOT NULL, name TEXT NOT NULL, value {float} NOT NULL, sigma {float} NOT NULL,
        unit TEXT NOT NULL, PRIMARY KEY (calibration_id, triad, name));
    """,
    # version 2: what made each calibration (run, replay, calibrate, resolve; "" when rebuilt
    # from a session), and each parameter's place in its file, for listing them in file order
    # (a PostgreSQL table has no rowid to order by)
    """
    ALTER TABLE calibrations ADD COLUMN source TEXT NOT NULL DEFAULT '';
    ALTER TABLE parameters ADD COLUMN position INTEGER NOT NULL DEFAULT 0;
    sqlite: UPDATE parameters SET position = rowid
    """,
    # version 3: who calibrated (the parameter file's provenance.operator; "" when it names none)
    """
    ALTER TABLE calibrations ADD COLUMN operator TEXT NOT NULL DEFAULT '';
    """,
)
SCHEMA_VERSION = len(_MIGRATIONS)
UNKNOWN = ""  # a serial or model the parameter file does not give
NO_SERIAL = "(none)"  # how `units` lists, and `history` names, the calibrations without a serial
SOURCES = ("", "run", "replay", "calibrate", "resolve")


def default_path() -> Path:
    base = os.environ.get("XDG_DATA_HOME") or os.path.join(os.path.expanduser("~"), ".local", "share")
    return Path(base) / "fieldcal" / "registry.sqlite"


def _statements(script: str, backend) -> list[str]:
    out = []
    for statement in filter(str.strip, script.format(**backend.types).split(";")):
        only, sep, body = statement.strip().partition(": ")
        if sep and only in ("sqlite", "postgresql"):
            if only == backend.kind:
                out.append(body)
        else:
            out.append(statement)
    return out


class Registry:
    """The registry at ``location``: an SQLite file path, or a ``postgresql://`` URL (default:
    the SQLite file under the data directory). ``require_tls``: a PostgreSQL connection without
    TLS is refused."""

    def __init__(self, location: str | os.PathLike | None = None, timeout_s: float = BUSY_TIMEOUT_S,
                 require_tls: bool = False, read_only: bool = False) -> None:
        """``read_only``: for a command that only reads (units, history): an SQLite file that does
        not exist is refused, not created; nothing is migrated."""
        location = default_path() if location is None else location
        self.read_only = read_only
        self.backend = open_backend(location if isinstance(location, str) else Path(location),
                                    timeout_s, require_tls, read_only)
        self.path = getattr(self.backend, "path", None)  # the SQLite file; None on a server
        self.where = self.backend.where  # printable: a password in a URL is hidden
        self.db = self.backend.db
        try:
            self._migrate()
        except BaseException:
            self.backend.close()
            raise

    def close(self) -> None:
        self.backend.close()

    def __enter__(self) -> Registry:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def query(self, sql: str, params=()) -> list[tuple]:
        """Rows of a read-only statement (``?`` placeholders, on either backend)."""
        return self.backend.execute(sql, params).fetchall()

    @property
    def version(self) -> int:
        return self.query("SELECT COALESCE(MAX(version), 0) FROM migrations")[0][0]

    def _transaction(self, work, migrating: bool = False):
        self.backend.begin(migrating)
        try:
            result = work()
        except BaseException:
            try:
                self.backend.rollback()
            except Exception:  # noqa: BLE001 -- a lost connection: the server rolls back itself
                pass
            raise
        self.backend.commit()
        return result

    def _migrate(self) -> None:
        # Read first: a registry already at this version needs no DDL and no migration lock, so
        # a station whose database role may only read and write rows (no CREATE) can record.
        try:
            have = self.version
        except RegistryError:  # no migrations table yet: a new registry
            have = 0
        if have == SCHEMA_VERSION:
            return
        if self.read_only:
            if have == 0:
                raise RegistryError(f"registry {self.where}: no such registry (an empty database: a calibration "
                                    "with --registry, or `fieldcal registry rebuild DIR`, makes one)")
            if have < SCHEMA_VERSION:
                raise RegistryError(f"registry {self.where}: schema version {have}, older than this fieldcal's "
                                    f"({SCHEMA_VERSION}); a command that records (fieldcal registry rebuild) "
                                    "upgrades it")

        def migrate():  # one station migrates; the others wait, then find it done
            self.backend.execute("CREATE TABLE IF NOT EXISTS migrations (version INTEGER PRIMARY KEY, "
                                 "applied TEXT NOT NULL)")
            have = self.version
            if have > SCHEMA_VERSION:
                raise RegistryError(f"{self.where}: registry schema version {have} is newer than this "
                                    f"fieldcal's ({SCHEMA_VERSION}); upgrade fieldcal")
            for version, script in enumerate(_MIGRATIONS[have:], start=have + 1):
                for statement in _statements(script, self.backend):
                    self.backend.execute(statement)
                self.backend.execute("INSERT INTO migrations VALUES (?, ?)", (version, _now()))
        self._transaction(migrate, migrating=True)

    def record(self, params: str | os.PathLike, passed: bool | None = None, source: str = "") -> bool:
        """Index one parameter file; False if it was already there (same path and SHA-256)."""
        from fieldcal.calibration import operator_values  # not acceptance: the spec checks are not needed
        from fieldcal.paramfile import load

        if source not in SOURCES:
            raise ValueError(f"registry: source {source!r}: expected one of {', '.join(map(repr, SOURCES))}")
        path = Path(params).resolve()
        data = path.read_bytes()
        pf = load(path)
        p = pf.provenance
        stamp = datetime.datetime.fromtimestamp(path.stat().st_mtime, datetime.timezone.utc)
        sha = hashlib.sha256(data).hexdigest()
        row = (p.device_serial or UNKNOWN, p.device_name or UNKNOWN,
               f"{p.latitude_deg:.4f}°, {p.height_m:g} m, g {p.gravity_m_s2:.5f} m/s^2",
               p.procedure, p.method, stamp.isoformat(timespec="seconds"),
               sha, str(path), None if passed is None else int(passed), source, p.operator or UNKNOWN)
        triads = [(cal, *operator_values(cal)) for cal in pf.triads]

        def write() -> bool:
            inserted = self.backend.execute(
                "INSERT INTO calibrations (serial, model, station, procedure, method, time, params_sha256, "
                "params_path, passed, source, operator) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?) "
                "ON CONFLICT (params_path, params_sha256) DO NOTHING RETURNING id", row).fetchone()
            if inserted is None:  # indexed already
                if passed is not None:  # a verdict given later (fieldcal check) is kept
                    self.backend.execute("UPDATE calibrations SET passed = ? WHERE params_path = ? AND "
                                         "params_sha256 = ?", (int(passed), str(path), sha))
                return False
            cid = inserted[0]
            position = 0
            for cal, values, sigmas, units in triads:
                self.backend.execute("INSERT INTO triads VALUES (?, ?, ?, ?, ?, ?)",
                                     (cid, cal.name, cal.kind, cal.output_unit, cal.residual_rms,
                                      cal.residual_unit))
                for n, v, s, u in zip(cal.parameter_names, values, sigmas, units):
                    if n in cal.not_calibrated:  # a nominal, no σ: nothing of the unit to track
                        continue
                    self.backend.execute("INSERT INTO parameters (calibration_id, triad, name, value, "
                                         "sigma, unit, position) VALUES (?, ?, ?, ?, ?, ?, ?)",
                                         (cid, cal.name, n, float(v), float(s), u, position))
                    position += 1
            return True
        return self._transaction(write)

    def units(self) -> list[tuple]:
        """(serial, model, calibrations, last time, last pass/fail) per unit."""
        return [tuple(r) for r in self.query(
            "SELECT serial, model, COUNT(*), MAX(time), (SELECT passed FROM calibrations d WHERE "
            "d.serial = c.serial AND d.model = c.model ORDER BY time DESC, id DESC LIMIT 1) "
            "FROM calibrations c GROUP BY serial, model ORDER BY serial, model")]

    def history(self, serial: str) -> list[dict]:
        """The unit's calibrations, oldest first: each a dict with its row and its parameters
        {(triad, name): (value, σ, unit)}."""
        rows = self.query(
            "SELECT id, model, station, procedure, method, time, params_sha256, params_path, passed, "
            "source, operator FROM calibrations WHERE serial = ? ORDER BY time, id", (serial,))
        keys = ("id", "model", "station", "procedure", "method", "time", "sha256", "path", "passed",
                "source", "operator")
        out = []
        for r in rows:
            entry = dict(zip(keys, r))
            entry["parameters"] = {(t, n): (v, s, u) for t, n, v, s, u in self.query(
                "SELECT triad, name, value, sigma, unit FROM parameters WHERE calibration_id = ? "
                "ORDER BY position", (r[0],))}
            out.append(entry)
        return out


def _now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


def session_parameter_files(directory: Path) -> list[Path]:
    """The numbered parameter files of a session (each one calibration), oldest first; a session
    from before numbering: its parameters.yaml."""
    from fieldcal.session.capture import PARAMETERS, PARAMETERS_NUMBERED

    numbered = sorted((int(m.group(1)), p) for p in directory.iterdir()
                      if (m := PARAMETERS_NUMBERED.fullmatch(p.name)))
    if numbered:
        return [p for _, p in numbered]
    return [directory / PARAMETERS] if (directory / PARAMETERS).is_file() else []


def the_calibration_file(params: Path) -> Path:
    """A session's parameters.yaml is a copy: the numbered file with the same bytes is the one
    recorded, so that a rebuild finds the same row."""
    from fieldcal.session.capture import LOG, PARAMETERS

    if params.name != PARAMETERS or not (params.parent / LOG).is_file():
        return params
    data = params.read_bytes()
    same = [p for p in session_parameter_files(params.parent) if p != params and p.read_bytes() == data]
    return same[-1] if same else params


RECORD_DEADLINE_S = 60.0  # past the lock wait and a migration: a registry this slow is not answering


def record_safely(params, passed: bool | None, registry=None, warn=print, source: str = "",
                  require_tls: bool = False, deadline_s: float = RECORD_DEADLINE_S) -> bool:
    """Record ``params`` in the registry at ``registry`` (see ``Registry``); any failure is a
    warning, never an exception: the session is already complete and is the source of truth."""
    failure = _record_or_why_not(params, passed, registry, source, require_tls, deadline_s)
    if failure is not None:
        warn(f"warning: the unit registry ({_where(registry)}) {failure} -- the session is complete; "
             "`fieldcal registry rebuild` will index it")
    return failure is None


def _where(registry) -> str:
    return redact(registry if registry is not None else default_path())


def _record_or_why_not(params, passed: bool | None, registry, source: str, require_tls: bool,
                       deadline_s: float) -> str | None:
    """Record ``params``; None, or why it was not (a phrase after "the unit registry (where)").

    The record runs on a daemon thread the station waits for at most ``deadline_s``: a server that
    stops answering after the connection was made (a dropped network, a stalled host) is beyond
    libpq's connect timeout and the server's own timeouts, and must not hold the station."""
    import threading

    outcome: list[BaseException | None] = []

    def record() -> None:
        try:
            with Registry(registry, require_tls=require_tls) as db:
                db.record(the_calibration_file(Path(params)), passed, source)
            outcome.append(None)
        except BaseException as exc:  # noqa: BLE001 -- handed to the station's thread below
            outcome.append(exc)

    worker = threading.Thread(target=record, name="fieldcal-registry", daemon=True)
    worker.start()
    worker.join(deadline_s)
    if not outcome:
        return f"did not answer within {deadline_s:g} s and was not updated"
    exc = outcome[0]
    if exc is None:
        return None
    where = _where(registry)
    text = str(exc).splitlines()[0] if str(exc) else ""
    if isinstance(exc, RegistryError) and text.startswith(f"registry {where}: "):
        text = text[len(f"registry {where}: "):]
    return f"was not updated: {type(exc).__name__}: {text}"


class BatchRecorder:
    """Records a batch's calibrations (``fieldcal resolve``) in the registry as they come. The
    first that cannot be recorded (a server down or gone mid-batch, no answer, a broken file)
    stops the attempts: it is said once, in one line, and the batch goes on without the registry
    instead of waiting for it again with every session. The sessions are the source of truth:
    ``rebuild`` (the command that indexes them, e.g. ``fieldcal registry rebuild DIR...``) is
    named for the ones left out."""

    def __init__(self, registry, warn=print, source: str = "", require_tls: bool = False,
                 rebuild: str = "fieldcal registry rebuild", deadline_s: float = RECORD_DEADLINE_S):
        self.registry, self.warn, self.source = registry, warn, source
        self.require_tls, self.rebuild, self.deadline_s = require_tls, rebuild, deadline_s
        self.recorded = 0
        self.left_out = 0  # calibrations not recorded (from the first failure on)

    def record(self, params, passed: bool | None = None) -> bool:
        if self.left_out:
            self.left_out += 1
            return False
        failure = _record_or_why_not(params, passed, self.registry, self.source, self.require_tls,
                                     self.deadline_s)
        if failure is None:
            self.recorded += 1
            return True
        self.left_out = 1
        self.warn(f"warning: the unit registry ({_where(self.registry)}) {failure} -- the batch goes on "
                  f"without it (the sessions are complete); `{self.rebuild}` will index them")
        return False

    def summary(self) -> str | None:
        """One line on what the registry missed; None if it missed nothing."""
        if not self.left_out:
            return None
        return (f"{self.left_out} calibration{'s' * (self.left_out != 1)} not in the unit registry "
                f"({_where(self.registry)}): index {'them' if self.left_out != 1 else 'it'} with `{self.rebuild}`")
