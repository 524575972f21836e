"""The on-disk session: exact round trips, torn tails, SIGKILL, determinism, one-line errors."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from drivers.chunk import SampleChunk
from fieldcal.session import capture as session_module
from fieldcal.earth import Station
from fieldcal.paramfile import ParameterFile, TriadParameters, dump, hash_inputs, load
from fieldcal.session.capture import LOG, SAMPLES, SessionError, SessionReader, SessionStateError, SessionWriter, to_plain

ROOT = Path(__file__).resolve().parents[1]

# Shared by the tests and the SIGKILL child process: chunk i is a function of (seed, i) only.
CHUNK_LIB = '''
import numpy as np
from drivers.chunk import SampleChunk

def make_chunk(seed, i, n=250):
    rng = np.random.default_rng([seed, i])
    t = (i * n + np.arange(n)) / 250.0
    triads = {name: rng.standard_normal((n, 3)) for name in ("accelerometer", "gyroscope", "inclinometer")}
    triads["gyroscope"][rng.integers(n), rng.integers(3)] = np.nan
    return SampleChunk(t=t, triads=triads, temperature=20.0 + rng.standard_normal(n))
'''
_ns: dict = {}
exec(CHUNK_LIB, _ns)  # noqa: S102 -- the same source runs in the SIGKILL child
make_chunk = _ns["make_chunk"]


# --------------------------------------------------------------------------------------------
# Helpers


def _bits(a: np.ndarray) -> tuple[str, tuple, bytes]:
    a = np.asarray(a)
    le = np.ascontiguousarray(a, dtype=a.dtype.newbyteorder("<"))
    return np.dtype(le.dtype).str, le.shape, le.tobytes()


def assert_identical(got: SampleChunk, want: SampleChunk) -> None:
    assert _bits(got.t) == _bits(want.t)
    assert list(got.triads) == list(want.triads)
    for name in want.triads:
        assert _bits(got.triads[name]) == _bits(want.triads[name]), name
    assert (got.temperature is None) == (want.temperature is None)
    if want.temperature is not None:
        assert _bits(got.temperature) == _bits(want.temperature)
    assert list(got.extras) == list(want.extras)
    for name in want.extras:
        assert _bits(got.extras[name]) == _bits(want.extras[name]), name


def assert_all_identical(got, want) -> None:
    got, want = list(got), list(want)
    assert len(got) == len(want)
    for g, w in zip(got, want):
        assert_identical(g, w)


def small_chunk(i: int, n: int = 4) -> SampleChunk:
    rng = np.random.default_rng(i)
    return SampleChunk(t=i * 10.0 + np.arange(n) * 0.004, triads={"accelerometer": rng.standard_normal((n, 3))})


def write_basic(directory: Path, n_chunks: int = 4, last: str = "chunk") -> list:
    """Small chunks with actions/events after the even ones; the last line is a chunk or an event."""
    w = SessionWriter.create(directory, {"procedure": "field-18", "seed": 3})
    chunks = []
    for i in range(n_chunks):
        c = small_chunk(i)
        w.chunk(c)
        chunks.append(c)
        if i % 2 == 0:
            w.action({"kind": "confirm", "i": i})
            w.event({"kind": "still", "i": i})
    if last == "event":
        w.event({"kind": "final"})
    w.close()
    return chunks


def lines_of(path: Path) -> list[bytes]:
    return path.read_bytes().splitlines(keepends=True)


@pytest.fixture
def no_fsync(monkeypatch):
    """For tests of logic that open and close hundreds of sessions: durability is tested apart."""
    monkeypatch.setattr(os, "fsync", lambda fd: None)


def _resign(line: bytes) -> bytes:
    """A log line edited on purpose, with its checksum made right again (to reach the checks
    behind the checksum); computed here from the format's definition, not by the writer's code."""
    import zlib

    body = line.rstrip(b"\n")
    body = body[:body.rindex(b',"crc":')] + b"}"
    return body[:-1] + b',"crc":%d}\n' % zlib.crc32(body)


def one_line(exc: BaseException) -> str:
    text = str(exc)
    assert "\n" not in text and text
    return text


def continue_session(directory: Path, extra: SampleChunk) -> SessionWriter:
    w = SessionWriter.append_to(directory)
    w.resume({"by": "test"})
    w.chunk(extra)
    w.stop("completed")
    w.close()
    return w


# --------------------------------------------------------------------------------------------
# Round trips


def test_chunks_round_trip_bit_for_bit(tmp_path):
    rng = np.random.default_rng(1)
    n = 7
    special = np.array([np.nan, -np.nan, np.inf, -np.inf, -0.0, 5e-324, 1.7976931348623157e308])
    payload_nan = np.frombuffer(np.array([0x7FF0_0000_DEAD_BEEF], dtype="<u8").tobytes(), dtype="<f8")
    acc = rng.standard_normal((n, 3))
    acc[:, 0] = special
    acc[0, 1] = payload_nan[0]
    chunks = [
        SampleChunk(t=np.arange(n) * 0.004, triads={"accelerometer": acc, "gyroscope": rng.standard_normal((n, 3))},
                    temperature=np.full(n, np.nan)),
        SampleChunk(t=np.arange(n) * 0.004 + 1, triads={"accelerometer": rng.standard_normal((n, 3)),
                                                        "gyroscope": rng.standard_normal((n, 3))},
                    temperature=rng.standard_normal(n)),
        # other layouts: no temperature, integer extras, float32 and big-endian triads, n == 0
        SampleChunk(t=np.arange(3.0), triads={"magnetometer": rng.standard_normal((3, 3)).astype(np.float32)},
                    extras={"counter": np.array([1, 2, 2**40], dtype=np.int64),
                            "flags": np.array([0, 255, 7], dtype=np.uint8)}),
        SampleChunk(t=np.arange(2.0), triads={"accelerometer": rng.standard_normal((2, 3)).astype(">f8")}),
        SampleChunk(t=np.zeros(0), triads={"accelerometer": np.zeros((0, 3))}),
        SampleChunk(t=np.arange(n) * 0.004 + 2, triads={"accelerometer": rng.standard_normal((n, 3)),
                                                        "gyroscope": rng.standard_normal((n, 3))},
                    temperature=rng.standard_normal(n)),
    ]
    with SessionWriter.create(tmp_path / "s", {"device": "IMU-7"}) as w:
        seqs = [w.chunk(c) for c in chunks]
        w.stop("completed")
    r = SessionReader(tmp_path / "s")
    assert_all_identical(r.chunks(), chunks)
    got = list(r.chunks())
    assert got[0].triads["accelerometer"][0, 1].view("<u8") == 0x7FF0_0000_DEAD_BEEF
    assert np.signbit(got[0].triads["accelerometer"][4, 0])
    assert got[2].extras["counter"].dtype == np.int64 and got[3].triads["accelerometer"].dtype == np.float64
    got[0].t[0] = 99.0  # chunks read back are ordinary writable arrays
    # one descriptor per distinct layout, written just before its first chunk
    docs = list(r.documents())
    assert [d["type"] for d in docs] == ["start", "descriptor", "chunk", "chunk", "descriptor", "chunk",
                                         "descriptor", "chunk", "chunk", "chunk", "stop"]
    assert docs[9]["descriptor"] == docs[1]["seq"]
    assert seqs == [d["seq"] for d in docs if d["type"] == "chunk"]
    assert [d["seq"] for d in docs] == list(range(len(docs)))
    cols = docs[4]["columns"]
    assert cols == [{"name": "t", "role": "time", "dtype": "<f8"},
                    {"name": "magnetometer", "role": "triad", "dtype": "<f4"},
                    {"name": "counter", "role": "extra", "dtype": "<i8"},
                    {"name": "flags", "role": "extra", "dtype": "|u1"}]
    chunk_doc = docs[2]
    assert chunk_doc["t_first"] == 0.0 and chunk_doc["t_last"] == (n - 1) * 0.004 and chunk_doc["n"] == n
    assert docs[8]["t_first"] is None and docs[8]["n"] == 0
    assert r.stopped and r.stop_reason == "completed"
    assert r.n_chunks == len(chunks) and r.n_samples == sum(len(c) for c in chunks)
    assert r.torn == []


def test_documents_actions_and_their_interleaving(tmp_path):
    w = SessionWriter.create(tmp_path / "s", {"procedure": "field-18", "procedure_yaml": "name: x\nsteps: []\n",
                                              "seed": 42, "simulation_truth": {"K": np.eye(3)}})
    expected = []
    for i in range(6):
        c = small_chunk(i)
        w.chunk(c)
        expected.append(("chunk", c))
        if i in (0, 3):
            a = {"kind": "start_rotation", "rate": np.float64(0.1), "dirs": (1, -1), "i": np.int32(i)}
            w.action(a)
            expected.append(("action", {"kind": "start_rotation", "rate": 0.1, "dirs": [1, -1], "i": i}))
        if i == 3:
            w.action({"kind": "skip"})
            expected.append(("action", {"kind": "skip"}))
        w.event({"kind": "progress", "i": i, "fraction": i / 6})
    w.step({"position": 7, "mean": np.array([0.1, -0.0, 9.81]), "n": 250, "bad": float("nan")})
    w.checkpoint({"rng": np.random.default_rng(5).bit_generator.state})
    w.checkpoint({"rng": np.random.default_rng(6).bit_generator.state, "step": 8})
    w.stop("aborted", {"why": "operator"})
    w.close()

    r = SessionReader(tmp_path / "s")
    assert r.start["seed"] == 42 and r.start["simulation_truth"] == {"K": np.eye(3).tolist()}
    assert r.start["procedure_yaml"] == "name: x\nsteps: []\n"
    got = list(r.replay_items())
    assert [k for k, _ in got] == [k for k, _ in expected]
    for (kind, item), (_, want) in zip(got, expected):
        if kind == "chunk":
            assert_identical(item, want)
        else:
            assert item == want
    assert [e["i"] for e in r.events()] == list(range(6))
    [step] = r.steps()
    assert step["mean"] == [0.1, -0.0, 9.81] and np.signbit(step["mean"][1]) and np.isnan(step["bad"])
    checkpoint = [doc["data"] for doc in r.documents("checkpoint")][-1]  # the last one
    assert checkpoint == {"rng": np.random.default_rng(6).bit_generator.state, "step": 8}
    rng = np.random.default_rng()
    rng.bit_generator.state = checkpoint["rng"]  # a checkpointed RNG state restores exactly
    assert rng.random() == np.random.default_rng(6).random()
    assert r.stopped and r.stop_reason == "aborted"
    # actions record the chunk they came after
    actions = list(r.documents("action"))
    chunk_seqs = [d["seq"] for d in r.documents("chunk")]
    assert [a["after_chunk"] for a in actions] == [chunk_seqs[0], chunk_seqs[3], chunk_seqs[3]]
    # with markers: resume/checkpoint documents can be included in the stream
    assert [k for k, _ in r.replay_items(("checkpoint",))] == ["checkpoint", "checkpoint"]


def test_json_values_become_plain_and_unsupported_ones_are_refused(tmp_path):
    value = {"a": (1, 2.5, np.float32(0.1)), "b": np.arange(3, dtype=np.int16), "c": np.bool_(True),
             "big": 2**100, "text": "µ-rate °/h\n", "inf": float("-inf"), "nested": [{"x": None}]}
    plain = to_plain(value)
    assert plain == {"a": [1, 2.5, float(np.float32(0.1))], "b": [0, 1, 2], "c": True, "big": 2**100,
                     "text": "µ-rate °/h\n", "inf": float("-inf"), "nested": [{"x": None}]}
    w = SessionWriter.create(tmp_path / "s", {})
    w.event(value)
    for bad, where in (({1: "x"}, "keys must be strings"), ({"p": Path("x")}, "event.p"),
                       ({"z": 1j}, "event.z")):
        with pytest.raises(TypeError, match=where):
            w.event(bad)
    with pytest.raises(TypeError, match="expected a dict"):
        w.step([1, 2])
    w.close()
    log = (tmp_path / "s" / LOG).read_bytes()
    assert log.isascii()
    [event] = SessionReader(tmp_path / "s").events()
    assert event == plain  # the refused calls wrote nothing


def test_raw_bytes_with_arrival_times_from_another_thread(tmp_path):
    w = SessionWriter.create(tmp_path / "s", {})
    reads = {"imu": [(0.001 * i, bytes([i % 256]) * (i % 7 + 1)) for i in range(300)],
             "table": [(0.01 * i, f"OK {i}\r\n".encode()) for i in range(100)]}

    def tap(name):
        for t, data in reads[name]:
            w.write_raw(name, t, data)

    threads = [threading.Thread(target=tap, args=(name,)) for name in reads]
    for th in threads:
        th.start()
    chunks = []
    for i in range(30):
        chunks.append(small_chunk(i))
        w.chunk(chunks[-1])
    for th in threads:
        th.join()
    w.stop("completed")
    w.close()
    r = SessionReader(tmp_path / "s")
    assert r.raw_names == ["imu", "table"]
    for name, want in reads.items():
        assert list(r.raw(name)) == want
        assert (tmp_path / "s" / f"raw-{name}.bin").read_bytes() == b"".join(d for _, d in want)
    assert_all_identical(r.chunks(), chunks)
    with pytest.raises(ValueError, match="raw stream name"):
        SessionWriter.create(tmp_path / "t", {}).write_raw("../x", 0.0, b"")


def test_a_flipped_byte_in_a_raw_capture_is_refused_not_read(tmp_path):
    """A raw device-byte file is checked against the CRC-32 its log line recorded: one changed
    byte ("2.0" read back as "3.0") is an error naming the file and the read, not a quiet value."""
    d = tmp_path / "s"
    w = SessionWriter.create(d, {})
    w.write_raw("imu", 1.0, b"ACC 1.0\r\n")
    w.write_raw("imu", 1.1, b"ACC 2.0\r\n")
    w.close()
    assert list(SessionReader(d).raw("imu")) == [(1.0, b"ACC 1.0\r\n"), (1.1, b"ACC 2.0\r\n")]
    path = d / "raw-imu.bin"
    data = bytearray(path.read_bytes())
    assert data[13:16] == b"2.0"
    data[13] = ord("3")  # the same length, the same shape: only the checksum can tell
    path.write_bytes(bytes(data))
    reads = SessionReader(d).raw("imu")
    assert next(reads) == (1.0, b"ACC 1.0\r\n")  # the read before the flip is intact
    with pytest.raises(SessionError, match=r"raw-imu\.bin: read at byte 9 .*checksum mismatch"):
        next(reads)


def _parameter_file(bias_x: float = 0.01) -> ParameterFile:
    triad = TriadParameters(name="accelerometer", kind="specific_force", output_unit="m/s^2",
                            bias=np.array([bias_x, -0.02, 0.03]), K=np.eye(3) * 1.001, sigma=np.full(9, 1e-4),
                            residual_rms=1e-3, method="powell")
    return ParameterFile.build([triad], station=Station(latitude_deg=48.15, height_m=520.0),
                               procedure="field-18", method="powell", input_sha256=hash_inputs(np.zeros(3)))


def test_parameters_are_saved_into_the_session_and_noted(tmp_path):
    pf = _parameter_file()
    w = SessionWriter.create(tmp_path / "s", {})
    w.chunk(small_chunk(0))
    w.write_parameters(pf)
    w.stop("completed")
    w.write_parameters(pf)  # e.g. solved again afterwards: allowed after stop
    w.close()
    r = SessionReader(tmp_path / "s")
    assert r.parameters_path == tmp_path / "s" / "parameters-002.yaml"
    loaded = load(r.parameters_path)
    assert np.array_equal(loaded.triad("accelerometer").K, pf.triad("accelerometer").K)
    import hashlib
    assert list(r.documents("parameters"))[-1]["sha256"] == hashlib.sha256(r.parameters_path.read_bytes()).hexdigest()
    assert sorted(p.name for p in (tmp_path / "s").iterdir()) == [
        "lock", "log.jsonl", "parameters-001.yaml", "parameters-002.yaml", "parameters.yaml", "samples.bin"]
    assert (tmp_path / "s" / "parameters.yaml").read_bytes() == r.parameters_path.read_bytes()


def _other_parameter_file() -> ParameterFile:
    """Another calibration of the same unit: a different accelerometer bias."""
    return _parameter_file(bias_x=0.02)


def test_each_calibration_of_a_session_is_kept_and_the_newest_is_current(tmp_path):
    """Issue 16 item 4: re-calibrating replaced parameters.yaml without a backup."""
    import hashlib

    d = tmp_path / "s"
    w = SessionWriter.create(d, {})
    w.chunk(small_chunk(0))
    w.stop("imported")
    w.close()
    files = []
    for pf in (_parameter_file(), _other_parameter_file(), _parameter_file()):
        w = SessionWriter.append_to(d)  # as `fieldcal calibrate SESSION` does, once per run
        w.write_parameters(pf)
        w.close()
        files.append(dump(pf).encode())
    assert files[0] != files[1]
    numbered = sorted(d.glob("parameters-*.yaml"))
    assert [p.name for p in numbered] == ["parameters-001.yaml", "parameters-002.yaml", "parameters-003.yaml"]
    assert [p.read_bytes() for p in numbered] == files
    assert (d / "parameters.yaml").read_bytes() == files[-1]
    docs = list(SessionReader(d).documents("parameters"))
    assert [doc["file"] for doc in docs] == [p.name for p in numbered]
    assert [doc["sha256"] for doc in docs] == [hashlib.sha256(f).hexdigest() for f in files]
    assert SessionReader(d).parameters_path == numbered[-1]


def test_an_old_session_with_one_parameters_yaml_reads_and_keeps_it_on_recalibration(tmp_path):
    d = tmp_path / "old"
    w = SessionWriter.create(d, {})
    w.chunk(small_chunk(0))
    w.stop("imported")
    w.write_parameters(_parameter_file(), "cal.yaml")
    w.close()
    # what an older fieldcal left: the single file named in the log, no numbered copies
    (d / "cal.yaml").rename(d / "parameters.yaml")
    lines = lines_of(d / LOG)
    lines[-1] = _resign(lines[-1].replace(b'"file":"cal.yaml"', b'"file":"parameters.yaml"'))
    (d / LOG).write_bytes(b"".join(lines))
    old = (d / "parameters.yaml").read_bytes()
    assert SessionReader(d).parameters_path == d / "parameters.yaml"
    w = SessionWriter.append_to(d)
    w.write_parameters(_other_parameter_file())
    w.close()
    assert (d / "parameters-001.yaml").read_bytes() == old  # kept before being replaced
    assert (d / "parameters-002.yaml").read_bytes() == (d / "parameters.yaml").read_bytes() != old


# --------------------------------------------------------------------------------------------
# Torn tails and resume


def _cut_copy(src: Path, dst: Path, log_size: int | None = None, samples_size: int | None = None) -> Path:
    dst.mkdir()
    for p in src.iterdir():
        data = p.read_bytes()
        if p.name == LOG and log_size is not None:
            data = data[:log_size]
        if p.name == SAMPLES and samples_size is not None:
            data = data[:samples_size]
        (dst / p.name).write_bytes(data)
    return dst


def test_a_torn_last_log_line_at_every_byte(tmp_path, no_fsync):
    base = tmp_path / "base"
    chunks = write_basic(base)
    full_docs = list(SessionReader(base).documents())
    lines = lines_of(base / LOG)
    assert full_docs[-1]["type"] == "chunk"
    start_of_last = sum(len(x) for x in lines[:-1])
    extra = small_chunk(99)
    for cut in range(start_of_last, start_of_last + len(lines[-1])):
        d = _cut_copy(base, tmp_path / f"c{cut}", log_size=cut)
        r = SessionReader(d)
        assert list(r.documents()) == full_docs[:-1]
        assert_all_identical(r.chunks(), chunks[:-1])
        assert not r.stopped
        # the last chunk's samples are orphans now: a torn line (if any) and those bytes are reported
        assert any(SAMPLES in t for t in r.torn)
        assert (cut > start_of_last) == any("torn last line" in t for t in r.torn)
        w = continue_session(d, extra)
        r2 = SessionReader(d)
        docs = list(r2.documents())
        assert docs[:len(full_docs) - 1] == full_docs[:-1]
        assert [x["type"] for x in docs[len(full_docs) - 1:]] == ["resume", "chunk", "stop"]
        assert docs[len(full_docs) - 1]["repaired"] and not w.repaired
        assert_all_identical(r2.chunks(), chunks[:-1] + [extra])
        assert r2.torn == [] and r2.stopped


def test_samples_cut_inside_a_logged_record_is_damage_named_and_never_cut(tmp_path, no_fsync):
    """Issue 16 item 3: resume cut 2,818 log documents of a completed session after its
    samples.bin was truncated. A crash writes the record before its log line, so a log pointing
    past the end of samples.bin is damage: refused, naming the file, the byte and the line."""
    base = tmp_path / "base"
    write_basic(base, last="event")
    full_docs = list(SessionReader(base).documents())
    record = [doc for doc in full_docs if doc["type"] == "chunk"][-1]
    log_before = (base / LOG).read_bytes()
    for cut in (record["offset"], record["offset"] + 1, record["offset"] + record["length"] - 1):
        d = _cut_copy(base, tmp_path / f"c{cut}", samples_size=cut)
        for opener in (SessionReader, SessionWriter.append_to):
            with pytest.raises(SessionError) as exc:
                opener(d)
            assert one_line(exc.value) .startswith(
                f"{d / SAMPLES}: damaged: the file ends at byte {cut}, but log.jsonl line {record['seq'] + 1} "
                f"(chunk {record['seq']}) says it was written up to byte {record['offset'] + record['length']}")
        assert (d / LOG).read_bytes() == log_before and (d / SAMPLES).stat().st_size == cut
        assert not list(d.glob("*.torn*"))


def test_a_torn_unlogged_samples_record_at_every_byte_is_cut_and_kept(tmp_path, no_fsync):
    """A crash between a record and its log line: the record (any prefix of it) is the torn tail."""
    base = tmp_path / "base"
    chunks = write_basic(base, last="chunk")
    full_docs = list(SessionReader(base).documents())
    record = full_docs[-1]
    lines = lines_of(base / LOG)
    samples = (base / SAMPLES).read_bytes()
    extra = small_chunk(99)
    for cut in range(record["offset"] + 1, record["offset"] + record["length"] + 1, 7):
        d = _cut_copy(base, tmp_path / f"c{cut}", log_size=len(b"".join(lines[:-1])), samples_size=cut)
        r = SessionReader(d)
        assert list(r.documents()) == full_docs[:-1]
        n = cut - record["offset"]
        assert r.torn == [f"samples.bin: ignored {n} byte{'s' if n > 1 else ''} after the last logged chunk "
                          f"(from byte {record['offset']})"]
        continue_session(d, extra)
        assert (d / "samples.bin.torn").read_bytes() == samples[record["offset"]:cut]
        r2 = SessionReader(d)
        resume = list(r2.documents("resume"))[0]
        assert resume["repaired"] == [r.torn[0].replace("ignored", "cut") + " (kept in samples.bin.torn)"]
        assert_all_identical(r2.chunks(), chunks[:-1] + [extra])


def test_truncations_are_a_torn_tail_or_named_damage_never_a_silent_cut(tmp_path, no_fsync):
    """Seeded truncations of both files. The expectation is worked out here from the format: the
    log's complete lines must find all their samples; beyond them at most one record, the next."""
    base = tmp_path / "base"
    w = SessionWriter.create(base, {"seed": 1})
    chunks = []
    for i in range(40):
        chunks.append(small_chunk(i, n=1 + i % 5))
        w.chunk(chunks[-1])
        w.write_raw("imu", float(i), bytes(range(i % 9)))
        if i % 3 == 0:
            w.action({"i": i})
    w.stop("aborted")
    w.close()
    full_docs = list(SessionReader(base).documents())
    log_bytes, samples = (base / LOG).read_bytes(), (base / SAMPLES).read_bytes()
    line_ends = np.cumsum([len(x) for x in lines_of(base / LOG)])
    rng = np.random.default_rng(2024)
    outcomes = {"torn": 0, "damage": 0}
    for trial in range(24):
        log_size = int(rng.integers(line_ends[0], len(log_bytes) + 1))
        k = int(np.searchsorted(line_ends, log_size, side="right"))  # complete lines kept
        logged = [doc for doc in full_docs[:k] if doc["type"] == "chunk"]
        need = logged[-1]["offset"] + logged[-1]["length"] if logged else 0
        nxt = full_docs[k] if k < len(full_docs) else None
        # a near miss half the time: the samples file ends inside the next record, or at need
        samples_size = int(rng.integers(need, need + (nxt["length"] if nxt and nxt["type"] == "chunk" else 1))
                           if trial % 2 else rng.integers(0, len(samples) + 1))
        d = _cut_copy(base, tmp_path / f"t{trial}", log_size=log_size, samples_size=samples_size)
        # the next record's seq is bytes 8-16 of its header: before they are there, nothing tells
        torn_ok = samples_size == need or (samples_size > need and nxt is not None and (
            nxt["type"] == "chunk" and samples_size - need <= nxt["length"] or samples_size - need < 16))
        if not torn_ok:
            outcomes["damage"] += 1
            with pytest.raises(SessionError) as exc:
                SessionWriter.append_to(d)
            assert one_line(exc.value).startswith(f"{d / SAMPLES}: damaged: ")
            assert (d / LOG).read_bytes() == log_bytes[:log_size]  # nothing cut
            assert (d / SAMPLES).read_bytes() == samples[:samples_size]
            continue
        outcomes["torn"] += 1
        r = SessionReader(d)
        assert list(r.documents()) == full_docs[:k]
        extra = small_chunk(100 + trial)
        continue_session(d, extra)
        cut_log = log_bytes[line_ends[k - 1]:log_size]
        cut_samples = samples[need:samples_size]
        assert (d / "log.jsonl.torn").read_bytes() == cut_log if cut_log else not (d / "log.jsonl.torn").exists()
        assert (d / "samples.bin.torn").read_bytes() == cut_samples if cut_samples else \
            not (d / "samples.bin.torn").exists()
        r2 = SessionReader(d)
        assert list(r2.documents())[:k] == full_docs[:k]
        assert_all_identical(r2.chunks(), chunks[:len(logged)] + [extra])
        assert r2.torn == []
    assert outcomes["torn"] and outcomes["damage"]


