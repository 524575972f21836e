"""The session log's checks, one refusal at a time, on logs built by hand from the format.

Each log here is written from docs/reference/session-format.md's definition (canonical JSON, its
CRC-32 appended as the last key), not by the writer, so every check behind the checksum is
reached with exactly the document it refuses; the expected refusal is written out word for word.
"""
from __future__ import annotations

import json
import os
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

from drivers.chunk import SampleChunk
from fieldcal.session.capture import LOG, SessionError, SessionReader, SessionStateError, SessionWriter, to_plain

START = {"seq": 0, "type": "start", "schema": "fieldcal-session/2", "metadata": {}}
DESCRIPTOR = {"seq": 1, "type": "descriptor",
              "columns": [{"name": "t", "role": "time", "dtype": "<f8"},
                          {"name": "accelerometer", "role": "triad", "dtype": "<f4"}]}


def _line(doc) -> bytes:
    """One log line as the format defines it (not the writer's code)."""
    body = json.dumps(doc, separators=(",", ":")).encode("ascii")
    return body[:-1] + b',"crc":%d}\n' % zlib.crc32(body)


def forge(directory: Path, *docs, start=START) -> Path:
    """A session directory whose log holds the start document and then ``docs``, with seqs
    (bytes: a line as it is)."""
    directory.mkdir()
    lines = [_line(start)]
    for i, doc in enumerate(docs, start=1):
        lines.append(doc if isinstance(doc, bytes) else _line(doc if "seq" in doc else {"seq": i, **doc}))
    (directory / LOG).write_bytes(b"".join(lines))
    return directory


def refusal(directory: Path) -> tuple[str, int | None]:
    """What reading the session says, without the log's path, and the line the error names."""
    with pytest.raises(SessionError) as exc:
        SessionReader(directory, log_only=True)
    text = str(exc.value)
    prefix = f"{directory / LOG}: "
    assert text.startswith(prefix) and "\n" not in text
    return text[len(prefix):], exc.value.line


