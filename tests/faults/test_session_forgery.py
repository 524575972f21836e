"""Issue 25 (last review, item 6): a session log forged with its line checksums recomputed.

A chunk's t_first/t_last (the log's account of its record's time span, read without the record
by a resume) passed every command when changed; and a step document repeated with the same
index, with no redo or resume to explain it, was taken by `solve` as a redo. Both are refused
in one line naming the file and line.
"""
from __future__ import annotations


import pytest
from test_outputs import one_line

from fieldcal.session.capture import LOG, _dumps, _parse_line


def _docs(session):
    return [_parse_line(line, True) for line in (session / LOG).read_bytes().splitlines(keepends=True)]


def _write(session, docs):
    (session / LOG).write_bytes(b"".join(_dumps(d) for d in docs))


@pytest.mark.parametrize("key", ["t_first", "t_last"])
@pytest.mark.parametrize("command", [["replay", "{S}", "--quiet"], ["allan", "{S}"]])
def test_a_forged_chunk_span_is_refused(capsys, session_copy, key, command):
    docs = _docs(session_copy)
    i = [k for k, d in enumerate(docs) if d["type"] == "chunk"][3]
    true_first, true_last = docs[i]["t_first"], docs[i]["t_last"]
    docs[i][key] = docs[i][key] + (0.001 if key == "t_first" else -0.001)  # still inside, still ordered
    _write(session_copy, docs)
    line = one_line(capsys, [a.replace("{S}", str(session_copy)) for a in command], 2)
    assert f"chunk {docs[i]['seq']} at byte {docs[i]['offset']} (log line {i + 1}): the log gives" in line
    assert f"the record holds {true_first!r} .. {true_last!r} s" in line


def test_a_chunk_span_out_of_order_is_refused_by_the_log_check(capsys, session_copy):
    docs = _docs(session_copy)
    i = [k for k, d in enumerate(docs) if d["type"] == "chunk"][2]
    docs[i]["t_first"], docs[i]["t_last"] = docs[i]["t_last"], docs[i]["t_first"]
    _write(session_copy, docs)
    line = one_line(capsys, ["solve", session_copy], 2)
    assert f"{session_copy / LOG}: line {i + 1}: chunk of {docs[i]['n']} samples from t" in line


def _insert_before_the_stop(docs, extra):
    """``extra`` documents (after the last chunk) put before the run's stop: no chunk after them, so
    only the stop and what follows it are renumbered (a chunk's seq is also in samples.bin)."""
    stop = next(k for k, d in enumerate(docs) if d["type"] == "stop")
    last_chunk = max(d["seq"] for d in docs[:stop] if d["type"] == "chunk")
    seq = docs[stop]["seq"]
    added = [dict(d, seq=seq + j, after_chunk=last_chunk) for j, d in enumerate(extra)]
    return docs[:stop] + added + [dict(d, seq=d["seq"] + len(extra)) for d in docs[stop:]], stop


def test_a_step_document_repeated_without_a_redo_is_refused(capsys, session_copy):
    docs = _docs(session_copy)
    first = next(k for k, d in enumerate(docs) if d["type"] == "step")
    docs, at = _insert_before_the_stop(docs, [docs[first]])  # the first step's document again, at the end
    _write(session_copy, docs)
    line = one_line(capsys, ["solve", session_copy], 2)
    step = docs[first]["data"]["step"]
    assert line == (f"fieldcal: {session_copy / LOG}: line {at + 1}: step document: step {step} again "
                    f"(recorded at line {first + 1}) with no redo, unskip or resume before it: a repeated "
                    "document, not a redo")


def test_a_step_redone_by_the_operator_is_taken(capsys, session_copy):
    """The same copy, preceded by the operator's redo action: taken, as the step's later record."""
    from fieldcal.cli.main import main

    docs = _docs(session_copy)
    first = next(k for k, d in enumerate(docs) if d["type"] == "step")
    redo = {"seq": 0, "type": "action", "after_chunk": 0, "data": {"action": "redo"}}
    docs, _ = _insert_before_the_stop(docs, [redo, docs[first]])
    _write(session_copy, docs)
    assert main(["solve", str(session_copy)]) == 0, capsys.readouterr().err