def test_append_to_reports_and_cuts_orphan_bytes(tmp_path):
    d = tmp_path / "s"
    write_basic(d)
    with open(d / SAMPLES, "ab") as fh:
        fh.write(b"FCS1" + b"\x00" * 10)  # a header torn before its seq
    with open(d / LOG, "ab") as fh:
        fh.write(b'{"seq":99,"ty')
    r = SessionReader(d)
    assert len(r.torn) == 2
    assert "log.jsonl: ignored a torn last line (13 bytes at byte" in r.torn[0]
    assert "samples.bin: ignored 14 bytes after the last logged chunk" in r.torn[1]
    w = SessionWriter.append_to(d)
    kept = [" (kept in log.jsonl.torn)", " (kept in samples.bin.torn)"]
    assert w.repaired == [t.replace("ignored", "cut") + k for t, k in zip(r.torn, kept)]
    w.resume({})
    w.close()
    resume = list(SessionReader(d).documents("resume"))[-1]
    assert resume["repaired"] == [t.replace("ignored", "cut") + k for t, k in zip(r.torn, kept)]
    assert (d / "log.jsonl.torn").read_bytes() == b'{"seq":99,"ty'
    assert (d / "samples.bin.torn").read_bytes() == b"FCS1" + b"\x00" * 10