def chunk_doc(n=2, offset=0, t_first=0.0, t_last=0.004, **kw):
    # a record of n samples of <f8 time and a <f4 triad: 40-byte header + 8n and 12n, each to 8 bytes
    length = 40 + -(-8 * n // 8) * 8 + -(-12 * n // 8) * 8
    return {"type": "chunk", "descriptor": 1, "offset": offset, "length": length, "n": n,
            "t_first": t_first if n else None, "t_last": t_last if n else None, "crc32": 0, **kw}


LONG = "x" * 400

CASES = {
    # every document
    "seq skipped": ([{"seq": 2, "type": "event", "after_chunk": None, "data": {}}],
                    "line 2: expected seq 1, got 2", 2),
    "seq a bool": ([{"seq": True, "type": "event", "after_chunk": None, "data": {}}],
                   "line 2: expected seq 1, got True", 2),
    "unknown type": ([{"type": "blob"}], "line 2: unknown document type 'blob'", 2),
    "second start": ([{"type": "start", "schema": "fieldcal-session/2", "metadata": {}}],
                     "line 2: a second start document", 2),
    # after_chunk documents, stop and resume
    "event after no chunk": ([{"type": "action", "after_chunk": 3, "data": {}}],
                             "line 2: action document: after_chunk 3 but the last chunk before it is None", 2),
    "event without after_chunk": ([{"type": "step", "data": {}}],
                                  "line 2: step document: after_chunk None but the last chunk before it is None", 2),
    "event data a list": ([{"type": "event", "after_chunk": None, "data": []}],
                          "line 2: event document: 'data' must be an object, got []", 2),
    "event without data": ([{"type": "checkpoint", "after_chunk": None}],
                           "line 2: checkpoint document without 'data'", 2),
    "stop without reason": ([{"type": "stop", "data": {}}], "line 2: stop document without 'reason'", 2),
    "stop reason a number": ([{"type": "stop", "reason": 5, "data": {}}],
                             "line 2: stop document: 'reason' must be a string, got 5", 2),
    "stop data a string": ([{"type": "stop", "reason": "aborted", "data": "x"}],
                           "line 2: stop document: 'data' must be an object, got 'x'", 2),
    "resume repaired a string": ([{"type": "stop", "reason": "aborted", "data": {}},
                                  {"type": "resume", "after_chunk": None, "repaired": "x", "data": {}}],
                                 "line 3: resume document: 'repaired' must be a list, got 'x'", 3),
    "resume repaired numbers": ([{"type": "resume", "after_chunk": None, "repaired": [1], "data": {}}],
                                "line 2: resume document: 'repaired' must be a list of strings", 2),
    "resume after the wrong chunk": ([{"type": "resume", "after_chunk": 0, "repaired": [], "data": {}}],
                                     "line 2: resume document: after_chunk 0 but the last chunk before it is None", 2),
    # raw
    "raw name": ([{"type": "raw", "name": "../x", "t": 0, "offset": 0, "length": 1, "crc32": 0}],
                 "line 2: raw document: bad stream name '../x'", 2),
    "raw name a number": ([{"type": "raw", "name": 7, "t": 0, "offset": 0, "length": 1, "crc32": 0}],
                          "line 2: raw document: 'name' must be a string, got 7", 2),
    "raw t a bool": ([{"type": "raw", "name": "imu", "t": True, "offset": 0, "length": 1, "crc32": 0}],
                     "line 2: raw document: 't' must be a number, got True", 2),
    "raw t missing": ([{"type": "raw", "name": "imu", "offset": 0, "length": 1, "crc32": 0}],
                      "line 2: raw document without 't'", 2),
    "raw offset negative": ([{"type": "raw", "name": "imu", "t": 0.5, "offset": -1, "length": 1, "crc32": 0}],
                            "line 2: raw document: 'offset' must be an integer >= 0, got -1", 2),
    "raw length a float": ([{"type": "raw", "name": "imu", "t": 0.5, "offset": 0, "length": 1.0, "crc32": 0}],
                           "line 2: raw document: 'length' must be an integer >= 0, got 1.0", 2),
    "raw crc missing": ([{"type": "raw", "name": "imu", "t": 0.5, "offset": 0, "length": 1}],
                        "line 2: raw document without 'crc32'", 2),
    "raw gap": ([{"type": "raw", "name": "imu", "t": 0.5, "offset": 0, "length": 3, "crc32": 0},
                 {"type": "raw", "name": "gps", "t": 0.6, "offset": 0, "length": 5, "crc32": 0},
                 {"type": "raw", "name": "imu", "t": 0.7, "offset": 4, "length": 1, "crc32": 0}],
                "line 4: raw 'imu' at byte 4, expected 3 (records are contiguous)", 4),
    # parameters
    "parameters name": ([{"type": "parameters", "file": "a/b.yaml", "sha256": "0" * 64}],
                        "line 2: parameters document: bad file name 'a/b.yaml'", 2),
    "parameters no name": ([{"type": "parameters", "sha256": "0" * 64}],
                           "line 2: parameters document without 'file'", 2),
    "parameters sha short": ([{"type": "parameters", "file": "p.yaml", "sha256": "0" * 63}],
                             f"line 2: parameters document: bad sha256 '{'0' * 63}'", 2),
    "parameters sha upper": ([{"type": "parameters", "file": "p.yaml", "sha256": "A" * 64}],
                             f"line 2: parameters document: bad sha256 '{'A' * 64}'", 2),
    "parameters sha a list": ([{"type": "parameters", "file": "p.yaml", "sha256": []}],
                              "line 2: parameters document: 'sha256' must be a SHA-256 hex digest, got []", 2),
    # descriptors (line 2)
    "descriptor without columns": ([{"type": "descriptor"}], "line 2: descriptor document without 'columns'", 2),
    "columns an object": ([{"type": "descriptor", "columns": {}}],
                          "line 2: descriptor document: 'columns' must be a list, got {}", 2),
    "column with another key": ([{"type": "descriptor", "columns": [{"name": "t", "role": "time", "dtype": "<f8", "x": 1}]}],
                                "line 2: descriptor column 0: expected name, role and dtype, got "
                                "{'name': 't', 'role': 'time', 'dtype': '<f8', 'x': 1}", 2),
    "column of an unknown role": ([{"type": "descriptor", "columns": [{"name": "t", "role": "clock", "dtype": "<f8"}]}],
                                  "line 2: descriptor column 0: expected name, role and dtype, got "
                                  "{'name': 't', 'role': 'clock', 'dtype': '<f8'}", 2),
    "column name a number": ([{"type": "descriptor", "columns": [{"name": 1, "role": "time", "dtype": "<f8"}]}],
                             "line 2: descriptor column 0: expected name, role and dtype, got "
                             "{'name': 1, 'role': 'time', 'dtype': '<f8'}", 2),
    "column dtype a number": ([{"type": "descriptor", "columns": [{"name": "t", "role": "time", "dtype": 8}]}],
                              "line 2: descriptor column 0: expected name, role and dtype, got "
                              "{'name': 't', 'role': 'time', 'dtype': 8}", 2),
    "column a list": ([{"type": "descriptor", "columns": [["t", "time", "<f8"]]}],
                      "line 2: descriptor column 0: expected name, role and dtype, got ['t', 'time', '<f8']", 2),
    "big-endian": ([{"type": "descriptor", "columns": [{"name": "t", "role": "time", "dtype": "<f8"},
                                                       {"name": "a", "role": "triad", "dtype": ">f4"}]}],
                   "line 2: descriptor column 1: not a little-endian numeric dtype: '>f4'", 2),
    "dtype not in numpy's own spelling": ([{"type": "descriptor", "columns": [{"name": "t", "role": "time", "dtype": "f8"}]}],
                                          "line 2: descriptor column 0: not a little-endian numeric dtype: 'f8'", 2),
    "text dtype": ([{"type": "descriptor", "columns": [{"name": "t", "role": "time", "dtype": "<U4"}]}],
                   "line 2: descriptor column 0: not a little-endian numeric dtype: '<U4'", 2),
    "no dtype at all": ([{"type": "descriptor", "columns": [{"name": "t", "role": "time", "dtype": "nonsense"}]}],
                        "line 2: descriptor column 0: not a little-endian numeric dtype: 'nonsense'", 2),
    "a column twice": ([{"type": "descriptor", "columns": [{"name": "t", "role": "time", "dtype": "<f8"},
                                                           {"name": "a", "role": "triad", "dtype": "<f4"},
                                                           {"name": "a", "role": "triad", "dtype": "<f8"}]}],
                       "line 2: descriptor column 2: 'a' appears twice", 2),
    "no columns": ([{"type": "descriptor", "columns": []}],
                   "line 2: descriptor: expected the time column first and at most one temperature", 2),
    "time not first": ([{"type": "descriptor", "columns": [{"name": "a", "role": "triad", "dtype": "<f4"},
                                                           {"name": "t", "role": "time", "dtype": "<f8"}]}],
                       "line 2: descriptor: expected the time column first and at most one temperature", 2),
    "two times": ([{"type": "descriptor", "columns": [{"name": "t", "role": "time", "dtype": "<f8"},
                                                      {"name": "u", "role": "time", "dtype": "<f8"}]}],
                  "line 2: descriptor: expected the time column first and at most one temperature", 2),
    "two temperatures": ([{"type": "descriptor", "columns": [{"name": "t", "role": "time", "dtype": "<f8"},
                                                             {"name": "a", "role": "temperature", "dtype": "<f4"},
                                                             {"name": "b", "role": "temperature", "dtype": "<f4"}]}],
                         "line 2: descriptor: expected the time column first and at most one temperature", 2),
    # chunks (line 3, after DESCRIPTOR)
    "unknown descriptor": ([DESCRIPTOR, chunk_doc(descriptor=5)],
                           "line 3: chunk refers to descriptor 5, which is not an earlier descriptor", 3),
    "descriptor a string": ([DESCRIPTOR, chunk_doc(descriptor="1")],
                            "line 3: chunk document: 'descriptor' must be a descriptor's seq, got '1'", 3),
    "n negative": ([DESCRIPTOR, chunk_doc(n=-1, t_first=None, t_last=None)],
                   "line 3: chunk document: 'n' must be an integer >= 0, got -1", 3),
    "offset a bool": ([DESCRIPTOR, chunk_doc(offset=False)],
                      "line 3: chunk document: 'offset' must be an integer >= 0, got False", 3),
    "length missing": ([DESCRIPTOR, {k: v for k, v in chunk_doc().items() if k != "length"}],
                       "line 3: chunk document without 'length'", 3),
    "crc negative": ([DESCRIPTOR, chunk_doc(crc32=-2)],
                     "line 3: chunk document: 'crc32' must be an integer >= 0, got -2", 3),
    "t_last a string": ([DESCRIPTOR, chunk_doc(t_last="1")],
                        "line 3: chunk document: 't_last' must be a number or null, got '1'", 3),
    "t_first missing": ([DESCRIPTOR, {k: v for k, v in chunk_doc().items() if k != "t_first"}],
                        "line 3: chunk document without 't_first'", 3),
    "samples without times": ([DESCRIPTOR, chunk_doc(t_first=None)],
                              "line 3: chunk of 2 samples from t None to 0.004: expected the times of its "
                              "first and last samples (null for none)", 3),
    "no samples with a time": ([DESCRIPTOR, {**chunk_doc(n=0), "t_last": 1.5}],
                               "line 3: chunk of 0 samples from t None to 1.5: expected the times of its "
                               "first and last samples (null for none)", 3),
    "times reversed": ([DESCRIPTOR, chunk_doc(t_first=1.0, t_last=0.5)],
                       "line 3: chunk of 2 samples from t 1.0 to 0.5: expected the times of its "
                       "first and last samples (null for none)", 3),
    "infinite first time": ([DESCRIPTOR, chunk_doc(t_first=-np.inf, t_last=1.0)],
                            "line 3: chunk 2: sample time -inf .. 1.0 s is not a finite number (forged or "
                            "damaged times)", 3),
    "infinite last time": ([DESCRIPTOR, chunk_doc(t_first=0.0, t_last=np.inf)],
                           "line 3: chunk 2: sample time 0.0 .. inf s is not a finite number (forged or "
                           "damaged times)", 3),
    "time goes back": ([DESCRIPTOR, chunk_doc(), chunk_doc(offset=80, t_first=0.002, t_last=0.006)],
                       "line 4: chunk 3: its samples start at t 0.002 s, before chunk 2's last sample at "
                       "t 0.004 s (time within a run never goes back: forged or damaged times in one of them)", 4),
    "records not contiguous": ([DESCRIPTOR, chunk_doc(offset=8)],
                               "line 3: chunk at byte 8 of samples.bin, expected 0 (records are contiguous)", 3),
    "the second record not after the first": ([DESCRIPTOR, chunk_doc(), chunk_doc(offset=72, t_first=1.0, t_last=2.0)],
                                              "line 4: chunk at byte 72 of samples.bin, expected 80 (records are "
                                              "contiguous)", 4),
    # 2 samples: a 40-byte header, 2 x 8 bytes of time, 2 x 3 x 4 of triad: 80, not 88
    "record length": ([DESCRIPTOR, chunk_doc(length=88)],
                      "line 3: chunk of 2 samples has length 88, its descriptor needs 80", 3),
    # 3 samples: 40 + 24 + 36 padded to 40: 104
    "record length unpadded": ([DESCRIPTOR, chunk_doc(n=3, length=100)],
                               "line 3: chunk of 3 samples has length 100, its descriptor needs 104", 3),
    # long values are cut so the line stays short
    "long type": ([{"type": LONG}], "line 2: " + ("unknown document type '" + LONG)[:200], 2),
    "long seq": ([{"seq": LONG, "type": "event"}], "line 2: " + ("expected seq 1, got '" + LONG)[:200], 2),
    "long after_chunk": ([{"type": "event", "after_chunk": LONG, "data": {}}],
                         "line 2: " + ("event document: after_chunk '" + LONG)[:200], 2),
    "long reason": ([{"type": "stop", "reason": [LONG], "data": {}}],
                    "line 2: " + ("stop document: 'reason' must be a string, got ['" + LONG)[:300], 2),
    "long raw name": ([{"type": "raw", "name": LONG, "t": 0, "offset": 0, "length": 1, "crc32": 0}],
                      "line 2: " + ("raw document: bad stream name '" + LONG)[:200], 2),
    "long file name": ([{"type": "parameters", "file": LONG, "sha256": "0" * 64}],
                       "line 2: " + ("parameters document: bad file name '" + LONG)[:200], 2),
    "long sha": ([{"type": "parameters", "file": "p.yaml", "sha256": LONG}],
                 "line 2: " + ("parameters document: bad sha256 '" + LONG)[:200], 2),
    "long column": ([{"type": "descriptor", "columns": [{"name": LONG, "role": "x", "dtype": "<f8"}]}],
                    "line 2: " + ("descriptor column 0: expected name, role and dtype, got {'name': '" + LONG)[:200], 2),
    "long dtype": ([{"type": "descriptor", "columns": [{"name": "t", "role": "time", "dtype": LONG}]}],
                   "line 2: " + ("descriptor column 0: not a little-endian numeric dtype: '" + LONG)[:200], 2),
    "long chunk times": ([DESCRIPTOR, chunk_doc(t_first=None, t_last=LONG)],
                         "line 3: " + ("chunk document: 't_last' must be a number or null, got '" + LONG)[:300], 3),
}


@pytest.mark.parametrize("case", CASES)
def test_each_malformed_document_is_refused_in_one_line_naming_its_line(tmp_path, case):
    docs, said, line = CASES[case]
    assert refusal(forge(tmp_path / "s", *docs)) == (said, line)


def test_a_line_that_is_no_object_is_refused_in_a_version_1_log(tmp_path):
    """(a version 2 line ends with its checksum, so only a version 1 log can hold one)"""
    start = {**START, "schema": "fieldcal-session/1"}
    assert refusal(forge(tmp_path / "s", b"[1, 2]\n", start=start)) == ("line 2: expected a JSON object, got list", 2)
    assert refusal(forge(tmp_path / "v2", b"[1, 2]\n")) == (
        'line 2 (byte 86): damaged: no checksum ("crc") at the end of the line; the session is not repaired '
        "automatically (restore it from a copy)", 2)


START_CASES = {
    "another format": ({**START, "schema": "other/9"}, "line 1: expected a start document of schema "
                       "'fieldcal-session/2' (or 'fieldcal-session/1'), got 'other/9'"),
    "no schema": ({"seq": 0, "type": "start", "metadata": {}}, "line 1: expected a start document of schema "
                  "'fieldcal-session/2' (or 'fieldcal-session/1'), got None"),
    "long schema": ({**START, "schema": LONG}, "line 1: " + ("expected a start document of schema "
                    "'fieldcal-session/2' (or 'fieldcal-session/1'), got '" + LONG)[:200]),
    "metadata a list": ({**START, "metadata": []}, "line 1: start document: 'metadata' must be an object, got []"),
    "no metadata": ({"seq": 0, "type": "start", "schema": "fieldcal-session/2"},
                    "line 1: start document without 'metadata'"),
    "an event first": ({"seq": 0, "type": "event", "after_chunk": None, "data": {}},
                       "line 1: the first document must be the start document, and only the first"),
}


@pytest.mark.parametrize("case", START_CASES)
def test_each_malformed_start_document_is_refused_at_line_1(tmp_path, case):
    start, said = START_CASES[case]
    assert refusal(forge(tmp_path / "s", start=start)) == (said, 1)


def test_a_well_formed_hand_built_log_reads(tmp_path):
    """The negative control: the same building blocks, valid, read without complaint."""
    d = forge(tmp_path / "s", {"type": "event", "after_chunk": None, "data": {"k": 1}},
              {"type": "raw", "name": "imu", "t": 0.5, "offset": 0, "length": 3, "crc32": 0},
              {"type": "raw", "name": "imu", "t": 0.7, "offset": 3, "length": 1, "crc32": 0},
              {"type": "parameters", "file": "parameters-001.yaml", "sha256": "0123456789abcdef" * 4},
              {"type": "stop", "reason": "aborted", "data": {}},
              {"type": "resume", "after_chunk": None, "repaired": ["x"], "data": {}})
    r = SessionReader(d, log_only=True)
    assert [doc["type"] for doc in r.documents()] == ["start", "event", "raw", "raw", "parameters", "stop", "resume"]
    assert r.events() == [{"k": 1}] and not r.stopped


def test_chunk_times_may_repeat_restart_after_a_resume_and_run_apart_per_layout(tmp_path):
    """What the time checks must let through: equal times (a clockless device's frames of one
    read), a chunk of no samples, a resume's new run of times, a second layout's own times."""
    other = {"seq": 5, "type": "descriptor",
             "columns": [{"name": "t", "role": "time", "dtype": "<i8"}, {"name": "t", "role": "extra", "dtype": "|u1"},
                         {"name": "c", "role": "temperature", "dtype": "<f2"}]}
    docs = [DESCRIPTOR, chunk_doc(t_first=1.0, t_last=2.0),                       # line 3, bytes 0-80
            chunk_doc(offset=80, t_first=2.0, t_last=2.0),                        # 4: starts at the last time
            chunk_doc(n=0, offset=160, length=40),                                # 5: no samples
            other,                                                                 # 6
            {**chunk_doc(offset=200, t_first=0.5, t_last=0.7), "descriptor": 5,   # 7: 40 + 16 + 8 + 8
             "length": 72},
            chunk_doc(n=3, offset=272, length=104, t_first=2.0, t_last=3.0),      # 8: after line 4's 2.0
            {"type": "stop", "reason": "aborted", "data": {}},
            {"type": "resume", "after_chunk": 7, "repaired": [], "data": {}},
            chunk_doc(offset=376, t_first=0.0, t_last=0.5)]                       # 11: the clock restarted
    r = SessionReader(forge(tmp_path / "s", *docs), log_only=True)
    assert [d["seq"] for d in r.documents("chunk")] == [2, 3, 4, 6, 7, 10]
    assert r.n_chunks == 6 and r.n_samples == 2 + 2 + 0 + 2 + 3 + 2


# --------------------------------------------------------------------------------------------
# to_plain


def test_to_plain_keeps_bools_bools_and_names_where_a_bad_value_is():
    for value in (True, False, None):
        assert to_plain(value) is value
    assert to_plain([np.bool_(True), np.int16(-3), np.float32(0.5), (1, "a")]) == [True, -3, 0.5, [1, "a"]]
    assert [type(x) for x in to_plain([np.bool_(False), np.uint8(7), np.float64(2.5), True])] == [bool, int, float, bool]
    with pytest.raises(TypeError, match=r"^data: keys must be strings, got 1$"):
        to_plain({1: 2})
    with pytest.raises(TypeError, match=r"^data\.a\[1\]: a set is not JSON-able"):
        to_plain({"a": [0, {3}]})


# --------------------------------------------------------------------------------------------
# Sample records, packed by hand from the format: "<4sIQQQQ" (magic FCS1, CRC-32 of the payload,
# chunk seq, descriptor seq, n, payload bytes), then one block per column, each padded to 8 bytes


FULL = {"seq": 1, "type": "descriptor",
        "columns": [{"name": "t", "role": "time", "dtype": "<f8"}, {"name": "acc", "role": "triad", "dtype": "<f4"},
                    {"name": "temperature", "role": "temperature", "dtype": "<f4"},
                    {"name": "status", "role": "extra", "dtype": "|u1"}]}
T = [0.0, 0.004]
ACC = [[1.0, 2.0, 3.0], [4.0, 5.0, -6.5], [0.25, 0.0, 9.0]]
TEMP = [21.5, 21.75, 22.0]
STATUS = [7, 255, 0]


def _record(t=T, seq=2, descriptor=1, magic=b"FCS1", n=None, crc=None, payload_size=None):
    k = len(t)
    blocks = [np.array(t, "<f8").tobytes(), np.array(ACC[:k], "<f4").tobytes(),
              np.array(TEMP[:k], "<f4").tobytes(), np.array(STATUS[:k], "|u1").tobytes()]
    payload = b"".join(b + bytes(-len(b) % 8) for b in blocks)  # 2 samples: 16 + 24 + 8 + 8 = 56 bytes
    n = len(t) if n is None else n
    crc = zlib.crc32(payload) if crc is None else crc
    header = struct.pack("<4sIQQQQ", magic, crc, seq, descriptor, n, len(payload) if payload_size is None else payload_size)
    return header + payload, zlib.crc32(payload)


def forge_with_record(directory: Path, record: bytes, crc: int, t_first=T[0], t_last=T[-1], n=2) -> Path:
    doc = {"type": "chunk", "descriptor": 1, "offset": 0, "length": len(record), "n": n, "t_first": t_first,
           "t_last": t_last, "crc32": crc}
    forge(directory, FULL, doc)
    (directory / "samples.bin").write_bytes(record)
    return directory


def test_a_record_packed_by_hand_reads_as_its_columns(tmp_path):
    d = forge_with_record(tmp_path / "s", *_record())
    (chunk,) = SessionReader(d).chunks()
    assert len((d / "samples.bin").read_bytes()) == 96
    assert chunk.t.tolist() == T and chunk.t.dtype == np.dtype("<f8")
    assert list(chunk.triads) == ["acc"] and chunk.triads["acc"].tolist() == ACC[:2]
    assert chunk.triads["acc"].shape == (2, 3)
    assert chunk.temperature.tolist() == TEMP[:2] and chunk.temperature.dtype == np.dtype("<f4")
    assert list(chunk.extras) == ["status"] and chunk.extras["status"].tolist() == STATUS[:2]
    assert [kind for kind, _ in SessionReader(d).replay_items(("chunk", "descriptor"))] == ["descriptor", "chunk"]


def _read_refusal(d: Path) -> str:
    with pytest.raises(SessionError) as exc:
        list(SessionReader(d).chunks())
    assert exc.value.line == 3 and exc.value.path == str(d / "samples.bin")
    text = str(exc.value)
    where = f"{d / 'samples.bin'}: chunk 2 at byte 0 (log line 3): "
    assert text.startswith(where)
    return text[len(where):]


def test_each_forged_record_is_refused_naming_the_chunk_its_byte_and_its_log_line(tmp_path):
    record, crc = _record()
    assert _read_refusal(forge_with_record(tmp_path / "magic", *_record(magic=b"FCS2"))) == "bad record magic b'FCS2'"
    assert _read_refusal(forge_with_record(tmp_path / "seq", *_record(seq=9))) == (
        "the record header (seq 9, descriptor 1, n 2, 56 bytes) does not match the log")
    assert _read_refusal(forge_with_record(tmp_path / "dseq", *_record(descriptor=0))) == (
        "the record header (seq 2, descriptor 0, n 2, 56 bytes) does not match the log")
    assert _read_refusal(forge_with_record(tmp_path / "n", *_record(n=3))) == (
        "the record header (seq 2, descriptor 1, n 3, 56 bytes) does not match the log")
    assert _read_refusal(forge_with_record(tmp_path / "size", *_record(payload_size=48))) == (
        "the record header (seq 2, descriptor 1, n 2, 48 bytes) does not match the log")
    # the header's CRC is the log's but not the payload's, or the payload's but not the log's
    assert _read_refusal(forge_with_record(tmp_path / "crc", _record(crc=crc ^ 1)[0], crc ^ 1)) == (
        "checksum mismatch (corrupt data)")
    assert _read_refusal(forge_with_record(tmp_path / "logcrc", record, crc ^ 1)) == "checksum mismatch (corrupt data)"
    flipped = bytearray(record)
    flipped[40 + 17] ^= 0x10
    assert _read_refusal(forge_with_record(tmp_path / "flip", bytes(flipped), crc)) == "checksum mismatch (corrupt data)"
    assert _read_refusal(forge_with_record(tmp_path / "span", record, crc, t_last=0.005)) == (
        "the log gives its samples t 0.0 .. 0.005 s, the record holds 0.0 .. 0.004 s")
    assert _read_refusal(forge_with_record(tmp_path / "first", record, crc, t_first=-1.0)) == (
        "the log gives its samples t -1.0 .. 0.004 s, the record holds 0.0 .. 0.004 s")


def test_times_inside_a_record_are_finite_and_never_go_back(tmp_path):
    def with_times(name, t):
        return forge_with_record(tmp_path / name, *_record(t=t), t_first=t[0], t_last=t[-1], n=len(t))

    assert _read_refusal(with_times("back", [0.5, 0.25, 0.75])) == (
        "sample 1's time 0.25 s is before sample 0's 0.5 s (time within a chunk never goes back: forged or "
        "damaged times)")
    assert _read_refusal(with_times("back2", [0.25, 0.75, 0.5])) == (
        "sample 2's time 0.5 s is before sample 1's 0.75 s (time within a chunk never goes back: forged or "
        "damaged times)")
    assert _read_refusal(with_times("nan", [0.5, float("nan"), 0.75])) == (
        "sample 1's time nan s is not a finite number (time within a chunk never goes back: forged or damaged times)")
    (chunk,) = SessionReader(with_times("equal", [0.5, 0.5, 0.75])).chunks()  # one read of a clockless device
    assert chunk.t.tolist() == [0.5, 0.5, 0.75]


# --------------------------------------------------------------------------------------------
# The writer's refusals of calls out of order or with bad arguments: each one line, word for word


def _chunk(t0=0.0, n=2):
    return SampleChunk(t=t0 + np.arange(n) * 0.004, triads={"acc": np.zeros((n, 3))})


def test_calls_out_of_order_are_refused_naming_the_session_and_what_to_do(tmp_path):
    d = tmp_path / "s"
    w = SessionWriter.create(d, {})
    with pytest.raises(SessionStateError) as exc:
        w.resume()
    assert str(exc.value) == f"{d}: cannot resume: the run is still active"
    w.stop("aborted")
    for call, kind in ((lambda: w.chunk(_chunk()), "chunk"), (lambda: w.event({}), "event"),
                       (lambda: w.action({}), "action"), (lambda: w.step({}), "step"),
                       (lambda: w.checkpoint({}), "checkpoint"), (lambda: w.stop("aborted"), "stop")):
        with pytest.raises(SessionStateError) as exc:
            call()
        assert str(exc.value) == (f"{d}: cannot write {kind!r}: no active run (after stop() or append_to(), "
                                  "call resume() first)")
    with pytest.raises(SessionStateError) as exc:
        w.resume(mid_run=True)
    assert str(exc.value) == f"{d}: cannot resume mid-run: no active run"
    w.write_raw("imu", 1.0, b"x")  # raw reads and parameters need no active run
    assert w.resume({"why": "test"}) == 3 and w.active
    assert w.resume({"why": "power cycle"}, mid_run=True) == 4 and w.active
    w.close()
    with pytest.raises(SessionStateError) as exc:
        w.event({})
    assert str(exc.value) == f"{d}: the session writer is closed"
    r = SessionReader(d)
    assert [(doc["type"], doc.get("data")) for doc in r.documents()] == [
        ("start", None), ("stop", {}), ("raw", None), ("resume", {"why": "test"}), ("resume", {"why": "power cycle"})]
    assert [doc["after_chunk"] for doc in r.documents("resume")] == [None, None]


def test_bad_arguments_are_refused_before_anything_is_written(tmp_path):
    d = tmp_path / "s"
    for bad in (-1, True, "1", None, float("nan")):
        with pytest.raises(ValueError) as exc:
            SessionWriter.create(d, {}, fsync_interval_s=bad)
        assert str(exc.value) == f"fsync_interval_s: expected a number >= 0, got {bad!r}"
    assert not d.exists()
    w = SessionWriter.create(d, {}, fsync_interval_s=0)
    for reason in ("", None, 3):
        with pytest.raises(ValueError) as exc:
            w.stop(reason)
        assert str(exc.value) == f"stop reason: expected a non-empty string, got {reason!r}"
    for name in ("", "-x", "a/b", "x" * 65, 5):
        with pytest.raises(ValueError) as exc:
            w.write_raw(name, 0.0, b"")
        assert str(exc.value) == ("raw stream name: expected letters, digits, '_', '.', '-' (at most 64), "
                                  f"got {name!r}")
    for t in (True, "0", None):
        with pytest.raises(TypeError):
            w.write_raw("imu", t, b"")
    with pytest.raises(TypeError) as exc:
        w.write_raw("imu", True, b"")
    assert str(exc.value) == "raw t: expected a number, got True"
    for filename in ("log.jsonl", "samples.bin", "parameters.yaml", "raw-x.bin", "a/b.yaml", "", 7):
        with pytest.raises(ValueError) as exc:
            w.write_parameters(None, filename)
        assert str(exc.value) == f"parameter file name: expected a plain file name, got {filename!r}"
    with pytest.raises(ValueError) as exc:
        w.chunk(SampleChunk(t=np.zeros((2, 1)), triads={}))
    assert str(exc.value) == "chunk t: expected 1 dimension(s), got shape (2, 1)"
    with pytest.raises(TypeError) as exc:
        w.chunk(SampleChunk(t=np.zeros(2), triads={}, extras={"flag": np.array(["a", "b"])}))
    assert str(exc.value) == "chunk channel 'flag': expected a numeric array, got dtype <U1"
    for call, said in ((lambda: w.step([1, 2]), "step: expected a dict, got a list"),
                       (lambda: w.stop("aborted", "why"), "stop: expected a dict, got a str"),
                       (lambda: SessionWriter.create(tmp_path / "t", (("a", 1),)),
                        "start_metadata: expected a dict, got a tuple")):
        with pytest.raises(TypeError) as exc:
            call()
        assert str(exc.value) == said
    assert not (tmp_path / "t").exists()
    w.write_raw("imu", np.float32(0.5), memoryview(b"ab"))
    w.write_raw("imu", 2, bytearray(b"c"))
    w.close()
    r = SessionReader(d)
    assert [doc["type"] for doc in r.documents()] == ["start", "raw", "raw"]  # the refused calls wrote nothing
    assert list(r.raw("imu")) == [(0.5, b"ab"), (2, b"c")] and list(r.raw("gps")) == []
    with pytest.raises(ValueError) as exc:
        list(r.documents("chunk", "blob"))
    assert str(exc.value) == ("unknown document type 'blob' (known: start, descriptor, chunk, event, action, step, "
                              "checkpoint, stop, resume, raw, parameters)")
    with pytest.raises(ValueError) as exc:
        list(r.replay_items(("chunks",)))
    assert str(exc.value).startswith("unknown document type 'chunks' (known: start, descriptor, ")


def test_a_refused_resume_leaves_the_writer_usable(tmp_path):
    """Refusing a resume writes nothing, so it must not mark the writer failed (which refuses every
    later write until append_to): the mid-run resume of a stopped run, the resume of a completed one."""
    d = tmp_path / "s"
    w = SessionWriter.create(d, {})
    w.stop("completed")
    with pytest.raises(SessionStateError):
        w.resume(mid_run=True)
    with pytest.raises(SessionError) as exc:
        w.resume()
    assert str(exc.value) == (f"{d / LOG}: line 2: this session completed; a completed session is never resumed "
                              "(replay it, or run again into a new directory)") and exc.value.line == 2
    assert w.write_raw("imu", 1.0, b"x") == 2
    w.close()
    w = SessionWriter.append_to(d)
    with pytest.raises(SessionError):
        w.resume()
    assert w.write_raw("imu", 2.0, b"y") == 3
    w.close()
    assert list(SessionReader(d).raw("imu")) == [(1.0, b"x"), (2.0, b"y")]


# --------------------------------------------------------------------------------------------
# What stands where a data file should be, and bytes beyond what the log indexes


def _one_chunk_one_read(d: Path) -> Path:
    w = SessionWriter.create(d, {})
    w.chunk(_chunk())  # line 3 (after the descriptor)
    w.write_raw("imu", 1.0, b"abc")  # line 4
    w.close()
    return d


@pytest.mark.parametrize("name, line", [("samples.bin", 3), ("raw-imu.bin", 4)])
def test_what_stands_where_a_logged_data_file_should_be_is_named(tmp_path, name, line):
    d = _one_chunk_one_read(tmp_path / "s")
    path = d / name
    path.unlink()
    cases = {"missing": lambda: None, "a directory, not a file": path.mkdir,
             "a FIFO, not a file": lambda: os.mkfifo(path),
             f"a link to {str(d / 'gone')!r}, which does not exist": lambda: path.symlink_to(d / "gone"),
             "a character device (a link to /dev/null), not a file": lambda: path.symlink_to("/dev/null")}
    for what, make in cases.items():
        make()
        for opener in (SessionReader, SessionWriter.append_to):
            with pytest.raises(SessionError) as exc:
                opener(d)
            assert str(exc.value) == f"{path}: {what}, but log.jsonl line {line} refers to it", what
            assert exc.value.line == line and exc.value.path == str(path)
        if path.is_dir() and not path.is_symlink():
            path.rmdir()
        elif os.path.lexists(path):
            path.unlink()
    if name == "samples.bin":  # without it, the log alone still reads
        assert SessionReader(d, log_only=True).n_chunks == 1


def test_bytes_beyond_the_log_are_named_per_file(tmp_path):
    d = _one_chunk_one_read(tmp_path / "s")
    with open(d / "raw-imu.bin", "ab") as fh:
        fh.write(b"de")  # a read whose log line was lost
    (d / "raw-gps.bin").write_bytes(b"x")  # a stream whose first log line was lost
    with open(d / LOG, "ab") as fh:
        fh.write(b'{"seq"')
    assert SessionReader(d).torn == [
        f"log.jsonl: ignored a torn last line (6 bytes at byte {(d / LOG).stat().st_size - 6})",
        "raw-gps.bin: ignored 1 byte after the last logged read (from byte 0)",
        "raw-imu.bin: ignored 2 bytes after the last logged read (from byte 3)"]
    w = SessionWriter.append_to(d)
    assert w.repaired[1:] == ["raw-gps.bin: cut 1 byte after the last logged read (from byte 0) (kept in raw-gps.bin.torn)",
                              "raw-imu.bin: cut 2 bytes after the last logged read (from byte 3) (kept in raw-imu.bin.torn)"]
    w.close()
    assert (d / "raw-imu.bin").read_bytes() == b"abc" and (d / "raw-imu.bin.torn").read_bytes() == b"de"
    assert (d / "raw-gps.bin").read_bytes() == b"" and (d / "raw-gps.bin.torn").read_bytes() == b"x"


def test_samples_beyond_the_log_must_be_the_next_record_or_its_start(tmp_path):
    """Only what a crash could leave: a prefix of the one record written before its log line."""
    d = _one_chunk_one_read(tmp_path / "s")
    end = (d / "samples.bin").stat().st_size
    assert end == 40 + 2 * 8 + 2 * 3 * 8  # one record: the header, 2 times, 2 float64 triad rows

    def refused(tail: bytes) -> str:
        (d / "samples.bin").write_bytes((d / "samples.bin").read_bytes()[:end] + tail)
        with pytest.raises(SessionError) as exc:
            SessionReader(d)
        prefix = f"{d / 'samples.bin'}: damaged: {len(tail)} bytes from byte {end} on are not indexed by log.jsonl, and "
        assert str(exc.value).startswith(prefix)
        assert str(exc.value).endswith(" (the log was cut short or the file damaged; restore it from a copy)")
        return str(exc.value)[len(prefix):-len(" (the log was cut short or the file damaged; restore it from a copy)")]

    header = struct.pack("<4sIQQQQ", b"FCS1", 0, 4, 1, 2, 40)  # seq 4: after start, descriptor, chunk, raw
    assert refused(b"FCS2") == "they do not start with a record header"
    assert refused(struct.pack("<4sIQ", b"FCS1", 0, 5)) == "they hold chunk 5, not the next one (4)"
    assert refused(header + bytes(41)) == "they are more than one unlogged record"
    for tail in (b"F", header[:15], header, header + bytes(40)):  # the next record (seq 5), or a prefix of it
        (d / "samples.bin").write_bytes((d / "samples.bin").read_bytes()[:end] + tail)
        assert SessionReader(d).torn == [f"samples.bin: ignored {len(tail)} byte{'s' if len(tail) > 1 else ''} "
                                         f"after the last logged chunk (from byte {end})"]


# --------------------------------------------------------------------------------------------
# The reader's views, and the rules of a cut


def test_the_readers_views_of_a_session(tmp_path):
    d = tmp_path / "s"
    w = SessionWriter.create(d, {"unit": "A1"})
    w.chunk(_chunk())
    w.action({"a": 1})
    w.step({"s": 1})
    w.checkpoint({"c": 1})
    w.stop("aborted", {"why": "test"})
    w.resume({"r": 1})
    w.event({"e": 1})
    w.close()
    r = SessionReader(d)
    assert r.start == {"unit": "A1"} and r.start_document["schema"] == "fieldcal-session/2"
    assert (r.actions(), r.steps(), r.events()) == ([{"a": 1}], [{"s": 1}], [{"e": 1}])
    assert (r.stopped, r.stop_reason) == (False, None) and r.parameters_path is None
    items = list(r.replay_items(("descriptor", "action", "checkpoint", "stop", "resume")))
    assert [kind for kind, _ in items] == ["descriptor", "action", "checkpoint", "stop", "resume"]
    assert items[0][1]["columns"][0] == {"name": "t", "role": "time", "dtype": "<f8"}  # a document without data: itself
    assert [item for _, item in items[1:]] == [{"a": 1}, {"c": 1}, {"why": "test"}, {"r": 1}]
    assert [kind for kind, _ in r.replay_items()] == ["chunk", "action"]  # what re-feeding an engine needs


def test_the_parameter_file_is_the_last_noted_and_only_if_it_is_there(tmp_path):
    from fieldcal.earth import Station
    from fieldcal.paramfile import ParameterFile, TriadParameters, hash_inputs

    triad = TriadParameters(name="accelerometer", kind="specific_force", output_unit="m/s^2", bias=np.zeros(3),
                            K=np.eye(3), sigma=np.full(9, 1e-4), residual_rms=1e-3, method="powell")
    pf = ParameterFile.build([triad], station=Station(latitude_deg=48.15, height_m=520.0), procedure="field-18",
                             method="powell", input_sha256=hash_inputs(np.zeros(3)))
    d = tmp_path / "s"
    w = SessionWriter.create(d, {})
    w.write_parameters(pf)
    w.write_parameters(pf, "mine.yaml")
    w.close()
    assert SessionReader(d).parameters_path == d / "mine.yaml"
    (d / "mine.yaml").unlink()
    assert SessionReader(d).parameters_path is None  # noted, but not there


def test_a_cut_keeps_its_copy_beside_the_earlier_ones_and_stops_at_999(tmp_path):
    d = _one_chunk_one_read(tmp_path / "s")
    log = (d / LOG).read_bytes()
    (d / "log.jsonl.torn").write_bytes(b"1")
    for n in range(2, 999):
        (d / f"log.jsonl.torn-{n}").write_bytes(b"n")
    (d / LOG).write_bytes(log + b'{"a')
    SessionWriter.append_to(d).close()  # the 999th copy is the last there may be
    assert (d / "log.jsonl.torn-999").read_bytes() == b'{"a' and (d / LOG).read_bytes() == log
    (d / LOG).write_bytes(log + b'{"b')
    with pytest.raises(SessionError) as exc:
        SessionWriter.append_to(d)
    assert str(exc.value) == f"{d / LOG}: too many earlier .torn copies beside it"
    assert exc.value.path == str(d / LOG)
    assert (d / LOG).read_bytes() == log + b'{"b'  # nothing cut without a copy


def test_bytes_beyond_the_log_of_a_session_being_written_are_a_write_in_progress(tmp_path):
    """While a writer holds the lock, what follows the last logged record is its next write, not
    damage: a reader lists it; once the writer is gone the same bytes are refused."""
    d = tmp_path / "s"
    w = SessionWriter.create(d, {})
    w.chunk(_chunk())
    w.sync()
    with open(d / "samples.bin", "ab") as fh:  # after one record: 40 + 2 x 8 (time) + 2 x 3 x 8 (triad) = 104
        fh.write(b"partial")
    assert SessionReader(d).torn == ["samples.bin: ignored 7 bytes after the last logged chunk (from byte 104)"]
    w.close()
    with pytest.raises(SessionError, match="they do not start with a record header"):
        SessionReader(d)


def _log_docs(d: Path) -> list[dict]:
    """The log's documents read as plain JSON, each line's CRC checked and dropped (the format)."""
    out = []
    for line in (d / LOG).read_bytes().splitlines():
        doc = json.loads(line)
        crc = doc.pop("crc")
        assert zlib.crc32(line[:line.rindex(b',"crc":')] + b"}") == crc
        out.append(doc)
    return out


def test_the_documents_the_writer_writes_field_by_field(tmp_path):
    d = tmp_path / "s"
    w = SessionWriter.create(d, {"unit": "A1"})
    acc = SampleChunk(t=np.array([1.0, 1.5]), triads={"acc": np.zeros((2, 3), "<f4")})
    w.chunk(acc)
    w.event({"e": 1})
    w.chunk(SampleChunk(t=np.array([2.0]), triads={"acc": np.zeros((1, 3), "<f4")}, temperature=np.array([20.0])))
    w.chunk(SampleChunk(t=np.zeros(0), triads={"acc": np.zeros((0, 3), "<f4")}))
    w.write_raw("imu", 2.5, b"abcd")
    w.stop("aborted")
    w.close()
    w = SessionWriter.append_to(d)
    w.resume()
    w.chunk(acc)  # a layout the session already has: no new descriptor
    w.close()
    time_col, acc_col = {"name": "t", "role": "time", "dtype": "<f8"}, {"name": "acc", "role": "triad", "dtype": "<f4"}
    got = _log_docs(d)
    crcs = [doc.pop("crc32", None) for doc in got]
    assert got == [
        {"seq": 0, "type": "start", "schema": "fieldcal-session/2", "metadata": {"unit": "A1"}},
        {"seq": 1, "type": "descriptor", "columns": [time_col, acc_col]},
        # 40 + 2 x 8 + 2 x 3 x 4 = 80 bytes
        {"seq": 2, "type": "chunk", "descriptor": 1, "offset": 0, "length": 80, "n": 2, "t_first": 1.0, "t_last": 1.5},
        {"seq": 3, "type": "event", "after_chunk": 2, "data": {"e": 1}},
        {"seq": 4, "type": "descriptor",
         "columns": [time_col, acc_col, {"name": "temperature", "role": "temperature", "dtype": "<f8"}]},
        # 40 + 8 + 12 padded to 16 + 8 = 72
        {"seq": 5, "type": "chunk", "descriptor": 4, "offset": 80, "length": 72, "n": 1, "t_first": 2.0, "t_last": 2.0},
        {"seq": 6, "type": "chunk", "descriptor": 1, "offset": 152, "length": 40, "n": 0, "t_first": None,
         "t_last": None},
        {"seq": 7, "type": "raw", "name": "imu", "t": 2.5, "offset": 0, "length": 4},
        {"seq": 8, "type": "stop", "reason": "aborted", "data": {}},
        {"seq": 9, "type": "resume", "after_chunk": 6, "repaired": [], "data": {}},
        {"seq": 10, "type": "chunk", "descriptor": 1, "offset": 192, "length": 80, "n": 2, "t_first": 1.0,
         "t_last": 1.5}]
    samples = (d / "samples.bin").read_bytes()
    assert len(samples) == 272
    for doc, crc in zip(got, crcs):
        if doc["type"] == "chunk":
            record = samples[doc["offset"]:doc["offset"] + doc["length"]]
            assert struct.unpack_from("<4sIQQQQ", record) == (b"FCS1", crc, doc["seq"], doc["descriptor"], doc["n"],
                                                             doc["length"] - 40)
            assert zlib.crc32(record[40:]) == crc
    assert crcs[7] == zlib.crc32(b"abcd")
    assert samples[192 + 40:192 + 56] == np.array([1.0, 1.5], "<f8").tobytes()


def test_a_samples_file_cut_after_the_reader_opened_the_session_is_named_when_read(tmp_path):
    d = forge_with_record(tmp_path / "s", *_record())
    r = SessionReader(d)  # a snapshot: the file was whole then
    with open(d / "samples.bin", "r+b") as fh:
        fh.truncate(90)
    with pytest.raises(SessionError) as exc:
        list(r.chunks())
    assert str(exc.value) == f"{d / 'samples.bin'}: chunk 2 at byte 0 (log line 3): the file ends inside the record"
    assert exc.value.line == 3 and exc.value.path == str(d / "samples.bin")
