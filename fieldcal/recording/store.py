"""A :class:`Recording` as a session directory, and back, bit for bit.

The session format is ``fieldcal.session.capture``'s; a recording session is told apart by its start
metadata ``"kind": "recording"``, which also holds everything needed to read it back and to
trace it to its sources: the triads' kinds and units, the rate, each source file with its
SHA-256 and malformed lines, and the import map's text. The samples follow as SampleChunks of
CHUNK_SAMPLES, and the run stops with reason "imported": a session without that stop is an
import that broke off, and is refused.
"""
from __future__ import annotations

import hashlib
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from drivers.chunk import SampleChunk
from fieldcal import __version__
from fieldcal.recording import Recording
from fieldcal.session.capture import SessionWriter

KIND = "recording"
STOP_REASON = "imported"
CHUNK_SAMPLES = 10000


class RecordingSessionError(ValueError):
    def __init__(self, message: str, path: str = ""):
        super().__init__(message)
        self.path = path


def save_recording(recording: Recording, directory: str | os.PathLike,
                   metadata_extra: Mapping | None = None, *, report=None) -> Path:
    """Write ``recording`` as a new session in ``directory`` (refused if it exists, non-empty).

    ``report`` (an ``importer.ImportReport``) adds the sources' SHA-256 as parsed, the map and
    what the import did; without it the sources are hashed now, if they are still there.
    ``metadata_extra`` adds keys to the start metadata (a key it would replace is an error).
    """
    writer = write_recording(recording, directory, metadata_extra, report=report)
    writer.close()
    return writer.directory


def write_recording(recording: Recording, directory: str | os.PathLike,
                    metadata_extra: Mapping | None = None, *, report=None) -> SessionWriter:
    """As save_recording, but the session's writer is returned still open, the import stopped:
    what is written next (the calibration's parameter file) goes through it, the session neither
    reopened nor its samples read back and checked again (``SessionWriter.append_to``)."""
    metadata = recording_metadata(recording, report)
    for key, value in (metadata_extra or {}).items():
        if key in metadata:
            raise ValueError(f"metadata_extra: {key!r} is written by save_recording itself")
        metadata[key] = value
    writer = SessionWriter.create(directory, metadata)
    try:
        n = len(recording.t)
        for i in range(0, n, CHUNK_SAMPLES):
            writer.chunk(SampleChunk(t=recording.t[i:i + CHUNK_SAMPLES],
                                     triads={name: v[i:i + CHUNK_SAMPLES]
                                             for name, v in recording.triads.items()}))
        writer.stop(STOP_REASON, {"n_samples": n})
    except BaseException:
        writer.close()
        raise
    return writer


def recording_metadata(recording: Recording, report=None) -> dict:
    """The start metadata of a recording session (plain JSON types)."""
    files = {f.path: f for f in report.files} if report is not None else {}
    sources = []
    for path in recording.sources:
        count, first = recording.malformed.get(path, (0, ()))
        f = files.get(path)
        sources.append({"path": path, "name": f.name if f else None,
                        "sha256": f.sha256 if f else _sha256_or_none(path),
                        "lines": f.lines if f else None, "samples": f.samples if f else None,
                        "header_lines": f.header_lines if f else None,
                        "malformed": count, "malformed_lines": list(first)})
    n = len(recording.t)
    return {
        "kind": KIND,
        "software": f"fieldcal {__version__}",
        "triads": {name: {"kind": recording.kinds[name], "unit": recording.units[name]}
                   for name in recording.triads},
        "n_samples": n,
        "rate_hz": recording.rate_hz,
        "duration_s": recording.duration_s,
        "t_first": float(recording.t[0]) if n else None,
        "t_last": float(recording.t[-1]) if n else None,
        "sources": sources,
        "import_map": ({"path": report.map_path, "text": report.map_text} if report is not None else None),
        "alignment": list(report.alignment) if report is not None else [],
        "warnings": list(report.warnings) if report is not None else [],
        **({"unit_serial": recording.unit_serial} if recording.unit_serial is not None else {}),
    }


def _sha256_or_none(path: str) -> str | None:
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return None


def load_recording(directory: str | os.PathLike) -> Recording:
    """The recording saved in ``directory``; a one-line error for anything else."""
    # Here, not above: the reader of every kind of session (and the procedure events it reads)
    # is some 20 ms of imports that calibrate on text files, which only writes one, never needs.
    from fieldcal.session.record import RunRecord

    reader = RunRecord.open(directory)  # SessionError (one line) if it is no session at all
    meta = reader.start
    where = str(reader.directory)
    if meta.get("kind") != KIND:
        what = (f"a procedure session ({meta['procedure'].get('name', '?')})"
                if isinstance(meta.get("procedure"), dict) else "another kind of session")
        raise RecordingSessionError(f"{where}: not a recording session ({what}); "
                                    "make one with fieldcal import", where)
    if not reader.stopped or reader.stop_reason != STOP_REASON:
        raise RecordingSessionError(f"{where}: the import did not finish (no '{STOP_REASON}' stop); "
                                    "import the recording again", where)
    try:
        triads_meta = meta["triads"]
        names = list(triads_meta)
        kinds = {name: triads_meta[name]["kind"] for name in names}
        units = {name: triads_meta[name]["unit"] for name in names}
        sources = meta["sources"]
        malformed = {s["path"]: (int(s["malformed"]), tuple(s["malformed_lines"])) for s in sources}
        expected = int(meta["n_samples"])
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise RecordingSessionError(f"{where}: recording metadata is incomplete ({exc!r})", where) from None

    chunks = list(reader.chunks())
    for chunk in chunks:
        if set(chunk.triads) != set(names):
            raise RecordingSessionError(f"{where}: a chunk holds triads {sorted(chunk.triads)}, the "
                                        f"metadata names {sorted(names)}", where)
    t = np.concatenate([c.t for c in chunks]) if chunks else np.zeros(0)
    triads = {name: (np.concatenate([c.triads[name] for c in chunks]) if chunks else np.zeros((0, 3)))
              for name in names}
    if len(t) != expected:
        raise RecordingSessionError(f"{where}: {len(t)} samples stored, the metadata says {expected}", where)
    serial = meta.get("unit_serial")
    return Recording(t=t, triads=triads, kinds=kinds, units=units,
                     sources=tuple(s["path"] for s in sources), malformed=malformed,
                     unit_serial=serial if isinstance(serial, str) and serial else None)