def test_a_second_cut_keeps_the_first_cuts_copy(tmp_path):
    d = tmp_path / "s"
    write_basic(d)
    for tail in (b'{"first', b'{"second'):
        with open(d / LOG, "ab") as fh:
            fh.write(tail)
        SessionWriter.append_to(d).close()
    assert (d / "log.jsonl.torn").read_bytes() == b'{"first'
    assert (d / "log.jsonl.torn-2").read_bytes() == b'{"second'


def test_samples_beyond_the_log_that_are_not_one_record_are_damage(tmp_path):
    """The log cut short by hand (issue 16: `truncate -s 500000 log.jsonl` lost 40 MB of samples)."""
    d = tmp_path / "s"
    write_basic(d, n_chunks=6, last="chunk")
    lines = lines_of(d / LOG)
    chunk_lines = [i for i, line in enumerate(lines) if b'"type":"chunk"' in line]
    cut_at = sum(map(len, lines[:chunk_lines[2]])) + 5  # inside the third chunk's line
    (d / LOG).write_bytes(b"".join(lines)[:cut_at])
    before = (d / SAMPLES).read_bytes()
    for opener in (SessionReader, SessionWriter.append_to):
        with pytest.raises(SessionError) as exc:
            opener(d)
        assert "are more than one unlogged record" in one_line(exc.value)
        assert one_line(exc.value).startswith(f"{d / SAMPLES}: damaged: ")
    assert (d / SAMPLES).read_bytes() == before and not list(d.glob("*.torn"))


