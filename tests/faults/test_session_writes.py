"""Issue 25 (last review, items 3 and 4): what a command writes in a session is checked before it
works, and a session file with another name elsewhere is never changed.

3. `resume` refused a linked parameters.yaml only after re-running the rest of the procedure; now
   every path it writes (log, samples, raw streams, their .torn copies, parameters.yaml) is
   checked before any device work.
4. A hard link to a session's log or samples (st_nlink > 1) made every append change the other
   name's content, outside the session: such a file is refused in one line naming it.
"""
from __future__ import annotations

import os

import pytest
from test_outputs import one_line
from test_write_rule import VICTIM, plant, recording, recording_copy, unfinished  # noqa: F401 (fixtures)

from fieldcal.session.capture import LOG, SAMPLES


def test_resume_refuses_a_linked_parameter_file_before_rerunning_anything(capsys, tmp_path, session_copy):
    session = unfinished(session_copy)
    victim = plant(session / "parameters.yaml", tmp_path / "victims")
    log = (session / LOG).read_bytes()
    line = one_line(capsys, ["resume", session, "--quiet"], 2)
    assert line.startswith(f"fieldcal: {session}: cannot resume: {session / 'parameters.yaml'}: is a symbolic link")
    assert line.endswith("; nothing was re-run")
    assert (session / LOG).read_bytes() == log  # not a step re-run, not a line appended
    assert victim.read_bytes() == VICTIM


@pytest.mark.parametrize("name", [LOG, SAMPLES])
@pytest.mark.parametrize("command", ["resume", "calibrate"])
def test_a_session_file_with_a_second_name_is_never_appended_to(capsys, tmp_path, request, name, command,
                                                               quick_session):
    # (quick_session named here, though taken through session_copy below: conftest.py then runs
    # this test on the worker that holds the one quick run, instead of making another)
    session = (unfinished(request.getfixturevalue("session_copy")) if command == "resume"
               else request.getfixturevalue("recording_copy"))
    other = tmp_path / "elsewhere" / name
    other.parent.mkdir()
    os.link(session / name, other)  # the same file under another name, outside the session
    before = other.read_bytes()
    argv = ["resume", session, "--quiet"] if command == "resume" else ["calibrate", session, "--latitude", "40"]
    line = one_line(capsys, argv, 2)
    assert f"{session / name}: has 2 names (hard links)" in line, line
    assert other.read_bytes() == before
    assert not list(session.glob("parameters*.yaml"))


def test_the_writer_refuses_a_hard_linked_log_in_one_line(tmp_path, session_copy):
    """At the session layer too (a library caller that skips the command's checks)."""
    from fieldcal.session import SessionError
    from fieldcal.session.capture import SessionWriter

    session = unfinished(session_copy)
    os.link(session / LOG, tmp_path / "second-name")
    with pytest.raises(SessionError) as err:
        SessionWriter.append_to(session)
    assert str(err.value).startswith(f"{session / LOG}: has 2 names (hard links)")
    assert "\n" not in str(err.value)
