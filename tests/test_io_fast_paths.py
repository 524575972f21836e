"""The read side's fast paths against the careful code they stand in for: the same answer, or
the same one-line refusal, on irregular inputs (Hypothesis), the careful path taken whenever the
fast one is not sure."""
from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fieldcal.recording import importer
from fieldcal.recording.errors import RecordingImportError

SHORT = 40  # LONGEST_LINE for these tests: lines near it are cheap to make


def _line_check(text: bytes, cuts: list[int]):
    """check_line_lengths on ``text`` fed in blocks cut at ``cuts``: its count, or its refusal."""
    bounds = [0, *sorted({c % (len(text) + 1) for c in cuts}), len(text)]
    blocks = [text[lo:hi] for lo, hi in zip(bounds, bounds[1:]) if hi > lo]
    try:
        return importer.check_line_lengths(iter(blocks), "f.txt")
    except RecordingImportError as exc:
        return str(exc), exc.line


lines_near_the_bound = st.lists(st.integers(0, 2 * SHORT + 3), max_size=12).map(
    lambda lengths: b"".join(b"x" * n + b"\n" for n in lengths))


@settings(max_examples=300)
@given(text=st.builds(bytes.__add__, lines_near_the_bound, st.binary(max_size=2 * SHORT).map(
    lambda b: b.replace(b"\n", b""))), cuts=st.lists(st.integers(0, 10_000), max_size=6))
def test_the_line_length_check_counts_and_refuses_as_the_careful_count(text, cuts):
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(importer, "LONGEST_LINE", SHORT)
        fast = _line_check(text, cuts)
        patch.setattr(importer, "_last_end_if_short_lines", lambda block, since: None)
        assert fast == _line_check(text, cuts)


def test_the_line_length_check_takes_the_fast_path_on_short_lines(monkeypatch):
    """A text of short lines is counted without listing its line ends (the careful path is not
    taken), and a long line still takes the careful path, which names it."""
    monkeypatch.setattr(importer, "LONGEST_LINE", SHORT)
    careful = []
    exact = importer._last_end_if_short_lines
    monkeypatch.setattr(importer, "_last_end_if_short_lines",
                        lambda block, since: careful.append(r := exact(block, since)) or r)
    assert importer.check_line_lengths(iter([b"1 2 3\n" * 100, b"4 5\n6"]), "f.txt") == 101
    assert None not in careful
    with pytest.raises(RecordingImportError, match="f.txt: line 3 is 41 bytes long"):
        importer.check_line_lengths(iter([b"1\n2\n", b"x" * 41 + b"\n"]), "f.txt")


def test_calibrate_writes_its_parameter_file_through_the_writer_that_saved_the_session(tmp_path, monkeypatch,
                                                                                     capsys):
    """The session calibrate has just written is not reopened, nor its samples read back and
    checked again, to add the parameter file: it holds the recording bit for bit, then the
    stop, then the parameters (the same bytes as --params)."""
    import numpy as np

    from drivers.sim.handheld import simulate_handheld, to_text
    from fieldcal.cli.importing import read_recording
    from fieldcal.cli.main import main
    from fieldcal.recording.store import load_recording
    from fieldcal.session.capture import SessionWriter
    from fieldcal.session.record import RunRecord

    files = to_text(simulate_handheld(6), tmp_path / "text")

    def no_reopening(*args, **kwargs):
        raise AssertionError("the new session was reopened")

    monkeypatch.setattr(SessionWriter, "append_to", no_reopening)
    out = tmp_path / "sessions"
    assert main(["calibrate", *map(str, files), "--map", "imu_tk", "--latitude", "40", "--out", str(out),
                 "--params", str(tmp_path / "p.yaml")]) == 0
    capsys.readouterr()
    (session,) = out.iterdir()
    assert (session / "parameters-001.yaml").read_bytes() == (tmp_path / "p.yaml").read_bytes()
    assert (session / "parameters.yaml").read_bytes() == (tmp_path / "p.yaml").read_bytes()
    types = [d["type"] for d in RunRecord.open(session).documents()]
    assert types[-2:] == ["stop", "parameters"]
    stored, (read, _) = load_recording(session), read_recording(files, "imu_tk")
    np.testing.assert_array_equal(stored.t, read.t)
    for name, values in read.triads.items():
        assert stored.triads[name].tobytes() == values.tobytes()


