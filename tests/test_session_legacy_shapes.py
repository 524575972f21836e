"""fieldcal.session.legacy on hand-written documents: what marks a format-1 session as written by
a later fieldcal (its version, a numbered parameter file), the refusal's line, and the old TUI's
checkpoints. (tests/test_session_legacy.py reads the real old sessions.)"""
import pytest

from fieldcal.session import LOG, SessionError
from fieldcal.session.legacy import SCHEMA_V1, is_format_1, later_writer, old_tui_bench, refuse_a_later_writer


def start(**metadata) -> dict:
    return {"type": "start", "seq": 0, "schema": SCHEMA_V1, "metadata": metadata}


@pytest.mark.parametrize("software, later", [
    ("fieldcal 0.1.0", False), ("0.1.9", False), ("fieldcal 0.2.0", True), ("0.2", True),
    ("fieldcal 0.10.1", True),  # numbers, not text: 0.10 is after 0.2
    ("fieldcal 1.0.0", True), ("fieldcal 1.1", True), ("imucal 0.5", False), ("fieldcal", False),
    (3, False), (None, False),
])
def test_the_software_version_from_0_2_is_a_later_writer(software, later):
    said = later_writer([start(software=software)])
    assert said == (f"its metadata's software is {software!r}" if later else None)


@pytest.mark.parametrize("environment, said", [
    ({"fieldcal": "0.3.1"}, "its metadata's numeric_environment.fieldcal is '0.3.1'"),
    ({"fieldcal": "0.1.0"}, None),
    ({"numpy": "1.26"}, None),
    ("fieldcal 0.3", None),  # not the environment's shape: nothing read from it
])
def test_the_numeric_environments_fieldcal_version_too(environment, said):
    assert later_writer([start(software="fieldcal 0.1.0", numeric_environment=environment)]) == said


def test_the_software_is_named_first_when_both_say_later():
    docs = [start(software="fieldcal 0.4.0", numeric_environment={"fieldcal": "0.4.0"})]
    assert later_writer(docs) == "its metadata's software is 'fieldcal 0.4.0'"


def test_no_metadata_is_no_later_writer():
    assert later_writer([{"type": "start", "seq": 0, "schema": SCHEMA_V1}]) is None


@pytest.mark.parametrize("name, numbered", [("parameters-001.yaml", True), ("parameters-0012.yaml", True),
                                            ("parameters-01.yaml", False), ("parameters.yaml", False),
                                            ("old-parameters-001.yaml", False), ("parameters-001.yaml.bak", False)])
def test_a_numbered_parameter_file_is_a_later_writers(name, numbered):
    docs = [start(software="fieldcal 0.1.0"), {"type": "event", "seq": 1, "file": "parameters-001.yaml"},
            {"type": "parameters", "seq": 4, "file": name}]
    assert later_writer(docs) == (f"line 5 notes a numbered parameter file ({name})" if numbered else None)


class Reader:
    def __init__(self, directory, docs):
        self.directory, self._docs = directory, docs

    def documents(self):
        return iter(self._docs)


def test_a_format_1_session_by_a_later_writer_is_refused_in_one_line(tmp_path):
    with pytest.raises(SessionError) as refused:
        refuse_a_later_writer(Reader(tmp_path, [start(software="fieldcal 0.2.1")]))
    assert str(refused.value) == (
        f"{tmp_path / LOG}: line 1: says format 1 (no checksums), which only fieldcal before 0.2.0 wrote, but its "
        "metadata's software is 'fieldcal 0.2.1': a later session with its checksums removed; refused (restore "
        "it from a copy)")
    assert refused.value.path == str(tmp_path / LOG) and refused.value.line == 1


def test_a_genuine_format_1_or_any_format_2_session_is_not_refused(tmp_path):
    refuse_a_later_writer(Reader(tmp_path, [start(software="fieldcal 0.1.0")]))
    format_2 = {**start(software="fieldcal 0.5.0"), "schema": "fieldcal-session/2"}
    refuse_a_later_writer(Reader(tmp_path, [format_2]))
    assert is_format_1(start()) and not is_format_1(format_2) and not is_format_1({})


def test_an_old_tui_checkpoint_gives_its_bench_only_to_its_own_step():
    checkpoint = {"type": "checkpoint", "data": {"step": 3, "bench": {"table": "stopped"}}}
    assert old_tui_bench(checkpoint, 3) == {"table": "stopped"}
    assert old_tui_bench(checkpoint, 2) is None and old_tui_bench(checkpoint, None) is None
    assert old_tui_bench({"type": "checkpoint", "data": {"step": 3}}, 3) is None