def test_resume_after_a_completed_stop_and_run_state_rules(tmp_path):
    d = tmp_path / "s"
    w = SessionWriter.create(d, {})
    w.chunk(small_chunk(0))
    w.stop("aborted")
    with pytest.raises(SessionStateError, match="resume"):
        w.chunk(small_chunk(1))
    with pytest.raises(SessionStateError):
        w.stop("again")
    w.resume({"operator": "continue"})
    with pytest.raises(SessionStateError, match="still active"):
        w.resume({})
    w.chunk(small_chunk(1))
    w.close()
    with pytest.raises(SessionStateError, match="closed"):
        w.event({})
    r = SessionReader(d)
    assert not r.stopped and r.stop_reason is None  # the last run was not stopped: resumable
    w = SessionWriter.append_to(d)
    assert not w.active and w.last_chunk == list(r.documents("chunk"))[-1]["seq"]
    with pytest.raises(SessionStateError, match="resume"):
        w.event({"x": 1})
    w.write_raw("imu", 1.0, b"ok")  # raw capture and parameters need no active run
    w.resume({})
    w.event({"x": 1})
    w.stop("completed")
    w.close()
    r = SessionReader(d)
    assert [doc["type"] for doc in r.documents()] == ["start", "descriptor", "chunk", "stop", "resume", "chunk",
                                                      "raw", "resume", "event", "stop"]
    assert r.stopped and r.stop_reason == "completed"