def test_calibrate_on_text_files_does_not_import_the_session_reader(tmp_path):
    """Calibrating text files writes a session and never reads one: the reader of every kind of
    session and the procedure events it reads stay unloaded; given the session it wrote,
    calibrate reads it, so loads them (the names are real)."""
    import json
    import subprocess
    import sys

    from drivers.sim.handheld import simulate_handheld, to_text

    files = to_text(simulate_handheld(3), tmp_path / "text")
    reader = {"fieldcal.session.record", "fieldcal.procedure.events"}
    loaded = []
    for argv in (["calibrate", *map(str, files), "--map", "imu_tk", "--gravity", "9.80", "--out",
                  str(tmp_path / "sessions"), "--registry", str(tmp_path / "registry.sqlite")],
                 ["calibrate", "SESSION", "--gravity", "9.80", "--registry", str(tmp_path / "registry.sqlite")]):
        if "SESSION" in argv:
            (session,) = (tmp_path / "sessions").iterdir()
            argv[1] = str(session)
        body = (f"import json, sys\nfrom fieldcal.cli.main import main\nassert main({argv!r}) == 0\n"
                "print(json.dumps(sorted(sys.modules)))\n")
        proc = subprocess.run([sys.executable, "-c", body], capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stderr
        loaded.append(set(json.loads(proc.stdout.strip().splitlines()[-1])))
    assert not loaded[0] & reader and reader <= loaded[1]


@settings(max_examples=150)
@given(order=st.permutations(range(6)), scales=st.lists(st.sampled_from([1.0, 0.001, 9.80665, -1.0]), min_size=3,
                                                         max_size=3))
def test_the_parsers_columns_are_the_texts_times_their_scale_however_they_sit(order, scales):
    """Time, a triad and the temperature in any columns (side by side or not), scaled or not:
    each is the text's column times its scale, bit for bit, as float() and a product give it."""
    import numpy as np

    from drivers.protocols.delimited import ChannelMap, DelimitedTextParser, TriadColumns

    rows = [[f"{i}.{k}{i % 7}" for k in range(6)] for i in range(1, 30)]
    time_scale, triad_scale, temperature_scale = abs(scales[0]), scales[1], scales[2]  # time runs forward
    cm = ChannelMap(triads={"a": TriadColumns(tuple(order[1:4]), scale=triad_scale)}, delimiter=None,
                    time_column=order[0], time_scale=time_scale, temperature_column=order[4],
                    temperature_scale=temperature_scale)
    chunk = DelimitedTextParser(cm).feed(("".join(" ".join(r) + "\n" for r in rows)).encode(), 0.0)
    text = np.array([[float(x) for x in r] for r in rows])
    assert chunk.t.tobytes() == (text[:, order[0]] * time_scale).tobytes()
    assert chunk.triads["a"].tobytes() == (text[:, list(order[1:4])] * triad_scale).tobytes()
    assert chunk.temperature.tobytes() == (text[:, order[4]] * temperature_scale).tobytes()


def test_an_imported_recordings_rate_is_its_first_files_median_rate_bit_for_bit(tmp_path, monkeypatch):
    """The recording on the first file's timestamps takes that file's median rate, found once
    while it was read: the same bits as the median over the recording's own steps."""
    import numpy as np

    from drivers.sim.handheld import simulate_handheld, to_text
    from fieldcal.recording import Recording
    from fieldcal.recording.importer import import_recording

    files = to_text(simulate_handheld(3), tmp_path)
    medians = []
    median = np.median
    monkeypatch.setattr(np, "median", lambda *a, **k: medians.append(1) or median(*a, **k))
    recording = import_recording(files, "imu_tk")
    found = len(medians)
    rate = recording.rate_hz
    assert len(medians) == found  # not computed again
    fresh = Recording(t=recording.t.copy(), triads=recording.triads, kinds=recording.kinds, units=recording.units)
    assert np.float64(rate).tobytes() == np.float64(fresh.rate_hz).tobytes()
