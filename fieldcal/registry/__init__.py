"""The unit registry: every calibration of every unit, in SQLite, indexed from the sessions.

The session directory stays the source of truth; the registry is an index of it that
``fieldcal registry rebuild`` can always re-create. So writing it must never endanger or stop
a calibration: ``record_safely`` turns any failure into a warning.

One row per parameter file (serial, model, station, procedure, method, the file's time, SHA-256
and path, pass/fail when a spec was applied), one per triad (its residual), one per parameter
(value and 1σ in operator units, with the unit). A file is recorded once: recording it again
(a rebuild) changes nothing. SQLite in WAL mode with a busy timeout, each record one
``BEGIN IMMEDIATE`` transaction, so concurrent stations wait for each other instead of failing
or losing a row; the schema is versioned in a ``migrations`` table.
"""
from __future__ import annotations

import datetime
import hashlib
import os
import sqlite3
import time
from pathlib import Path

BUSY_TIMEOUT_S = 10.0
_MIGRATIONS = (
    # version 1
    """
    CREATE TABLE calibrations (
        id INTEGER PRIMARY KEY,
        serial TEXT NOT NULL, model TEXT NOT NULL, station TEXT NOT NULL,
        procedure TEXT NOT NULL, method TEXT NOT NULL, time TEXT NOT NULL,
        params_sha256 TEXT NOT NULL, params_path TEXT NOT NULL, passed INTEGER,
        UNIQUE (params_path, params_sha256));
    CREATE INDEX calibrations_unit ON calibrations (serial, model, time);
    CREATE TABLE triads (
        calibration_id INTEGER NOT NULL REFERENCES calibrations (id) ON DELETE CASCADE,
        triad TEXT NOT NULL, kind TEXT NOT NULL, output_unit TEXT NOT NULL,
        residual_rms REAL NOT NULL, residual_unit TEXT NOT NULL,
        PRIMARY KEY (calibration_id, triad));
    CREATE TABLE parameters (
        calibration_id INTEGER NOT NULL REFERENCES calibrations (id) ON DELETE CASCADE,
        triad TEXT NOT NULL, name TEXT NOT NULL, value REAL NOT NULL, sigma REAL NOT NULL,
        unit TEXT NOT NULL, PRIMARY KEY (calibration_id, triad, name));
    """,
)
UNKNOWN = ""  # a serial or model the parameter file does not give


def default_path() -> Path:
    base = os.environ.get("XDG_DATA_HOME") or os.path.join(os.path.expanduser("~"), ".local", "share")
    return Path(base) / "fieldcal" / "registry.sqlite"