# --------------------------------------------------------------------------------------------
# SIGKILL


CHILD = CHUNK_LIB + '''
import sys, time
from fieldcal.session.capture import SessionWriter
w = SessionWriter.create(sys.argv[1], {"seed": 11}, fsync_interval_s=0.2)
i = 0
while True:
    w.chunk(make_chunk(11, i))
    if i % 5 == 4:
        w.action({"i": i})
    print(i, flush=True)
    i += 1
    time.sleep(0.001)
'''


def test_sigkill_loses_at_most_the_write_in_progress(tmp_path):
    d = tmp_path / "s"
    proc = subprocess.Popen([sys.executable, "-c", CHILD, str(d)], stdout=subprocess.PIPE, cwd=ROOT,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        printed = []
        for line in proc.stdout:  # the kill lands while the child is writing, wherever it is
            printed.append(int(line))
            if len(printed) >= 300:
                break
        os.kill(proc.pid, signal.SIGKILL)
        rest, _ = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    printed += [int(x) for x in rest.split()]
    assert proc.returncode == -signal.SIGKILL
    assert len(printed) >= 50, "the child wrote too little to test anything"
    r = SessionReader(d)
    got = list(r.chunks())
    # every chunk whose write returned was flushed to the OS: nothing printed is lost
    assert len(printed) <= len(got) <= len(printed) + 1
    assert_all_identical(got, [make_chunk(11, i) for i in range(len(got))])
    # The child logs the action of every fifth chunk before printing that chunk's number: each
    # printed one is there (at least ten of them), and at most the one being written besides.
    logged = [a["i"] for a in r.actions()]
    printed_actions = [i for i in printed if i % 5 == 4]
    assert len(printed_actions) >= 10
    assert logged[:len(printed_actions)] == printed_actions
    assert logged[len(printed_actions):] in ([], [printed_actions[-1] + 5])
    assert not r.stopped
    # and the session continues
    extra = make_chunk(11, 10**6)
    continue_session(d, extra)
    assert_all_identical(SessionReader(d).chunks(), got + [extra])


# --------------------------------------------------------------------------------------------
# Durability cadence and determinism


def test_fsync_at_most_once_per_interval_and_always_on_stop_and_close(tmp_path, monkeypatch):
    synced = []
    real_fsync = os.fsync
    monkeypatch.setattr(session_module.os, "fsync", lambda fd: (synced.append(fd), real_fsync(fd)))
    now = [100.0]
    w = SessionWriter.create(tmp_path / "s", {}, fsync_interval_s=1.0, clock=lambda: now[0])
    files = {w._log.fileno(), w._samples.fileno()}
    synced.clear()
    for t in (100.1, 100.5, 100.99):
        now[0] = t
        w.chunk(small_chunk(0))
        w.event({})
    assert synced == []
    now[0] = 101.0
    w.chunk(small_chunk(1))
    assert set(synced) == files and len(synced) == 2
    assert synced[-1] == w._log.fileno()  # data first, then the log that indexes it
    synced.clear()
    now[0] = 101.5
    w.chunk(small_chunk(2))
    assert synced == []
    w.stop("completed")
    assert len(synced) == 2
    synced.clear()
    w.close()
    assert len(synced) == 2


def _scripted_session(directory: Path) -> None:
    w = SessionWriter.create(directory, {"software": "fieldcal 0.1.0", "seed": 5, "settings": {"rate_hz": 250.0}})
    for i in range(6):
        w.chunk(make_chunk(5, i, n=50))
        w.write_raw("imu", i * 0.2, bytes(range(i, i + 10)))
        if i == 2:
            w.action({"kind": "confirm_position", "position": 3})
        w.event({"kind": "progress", "t": i * 0.2})
    w.step({"position": 3, "mean": np.array([0.1, 0.2, 9.8])})
    w.checkpoint({"rng": np.random.default_rng(5).bit_generator.state})
    w.write_parameters(_parameter_file())
    w.stop("completed")
    w.close()


def test_the_same_calls_give_byte_identical_files(tmp_path):
    _scripted_session(tmp_path / "a")
    _scripted_session(tmp_path / "b")
    names = sorted(p.name for p in (tmp_path / "a").iterdir())
    assert names == sorted(p.name for p in (tmp_path / "b").iterdir())
    assert names == ["lock", "log.jsonl", "parameters-001.yaml", "parameters.yaml", "raw-imu.bin", "samples.bin"]
    for name in names:
        if name == "lock":  # who held it: a PID and a time
            continue
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    first = json.loads(lines_of(tmp_path / "a" / LOG)[0])
    assert list(first) == ["seq", "type", "schema", "metadata", "crc"]


# --------------------------------------------------------------------------------------------
# One-line errors


def test_create_refuses_an_existing_non_empty_directory(tmp_path):
    (tmp_path / "s").mkdir()
    (tmp_path / "s" / "notes.txt").write_text("x")
    with pytest.raises(SessionError) as exc:
        SessionWriter.create(tmp_path / "s", {})
    assert one_line(exc.value).startswith(f"{tmp_path / 's'}: already exists and is not empty")
    (tmp_path / "empty").mkdir()
    SessionWriter.create(tmp_path / "empty", {}).close()  # an empty directory is fine
    (tmp_path / "file").write_text("x")
    with pytest.raises(SessionError, match="not a directory"):
        SessionWriter.create(tmp_path / "file", {})


def test_not_a_session_is_a_one_line_error(tmp_path):
    (tmp_path / "plain").mkdir()
    (tmp_path / "plain" / "x.txt").write_text("x")
    (tmp_path / "file").write_text("x")
    (tmp_path / "emptylog").mkdir()
    (tmp_path / "emptylog" / LOG).write_bytes(b"")
    (tmp_path / "text").mkdir()
    (tmp_path / "text" / LOG).write_bytes(b"hello world\n")
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / LOG).write_bytes(b'{"seq":0,"type":"start","schema":"other/9","metadata":{}}\n')
    cases = {"missing": "no such session directory", "plain": "not a session directory (no log.jsonl)",
             "file": "not a directory", "emptylog": "no complete start document",
             "text": "line 1: not a session log", "other": "line 1: expected a start document of schema"}
    for name, message in cases.items():
        for opener in (SessionReader, SessionWriter.append_to):
            with pytest.raises(SessionError) as exc:
                opener(tmp_path / name)
            assert message in one_line(exc.value), name
            assert str(tmp_path / name) in str(exc.value)


