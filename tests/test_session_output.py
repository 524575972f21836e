"""Parameter files written where the user asks (fieldcal.session.output): never into a session,
never over a file without --force, and the bytes written are the file's own."""
from pathlib import Path

import pytest

from fieldcal.atomic import WouldOverwrite
from fieldcal.paramfile import dump, loads
from fieldcal.session import LOG, SessionError
from fieldcal.session.output import check_output_path, refuse_inside_session, save_parameter_file

GOLDEN = Path(__file__).parent / "data" / "golden" / "headless-resumed" / "parameters.yaml"


def _session(tmp_path) -> Path:
    session = tmp_path / "session"
    session.mkdir()
    (session / LOG).write_text("")
    return session


@pytest.mark.parametrize("inside", ["", "params.yaml"])
def test_a_path_in_a_session_is_refused_in_one_line_naming_both(tmp_path, inside):
    session = _session(tmp_path)
    target = session / inside if inside else session
    with pytest.raises(SessionError) as refused:
        refuse_inside_session(target, "--out's parameter file")
    assert str(refused.value) == (f"{target}: --out's parameter file would be written into the session {session}, "
                                  "whose files are never overwritten nor added to by hand; give a path outside it")
    assert refused.value.path == str(target)


def test_a_directory_named_like_a_log_does_not_make_a_session(tmp_path):
    (tmp_path / LOG).mkdir()  # not a log file: no session here
    refuse_inside_session(tmp_path / "params.yaml", "x")
    refuse_inside_session(tmp_path, "x")


def test_saving_into_a_session_is_refused_before_anything_is_written(tmp_path):
    session = _session(tmp_path)
    with pytest.raises(SessionError, match=r"--params's parameter file would be written into the session"):
        save_parameter_file(None, session / "mine.yaml", option="--params", data=b"x")
    assert sorted(p.name for p in session.iterdir()) == [LOG]


def test_an_existing_file_is_kept_unless_forced_and_the_refusal_names_the_option(tmp_path):
    target = tmp_path / "params.yaml"
    target.write_bytes(b"the user's earlier file\n")
    for refuse in (lambda: check_output_path(target, force=False, option="--out"),
                   lambda: save_parameter_file(None, target, option="--out", data=b"new\n")):
        with pytest.raises(WouldOverwrite) as refused:
            refuse()
        assert str(refused.value) == f"{target}: already exists; not overwritten (give --force to replace it)"
    assert target.read_bytes() == b"the user's earlier file\n"
    check_output_path(target, force=True, option="--out")
    assert save_parameter_file(None, target, force=True, data=b"new\n") == target
    assert target.read_bytes() == b"new\n"


def test_an_input_of_the_command_is_never_written_over_even_with_force(tmp_path):
    target = tmp_path / "params.yaml"
    target.write_bytes(b"input\n")
    with pytest.raises(ValueError, match=r"^--params .*params.yaml is the input .* of this command"):
        save_parameter_file(None, target, force=True, option="--params", data=b"new\n", inputs=(target,))
    assert target.read_bytes() == b"input\n"


def test_a_parameter_file_is_written_as_its_text_and_given_bytes_as_they_are(tmp_path):
    text = GOLDEN.read_text(encoding="utf-8")
    pf = loads(text, str(GOLDEN))
    written = save_parameter_file(pf, tmp_path / "a.yaml")
    assert written == tmp_path / "a.yaml"
    assert written.read_text(encoding="utf-8") == dump(pf)
    again = loads(written.read_text(encoding="utf-8"), str(written))
    assert again.provenance == pf.provenance
    # a session's copy is written byte for byte, not made again from ``pf``
    copy = save_parameter_file(pf, tmp_path / "b.yaml", data=b"# the session's copy\n" + GOLDEN.read_bytes())
    assert copy.read_bytes() == b"# the session's copy\n" + GOLDEN.read_bytes()


def test_the_default_option_named_in_a_refusal_is_out(tmp_path):
    session = _session(tmp_path)
    with pytest.raises(SessionError, match=r": --out's parameter file would be written into the session"):
        save_parameter_file(None, session / "x.yaml", data=b"x")


def test_a_file_made_between_the_check_and_the_write_is_not_written_over(tmp_path, monkeypatch):
    """The write itself refuses too (another process may create the file after the early check)."""
    import fieldcal.session.output as output

    monkeypatch.setattr(output, "check_output_path", lambda *args, **kwargs: None)
    target = tmp_path / "params.yaml"
    target.write_bytes(b"made meanwhile\n")
    with pytest.raises(WouldOverwrite) as refused:
        save_parameter_file(None, target, data=b"new\n")
    assert str(refused.value) == f"{target}: already exists; not overwritten (give --force to replace it)"
    with pytest.raises(ValueError, match=r"is the input .* of this command"):
        save_parameter_file(None, target, force=True, data=b"new\n", inputs=(target,))
    assert target.read_bytes() == b"made meanwhile\n"