def _forge_times(session, docs, i, change):
    """Chunk document ``i``'s sample times changed in samples.bin, its record's CRC and its log
    line (checksum, span) recomputed: a forgery every checksum agrees with."""
    import zlib

    import numpy as np

    from fieldcal.session.capture import RECORD_HEADER, SAMPLES

    doc = docs[i]
    with open(session / SAMPLES, "r+b") as fh:
        fh.seek(doc["offset"])
        record = bytearray(fh.read(doc["length"]))
        magic, _, seq, dseq, n, payload = RECORD_HEADER.unpack_from(record)
        t = change(np.frombuffer(record, "<f8", n, RECORD_HEADER.size).copy())
        record[RECORD_HEADER.size:RECORD_HEADER.size + 8 * n] = t.astype("<f8").tobytes()
        crc = zlib.crc32(bytes(record[RECORD_HEADER.size:]))
        RECORD_HEADER.pack_into(record, 0, magic, crc, seq, dseq, n, payload)
        fh.seek(doc["offset"])
        fh.write(record)
    docs[i] = dict(doc, crc32=crc, t_first=t[0].item(), t_last=t[-1].item())
    _write(session, docs)


def _with_nan(t):
    t[5] = float("nan")
    return t


@pytest.mark.parametrize("forgery, said", [
    ("shift", "before chunk"), ("back", "before chunk"), ("copy", "before chunk"),
    ("nan", "sample 5's time nan s is not a finite number"), ("swap", "is before sample 5's")])
@pytest.mark.parametrize("command", [["replay", "{S}", "--quiet"], ["certificate", "{S}", "--out", "{W}/c.html"]])
def test_forged_sample_times_are_refused(capsys, session_copy, tmp_path, forgery, said, command):
    """Issue 25, round 4, item 3: sample times forged consistently (record, CRC and log agreeing)
    passed replay ("identical") and certificate. Time is finite and never goes back within a chunk
    nor from one chunk to the next; the refusal names the file and the chunk."""
    docs = _docs(session_copy)
    chunks = [k for k, d in enumerate(docs) if d["type"] == "chunk"]
    i, previous = chunks[-1], docs[chunks[-2]]  # the last chunk, after every window
    change = {"shift": lambda t: t + 1000.0, "back": lambda t: t - 2.0,
              "copy": lambda t: t - (t[0] - previous["t_first"]), "nan": _with_nan,
              "swap": lambda t: t[[*range(5), 6, 5, *range(7, len(t))]]}[forgery]
    if forgery == "shift":  # the chunk before the last one: the last then goes back in time
        i = chunks[-2]
    _forge_times(session_copy, docs, i, change)
    argv = [a.replace("{S}", str(session_copy)).replace("{W}", str(tmp_path)) for a in command]
    line = one_line(capsys, argv, 2)
    assert said in line and "forged or damaged times" in line
    assert str(session_copy) in line and "chunk " in line
    assert not (tmp_path / "c.html").exists()


def test_a_step_whose_windows_were_moved_onto_another_is_refused_by_line(capsys, session_copy):
    """Issue 25, round 4, item 4: a step document whose window was moved to overlap another
    step's made `solve` say only "fieldcal: windows overlap"; now the session file and the lines."""
    docs = _docs(session_copy)
    first, second = [k for k, d in enumerate(docs) if d["type"] == "step"][:2]
    target = docs[first]["data"]["windows"][0]
    docs[second]["data"]["windows"][0]["start"] = target["start"] + target["duration"] / 2
    _write(session_copy, docs)
    line = one_line(capsys, ["solve", session_copy], 2)
    assert line.startswith(f"fieldcal: {session_copy / LOG}: line {second + 1}: step document: a window from t")
    assert f"(step document at line {first + 1})" in line and "overlap" in line