def test_a_missing_data_file_is_an_error_not_a_torn_tail(tmp_path):
    d = tmp_path / "s"
    w = SessionWriter.create(d, {})
    w.chunk(small_chunk(0))
    w.write_raw("imu", 0.5, b"abc")
    w.close()
    (d / "raw-imu.bin").unlink()
    with pytest.raises(SessionError, match=r"raw-imu.bin: missing, but log.jsonl line 4 refers to it"):
        SessionWriter.append_to(d)
    (d / SAMPLES).unlink()
    for opener in (SessionReader, SessionWriter.append_to):
        with pytest.raises(SessionError) as exc:
            opener(d)
        assert one_line(exc.value) == f"{d / SAMPLES}: missing, but log.jsonl line 3 refers to it"
    assert len(lines_of(d / LOG)) == 4  # nothing was cut


def test_garbage_in_the_middle_of_the_log_names_the_line(tmp_path):
    base = tmp_path / "base"
    write_basic(base)
    lines = lines_of(base / LOG)

    def broken(name, new_lines):
        d = _cut_copy(base, tmp_path / name)
        (d / LOG).write_bytes(b"".join(new_lines))
        return d

    at4 = sum(map(len, lines[:3]))
    cases = {
        "garbage": (lines[:3] + [b"\x00\x00garbage\n"] + lines[4:],
                    f"log.jsonl: line 4 (byte {at4}): damaged: no checksum"),
        "gap": (lines[:3] + lines[4:], "log.jsonl: line 4: expected seq 3, got 4"),
        "last": (lines + [b"{not json}\n"], f"log.jsonl: line {len(lines) + 1} "),
        "edited": (lines[:2] + [lines[2].replace(b'"type":"chunk"', b'"type":"blob"')] + lines[3:],
                   f"log.jsonl: line 3 (byte {sum(map(len, lines[:2]))}): damaged: checksum mismatch"),
        "type": (lines[:2] + [_resign(lines[2].replace(b'"type":"chunk"', b'"type":"blob"'))] + lines[3:],
                 "log.jsonl: line 3: unknown document type 'blob'"),
        "offset": (lines[:2] + [_resign(lines[2].replace(b'"offset":0', b'"offset":8'))] + lines[3:],
                   "line 3: chunk at byte 8 of samples.bin, expected 0"),
        "array": (lines[:3] + [b"[1, 2]\n"] + lines[4:], "line 4 (byte "),
    }
    for name, (new_lines, message) in cases.items():
        d = broken(name, new_lines)
        for opener in (SessionReader, SessionWriter.append_to):
            with pytest.raises(SessionError) as exc:
                opener(d)
            assert message in one_line(exc.value), name
            assert exc.value.line == int(message.split("line ")[1].split(":")[0].split(" ")[0])