class Registry:
    def __init__(self, path: str | os.PathLike | None = None, timeout_s: float = BUSY_TIMEOUT_S) -> None:
        self.path = Path(path) if path is not None else default_path()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.db = sqlite3.connect(self.path, timeout=timeout_s, isolation_level=None)
        self.db.execute(f"PRAGMA busy_timeout = {int(timeout_s * 1000)}")
        self._wal(timeout_s)
        self.db.execute("PRAGMA foreign_keys = ON")
        self._migrate()

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

    def close(self) -> None:
        self.db.close()

    def __enter__(self) -> Registry:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def version(self) -> int:
        return self.db.execute("SELECT COALESCE(MAX(version), 0) FROM migrations").fetchone()[0]

    def _migrate(self) -> None:
        self.db.execute("BEGIN IMMEDIATE")  # one station migrates; the others wait, then see it done
        try:
            self.db.execute("CREATE TABLE IF NOT EXISTS migrations (version INTEGER PRIMARY KEY, "
                            "applied TEXT NOT NULL)")
            have = self.version
            if have > len(_MIGRATIONS):
                raise ValueError(f"{self.path}: registry schema version {have} is newer than this "
                                 f"fieldcal's ({len(_MIGRATIONS)}); upgrade fieldcal")
            for version, script in enumerate(_MIGRATIONS[have:], start=have + 1):
                for statement in filter(str.strip, script.split(";")):
                    self.db.execute(statement)
                self.db.execute("INSERT INTO migrations VALUES (?, ?)", (version, _now()))
            self.db.execute("COMMIT")
        except BaseException:
            self.db.execute("ROLLBACK")
            raise

    def record(self, params: str | os.PathLike, passed: bool | None = None) -> bool:
        """Index one parameter file; False if it was already there (same path and SHA-256)."""
        from fieldcal.acceptance import operator_values
        from fieldcal.paramfile import load

        path = Path(params).resolve()
        data = path.read_bytes()
        pf = load(path)
        p = pf.provenance
        stamp = datetime.datetime.fromtimestamp(path.stat().st_mtime, datetime.timezone.utc)
        row = (p.device_serial or UNKNOWN, p.device_name or UNKNOWN,
               f"{p.latitude_deg:.4f}°, {p.height_m:g} m, g {p.gravity_m_s2:.5f} m/s^2",
               p.procedure, p.method, stamp.isoformat(timespec="seconds"),
               hashlib.sha256(data).hexdigest(), str(path), None if passed is None else int(passed))
        self.db.execute("BEGIN IMMEDIATE")
        try:
            cursor = self.db.execute(
                "INSERT OR IGNORE INTO calibrations (serial, model, station, procedure, method, time, "
                "params_sha256, params_path, passed) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)", row)
            if cursor.rowcount == 0:
                if passed is not None:  # a verdict given later (fieldcal check) is kept
                    self.db.execute("UPDATE calibrations SET passed = ? WHERE params_path = ? AND "
                                    "params_sha256 = ?", (int(passed), row[7], row[6]))
                self.db.execute("COMMIT")
                return False
            cid = cursor.lastrowid
            for cal in pf.triads:
                self.db.execute("INSERT INTO triads VALUES (?, ?, ?, ?, ?, ?)",
                                (cid, cal.name, cal.kind, cal.output_unit, cal.residual_rms, cal.residual_unit))
                values, sigmas, units = operator_values(cal)
                self.db.executemany("INSERT INTO parameters VALUES (?, ?, ?, ?, ?, ?)",
                                    [(cid, cal.name, n, float(v), float(s), u) for n, v, s, u
                                     in zip(cal.parameter_names, values, sigmas, units)])
            self.db.execute("COMMIT")
            return True
        except BaseException:
            self.db.execute("ROLLBACK")
            raise

    def units(self) -> list[tuple]:
        """(serial, model, calibrations, last time, last pass/fail) per unit."""
        return self.db.execute(
            "SELECT serial, model, COUNT(*), MAX(time), (SELECT passed FROM calibrations d WHERE "
            "d.serial = c.serial AND d.model = c.model ORDER BY time DESC, id DESC LIMIT 1) "
            "FROM calibrations c GROUP BY serial, model ORDER BY serial, model").fetchall()

    def history(self, serial: str) -> list[dict]:
        """The unit's calibrations, oldest first: each a dict with its row and its parameters
        {(triad, name): (value, σ, unit)}."""
        rows = self.db.execute(
            "SELECT id, model, station, procedure, method, time, params_sha256, params_path, passed "
            "FROM calibrations WHERE serial = ? ORDER BY time, id", (serial,)).fetchall()
        keys = ("id", "model", "station", "procedure", "method", "time", "sha256", "path", "passed")
        out = []
        for r in rows:
            entry = dict(zip(keys, r))
            entry["parameters"] = {(t, n): (v, s, u) for t, n, v, s, u in self.db.execute(
                "SELECT triad, name, value, sigma, unit FROM parameters WHERE calibration_id = ? "
                "ORDER BY rowid", (r[0],))}
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


def record_safely(params, passed: bool | None, registry_path=None, warn=print) -> bool:
    """Record ``params`` in the registry; any failure is a warning, never an exception: the
    session is already complete and is the source of truth."""
    try:
        with Registry(registry_path) as registry:
            registry.record(the_calibration_file(Path(params)), passed)
        return True
    except Exception as exc:  # noqa: BLE001 -- the registry must never fail a calibration
        warn(f"warning: the unit registry ({registry_path or default_path()}) was not updated: "
             f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''} -- the session is "
             "complete; `fieldcal registry rebuild` will index it")
        return False