def test_corrupt_samples_are_detected_with_file_and_line(tmp_path):
    base = tmp_path / "base"
    chunks = write_basic(base)
    docs = list(SessionReader(base).documents("chunk"))
    d = _cut_copy(base, tmp_path / "flip")
    data = bytearray((d / SAMPLES).read_bytes())
    data[docs[2]["offset"] + 60] ^= 0x01
    (d / SAMPLES).write_bytes(bytes(data))
    r = SessionReader(d)
    it = r.chunks()
    assert_all_identical([next(it), next(it)], chunks[:2])
    with pytest.raises(SessionError) as exc:
        next(it)
    text = one_line(exc.value)
    assert f"samples.bin: chunk {docs[2]['seq']} at byte {docs[2]['offset']} (log line {docs[2]['seq'] + 1})" in text
    assert "checksum mismatch" in text
    # a damaged last record is not something to build on either
    d = _cut_copy(base, tmp_path / "last")
    data = bytearray((d / SAMPLES).read_bytes())
    data[docs[-1]["offset"]] ^= 0xFF
    (d / SAMPLES).write_bytes(bytes(data))
    with pytest.raises(SessionError, match="bad record magic"):
        SessionWriter.append_to(d)


def test_a_write_that_breaks_off_stops_the_writer_and_append_to_cuts_the_partial_record(tmp_path):
    d = tmp_path / "s"
    w = SessionWriter.create(d, {})
    chunks = [small_chunk(0), small_chunk(1)]
    for c in chunks:
        w.chunk(c)
    real = w._samples

    class DiskFull:
        def __init__(self):
            self.calls = 0

        def write(self, b):
            self.calls += 1
            if self.calls == 2:  # the header went out, the first column does not
                raise OSError(28, "No space left on device")
            return real.write(b)

        def __getattr__(self, name):
            return getattr(real, name)

    w._samples = DiskFull()
    with pytest.raises(OSError, match="No space"):
        w.chunk(small_chunk(2))
    w._samples = real
    with pytest.raises(SessionStateError) as exc:
        w.event({"after": "failure"})
    assert "an earlier write failed (" in one_line(exc.value) and "append_to" in str(exc.value)
    w.close()
    r = SessionReader(d)
    assert_all_identical(r.chunks(), chunks)
    assert any("samples.bin: ignored 40 bytes" in t for t in r.torn)
    continue_session(d, small_chunk(3))
    assert_all_identical(SessionReader(d).chunks(), chunks + [small_chunk(3)])


def test_misuse_that_writes_nothing_does_not_break_the_writer(tmp_path):
    w = SessionWriter.create(tmp_path / "s", {})
    with pytest.raises(SessionStateError, match="still active"):
        w.resume({})
    with pytest.raises(AttributeError):
        w.write_parameters(object())
    with pytest.raises(TypeError, match="numeric"):
        w.chunk(SampleChunk(t=np.array(["a"]), triads={}))
    w.chunk(small_chunk(0))
    w.close()
    assert SessionReader(tmp_path / "s").n_chunks == 1


# --------------------------------------------------------------------------------------------
# One writer at a time (issue 16 item 1)


LOCK_HOLDER = '''
import sys
from fieldcal.session.capture import SessionWriter
w = SessionWriter.append_to(sys.argv[1])
print("locked", flush=True)
sys.stdin.read()  # hold the lock until the test closes our stdin (or kills us)
w.close()
'''


def _hold_lock(directory: Path) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", LOCK_HOLDER, str(directory)], cwd=ROOT,
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "locked"
    return proc


def test_a_second_writer_is_refused_with_the_holders_pid_and_start_time(tmp_path):
    d = tmp_path / "s"
    write_basic(d)
    holder = _hold_lock(d)
    try:
        log_before, samples_before = (d / LOG).read_bytes(), (d / SAMPLES).read_bytes()
        for second in (lambda: SessionWriter.append_to(d), lambda: SessionWriter.create(d, {})):
            with pytest.raises(ValueError) as exc:
                second()
            text = one_line(exc.value)
            assert text.startswith(f"{d}: ")
            if "another fieldcal" in text:
                assert f"pid {holder.pid} on " in text and ", started 20" in text
            else:  # create is refused before it looks at the lock: the directory is not empty
                assert "already exists and is not empty" in text
        assert (d / LOG).read_bytes() == log_before and (d / SAMPLES).read_bytes() == samples_before
        # readers are not writers: a live session reads as its consistent prefix
        assert SessionReader(d).n_chunks == 4
    finally:
        holder.stdin.close()
        holder.wait(timeout=60)
    SessionWriter.append_to(d).close()  # released on close


def test_the_lock_of_a_killed_writer_is_taken_over(tmp_path):
    d = tmp_path / "s"
    write_basic(d)
    holder = _hold_lock(d)
    os.kill(holder.pid, signal.SIGKILL)
    holder.wait(timeout=60)
    assert f"pid {holder.pid} " in (d / "lock").read_text()  # the dead holder's note is still there
    w = SessionWriter.append_to(d)  # the kernel dropped the flock with the process
    assert f"pid {os.getpid()} " in (d / "lock").read_text()
    w.resume({})
    w.chunk(small_chunk(9))
    w.close()
    assert SessionReader(d).n_chunks == 5


def test_two_writers_in_one_process_are_refused_too(tmp_path):
    w = SessionWriter.create(tmp_path / "s", {})
    with pytest.raises(ValueError, match=f"pid {os.getpid()} on "):
        SessionWriter.append_to(tmp_path / "s")
    w.close()
    SessionWriter.append_to(tmp_path / "s").close()


# --------------------------------------------------------------------------------------------
# Checksummed documents (issue 16 item 5), format versions


def test_one_changed_digit_in_a_step_document_is_refused_on_every_read(tmp_path):
    """Issue 16 item 5: one digit of a step average changed moved a bias and nobody noticed."""
    d = tmp_path / "s"
    w = SessionWriter.create(d, {})
    w.chunk(small_chunk(0))
    w.step({"step": 0, "windows": [{"means": {"accelerometer": [0.01, -0.02, 9.81]}}]})
    w.stop("aborted")
    w.close()
    lines = lines_of(d / LOG)
    step_line = next(i for i, line in enumerate(lines) if b'"type":"step"' in line)
    assert b"9.81" in lines[step_line]
    lines[step_line] = lines[step_line].replace(b"9.81", b"9.91")
    (d / LOG).write_bytes(b"".join(lines))
    for opener in (SessionReader, SessionWriter.append_to):
        with pytest.raises(SessionError) as exc:
            opener(d)
        assert one_line(exc.value).startswith(
            f"{d / LOG}: line {step_line + 1} (byte {sum(map(len, lines[:step_line]))}): damaged: checksum mismatch")
        assert exc.value.line == step_line + 1


def test_a_version_2_line_without_its_checksum_is_refused(tmp_path):
    d = tmp_path / "s"
    write_basic(d)
    lines = lines_of(d / LOG)
    lines[3] = lines[3][:lines[3].rindex(b',"crc":')] + b"}\n"  # a valid document, its checksum gone
    json.loads(lines[3])
    (d / LOG).write_bytes(b"".join(lines))
    with pytest.raises(SessionError, match=r"line 4 \(byte \d+\): damaged: no checksum"):
        SessionReader(d)


DATA = Path(__file__).resolve().parent / "data"


def test_a_completed_session_is_never_resumed(tmp_path):
    d = tmp_path / "s"
    w = SessionWriter.create(d, {})
    w.chunk(small_chunk(0))
    stop = w.stop("completed")
    w.close()
    w = SessionWriter.append_to(d)
    with pytest.raises(SessionError) as exc:
        w.resume({})
    assert one_line(exc.value).startswith(f"{d / LOG}: line {stop + 1}: this session completed; a completed "
                                          "session is never resumed")
    w.close()
    assert SessionReader(d).stop_reason == "completed" and len(lines_of(d / LOG)) == stop + 1
